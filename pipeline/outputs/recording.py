"""``run.rrd``: the run for review in the rerun viewer (rerun-sdk 0.41), written column-wise.

Every time history goes in with ONE ``send_columns`` call per entity (``rr.TimeColumn`` index
columns + ``rr.Scalars.columns``), never one call per sample. Each series entity also gets a
static ``rr.SeriesLines`` (legend name with unit, colour per method). The file is written to
a temporary name and renamed (:class:`pipeline.paths.atomic_path`).

Entity layout (stable; ``<out>``/``<in>`` are model output/input names, ``<method>`` the
keys of ``results`` such as ``oem``, ``<name>`` a parameter name with any character outside
``[A-Za-z0-9_.-]`` replaced by ``_``, so ``bias_az[0]`` becomes ``bias_az_0_``)::

    /README                               static TextDocument: this layout
    /summary/<method>                     static TextDocument: result.summary(truth)
    /outputs/<out>/measured               z            timelines t, segment
    /outputs/<out>/<method>               model y      t, segment
    /residuals/<method>/<out>             z - y        t, segment
    /inputs/<in>                          u            t, segment
    /match/<out>/measured                 held-out z   t, segment
    /match/<out>/<method>                 held-fixed model prediction of the held-out data
                                          (simulation, or air-data driven: report.json mode)
    /match/<out>/upper, /match/<out>/lower   measured +/- tolerance (judged channels only)
    /match/<out>/<method>/lower|upper     the prediction's range with the held-out segments'
                                          control steps between slow samples moved within
                                          their timing uncertainty (only when some has one)
    /match/<out>/<method>/model_lower|model_upper   the prediction -/+ 2 of its own std
                                          from the estimates' covariance
    /params/<name>/<method>               estimate per iteration (timeline ``iteration``) or,
                                          for filters, per sample (timelines t, segment)
    /params/<name>/<method>/upper|lower   estimate +/- std (final Cramer-Rao std for
                                          iterations; the step's std for filters)
    /params/<name>/truth                  true value on every iteration index of the
                                          longest history (and at the first and last t
                                          of a filter trajectory)
    /spectra/<method>/<out>               residual PSD, 10 log10(units^2/Hz) dB, timeline
                                          ``frequency`` = f in mHz (integer)
    /freq_response/<out>/<in>/mag_db/data            |H| of the spectral estimate (dB)
    /freq_response/<out>/<in>/mag_db/<method>        the model through the same estimator
    /freq_response/<out>/<in>/mag_db/<method>_linear G(jw) of the linearised model
    /freq_response/<out>/<in>/phase_deg/...          same three, phase in deg
    /freq_response/<out>/<in>/coherence              coherence of the data estimate [0, 1]
    /inverse/<method>/<in>                inverse simulation: residual input (needed - flown)
                                          on the first fitted segment, timelines t, segment
    /data/<channel>                       optional extra channels (``data=``), t, segment

Values are SI (rad, rad/s, m/s, m/s^2, N ...) as in the data contract, not degrees.
A time-series view plots against the time line selected in the time panel: ``t`` (the
default) for time histories, ``iteration`` for parameter convergence, ``frequency`` for
spectra and frequency responses. The blueprint sent with the file has one tab per group.

Timelines: ``t`` (duration, s); ``segment`` (sequence) the index of the segment a sample
belongs to; ``iteration`` (sequence) the optimiser iteration; ``frequency`` (sequence, mHz).
Segments are told apart by name (``Segment.name``, or ``#k`` by position when unnamed) and
their own times, so a maneuver fitted by several methods is one segment; they are numbered
in order of first appearance: the first result's fitted segments, its held-out ones, then
those of the next result not seen yet (another axis).
When all segments are disjoint in time (pieces of one log) they keep their own times on
``t``; when any overlap (e.g. each starts at 0) they are laid end to end in that order,
each starting 1 s (:data:`SEGMENT_GAP`) after the previous one ends. A series' sample
count is the sum of its segments' finite samples; measured data (outputs, inputs, held-out
outputs) is written once per segment.

Filter methods (EKF/UKF) keep their parameter trajectory in ``result.extra["trajectory"]``
(per segment, DataFrames on t, one column per free parameter) and its std in
``result.extra["trajectory_std"]``; it is recorded on ``t``/``segment`` (same segment
layout as the outputs) instead of the iteration history.
"""

