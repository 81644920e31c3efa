"""Whether each axis of a flight can be identified with the built-in models, and exactly why
not: the bottom line of ``fsid check`` and the reasons ``fsid estimate`` refuses with.

One function decides (:func:`identifiability`); both commands call it, so they never tell
different stories. Per axis (longitudinal, lateral) it asks what the axis' problem
(:mod:`pipeline.problems.longitudinal`, :mod:`pipeline.problems.lateral`) really needs:

* channels: those the problem reads (:data:`AXIS_NEEDS`), where alpha and beta count as
  present when the flight path can rebuild them
  (:func:`pipeline.conditioning.flow_angles.reconstruct_flow_angles`) and the air density
  is never missing (the rho channel, else ISA at h, else sea level); thrust from a thrust
  channel or throttle times the aircraft's max_thrust;
* forward flight: the airspeed rule of the checks and of the problems' windows
  (:func:`pipeline.conditioning.checks.no_forward_flight`, :func:`~pipeline.conditioning.checks.airborne_speed`:
  5 m/s or the aircraft's stall speed): a log on the ground or
  hovering holds no aircraft flight dynamics, whatever else it lacks;
* sample rates: the channels that carry the axis' fastest mode (the short period, the roll
  mode) at ten samples a period of the fastest motion their own spectra show (up to
  :data:`RESPONSE_HZ`: a small UAV's 2 Hz modes; a business jet's 0.5 Hz modes ask for
  less), the control inputs at :data:`INPUT_HZ`, the slower states at :data:`STATE_HZ`;
* maneuvers: at least ``1 + hold_out`` of the axis' maneuver windows (found from its
  control surfaces, overlapping ones merged) in forward flight with samples of its
  outputs (one fitted, ``hold_out`` held out for the proof of match), enough forward
  flight for them, a surface moved by at least the checks' excitation threshold, and the
  body rate answering it above its noise;
* the data-quality checks' failures on any channel the axis needs (degrees in a radian
  field, time going backwards, mostly NaN).

Channels a reader derives (a pose turned into flight states, an autopilot's angle of
attack) are present like logged ones.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from pipeline.conditioning.checks import (
    FAIL,
    MIN_EXCITATION_RAD,
    Finding,
    airborne_speed,
    no_forward_flight,
    slow_airspeed,
)
from pipeline.conditioning.flow_angles import NEEDS as FLIGHT_PATH_CHANNELS
from pipeline.conditioning.flow_angles import reconstruct_flow_angles
from pipeline.errors import FsidError
from pipeline.ingest.constants import AircraftConstants
from pipeline.ingest.flightdata import ANSWER_RAD_S, MOVED_RAD, FlightData, SegmentSpec, merge_overlapping
from pipeline.ingest.sampling import response_floor_hz

#: the channels carrying the fastest rigid-body mode (short period, roll mode: up to about
#: 2 Hz on light aircraft and small UAVs) need this rate [Hz]: some ten samples a period
#: (the checks' MIN_RATE_HZ)
RESPONSE_HZ = 20.0
#: the control inputs need this rate [Hz]: two samples within the shortest pulse of a
#: maneuver (0.2-0.3 s) so that its steps can be timed from the gyros (10 Hz surfaces
#: are fitted; the margin takes a jittered log)
INPUT_HZ = 8.0
#: the slower states (airspeed, flow angles, attitude) need this rate [Hz]: the fits count
#: only their own samples, a handful per maneuver step
STATE_HZ = 4.0
#: a maneuver window needs this many samples of each output (the problems' window rule)
MIN_OUTPUT_SAMPLES = 10
#: a maneuver lasts about this long [s] (the checks' segment duration)
MANEUVER_S = 5.0
#: the body rate must answer the surface by ANSWER_RAD_S (std) at least, and this many
#: times its white-noise std
RESPONSE_NOISE_RATIO = 3.0
#: the angles the flight path can rebuild
FLOW_ANGLES = ("alpha", "beta")


@dataclass(frozen=True)
class AxisNeeds:
    """What one axis' built-in problem needs: ``channels`` it reads from the log, its
    ``outputs`` (each with samples in every maneuver window), its control ``surfaces``
    (maneuvers are found where they move), the ``response`` channels carrying its fastest
    mode (``mode``: its name with its verb, for messages), the body ``rates`` that must answer the surfaces, and the
    maneuvers' name for messages (``maneuver``)."""

    channels: tuple[str, ...]
    outputs: tuple[str, ...]
    surfaces: tuple[str, ...]
    response: tuple[str, ...]
    rates: tuple[str, ...]
    mode: str
    maneuver: str


