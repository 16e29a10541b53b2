"""Shape buckets (issue 55): every record is padded to its bucket, exactly, so that the
programs of one bucket share one compiled engine for map and bayes; ``chekan warmup``
stores the default buckets' executables; ``reanalyze`` says first when it will compile."""

from __future__ import annotations

import importlib
import itertools
import math
import warnings

import numpy as np
import pytest

from chekan.joint.layout import beta_noise_order, draw_order, padded_beta_index
from chekan.runtime.padding import LADDER, bucket_of, padded_for, rung
from chekan.warmup import padded_model

# the module (chekan.joint re-exports its function of the same name)
joint_estimate = importlib.import_module("chekan.fit.record")


def test_the_ladder_overshoots_by_at_most_a_fifth_above_32():
    assert LADDER[:9] == (8, 16, 24, 32, 36, 40, 48, 56, 64)
    assert list(LADDER) == sorted(set(LADDER))
    assert all(b / a <= 1.2 for a, b in itertools.pairwise(LADDER[3:]))
    assert [rung(n) for n in (0, 1, 8, 9, 35, 36, 37, 216, 800)] == [
        0,
        8,
        8,
        16,
        36,
        36,
        40,
        224,
        896,
    ]


def test_the_paper_program_and_its_quick_version_share_one_engine(short_session):
    from chekan.demo import demo_program
    from chekan.records.simulate import Truth, simulate_session
    from chekan.runtime.engine import engine_for

    _, short, _ = short_session
    long, _ = simulate_session(demo_program(False), Truth(serial="T-1"), seed=7)
    a, b = padded_model(short), padded_model(long)
    assert a.duration_h < b.duration_h / 2  # two programs: 3 h and 9 h
    assert a.structure == b.structure  # one bucket
    assert engine_for(a.structure) is engine_for(b.structure)  # one engine, built once


def test_two_short_programs_share_one_bucket():
    from chekan.physics.program import build_program
    from chekan.records.simulate import Truth, simulate_session

    def model(angles, dwell_s):
        prog = build_program(angles, dwell_s=dwell_s, settle_s=20, rounds=1, name="short")
        return padded_model(simulate_session(prog, Truth(serial="T-1"), seed=7)[0])

    a, b = model([1.0, 2.0], 60), model([1.0, 2.0, 3.0], 60)
    assert (a.n_real_holds, a.n_real_bins) == (6, 18) and (b.n_real_holds, b.n_real_bins) == (8, 24)
    assert a.structure == b.structure


def test_a_three_angle_program_runs_in_the_papers_warmed_bucket():
    """A program whose own bucket lies within reach of a default one takes the default:
    three angles in four rounds (32 holds, 160 bins) share the paper's executables, which
    ``chekan warmup`` stored; so does a short program, whose own bucket is the smallest
    (as the live page's fit of the xy program's first round), and a short xy program takes the
    2.6 h xy program's."""
    from chekan.physics.program import build_program
    from chekan.records.simulate import Truth, simulate_session
    from chekan.runtime.padding import DEFAULT_BUCKETS, SMALLEST

    prog = build_program([2.0, 3.5, 5.0], axis="y", rounds=4, dwell_s=240, settle_s=120)
    m = padded_model(simulate_session(prog, Truth(serial="T-1"), seed=7)[0])
    assert (m.n_real_holds, m.n_real_bins) == (32, 160)
    assert tuple(bucket_of(m.structure)) == DEFAULT_BUCKETS[0] == (36, 224, 24, 36, 0)
    short = build_program([1.0, 2.0], dwell_s=60, settle_s=20, rounds=1, name="short")
    short_xy = build_program([2.0, 3.5, 5.0], dwell_s=300, settle_s=120, round_axes=["y", "x"])
    for program, bucket in ((short, DEFAULT_BUCKETS[0]), (short_xy, DEFAULT_BUCKETS[1])):
        s = padded_model(simulate_session(program, Truth(serial="T-1"), seed=7)[0])
        own = (s.n_real_holds, s.n_real_bins)
        assert own[0] <= SMALLEST.n_holds and own[1] <= SMALLEST.n_bins, own
        assert tuple(bucket_of(s.structure)) == bucket, own
    assert DEFAULT_BUCKETS[1] == (48, 256, 24, 32, 24)


