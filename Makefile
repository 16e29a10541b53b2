# Set-up and the two main jobs. Everything runs from a fresh clone with Python 3.11 and pip.
PY ?= python3.11
VENV := .venv
BIN := $(VENV)/bin
DEMO := demo

.PHONY: venv browser docs demo test lint bench clean

$(BIN)/chekan: pyproject.toml
	@command -v $(PY) >/dev/null 2>&1 || { echo "need $(PY) (set PY=python3)"; exit 1; }
	$(PY) -m venv $(VENV)
	$(BIN)/pip install -q --upgrade pip
	$(BIN)/pip install -q -e ".[dev,report,dask,bench]"
	@touch $@

# bytecode of the project's own modules, as pip writes it for installed packages: a new
# `chekan` process then skips compiling ~50 source files (0.3 s; where PYTHONDONTWRITEBYTECODE
# is set, Python never writes it). Quick, and only changed files are recompiled.
venv: $(BIN)/chekan browser docs $(VENV)/.warm
	@$(BIN)/python -m compileall -q chekan inference hw bench >/dev/null

# the joint model compiled for the default programs' shape buckets and kept in the
# executable store (`chekan warmup`, a few minutes on 2 cores, once per new venv): a first
# map or bayes run of such a program then loads instead of compiling. It says what it
# stored where; run it again after an update of the code (it skips what is stored)
$(VENV)/.warm: $(BIN)/chekan
	$(BIN)/chekan warmup
	@touch $@

# the documentation site (MkDocs, Material theme, mkdocstrings for the API reference) into
# site/ (a few seconds); --strict: a broken link or anchor, a page left out of the nav or a
# docstring the API reference cannot read fails the build. Every `make venv` builds it, so
# `make test` checks it before pytest
docs: $(BIN)/chekan
	NO_MKDOCS_2_WARNING=1 $(BIN)/mkdocs build --strict --quiet -d site

# Debian's chromium for the live page's end-to-end test (playwright drives it; it never
# downloads a browser) and poppler-utils (pdftotext: the certificates' text as a second
# reader beside pypdf). Needs root or sudo; without it those tests are skipped with the reason.
browser:
	@{ command -v chromium && command -v pdftotext; } >/dev/null 2>&1 || { \
	  if [ "$$(id -u)" = 0 ]; then apt-get update -qq && apt-get install -y -qq chromium poppler-utils; \
	  elif sudo -n true 2>/dev/null; then sudo -n apt-get update -qq && sudo -n apt-get install -y -qq chromium poppler-utils; \
	  else echo "browser: no chromium and no root (or password-less sudo): the live-page browser test will be skipped"; fi; }

demo: venv
	$(BIN)/chekan demo --out $(DEMO) --quick

# pytest-xdist: one worker per core (at most 4), a test file per worker so module fixtures
# are built once; the suite is single-threaded CPU work, so 2 cores halve it (10 min 36 s →
# 6 min 31 s warm). `pytest tests/…` alone still runs in one process.
# A worker that dies (a segfault, pytest-timeout's thread ending a hang) ends the run as a
# failure naming its test: xdist 3.8's replacement worker under loadfile can wait forever
# (pytest-xdist#1327; a CI run hung so until its 90 min ran out). A process that crashed
# leaves its stacks in .crash/, printed last (tests/conftest.py, tests/crash_report.py).
test: venv
	$(BIN)/ruff check .
	$(BIN)/mypy
	rm -rf .crash
	CHEKAN_CRASH_DIR=.crash $(BIN)/python -m pytest -q -n auto --maxprocesses 4 --dist loadfile \
	  --max-worker-restart 0 || { rc=$$?; $(BIN)/python tests/crash_report.py .crash; exit $$rc; }

lint: venv
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .
	$(BIN)/mypy

bench: venv
	$(BIN)/python -m bench

clean:
	rm -rf $(VENV) $(DEMO) .pytest_cache site
