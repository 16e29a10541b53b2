r"""Compiled executables kept across processes: trace and compile once, load ever after.

JAX's persistent compilation cache keeps XLA's output, but every new process still traces
and lowers the Python function to compute the cache key: for an optimistix solve over a
large model that is seconds of work before a millisecond-scale call. An
:class:`ExecutableStore` keeps the *loaded-ready executable* instead (ahead-of-time
``jit(f).lower(*args).compile()``, serialised by ``jax.experimental.serialize_executable``),
so a new process that calls the same function on arguments of the same shapes reads a file
and runs.

The key of an executable is everything that decides what it computes:

    key = sha256(name, fingerprint, argument tree and static leaves, shapes and dtypes,
                 jax/jaxlib versions, backend, CPU features, XLA_FLAGS)

``fingerprint`` is the caller's statement of *which code* the function runs (a hash of the
model's source files, say): the store cannot see inside a closure, so a wrong fingerprint
would load a stale executable. On a miss the function is traced and lowered, and the
executable is also filed under the hash of its lowered StableHLO module (``module/``): after an
edit that does not change what a function computes, a new fingerprint costs a trace, not
a compile. Files are written atomically; a file that cannot be loaded is deleted and the
function recompiled (never a wrong answer, at worst a compile).

Serialised executables are machine code: load only files that chekan wrote (the store's
folder is the user's cache, like JAX's own).

The folder is capped (``max_bytes``, default ``MAX_STORE_BYTES``): after each file it
writes, a store over the cap deletes the least recently used files (a load touches its
file) down to ``PRUNE_TO`` of it. Every edit of the code is a new fingerprint, so without a
cap a developer's store only grows (2.2 GB seen). A file deleted while another process
loads it is a failed load there: recompiled, never a wrong answer.
"""

from __future__ import annotations

import contextlib
import hashlib
import os
import pickle
import platform
import tempfile
import threading
import weakref
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import jax
import numpy as np

from chekan.runtime.background import initialise_lapack, loads_in_background
from chekan.runtime.caches import cached
from chekan.runtime.xla import XLA

__all__ = ["ExecutableStore", "source_fingerprint"]

_SUFFIX = ".jaxexe"
#: default size cap of a store's folder, and the fraction of it a prune leaves
MAX_STORE_BYTES = 1 << 30
PRUNE_TO = 0.75
_FORMAT = "chekan-aot/2"  # part of every key: a new format never reads an old file
#: share of the system's limit on memory maps (vm.max_map_count) that a store's loaded
#: executables may fill: one XLA CPU executable of the joint model maps ≈ 1 600 regions
MAP_SHARE = 0.5
# preload threads, taking the executables in their order of first use: 2 beat 1 in every
# interleaved pair of CLI map runs on 2 cores (9 h record: 3.1–5.0 s against 3.5–6.0 s)
PRELOAD_THREADS = 2
#: preload manifests kept in a store's ``recent/`` (one per label: a tilt program and its
#: options): the most recently written stay, the oldest go
MAX_MANIFESTS = 64


class KeyLocks:
    """One lock per key, made on first use under one lock: a thread that loads or compiles
    an executable holds its key's, so a second thread asking for the same key waits and
    uses it rather than compiling it again (the draws' chunks, two threads)."""

    def __init__(self) -> None:
        self._guard = threading.Lock()
        self._locks: dict[str, threading.RLock] = {}

    def __call__(self, key: str) -> threading.RLock:
        with self._guard:
            return self._locks.setdefault(key, threading.RLock())


#: every live store: the memory maps that their executables hold are the process's, so a
#: store over its budget may let go of another's (a store that a cache somewhere keeps alive)
_STORES: weakref.WeakSet[ExecutableStore] = weakref.WeakSet()


def _is_array(x: Any) -> bool:
    """Traced leaves: arrays and Python numbers (as ``jax.jit`` treats them)."""
    return isinstance(x, (jax.Array, np.ndarray, np.generic, int, float, complex))


