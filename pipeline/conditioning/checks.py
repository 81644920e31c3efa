"""Data-quality checks on :class:`~pipeline.ingest.flightdata.FlightData`.

Each check returns :class:`Finding` objects (status pass / warn / fail, the channel, the
time span and one sentence a user understands). ``run_checks`` runs them all; findings
never stop a run — a "fail" says the data will not support identification as it is.

Per channel: sample rate and jitter, gaps, non-monotonic or duplicate times, NaN/Inf,
saturation/clipping, stuck values, unit plausibility (degrees in a radian field, g in an
m/s^2 field). Per file: damage (truncation), missing channels. Per segment: duration,
ground-only data, and the excitation of each control axis. Across channels: kinematic
consistency (:mod:`.kinematics`: bank against turn, heading against course, rates against
attitude), which finds a frame, handedness or sign defect.
"""

from __future__ import annotations

import json
from collections.abc import Iterable, Sequence
from dataclasses import replace

import numpy as np

from pipeline.conditioning.findings import FAIL, PASS, WARN, Finding
from pipeline.conditioning.kinematics import check_kinematics
from pipeline.ingest.flightdata import CONTROL_INPUTS, FlightData, SegmentSpec
from pipeline.ingest.sampling import GAP_FACTOR, response_floor_hz, start_statement, typical_interval

#: channels system identification needs (missing ones are reported)
CORE = ("ax", "ay", "az", "p", "q", "r", "phi", "theta", "psi", "V", "alpha", "beta", "h", "de", "da", "dr")
#: the body rates and accelerations: their own spectra size the rate they need
MOTION = ("ax", "ay", "az", "p", "q", "r", "pdot", "qdot", "rdot")
#: channels with fast dynamics: should be sampled at >= MIN_RATE_HZ
DYNAMIC = (
    "ax",
    "ay",
    "az",
    "p",
    "q",
    "r",
    "phi",
    "theta",
    "psi",
    "alpha",
    "beta",
    "V",
    "de",
    "da",
    "dr",
    "pdot",
    "qdot",
    "rdot",
)
MIN_RATE_HZ = 20.0
ANGLES = ("phi", "theta", "psi", "alpha", "beta", "de", "da", "dr")
MIN_EXCITATION_RAD = np.radians(1.0)
#: commands/actuators: held values and full-deflection plateaus are normal, not faults
COMMANDS = ("de", "da", "dr", "throttle", "thrust")


def _span(t: np.ndarray) -> tuple[float | None, float | None]:
    return (float(t[0]), float(t[-1])) if t.size else (None, None)


def _runs(mask: np.ndarray) -> np.ndarray:
    """(k, 2) start/stop indices (stop exclusive) of True runs."""
    e = np.flatnonzero(np.diff(np.r_[0, mask.astype(np.int8), 0]))
    return e.reshape(-1, 2)


def check_channel(name: str, t: np.ndarray, v: np.ndarray) -> list[Finding]:
    """All per-channel checks for one channel (times t [s], values v in SI)."""
    out: list[Finding] = []
    n = t.size
    a, b = _span(t)
    if n < 2:
        out.append(Finding(WARN, "samples", name, f"{name} has only {n} sample(s)", a, b, n))
        return out
    dt = np.diff(t)
    _check_time_order(out, name, t, dt)
    span = _check_rate(out, name, t, dt, v)
    _check_finite(out, name, t, v)
    fin = v[np.isfinite(v)]
    if fin.size < 2:
        return out
    lo, hi = float(fin.min()), float(fin.max())
    _check_saturation(out, name, t, v, lo, hi)
    _check_stuck(out, name, t, v, lo, hi, span, fin.size)
    _check_units(out, name, t, fin)
    return out


def _check_time_order(out: list[Finding], name: str, t: np.ndarray, dt: np.ndarray) -> None:
    """Times t [s] (n >= 2, intervals dt) going backwards or repeated."""
    a, b = _span(t)
    back = int(np.sum(dt < 0))
    dup = int(np.sum(dt == 0))
    if back:
        i = int(np.flatnonzero(dt < 0)[0])
        out.append(
            Finding(
                FAIL,
                "time_order",
                name,
                f"{name}: time goes backwards {back} time(s), "
                f"first at t={t[i]:.3f} s; the log's clock jumped or records are out of order",
                float(t[i]),
                float(t[i + 1]),
                back,
            )
        )
    if dup:
        i = int(np.flatnonzero(dt == 0)[0])
        out.append(
            Finding(
                WARN,
                "duplicate_times",
                name,
                f"{name}: {dup} duplicate time stamp(s), first at t={t[i]:.3f} s",
                float(t[i]),
                float(t[i]),
                dup,
            )
        )
    if not back and not dup:
        out.append(Finding(PASS, "time_order", name, f"{name}: times strictly increasing", a, b))


