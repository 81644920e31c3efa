"""The series of run.rrd: time histories of outputs, residuals, inputs, inverse simulation
and proof of match, parameter histories, residual spectra and frequency responses, each
entity written with one ``send_columns`` call (layout in the module doc of
:mod:`pipeline.outputs.recording`)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import pandas as pd

from estimators import EstimationResult
from estimators.validation import PREDICTION_K
from pipeline.outputs.recording_layout import (
    COLORS,
    SegmentLayout,
    entity_part,
    held_out_arrays,
    method_color,
    segment_names,
    si_unit,
)

#: colour of measured inputs, extra data channels
_GREY = (90, 90, 90)
#: colour of the tolerance band around held-out data
_BAND_GREY = (170, 170, 170)


class SeriesWriter:
    """Thin helper around one RecordingStream: series and their static styles."""

    def __init__(self, rec, methods: Sequence[str]) -> None:
        import rerun as rr

        self.rr, self.rec, self.methods = rr, rec, list(methods)
        self.counts: dict[str, int] = {}

    def style(self, path: str, name: str, color: tuple[int, int, int], width: float = 1.5) -> None:
        """The static legend name, colour and width of a series entity."""
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
        """One entity, one send_columns call; non-finite samples (value or time) are left out."""
        rr = self.rr
        v = np.asarray(values, dtype=float).ravel()
        ok = np.isfinite(v)
        if t is not None:
            ok &= np.isfinite(np.asarray(t, dtype=float).ravel())
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
        """A static text document."""
        self.rec.log(path, self.rr.TextDocument(body, media_type=media_type), static=True)

    def states(self, path: str, t: Sequence[float], states: Sequence[str | None]) -> None:
        """A state track on ``t`` [s] (rr.StateChange, one send_columns call): each state holds
        from its time to the next; None ends the one before (an empty state)."""
        rr = self.rr
        col = rr.StateChange.columns(state=[s for s in states if s is not None])
        self.rec.send_columns(
            path,
            indexes=[rr.TimeColumn("t", duration=np.asarray(t, dtype=float))],
            columns=col.partition([0 if s is None else 1 for s in states]),
        )
        self.counts[path] = self.counts.get(path, 0) + len(states)

    def events(self, path: str, t: Sequence[float], texts: Sequence[str], levels: Sequence[str]) -> None:
        """Text-log entries at times ``t`` [s] with their levels (INFO, WARN, ERROR), one
        send_columns call."""
        rr = self.rr
        self.rec.send_columns(
            path,
            indexes=[rr.TimeColumn("t", duration=np.asarray(t, dtype=float))],
            columns=rr.TextLog.columns(text=list(texts), level=list(levels)),
        )
        self.counts[path] = self.counts.get(path, 0) + len(texts)


class _Once:
    """Which segments an entity has been written for: measured data is written once per
    segment, whichever result brings it first."""

    def __init__(self) -> None:
        self.done: dict[str, set[int]] = {}  # entity -> segment indices already written

    def __call__(self, path: str, sg: np.ndarray) -> np.ndarray:
        """Rows of segments not yet written to ``path`` (they count as written from now)."""
        seen = self.done.setdefault(path, set())
        mask = ~np.isin(sg, list(seen))
        seen.update(np.unique(sg[mask]).tolist())
        return mask


def time_histories(
    w: SeriesWriter,
    results: Mapping[str, EstimationResult],
    validations: Mapping[str, Mapping[str, Any]],
    inputs: Sequence[pd.DataFrame] | None,
    lay: SegmentLayout,
) -> None:
    """Per result: measured and model outputs, residuals, inputs (``inputs``: the caller's
    tables for the first result), the inverse simulation's residual inputs and the proof of
    match on the held-out segments."""
    fresh = _Once()
    for n, (m, r) in enumerate(results.items()):
        names = segment_names(r)
        _outputs(w, m, r, names, lay, fresh)
        _inputs(w, r, names, inputs if n == 0 else None, lay, fresh)
        v = validations.get(m) or {}
        _inverse(w, m, v, names, lay)
        _match(w, m, v, lay, fresh)


def _outputs(w: SeriesWriter, m: str, r: EstimationResult, names: list[str], lay: SegmentLayout, fresh: _Once) -> None:
    """Measured outputs (once per segment), method ``m``'s model outputs and residuals."""
    pm, col = entity_part(m), method_color(m, w.methods)
    meas = [p + e for p, e in zip(r.predicted, r.residuals)]
    t, sg, z = lay.cat(meas, names)
    _, _, y = lay.cat(r.predicted, names)
    _, _, e = lay.cat(r.residuals, names)
    for o in r.outputs:
        po, unit = entity_part(o), si_unit(o)
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


def _inputs(
    w: SeriesWriter,
    r: EstimationResult,
    names: list[str],
    inputs: Sequence[pd.DataFrame] | None,
    lay: SegmentLayout,
    fresh: _Once,
) -> None:
    """The inputs of the result's segments (or the caller's tables), once per segment."""
    if inputs is not None:
        frames = list(inputs)
        in_names = names[: len(frames)] + [f"inputs #{k}" for k in range(len(names), len(frames))]
    else:
        frames = [pd.DataFrame(s_.u, index=pd.Index(s_.t, name="t"), columns=r.model.inputs) for s_ in r.segments]
        in_names = names
    if not frames:
        return
    t, sg, u = lay.cat(frames, in_names)
    for i in u.columns:
        k = fresh(f"/inputs/{entity_part(i)}", sg)
        if k.any():
            w.series(
                f"/inputs/{entity_part(i)}", u[i][k], t=t[k], segment=sg[k], name=f"{i} [{si_unit(i)}]", color=_GREY
            )