from __future__ import annotations

import re
import uuid
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from estimators import EstimationResult
from estimators.validation import PREDICTION_K
from pipeline.paths import atomic_path
from pipeline.validation.validate import display_unit

#: gap in s between segments laid end to end on the ``t`` timeline
SEGMENT_GAP = 1.0
#: colours of the methods and of measured/truth lines (RGB)
COLORS = {
    "measured": (40, 40, 40),
    "truth": (200, 160, 0),
    "data": (40, 40, 40),
    "oem": (31, 119, 180),
    "fem": (255, 127, 14),
    "ekf": (44, 160, 44),
    "ukf": (214, 39, 40),
    "ls": (148, 103, 189),
    "eq": (148, 103, 189),
}
_PALETTE = [(140, 86, 75), (227, 119, 194), (127, 127, 127), (188, 189, 34), (23, 190, 207)]


def entity_part(name: str) -> str:
    """One entity-path part from a name: characters outside [A-Za-z0-9_.-] become '_'."""
    return re.sub(r"[^A-Za-z0-9_.\-]", "_", str(name))


def _color(key: str, order: Sequence[str]) -> tuple[int, int, int]:
    if key in COLORS:
        return COLORS[key]
    return _PALETTE[list(order).index(key) % len(_PALETTE)] if key in order else _PALETTE[0]


def _si_unit(channel: str) -> str:
    fac, unit = display_unit(channel)
    if fac == 1.0:
        return unit
    return {"deg": "rad", "deg/s": "rad/s", "deg/s^2": "rad/s^2", "g": "m/s^2"}[unit]


def segment_starts(t_list: Sequence[np.ndarray], gap: float = SEGMENT_GAP) -> list[float]:
    """Offset in s to add to each segment's own times (t, (N_k,)) on the shared ``t`` line:
    0 for all when the segments are pairwise disjoint in time (pieces of one log), else end
    to end in the given order, each ``gap`` s after the previous one ends."""
    t_list = [np.asarray(t, dtype=float) for t in t_list]
    spans = sorted((float(t[0]), float(t[-1])) for t in t_list)
    if all(a1 < b0 for (_, a1), (b0, _) in zip(spans, spans[1:])):
        return [0.0] * len(t_list)
    offs, start = [], 0.0
    for t in t_list:
        offs.append(start - float(t[0]))
        start += float(t[-1] - t[0]) + gap
    return offs


def _sig(t, name: str) -> tuple[float, float, int, str]:
    """Identity of a segment: its name and its own times (first, last, count)."""
    t = np.asarray(t, dtype=float)
    return (round(float(t[0]), 9), round(float(t[-1]), 9), int(t.size), str(name))


def segment_names(r: EstimationResult) -> list[str]:
    """Names of a result's fitted segments: ``Segment.name``, or ``#k`` when unnamed or when
    the result keeps no Segment objects (a regression)."""
    segs = r.segments if len(r.segments) == len(r.predicted) else [None] * len(r.predicted)
    return [(s.name if s is not None and s.name else f"#{k}") for k, s in enumerate(segs)]


