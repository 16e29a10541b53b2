"""``chekan demo``: the main job end to end on the built-in emulator.

emulate (both devices, in-process, faster than real time) → acquire (the paper's
program, or a short one with ``--quick``) → calibrate (classical and Bayesian) →
certificate. Prints what it wrote where.
"""

from __future__ import annotations

import time
from pathlib import Path

from chekan.physics.program import PAPER_ANGLES, build_program, default_program, parse_angle_deg


def demo_program(quick: bool):
    """The paper's 9 h program, or the same angles with 300 s dwells (3 h) for ``--quick``."""
    if not quick:
        return default_program()
    return build_program(
        [parse_angle_deg(a) for a in PAPER_ANGLES],
        name="paper-short",
        dwell_s=300.0,
        settle_s=200.0,
    )


def dual_axis_program(quick: bool):
    """The designer's 9 h program about both axes (6 rounds, ≈ 2.6 h, for ``quick``)."""
    return build_program(
        [4.5, 4 + 51 / 60, 5 + 10 / 60],
        name="design-best-xy" + ("-short" if quick else ""),
        axis="xy",
        order="alternate",
        rounds=6 if quick else 20,
        dwell_s=188.0,
        settle_s=120.0,
    )


def run_demo(
    out: str | Path, *, quick: bool = False, use_emulator: bool = True, seed: int = 1
) -> int:
    from chekan.pipeline import CalibrationOptions, calibrate_file
    from chekan.records import write_record
    from chekan.records.simulate import Truth, simulate_session, write_truth
    from chekan.results.document import write_result
    from chekan.results.summary import format_summary

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    program = demo_program(quick)
    truth = Truth(serial="DEMO-1")
    rec = out / "record.csv"
    for stale in out.glob("record.csv*"):
        stale.unlink()
    t0 = time.perf_counter()
    print(f"1/4 acquisition: {program.describe()}")
    if use_emulator:
        from hw.acquisition import Options, acquire
        from hw.emulator import InProcessEmulator

        with InProcessEmulator(f"demo-{seed}", speed=0, seed=seed, truth=truth) as emu:
            summary = acquire(
                rec,
                program,
                Options(sensor_url=emu.sensor_url, platform_url=emu.platform_url),
                g_local_mgal=truth.g_local_mgal,
                meta={"site": "built-in emulator", "operator": "chekan demo"},
            )
        print(summary.format())
        if summary.exit_code != 0:
            print(f"acquisition failed (exit {summary.exit_code})")
            return summary.exit_code
    else:
        record, truth = simulate_session(program, truth, seed=seed)
        write_record(rec, record)
    write_truth(out / "truth.json", truth)
    print(f"   wrote {rec} and {out / 'truth.json'} ({time.perf_counter() - t0:.0f} s)")
    print("2/4 classical calibration (Calibr.exe method)")
    classical = calibrate_file(rec, CalibrationOptions(method="classical"))
    write_result(out / "result_classical.json", classical)
    print(f"   wrote {out / 'result_classical.json'}")
    print("3/4 joint Bayesian calibration")
    res = calibrate_file(
        rec, CalibrationOptions(method="bayes", netcdf=out / "result_bayes.nc", quick=quick)
    )
    write_result(out / "result_bayes.json", res)
    print(format_summary(res))
    print(f"   wrote {out / 'result_bayes.json'} and {res.get('posterior_netcdf')}")
    print("4/4 certificate")
    from chekan.report import render_report

    pdf = render_report(res, out / f"calibr_{res['serial']}.pdf", lang="en")
    print(f"   wrote {pdf}")
    d = truth.derived()
    print(
        "truth: b1 = {b1:.6f}, b2 = {b2:.6f}, a = {a:.4e} mGal/pix^2 "
        "(posterior: b1 = {p1:.6f} ± {s1:.6f}, b2 = {p2:.6f} ± {s2:.6f})".format(
            **d,
            p1=res["parameters"]["b1"]["mean"],
            s1=res["parameters"]["b1"]["sd"],
            p2=res["parameters"]["b2"]["mean"],
            s2=res["parameters"]["b2"]["sd"],
        )
    )
    print(f"demo done in {time.perf_counter() - t0:.0f} s; everything is in {out}/")
    return 0