def _check_rate(out: list[Finding], name: str, t: np.ndarray, dt: np.ndarray, v: np.ndarray) -> float:
    """Sample rate, jitter and gaps of times t [s] (n >= 2, intervals dt); returns their span
    [s]. Rate and jitter from the intervals between gaps (longer than GAP_FACTOR typical
    intervals, :func:`pipeline.ingest.sampling.typical_interval`): a log paused between
    maneuvers keeps its rate and is not irregular; its gaps are reported as such."""
    a, b = _span(t)
    pos = dt[dt > 0]
    span = float(np.nanmax(t) - np.nanmin(t))
    med = typical_interval(t)
    rate = 1.0 / med if np.isfinite(med) and med > 0 else 0.0
    regular = pos[pos <= GAP_FACTOR * med] if np.isfinite(med) else pos
    jitter = float(np.std(regular) / np.mean(regular)) if regular.size > 1 else 0.0
    # the body rates and accelerations show the motion they carry (the rate they need comes
    # from their own spectra, as the identifiability verdict's); attitudes, angles and
    # surfaces are mostly slow trim and turns whatever modes ride on them: the fixed floor
    need = 0.0
    if name in DYNAMIC and rate < MIN_RATE_HZ:
        need = response_floor_hz(t, v, MIN_RATE_HZ, 0.0) if name in MOTION else MIN_RATE_HZ
    if rate < need:
        out.append(
            Finding(
                WARN,
                "rate",
                name,
                f"{name} is sampled at {rate:.1f} Hz; the motion it shows needs >= {need:.1f} Hz (ten samples "
                "a period; telemetry logs are usually too slow: use the onboard log)",
                a,
                b,
                rate,
            )
        )
    else:
        out.append(Finding(PASS, "rate", name, f"{name} sampled at {rate:.1f} Hz", a, b, rate))
    if jitter > 0.25:
        out.append(
            Finding(
                WARN,
                "jitter",
                name,
                f"{name}: sample interval varies by {jitter:.0%} (std/mean of dt); samples arrive in bursts or irregularly",
                a,
                b,
                jitter,
            )
        )
    # gaps
    if pos.size:
        lim = max(GAP_FACTOR * med, 0.1)
        big = np.flatnonzero(dt > lim)
        if big.size:
            k = int(big[np.argmax(dt[big])])
            out.append(
                Finding(
                    WARN,
                    "gaps",
                    name,
                    f"{name}: {big.size} gap(s) longer than {lim:.3g} s, longest {dt[k]:.3g} s from t={t[k]:.3f} s",
                    float(t[k]),
                    float(t[k + 1]),
                    float(dt[k]),
                )
            )
    return span


def _check_finite(out: list[Finding], name: str, t: np.ndarray, v: np.ndarray) -> None:
    """NaN / Inf values."""
    b = _span(t)[1]
    bad = ~np.isfinite(v)
    if bad.any():
        frac = float(bad.mean())
        i = int(np.flatnonzero(bad)[0])
        out.append(
            Finding(
                FAIL if frac > 0.5 else WARN,
                "finite",
                name,
                f"{name}: {int(bad.sum())} NaN/Inf value(s) ({frac:.1%}), first at t={t[i]:.3f} s",
                float(t[i]),
                b,
                frac,
            )
        )


def _check_saturation(out: list[Finding], name: str, t: np.ndarray, v: np.ndarray, lo: float, hi: float) -> None:
    """Saturation / clipping: many samples pinned at the extreme (lo or hi) with a run of >= 3."""
    if hi > lo and name not in COMMANDS:
        for edge, label in ((lo, "minimum"), (hi, "maximum")):
            at = np.isfinite(v) & (v == edge)
            frac = float(at.mean())
            runs = _runs(at)
            longest = int((runs[:, 1] - runs[:, 0]).max()) if runs.size else 0
            if 0.01 < frac < 0.5 and longest >= 3 and at.sum() >= 5:
                r0 = runs[np.argmax(runs[:, 1] - runs[:, 0])]
                out.append(
                    Finding(
                        WARN,
                        "saturation",
                        name,
                        f"{name}: {frac:.1%} of samples sit at "
                        f"its {label} {edge:.4g} (longest run {longest} samples); the "
                        "sensor or actuator may be clipping",
                        float(t[r0[0]]),
                        float(t[r0[1] - 1]),
                        frac,
                    )
                )