class SegmentLayout:
    """Where every distinct segment sits on ``t`` and its ``segment`` index.

    Segments are told apart by name and times (:func:`_sig`); the same maneuver fitted by
    several methods is one segment. Order of first appearance: for each result its fitted
    segments, then its held-out ones. Offsets from :func:`segment_starts` over that order."""

    def __init__(self, results: Mapping[str, EstimationResult], validations: Mapping[str, Mapping[str, Any]]) -> None:
        times: dict[tuple, np.ndarray] = {}
        for m, r in results.items():
            for p, name in zip(r.predicted, segment_names(r)):
                times.setdefault(_sig(p.index, name), np.asarray(p.index, dtype=float))
            for a in _match(validations.get(m)):
                times.setdefault(_sig(a["t"], a["name"]), np.asarray(a["t"], dtype=float))
        offs = segment_starts(list(times.values())) if times else []
        self.index = {k: i for i, k in enumerate(times)}
        self.offset = dict(zip(times, offs))

    def place(self, t, name: str) -> tuple[float, int]:
        """(offset s, segment index) of segment ``name`` with own times t; unseen ones are
        appended."""
        k = _sig(t, name)
        if k not in self.index:
            end = max((s[1] + o for s, o in self.offset.items()), default=-SEGMENT_GAP)
            self.index[k] = len(self.index)
            overlap = any(not (k[1] < s[0] or s[1] < k[0]) for s in self.offset)
            self.offset[k] = (end + SEGMENT_GAP - k[0]) if overlap or any(self.offset.values()) else 0.0
        return self.offset[k], self.index[k]

    def cat(
        self, frames: Sequence[pd.DataFrame], names: Sequence[str], times: Sequence[Any] | None = None
    ) -> tuple[np.ndarray, np.ndarray, pd.DataFrame]:
        """Concatenate per-segment DataFrames on t (or with explicit own ``times``) of the
        named segments into (t_run (N,), segment (N,), values)."""
        times = [df.index for df in frames] if times is None else times
        ts, sg = [], []
        for df, t, name in zip(frames, times, names):
            o, k = self.place(t, name)
            ts.append(np.asarray(t, dtype=float) + o)
            sg.append(np.full(len(df), k, dtype=np.int64))
        vals = pd.concat([df.reset_index(drop=True) for df in frames], ignore_index=True)
        return np.concatenate(ts), np.concatenate(sg), vals


def _match(v: Mapping[str, Any] | None) -> list[dict[str, Any]]:
    return list(((v or {}).get("arrays") or {}).get("match") or [])


class _Writer:
    """Thin helper around one RecordingStream: series and their static styles."""

    def __init__(self, rec, methods: Sequence[str]) -> None:
        import rerun as rr

        self.rr, self.rec, self.methods = rr, rec, list(methods)
        self.counts: dict[str, int] = {}

    def style(self, path: str, name: str, color: tuple[int, int, int], width: float = 1.5) -> None:
        self.rec.log(path, self.rr.SeriesLines(names=name, colors=[color], widths=width), static=True)

    def series(
        self,
        path: str,
        values,
        *,
        t=None,
        segment=None,
        sequence=None,
        timeline: str = "iteration",
        name: str | None = None,
        color=None,
    ) -> None:
        """One entity, one send_columns call; non-finite samples are left out."""
        rr = self.rr
        v = np.asarray(values, dtype=float).ravel()
        ok = np.isfinite(v)
        idx = []
        if t is not None:
            idx.append(rr.TimeColumn("t", duration=np.asarray(t, dtype=float).ravel()[ok]))
        if segment is not None:
            idx.append(rr.TimeColumn("segment", sequence=np.asarray(segment, dtype=np.int64).ravel()[ok]))
        if sequence is not None:
            idx.append(rr.TimeColumn(timeline, sequence=np.asarray(sequence, dtype=np.int64).ravel()[ok]))
        if not ok.any():
            return
        self.rec.send_columns(path, indexes=idx, columns=rr.Scalars.columns(scalars=v[ok]))
        self.counts[path] = self.counts.get(path, 0) + int(ok.sum())
        if name is not None:
            self.style(path, name, color or (100, 100, 100))

    def text(self, path: str, body: str, media_type: str = "text/markdown") -> None:
        self.rec.log(path, self.rr.TextDocument(body, media_type=media_type), static=True)


