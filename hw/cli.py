"""``chekan emulate`` and ``chekan acquire``: argparse sub-commands of the hardware layer.

The lead's CLI calls :func:`add_emulate_parser` and :func:`add_acquire_parser`;
each sets ``func`` (Namespace → exit code). :func:`main` runs them standalone
(``python -m hw.cli acquire …``), which the tests use for subprocesses.

Typical session (two terminals)::

    chekan emulate --sensor /tmp/chekan-sensor --platform /tmp/chekan-platform --speed 200
    chekan acquire --sensor /tmp/chekan-sensor --platform /tmp/chekan-platform \\
        --out rec.csv --g-local-mgal 981922.05 --meta site=Lab
    chekan acquire --resume rec.csv          # after a crash or Ctrl-C
"""

from __future__ import annotations

import argparse
import os
import re
import signal
import sys
import threading

from chekan import argtypes
from chekan.errors import ChekanError
from chekan.files.kinds import RECORD, TRUTH
from chekan.files.outputs import Output, check_outputs, run_command

_META_RE = re.compile(r"([a-z0-9_]+)=(.*)", re.DOTALL)


def add_emulate_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "emulate",
        help="emulate the sensor and the platform on pseudo-terminals",
        description=(
            "Run both devices of the gravimeter on pseudo-terminals until Ctrl-C. The host "
            "opens the stable symlinks given by --sensor/--platform."
        ),
    )
    p.add_argument("--sensor", default="/tmp/chekan-sensor", help="symlink to the sensor pty")
    p.add_argument("--platform", default="/tmp/chekan-platform", help="symlink to the platform pty")
    p.add_argument(
        "--speed",
        type=argtypes.real(0.0, 1e6),
        default=1.0,
        help="device seconds per wall second (200: 9 h in under 3 min; 0: as fast as the host "
        "reads, lock-stepped)",
    )
    p.add_argument("--seed", type=argtypes.seed, default=0, help="seed of noise, errors and faults")
    p.add_argument(
        "--faults",
        default="",
        help="fault plan, e.g. 'garbage=0.01;badsum=0.01;drop=0.005;stall=sensor@600+30;"
        "vanish=sensor@900+20;fault=1200+40;tilterr=BUSY@3' (see hw/faults.py)",
    )
    p.add_argument(
        "--duration-s", type=argtypes.non_negative, help="stop after this many wall seconds"
    )
    p.add_argument("--serial", default="SIM-1", help="sensor serial number (ID reply)")
    p.add_argument(
        "--seq-start", type=argtypes.integer(0, 65535), default=0, help="first sensor seq (0-65535)"
    )
    p.add_argument("--random-truth", action="store_true", help="draw the instrument from --seed")
    p.add_argument(
        "--angle-errors",
        default="default",
        metavar="SPEC",
        help="errors of the platform's angle sensors: 'default' (each sensor a periodic and "
        "a scale error inside the 3″ bound), 'none' (no systematic error), 'random' "
        "(drawn from --seed), then items AXIS.FIELD=VALUE to change one number, e.g. "
        "'none;x.scale_ppm=40;y.sd=1' (fields amp, period_deg, phase_deg, scale_ppm, sd, "
        "jitter; see hw/anglesensors.py)",
    )
    p.add_argument("--truth", help="write the true parameters and holds here (JSON) at exit")
    p.add_argument(
        "-v", "--verbose", action="store_true", help="print device events as they happen"
    )
    p.set_defaults(func=cmd_emulate)
    return p


