"""The runtime room (issue 55): every cache registered with one ``clear_caches``."""

from __future__ import annotations

import ast
from pathlib import Path

import numpy as np

from chekan import runtime
from chekan.runtime.caches import registered

ROOT = Path(__file__).resolve().parents[1]


def test_clear_caches_forgets_every_cache_of_the_package():
    from chekan.archive import history
    from chekan.design import information
    from chekan.joint import engine_for
    from chekan.joint.layout import ModelStructure
    from chekan.physics import sensor as fm
    from chekan.records.simulate import Truth
    from chekan.runtime import process

    st = ModelStructure(4, 12, 5)
    engine, store, kernels = engine_for(st), process.executable_store(), history._compiled()
    sens = information.sensitivities(Truth())
    p = fm.make_params(
        g_mgal=981_000.0, K_pix_per_rad=1e5, b_mgal_per_pix=(1.0, 1.0), m_level_pix=(1e3, 1e3)
    )
    fm.scale_factor_at_centre(p)
    assert fm.scale_factor_at_centre._cache_size() == 1
    assert information.sensitivities(Truth()) is sens  # kept until cleared
    runtime.clear_caches()
    assert engine_for(st) is not engine and process.executable_store() is not store
    assert history._compiled() is not kernels
    assert information.sensitivities(Truth()) is not sens
    assert fm.scale_factor_at_centre._cache_size() == 0


def test_the_sensitivities_cache_is_bounded():
    from chekan.design import information

    info = information._sensitivities.cache_info()
    assert info.maxsize == information.MAX_SENSITIVITIES


def test_a_jit_made_inside_a_cache_leaves_the_registry_with_it():
    runtime.clear_caches()
    before = registered()
    made = runtime.cached(lambda: runtime.jit(lambda x: x + 1))
    f = made()
    assert float(f(np.float64(1.0))) == 2.0 and registered() == before + 2
    del f
    runtime.clear_caches()  # drops ``made``'s jit: only ``made`` itself stays registered
    assert registered() == before + 1


_FORBIDDEN = {
    ("jax", "jit"),
    ("eqx", "filter_jit"),
    ("equinox", "filter_jit"),
    ("functools", "cache"),
    ("functools", "lru_cache"),
}


_JITS = {("jax", "jit"), ("eqx", "filter_jit"), ("equinox", "filter_jit")}


def test_only_the_runtime_caches_or_jits():
    """No module of chekan outside chekan/runtime calls jax.jit, equinox's filter_jit or
    functools' caches (chekan/report is another engineer's room, left as it is), and none of
    inference (pure: the caller jits) jits (its fusion barrier's primitive is defined once,
    not a cache)."""
    offenders = []
    files = [*sorted((ROOT / "chekan").rglob("*.py")), *sorted((ROOT / "inference").rglob("*.py"))]
    for p in files:
        rel = p.relative_to(ROOT).parts
        if rel[:2] in (("chekan", "runtime"), ("chekan", "report")):
            continue
        forbidden = _FORBIDDEN if rel[0] == "chekan" else _JITS
        for node in ast.walk(ast.parse(p.read_text(encoding="utf-8"))):
            if (
                isinstance(node, ast.Attribute)
                and isinstance(node.value, ast.Name)
                and (node.value.id, node.attr) in forbidden
            ):
                offenders.append(f"{'/'.join(rel)}:{node.lineno}: {node.value.id}.{node.attr}")
            if isinstance(node, ast.ImportFrom) and any(
                (node.module, a.name) in forbidden for a in node.names
            ):
                offenders.append(f"{'/'.join(rel)}:{node.lineno}: from {node.module} import")
    assert offenders == []


def test_a_compiler_keeps_one_function_per_name_and_counts_its_traces():
    from chekan.runtime.compiler import Compiler

    c = Compiler()
    f = c.jit("double", lambda x: 2.0 * x)
    assert c.jit("double", lambda x: 3.0 * x) is f  # one per name: the first stays
    assert float(f(np.float64(2.0))) == 4.0 and float(f(np.float64(5.0))) == 10.0
    assert c.traces == 1
    f(np.ones(3))  # a new shape: traced again
    assert c.traces == 2
    runtime.clear_caches()
    assert float(c.jit("double", lambda x: 3.0 * x)(np.float64(2.0))) == 6.0