def _time_histories(
    w: _Writer,
    results: Mapping[str, EstimationResult],
    validations: Mapping[str, Mapping[str, Any]],
    inputs: Sequence[pd.DataFrame] | None,
    lay: SegmentLayout,
) -> None:
    done: dict[str, set[int]] = {}  # entity -> segment indices already written

    def fresh(path: str, sg: np.ndarray) -> np.ndarray:
        """Rows of segments not yet written to ``path`` (measured data is written once)."""
        seen = done.setdefault(path, set())
        mask = ~np.isin(sg, list(seen))
        seen.update(np.unique(sg[mask]).tolist())
        return mask

    for n, (m, r) in enumerate(results.items()):
        pm, col = entity_part(m), _color(m, w.methods)
        names = segment_names(r)
        meas = [p + e for p, e in zip(r.predicted, r.residuals)]
        t, sg, z = lay.cat(meas, names)
        _, _, y = lay.cat(r.predicted, names)
        _, _, e = lay.cat(r.residuals, names)
        for o in r.outputs:
            po, unit = entity_part(o), _si_unit(o)
            k = fresh(f"/outputs/{po}/measured", sg)
            if k.any():
                w.series(
                    f"/outputs/{po}/measured",
                    z[o][k],
                    t=t[k],
                    segment=sg[k],
                    name=f"{o} measured [{unit}]",
                    color=COLORS["measured"],
                )
            w.series(f"/outputs/{po}/{pm}", y[o], t=t, segment=sg, name=f"{o} {m} [{unit}]", color=col)
            w.series(f"/residuals/{pm}/{po}", e[o], t=t, segment=sg, name=f"{o} residual {m} [{unit}]", color=col)

        # inputs: the result's segments (or the caller's tables for the first result)
        if n == 0 and inputs is not None:
            frames = list(inputs)
            in_names = names[: len(frames)] + [f"inputs #{k}" for k in range(len(names), len(frames))]
        else:
            frames = [pd.DataFrame(s_.u, index=pd.Index(s_.t, name="t"), columns=r.model.inputs) for s_ in r.segments]
            in_names = names
        if frames:
            t, sg, u = lay.cat(frames, in_names)
            for i in u.columns:
                k = fresh(f"/inputs/{entity_part(i)}", sg)
                if k.any():
                    w.series(
                        f"/inputs/{entity_part(i)}",
                        u[i][k],
                        t=t[k],
                        segment=sg[k],
                        name=f"{i} [{_si_unit(i)}]",
                        color=(90, 90, 90),
                    )

        v = validations.get(m) or {}
        # inverse simulation (on the result's first fitted segment)
        inv = (v.get("arrays") or {}).get("inverse")
        if inv:
            o_, k_ = lay.place(inv["t"], inv.get("name") or names[0])
            t = np.asarray(inv["t"], dtype=float) + o_
            for j, i in enumerate(inv["inputs"]):
                w.series(
                    f"/inverse/{pm}/{entity_part(i)}",
                    inv["residual_inputs"][:, j],
                    t=t,
                    segment=np.full(t.size, k_, dtype=np.int64),
                    name=f"{i} residual input {m} [{_si_unit(i)}]",
                    color=col,
                )

        # proof of match on held-out segments
        arr = _match(v)
        if arr:
            times, hnames = [a["t"] for a in arr], [a["name"] for a in arr]
            t, sg, z = lay.cat([a["measured"] for a in arr], hnames, times)
            _, _, y = lay.cat([a["predicted"] for a in arr], hnames, times)
            tol = arr[0]["tolerance"]
            # the prediction's range over the times of the control steps between slow
            # samples, where a segment has one (the prediction itself elsewhere)
            bounds = (
                []
                if all(a.get("envelope") is None for a in arr)
                else [
                    lay.cat(
                        [a["predicted"] if a.get("envelope") is None else a["envelope"][i] for a in arr], hnames, times
                    )[2]
                    for i in (0, 1)
                ]
            )
            # the prediction -/+ PREDICTION_K of its own std from the estimates' covariance
            spread = (
                []
                if all(a.get("prediction_std") is None for a in arr)
                else [
                    y
                    + sign
                    * PREDICTION_K
                    * lay.cat(
                        [
                            a["predicted"] * np.nan if a.get("prediction_std") is None else a["prediction_std"]
                            for a in arr
                        ],
                        hnames,
                        times,
                    )[2]
                    for sign in (-1.0, 1.0)
                ]
            )
            for j, o in enumerate(z.columns):
                po, unit = entity_part(o), _si_unit(o)
                k = fresh(f"/match/{po}/measured", sg)
                if k.any():
                    zk = z[o][k]
                    w.series(
                        f"/match/{po}/measured",
                        zk,
                        t=t[k],
                        segment=sg[k],
                        name=f"{o} measured (held out) [{unit}]",
                        color=COLORS["measured"],
                    )
                    if np.isfinite(tol[j]):
                        w.series(
                            f"/match/{po}/upper",
                            zk + tol[j],
                            t=t[k],
                            segment=sg[k],
                            name=f"{o} + tolerance",
                            color=(170, 170, 170),
                        )
                        w.series(
                            f"/match/{po}/lower",
                            zk - tol[j],
                            t=t[k],
                            segment=sg[k],
                            name=f"{o} - tolerance",
                            color=(170, 170, 170),
                        )
                w.series(
                    f"/match/{po}/{pm}", y[o], t=t, segment=sg, name=f"{o} {m} (held-fixed model) [{unit}]", color=col
                )
                for side, b in zip(("lower", "upper"), bounds):
                    w.series(
                        f"/match/{po}/{pm}/{side}",
                        b[o],
                        t=t,
                        segment=sg,
                        name=f"{o} {m} with the steps moved in time ({side}) [{unit}]",
                        color=col,
                    )
                for side, b in zip(("model_lower", "model_upper"), spread):
                    if np.isfinite(b[o].to_numpy(float)).any():
                        w.series(
                            f"/match/{po}/{pm}/{side}",
                            b[o],
                            t=t,
                            segment=sg,
                            name=f"{o} {m} {side[6:]} {PREDICTION_K:g} std from the estimates' covariance [{unit}]",
                            color=col,
                        )