#: per axis: the same channels as pipeline.problems' LONG_CHANNELS / LAT_CHANNELS and
#: outputs as LONG_OUTPUTS / LAT_OUTPUTS (the problems layer sits above this one; a test
#: keeps them equal)
AXIS_NEEDS: dict[str, AxisNeeds] = {
    "longitudinal": AxisNeeds(
        channels=("V", "alpha", "theta", "q", "ax", "az", "de"),
        outputs=("V", "alpha", "theta", "q", "ax", "az"),
        surfaces=("de",),
        response=("q", "ax", "az"),
        rates=("q",),
        mode="the short period needs",
        maneuver="elevator",
    ),
    "lateral": AxisNeeds(
        channels=("V", "alpha", "theta", "beta", "p", "r", "phi", "ay", "da", "dr"),
        outputs=("beta", "p", "r", "phi", "ay"),
        surfaces=("da", "dr"),
        response=("p", "r", "ay"),
        rates=("p", "r"),
        mode="the roll mode and the Dutch roll need",
        maneuver="aileron/rudder",
    ),
}


@dataclass(frozen=True)
class Maneuver:
    """One maneuver window of an axis: ``name``, ``t0``..``t1`` [s] on the log's time base,
    the ``surfaces`` moved, the flight ``mode`` at its start (None without modes),
    whether it is in forward flight (``airborne``) with samples of the axis' outputs
    (``usable``), and the largest surface std in it [rad] (``excitation``)."""

    name: str
    t0: float
    t1: float
    surfaces: str
    mode: str | None
    airborne: bool
    usable: bool
    excitation: float

    def as_dict(self) -> dict:
        return {
            "name": self.name,
            "t0": float(self.t0),
            "t1": float(self.t1),
            "surfaces": self.surfaces,
            "mode": self.mode,
            "airborne": self.airborne,
            "usable": self.usable,
            "excitation_deg": round(float(np.degrees(self.excitation)), 3),
        }


@dataclass(frozen=True)
class Identifiability:
    """The bottom line for one axis: ``possible`` or not, the canonical channels
    ``missing`` (absent and not derivable), every ``reason`` it is not possible (one
    sentence each, naming the channels), the axis' ``maneuvers`` and the flight ``modes``
    found in the log ((start [s], name))."""

    axis: str
    possible: bool
    missing: tuple[str, ...] = ()
    reasons: tuple[str, ...] = ()
    maneuvers: tuple[Maneuver, ...] = ()
    modes: tuple[tuple[float, str], ...] = field(default_factory=tuple)
    #: the rate reasons taken as a risk instead (``accept_low_rate``): the estimate goes on
    #: and its report says them
    risks: tuple[str, ...] = ()

    def as_dict(self) -> dict:
        """The checks.json entry of the axis."""
        return {
            "possible": self.possible,
            "missing": list(self.missing),
            "reasons": list(self.reasons),
            "maneuvers": [m.as_dict() for m in self.maneuvers],
            "modes": [{"t0": float(t), "mode": name} for t, name in self.modes],
            **({"risks": list(self.risks)} if self.risks else {}),
        }


def identifiability(
    fd: FlightData,
    findings: Sequence[Finding] = (),
    aircraft: AircraftConstants | None = None,
    *,
    hold_out: int = 1,
    axes: Iterable[str] = tuple(AXIS_NEEDS),
    accept_low_rate: bool = False,
) -> dict[str, Identifiability]:
    """Axis -> :class:`Identifiability` of the flight ``fd`` as the estimate would fit it
    (module docstring), from the data-quality ``findings`` on it and, when given, the
    ``aircraft`` (its max_thrust stands in for a thrust channel). ``hold_out``: maneuvers
    per axis held out for the proof of match (0 with validation flights);
    ``accept_low_rate``: channels slower than they need are a risk (``risks``), not a
    reason the axis cannot be identified (the user's soft limit)."""
    angles = _flow_angles(fd)
    ground, ground_why = no_forward_flight(fd, _whole(fd))
    airborne_s = _airborne_seconds(fd, bool(ground))
    out = {}
    for axis in axes:
        needs = AXIS_NEEDS[axis]
        missing, reasons = _missing(fd, needs, angles, bool(ground), aircraft, axis)
        if ground:
            reasons.insert(0, f"on the ground or hovering over the whole log ({ground_why}): no flight dynamics to fit")
        reasons += _failed_checks(findings, needs, missing)
        rates = _rate_reasons(fd, needs, missing)
        risks = tuple(rates) if accept_low_rate else ()
        reasons += [] if accept_low_rate else rates
        mans = _maneuvers(fd, needs)
        if not (set(needs.surfaces) & set(missing)):
            reasons += _maneuver_reasons(fd, needs, mans, hold_out, airborne_s, bool(ground))
        out[axis] = Identifiability(
            axis, not reasons and not missing, tuple(missing), tuple(reasons), tuple(mans), tuple(fd.modes), risks
        )
    return out


