"""Control inputs logged more slowly than the fit's grid: the unknown time of each step.

A log's surface positions are often slower than its IMU (ArduPilot's RCOU at 10-25 Hz
beside a 50-400 Hz IMU). The fits read an input between its samples by linear
interpolation. For a smooth input (a sweep, a multisine, a pilot's stick) that is close
to the truth. A step (a doublet, a 3-2-1-1 flown by the flight computer) happened at an
unknown time between the two samples that bracket it: the linear ramp between them is
its expectation when that time is uniform over the interval (std h / sqrt(12), h the
sample interval), but each step keeps its own timing error, and output error, which
takes the inputs as exact, books those errors on the derivatives with a Cramér-Rao bound
that knows nothing of them.

This module finds those steps (:func:`step_edges`), times them from the gyro rates
(:func:`refine_steps`: a step of a surface is a step of angular acceleration, a kink in the
rates, which shows in the samples after it also when the gyros are as slow as the inputs)
and moves them in a log
(:func:`with_edges_moved`), so :func:`pipeline.uncertainty.consider.input_sampling` can
carry the remaining timing uncertainty to the estimates as a consider part, by refits, as
it carries the sensor corrections' and the wind's. :func:`time_steps` runs it on a log as
it is read (``fsid run``, ``fsid estimate`` and their validation flights).

A step is a sample-to-sample change of a control input that stands out: at least
``STEP_RATIO`` times both neighbouring changes and at least ``MIN_STEP_RAD``; only changes
over an interval longer than ``SLOW_FACTOR`` fit-grid steps (at the grid's rate the
interpolation puts a step within one grid step of where it was) or than
``COARSE_INTERVAL_S`` (a 25 Hz log throughout) count.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace

import numpy as np

from estimators.model import Segment
from estimators.statistics import difference_noise_std
from pipeline.ingest.flightdata import CONTROL_INPUTS, Channel, FlightData, fit_grid_rate

#: where in the range of its time the proof of match puts a step (:func:`timing_variants`)
TIMING_FRACTIONS = (0.0, 0.25, 0.5, 0.75, 1.0)
#: ... the range of a timed step's time: this many std either side
TIMED_RANGE_STD = 2.0
#: a step's change is at least this many times its neighbouring changes ...
STEP_RATIO = 4.0
#: ... and at least this large [rad] (0.2 deg: below any designed maneuver's steps)
MIN_STEP_RAD = np.radians(0.2)
#: an input counts as slow when its sample interval exceeds this many fit-grid steps ...
SLOW_FACTOR = 1.5
#: ... or this many seconds whatever the grid (a 25 Hz log throughout: the fits' grid is the
#: inputs' own, and a step's time within its 40 ms is as unknown)
COARSE_INTERVAL_S = 0.025


@dataclass(frozen=True)
class Edge:
    """One step of control input ``channel`` between its samples ``k`` and ``k + 1``
    (times ``t0``, ``t1`` [s]); ``size`` the change [rad]; ``std`` [s] the uncertainty of
    its time: ``time_std`` when timed, else (t1 - t0) / sqrt(12)."""

    channel: str
    k: int
    t0: float
    t1: float
    size: float
    #: the std of a time refined from the angular rates [s] (:func:`refine_steps`); None: unknown
    #: within the interval
    time_std: float | None = None
    #: the part of ``time_std`` [s] from the kink's model (the spread between its orders):
    #: systematic, alike for the steps of one surface, so carried as one shift of them all
    form_std: float = 0.0

    @property
    def std(self) -> float:
        return self.time_std if self.time_std is not None else (self.t1 - self.t0) / np.sqrt(12.0)

    @property
    def name(self) -> str:
        return f"{self.channel} step at {0.5 * (self.t0 + self.t1):.3f} s"


def step_edges(
    fd: FlightData, spans: Sequence[tuple[float, float]], grid_step_s: float, channels: Sequence[str] = CONTROL_INPUTS
) -> list[Edge]:
    """The steps (:class:`Edge`, in time order) of the control inputs ``channels`` over
    sample intervals longer than SLOW_FACTOR x ``grid_step_s`` [s] (the fit grid's step)
    or than COARSE_INTERVAL_S, that lie in one of ``spans`` ((start, end) [s], the fitted
    windows)."""
    out: list[Edge] = []
    for c in channels:
        if c not in fd.channels or c == "throttle" or len(fd[c]) < 4:
            continue
        ch = fd[c]
        t, u = np.asarray(ch.t, float), np.asarray(ch.values, float)
        h = np.diff(t)
        d = np.abs(np.diff(u))
        coarse = (h > SLOW_FACTOR * grid_step_s) | (h >= COARSE_INTERVAL_S)
        if not np.any(coarse):
            continue
        nb = np.maximum(np.r_[0.0, d[:-1]], np.r_[d[1:], 0.0])  # the larger neighbour
        step = (d >= MIN_STEP_RAD) & (d >= STEP_RATIO * nb) & coarse
        inside = np.zeros_like(step)
        for a, b in spans:
            inside |= (t[1:] > a) & (t[:-1] < b)
        out += [
            Edge(c, int(k), float(t[k]), float(t[k + 1]), float(u[k + 1] - u[k])) for k in np.flatnonzero(step & inside)
        ]
    return sorted(out, key=lambda e: (e.t0, e.channel))


def with_edges_moved(fd: FlightData, edges: Sequence[Edge], shifts: Sequence[float]) -> FlightData:
    """``fd`` with each step of ``edges`` moved by ``shifts`` [s] (same length): the two
    samples that bracket it move together, so the linearly interpolated ramp between them
    keeps its width and its centre moves by the shift (the samples before and after are
    the step's flat levels: moving them along the level changes nothing else). Raises
    ValueError when a shift would pass a neighbouring sample. The data are copied, never
    changed in place."""
    ramps = {}
    times = {c: np.array(fd[c].t, dtype=float) for c in {e.channel for e in edges}}
    for e, s in zip(edges, shifts):
        if s == 0.0:
            continue
        t = times[e.channel]  # with the steps moved so far: none may cross
        lo = t[e.k - 1] if e.k > 0 else -np.inf
        hi = t[e.k + 2] if e.k + 2 < t.size else np.inf
        if not (lo < t[e.k] + s and t[e.k + 1] + s < hi):
            raise ValueError(f"{e.name}: a shift of {s:+.4f} s passes a neighbouring sample")
        t[e.k] += s
        t[e.k + 1] += s
        ramps[e] = (float(t[e.k]), float(t[e.k + 1]))
    return _with_ramps(fd, ramps)


def _with_ramps(fd: FlightData, ramps: dict[Edge, tuple[float, float]]) -> FlightData:
    """A copy of ``fd`` whose steps (``ramps``' keys) have their two bracketing samples at
    the times of the values (start, end) [s]; the other samples as they are."""
    chans = dict(fd.channels)
    for c in sorted({e.channel for e in ramps}):
        ch = chans[c]
        t = np.array(ch.t, dtype=float)
        for e, (a, b) in ramps.items():
            if e.channel == c:
                t[e.k], t[e.k + 1] = a, b
        chans[c] = Channel(t, ch.values, ch.unit, ch.source, ch.notes, ch.derived)
    return FlightData(chans, fd.meta, fd.segments)


#: gyro samples either side of a step's interval used to time it, in intervals
REFINE_WINDOW = 3
#: the kink a step puts in the angular rates must stand this many std above the noise
REFINE_SIGNIFICANCE = 10.0
#: points of the grid of trial times over a step's interval
REFINE_GRID = 81
#: gyro samples either side of a step at least (gyros as slow as the inputs: none inside)
REFINE_MIN_SAMPLES = 6.5
#: ... within this many seconds either side: the cubic and the kink's powers stand in for
#: the aircraft's motion only over a fraction of its periods (a 4 Hz telemetry gyro would
#: otherwise be fitted over 3 s)
REFINE_MAX_HALF_S = 0.25
#: powers of (t - tau)+ after the kink tried; the one with the smaller BIC times the step
KINK_ORDERS = (2, 3)


def _kink_profile(tw: np.ndarray, W: np.ndarray, taus: np.ndarray, order: int = 2) -> tuple[np.ndarray, np.ndarray]:
    """For each trial time tau: the weighted residual sum of squares of the gyro samples
    ``W`` ((n, 3) rates / their noise std, at times ``tw``) fitted per axis by a cubic in
    time plus a kink c1 (t - tau)+ (the rate's response to a step of angular acceleration
    at tau) and its ``order`` - 1 higher powers c2 (t - tau)+^2, ... (the response's
    curvature after it: a roll mode's 0.1 s time constant bends it within the window), and
    the kink's largest |c1| / std over the axes. Shapes (len(taus),)."""
    span = max(np.ptp(tw), 1e-9)
    x = (tw - tw.mean()) / span
    base = np.broadcast_to(np.vander(x, 4, increasing=True), (taus.size, tw.size, 4))
    k = np.maximum(tw[None, :] - taus[:, None], 0.0) / span  # (T, n)
    # one design per trial time, the same for every axis: (T, n, 4 + order)
    A = np.concatenate([base, np.stack([k**j for j in range(1, order + 1)], axis=-1)], axis=-1)
    Ap = np.linalg.pinv(A)  # (T, 4 + order, n)
    coef = Ap @ W  # (T, 4 + order, 3)
    r = W[None] - A @ coef
    rss = np.sum(r * r, axis=(1, 2))
    s2 = np.sum(r * r, axis=1) / max(W.shape[0] - A.shape[2], 1)  # (T, 3), in noise units^2
    cov_c = np.sum(Ap[:, 4, :] ** 2, axis=1)  # (A^T A)^+ [4, 4]
    sig = np.max(np.abs(coef[:, 4, :]) / np.sqrt(np.maximum(s2, 1.0) * cov_c[:, None]), axis=1)
    return rss, sig


def refine_steps(fd: FlightData, edges: Sequence[Edge], grid_step_s: float) -> tuple[FlightData, list[Edge], dict]:
    """Time the steps ``edges`` from the angular rates: a step of a surface is a step of
    angular acceleration, a kink in the gyro rates. Steps in the same interval (aileron and
    rudder moved together) share a time. For each such interval, the gyro samples within
    REFINE_WINDOW intervals either side (at least REFINE_MIN_SAMPLES gyro samples: gyros as
    slow as the inputs sample nothing inside the interval, and the kink's time shows in
    the samples after it; at most REFINE_MAX_HALF_S) are fitted per axis by a cubic in time
    plus a kink at a trial time tau and its higher powers (KINK_ORDERS; weighted by each gyro's noise std, second
    differences over the log), tau on REFINE_GRID points over the interval. The order with
    the smaller BIC times the step; its std comes from the weighted residual sum of
    squares' curvature (Delta chi^2 = 1), scaled by the reduced chi^2 where that exceeds 1
    (turbulence, the cubic's misfit), combined with the distance to the other order's time
    (``Edge.form_std``: the kink's shape is a Taylor series of the aircraft's response) and
    bounded by the interval's own h / sqrt(12). A step is timed when the kink stands
    REFINE_SIGNIFICANCE std above the noise on some axis in either order's fit (the
    higher powers share the kink's slope's variance: a kink plain in the 2-power fit may
    stand at 6 std in the 3-power one) and the chosen order's best tau is inside the
    interval; the others keep their interval.

    A timed step becomes a ramp ``grid_step_s`` wide centred on its time (its two bracketing
    samples moved there: before and after them the input is flat), so that the fits' grid,
    which reads the input linearly between its times, integrates the step's area where it
    was: between its two grid times the ramp's value at the first is the share of the step
    the interval before it did not have. Returns (flight data with the timed steps, every
    edge as it now is in that data - a timed one with its ``time_std`` -, JSON-ready
    document)."""
    gyro = [c for c in ("p", "q", "r") if c in fd.channels]
    doc: dict = {
        "steps": len(edges),
        "timed": 0,
        "method": (
            "each step's time from the kink it puts in the gyro rates (a cubic per axis plus a "
            "kink and its higher powers, the number of powers by BIC, least squares over trial "
            "times; std from Delta chi^2 = 1 and the other number's time)"
        ),
    }
    if not edges or len(gyro) < 3:
        doc["note"] = "no gyro rates to time the steps by" if edges else "no step"
        return fd, list(edges), doc
    tg = np.asarray(fd[gyro[0]].t, float)
    G = np.column_stack([np.interp(tg, fd[c].t, fd[c].values) for c in gyro])
    noise = difference_noise_std([G], robust=True)
    rough = difference_noise_std([G])  # a noise-free, quantised gyro: robust 0
    noise = np.where(np.isfinite(noise) & (noise > 0), noise, np.where(np.isfinite(rough) & (rough > 0), rough, 1e-6))
    dt_gyro = float(np.median(np.diff(tg))) if tg.size > 1 else np.inf
    W = G / noise  # the rates in units of their noise
    groups: dict[tuple[float, float], list[Edge]] = {}
    for e in edges:
        groups.setdefault((round(e.t0, 6), round(e.t1, 6)), []).append(e)
    timed: dict[Edge, Edge] = {}
    stds = []
    for (t0, t1), grp in groups.items():
        got = _step_time(tg, W, t0, t1, dt_gyro)
        if got is None:
            continue
        tau, std, form = got
        a0, a1 = tau - 0.5 * grid_step_s, tau + 0.5 * grid_step_s

        def fits_between(e: Edge, a0: float = a0, a1: float = a1) -> bool:  # the ramp stays between the flat samples
            t = fd[e.channel].t
            return (e.k == 0 or t[e.k - 1] < a0) and (e.k + 2 >= t.size or a1 < t[e.k + 2])

        if not all(fits_between(e) for e in grp):
            continue
        for e in grp:
            timed[e] = Edge(e.channel, e.k, a0, a1, e.size, std, form)
        stds.append(std)
    if not timed:
        doc["note"] = "too few gyro samples around them, or the kinks are too weak"
        return fd, list(edges), doc
    doc.update(
        timed=len(timed),
        time_std_ms={"median": 1e3 * float(np.median(stds)), "max": 1e3 * float(np.max(stds))},
        shifts_ms={e.name: round(1e3 * (0.5 * (timed[e].t0 + timed[e].t1) - 0.5 * (e.t0 + e.t1)), 2) for e in timed},
    )
    return (
        _with_ramps(fd, {e: (new.t0, new.t1) for e, new in timed.items()}),  # tau -+ width / 2
        [timed.get(e, e) for e in edges],
        doc,
    )


def _step_time(
    tg: np.ndarray, W: np.ndarray, t0: float, t1: float, dt_gyro: float
) -> tuple[float, float, float] | None:
    """(time, std, form_std) [s] of a step in the interval (t0, t1) [s] from the gyro
    samples ``W`` ((n, 3) rates / their noise std at times ``tg``, median interval
    ``dt_gyro``) around it (:func:`refine_steps`), or None when it cannot be timed."""
    h = t1 - t0
    half = min(max(REFINE_WINDOW * h, REFINE_MIN_SAMPLES * dt_gyro), REFINE_MAX_HALF_S)
    sel = (tg >= t0 - half) & (tg <= t1 + half)
    if sel.sum() < 12:
        return None  # too few gyro samples around the step
    taus = np.linspace(t0, t1, REFINE_GRID)
    fits = {}
    for order in KINK_ORDERS:
        rss, sig = _kink_profile(tg[sel], W[sel], taus, order)
        i = int(np.argmin(rss))
        if i in (0, taus.size - 1):  # no minimum inside the interval
            fits[order] = dict(tau=float(taus[i]), sig=float(sig[i]), std=np.inf, bic=np.inf)
            continue
        a = 0.5 * (rss[i + 1] - 2 * rss[i] + rss[i - 1]) / (taus[1] - taus[0]) ** 2
        off = 0.5 * (rss[i - 1] - rss[i + 1]) / (rss[i + 1] - 2 * rss[i] + rss[i - 1])
        n_obs, n_par = 3 * int(sel.sum()), 3 * (4 + order) + 1
        red = rss[i] / max(n_obs - n_par, 1)
        fits[order] = dict(
            tau=float(taus[i] + off * (taus[1] - taus[0])),
            sig=float(sig[i]),
            std=float(np.sqrt(max(red, 1.0) / a)) if a > 0 else np.inf,
            bic=float(n_obs * np.log(max(rss[i], 1e-300) / n_obs) + n_par * np.log(n_obs)),
        )
    best = min(fits, key=lambda o: fits[o]["bic"])
    if not np.isfinite(fits[best]["bic"]) or max(f["sig"] for f in fits.values()) < REFINE_SIGNIFICANCE:
        return None
    tau, std = fits[best]["tau"], fits[best]["std"]
    # the other order's time (an interval's end where it has no minimum inside) is the
    # model's own uncertainty: the kink's shape after the step is a Taylor series of
    # the aircraft's response
    form = max([abs(f["tau"] - tau) for o, f in fits.items() if o != best], default=0.0)
    std = min(max(float(np.hypot(std, form)), 1e-4), h / np.sqrt(12.0))
    form = min(form, std)
    return tau, std, form


def time_steps(fd: FlightData, max_rate_hz: float) -> tuple[FlightData, list[Edge], dict]:
    """The ingest step of a log whose control inputs are logged more slowly than its gyros
    or at 40 Hz and below: the steps of its maneuver windows (:meth:`FlightData.find_segments`'
    spans, else the whole log) on the grid the fits will use
    (:func:`pipeline.ingest.flightdata.fit_grid_rate` of the gyros' rate, at most ``max_rate_hz``)
    found (:func:`step_edges`) and timed from the rates
    (:func:`refine_steps`); every step's span as it now is and its time's std (None:
    untimed, anywhere in the span) go to the data's ``meta["input_steps"]`` (channel ->
    [[start, end, std], ...] s) for :func:`step_spans` and :func:`step_times`. Returns
    (flight data, its steps - what :func:`pipeline.uncertainty.consider.input_sampling`
    carries -, JSON-ready document; {} when no input is slower than the grid)."""
    gyro = [fd[c].rate_hz for c in ("p", "q", "r") if c in fd.channels]
    if not gyro:
        return fd, [], {}
    grid = 1.0 / fit_grid_rate(max(gyro), max_rate_hz)
    spans = [(s.t0, s.t1) for s in fd.segments] or [fd.span]
    edges = step_edges(fd, spans, grid)
    if not edges:
        return fd, [], {}
    out, edges, doc = refine_steps(fd, edges, grid)
    steps: dict[str, list[list[float | None]]] = {}
    for e in edges:
        steps.setdefault(e.channel, []).append(
            [float(e.t0), float(e.t1), None if e.time_std is None else float(e.time_std)]
        )
    return FlightData(out.channels, {**out.meta, "input_steps": steps}, out.segments), edges, doc


def step_spans(meta: dict) -> list[tuple[float, float]]:
    """The spans [s] over which the fits' control inputs are a ramp standing in for a step
    between two slow samples (``meta["input_steps"]`` of :func:`time_steps`), each moved by
    its surface's delay where input dynamics are applied (``meta["input_dynamics"]``:
    the models see u(t - d)). At a grid time inside such a span the model's input is part of
    the way through the step while the aircraft's surface was either before or after it:
    an output the input reaches without dynamics (the accelerometers: the control forces)
    is then off by up to the step's whole force, and :func:`pipeline.problems.windows.multirate_frame`
    leaves those samples out (FEEDTHROUGH_OUTPUTS)."""
    return sorted((a, b) for rows in step_times(meta).values() for a, b, _ in rows)


def step_times(meta: dict) -> dict[str, list[tuple[float, float, float | None]]]:
    """Per control input, its steps between two slow samples as (start, end, std) [s]
    (``meta["input_steps"]`` of :func:`time_steps`; a row without its std counts as
    untimed): a timed step is a ramp one grid step wide over (start, end) with its time's
    std; an untimed one (std None) happened anywhere in the interval. Each moved by its
    surface's delay where input dynamics are applied (``meta["input_dynamics"]``: the
    models see u(t - d)). The proof of match predicts a held-out maneuver with its steps
    moved within their uncertainty as well (:func:`timing_variants`)."""
    d = {c: float(v.get("delay_s", 0.0)) for c, v in (meta.get("input_dynamics") or {}).items()}
    return {
        c: sorted(
            ((r[0] + d.get(c, 0.0), r[1] + d.get(c, 0.0), r[2] if len(r) > 2 else None) for r in rows),
            key=lambda r: r[:2],
        )
        for c, rows in (meta.get("input_steps") or {}).items()
        if rows
    }


def timing_variants(
    seg: Segment,
    inputs: Sequence[str],
    steps: Mapping[str, Sequence[tuple[float, float, float | None]]],
    fractions: Sequence[float] = TIMING_FRACTIONS,
    k: float = TIMED_RANGE_STD,
) -> list[Segment]:
    """Copies of ``seg`` (inputs ``inputs``, the model's order) with every step of ``steps``
    (input -> [(start, end, std), ...] s, :func:`step_times`) at each of ``fractions`` of the
    range of its time: an untimed step (std None) anywhere in its interval, as a sharp step
    on the grid (0: at the start, 1: at the end); a timed one within ``k`` std of its time,
    as the fits' ramp one grid step wide. The samples around a step take the value before
    it and the value after it (those of the samples just outside that range) with the step
    at that time. [] when no step moves a grid sample of ``seg`` (none in it, or only at its
    edges). Steps are taken one by one: two whose ranges overlap would each take the
    other's samples as its before or after. A first-order lag applied to an input (input
    dynamics) is not undone: the copies are then approximate."""
    t = seg.t
    moves = []  # (column, samples, value before, after, earliest time, latest, ramp width)
    for j, c in enumerate(inputs):
        for a, b, sd in steps.get(c, ()):
            if sd is None:
                lo, hi, t0, t1, w = a, b, a, b, 0.0
            else:
                mid = 0.5 * (a + b)
                lo, hi, t0, t1, w = a - k * sd, b + k * sd, mid - k * sd, mid + k * sd, b - a
            near = np.flatnonzero((t > lo) & (t < hi))
            if not near.size or near[0] == 0 or near[-1] == t.size - 1:
                continue  # a step at the segment's edge: its before or after is not in it
            moves.append((j, near, seg.u[near[0] - 1, j], seg.u[near[-1] + 1, j], t0, t1, w))
    out = []
    for f in fractions:
        u = seg.u.copy()
        for j, near, before, after, t0, t1, w in moves:
            tau = t0 + f * (t1 - t0)
            x = (t[near] >= tau).astype(float) if w <= 0 else np.clip((t[near] - tau) / w + 0.5, 0.0, 1.0)
            u[near, j] = before + (after - before) * x
        out.append(replace(seg, u=u))
    if not any(np.any(v.u != seg.u) for v in out):
        return []
    return out


def summary(doc: dict) -> str:
    """One line for the progress and report.md."""
    if not doc:
        return ""
    if not doc.get("timed"):
        return f"{doc['steps']} control-input steps between slow samples, none timed ({doc.get('note', '')})"
    ms = doc["time_std_ms"]
    return (
        f"{doc['timed']} of {doc['steps']} control-input steps between slow samples timed "
        f"from the gyro rates (std median {ms['median']:.1f}, max {ms['max']:.1f} ms)"
    )