def _trajectory(r: EstimationResult) -> tuple[list[pd.DataFrame], list[pd.DataFrame] | None] | None:
    """The filter's parameter trajectory per segment (``extra["trajectory"]`` and
    ``extra["trajectory_std"]``: a DataFrame on t or a list of them), or None."""
    ex = r.extra if isinstance(r.extra, Mapping) else {}
    traj = ex.get("trajectory", ex.get("param_trajectory"))
    std = ex.get("trajectory_std", ex.get("param_std_trajectory"))
    as_list = lambda x: (
        [x]
        if isinstance(x, pd.DataFrame)
        # noqa: E731
        else ([f for f in x if isinstance(f, pd.DataFrame)] if isinstance(x, (list, tuple)) else [])
    )
    traj = [f for f in as_list(traj) if len(f)]
    if not traj:
        return None
    std = as_list(std)
    return traj, (std if len(std) == len(traj) else None)


def _params(
    w: _Writer, results: Mapping[str, EstimationResult], truth: Mapping[str, float] | None, lay: SegmentLayout
) -> None:
    n_iter = 0
    t_span: list[float] = []
    for m, r in results.items():
        pm, col = entity_part(m), _color(m, w.methods)
        tr = _trajectory(r)
        if tr is not None:
            traj, tstd = tr
            tn = segment_names(r)
            tn = tn if len(tn) == len(traj) else [f"#{k}" for k in range(len(traj))]
            t, sg, x = lay.cat(traj, tn)
            sd = lay.cat(tstd, tn, [f.index for f in traj])[2] if tstd is not None else None
            t_span += [float(t[0]), float(t[-1])]
            for name in x.columns:
                base = f"/params/{entity_part(name)}/{pm}"
                w.series(base, x[name], t=t, segment=sg, name=f"{name} {m}", color=col)
                if sd is not None and name in sd:
                    w.series(f"{base}/upper", x[name] + sd[name], t=t, segment=sg, name=f"{name} {m} + std", color=col)
                    w.series(f"{base}/lower", x[name] - sd[name], t=t, segment=sg, name=f"{name} {m} - std", color=col)
            continue
        h = r.history
        if h is None or not len(h):
            continue
        it = h["iteration"].to_numpy() if "iteration" in h else np.arange(len(h))
        n_iter = max(n_iter, int(np.max(it)) + 1)
        std = r.std
        for name in r.free_names:
            if name not in h:
                continue
            base = f"/params/{entity_part(name)}/{pm}"
            x = h[name].to_numpy(float)
            w.series(base, x, sequence=it, name=f"{name} {m}", color=col)
            s = float(std[name])
            if np.isfinite(s):
                w.series(f"{base}/upper", x + s, sequence=it, name=f"{name} {m} + std (CRB)", color=col)
                w.series(f"{base}/lower", x - s, sequence=it, name=f"{name} {m} - std (CRB)", color=col)
    if truth:
        names = sorted({n for r in results.values() for n in r.free_names if n in truth})
        for name in names:
            path = f"/params/{entity_part(name)}/truth"
            if n_iter:
                w.series(
                    path,
                    np.full(n_iter, float(truth[name])),
                    sequence=np.arange(n_iter),
                    name=f"{name} truth",
                    color=COLORS["truth"],
                )
            if t_span:
                w.series(
                    path, [truth[name]] * 2, t=[min(t_span), max(t_span)], name=f"{name} truth", color=COLORS["truth"]
                )