def _whole(fd: FlightData) -> SegmentSpec:
    lo, hi = fd.span
    return SegmentSpec("whole_log", lo, hi, "time")


def _flow_angles(fd: FlightData) -> dict[str, str | None]:
    """Absent alpha/beta -> None when the flight path can rebuild it (the estimate's
    air-data-angle stage will), else why not."""
    absent = fd.missing(FLOW_ANGLES)
    if not absent:
        return {}
    lacking = fd.missing(FLIGHT_PATH_CHANNELS)
    if lacking:
        why = f"no vane, and the flight path lacks {', '.join(lacking)} to rebuild it from"
    else:
        try:
            reconstruct_flow_angles(fd)
            why = None
        except FsidError as exc:
            why = f"cannot be rebuilt from the flight path: {exc}"
    return dict.fromkeys(absent, why)


def _missing(
    fd: FlightData,
    needs: AxisNeeds,
    angles: Mapping[str, str | None],
    ground: bool,
    aircraft: AircraftConstants | None,
    axis: str,
) -> tuple[list[str], list[str]]:
    """(channels the axis needs that are absent and cannot be derived, a reason for each);
    an angle the flight path could rebuild but for the forward flight a grounded log lacks
    is not missing: the ground is the reason."""
    why = fd.explain_missing(needs.channels)
    missing, reasons = [], []
    for ch in needs.channels:
        if ch in angles:
            if angles[ch] is None or (ground and not fd.missing(FLIGHT_PATH_CHANNELS)):
                continue
            missing.append(ch)
            reasons.append(f"{ch} missing: {why.get(ch, 'not in the log')}; {angles[ch]}")
        elif ch in why:
            missing.append(ch)
            reasons.append(f"{ch} missing: {why[ch]} (map it with --map)")
    if axis == "longitudinal" and "thrust" not in fd:
        if "throttle" not in fd:
            missing.append("thrust")
            reasons.append(
                "thrust missing: the log has neither a thrust nor a throttle channel (throttle x the "
                "aircraft's [propulsion] max_thrust_N stands in for thrust)"
            )
        elif aircraft is not None and not aircraft.max_thrust:
            reasons.append(
                "thrust unknown: the log has throttle but no thrust channel, and the aircraft file gives "
                "no [propulsion] max_thrust_N to turn throttle into thrust"
            )
    return missing, reasons


def _failed_checks(findings: Sequence[Finding], needs: AxisNeeds, missing: Sequence[str]) -> list[str]:
    """The data-quality failures on channels the axis needs (once per message)."""
    need = set(needs.channels) - set(missing)
    seen = dict.fromkeys(f.message for f in findings if f.status == FAIL and f.channel in need)
    return [f"data-quality check failed: {m}" for m in seen]


def _rate(fd: FlightData, ch: str) -> float:
    """The native rate [Hz] of ``ch``, or of the inertial velocity it will be rebuilt from."""
    if ch in fd:
        return fd[ch].rate_hz
    return fd["vn"].rate_hz if ch in FLOW_ANGLES and "vn" in fd else float("nan")


def response_floors(fd: FlightData, channels: Sequence[str]) -> dict[str, float]:
    """Channel -> the rate [Hz] it needs to carry the aircraft's motion it shows
    (:func:`pipeline.ingest.sampling.response_floor_hz`: ten samples a period of its
    fastest motion, at most RESPONSE_HZ, at least STATE_HZ)."""
    return {
        c: response_floor_hz(fd[c].t, fd[c].values, RESPONSE_HZ, STATE_HZ)
        for c in channels
        if c in fd and len(fd[c]) > 1
    }


