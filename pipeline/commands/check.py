"""``fsid check LOG``: ingest a log, run the data-quality checks (and, when the log has the
channels, the sensor-compatibility reconstruction), write ``checks.json`` and the
canonical data (``canonical.csv``: every canonical channel resampled to one time base)."""

from __future__ import annotations

import argparse
import io
import sys
from pathlib import Path

from pipeline.errors import FsidError

HELP = "ingest a flight log, check its data quality and sensor compatibility"


def add_time_base_argument(parser: argparse.ArgumentParser) -> None:
    """``--time-base``: the time base of a .tlog or .mcap log (pipeline.ingest.readers.TIME_BASES)."""
    parser.add_argument(
        "--time-base",
        default=None,
        choices=["auto", "boot", "header", "log"],
        help="time base of a .tlog (auto = the autopilot's own stamps, boot = "
        "those only, log = the ground station's receive times) or .mcap "
        "(auto, header = the messages' header stamps, log = log times); "
        "default auto",
    )


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("log", help="flight log: .mcap, .bin, .tlog, .ulg or .csv")
    parser.add_argument(
        "--map", default=None, help="channel map (built-in name or TOML file; default: built-in for the format)"
    )
    parser.add_argument("--out", default=None, help="output folder (default: a new folder under ./runs/)")
    parser.add_argument(
        "--rate",
        type=float,
        default=None,
        help="rate of canonical.csv in Hz (default: fastest core channel, at most 100)",
    )
    parser.add_argument(
        "--segments", default=None, help="'mode', 'auto' or time ranges 't0:t1,t0:t1' in s on the log's time base"
    )
    add_time_base_argument(parser)
    parser.add_argument("--no-compat", action="store_true", help="skip the sensor-compatibility fit")
    parser.add_argument(
        "--imu-pos",
        default=None,
        metavar="X,Y,Z",
        help="IMU position from the CG, body axes, m (default: from a truth.json next to the log, else 0,0,0)",
    )
    parser.add_argument(
        "--boom-pos",
        default=None,
        metavar="X,Y,Z",
        help="air-data boom position from the CG, body axes, m (default as --imu-pos)",
    )


def _vec(text: str | None, name: str):
    if text is None:
        return None
    try:
        v = [float(x) for x in text.split(",")]
    except ValueError:
        v = []
    if len(v) != 3:
        raise FsidError(f"{name} '{text}' is not three numbers x,y,z in metres; e.g. {name} 0.8,0,0.05")
    return v


def _positions(log: Path, args) -> tuple[list[float], list[float], str]:
    imu, boom = _vec(args.imu_pos, "--imu-pos"), _vec(args.boom_pos, "--boom-pos")
    origin = "command line" if imu or boom else "default 0,0,0"
    tj = log.parent / "truth.json"
    if (imu is None or boom is None) and tj.is_file():
        import json

        try:
            sens = json.loads(tj.read_text()).get("sensors", {})
            imu = imu or sens.get("imu", {}).get("position_m")
            boom = boom or sens.get("airdata", {}).get("position_m")
            origin = f"{tj} (sensor positions)"
        except (ValueError, AttributeError):
            pass
    return list(imu or [0.0, 0.0, 0.0]), list(boom or [0.0, 0.0, 0.0]), origin


def _segments(spec: str | None):
    if spec is None or spec in ("mode", "auto"):
        return spec
    out = []
    for part in spec.split(","):
        try:
            a, b = part.split(":")
            out.append((float(a), float(b)))
        except ValueError:
            raise FsidError(f"--segments '{part}' is not t0:t1 (seconds); e.g. --segments 10:30,45:70") from None
    return out


def run(args: argparse.Namespace) -> int:
    from pipeline.conditioning.checks import findings_to_json, run_checks, summarize
    from pipeline.ingest.readers import read_log
    from pipeline.paths import atomic_write_text, new_run_dir

    log = Path(args.log)
    if not log.is_file():
        raise FsidError(f"log '{log}' not found; give the path of a .mcap/.bin/.tlog/.ulg/.csv file")
    fd = read_log(log, map=args.map, segments=_segments(args.segments), time_base=args.time_base)
    print(f"read {log} ({fd.meta['format']}, map {fd.meta['map']}): {len(fd.channels)} channels")
    findings = run_checks(fd)
    extra: dict = {}
    if not args.no_compat:
        # the same stages, estimates and rules as fsid estimate's: the air-data angles a log
        # lacks, or holds as an autopilot's estimate, rebuilt from the flight path with a
        # fitted wind and the pitot's scale factor where the headings allow; then the
        # compatibility reconstruction on the logged channels (IMU errors only without
        # vanes, the wind held), which errors that stage would remove: "applied"
        from pipeline.conditioning.flow_angles import summary
        from pipeline.jobs.run import Progress, compatibility_after_flow_angles, flow_angle_stage

        quiet = Progress(2, quiet=True)
        rebuilt, _, logged, flow = flow_angle_stage(fd, None, quiet)
        extra["air_data_angles"] = flow
        print(
            f"air-data angles: {summary(flow) if flow['status'] == 'reconstructed' else flow['status']}"
            + (f" ({flow['reason']})" if flow.get("reason") else "")
        )
        imu, boom, origin = _positions(log, args)
        print("sensor compatibility (flight path reconstruction) ...")
        extra["compatibility"] = compatibility_after_flow_angles(
            logged, rebuilt, flow, None, quiet, positions=(imu, boom)
        )[1]
        extra["compatibility"]["positions_from"] = origin
    out = new_run_dir("check", args.out)
    atomic_write_text(out / "checks.json", findings_to_json(findings, fd, extra))
    rate = args.rate
    if rate is None:
        rates = [c.rate_hz for k, c in fd.channels.items() if k in ("ax", "p", "phi", "V", "de")]
        rate = min(max(rates), 100.0) if rates else 10.0
    df = fd.resample(rate, span="union")
    buf = io.StringIO()
    df.to_csv(buf, index=False, float_format="%.9g")
    atomic_write_text(out / "canonical.csv", buf.getvalue())
    comp = extra.get("compatibility", {})
    if comp.get("status") in ("ok", "not converged"):
        print(f"compatibility: {comp['status']}, {len(comp['parameters'])} sensor errors estimated")
        for n, row in comp["parameters"].items():
            sd = f"+- {row['std']:.2g}" if row.get("std") is not None else "(no std)"
            print(
                f"  {n:12s} {row['estimate']: .5g} {sd} {row['unit']}{'  (significant)' if row.get('applied') else ''}"
            )
        if comp.get("note"):
            print(f"  note: {comp['note']}")
    elif comp:
        print(f"compatibility: {comp.get('status')}: {comp.get('reason', '')}")
    c = summarize(findings)
    print(f"checks: {c['pass']} pass, {c['warn']} warn, {c['fail']} fail")
    for f in findings:
        if f.status == "fail":
            print(f"  FAIL {f.check} {f.channel or ''}: {f.message}", file=sys.stderr)
    print(f"wrote {out / 'checks.json'} and {out / 'canonical.csv'} ({len(df)} rows at {rate:g} Hz)")
    return 0
