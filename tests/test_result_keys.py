"""No key of a ``chekan-result/1`` dict is private: nothing in a result (at any depth) starts
with ``_`` (the estimators hand typed fits to one writer, :mod:`chekan.results.joint`), and
the writer does not change the classical result it starts from (issue 55)."""

from __future__ import annotations

import copy
from collections.abc import Iterator
from typing import Any

import pytest

from chekan.options import CalibrationOptions
from chekan.pipeline import calibrate_file, classical_stage, joint_stage


def private_keys(obj: Any, path: str = "") -> Iterator[str]:
    """The paths of every key in ``obj`` (nested dicts and lists) that starts with ``_``."""
    if isinstance(obj, dict):
        for k, v in obj.items():
            if str(k).startswith("_"):
                yield f"{path}.{k}"
            yield from private_keys(v, f"{path}.{k}")
    elif isinstance(obj, list | tuple):
        for i, v in enumerate(obj):
            yield from private_keys(v, f"{path}[{i}]")


def test_the_finder_finds_a_private_key():
    assert list(private_keys({"a": [{"b": 1, "_c": {"_d": 2}}]})) == [".a[0]._c", ".a[0]._c._d"]


@pytest.mark.parametrize("method", ["classical", "map"])
def test_a_record_result_has_no_private_key(short_session, method):
    res = calibrate_file(short_session[0], CalibrationOptions(method=method, progress=False))
    assert res["method"] == method
    assert list(private_keys(res)) == []


@pytest.mark.parametrize("method", ["classical", "map", "bayes"])
def test_a_protocol_result_has_no_private_key(paper_protocol, method):
    res = calibrate_file(paper_protocol, CalibrationOptions(method=method, progress=False))
    assert res["method"] == method
    assert list(private_keys(res)) == []


@pytest.mark.parametrize("which", ["record", "protocol"])
def test_the_joint_writer_leaves_the_classical_result_as_it_was(
    short_session, paper_protocol, which
):
    path = short_session[0] if which == "record" else paper_protocol
    opts = CalibrationOptions(method="map", progress=False)
    data, kind, cres, base = classical_stage(path, opts)
    before = copy.deepcopy(base)
    out = joint_stage(data, kind, cres, base, opts)
    assert base == before
    assert out["method"] == "map" and base["method"] == "map"
    if which == "protocol":  # the model's per-round b beside the classical ones: in out only
        assert all("model_b1" in r for r in out["rounds"])
        assert not any("model_b1" in r for r in base["rounds"])