def _rate_reasons(fd: FlightData, needs: AxisNeeds, missing: Sequence[str]) -> list[str]:
    """A reason per class of needed channels sampled too slowly for what they must show
    (the response channels: for the motion their own spectra show, :func:`response_floors`)."""
    present = [c for c in needs.channels if c not in missing]
    floors = response_floors(fd, [c for c in needs.response if c in present])
    slow = {c: (_rate(fd, c), floors[c]) for c in floors if _rate(fd, c) < floors[c]}
    out = []
    if slow:
        listed = ", ".join(f"{c} {r:.1f} Hz (needs {need:.1f})" for c, (r, need) in slow.items())
        out.append(
            f"rate too low: {listed}; {needs.mode} them at ten samples a period of the motion they show "
            f"(up to {RESPONSE_HZ:g} Hz; telemetry is usually too slow: use the onboard log)"
        )
    classes = (
        (needs.surfaces, INPUT_HZ, f"a maneuver's steps need the control inputs at >= {INPUT_HZ:g} Hz"),
        (
            [c for c in present if c not in needs.response and c not in needs.surfaces],
            STATE_HZ,
            f"the maneuvers' response needs the states at >= {STATE_HZ:g} Hz",
        ),
    )
    for chans, floor, what in classes:
        slow_c = {c: _rate(fd, c) for c in chans if c in present and _rate(fd, c) < floor}
        if slow_c:
            out.append(f"rate too low: {', '.join(f'{c} {r:.1f} Hz' for c, r in slow_c.items())}; {what}")
    return out


def _samples(fd: FlightData, ch: str, t0: float, t1: float) -> np.ndarray:
    """The finite samples of ``ch`` within ``t0``..``t1`` [s]."""
    c = fd[ch]
    v = np.asarray(c.values, dtype=float)[(c.t >= t0) & (c.t <= t1)]
    return v[np.isfinite(v)]


def _mode_at(fd: FlightData, t: float) -> str | None:
    before = [name for ts, name in sorted(fd.modes) if ts <= t]
    return before[-1] if before else None


def _maneuvers(fd: FlightData, needs: AxisNeeds) -> list[Maneuver]:
    """The axis' maneuver windows as the problems cut them: the found segments of its
    surfaces, overlapping ones merged; each in forward flight or not (the problems' window
    rule; a window given by time counts as given), with samples of the outputs or not, and
    its largest surface std."""
    specs = merge_overlapping([s for s in fd.segments if s.axis in needs.surfaces])
    out = []
    for s in specs:
        if s.kind == "time":  # a window given by time is fitted as given (the problems' rule)
            airborne = True
        elif "V" in fd and _samples(fd, "V", s.t0, s.t1).size:
            airborne = not slow_airspeed(_samples(fd, "V", s.t0, s.t1), airborne_speed(fd))[0]
        else:
            airborne = no_forward_flight(fd, s)[0] is not True
        usable = all(_samples(fd, c, s.t0, s.t1).size >= MIN_OUTPUT_SAMPLES for c in needs.outputs if c in fd)
        stds = [float(np.std(x)) for c in needs.surfaces if c in fd and (x := _samples(fd, c, s.t0, s.t1)).size >= 3]
        out.append(Maneuver(s.name, s.t0, s.t1, s.axis or "", _mode_at(fd, s.t0), airborne, usable, max(stds or [0])))
    return out


def _airborne_seconds(fd: FlightData, ground: bool) -> float:
    """Seconds of forward flight: where the airspeed is at least :func:`airborne_speed`
    (the whole log without airspeed, unless it is on the ground)."""
    if ground:
        return 0.0
    if "V" not in fd or len(fd["V"]) < 2:
        lo, hi = fd.span
        return float(hi - lo) if np.isfinite(lo) else 0.0
    t, v = np.asarray(fd["V"].t, float), np.asarray(fd["V"].values, float)
    dt = np.diff(t)
    floor = airborne_speed(fd)
    fast = (v[:-1] >= floor) & (v[1:] >= floor)
    return float(np.sum(np.where(fast, np.minimum(dt, 1.0), 0.0)))