def _check_stuck(
    out: list[Finding], name: str, t: np.ndarray, v: np.ndarray, lo: float, hi: float, span: float, n_finite: int
) -> None:
    """A long run of identical values while the channel moves elsewhere, or a constant channel."""
    a, b = _span(t)
    same = np.r_[False, np.diff(v) == 0]
    runs = _runs(same)
    if name in COMMANDS:
        pass
    elif runs.size and hi > lo:
        lens = runs[:, 1] - runs[:, 0]
        k = int(np.argmax(lens))
        s0, s1 = max(runs[k, 0] - 1, 0), runs[k, 1] - 1
        dur = float(t[s1] - t[s0])
        if lens[k] >= 20 and dur >= 1.0 and dur > 0.2 * span:
            out.append(
                Finding(
                    WARN,
                    "stuck",
                    name,
                    f"{name} does not change for {dur:.2f} s "
                    f"({lens[k] + 1} samples at {v[s0]:.4g}) from t={t[s0]:.3f} s; "
                    "sensor stuck or output held",
                    float(t[s0]),
                    float(t[s1]),
                    dur,
                )
            )
    elif hi == lo and n_finite >= 20:
        out.append(Finding(WARN, "stuck", name, f"{name} is constant ({lo:.4g}) over the whole log", a, b, 0.0))


def _check_units(out: list[Finding], name: str, t: np.ndarray, fin: np.ndarray) -> None:
    """Unit plausibility from the largest finite magnitude (degrees in a radian field ...)."""
    a, b = _span(t)
    amax = float(np.max(np.abs(fin)))
    if name in ANGLES and amax > 2 * np.pi + 0.1:
        out.append(
            Finding(
                FAIL,
                "units",
                name,
                f"{name} reaches {amax:.3g} but is an angle in rad; "
                "this looks like degrees in a radian field — set unit = \"deg\" in the map",
                a,
                b,
                amax,
            )
        )
    elif name in ("p", "q", "r") and amax > 20:
        out.append(
            Finding(
                FAIL,
                "units",
                name,
                f"{name} reaches {amax:.3g} rad/s; this looks like deg/s in a rad/s field — set unit = \"deg/s\" in the map",
                a,
                b,
                amax,
            )
        )
    elif name in ("ax", "ay", "az") and (amax > 400 or (amax < 2.5 and name == "az")):
        hint = "mG" if amax > 400 else "g"
        out.append(
            Finding(
                FAIL,
                "units",
                name,
                f"{name} peaks at {amax:.3g} m/s^2; this looks like {hint} — set unit = \"{hint}\" in the map",
                a,
                b,
                amax,
            )
        )
    elif name == "V" and amax > 350:
        out.append(
            Finding(
                FAIL,
                "units",
                name,
                f"V reaches {amax:.4g} m/s; this looks like cm/s or km/h in a m/s field",
                a,
                b,
                amax,
            )
        )


def check_file(fd: FlightData, required: Sequence[str] = CORE) -> list[Finding]:
    """File-level findings: damage and missing channels."""
    out: list[Finding] = []
    dmg = fd.meta.get("damage")
    if dmg:
        out.append(
            Finding(
                WARN,
                "damage",
                None,
                f"{dmg['message']}; kept the {dmg.get('kept_records', 0)} records before it",
                None,
                None,
                float(dmg.get("offset", -1)),
            )
        )
    else:
        out.append(Finding(PASS, "damage", None, "the whole file was readable"))
    for ch, n in (fd.meta.get("untimed") or {}).items():
        out.append(
            Finding(
                WARN,
                "damage",
                ch,
                f"{ch}: {n} sample{'s' if n != 1 else ''} without a finite time (NaN or infinite) dropped; "
                "the log's time field is damaged or blank there",
            )
        )
    why = fd.explain_missing(required)
    for ch, reason in why.items():
        out.append(
            Finding(
                WARN,
                "missing",
                ch,
                f"{ch} is missing: {reason}; identification that needs {ch} cannot run (add it with --map)",
            )
        )
    return out