def _aval(x: Any) -> tuple:
    """Shape, dtype and weak type of a traced leaf (what the compiled code depends on)."""
    if isinstance(x, (int, float, complex)):
        return ((), type(x).__name__, True)
    return (tuple(np.shape(x)), np.dtype(x.dtype).str, bool(getattr(x, "weak_type", False)))


def source_fingerprint(*folders: str | Path, extra: tuple[str, ...] = ()) -> str:
    """sha256 of every ``*.py`` file under ``folders`` (path and content) and ``extra``:
    what a caller passes as the store's ``fingerprint`` for code it owns."""
    h = hashlib.sha256()
    for folder in folders:
        root = Path(folder)
        for path in sorted(root.rglob("*.py")):
            h.update(str(path.relative_to(root.parent)).encode())
            h.update(path.read_bytes())
    for item in extra:
        h.update(item.encode())
    return h.hexdigest()


def _keep_newest(folder: Path, pattern: str, n: int) -> int:
    """Delete all but the ``n`` most recently modified files of ``folder`` matching
    ``pattern`` (one another process deletes first is skipped); the number deleted."""
    stamped = []
    for f in folder.glob(pattern):
        try:
            stamped.append((f.stat().st_mtime_ns, f))
        except OSError:
            continue
    gone = 0
    for _, f in sorted(stamped, reverse=True)[n:]:
        try:
            f.unlink()
            gone += 1
        except OSError:
            continue
    return gone


def _maps_in_use() -> int | None:
    """The memory maps of this process (lines of ``/proc/self/maps``); None where the system
    has no such file."""
    try:
        with open("/proc/self/maps", "rb") as f:
            return f.read().count(b"\n")
    except OSError:
        return None


@cached
def _default_map_budget() -> int | None:
    """``MAP_SHARE`` of the system's limit on memory maps; None where it cannot be read."""
    try:
        limit = int(Path("/proc/sys/vm/max_map_count").read_text())
    except (OSError, ValueError):
        return None
    return int(MAP_SHARE * limit) if _maps_in_use() is not None else None


@cached
def _machine() -> str:
    """What makes machine code unsafe to share: versions, backend, CPU model and flags."""
    import jaxlib

    parts = [jax.__version__, jaxlib.__version__, jax.default_backend(), platform.machine()]
    if os.environ.get("XLA_FLAGS"):  # e.g. another backend optimisation level: other code
        parts.append(os.environ["XLA_FLAGS"])
    try:
        dev = jax.devices()[0]
        parts.append(str(dev.client.platform_version))
    except Exception:  # pragma: no cover - no device to ask
        pass
    try:
        with open("/proc/cpuinfo", encoding="utf-8", errors="replace") as f:
            for line in f:
                if line.startswith(("flags", "model name", "Features")):
                    parts.append(line.strip())
                if line.strip() == "":
                    break  # the first processor is enough
    except OSError:
        parts.append(platform.processor())
    return "\n".join(parts)


@contextlib.contextmanager
def _compilation_cache_off():
    """A context without JAX's persistent compilation cache.

    An executable that ``compile()`` takes from that cache serialises incompletely: loaded
    in a new process it fails with "NOT_FOUND: Function <fusion> not found" (measured on
    jax 0.10.2, CPU). What the store keeps is therefore compiled afresh. JAX decides once
    per process whether the cache is used, so the decision is reset on entry (with the
    cache disabled) and on exit (with it as configured).
    """
    from jax._src import compilation_cache, config

    compilation_cache.reset_cache()
    try:
        with config.enable_compilation_cache(False):
            yield
    finally:
        compilation_cache.reset_cache()