def _maneuver_reasons(
    fd: FlightData, needs: AxisNeeds, mans: Sequence[Maneuver], hold_out: int, airborne_s: float, ground: bool
) -> list[str]:
    """Too short, too few maneuvers in forward flight, no excitation, no response."""
    need = 1 + hold_out
    word = (
        f"{need} maneuvers (one fitted, {'one' if hold_out == 1 else hold_out} held out for the proof of match)"
        if hold_out
        else "a maneuver"
    )
    out = []
    lo, hi = fd.span
    short = bool(np.isfinite(lo) and (hi - lo) < need * MANEUVER_S)
    if short:
        out.append(f"too short: the log spans {hi - lo:.1f} s; {word} need >= {need * MANEUVER_S:g} s")
    if not mans:
        return out + [_no_maneuvers(fd, needs)]
    good = [m for m in mans if m.airborne and m.usable]
    if len(good) < need:
        if not (short or ground) and airborne_s < need * MANEUVER_S:
            out.append(
                f"too short: {airborne_s:.1f} s of forward flight (airspeed >= {airborne_speed(fd):g} m/s); "
                f"{word} need >= {need * MANEUVER_S:g} s"
            )
        grounded = sum(not m.airborne for m in mans)
        gaps = sum(m.airborne and not m.usable for m in mans)
        parts = [f"{grounded} on the ground or hovering"] * bool(grounded) + [
            f"{gaps} with too few samples of {', '.join(needs.outputs)}"
        ] * bool(gaps)
        out.append(
            f"too few maneuvers: {len(good)} of {len(mans)} {needs.maneuver} maneuvers usable"
            + (f" ({'; '.join(parts)})" if parts else "")
            + f", need {word}: fly more in forward flight"
        )
    if good:
        out += _excitation_reasons(fd, needs, good)
    return out


def _no_maneuvers(fd: FlightData, needs: AxisNeeds) -> str:
    """Why the axis has no maneuver: its surfaces move in segments that carry no control
    axis (windows a log or a user named; the fits take a window's axes from the surfaces
    found moving), or they never move like a maneuver."""
    surf = "/".join(needs.surfaces)
    moved = {
        s.name: std
        for s in fd.segments
        if s.axis is None
        and (
            std := max(
                (float(np.std(x)) for c in needs.surfaces if c in fd and (x := _samples(fd, c, s.t0, s.t1)).size >= 3),
                default=0.0,
            )
        )
        >= MIN_EXCITATION_RAD
    }
    if moved:
        names = ", ".join(list(moved)[:3]) + (f" and {len(moved) - 3} more" if len(moved) > 3 else "")
        return (
            f"no {needs.maneuver} maneuvers found: {surf} {'moves' if len(needs.surfaces) == 1 else 'move'} in the log's windows {names} (std up to "
            f"{np.degrees(max(moved.values())):.1f} deg), but they carry no control axis: give them as time "
            "ranges (--segments T0:T1,...) and their axes are found from the surfaces moved"
        )
    idle = [s for s in fd.segments if s.kind == "time" and s.axis is None]
    if idle:
        names = ", ".join(f"{s.name} ({s.t0:.1f}-{s.t1:.1f} s)" for s in idle[:3]) + (
            f" and {len(idle) - 3} more" if len(idle) > 3 else ""
        )
        return (
            f"no {needs.maneuver} maneuvers found: the windows given, {names}, move no control input by "
            f"{np.degrees(MOVED_RAD):.1f} deg (std) and no body rate by {np.degrees(ANSWER_RAD_S):.1f} deg/s, "
            "so no axis takes them: give windows where the aircraft is maneuvered"
        )
    return (
        f"no excitation: {surf} never {'moves' if len(needs.surfaces) == 1 else 'move'} like a maneuver "
        f"(no {needs.maneuver} maneuvers found); fly doublets or 3-2-1-1s on the axis"
    )


def _excitation_reasons(fd: FlightData, needs: AxisNeeds, good: Sequence[Maneuver]) -> list[str]:
    """Some usable maneuver excites the axis - its surface moves by MIN_EXCITATION_RAD, or
    a body rate answers by :func:`_response`'s floor (a pulse and the free motion after it:
    the surface's std over the window is small, the aircraft's response is not) - and a
    body rate answers a maneuver whose surface moved."""
    surf = "/".join(needs.surfaces)
    floors = response_floors(fd, needs.rates)
    rates = [c for c in needs.rates if c in floors and fd[c].rate_hz >= floors[c]]
    response = {m.name: _response(fd, m, rates) for m in good}
    moved = [m for m in good if m.excitation >= MIN_EXCITATION_RAD or response[m.name] >= 1.0]
    if not moved:
        answer = f" and {', '.join(rates)} {max(response.values()):.1f}x the response floor" if rates else ""
        return [
            f"no excitation: {surf} moves by at most {np.degrees(max(m.excitation for m in good)):.2f} deg (std)"
            f"{answer} in its maneuvers in flight; want >= {np.degrees(MIN_EXCITATION_RAD):.0f} deg, or a body "
            f"rate of >= {np.degrees(ANSWER_RAD_S):.1f} deg/s and {RESPONSE_NOISE_RATIO:g}x its noise"
        ]
    if not rates:  # absent, or too slow to tell a response from noise: said already
        return []
    if max(response[m.name] for m in moved) >= 1.0:
        return []
    return [
        f"no response: {', '.join(rates)} hardly move in the {surf} maneuvers (std below "
        f"{np.degrees(ANSWER_RAD_S):.1f} deg/s or {RESPONSE_NOISE_RATIO:g}x its noise): the surface "
        "does not act on the aircraft (on the ground, or not connected)"
    ]