def _inverse(w: SeriesWriter, m: str, v: Mapping[str, Any], names: list[str], lay: SegmentLayout) -> None:
    """The inverse simulation's residual inputs (on the result's first fitted segment)."""
    inv = (v.get("arrays") or {}).get("inverse")
    if not inv:
        return
    pm, col = entity_part(m), method_color(m, w.methods)
    o_, k_ = lay.place(inv["t"], inv.get("name") or names[0])
    t = np.asarray(inv["t"], dtype=float) + o_
    for j, i in enumerate(inv["inputs"]):
        w.series(
            f"/inverse/{pm}/{entity_part(i)}",
            inv["residual_inputs"][:, j],
            t=t,
            segment=np.full(t.size, k_, dtype=np.int64),
            name=f"{i} residual input {m} [{si_unit(i)}]",
            color=col,
        )


def _match(w: SeriesWriter, m: str, v: Mapping[str, Any], lay: SegmentLayout, fresh: _Once) -> None:
    """The proof of match on the held-out segments: measured data with its tolerance band
    (once per segment), method ``m``'s prediction, its range over the control steps'
    timing and its -/+ PREDICTION_K std from the estimates' covariance."""
    arr = held_out_arrays(v)
    if not arr:
        return
    pm, col = entity_part(m), method_color(m, w.methods)
    times, hnames = [a["t"] for a in arr], [a["name"] for a in arr]
    t, sg, z = lay.cat([a["measured"] for a in arr], hnames, times)
    _, _, y = lay.cat([a["predicted"] for a in arr], hnames, times)
    tol = arr[0]["tolerance"]
    bounds, spread = _match_ranges(arr, y, hnames, times, lay)
    for j, o in enumerate(z.columns):
        po, unit = entity_part(o), si_unit(o)
        k = fresh(f"/match/{po}/measured", sg)
        if k.any():
            _held_out_measured(w, o, z[o][k], tol[j], t[k], sg[k])
        w.series(f"/match/{po}/{pm}", y[o], t=t, segment=sg, name=f"{o} {m} (held-fixed model) [{unit}]", color=col)
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


def _match_ranges(
    arr: list[dict[str, Any]], y: pd.DataFrame, hnames: list[str], times: list[Any], lay: SegmentLayout
) -> tuple[list[pd.DataFrame], list[pd.DataFrame]]:
    """(bounds, spread) over the held-out segments laid out as ``y``: (lower, upper) of
    the prediction's range over the times of the control steps between slow samples
    where a segment has one (the prediction itself elsewhere), and the prediction -/+
    PREDICTION_K of its own std from the estimates' covariance; each [] when no segment
    has it."""
    bounds = (
        []
        if all(a.get("envelope") is None for a in arr)
        else [
            lay.cat([a["predicted"] if a.get("envelope") is None else a["envelope"][i] for a in arr], hnames, times)[2]
            for i in (0, 1)
        ]
    )
    spread = (
        []
        if all(a.get("prediction_std") is None for a in arr)
        else [
            y
            + sign
            * PREDICTION_K
            * lay.cat(
                [a["predicted"] * np.nan if a.get("prediction_std") is None else a["prediction_std"] for a in arr],
                hnames,
                times,
            )[2]
            for sign in (-1.0, 1.0)
        ]
    )
    return bounds, spread


def _held_out_measured(w: SeriesWriter, o: str, zk: pd.Series, tol: float, t: np.ndarray, sg: np.ndarray) -> None:
    """Held-out measurements of output ``o`` and, on a judged channel, their -/+ ``tol`` band."""
    po, unit = entity_part(o), si_unit(o)
    w.series(
        f"/match/{po}/measured", zk, t=t, segment=sg, name=f"{o} measured (held out) [{unit}]", color=COLORS["measured"]
    )
    if np.isfinite(tol):
        w.series(f"/match/{po}/upper", zk + tol, t=t, segment=sg, name=f"{o} + tolerance", color=_BAND_GREY)
        w.series(f"/match/{po}/lower", zk - tol, t=t, segment=sg, name=f"{o} - tolerance", color=_BAND_GREY)


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


def parameter_histories(
    w: SeriesWriter, results: Mapping[str, EstimationResult], truth: Mapping[str, float] | None, lay: SegmentLayout
) -> None:
    """Per method each free parameter's estimate -/+ std: per iteration of the optimiser,
    or for a filter per sample on ``t``; and the truth on both timelines."""
    n_iter = 0
    t_span: list[float] = []
    for m, r in results.items():
        pm, col = entity_part(m), method_color(m, w.methods)
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


def spectra(
    w: SeriesWriter, results: Mapping[str, EstimationResult], validations: Mapping[str, Mapping[str, Any]]
) -> None:
    """Per method the residual power spectra (dB) and the frequency responses (magnitude
    dB, phase deg) of the model, its linearisation and the data (with its coherence, once
    per output/input pair) on the ``frequency`` timeline (mHz)."""
    data_done: set[tuple[str, str]] = set()
    for m, v in validations.items():
        arr = (v or {}).get("arrays") or {}
        pm, col = entity_part(m), method_color(m, w.methods)
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


def extra_data(w: SeriesWriter, data: pd.DataFrame | Sequence[pd.DataFrame]) -> None:
    """Extra numeric channels (a DataFrame on t, or one per segment) under ``/data``."""
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
                name=f"{c} [{si_unit(str(c))}]",
                color=_GREY,
            )