def _window(fd: FlightData, name: str, seg: SegmentSpec) -> np.ndarray:
    c = fd.channels[name]
    m = (c.t >= seg.t0) & (c.t <= seg.t1)
    v = c.values[m]
    return v[np.isfinite(v)]


#: airspeed [m/s] below which a span is on the ground or hovering, for an aircraft whose
#: stall speed is not known (:func:`airborne_speed`)
AIRBORNE_MPS = 5.0


def airborne_speed(fd: FlightData) -> float:
    """The airspeed [m/s] below which this log's aircraft is not flying: its stall speed
    when the aircraft file gives it (``fd.meta["stall_speed_mps"]``, set by the jobs once
    the aircraft is known: a micro aircraft flies below 5 m/s), else :data:`AIRBORNE_MPS`.
    The one floor for the checks, the fit windows and the identifiability bottom line."""
    v = fd.meta.get("stall_speed_mps")
    return float(v) if v else AIRBORNE_MPS


def slow_airspeed(v: np.ndarray, floor: float = AIRBORNE_MPS) -> tuple[bool, str]:
    """Whether airspeed samples ``v`` (m/s, finite) are below ``floor`` (m/s,
    :func:`airborne_speed`) more than 90 % of the time - on the ground or hovering - and a
    phrase that says how much."""
    low = float(np.mean(np.asarray(v) < floor))
    return low > 0.9, f"airspeed below {floor:g} m/s for {low:.0%} of it"


def no_forward_flight(fd: FlightData, seg: SegmentSpec) -> tuple[bool | None, str]:
    """Whether ``seg`` holds no forward flight (on the ground or hovering), and why.

    With airspeed: below :func:`airborne_speed` for more than 90 % of the span. Without it, from the
    altitude: within 2 m of a median within 5 m of 0, and no body rate above 0.3 rad/s.
    None (unknown) when neither channel has samples in the span."""
    if "V" in fd.channels:
        v = _window(fd, "V", seg)
        if v.size:
            return slow_airspeed(v, airborne_speed(fd))
    if "h" in fd.channels:
        h = _window(fd, "h", seg)
        rates = [_window(fd, c, seg) for c in ("p", "q", "r") if c in fd.channels]
        if h.size:
            still = all(r.size == 0 or np.max(np.abs(r)) < 0.3 for r in rates)
            return (
                bool(np.ptp(h) < 2.0 and abs(float(np.median(h))) < 5.0 and still),
                f"altitude within {np.ptp(h):.2f} m of {np.median(h):.2f} m and no rotation",
            )
    return None, ""


def check_segment(
    fd: FlightData, seg: SegmentSpec, *, min_duration: float = 5.0, inputs: Iterable[str] = CONTROL_INPUTS
) -> list[Finding]:
    """Duration, ground-only data and excitation of each control axis in one segment."""
    out: list[Finding] = []
    label = f"segment {seg.name}"
    if seg.duration < min_duration:
        out.append(
            Finding(
                WARN,
                "segment_duration",
                None,
                f"{label} lasts {seg.duration:.2f} s; maneuvers need >= {min_duration:.0f} s of data",
                seg.t0,
                seg.t1,
                seg.duration,
            )
        )
    else:
        out.append(
            Finding(PASS, "segment_duration", None, f"{label} lasts {seg.duration:.1f} s", seg.t0, seg.t1, seg.duration)
        )
    ground, why = no_forward_flight(fd, seg)
    if ground:
        out.append(
            Finding(
                WARN,
                "ground",
                None,
                f"{label} has no forward flight ({why}): on the ground or hovering; it holds no aircraft flight dynamics",
                seg.t0,
                seg.t1,
            )
        )
    stds = {}
    for ax in inputs:
        if ax in fd.channels:
            x = _window(fd, ax, seg)
            if x.size >= 3:
                stds[ax] = float(np.std(x))
    if stds:
        moved = {k: v for k, v in stds.items() if v >= MIN_EXCITATION_RAD}
        if moved:
            out.append(
                Finding(
                    PASS,
                    "excitation",
                    ",".join(moved),
                    f"{label}: excited " + ", ".join(f"{k} (std {np.degrees(v):.2f} deg)" for k, v in moved.items()),
                    seg.t0,
                    seg.t1,
                    max(moved.values()),
                )
            )
        else:
            out.append(
                Finding(
                    WARN,
                    "excitation",
                    None,
                    f"{label}: no control axis is moved "
                    f"(largest std {np.degrees(max(stds.values())):.2f} deg, want >= "
                    f"{np.degrees(MIN_EXCITATION_RAD):.0f} deg); nothing to identify here",
                    seg.t0,
                    seg.t1,
                    max(stds.values()),
                )
            )
        if seg.axis and seg.axis in stds and stds[seg.axis] < MIN_EXCITATION_RAD:
            out.append(
                Finding(
                    WARN,
                    "excitation",
                    seg.axis,
                    f"{label}: its own axis {seg.axis} hardly moves (std {np.degrees(stds[seg.axis]):.2f} deg)",
                    seg.t0,
                    seg.t1,
                    stds[seg.axis],
                )
            )
    return out


