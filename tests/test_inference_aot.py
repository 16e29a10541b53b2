"""chekan.runtime.store: executables compiled once and loaded by later processes, never stale."""

from __future__ import annotations

import json
import mmap
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import jax.numpy as jnp
import numpy as np
import pytest

import chekan.jaxconfig  # noqa: F401  (float64, as for every caller of the store)
from chekan.runtime.store import ExecutableStore, source_fingerprint

ROOT = Path(__file__).resolve().parents[1]

# a function with a LAPACK kernel inside (Cholesky): a loaded executable that calls one
# crashed the process before the store initialised jaxlib's LAPACK bindings
PROGRAM = textwrap.dedent(
    """
    import sys
    from pathlib import Path
    import numpy as np
    import jax, jax.numpy as jnp
    jax.config.update("jax_enable_x64", True)
    from chekan.runtime.store import ExecutableStore

    def fn(x, data):
        m = x @ x.T + data["shift"] * jnp.eye(x.shape[0]) * float(sys.argv[3])
        return {"chol": jnp.linalg.cholesky(m), "trace": jnp.trace(m) * data["scale"]}

    store = ExecutableStore(Path(sys.argv[1]), sys.argv[2])
    f = store.jit("toy", fn)
    x = np.arange(12.0).reshape(3, 4) / 10
    data = {"shift": np.float64(2.0), "scale": 3.0}
    how = sys.argv[4] if len(sys.argv) > 4 else ""
    if how == "prefetch":  # load in the background first, as chekan does for what comes next
        store.prefetch("toy", np.zeros((3, 4)), data)
    started = store.preload("toy-run") if how == "preload" else -1  # what the last run used
    out = f(x, data)
    store.remember("toy-run")
    print(store.events[-1][1], repr(float(out["trace"])), repr(float(out["chol"][2, 1])),
          len(store.events), started)
    """
)