def _spectra(w: _Writer, results: Mapping[str, EstimationResult], validations: Mapping[str, Mapping[str, Any]]) -> None:
    data_done: set[tuple[str, str]] = set()
    for m, v in validations.items():
        arr = (v or {}).get("arrays") or {}
        pm, col = entity_part(m), _color(m, w.methods)
        ps = arr.get("psd")
        if ps is not None and m in results:
            fm = np.round(np.asarray(ps["f"]) * 1000.0).astype(np.int64)
            with np.errstate(divide="ignore"):
                db = 10.0 * np.log10(np.asarray(ps["Pxx"], dtype=float))
            for j, o in enumerate(results[m].outputs):
                w.series(
                    f"/spectra/{pm}/{entity_part(o)}",
                    db[:, j],
                    sequence=fm,
                    timeline="frequency",
                    name=f"{o} residual PSD {m} [dB]",
                    color=col,
                )
        fr = arr.get("freq")
        if not fr:
            continue
        fm = np.round(np.asarray(fr["f"]) * 1000.0).astype(np.int64)
        for a, o in enumerate(fr["outputs"]):
            for b, i in enumerate(fr["inputs"]):
                base = f"/freq_response/{entity_part(o)}/{entity_part(i)}"
                curves = {m: fr["H_model"][:, a, b], f"{m}_linear": fr["H_analytic"][:, a, b]}
                if (o, i) not in data_done:
                    curves["data"] = fr["H_data"][:, a, b]
                    w.series(
                        f"{base}/coherence",
                        fr["coherence"][:, a, b],
                        sequence=fm,
                        timeline="frequency",
                        name=f"{o}/{i} coherence",
                        color=COLORS["data"],
                    )
                    data_done.add((o, i))
                for key, H in curves.items():
                    with np.errstate(divide="ignore"):
                        mag = 20.0 * np.log10(np.abs(H))
                    ph = np.degrees(np.unwrap(np.angle(H)))
                    c = COLORS["data"] if key == "data" else col
                    w.series(
                        f"{base}/mag_db/{entity_part(key)}",
                        mag,
                        sequence=fm,
                        timeline="frequency",
                        name=f"{o}/{i} {key} [dB]",
                        color=c,
                    )
                    w.series(
                        f"{base}/phase_deg/{entity_part(key)}",
                        ph,
                        sequence=fm,
                        timeline="frequency",
                        name=f"{o}/{i} {key} [deg]",
                        color=c,
                    )


def _extra_data(w: _Writer, data: pd.DataFrame | Sequence[pd.DataFrame]) -> None:
    frames = [data] if isinstance(data, pd.DataFrame) else list(data)
    if not frames:
        return
    t, sg, d = SegmentLayout({}, {}).cat(frames, [f"data #{k}" for k in range(len(frames))])
    for c in d.columns:
        if pd.api.types.is_numeric_dtype(d[c]):
            w.series(
                f"/data/{entity_part(c)}",
                d[c].to_numpy(float),
                t=t,
                segment=sg,
                name=f"{c} [{_si_unit(str(c))}]",
                color=(90, 90, 90),
            )