def test_the_live_pages_early_rounds_run_in_a_default_bucket():
    """The live page fits the completed rounds in a worker while the acquisition runs
    (:func:`chekan.live.calib.partial_record`): after the first round of the paper's program
    (19 holds) and of the designer's 9 h xy program (9 holds, about Y only) that record is
    in a default bucket, so its first MAP loads what ``chekan warmup`` stored."""
    from chekan.demo import demo_program, dual_axis_program
    from chekan.live.calib import partial_record
    from chekan.records import DEFAULT_COLUMNS
    from chekan.records.simulate import Truth, simulate_session
    from chekan.runtime.padding import DEFAULT_BUCKETS

    for program, holds in ((demo_program(False), 19), (dual_axis_program(False), 9)):
        rec, _ = simulate_session(program, Truth(serial="L-1"), seed=2)
        first = set(range(program.n_steps // program.rounds + 1))  # with the next level
        part = partial_record(dict(rec.meta), {c: getattr(rec, c) for c in DEFAULT_COLUMNS}, first)
        m = padded_model(part)
        assert m.n_real_holds == holds
        assert tuple(bucket_of(m.structure)) == DEFAULT_BUCKETS[0]


@pytest.mark.parametrize(
    "angles,axis,rounds,own,default",
    [
        ([2.5, 25 / 6, 31 / 6], "y", 3, (24, 120), 0),  # own bucket (24, 128): ½ and 4/7
        ([4.5, 4 + 51 / 60, 31 / 6], "xy", 4, (32, 160), 1),  # (32, 160): ⅔ and 5/8
        ([2.5, 25 / 6, 31 / 6], "x", 3, (24, 120), 1),  # about X alone: the xy bucket
    ],
)
def test_a_record_takes_a_default_bucket_up_to_twice_its_own(angles, axis, rounds, own, default):
    """``DEFAULT_REACH`` = 2: a default bucket with at most twice the holds and bins of a
    record's own bucket, and its kinds of terms, takes the record (its warm run costs at most
    about twice its own, a first run's compile a minute or more)."""
    from chekan.physics.program import build_program
    from chekan.records.simulate import Truth, simulate_session
    from chekan.runtime.padding import DEFAULT_BUCKETS, DEFAULT_REACH

    prog = build_program(angles, axis=axis, rounds=rounds, dwell_s=300, settle_s=120)
    m = padded_model(simulate_session(prog, Truth(serial="T-1"), seed=7)[0])
    assert (m.n_real_holds, m.n_real_bins) == own
    assert DEFAULT_REACH == 2.0
    assert tuple(bucket_of(m.structure)) == DEFAULT_BUCKETS[default]


def test_the_warmup_stores_the_em_newton_step(short_session):
    """``store_em_newton`` runs the EM's Newton step on a model's bucket, so that the store
    holds it (the calibration runs it only where plain EM updates have not converged)."""
    from chekan.joint.problem import default_hyper
    from chekan.runtime.engine import EM_NEWTON, engine_for
    from chekan.warmup import em_newton_args, store_em_newton

    model = padded_model(short_session[1])
    store_em_newton(model)
    h, n, change = em_newton_args(model)[1:4]
    assert int(n) > 0 and float(change) >= 0 and set(h) == set(default_hyper())
    assert engine_for(model.structure).store.stored(EM_NEWTON, *em_newton_args(model))


@pytest.mark.parametrize("n", [1, 13, 2048, 3360, 8192, 8193])
def test_keys_split_at_a_bucketed_count_are_the_keys_of_their_own_count(n):
    """The posterior's β keys: one compiled split for every number of draws, the same keys."""
    import jax

    from chekan.runtime.padding import split_keys

    key = jax.random.fold_in(jax.random.PRNGKey(7), 3)
    got = np.asarray(split_keys(key, n))
    assert got.shape == (n, 2)
    np.testing.assert_array_equal(got, np.asarray(jax.random.split(key, n)))


def test_x_response_padding_keeps_the_level_angle_last():
    """Padded X-response columns are zero, unit prior variance, before the last column
    (the level angle Δm₀ⱼ that the derived quantities read)."""
    from chekan.physics.program import build_program
    from chekan.records.simulate import Truth, simulate_session

    prog = build_program([1.0, 2.0], axis="xy", dwell_s=60, settle_s=10, rounds=2, name="xy")
    rec, _ = simulate_session(prog, Truth(serial="T-1"), seed=7)
    from chekan.joint.binning import prepare

    _, raw = prepare(rec, 10)
    X0 = raw.structure.n_x_response
    assert X0 > 1
    padded = raw.pad(*bucket_of(raw.structure)[:4], X0 + 3)
    xb0, xb1 = np.asarray(raw.data.x_basis), np.asarray(padded.data.x_basis)
    np.testing.assert_array_equal(xb1[: raw.n_holds, : X0 - 1], xb0[:, :-1])
    np.testing.assert_array_equal(xb1[: raw.n_holds, -1], xb0[:, -1])
    assert not xb1[:, X0 - 1 : -1].any()
    v1 = np.asarray(padded.data.x_prior_var)
    assert list(v1[X0 - 1 : -1]) == [1.0] * 3 and v1[-1] == np.asarray(raw.data.x_prior_var)[-1]
    mv0, mv1 = np.asarray(raw.data.mv_x_basis), np.asarray(padded.data.mv_x_basis)
    np.testing.assert_array_equal(mv1[: raw.n_holds, : mv0.shape[1], -1], mv0[..., -1])
    # β's map: the level angle goes to the padded block's last column of each system
    ix = padded_beta_index(raw.structure, padded.structure)
    xr0, xr1 = raw.structure.beta_blocks["x_response"], padded.structure.beta_blocks["x_response"]
    X1 = padded.structure.n_x_response
    assert ix[xr0[X0 - 1]] == xr1[X1 - 1] and ix[xr0[-1]] == xr1[-1]


def test_a_padded_draw_of_beta_takes_the_same_normals(short_session):
    """``jax.random.normal`` is prefix-stable (partitionable threefry): a padded record's
    real β entries take, through ``noise_order``, the normals they take unpadded."""
    import jax

    from chekan.joint.binning import prepare

    _, rec, _ = short_session
    _, raw = prepare(rec, 200)
    s0 = raw.structure
    once = raw.pad(s0.n_holds + 3, s0.n_bins + 5, s0.n_moves + 1, s0.n_systematic + 2)
    twice = once.pad(*bucket_of(once.structure)[:4], None)
    key = jax.random.PRNGKey(5)
    xi0 = np.asarray(jax.random.normal(key, (s0.n_beta,)))
    u0 = np.argsort(draw_order(s0))  # each β's position in its draw
    for model in (once, twice):
        s = model.structure
        order = np.asarray(model.data.noise_order)
        assert sorted(order) == list(range(s.n_beta))
        xi = np.asarray(jax.random.normal(key, (s.n_beta,)))[order]
        u = np.argsort(draw_order(s))
        real = padded_beta_index(s0, s) if model is once else None
        if real is None:
            real = padded_beta_index(once.structure, s)[padded_beta_index(s0, once.structure)]
        np.testing.assert_array_equal(xi[u[real]], xi0[u0])
    assert beta_noise_order(s0, s0).tolist() == list(range(s0.n_beta))
    # a record that fills its bucket carries the order too: one argument tree per bucket
    same = raw.pad(s0.n_holds, s0.n_bins, s0.n_moves)
    assert np.asarray(same.data.noise_order).tolist() == list(range(s0.n_beta))


def _floats(a, b, path=""):
    """(difference relative to 1e-6 of the value + 1e-9, path) of every float of two result
    dicts, timings aside: below 1 where they agree to round-off (a figure near zero, such
    as the bound of a drift slope's interval, by 1e-9 absolute)."""
    if isinstance(a, dict):
        for k in a:
            if k not in ("seconds", "posterior_netcdf", "created"):
                yield from _floats(a[k], b[k], f"{path}/{k}")
    elif isinstance(a, list | tuple):
        assert len(a) == len(b), path
        for i, (x, y) in enumerate(zip(a, b, strict=True)):
            yield from _floats(x, y, f"{path}[{i}]")
    elif isinstance(a, float):
        d = 0.0 if a == b or (math.isnan(a) and math.isnan(b)) else abs(a - b)
        # R̂ and ESS are rank-normalised: where round-off reorders two draws their rank moves
        # by one, a step of ~1e-5 relative for a few hundred draws; they are held to 1e-4
        rel = 1e-4 if path.rsplit("/", 1)[-1].startswith(("r_hat", "ess")) else 1e-6
        yield d / (rel * max(abs(a), abs(b)) + 1e-9), path
    else:
        assert a == b, path


@pytest.mark.slow
@pytest.mark.parametrize("method", ["map", "bayes"])
def test_a_record_gives_the_same_result_on_its_own_shape_and_on_its_bucket(
    short_session, method, monkeypatch
):
    """Padding is exact: the same record, unpadded and padded to its bucket, gives the same
    result to round-off (bayes: a short sampler, the same seed; its draws match draw by
    draw: measured, every figure within 1.8e-8 of its sd, relative 5e-7 at most, an
    interval's bound of a drift slope near zero)."""
    from chekan.fit import sampling
    from chekan.pipeline import CalibrationOptions, calibrate

    _, rec, _ = short_session
    config = sampling.sampler_config
    monkeypatch.setattr(
        sampling, "sampler_config", lambda o, **kw: config(o, **{"max_steps": 30, **kw})
    )
    opts = CalibrationOptions(method=method, progress=False, seed=3)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # a short sampler: not converged
        padded = calibrate(rec, opts)
        monkeypatch.setattr(joint_estimate, "padded_for", lambda model: model)
        own = calibrate(rec, opts)
    worst = max(_floats(own, padded))
    assert worst[0] < 1.0, worst
    if method == "bayes":
        H = padded_model(rec).n_real_holds
        assert len(padded["angle_error_arcsec"]["mean"]) == H


def test_padding_a_model_keeps_its_real_holds_first(short_session):
    _, rec, _ = short_session
    model = padded_model(rec)
    H = model.n_real_holds
    mask = np.asarray(model.data.hold_mask)
    assert mask[:H].all() and not mask[H:].any()
    assert model.n_real_bins == len(model.bin_t_s) < model.structure.n_bins
    assert padded_for(model) is model  # a bucket's shape is its own bucket


def test_the_default_targets_are_the_buckets_the_padding_names():
    """The docstring of :mod:`chekan.runtime.padding` names these buckets."""
    from chekan.records.simulate import Truth, simulate_session
    from chekan.warmup import default_targets

    buckets = []
    for t in default_targets():
        rec, _ = simulate_session(t.program(), Truth(serial="T-1"), seed=1)
        buckets.append(tuple(bucket_of(padded_model(rec).structure)))
    assert buckets == [(36, 224, 24, 36, 0), (160, 896, 24, 32, 24), (48, 256, 24, 32, 24)]


def test_warmup_keeps_what_each_method_compiled(monkeypatch):
    """``warm`` calibrates a session of each target with each method, runs the EM's Newton
    step after ``map`` (a calibration whose EM converges never runs it) and counts what the
    store compiled or loaded (stand-ins: a tiny executable per method and one for Newton)."""
    from chekan.physics.program import build_program
    from chekan.runtime.process import executable_store
    from chekan.warmup import WarmTarget, warm

    store = executable_store().scoped("test_buckets warmup")
    arg = np.arange(3.0)

    def calibrate(record, opts):
        assert opts.method in ("map", "bayes") and not opts.progress
        store.jit(f"tiny_{opts.method}", lambda x: 2.0 * x)(arg)
        return {}

    prog = build_program([1.0, 2.0], dwell_s=60, settle_s=20, rounds=1, name="short")
    said: list[str] = []
    target = WarmTarget("short", lambda: prog)
    newton = []

    def store_newton(model):
        newton.append(model.structure)
        store.jit("tiny_newton", lambda x: 3.0 * x)(arg)

    steps = warm([target], say=said.append, calibrate=calibrate, newton=store_newton, force=True)
    assert [s.method for s in steps] == ["map", "bayes"]
    assert [s.compiled + s.loaded for s in steps] == [2, 1]  # map and Newton; bayes
    assert [tuple(bucket_of(s)) for s in newton] == [steps[0].bucket]  # once, on the bucket
    assert steps[0].bucket == (36, 224, 24, 36, 0)  # a short program: the paper's bucket
    assert said[0].startswith("[1/1] short") and "compiled" in said[-1]
    if store.folder is not None:  # kept for the next process
        assert all(store.stored(f"tiny_{n}", arg) for n in ("map", "newton", "bayes"))


def test_the_warmup_command_says_where_it_stored(monkeypatch, capsys):
    from chekan import warmup
    from chekan.cli import commands as cli

    ran = []
    monkeypatch.setattr(warmup, "warm", lambda targets, methods, **kw: ran.append(methods))
    assert cli.main(["warmup", "--method", "map", "-q"]) == 0
    assert ran == [["map"]]
    out = capsys.readouterr().out
    assert "executable store" in out


def test_reanalyze_says_first_that_it_compiles(short_session, paper_protocol, monkeypatch, capsys):
    from chekan.archive import reanalyze
    from chekan.options import CalibrationOptions
    from chekan.runtime import engine
    from chekan.warmup import first_compile

    path = str(short_session[0])
    opts = CalibrationOptions(method="map", progress=False)
    monkeypatch.setattr(engine, "compiled_before", lambda model: False)
    assert first_compile([path], opts)
    assert not first_compile([str(paper_protocol)], opts)  # a protocol: no joint model
    reanalyze._notice_first_compile([path], "map", {})
    assert engine.FIRST_RUN_NOTICE in capsys.readouterr().out
    monkeypatch.setattr(engine, "compiled_before", lambda model: True)
    assert not first_compile([path], opts)
    reanalyze._notice_first_compile([path], "map", {})
    assert capsys.readouterr().out == ""
