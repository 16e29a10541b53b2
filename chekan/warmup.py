"""``chekan warmup``: compile the joint model for the default programs' shape buckets and
keep it in the executable store, so that a first calibration after set-up loads instead of
compiling (a minute or two per bucket on 2 cores).

Every record is padded to its bucket (:mod:`chekan.runtime.padding`), and ``map`` and
``bayes`` share the bucket's engine (:mod:`chekan.runtime.engine`), so one simulated
session per bucket, calibrated with ``map`` and then ``bayes`` the way a user's record is
(:func:`chekan.pipeline.calibrate`), stores every executable that any record of the same
bucket and options needs: the paper's 9 h program (and its 3 h version: the same bucket)
and the designer's xy programs (9 h and 2.6 h). A lab's own programs: ``chekan warmup
PROGRAM.toml …``.
"""

from __future__ import annotations

import functools
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

METHODS = ("map", "bayes")


class WarmTarget(NamedTuple):
    """A program whose bucket warmup compiles: its name and a function giving it."""

    name: str
    program: Callable[[], Any]  # → chekan.physics.program.TiltProgram


def default_targets() -> tuple[WarmTarget, ...]:
    """The programs of the default buckets: the paper's 9 h program (its 3 h version has
    the same bucket) and the designer's xy programs."""
    from chekan.demo import demo_program, dual_axis_program

    return (
        WarmTarget("paper 9 h program", lambda: demo_program(False)),
        WarmTarget("designer's xy program, 9 h", lambda: dual_axis_program(False)),
        WarmTarget("designer's xy program, 2.6 h", lambda: dual_axis_program(True)),
    )


def program_targets(paths: Sequence[str | Path]) -> tuple[WarmTarget, ...]:
    """Targets for tilt-program files (TOML, :func:`chekan.physics.program.load_program`)."""
    from chekan.physics.program import load_program

    return tuple(WarmTarget(str(p), functools.partial(load_program, p)) for p in paths)


class WarmStep(NamedTuple):
    """What one method's calibration of one target did in the store."""

    target: str
    method: str
    bucket: tuple[int, ...]  # (holds, bins, slew samples, systematic, X-response terms)
    compiled: int
    loaded: int
    seconds: float


def padded_model(record, options=None, name: str = "record"):
    """The model of ``record`` as ``map`` and ``bayes`` fit it
    (:func:`chekan.fit.record.estimate`: binned with the options' settings, padded to
    its bucket)."""
    from chekan.joint.binning import prepare
    from chekan.joint.xresponse import horizontal_prior
    from chekan.options import CalibrationOptions
    from chekan.runtime.padding import padded_for

    o = options or CalibrationOptions()
    spec = o.angle_spec(record.meta, name, record.angle_calibration)
    spec_x = o.angle_spec(record.meta, name, record.angle_calibration, axis="x")
    u = horizontal_prior(o.horizontal_u_pix)[0]
    _, model = prepare(
        record, o.settle_s, encoder=o.encoder_error, angle_spec=spec, angle_spec_x=spec_x,
        horizontal_u_pix=u,
    )  # fmt: skip
    return padded_for(model)


def first_compile(paths: Sequence[str | Path], options, limit: int = 8) -> bool:
    """Whether calibrating ``paths`` with ``options`` (map or bayes) will compile the joint
    model first (:func:`chekan.runtime.engine.compiled_before`), judged on the records among
    the first ``limit`` files of distinct sizes (records of one program have about one size
    and one bucket); unreadable files and protocols are left to the calibration."""
    from chekan.pipeline import input_ready, read_input
    from chekan.runtime.engine import compiled_before

    sizes: set[int] = set()
    for p in paths:
        try:
            size = Path(p).stat().st_size // 4096
            if size in sizes:
                continue
            sizes.add(size)
            ready = input_ready(read_input(p), options, p)
            if ready.kind == "record" and not compiled_before(padded_model(ready.data, options)):
                return True
        except Exception:  # the calibration reports a bad file; here it only stays unknown
            continue
        if len(sizes) >= limit:
            break
    return False