def _response(fd: FlightData, m: Maneuver, rates: Sequence[str]) -> float:
    """The largest std of the body rates ``rates`` in maneuver ``m`` over their floor
    (ANSWER_RAD_S, or RESPONSE_NOISE_RATIO times the rate's white noise): >= 1 when
    the aircraft answers; 0 without rates to tell."""
    best = 0.0
    for c in rates:
        x = _samples(fd, c, m.t0, m.t1)
        if x.size < 4:
            continue
        noise = fd.noise_std(c, [(m.t0, m.t1)])
        floor = max(ANSWER_RAD_S, RESPONSE_NOISE_RATIO * (noise if np.isfinite(noise) else 0.0))
        best = max(best, float(np.std(x)) / floor)
    return best


def identifiability_json(result: Mapping[str, Identifiability]) -> dict:
    """checks.json's ``identifiability``: axis -> possible, missing, reasons, maneuvers, modes."""
    return {axis: r.as_dict() for axis, r in result.items()}


def reason_lines(result: Mapping[str, Identifiability], axes: Iterable[str] | None = None) -> list[str]:
    """One line per reason an axis of ``axes`` (default all) is not identifiable:
    "<axis>: <reason>"."""
    return [f"{a}: {why}" for a in axes or result for why in result[a].reasons if not result[a].possible]


def bottom_line(result: Mapping[str, Identifiability]) -> list[str]:
    """The lines ``fsid check`` ends with: per axis identifiable or not and why, the
    maneuvers found, the flight modes."""
    lines = []
    for axis, r in result.items():
        good = [m for m in r.maneuvers if m.airborne and m.usable]
        found = f"{len(good)} of {len(r.maneuvers)} {AXIS_NEEDS[axis].maneuver} maneuvers usable"
        lines.append(f"  {axis}: {'identifiable' if r.possible else 'NOT identifiable'} ({found})")
        lines += [f"    - {why}" for why in r.reasons]
        lines += [
            f"    maneuver {m.name} {m.t0:.2f}-{m.t1:.2f} s ({m.surfaces}"
            + (f", mode {m.mode}" if m.mode else "")
            + f", {'in flight' if m.airborne else 'on the ground or hovering'}"
            + f", std {np.degrees(m.excitation):.1f} deg)"
            for m in r.maneuvers
        ]
    modes = next(iter(result.values())).modes if result else ()
    lines.append("  flight modes: " + (", ".join(f"{name} from {t:.2f} s" for t, name in modes) or "none logged"))
    return lines


def identifiability_findings(result: Mapping[str, Identifiability]) -> list[Finding]:
    """A failed data-quality finding per axis that cannot be identified, so a check of a log
    that cannot be identified never ends '0 fail'."""
    return [
        Finding(FAIL, "identifiability", None, f"the {axis} axis cannot be identified: " + "; ".join(r.reasons))
        for axis, r in result.items()
        if not r.possible
    ]


def identifiable_axes(result: Mapping[str, Identifiability], axes: Sequence[str], where: str) -> tuple[str, ...]:
    """Those of ``axes`` that can be identified; FsidError with every reason, one line each,
    when none can (``where``: the log, for the message)."""
    ok = tuple(a for a in axes if result[a].possible)
    if not ok:
        raise FsidError(
            (
                f"no axis of {where} can be identified"
                if len(axes) > 1
                else f"the {axes[0]} axis of {where} cannot be identified"
            )
            + ":\n  "
            + "\n  ".join(reason_lines(result, axes))
        )
    return ok
