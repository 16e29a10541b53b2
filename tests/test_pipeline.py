"""``chekan.pipeline.calibrate``: an in-memory record or protocol gives the numbers its file
gives (issue 28)."""

from __future__ import annotations

import pytest

from chekan.errors import ChekanError
from chekan.pipeline import IN_MEMORY, CalibrationOptions, calibrate, calibrate_file
from chekan.records.inputs import read_input


def _numbers(res: dict) -> dict:
    return {k: (v["mean"], v.get("sd")) for k, v in res["parameters"].items()}


@pytest.mark.parametrize("method", ["classical", "map"])
def test_a_record_in_memory_equals_its_file(short_session, method):
    path, rec, _ = short_session
    opts = CalibrationOptions(method=method, progress=False)
    from_file = calibrate_file(path, opts)
    in_memory = calibrate(read_input(path), opts)
    assert _numbers(in_memory) == _numbers(from_file)
    assert from_file["record"] == str(path) and len(from_file["record_sha256"]) == 64
    assert in_memory["record"] == IN_MEMORY and in_memory["record_sha256"] is None
    # the simulator's own Record (not read from a file) calibrates without a file too
    assert calibrate(rec, opts)["parameters"]["b1"]["mean"] == pytest.approx(
        from_file["parameters"]["b1"]["mean"], rel=1e-6
    )


def test_a_protocol_in_memory_equals_its_file(paper_protocol):
    opts = CalibrationOptions(method="classical", progress=False)
    data = read_input(paper_protocol)
    assert _numbers(calibrate(data, opts)) == _numbers(calibrate_file(paper_protocol, opts))
    named = calibrate(data, opts, input_path=paper_protocol)
    assert named["record"] == str(paper_protocol) and named["record_sha256"]


def test_anything_else_is_refused():
    with pytest.raises(ChekanError, match="give a Record or a Protocol"):
        calibrate({"t_s": [0.0]})


def test_the_preload_label_follows_the_program_not_the_instrument(short_session, monkeypatch):
    """A process preloads what the last calibration of the same tilt program ran: two records
    of one program share the label, another program (rounds about X too) or other model
    options do not, and the program's name does not count. calibrate() asks the store for
    that label and writes its manifest under it."""
    import copy
    import dataclasses

    from chekan.pipeline import classical_of, preload_label
    from chekan.runtime import process

    path, rec, _ = short_session
    opts = CalibrationOptions(method="map", progress=False)
    _, _, result = classical_of(read_input(path), opts)
    label = preload_label(result, opts)
    assert label.startswith("calibrate-map-")
    other = copy.deepcopy(result)
    other["serial"], other["g_local_mgal"] = "other", result["g_local_mgal"] + 3.0
    other["tilt_program"]["name"] = "renamed"
    assert preload_label(other, opts) == label  # another instrument, the same program
    xy = copy.deepcopy(result)
    xy["tilt_program"]["rounds"][-1]["axis"] = "x"
    assert preload_label(xy, opts) != label
    assert preload_label(result, dataclasses.replace(opts, encoder_error=True)) != label
    assert preload_label(result, dataclasses.replace(opts, method="bayes")) != label

    asked: list = []
    store = process.executable_store()
    monkeypatch.setattr(type(store), "preload", lambda self, lab: asked.append(("p", lab)) or 0)
    monkeypatch.setattr(type(store), "remember", lambda self, lab: asked.append(("r", lab)))
    calibrate(rec, opts)
    assert asked == [("p", label), ("r", label)]


def test_the_first_run_of_a_model_structure_says_that_it_compiles(
    short_session, capsys, monkeypatch
):
    """A program's first run compiles for a minute or two before the MAP prints anything: it
    says so first; a run whose executables are stored (or loaded) does not."""
    import importlib

    # the module (chekan.joint re-exports its function of the same name)
    joint_estimate = importlib.import_module("chekan.fit.record")

    _, rec, _ = short_session
    opts = CalibrationOptions(method="map", progress=True)
    calibrate(rec, opts)  # compiles or loads this structure's executables
    capsys.readouterr()
    calibrate(rec, opts)  # now loaded in this process
    assert joint_estimate.FIRST_RUN_NOTICE not in capsys.readouterr().out
    monkeypatch.setattr(joint_estimate, "compiled_before", lambda model: False)
    calibrate(rec, opts)
    out = capsys.readouterr().out
    assert joint_estimate.FIRST_RUN_NOTICE in out
    assert out.index(joint_estimate.FIRST_RUN_NOTICE) < out.index("MAP pass 1")