def cmd_emulate(args: argparse.Namespace) -> int:
    import json

    import numpy as np

    from chekan.records.simulate import Truth, random_truth
    from hw import anglesensors
    from hw.emulator import PtyEmulator
    from hw.faults import parse_faults

    check_outputs([], [Output(args.truth, writes=TRUTH)])
    if args.random_truth:
        truth = random_truth(np.random.default_rng(args.seed + 10_000), serial=args.serial)
    else:
        truth = Truth(serial=args.serial)
    try:
        faults = parse_faults(args.faults)
        sensors = anglesensors.parse(
            args.angle_errors,
            seed=args.seed,
            sd_arcsec=truth.angle_error_sd_arcsec,
            jitter_arcsec=truth.tilt_jitter_arcsec,
        )
    except ValueError as e:
        print(f"chekan emulate: {e}", file=sys.stderr)
        return 2
    emu = PtyEmulator(
        args.sensor,
        args.platform,
        truth=truth,
        seed=args.seed,
        speed=args.speed,
        faults=faults,
        seq_start=args.seq_start,
        sensors=sensors,
    )
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGTERM, _on_sigterm)  # clean up the symlinks on kill too
    emu.start(args.duration_s)
    print(f"sensor   {emu.sensor.link_path} -> {emu.sensor.device}")
    print(f"platform {emu.platform.link_path} -> {emu.platform.device}")
    speed = "as fast as the host reads" if args.speed == 0 else f"{args.speed:g}x"
    print(sensors.describe())
    print(f"speed {speed}, {truth.sample_rate_hz:g} Hz; Ctrl-C to stop", flush=True)
    shown = 0
    try:
        while not emu.wait(0.2):
            if args.verbose:
                ev = emu.emulator.events
                for t, what in ev[shown:]:
                    print(f"  t={t:9.1f} s  {what}", flush=True)
                shown = len(ev)
    except KeyboardInterrupt:
        pass
    finally:
        emu.stop()
    em = emu.emulator
    print(
        f"stopped at device time {em.t:.0f} s after {em.ticks} ticks; "
        f"{em.tilt_commands} TILT commands; {dict(sorted(em.stats.items()))}"
    )
    if args.truth:
        d = truth.to_json()
        d["angle_sensors"] = sensors.to_json()
        d["holds"] = [h.to_json() for h in em.platform.holds]
        from chekan.files.durable import atomic_output

        with atomic_output(args.truth) as f:
            f.write(json.dumps(d, indent=2) + "\n")
        print(f"wrote {args.truth}")
    return 0 if emu.error is None else 1


def add_acquire_parser(subparsers) -> argparse.ArgumentParser:
    p = subparsers.add_parser(
        "acquire",
        help="run a tilt program and record every sensor sample",
        description=(
            "Run the tilt program on the platform and record every sensor sample to a "
            "chekan-record/1 file, with a journal (REC.journal.jsonl) and a raw log "
            "(REC.raw.log). Exit status: 0 done, 1 device error (e.g. TILT,ERR), "
            "2 usage, 3 a port stayed down, 130 interrupted. Resume with --resume."
        ),
    )
    p.add_argument("--sensor", help="pyserial URL of the sensor (device path, socket://, …)")
    p.add_argument("--platform", help="pyserial URL of the platform")
    p.add_argument("-o", "--out", help="record file to write (must not exist)")
    p.add_argument("--program", help="program TOML file (default: the paper's program)")
    p.add_argument("--g-local-mgal", help="absolute gravity at the site, mGal (required)")
    p.add_argument(
        "--meta",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="extra header line (repeatable), e.g. site=Lab operator=AB",
    )
    p.add_argument(
        "--resume",
        nargs="?",
        const=True,
        metavar="REC",
        help="continue an interrupted run of REC (or of --out); ports come from its journal",
    )
    p.add_argument(
        "--timeout-s", type=argtypes.positive, help="silence before a port is reopened (5)"
    )
    p.add_argument(
        "--give-up-s", type=argtypes.positive, help="time without data before giving up (120)"
    )
    p.add_argument(
        "--reply-timeout-s", type=argtypes.positive, help="wait for a reply to a query (2)"
    )
    p.add_argument("-q", "--quiet", action="store_true", help="no progress line")
    p.add_argument(
        "--live",
        metavar="[HOST:]PORT",
        help="serve a live page of the run (default host 127.0.0.1; port 0: any free port, "
        "printed); a separate process that only reads the record and journal",
    )
    p.set_defaults(func=cmd_acquire)
    return p


def _parse_meta(items: list[str]) -> dict[str, str]:
    out: dict[str, str] = {}
    for item in items:
        m = _META_RE.fullmatch(item)
        if not m:
            raise ChekanError(f"--meta {item!r}: expected key=value with a key of [a-z0-9_]")
        out[m[1]] = m[2]
    return out


class _Terminate(KeyboardInterrupt):
    """SIGTERM, handled like Ctrl-C (the platform is levelled, the journal closed)."""


def _on_sigterm(signum, frame) -> None:
    raise _Terminate()