def _blueprint(results: Mapping[str, EstimationResult], validations) -> Any:
    import rerun.blueprint as rrb

    ins = list(dict.fromkeys(i for r in results.values() for i in r.model.inputs))
    outs = list(dict.fromkeys(o for r in results.values() for o in r.outputs))
    params = list(dict.fromkeys(n for r in results.values() for n in r.free_names))
    tabs = [
        rrb.Grid(*[rrb.TimeSeriesView(origin=f"/outputs/{entity_part(o)}", name=o) for o in outs], name="outputs"),
        rrb.Grid(
            *[rrb.TimeSeriesView(origin=f"/residuals/{entity_part(m)}", name=f"residuals {m}") for m in results],
            name="residuals",
        ),
        rrb.Grid(*[rrb.TimeSeriesView(origin=f"/inputs/{entity_part(i)}", name=i) for i in ins], name="inputs"),
        rrb.Grid(*[rrb.TimeSeriesView(origin=f"/params/{entity_part(p)}", name=p) for p in params], name="parameters"),
    ]
    if any((v or {}).get("arrays", {}).get("match") for v in validations.values()):
        tabs.append(
            rrb.Grid(
                *[rrb.TimeSeriesView(origin=f"/match/{entity_part(o)}", name=o) for o in outs], name="proof of match"
            )
        )
    tabs.append(
        rrb.Grid(
            *[rrb.TimeSeriesView(origin=f"/spectra/{entity_part(m)}", name=f"PSD {m}") for m in results], name="spectra"
        )
    )
    pairs = list(
        dict.fromkeys(
            (o, i)
            for v in validations.values()
            for fr in [((v or {}).get("arrays") or {}).get("freq")]
            if fr
            for o in fr["outputs"]
            for i in fr["inputs"]
        )
    )
    if pairs:
        views = []
        for o, i in pairs:
            base = f"/freq_response/{entity_part(o)}/{entity_part(i)}"
            views.append(
                rrb.Vertical(
                    rrb.TimeSeriesView(origin=f"{base}/mag_db", name=f"{o}/{i} magnitude (dB)"),
                    rrb.TimeSeriesView(origin=f"{base}/phase_deg", name=f"{o}/{i} phase (deg)"),
                    rrb.TimeSeriesView(origin=f"{base}/coherence", name=f"{o}/{i} coherence"),
                    name=f"{o}/{i}",
                )
            )
        tabs.append(rrb.Grid(*views, name="frequency response"))
    if any(((v or {}).get("arrays") or {}).get("inverse") for v in validations.values()):
        tabs.append(
            rrb.Grid(
                *[
                    rrb.TimeSeriesView(origin=f"/inverse/{entity_part(m)}", name=f"inverse simulation {m}")
                    for m in results
                ],
                name="inverse simulation",
            )
        )
    tabs.append(
        rrb.Vertical(
            rrb.TextDocumentView(origin="/README", name="layout"),
            *[rrb.TextDocumentView(origin=f"/summary/{entity_part(m)}", name=m) for m in results],
            name="summary",
        )
    )
    return rrb.Blueprint(rrb.Tabs(*tabs), rrb.TimePanel(timeline="t"), collapse_panels=False)


def write_recording(
    path: str | Path,
    results: Mapping[str, EstimationResult],
    validations: Mapping[str, Mapping[str, Any]] | None = None,
    *,
    data: pd.DataFrame | Sequence[pd.DataFrame] | None = None,
    truth: Mapping[str, float] | None = None,
    inputs: Sequence[pd.DataFrame] | None = None,
    application_id: str = "fsid",
    recording_id: str | None = None,
    blueprint: bool = True,
) -> Path:
    """Write the rerun recording of a run (layout in the module doc); returns the path.

    results: method -> result (the first one's segments give the inputs and the time base);
    validations: method -> :func:`pipeline.validation.validate.validate` output (its ``"arrays"`` give
    the spectra, frequency responses and proof-of-match histories; may be empty);
    data: optional extra channels, a DataFrame on t (s) or one per segment, SI units;
    truth: true parameter values; inputs: per fitted segment, DataFrames on t of the inputs
    (default: the first result's segments' u under the model's input names).
    """
    import rerun as rr

    if not results:
        raise ValueError("write_recording needs at least one result")
    validations = dict(validations or {})
    path = Path(path)
    rec = rr.RecordingStream(application_id, recording_id=recording_id or str(uuid.uuid4()))
    with atomic_path(path) as tmp:
        rec.save(str(tmp))
        try:
            rec.send_recording_name(path.parent.name or "fsid run")
            w = _Writer(rec, list(results))
            w.text("/README", __doc__ or "")
            for m, r in results.items():
                w.text(f"/summary/{entity_part(m)}", "```\n" + r.summary(dict(truth) if truth else None) + "\n```")
            lay = SegmentLayout(results, validations)
            _time_histories(w, results, validations, inputs, lay)
            _params(w, results, truth, lay)
            _spectra(w, results, validations)
            if data is not None:
                _extra_data(w, data)
            if blueprint:
                rec.send_blueprint(_blueprint(results, validations))
        finally:
            rec.flush()
            rec.disconnect()
    return path
