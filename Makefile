# Set-up and the two main jobs. Everything runs from a fresh clone with Python 3.11 and pip.
PY ?= python3.11
VENV := .venv
BIN := $(VENV)/bin
DEMO := demo

.PHONY: venv demo test lint bench clean

$(BIN)/chekan: pyproject.toml
	@command -v $(PY) >/dev/null 2>&1 || { echo "need $(PY) (set PY=python3)"; exit 1; }
	$(PY) -m venv $(VENV)
	$(BIN)/pip install -q --upgrade pip
	$(BIN)/pip install -q -e ".[dev,report,dask,bench]"
	@touch $@

venv: $(BIN)/chekan

demo: venv
	$(BIN)/chekan demo --out $(DEMO) --quick

test: venv
	$(BIN)/ruff check .
	$(BIN)/python -m pytest -q

lint: venv
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .

bench: venv
	$(BIN)/python -m bench

clean:
	rm -rf $(VENV) $(DEMO) .pytest_cache
