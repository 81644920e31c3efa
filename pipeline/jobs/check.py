"""``fsid check``: ingest a log, run the data-quality checks and (when the log has the
channels) the air-data-angle and sensor-compatibility stages as ``fsid estimate`` runs
them, write ``checks.json`` and the canonical data (``canonical.csv``: every canonical
channel resampled to one time base)."""

from __future__ import annotations

import io
import sys
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

from pipeline.conditioning.checks import findings_to_json, run_checks, summarize
from pipeline.conditioning.flow_angles import summary as flow_summary
from pipeline.conditioning.identifiability import (
    bottom_line,
    identifiability,
    identifiability_findings,
    identifiability_json,
)
from pipeline.ingest.aircraft import aircraft_for_log, servo_travel_for
from pipeline.ingest.readers import read_log
from pipeline.jobs.progress import Progress
from pipeline.jobs.stages import compatibility_after_flow_angles, flow_angle_stage
from pipeline.outputs.recording import write_check_recording
from pipeline.outputs.recording_flight import FlightRecord
from pipeline.paths import atomic_write_text, new_run_dir, run_id, staged

#: core channels whose fastest rate sets canonical.csv's (at most 100 Hz)
CORE_CHANNELS = ("ax", "p", "phi", "V", "de")


def check_log(
    log: Path,
    out: str | Path | None = None,
    *,
    map_path: str | None = None,
    segments: Any = None,
    time_base: str | None = None,
    compat: bool = True,
    rate: float | None = None,
    positions: tuple[Sequence[float], Sequence[float], str] | None = None,
    aircraft: str | Path | None = None,
) -> int:
    """Check ``log`` (``segments``, ``map_path``, ``time_base``: how to read it) into the
    run folder ``out``; ``compat``: with the air-data-angle and compatibility stages, the
    sensors at ``positions`` (IMU, boom [m], where they came from); ``rate``: of
    canonical.csv [Hz] (default: the fastest core channel, at most 100); ``aircraft``: the
    aircraft file (servo travel, max thrust; default: a truth.json next to the log). Prints
    what it found and ends with the identifiability of each axis (checks.json
    ``identifiability``; an axis that cannot be identified is a failed finding); returns 0."""
    out = new_run_dir("check", out, inputs=[log, map_path, aircraft])
    picked = isinstance(segments, (list, tuple))
    fd = read_log(
        log,
        map=map_path,
        segments=None if picked else segments,
        time_base=time_base,
        servo_travel=servo_travel_for(log, aircraft),
    )
    by_axis = fd  # the windows as fsid estimate takes them: a range once per control axis moved in it
    if picked:
        by_axis = replace(fd, segments=fd.chosen_segments(segments))
        fd.segments = fd.chosen_segments(segments, per_axis=False)
    print(f"read {log} ({fd.meta['format']}, map {fd.meta['map']}): {len(fd.channels)} channels")
    named = {w["name"] for w in (fd.meta.get("info") or {}).get("windows") or ()}
    for sg in (g for g in fd.segments if g.name in named):
        print(f"  window {sg.name}: {sg.t0:.2f}-{sg.t1:.2f} s, {sg.axis or 'no control input moved'}")
    ac = aircraft_for_log(log, aircraft, fd, required=False, say=lambda _: None)[0]
    fd.meta["stall_speed_mps"] = by_axis.meta["stall_speed_mps"] = getattr(ac, "stall_speed", None)
    findings = run_checks(fd)
    extra: dict = {}
    if compat:
        extra = _compatibility(fd, positions or ([0.0] * 3, [0.0] * 3, "default 0,0,0"))
    ident = identifiability(by_axis, findings, ac)
    findings += identifiability_findings(ident)
    extra["identifiability"] = identifiability_json(ident)
    extra["run_id"] = rid = run_id(out)
    if rate is None:
        rates = [c.rate_hz for k, c in fd.channels.items() if k in CORE_CHANNELS]
        rate = min(max(rates), 100.0) if rates else 10.0
    df = fd.resample(rate, span="union")
    with staged(out, "checks.json") as stage:  # checks.json last: it says the set is whole
        write_check_recording(stage / "check.rrd", FlightRecord(fd, findings), recording_id=rid)
        atomic_write_text(stage / "canonical.csv", _canonical_csv(df, fd))
        atomic_write_text(stage / "checks.json", findings_to_json(findings, fd, extra))
    _print_compatibility(extra.get("compatibility", {}))
    c = summarize(findings)
    print(f"checks: {c['pass']} pass, {c['warn']} warn, {c['fail']} fail")
    for f in findings:
        if f.status == "fail" and f.check != "identifiability":
            print(f"  FAIL {f.check} {f.channel or ''}: {f.message}", file=sys.stderr)
    print("identifiability (built-in models; one maneuver per axis held out for the proof of match):")
    print("\n".join(bottom_line(ident)))
    print(f"wrote {out / 'checks.json'} and {out / 'canonical.csv'} ({len(df)} rows at {rate:g} Hz)")
    print(f"recording: {out / 'check.rrd'}  (open with: fsid view {out})")
    return 0


def _compatibility(fd: Any, positions: tuple[Sequence[float], Sequence[float], str]) -> dict[str, Any]:
    """The same stages, estimates and rules as fsid estimate's: the air-data angles a log
    lacks, or holds as an autopilot's estimate, rebuilt from the flight path with a fitted
    wind and the pitot's scale factor where the headings allow; then the compatibility
    reconstruction on the logged channels (IMU errors only without vanes, the wind held),
    which errors that stage would remove: "applied". Returns the checks.json entries."""
    quiet = Progress(2, quiet=True)
    rebuilt, _, logged, flow = flow_angle_stage(fd, None, quiet)
    print(
        f"air-data angles: {flow_summary(flow) if flow['status'] == 'reconstructed' else flow['status']}"
        + (f" ({flow['reason']})" if flow.get("reason") else "")
    )
    imu, boom, origin = positions
    print("sensor compatibility (flight path reconstruction) ...")
    comp = compatibility_after_flow_angles(logged, rebuilt, flow, None, quiet, positions=(imu, boom))[1]
    comp["positions_from"] = origin
    return {"air_data_angles": flow, "compatibility": comp}


def _print_compatibility(comp: dict[str, Any]) -> None:
    """The compatibility stage's estimates, one line each."""
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


def _canonical_csv(df, fd) -> str:
    """canonical.csv's text: ``t`` seconds from the log's start and ``t_abs`` the same
    instants on the log's own clock (epoch or boot, meta t0_kind), to the microsecond
    whatever its size (1.7e9 s), then the resampled channels."""
    buf = io.StringIO()
    t_abs = (df["t"] + float(fd.meta.get("t0_abs", 0.0))).map("{:.6f}".format)
    df = df.assign(t=df["t"].map("{:.6f}".format))
    df.insert(1, "t_abs", t_abs)
    df.to_csv(buf, index=False, float_format="%.9g")
    return buf.getvalue()