def _run(
    folder: Path, fingerprint: str, code: str = "1", how: str = "", xla_flags: str = ""
) -> list[str]:
    """The program in a new process; ``code`` changes what it computes (× the shift);
    ``how``: "prefetch" or "preload" the executable before the call; ``xla_flags``: the
    process's ``XLA_FLAGS``."""
    env = {**os.environ, "PYTHONPATH": str(ROOT), "JAX_PLATFORMS": "cpu", "XLA_FLAGS": xla_flags}
    proc = subprocess.run(
        [sys.executable, "-c", PROGRAM, str(folder), fingerprint, code] + ([how] if how else []),
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    return proc.stdout.split()


def _expected() -> tuple[float, float]:
    x = np.arange(12.0).reshape(3, 4) / 10
    m = x @ x.T + 2.0 * np.eye(3)
    return float(np.trace(m) * 3.0), float(np.linalg.cholesky(m)[2, 1])


def test_a_new_process_loads_what_the_first_compiled_with_the_same_numbers(tmp_path):
    first = _run(tmp_path, "code-v1")
    second = _run(tmp_path, "code-v1")
    assert first[0] == "compiled" and second[0] == "loaded"
    assert first[1:3] == second[1:3]  # bit for bit
    trace, chol = _expected()
    assert float(second[1]) == pytest.approx(trace, rel=1e-14)
    assert float(second[2]) == pytest.approx(chol, rel=1e-14)
    assert len(list(tmp_path.glob("*.jaxexe"))) == 1


def test_a_prefetched_executable_is_loaded_once_and_used(tmp_path):
    first = _run(tmp_path, "code-v1")
    out = _run(tmp_path, "code-v1", how="prefetch")  # same signature: the call waits for it
    assert out[0] == "loaded" and out[3] == "1"  # one event: loaded once, in the background
    assert out[1:3] == first[1:3]


def test_preload_starts_what_the_last_run_used_and_only_for_the_same_code(tmp_path):
    first = _run(tmp_path, "code-v1", how="preload")  # no manifest yet: nothing to start
    assert first[0] == "compiled" and first[4] == "0"
    manifest = tmp_path / "recent" / "toy-run.json"
    assert manifest.is_file()  # remember() wrote what this run used
    out = _run(tmp_path, "code-v1", how="preload")
    assert out[4] == "1"  # started before the call knew its key
    assert out[0] == "loaded" and out[3] == "1"  # the call used that load: one event
    assert out[1:3] == first[1:3]
    other = _run(tmp_path, "code-v2", code="2", how="preload")  # other code: never guessed
    assert other[4] == "0" and other[0] == "compiled"
    manifest.write_text("{not json")  # a damaged manifest only means no preload
    assert _run(tmp_path, "code-v2", code="2", how="preload")[4] == "0"


# a new process that starts loading in the background: the loader's `import scipy.linalg`
# (jaxlib binds LAPACK from SciPy's Cython capsules) must be done before any thread starts,
# or it races the caller's own import of SciPy (a `_DeadlockError`, seen once)
SPY = textwrap.dedent(
    """
    import sys, threading
    from pathlib import Path
    import numpy as np
    import jax
    jax.config.update("jax_enable_x64", True)
    from chekan.runtime.store import ExecutableStore
    assert "scipy.linalg" not in sys.modules  # else the check below proves nothing
    seen = []
    start = threading.Thread.start

    def spy(self):
        if self.name.startswith("aot-"):
            seen.append("scipy.linalg.cython_lapack" in sys.modules)
        return start(self)

    threading.Thread.start = spy
    store = ExecutableStore(Path(sys.argv[1]), sys.argv[2])
    store.prefetch("toy", np.zeros((3, 4)), {"shift": np.float64(2.0), "scale": 3.0})
    loaded = [f.result() is not None for f in store.pending.values()]
    print(seen, loaded)
    """
)


def test_background_loads_bind_lapack_before_their_threads_start(tmp_path):
    _run(tmp_path, "code-v1")  # compiles and stores "toy"
    # the flags `_run` stored under: a developer's own XLA_FLAGS would change the key
    env = {**os.environ, "PYTHONPATH": str(ROOT), "JAX_PLATFORMS": "cpu", "XLA_FLAGS": ""}
    proc = subprocess.run(
        [sys.executable, "-c", SPY, str(tmp_path), "code-v1"],
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert proc.stdout.split("\n")[0] == "[True] [True]"


def test_other_code_never_loads_a_stored_executable(tmp_path):
    _run(tmp_path, "code-v1")
    out = _run(tmp_path, "code-v2", code="2")  # other code, a new fingerprint: compiled
    assert out[0] == "compiled"
    x = np.arange(12.0).reshape(3, 4) / 10
    assert float(out[1]) == pytest.approx(float(np.trace(x @ x.T + 4.0 * np.eye(3)) * 3))
    assert len(list(tmp_path.glob("*.jaxexe"))) == 2


def test_other_xla_flags_never_load_a_stored_executable(tmp_path):
    """XLA_FLAGS change the machine code of the same module (here LLVM's optimisation
    level): a process with other flags compiles its own, then loads that one."""
    first = _run(tmp_path, "code-v1")
    other = "--xla_backend_optimization_level=0"
    assert _run(tmp_path, "code-v1", xla_flags=other)[0] == "compiled"
    again = _run(tmp_path, "code-v1", xla_flags=other)
    assert again[0] == "loaded"
    assert [float(v) for v in again[1:3]] == pytest.approx([float(v) for v in first[1:3]])
    assert _run(tmp_path, "code-v1")[0] == "loaded"


def test_a_new_fingerprint_of_the_same_module_reuses_its_executable(tmp_path):
    first = _run(tmp_path, "code-v1")
    again = _run(tmp_path, "code-v1-edited-elsewhere")  # traced, then found by its module
    assert again[0] == "loaded" and again[1:3] == first[1:3]
    assert len(list(tmp_path.glob("*.jaxexe"))) == 2  # filed under the new key too
    assert _run(tmp_path, "code-v1-edited-elsewhere")[0] == "loaded"


def test_an_unreadable_file_is_discarded_and_compiled_afresh(tmp_path):
    _run(tmp_path, "code-v1")
    (path,) = tmp_path.glob("*.jaxexe")
    for p in tmp_path.rglob("*.jaxexe"):  # the keyed file and the one filed by module
        p.write_bytes(b"not an executable")
    out = _run(tmp_path, "code-v1")
    assert out[0] == "compiled"
    assert float(out[1]) == pytest.approx(_expected()[0], rel=1e-14)
    assert path.stat().st_size > 1000  # written again


def test_an_executable_that_cannot_be_stored_says_so_and_still_runs(tmp_path, monkeypatch):
    """XLA cannot serialise some executables (jax 0.10: ``NotImplementedError`` for one
    with constant arguments): the function still runs, nothing is written, and the store's
    events say why, where the store used to swallow it."""
    from jax.experimental import serialize_executable

    def refuse(compiled):
        raise NotImplementedError("const_args")

    monkeypatch.setattr(serialize_executable, "serialize", refuse)
    store = ExecutableStore(tmp_path, "code-v1")
    f = store.jit("toy", lambda x: 2.0 * x)
    assert float(f(jnp.ones(3))[1]) == 2.0
    assert not list(tmp_path.rglob("*.jaxexe"))
    names = [e for e in store.events if e[0] == "toy"]
    assert names[0] == ("toy", "compiled")
    assert names[1:] == [("toy", "not stored: NotImplementedError: const_args")]


def test_a_store_keeps_the_newest_preload_manifests(tmp_path, monkeypatch):
    """One manifest per label (a tilt program and its options): past MAX_MANIFESTS the
    oldest go when a process remembers, the one it wrote and the newest others stay."""
    from chekan.runtime import store as aot

    monkeypatch.setattr(aot, "MAX_MANIFESTS", 3)
    store = aot.ExecutableStore(tmp_path, "fp")
    store.used["k"] = "toy"  # as if it had run one executable
    recent = tmp_path / "recent"
    recent.mkdir()
    for i in range(5):  # older manifests of other programs, oldest first
        f = recent / f"program-{i}.json"
        f.write_text("{}")
        os.utime(f, ns=(10**18 + i * 10**9, 10**18 + i * 10**9))
    path = store.remember("this-program")
    assert sorted(p.name for p in recent.iterdir()) == [
        "program-3.json",
        "program-4.json",
        "this-program.json",
    ]
    assert json.loads(path.read_text())["executables"] == [{"key": "k", "name": "toy"}]


def test_a_store_over_its_cap_deletes_the_least_recently_used(tmp_path):
    """Over ``max_bytes`` the store deletes the oldest executables down to PRUNE_TO of the
    cap; the newest stay, and so does one this process has loaded, however old."""
    from chekan.runtime.store import PRUNE_TO

    store = ExecutableStore(tmp_path, "code-v1", max_bytes=10_000)
    ages = {f"k{i}": 1_000_000 + 1000 * i for i in range(8)}  # k0 the oldest
    for key, mtime in ages.items():
        f = tmp_path / ("program" if key == "k5" else "") / f"{key}.jaxexe"
        f.parent.mkdir(exist_ok=True)
        f.write_bytes(b"x" * 2_000)
        os.utime(f, (mtime, mtime))
    os.link(tmp_path / "k7.jaxexe", tmp_path / "program" / "k7p.jaxexe")  # counted once
    (tmp_path / "recent").mkdir()
    (tmp_path / "recent" / "calibrate-map.json").write_text("{}")  # not an executable
    store.loaded["k1"] = object()  # in use here
    assert store.prune() == 5  # 16 000 bytes down to ≤ 7 500: k0, k2, k3, k4, k5 (module/)
    left = sorted(p.stem for p in tmp_path.rglob("*.jaxexe"))
    assert left == ["k1", "k6", "k7", "k7p"]
    assert len({p.stat().st_ino for p in tmp_path.rglob("*.jaxexe")}) * 2_000 <= PRUNE_TO * 10_000
    assert (tmp_path / "recent" / "calibrate-map.json").is_file()
    assert store.prune() == 0  # under the cap: nothing more
    assert ExecutableStore(None, "memory only").prune() == 0


def test_past_the_map_budget_the_least_recently_used_executables_are_let_go(tmp_path):
    """Each loaded executable holds memory maps, and past the system's limit XLA dies: a
    store over its ``map_budget`` lets go of other stores' executables, then of its own
    least recently used ones (never the one in hand), and one let go is loaded again from
    its file, same numbers."""
    from chekan.runtime import store as aot

    in_use = aot._maps_in_use()
    if in_use is None:  # pragma: no cover - not Linux
        pytest.skip("this system has no /proc/self/maps")
    held = [
        mmap.mmap(-1, 4096, prot=mmap.PROT_READ | (i % 2) * mmap.PROT_WRITE) for i in range(200)
    ]
    assert aot._maps_in_use() >= in_use + 200  # counted afresh (200 regions not merged)
    del held
    budget = aot._default_map_budget()
    assert budget is not None and budget == int(
        aot.MAP_SHARE * int(Path("/proc/sys/vm/max_map_count").read_text())
    )
    store = ExecutableStore(tmp_path, "code-v1", map_budget=1)  # always over it
    fs = {k: store.jit(f"f{k}", lambda x, k=k: jnp.sin(x) * k + x) for k in range(3)}
    first = float(fs[1](0.5))
    fs[2](0.5)
    fs[0](0.5)
    assert [e for e in store.events if e[1] == "let go"] == [("f1", "let go"), ("f2", "let go")]
    assert len(store.loaded) == 1  # only the one in hand
    assert float(fs[1](0.5)) == first
    assert store.events[-2:] == [("f1", "loaded"), ("f0", "let go")]
    other = ExecutableStore(tmp_path, "code-v2", map_budget=None)  # another root, kept alive
    other.jit("g", lambda x: x + 1.0)(0.5)
    fs[2](0.5)  # loaded again: the other store's executable goes first
    assert other.events[-1] == ("g", "let go") and not other.loaded
    assert store.events[-2:] == [("f2", "loaded"), ("f1", "let go")]
    ahead = ExecutableStore(tmp_path, "code-v1", map_budget=1)
    ahead.prefetch("f0", 0.5)  # a guess that no call asks for
    (guess,) = ahead.pending
    assert float(ahead.jit("f1", lambda x: jnp.sin(x) * 1 + x)(0.5)) == first
    assert not ahead.pending and (guess, "let go") in ahead.events
    roomy = ExecutableStore(tmp_path, "code-v1", map_budget=in_use + 10**6)  # far from it
    for k in range(3):
        roomy.jit(f"f{k}", lambda x, k=k: jnp.sin(x) * k + x)(0.5)
    assert len(roomy.loaded) == 3 and all(e[1] == "loaded" for e in roomy.events)


def test_a_load_marks_the_file_recently_used_under_both_its_names(tmp_path):
    """Loading touches the file, so a prune deletes executables by last use; the keyed
    name and the one filed by program are one file (a hard link), so a load by key also
    keeps the program's name, which the next fingerprint of the same program needs."""
    _run(tmp_path, "code-v1")
    files = list(tmp_path.rglob("*.jaxexe"))
    assert len(files) == 2 and len({f.stat().st_ino for f in files}) == 1
    for f in files:
        os.utime(f, (1_000_000, 1_000_000))
    assert _run(tmp_path, "code-v1")[0] == "loaded"
    assert all(f.stat().st_mtime > 1_000_000 for f in files)


def test_shapes_and_static_leaves_key_the_executables():
    store = ExecutableStore(None, "memory only")
    f = store.jit("scaled", lambda x, how: x * 2 if how == "double" else x * 3)
    assert float(f(jnp.ones(2), "double")[0]) == 2.0
    assert float(f(jnp.ones(2), "triple")[0]) == 3.0  # a static leaf: its own executable
    assert f(jnp.ones(3), "double").shape == (3,)  # a new shape: its own executable
    assert float(f(np.full(2, 5.0), "double")[1]) == 10.0  # same key (NumPy or JAX): reused
    assert [e for _, e in store.events] == ["compiled"] * 3
    assert float(f(7.0, "double")) == 14.0  # Python numbers are traced, as jax.jit does


def test_stored_tells_whether_a_call_would_load_or_compile(tmp_path):
    """``stored``: False before the first call of a signature, True once it is compiled (in
    memory, and in the folder for a new store of the same code), False for another shape
    and for other code."""
    x = np.ones(3)
    memory = ExecutableStore(None, "memory only")
    assert not memory.stored("f", x)
    memory.jit("f", lambda v: v + 1)(x)
    assert memory.stored("f", x) and not memory.stored("f", np.ones(4))
    first = ExecutableStore(tmp_path, "code-v1")
    assert not first.stored("f", x)
    first.jit("f", lambda v: v + 1)(x)
    assert ExecutableStore(tmp_path, "code-v1").stored("f", x)  # a new process: its file
    assert not ExecutableStore(tmp_path, "code-v2").stored("f", x)


def test_scoped_stores_never_share_an_executable():
    store = ExecutableStore(None, "code")
    a = store.scoped("structure A").jit("f", lambda x: x + 1)
    b = store.scoped("structure B").jit("f", lambda x: x + 2)
    assert float(a(jnp.zeros(()))) == 1.0 and float(b(jnp.zeros(()))) == 2.0


def test_source_fingerprint_follows_the_code(tmp_path):
    pkg = tmp_path / "pkg"
    pkg.mkdir()
    (pkg / "m.py").write_text("x = 1\n")
    before = source_fingerprint(pkg)
    assert source_fingerprint(pkg) == before
    (pkg / "m.py").write_text("x = 2\n")
    assert source_fingerprint(pkg) != before
    assert source_fingerprint(pkg, extra=("jax==0",)) != source_fingerprint(pkg)


class _Unhashable:
    """A static leaf that cannot be hashed (its key is then computed on every call)."""

    __hash__ = None  # type: ignore[assignment]

    def __init__(self, k: float) -> None:
        self.k = k

    def __repr__(self) -> str:
        return f"_Unhashable({self.k})"


def test_remembered_keys_equal_fresh_keys_and_tell_programs_apart():
    """The key memo gives the key a fresh computation gives; other shapes, other static
    leaves, another name or a scoped store get their own; an unhashable static leaf works."""
    store = ExecutableStore(None, "fp")
    x, y = np.zeros(3), np.zeros(4)
    first = store._signature("f", (x, "a"))[0]
    assert store._signature("f", (x, "a"))[0] == first
    assert len(store.keys) == 1
    fresh = ExecutableStore(None, "fp")._key("f", *_tree_static_sig((x, "a")))
    assert first == fresh
    others = {
        store._signature("f", (y, "a"))[0],
        store._signature("f", (x, "b"))[0],
        store._signature("g", (x, "a"))[0],
        store.scoped("structure")._signature("f", (x, "a"))[0],
    }
    assert first not in others and len(others) == 4
    f = store.jit("u", lambda v, u: v * u.k)
    np.testing.assert_array_equal(np.asarray(f(x + 1, _Unhashable(2.0))), 2.0)
    np.testing.assert_array_equal(np.asarray(f(x + 1, _Unhashable(3.0))), 3.0)


def _tree_static_sig(args):
    """(treedef, static, signature) of ``args`` as the store builds them."""
    import jax

    from chekan.runtime.store import _aval, _is_array

    leaves, treedef = jax.tree_util.tree_flatten(args)
    dyn = [i for i, v in enumerate(leaves) if _is_array(v)]
    static = tuple((i, leaves[i]) for i in range(len(leaves)) if i not in dyn)
    return treedef, static, [_aval(leaves[i]) for i in dyn]


def test_an_unused_leaf_does_not_fetch_another_trees_executable(tmp_path):
    """jit prunes an unused (here zero-size) argument, so a tree with one more leaf lowers
    to the same text: the store must not hand it the executable of the smaller tree (a
    record model that gained a field met exactly that after an upgrade)."""

    def f(d):
        return jnp.sum(d["a"] * 2.0)

    a = jnp.arange(3.0)
    small = ExecutableStore(tmp_path, "v1").jit("f", f)
    assert float(small({"a": a})) == 6.0
    big = ExecutableStore(tmp_path, "v2").jit("f", f)  # other code: found by its program
    assert float(big({"a": a, "z": jnp.zeros((3, 0))})) == 6.0


def _timed(monkeypatch, spans: list) -> None:
    """Slow every deserialisation by 0.4 s and record (what, start, end) of it and of every
    compile (public jax API only)."""
    import time

    import jax.stages
    from jax.experimental import serialize_executable as se

    real_load, real_compile = se.deserialize_and_load, jax.stages.Lowered.compile

    def load(*a, **k):
        t0 = time.perf_counter()
        spans.append(("load started", t0, t0))
        time.sleep(0.4)
        out = real_load(*a, **k)
        spans.append(("load", t0, time.perf_counter()))
        return out

    def compile_(self, *a, **k):
        t0 = time.perf_counter()
        out = real_compile(self, *a, **k)
        spans.append(("compile", t0, time.perf_counter()))
        return out

    monkeypatch.setattr(se, "deserialize_and_load", load)
    monkeypatch.setattr(jax.stages.Lowered, "compile", compile_)


def test_a_compile_waits_for_the_loads_in_flight_and_loads_share(tmp_path, monkeypatch):
    import time

    # workers died inside XLA's deserialiser beside a compile and beside another load; the
    # cause was the memory maps running out (docs/tuning.md): loads share again, compiles
    # stay apart from them
    first = ExecutableStore(tmp_path, "code-v1")
    for name in ("a", "b"):
        first.jit(name, lambda x: x + 1)(jnp.ones(3))
    spans: list = []
    _timed(monkeypatch, spans)
    store = ExecutableStore(tmp_path, "code-v1")  # what a new process holds
    store.prefetch("a", jnp.ones(3))
    store.prefetch("b", jnp.ones(3))
    for _ in range(500):  # both loads in flight (inside the store's guard) before the compile
        if sum(s[0] == "load started" for s in spans) == 2:
            break
        time.sleep(0.01)
    assert float(store.jit("c", lambda x: x * 5)(jnp.ones(3))[0]) == 5.0  # compiles now
    assert float(store.jit("a", lambda x: x + 1)(jnp.ones(3))[0]) == 2.0
    assert float(store.jit("b", lambda x: x + 1)(jnp.ones(3))[0]) == 2.0
    loads = [s for s in spans if s[0] == "load"]
    (compile_,) = [s for s in spans if s[0] == "compile"]
    assert len(loads) == 2
    assert sorted(e for _, e in store.events) == ["compiled", "loaded", "loaded"]
    assert compile_[1] >= max(end for _, _, end in loads)  # started once both had ended
    assert max(start for _, start, _ in loads) < min(end for _, _, end in loads)  # together


def test_jax_own_compiles_wait_for_the_loads_in_flight(tmp_path, monkeypatch):
    import time

    import jax

    from chekan.runtime.xla import guard_jax_compiles

    # CI crashed again with the store's compiles guarded: JAX's own (a jax.jit outside the
    # store, an eager operation) still ran beside a load
    assert "jax._src.compiler.backend_compile_and_load" in guard_jax_compiles()
    first = ExecutableStore(tmp_path, "code-v1")
    first.jit("a", lambda x: x + 1)(jnp.ones(3))
    spans: list = []
    _timed(monkeypatch, spans)
    store = ExecutableStore(tmp_path, "code-v1")
    store.prefetch("a", jnp.ones(3))
    for _ in range(500):
        if any(s[0] == "load started" for s in spans):
            break
        time.sleep(0.01)
    started = time.perf_counter()
    out = jax.jit(lambda x: x * 7.25 - 0.5)(jnp.ones(5))  # a program new to this process
    ended = time.perf_counter()
    assert float(out[0]) == 6.75
    assert float(store.jit("a", lambda x: x + 1)(jnp.ones(3))[0]) == 2.0
    ((_, load_start, load_end),) = [s for s in spans if s[0] == "load"]
    assert load_start < started and ended >= load_end  # the compile waited for the load


def test_two_threads_asking_for_one_key_compile_it_once():
    """One lock per key: a second thread waits for the first one's compile and uses it (a
    first ``bayes`` compiled its draws twice, one per chunk thread)."""
    import threading
    import time

    store = ExecutableStore(None, "fp")

    def slow(x):
        time.sleep(0.5)  # at trace time: both threads ask before either has it
        return x * 2.0

    f = store.jit("slow", slow)
    start = threading.Barrier(2)
    outs: list[float] = []

    def work() -> None:
        start.wait()
        outs.append(float(f(jnp.ones(3))[0]))

    threads = [threading.Thread(target=work) for _ in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert outs == [2.0, 2.0]
    assert [e for _, e in store.events] == ["compiled"]


def test_nothing_is_patched_at_import_and_the_store_guards_jax_when_first_used(tmp_path):
    code = textwrap.dedent(
        """
        import jax, jax.numpy as jnp
        from jax._src import compiler
        from chekan.runtime.store import ExecutableStore
        before = getattr(compiler.backend_compile_and_load, "guarded_by_chekan", False)
        ExecutableStore(None, "fp").jit("f", lambda x: x + 1)(jnp.ones(2))
        after = getattr(compiler.backend_compile_and_load, "guarded_by_chekan", False)
        print(before, after)
        """
    )
    env = {**os.environ, "PYTHONPATH": str(ROOT), "JAX_PLATFORMS": "cpu"}
    proc = subprocess.run(
        [sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=300
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert proc.stdout.split() == ["False", "True"]