def run_checks(
    fd: FlightData, segments: Sequence[SegmentSpec] | None = None, required: Sequence[str] = CORE
) -> list[Finding]:
    """Every check on ``fd``; segments default to ``fd.segments`` (or the whole log)."""
    out = check_file(fd, required)
    for name, ch in fd.channels.items():
        out.extend(check_channel(name, np.asarray(ch.t, float), np.asarray(ch.values, float)))
        if getattr(ch, "notes", ""):
            out.append(Finding(WARN, "units", name, f"{name}: {ch.notes}"))
    segs = list(segments if segments is not None else fd.segments)
    if not segs:
        lo, hi = fd.span
        if np.isfinite(lo):
            segs = [SegmentSpec("whole_log", lo, hi, "time")]
    out = [_between_maneuvers(f, fd, segs) if f.check == "gaps" and f.status == WARN else f for f in out]
    for s in segs:
        out.extend(check_segment(fd, s))
    excited = {f.channel for f in out if f.check == "excitation" and f.status == PASS}
    excited = {a for c in excited for a in (c or "").split(",")}
    for ax in CONTROL_INPUTS:
        if ax in fd.channels and ax not in excited:
            out.append(
                Finding(
                    WARN,
                    "excitation",
                    ax,
                    f"{ax} is never moved enough in any segment "
                    f"(std >= {np.degrees(MIN_EXCITATION_RAD):.0f} deg); the derivatives "
                    f"of {ax} cannot be identified from this log",
                )
            )
    out.extend(check_kinematics(fd))
    return out


def _between_maneuvers(f: Finding, fd: FlightData, segs: Sequence[SegmentSpec]) -> Finding:
    """A ``gaps`` finding passed when every gap of its channel lies outside the maneuver
    windows ``segs``: the logger paused between maneuvers (segment boundaries), nothing is
    missing from what is fitted."""
    gaps = fd[f.channel].gaps() if f.channel in fd.channels else []
    dt = typical_interval(fd[f.channel].t) if gaps else 0.0  # a window may end between two samples
    if not gaps or any(a + dt < s.t1 and b - dt > s.t0 for a, b in gaps for s in segs):
        return f
    return replace(f, status=PASS, message=f"{f.message}; all between the maneuvers (pauses in logging)")


def summarize(findings: Sequence[Finding]) -> dict[str, int]:
    """Counts per status."""
    c = {PASS: 0, WARN: 0, FAIL: 0}
    for f in findings:
        c[f.status] = c.get(f.status, 0) + 1
    return c


def findings_to_json(findings: Sequence[Finding], fd: FlightData | None = None, extra: dict | None = None) -> str:
    """The ``checks.json`` document: summary, findings, and (with ``fd``) the file's facts."""
    doc: dict = {"summary": summarize(findings), "findings": [f.as_dict() for f in findings]}
    if fd is not None:
        doc["source"] = {
            "path": fd.meta.get("source"),
            "format": fd.meta.get("format"),
            "map": fd.meta.get("map"),
            "time_base": fd.meta.get("time_base"),
            "start": start_statement(fd.meta) or None,
            "t0_abs": fd.meta.get("t0_abs"),
            "t0_kind": fd.meta.get("t0_kind"),
            "damage": fd.meta.get("damage"),
            "channels": {
                k: {"samples": len(c), "rate_hz": c.rate_hz, "unit": c.unit, "source": c.source}
                for k, c in fd.channels.items()
            },
            "missing": fd.meta.get("unmapped", {}),
            "modes": [[float(t), m] for t, m in fd.modes],
            "segments": [s.as_dict() for s in fd.segments],
            "n_params": len(fd.params),
        }
    if extra:
        doc.update(extra)
    return json.dumps(doc, indent=2, default=_default)


def _default(o):
    if isinstance(o, (np.floating, np.integer)):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    return str(o)