def _start_live(args: argparse.Namespace, record) -> None:
    """``--live``: the page in its own process (chekan.live); whatever happens to it, the
    acquisition goes on."""
    if not getattr(args, "live", None):
        return
    try:
        from chekan.live import start_beside

        _proc, line = start_beside(record, args.live)
    except Exception as e:  # the run matters more than its page
        line = f"the live page did not start: {type(e).__name__}: {e}"
    print(line, flush=True)


def check_ports(sensor: str | None, platform: str | None) -> None:
    """A port given as a device path must exist before anything is written: a typo fails at
    once, naming the port, instead of waiting out the give-up time and leaving a journal.
    URLs (``socket://``, ``rfc2217://``, ``loop://``) are left to pyserial."""
    from hw.linkio import url_scheme

    for option, url in (("--sensor", sensor), ("--platform", platform)):
        if url and not url_scheme(url) and not os.path.exists(url):
            raise ChekanError(f"{option} {url}: no such port (check the device name)")


def cmd_acquire(args: argparse.Namespace) -> int:
    from chekan.physics.program import default_program, load_program
    from hw.acquisition import Options, acquire, resume
    from hw.errors import BadMetadata, PortsUnknown, RecordExists
    from hw.progress import StatusLine

    if not args.resume:  # a new record must not replace a measurement (or its program)
        check_outputs([args.program], [Output(args.out, writes=RECORD)])
    check_ports(args.sensor, args.platform)
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGTERM, _on_sigterm)
    status = None if args.quiet else StatusLine()
    overrides = {
        "timeout_s": args.timeout_s,
        "give_up_s": args.give_up_s,
        "reply_timeout_s": args.reply_timeout_s,
    }
    try:
        if args.resume:
            rec = args.out if args.resume is True else args.resume
            if not rec:
                raise ChekanError("--resume needs the record: --resume REC or --out REC")
            ignored = [
                f"--{n.replace('_', '-')}"
                for n in ("program", "g_local_mgal", "meta")
                if getattr(args, n)
            ]
            if ignored:
                print(f"resume: {', '.join(ignored)} ignored (taken from the record's journal)")
            _start_live(args, rec)
            summary = resume(
                rec,
                sensor_url=args.sensor,
                platform_url=args.platform,
                overrides=overrides,
                progress=status,
                report=None,
            )
        else:
            missing = [
                f"--{n.replace('_', '-')}"
                for n in ("sensor", "platform", "out", "g_local_mgal")
                if not getattr(args, n)
            ]
            if missing:
                raise ChekanError(f"acquire needs {', '.join(missing)}")
            program = load_program(args.program) if args.program else default_program()
            opts = Options(sensor_url=args.sensor, platform_url=args.platform)
            for k, v in overrides.items():
                if v is not None:
                    setattr(opts, k, v)
            print(f"program {program.describe()}", flush=True)
            _start_live(args, args.out)
            summary = acquire(
                args.out,
                program,
                opts,
                g_local_mgal=args.g_local_mgal,
                meta=_parse_meta(args.meta),
                progress=status,
                report=None,
            )
    except RecordExists as e:
        raise ChekanError(
            f"{e.path} exists: resume it (--resume) or choose another --out"
        ) from None
    except BadMetadata as e:
        raise ChekanError(f"--meta: {e.problem}") from None
    except PortsUnknown:
        raise ChekanError(
            "resume: the ports are not in the journal: give --sensor and --platform"
        ) from None
    finally:
        if status is not None:
            status.done()
    print(summary.format(), flush=True)  # the summary, once (the library does not print it)
    return summary.exit_code


def build_parser() -> argparse.ArgumentParser:
    from chekan import __version__

    ap = argtypes.Parser(prog="python -m hw.cli")
    ap.add_argument("-V", "--version", action="version", version=f"chekan {__version__}")
    sub = ap.add_subparsers(dest="command", required=True)
    add_emulate_parser(sub)
    add_acquire_parser(sub)
    return ap


def main(argv: list[str] | None = None) -> int:
    """Standalone entry (the ``chekan`` CLI wires the same sub-commands)."""
    return run_command(lambda: (a := build_parser().parse_args(argv)).func(a))


if __name__ == "__main__":
    sys.exit(main())
