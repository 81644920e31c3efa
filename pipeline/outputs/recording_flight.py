"""The whole flight in a recording (check.rrd, and run.rrd beside the fits): every canonical
channel on the ``t`` time line in seconds from the log's start, the flight modes and the
maneuver windows as state tracks, the data-quality findings as a text log at their times,
and one document saying what ``t = 0`` is (layout in the module doc of
:mod:`pipeline.outputs.recording`)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from pipeline.conditioning.checks import Finding, summarize
from pipeline.ingest.flightdata import FlightData, SegmentSpec
from pipeline.ingest.sampling import utc_text
from pipeline.outputs.recording_layout import entity_part
from pipeline.outputs.recording_series import SeriesWriter

#: channels faster than this [Hz] are thinned for display: per bin of samples its minimum
#: and maximum are kept (peaks, spikes and clipping stay visible), at most this many
#: points per second
DISPLAY_MAX_HZ = 200.0
#: the state shown on ``/flight/mode`` when the log records no flight modes
NO_MODES = "no modes logged"
#: canonical channels by the panel they are plotted in (others go to "other")
CHANNEL_GROUPS: dict[str, tuple[str, ...]] = {
    "specific force": ("ax", "ay", "az"),
    "body rates": ("p", "q", "r"),
    "angular accelerations": ("pdot", "qdot", "rdot"),
    "Euler angles": ("phi", "theta", "psi"),
    "quaternion": ("q_w", "q_x", "q_y", "q_z"),
    "airspeed": ("V",),
    "flow angles": ("alpha", "beta"),
    "air-relative velocity": ("u", "v", "w"),
    "inertial velocity": ("vn", "ve", "vd"),
    "altitude": ("h",),
    "position": ("x_n", "y_e", "z_d"),
    "dynamic pressure": ("qbar",),
    "air density": ("rho",),
    "control surfaces": ("de", "da", "dr"),
    "throttle": ("throttle",),
    "thrust": ("thrust",),
}
#: colours of the channels of a group, in order (x y z like red green blue)
_GROUP_COLORS = [(214, 39, 40), (44, 160, 44), (31, 119, 180), (148, 103, 189)]
#: the text-log level of a finding's status
FINDING_LEVELS = {"pass": "INFO", "warn": "WARN", "fail": "ERROR"}
#: the kinds of segment that are maneuver windows (a mode segment is a flight mode)
WINDOW_KINDS = ("auto", "time")


@dataclass
class FlightRecord:
    """What a recording shows of the whole flight.

    data: the flight as ingested (canonical channels on the log's time base, its modes in
    ``meta["modes"]`` and the maneuver windows found in ``segments``); findings: the
    data-quality checks made on it (:func:`pipeline.conditioning.checks.run_checks`);
    plan: the maneuvers as designed, when known (a simulated flight's plan: name, axis and
    span on the log's own clock, moved as the reader moved the data: less
    ``meta["t0_abs"]``), shown beside the windows found.
    """

    data: FlightData
    findings: Sequence[Finding] = field(default_factory=list)
    plan: Sequence[SegmentSpec] = field(default_factory=list)

    @property
    def origin(self) -> float:
        """The log's start on its own time base [s]: ``t = 0`` of the recording. The
        first sample of any channel (NaN for a flight without samples)."""
        return float(self.data.span[0])

    @property
    def duration(self) -> float:
        """Seconds from the first to the last sample (0 without samples)."""
        lo, hi = self.data.span
        return float(hi - lo) if np.isfinite(lo) else 0.0

    def windows(self) -> list[SegmentSpec]:
        """The maneuver windows: found from control activity or given by time, in time order."""
        return sorted((s for s in self.data.segments if s.kind in WINDOW_KINDS), key=lambda s: s.t0)


def planned_maneuvers(maneuvers: Sequence[tuple[str, str, float, float]]) -> list[SegmentSpec]:
    """A flight plan's maneuvers ((name, axis, t_start, t_end [s]), as a simulated flight
    lists them) as spans for :attr:`FlightRecord.plan`."""
    return [SegmentSpec(str(n), float(a), float(b), "plan", axis=str(ax)) for n, ax, a, b in maneuvers]


def channel_group(name: str) -> str:
    """The panel a channel is plotted in (:data:`CHANNEL_GROUPS`, else "other")."""
    return next((g for g, names in CHANNEL_GROUPS.items() if name in names), "other")


def display_samples(t: np.ndarray, v: np.ndarray, max_hz: float = DISPLAY_MAX_HZ) -> tuple[np.ndarray, np.ndarray]:
    """A channel's finite samples (times t [s], values v, shapes (n,)) in time order, thinned
    when faster than ``max_hz``: each bin of k samples keeps its minimum and maximum (in
    their order), so at most ``max_hz`` points per second are left."""
    t, v = np.asarray(t, dtype=float), np.asarray(v, dtype=float)
    ok = np.isfinite(t) & np.isfinite(v)
    t, v = t[ok], v[ok]
    if t.size > 1 and np.any(np.diff(t) < 0):
        order = np.argsort(t, kind="stable")
        t, v = t[order], v[order]
    rate = points_per_second(t)
    if rate <= max_hz:
        return t, v
    k = math.ceil(2.0 * rate / max_hz)
    m = t.size // k
    body = v[: m * k].reshape(m, k)
    pick = np.sort(np.stack([body.argmin(axis=1), body.argmax(axis=1)], axis=1), axis=1)
    idx = (pick + (np.arange(m) * k)[:, None]).ravel()
    idx = np.concatenate([idx[np.r_[True, np.diff(idx) > 0]], np.arange(m * k, t.size)])
    return t[idx], v[idx]


def points_per_second(t: np.ndarray) -> float:
    """Finite samples per second over their span (0 for fewer than two): what decides the
    thinning for display (a bursty channel's median interval would overstate it)."""
    t = np.asarray(t, dtype=float)
    t = t[np.isfinite(t)]
    span = float(t.max() - t.min()) if t.size > 1 else 0.0
    return (t.size - 1) / span if span > 0 else 0.0


def absolute_start(fd: FlightData, origin: float) -> str:
    """One sentence: what ``t = 0`` of the recording (``origin`` [s] on the flight's time
    base) is on the log's own clock: from ``meta["t0_abs"]`` and ``meta["t0_kind"]`` when
    the reader moved the times to the log's start (a calendar time for "epoch UTC"), else
    the time base itself (a calendar time when it counts from 1970)."""
    tb = str(fd.meta.get("time_base") or "the log's time base")
    if not np.isfinite(origin):
        return "the log holds no samples"
    t_abs, kind = fd.meta.get("t0_abs"), str(fd.meta.get("t0_kind") or "")
    if isinstance(t_abs, (int, float)) and np.isfinite(t_abs):
        at = float(t_abs) + origin
        if "epoch" in kind.lower() or "utc" in kind.lower():
            return f"t = 0 is the log's first sample, {_utc(at)} ({at:.6f} s Unix epoch)"
        return f"t = 0 is the log's first sample, {at:.6f} s on the log's own clock ({kind or tb})"
    text = f"t = 0 is the log's first sample, {origin:.6f} s on its time base ({tb})"
    if ("1970" in tb or "epoch" in tb.lower()) and origin > 1e8:
        return f"{text}: {_utc(origin)}"
    return text


def _utc(seconds: float) -> str:
    """Seconds since 1970 as an ISO UTC time to the millisecond (or said to be beyond any
    calendar date)."""
    return utc_text(seconds, "milliseconds") or "beyond any calendar date (a damaged time stamp?)"


def write_flight(w: SeriesWriter, flight: FlightRecord) -> None:
    """The whole flight into the recording of SeriesWriter ``w``: ``/flight/info``, every
    channel under ``/flight/channels``, ``/flight/mode``, ``/flight/maneuvers/<axis>`` and
    ``/flight/findings`` (one send_columns call per entity)."""
    fd, t0 = flight.data, flight.origin
    if not np.isfinite(t0):
        t0 = 0.0
    w.text("/flight/info", flight_info(flight))
    groups = flight_groups(flight)
    for name, ch in fd.channels.items():
        t, v = display_samples(ch.t, ch.values)
        color = _GROUP_COLORS[groups[channel_group(name)].index(name) % len(_GROUP_COLORS)]
        w.series(f"/flight/channels/{entity_part(name)}", v, t=t - t0, name=f"{name} [{ch.unit or '-'}]", color=color)
    modes = sorted(fd.modes, key=lambda m: m[0])
    if modes:
        w.states("/flight/mode", [max(float(a) - t0, 0.0) for a, _ in modes], [str(m) for _, m in modes])
    else:
        w.states("/flight/mode", [0.0], [NO_MODES])
    write_tracks(w, "/flight/maneuvers", flight.windows(), t0)
    write_tracks(w, "/flight/plan", flight.plan, t0 + float(fd.meta.get("t0_abs") or 0.0))
    if flight.findings:
        at = [f.t0 - t0 if f.t0 is not None and np.isfinite(f.t0) else 0.0 for f in flight.findings]
        w.events(
            "/flight/findings",
            at,
            [finding_text(f, t0) for f in flight.findings],
            [FINDING_LEVELS.get(f.status, "INFO") for f in flight.findings],
        )


def write_tracks(w: SeriesWriter, base: str, specs: Sequence[SegmentSpec], origin: float = 0.0) -> None:
    """Spans (times [s] less ``origin``) as state tracks ``<base>/<track>`` (:func:`lanes`):
    each span's name from its start, an empty state at its end."""
    for track, lane in lanes(sorted(specs, key=lambda s: s.t0)).items():
        times = [x for s in lane for x in (s.t0 - origin, s.t1 - origin)]
        w.states(f"{base}/{track}", times, [x for s in lane for x in (s.name, None)])


def finding_text(f: Finding, origin: float) -> str:
    """One finding as a line: status, check, channel, message and its span in s from the
    log's start."""
    where = ""
    if f.t0 is not None and np.isfinite(f.t0):
        t1 = f.t1 if f.t1 is not None and np.isfinite(f.t1) else f.t0
        where = f" [{f.t0 - origin:.2f} s]" if t1 == f.t0 else f" [{f.t0 - origin:.2f}-{t1 - origin:.2f} s]"
    return f"{f.status.upper()} {f.check}{' ' + f.channel if f.channel else ''}: {f.message}{where}"


def flight_info(flight: FlightRecord) -> str:
    """The ``/flight/info`` document (markdown): the log, what t = 0 is, the channels with
    their rates and sources, the flight modes, the maneuver windows, the findings' counts."""
    fd, t0 = flight.data, flight.origin
    z = t0 if np.isfinite(t0) else 0.0
    lines = [
        "# The flight",
        "",
        f"- log: `{fd.meta.get('source', '?')}` ({fd.meta.get('format', '?')}, map {fd.meta.get('map', '?')})",
        f"- {absolute_start(fd, t0)}; times on `t` are seconds from it",
        f"- duration: {flight.duration:.2f} s",
        "",
        "## Channels (`/flight/channels/<name>`, SI units)",
        "",
        "| channel | unit | samples | rate [Hz] | source | shown |",
        "|---|---|---|---|---|---|",
    ]
    for name, ch in fd.channels.items():
        thin = points_per_second(ch.t) > DISPLAY_MAX_HZ
        shown = f"min/max per bin, <= {DISPLAY_MAX_HZ:g} points/s" if thin else "every sample"
        lines.append(f"| {name} | {ch.unit or '-'} | {len(ch)} | {ch.rate_hz:.2f} | {ch.source} | {shown} |")
    lines += ["", "## Flight modes (`/flight/mode`)", ""]
    if fd.modes:
        lines += ["| from [s] | mode |", "|---|---|"]
        lines += [f"| {float(a) - z:.2f} | {m} |" for a, m in sorted(fd.modes, key=lambda m: m[0])]
    else:
        lines.append(f"The log records no flight modes: the track holds '{NO_MODES}'.")
    lines += ["", "## Maneuver windows (`/flight/maneuvers/<axis>`)", ""]
    wins = flight.windows()
    if wins:
        lines += ["| window | axis | from [s] | to [s] | duration [s] |", "|---|---|---|---|---|"]
        lines += [
            f"| {s.name} | {s.axis or s.kind} | {s.t0 - z:.2f} | {s.t1 - z:.2f} | {s.duration:.2f} |" for s in wins
        ]
    else:
        lines.append("No maneuver windows found (no control input moved).")
    if flight.plan:
        lines += ["", "## Maneuvers as designed (`/flight/plan/<axis>`)", ""]
        lines += ["| maneuver | axis | from [s] | to [s] |", "|---|---|---|---|"]
        lines += [
            f"| {s.name} | {s.axis} | {s.t0 - z:.2f} | {s.t1 - z:.2f} |"
            for s in sorted(flight.plan, key=lambda s: s.t0)
        ]
    c = summarize(flight.findings)
    lines += [
        "",
        "## Data-quality findings (`/flight/findings`)",
        "",
        f"{c['pass']} pass, {c['warn']} warn, {c['fail']} fail; each at its start time "
        "(the flight's start when it has none), level INFO / WARN / ERROR.",
    ]
    return "\n".join(lines) + "\n"


def flight_groups(flight: FlightRecord) -> dict[str, list[str]]:
    """Panel name -> the flight's channels plotted in it, in :data:`CHANNEL_GROUPS` order."""
    out: dict[str, list[str]] = {}
    names = list(flight.data.channels)
    for g in [*CHANNEL_GROUPS, "other"]:
        members = [n for n in names if channel_group(n) == g]
        if members:
            out[g] = members
    return out


def window_tracks(flight: FlightRecord) -> dict[str, list[SegmentSpec]]:
    """The maneuver windows found by track (entity part): :func:`lanes` of
    :meth:`FlightRecord.windows` (``time`` for windows given by time)."""
    return lanes(flight.windows())


def plan_tracks(flight: FlightRecord) -> dict[str, list[SegmentSpec]]:
    """The designed maneuvers by track (entity part): :func:`lanes` of ``flight.plan``."""
    return lanes(sorted(flight.plan, key=lambda s: s.t0))


def lanes(specs: Sequence[SegmentSpec]) -> dict[str, list[SegmentSpec]]:
    """Time-ordered spans by track, in order of their first span: one per control axis
    (its kind without one); a span overlapping an earlier one on its track goes to the next
    track of that axis (``<axis>_2``, ...), so each span ends where it ends."""
    by_axis: dict[str, list[list[SegmentSpec]]] = {}
    for s in specs:
        axis = by_axis.setdefault(entity_part(s.axis or s.kind), [])
        lane = next((x for x in axis if x[-1].t1 <= s.t0), None)
        if lane is None:
            axis.append(lane := [])
        lane.append(s)
    return {(a if k == 0 else f"{a}_{k + 1}"): lane for a, axis in by_axis.items() for k, lane in enumerate(axis)}