@dataclass(frozen=True, eq=False)
class ExecutableStore:
    """Compiled executables by key, in ``folder`` (None: in memory only, this process).

    ``fingerprint``: the code the stored functions run (see the module docstring).
    Executables loaded or compiled in this process are kept in ``loaded`` (the store is
    the state: hold it as long as its functions are used).
    """

    folder: Path | None
    fingerprint: str
    loaded: dict[str, Any] = field(default_factory=dict, repr=False)
    events: list[tuple[str, str]] = field(default_factory=list, repr=False)
    """``(name, "loaded" | "compiled" | "discarded" | "let go" | "not stored: <why>")`` per
    executable, oldest first (an unused preload let go is named by its key)."""
    unproven: set[str] = field(default_factory=set, repr=False)
    """Keys loaded from a file that have not run yet (a failure there recompiles)."""
    pending: dict[str, Any] = field(default_factory=dict, repr=False)
    """Loads started by :meth:`prefetch` or :meth:`preload` (futures), by key."""
    used: dict[str, str] = field(default_factory=dict, repr=False)
    """Name of every executable run in this process, by key, in order of first use."""
    keys: dict[tuple, str] = field(default_factory=dict, repr=False)
    """Keys already computed, by (fingerprint, name, tree, static leaves, signature): a
    sampler calls the same executable a thousand times, and hashing the key each time
    cost ≈ 0.3 ms a call."""
    max_bytes: int = MAX_STORE_BYTES
    """Size cap of the folder's executables (see the module docstring)."""
    map_budget: int | None = field(default_factory=_default_map_budget)
    """Memory maps this process may hold before the least recently used executables are
    let go (None: never). Each executable maps its kernels separately (≈ 1 600 regions for
    one of the joint model's); past the system's limit (``vm.max_map_count``, 65 530 by
    default) the next load or compile dies inside XLA with a segfault or an abort, which a
    test worker holding every structure's executables reached (56 000 seen). A let-go
    executable is loaded again from its file (or compiled again, in memory only) when called.
    """
    locks: KeyLocks = field(default_factory=KeyLocks, repr=False)
    """One lock per key (shared with its scoped stores): no executable compiles twice."""
    label: str = ""
    """What this store is scoped by (:meth:`scoped`; empty: not scoped)."""
    compiles: list[tuple[str, str]] = field(default_factory=list, repr=False)
    """``(label, name)`` of every executable compiled in this process, oldest first, shared
    with its scoped stores: which structures a run compiled (the test profile counts them)."""

    def __post_init__(self) -> None:
        object.__setattr__(self, "_machine", _machine())
        _STORES.add(self)

    def scoped(self, label: str) -> ExecutableStore:
        """The same store for code that also depends on ``label`` (a model structure, say,
        that changes what a closure computes without changing argument shapes)."""
        fp = hashlib.sha256(f"{self.fingerprint}\0{label}".encode()).hexdigest()
        return ExecutableStore(
            self.folder,
            fp,
            self.loaded,
            self.events,
            self.unproven,
            self.pending,
            self.used,
            self.keys,
            self.max_bytes,
            self.map_budget,
            self.locks,
            label,
            self.compiles,
        )

    def jit(self, name: str, fn: Callable) -> Callable:
        """``fn`` compiled per argument signature, ahead of time and kept in the store.

        Array and number leaves of the arguments are traced (as ``jax.jit`` does); any other
        leaf is static (part of the key and closed over, as ``equinox.filter_jit`` does).
        Returns a function of the same arguments.
        """

        def call(*args):
            key, leaves, treedef, dyn = self._signature(name, args)
            with self.locks(key):  # one thread loads or compiles it, the others wait
                if key in self.pending:  # a load started by prefetch: wait for it
                    loaded = self.pending.pop(key).result()
                    if loaded is not None:
                        self.loaded[key] = loaded
                exe = self.loaded.pop(key, None)
                fresh = exe is None or key in self.unproven  # new in this process's memory
                if exe is None:
                    exe = self._load_or_compile(key, name, fn, leaves, treedef, dyn)
                self.loaded[key] = exe  # last: the dict's order is the order of last use
            compiled, out_tree = exe
            try:
                outs = compiled(*[leaves[i] for i in dyn])
                if key in self.unproven:  # its first run: let a failure surface here
                    jax.block_until_ready(outs)
            except (jax.errors.JaxRuntimeError, TypeError):
                if key not in self.unproven:  # not a freshly loaded file: a real error
                    raise
                # a stored executable that loads but cannot run: compile afresh (and
                # overwrite it, under its key and under its module)
                self.events.append((name, "discarded"))
                with self.locks(key):
                    exe = self._load_or_compile(key, name, fn, leaves, treedef, dyn, reuse=False)
                    self.loaded[key] = exe
                compiled, out_tree = exe
                outs = compiled(*[leaves[i] for i in dyn])
            self.unproven.discard(key)
            self.used.setdefault(key, name)
            if fresh:  # its maps are made: let go of others past the budget
                self._within_map_budget(key)
            return jax.tree_util.tree_unflatten(out_tree, outs)

        call.__name__ = f"aot_{name}"
        call.__doc__ = fn.__doc__
        return call

    def prefetch(self, name: str, *args) -> None:
        """Start loading the stored executable of ``name`` for ``args`` in a background
        thread (loading releases the GIL: a new process overlaps it with other work); the
        first call with the same signature waits for it. Nothing happens if it is already
        loaded, not stored, or the store is in memory only."""
        key, *_ = self._signature(name, args)
        path = self._path(key)
        if key in self.loaded or key in self.pending or path is None or not path.is_file():
            return
        (self.pending[key],) = loads_in_background([(self._load, (path, name, key))], 1, name)

    def stored(self, name: str, *args) -> bool:
        """Whether a call of ``name`` with ``args`` would find its executable (loaded in this
        process, loading, or in the folder) rather than compile it."""
        key, *_ = self._signature(name, args)
        path = self._path(key)
        return key in self.loaded or key in self.pending or (path is not None and path.is_file())

    def remember(self, label: str) -> Path | None:
        """Write the executables this process has run, in order of first use, as the
        manifest ``recent/<label>.json`` (what :meth:`preload` starts loading in the next
        process with the same label). Returns its path (None: in memory only)."""
        if self.folder is None or not self.used:
            return None
        import json

        entry = {
            "format": _FORMAT,
            "fingerprint": self.fingerprint,
            "executables": [{"key": k, "name": n} for k, n in self.used.items()],
        }
        path = self.folder / "recent" / f"{label}.json"
        try:
            _write_atomic(path, json.dumps(entry, indent=1).encode())
        except OSError:
            return None  # a read-only cache: the next process just does not preload
        _keep_newest(path.parent, "*.json", MAX_MANIFESTS)
        return path

    def preload(self, label: str) -> int:
        """Start loading, in ``PRELOAD_THREADS`` background threads and in their order of
        first use, the executables the last process with ``label`` ran (:meth:`remember`),
        before this process knows which it needs: a CLI overlaps the loads with its heavy
        imports and its set-up (``chekan.pipeline.calibrate_file`` starts them once the input
        has been read). A call whose key was preloaded waits for that load; one that
        is not wastes only background time. Only a manifest of this store's fingerprint
        (this code) is used, and only in a process that has not run or started loading an
        executable yet (a batch of records of other shapes guesses once, not per record).
        Returns the number of loads started."""
        if self.folder is None or self.used or self.pending or self.loaded:
            return 0
        import json

        try:
            entry = json.loads((self.folder / "recent" / f"{label}.json").read_text())
            if entry.get("format") != _FORMAT or entry.get("fingerprint") != self.fingerprint:
                return 0
            todo = [(str(e["key"]), str(e["name"])) for e in entry["executables"]]
        except (OSError, ValueError, KeyError, TypeError, AttributeError):
            return 0  # no manifest, or not one of ours: nothing to guess from
        jobs = []
        for key, name in todo:
            path = self._path(key)
            if key not in self.pending and path is not None and path.is_file():
                jobs.append((key, (self._load, (path, name, key))))
        futures = loads_in_background([job for _, job in jobs], PRELOAD_THREADS, label)
        for (key, _), fut in zip(jobs, futures, strict=True):
            self.pending[key] = fut
        return len(jobs)

    # ----------------------------------------------------------------- internals
    def _within_map_budget(self, keep: str) -> None:
        """While this process holds more memory maps than ``map_budget`` (see that field),
        let go of executables, all but ``keep``: first the preloads not yet asked for (a
        guess from the last process's list, which may name other structures'), then those of
        other stores (their order of use is their own), then this store's, least recently
        used first."""
        if self.map_budget is None:
            return
        in_use = _maps_in_use()
        if in_use is None or in_use <= self.map_budget:
            return
        stores = list(_STORES)
        for store in stores:
            for key in [k for k in store.pending if k != keep]:
                store.pending.pop(key, None)  # a load still running is freed when it ends
                store.events.append((key, "let go"))
        others = {id(s.loaded): s for s in stores if s.loaded is not self.loaded}
        for store in [*others.values(), self]:
            for oldest in [k for k in list(store.loaded) if k != keep]:  # a copy: threads
                in_use = _maps_in_use()
                if in_use is None or in_use <= self.map_budget:
                    return
                if store.loaded.pop(oldest, None) is None:  # freed here, if still there
                    continue
                store.unproven.discard(oldest)
                store.events.append((store.used.get(oldest, oldest), "let go"))

    def _signature(self, name: str, args: tuple):
        leaves, treedef = jax.tree_util.tree_flatten(args)
        dyn = [i for i, x in enumerate(leaves) if _is_array(x)]
        traced = set(dyn)
        static = tuple((i, leaves[i]) for i in range(len(leaves)) if i not in traced)
        sig = [_aval(leaves[i]) for i in dyn]
        try:
            memo = (self.fingerprint, name, treedef, static, tuple(sig))
            key = self.keys.get(memo)
        except TypeError:  # a static leaf that cannot be hashed: compute the key each time
            return self._key(name, treedef, static, sig), leaves, treedef, dyn
        if key is None:
            key = self.keys[memo] = self._key(name, treedef, static, sig)
        return key, leaves, treedef, dyn

    def _key(self, name, treedef, static, sig) -> str:
        h = hashlib.sha256()
        for part in (_FORMAT, name, self.fingerprint, str(treedef), repr(static), repr(sig)):
            h.update(part.encode())
            h.update(b"\0")
        h.update(self._machine.encode())  # type: ignore[attr-defined]
        return h.hexdigest()[:40]

    def _path(self, key: str) -> Path | None:
        return None if self.folder is None else self.folder / f"{key}{_SUFFIX}"

    def _load_or_compile(self, key, name, fn, leaves, treedef, dyn, reuse: bool = True):
        """The executable from its file (``reuse``), else compiled and saved."""
        path = self._path(key)
        if reuse and path is not None and path.is_file():
            loaded = self._load(path, name, key)
            if loaded is not None:
                return loaded

        out_box: list[Any] = []

        def flat_fn(*dyn_leaves):
            full = list(leaves)
            for i, x in zip(dyn, dyn_leaves, strict=True):
                full[i] = x
            out = fn(*jax.tree_util.tree_unflatten(treedef, full))
            flat, tree = jax.tree_util.tree_flatten(out)
            out_box.append(tree)
            return tuple(flat)

        lowered = jax.jit(flat_fn).lower(*[leaves[i] for i in dyn])
        out_tree = out_box[-1]
        # the same module under another fingerprint (code edited elsewhere): reuse it
        # the argument tree is part of it: jit prunes unused (e.g. zero-size) arguments, so two
        # trees can lower to one text, and an executable keeps the tree it was compiled for
        module = hashlib.sha256(
            lowered.as_text().encode() + str(treedef).encode() + self._machine.encode()  # type: ignore[attr-defined]
        )
        by_module = self._path(f"module/{_FORMAT.replace('/', '-')}-{module.hexdigest()[:40]}")
        if reuse and by_module is not None and by_module.is_file():
            loaded = self._load(by_module, name, key)
            if loaded is not None:
                if path is not None:
                    _link_or_copy(by_module, path)
                    self.prune()
                return loaded
        with XLA.alone(), _compilation_cache_off():
            compiled = lowered.compile()
        self.events.append((name, "compiled"))
        self.compiles.append((self.label, name))
        if path is not None and by_module is not None:
            self._save(by_module, name, compiled, out_tree)
            if by_module.is_file():
                _link_or_copy(by_module, path)
            self.prune()
        return compiled, out_tree

    def prune(self) -> int:
        """Delete the least recently used executables while the folder holds more than
        ``max_bytes`` of them, down to ``PRUNE_TO`` of it; those this process has loaded
        or compiled stay. A file with two names (keyed and filed by module: hard links)
        counts once and goes with both. Returns the number of files deleted."""
        if self.folder is None:
            return 0
        groups: dict[tuple[int, int], list] = {}  # inode → [mtime, size, names]
        for f in self.folder.rglob(f"*{_SUFFIX}"):
            try:
                st = f.stat()
            except OSError:  # deleted meanwhile by another process
                continue
            groups.setdefault((st.st_dev, st.st_ino), [st.st_mtime, st.st_size, []])[2].append(f)
        total = sum(size for _, size, _ in groups.values())
        if total <= self.max_bytes:
            return 0
        keep = {self._path(k) for k in self.loaded}
        deleted = 0
        for _, size, names in sorted(groups.values(), key=lambda g: g[0]):
            if total <= PRUNE_TO * self.max_bytes:
                break
            if keep.intersection(names):
                continue
            for f in names:
                with contextlib.suppress(OSError):
                    f.unlink()
                    deleted += 1
            total -= size
        return deleted

    def _load(self, path: Path, name: str, key: str):
        from jax.experimental import serialize_executable as se

        initialise_lapack()
        try:
            payload, in_tree, out_tree = pickle.loads(path.read_bytes())
            with XLA.load():
                compiled = se.deserialize_and_load(payload, in_tree, out_tree[0])
        except Exception:  # unreadable or from another build: recompile, never guess
            path.unlink(missing_ok=True)
            self.events.append((name, "discarded"))
            return None
        self.events.append((name, "loaded"))
        self.unproven.add(key)
        with contextlib.suppress(OSError):  # recently used: the last a prune deletes
            os.utime(path)
        return compiled, out_tree[1]

    def _save(self, path: Path, name: str, compiled, out_tree) -> None:
        """Write the executable to ``path``; where it cannot be (a read-only cache, or an
        executable that XLA cannot serialise, e.g. one with constant arguments: jax 0.10
        raises ``NotImplementedError``) it stays in memory only, and the event
        ``(name, "not stored: <why>")`` says so: the next process compiles it again."""
        from jax.experimental import serialize_executable as se

        try:
            with XLA.alone():
                payload, in_tree, flat_out_tree = se.serialize(compiled)
            _write_atomic(path, pickle.dumps((payload, in_tree, (flat_out_tree, out_tree))))
        except Exception as e:
            self.events.append((name, f"not stored: {type(e).__name__}: {e}"[:200]))


def _link_or_copy(src: Path, dst: Path) -> None:
    """``dst`` as a second name of ``src``: a hard link (one file on disk, one last-use
    time for the prune), else an atomic copy."""
    tmp = dst.with_name(f".tmp-{os.getpid()}-{dst.name}")
    try:
        os.link(src, tmp)
        os.replace(tmp, dst)
    except OSError:
        tmp.unlink(missing_ok=True)
        _write_atomic(dst, src.read_bytes())


def _write_atomic(path: Path, blob: bytes) -> None:
    """``blob`` at ``path`` whole or not at all (no temporary file left behind)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=".tmp-", suffix=_SUFFIX)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(blob)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
