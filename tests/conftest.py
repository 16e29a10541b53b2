"""Shared fixtures: the paper's protocol, a short simulated session."""

from __future__ import annotations

import faulthandler
import os
import signal
import time
from pathlib import Path

import pytest

# the executable store is the user's (CHEKAN_JAX_CACHE, else ~/.cache/chekan/jax): what the
# README's set-up stored (`chekan warmup`) serves the tests too
# a shell starts a background job (`make test &`, nohup) with SIGINT ignored, and an ignored
# signal stays ignored in every child: the tests that stop `acquire` or `live` with Ctrl-C
# would wait out their timeout. A handled signal is reset to the default on exec.
if signal.getsignal(signal.SIGINT) == signal.SIG_IGN:
    signal.signal(signal.SIGINT, signal.default_int_handler)

# opt-in: CHEKAN_TEST_PROFILE=FILE appends, per test, its wall seconds (setup and teardown
# included) and what it added to the JAX cache folder: which tests compile a model
# structure of their own, where a cold suite spends its time
PROFILE = os.environ.get("CHEKAN_TEST_PROFILE")
# the paper's protocol no. 46, shipped with the repository (a clone stands alone)
PAPER_PROTOCOL = Path(__file__).resolve().parents[1] / "examples" / "calibr_46_protocol.csv"


@pytest.hookimpl(trylast=True)
def pytest_configure(config):
    """Opt-in (``make test`` sets it): ``CHEKAN_CRASH_DIR`` receives each process's stacks
    if it dies (a segmentation fault), ``<worker>.log``; ``tests/crash_report.py`` prints them
    at the end of a failed run, where a CI log's tail shows them (xdist's own report of a
    dead worker ends with the main thread's stack, not the crashing one's)."""
    folder = os.environ.get("CHEKAN_CRASH_DIR")
    if folder:
        Path(folder).mkdir(parents=True, exist_ok=True)
        worker = os.environ.get("PYTEST_XDIST_WORKER", "controller")
        log = open(Path(folder) / f"{worker}.log", "w")  # open until the process exits
        faulthandler.enable(file=log, all_threads=True)
        config.stash[_CRASH_LOG] = log


_CRASH_LOG = pytest.StashKey()


@pytest.fixture(scope="session")
def paper_protocol() -> Path:
    """The paper's protocol no. 46 (``examples/``); missing, the suite fails rather than skips."""
    if not PAPER_PROTOCOL.is_file():
        pytest.fail(f"the paper's protocol is missing from the repository: {PAPER_PROTOCOL}")
    return PAPER_PROTOCOL


@pytest.fixture(scope="session")
def short_program():
    """The paper's eight angles with 300 s dwells (200 s settle): 3 h, ~11 000 samples."""
    from chekan.demo import demo_program

    return demo_program(quick=True)


@pytest.fixture(scope="session")
def short_session(short_program, tmp_path_factory):
    """(record path, Record, Truth) of a short simulated session (seed 7)."""
    from chekan.records import write_record
    from chekan.records.simulate import Truth, simulate_session

    rec, truth = simulate_session(short_program, Truth(serial="T-1"), seed=7)
    path = tmp_path_factory.mktemp("session") / "rec.csv"
    write_record(path, rec)
    return path, rec, truth


@pytest.fixture(scope="session")
def short_session_theta(short_session) -> dict:
    """The joint model's θ (b₁, b₂, K, ε₁, ε₂, Δγ, τ) at the short session's truth, as JAX
    scalars."""
    import jax.numpy as jnp

    truth = short_session[2]
    return {
        "b1": jnp.asarray(truth.b_mgal_per_pix[0]),
        "b2": jnp.asarray(truth.b_mgal_per_pix[1]),
        "K": jnp.asarray(truth.K_pix_per_rad),
        "eps1_arcmin": jnp.asarray(truth.eps_arcmin[0]),
        "eps2_arcmin": jnp.asarray(truth.eps_arcmin[1]),
        "dgamma_arcmin": jnp.asarray(truth.dgamma_arcmin),
        "tau_s": jnp.asarray(truth.tau_s),
    }


def _cache_files(folder: Path) -> dict[str, int]:
    """Every file under ``folder`` and its size."""
    out = {}
    for root, _dirs, files in os.walk(folder):
        for f in files:
            p = os.path.join(root, f)
            try:
                out[p] = os.path.getsize(p)
            except OSError:
                pass
    return out


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item, nextitem):
    """With ``CHEKAN_TEST_PROFILE``: one tab-separated line per test (node id, seconds,
    files and MB added to the cache folder, executables compiled, and the model structures
    they were compiled for, ``;``-separated: ``tests/profile_summary.py`` counts them)."""
    if not PROFILE:
        yield
        return
    from chekan.jaxconfig import cache_dir
    from chekan.runtime.process import executable_store

    cache = cache_dir() or Path(os.devnull)
    before = _cache_files(cache)
    compiles = executable_store().compiles
    done = len(compiles)
    t0 = time.perf_counter()
    yield
    seconds = time.perf_counter() - t0
    added = {p: n for p, n in _cache_files(cache).items() if p not in before}
    now = executable_store().compiles  # a new store where the test cleared the caches
    new = now[done:] if now is compiles else [*compiles[done:], *now]
    scopes = sorted({label for label, _ in new if label})
    with open(PROFILE, "a", encoding="utf-8") as f:
        mb = sum(added.values()) / 1e6
        f.write(
            f"{item.nodeid}\t{seconds:.1f}\t{len(added)}\t{mb:.1f}\t"
            f"{len(new)}\t{';'.join(scopes)}\n"
        )