def stored(model, method: str) -> bool:
    """Whether the store holds the last executable that ``method`` runs on ``model``'s
    bucket (``map``: the derived quantities; ``bayes``: the draws, in chunks of
    :func:`chekan.fit.reported.posterior_draws`), and so, as warmup stores them, all."""
    import inspect

    from chekan.fit.reported import posterior_draws
    from chekan.runtime.engine import DRAWS, EM_NEWTON, MAP_DERIVED, engine_for

    engine = engine_for(model.structure)
    if method == "map":
        return engine.stored(MAP_DERIVED, model.data, model.duration_h) and engine.store.stored(
            EM_NEWTON, *em_newton_args(model)
        )
    chunk = inspect.signature(posterior_draws).parameters["chunk"].default
    zs = np.zeros((chunk, engine.problem.bayes_space.size))
    keys = np.zeros((chunk, 2), dtype=np.uint32)
    return engine.store.stored(DRAWS, zs, keys, model.data, model.duration_h)


def em_newton_args(model) -> tuple:
    """The arguments of the EM's Newton step (:attr:`chekan.runtime.engine.Engine.em_newton`)
    for ``model``: z at the centre of the MAP space, the hyperparameters, updates and change
    as one EM pass from the prior's hyperparameters leaves them."""
    from chekan.jaxconfig import device_array
    from chekan.joint.problem import default_hyper
    from chekan.runtime.engine import engine_for

    engine = engine_for(model.structure)
    z = device_array(np.zeros(engine.problem.map_space.size))
    _, h, n, change = engine.em_pass(z, default_hyper(), model.data)
    return z, h, n, change, model.data


def store_em_newton(model) -> None:
    """Run the EM's Newton step once on ``model``, so that the store keeps it: a calibration
    runs it only where plain EM updates have not converged (:func:`chekan.fit.map.between_passes`),
    which the warmup's session need not show, and a user's first record that needs it would
    then compile it (≈ 40 s on 2 cores)."""
    from chekan.runtime.engine import engine_for

    engine_for(model.structure).em_newton(*em_newton_args(model))


def warm(
    targets: Sequence[WarmTarget],
    methods: Sequence[str] = METHODS,
    *,
    say: Callable[[str], None] = print,
    calibrate: Callable[..., dict] | None = None,
    newton: Callable[[Any], None] | None = None,
    force: bool = False,
) -> list[WarmStep]:
    """Calibrate a simulated session of each target with each method (default options,
    the sampler capped as ``--quick``) so that the store keeps what they compiled, and after
    ``map`` run the EM's Newton step on it (:func:`store_em_newton`), unless the store holds
    them already (:func:`stored`; ``force``: calibrate anyway); ``say`` tells the progress.
    ``calibrate``: :func:`chekan.pipeline.calibrate`, ``newton``: :func:`store_em_newton`
    (a test's stand-ins)."""
    from chekan.options import CalibrationOptions
    from chekan.pipeline import calibrate as calibrate_record
    from chekan.records.simulate import Truth, simulate_session
    from chekan.runtime.padding import bucket_of
    from chekan.runtime.process import executable_store

    run = calibrate or calibrate_record
    events = executable_store().events
    steps = []
    for i, target in enumerate(targets, 1):
        say(f"[{i}/{len(targets)}] {target.name}: simulating a session…")
        record, _ = simulate_session(target.program(), Truth(serial="warmup"), seed=1)
        model = padded_model(record)
        bucket = tuple(bucket_of(model.structure))
        for method in methods:
            if not force and stored(model, method):
                say(f"  {method} on its bucket {_bucket_text(bucket)}: stored already")
                steps.append(WarmStep(target.name, method, bucket, 0, 0, 0.0))
                continue
            say(f"  {method} on its bucket {_bucket_text(bucket)}…")
            seen, t0 = len(events), time.perf_counter()
            opts = CalibrationOptions(method=method, progress=False, quick=True)
            run(record, opts)
            if method == "map":
                (newton or store_em_newton)(model)
            new = [state for _, state in events[seen:]]
            step = WarmStep(
                target.name,
                method,
                bucket,
                new.count("compiled"),
                new.count("loaded"),
                time.perf_counter() - t0,
            )
            say(f"    {step.compiled} compiled, {step.loaded} loaded ({step.seconds:.0f} s)")
            steps.append(step)
    return steps


def _bucket_text(bucket: Sequence[int]) -> str:
    names = ("holds", "bins", "slew samples", "systematic", "X terms")
    return "(" + ", ".join(f"{n} {k}" for n, k in zip(bucket, names, strict=True)) + ")"


def store_summary() -> str:
    """Where the executables are kept and how much they take."""
    from chekan.runtime.process import executable_store

    folder = executable_store().folder
    if folder is None:
        return "the executable store is off (no writable cache folder): nothing was kept"
    files = list(Path(folder).glob("*.jaxexe"))
    size = sum(f.stat().st_size for f in files)
    return f"executable store: {folder} ({len(files)} executables, {size / 1e6:.0f} MB)"
