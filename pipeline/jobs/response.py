"""``fsid response``: frequency responses with coherence from any log the ingest reads, over
the airborne time or the given windows (no designed maneuvers needed: piloted flight,
autotune steps, stabilise-mode hops), with a transfer-function or LOES fit when asked.

The windows are cut where a channel has a gap and resampled at the slowest chosen
channel's rate (no channel is read faster than it was logged); their averages add up in
:func:`estimators.frequency_response` (composite windows, conditioned responses with several
inputs). Writes response.csv, response.json, figures/bode.png, report.md, report.html and
run.rrd, published whole with response.json last.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from estimators import EstimationError, FrequencyResponse, TransferFunction, frequency_response, loes_parameters
from estimators.frequency.response import PERIODS_PER_WINDOW
from pipeline.conditioning.checks import airborne_speed
from pipeline.errors import FsidError
from pipeline.ingest.aircraft import servo_travel_for
from pipeline.ingest.flightdata import FlightData, fit_grid_rate
from pipeline.ingest.readers import read_log
from pipeline.ingest.sampling import contiguous
from pipeline.jobs.progress import Progress
from pipeline.paths import atomic_write_text, new_run_dir, run_id, staged
from pipeline.validation.json_values import num

#: a stretch shorter than this (s) is left out (its longest window, half of it, resolves
#: little below 5 Hz)
MIN_WINDOW_S = 2.0
#: the grid is at most this rate (Hz)
MAX_RATE_HZ = 100.0
#: a pair is fitted over the band where its coherence reaches this
FIT_COHERENCE = 0.6


@dataclass(frozen=True)
class ResponseOptions:
    """``fsid response``'s settings: ``inputs``, ``outputs`` (canonical channel names);
    ``segments`` (time ranges or segment names; None: the airborne time); ``map_path``,
    ``aircraft`` (its servo travel), ``time_base``: how the log is read; ``band`` (Hz) of
    the responses (None: from the windows' resolution to a fifth of the rate, at most
    10 Hz); ``fit`` (numerator order, denominator order) and ``delay``: a transfer function
    fitted to each pair; ``quiet``; ``figures``."""

    inputs: Sequence[str]
    outputs: Sequence[str]
    segments: Sequence[str | tuple[float, float]] | None = None
    map_path: str | None = None
    aircraft: str | Path | None = None
    time_base: str | None = None
    band: tuple[float, float] | None = None
    fit: tuple[int, int] | None = None
    delay: bool = False
    quiet: bool = False
    figures: bool = True


def windows(fd: FlightData, segments: Sequence[Any] | None) -> tuple[list[tuple[float, float]], str]:
    """The spans (s) to analyse and what they are: the user's, else where the airspeed is
    above the airborne floor (:func:`pipeline.conditioning.checks.airborne_speed`), else the
    whole log."""
    if segments:
        chosen = fd.chosen_segments(segments, per_axis=False)
        return [(s.t0, s.t1) for s in chosen], "the given windows " + ", ".join(s.name for s in chosen)
    named = [s for s in fd.segments if s.kind == "time"]
    if named:  # an archive of named windows: they are the flight
        return [(s.t0, s.t1) for s in named], f"the log's {len(named)} named windows"
    lo, hi = fd.span
    if "V" not in fd.channels or len(fd.channels["V"]) < 2:
        return [(lo, hi)], "the whole log (no airspeed to tell the airborne time)"
    v = fd.channels["V"]
    floor = airborne_speed(fd)
    up = np.asarray(v.values, float) >= floor
    edges = np.flatnonzero(np.diff(np.r_[0, up.astype(int), 0]))
    spans = [(float(v.t[a]), float(v.t[b - 1])) for a, b in zip(edges[::2], edges[1::2])]
    spans = [s for s in spans if s[1] - s[0] >= MIN_WINDOW_S]
    if not spans:
        raise FsidError(
            f"no airborne span of {MIN_WINDOW_S:g} s or more (airspeed above {floor:g} m/s): give the windows with "
            "--segments T0:T1,..."
        )
    return spans, f"the airborne time (airspeed above {floor:g} m/s)"


def records(fd: FlightData, channels: Sequence[str], spans: Sequence[tuple[float, float]]) -> tuple[list, float]:
    """(the windows resampled at the slowest channel's rate and cut at gaps, as DataFrames
    on t of at least MIN_WINDOW_S, the rate)."""
    missing = [c for c in channels if c not in fd.channels or len(fd.channels[c]) < 2]
    if missing:
        have = ", ".join(sorted(fd.channels)) or "none"
        raise FsidError(
            f"channel(s) {', '.join(missing)} not in the log (it has: {have}); check --input/--output or --map"
        )
    rate = fit_grid_rate(min(fd.channels[c].rate_hz for c in channels), MAX_RATE_HZ)
    out = []
    for a, b in spans:
        df = fd.resample(rate, list(channels), t0=a, t1=b)
        ok = np.all(np.isfinite(df[list(channels)].to_numpy()), axis=1)
        t = df["t"].to_numpy()
        for run in contiguous(t[ok], 1.5 / rate):  # cut where a sample is missing or the grid skips
            piece = df[ok].iloc[run]
            if len(piece) * (1.0 / rate) >= MIN_WINDOW_S:
                out.append(piece.reset_index(drop=True))
    if not out:
        raise FsidError(
            f"no stretch of {MIN_WINDOW_S:g} s or more where {', '.join(channels)} all have samples in the windows; "
            "give longer windows with --segments"
        )
    return out, rate


def analyse(recs: Sequence[pd.DataFrame], inputs: Sequence[str], outputs: Sequence[str], band, rate: float):
    """The frequency responses of the records (:func:`estimators.frequency_response`) on a
    log-spaced grid over ``band`` (default: the longest window's resolution to a fifth of
    the rate, at most 10 Hz)."""
    T = max(len(r) for r in recs) / rate
    lo, hi = band if band else (PERIODS_PER_WINDOW / (T / 2), min(10.0, rate / 5))
    if not 0 < lo < hi:
        raise FsidError(f"--band {lo:g}:{hi:g} Hz is empty: give LO:HI with 0 < LO < HI")
    f = np.geomspace(lo, hi, 100)
    ts = [r["t"].to_numpy() for r in recs]
    us = [r[list(inputs)].to_numpy() for r in recs]
    ys = [r[list(outputs)].to_numpy() for r in recs]
    try:
        return frequency_response(ts, us, ys, f=f, inputs=inputs, outputs=outputs)
    except EstimationError as exc:
        raise FsidError(f"frequency response: {exc}; give a band the windows resolve with --band LO:HI") from None


def fit_pairs(fr: FrequencyResponse, order: tuple[int, int], delay: bool) -> dict[str, dict[str, Any]]:
    """A transfer function of ``order`` (and delay) fitted to each pair over the band where
    its coherence reaches FIT_COHERENCE; LOES figures for a 1/2 fit."""
    out = {}
    tf = TransferFunction(order[0], order[1], delay=delay)
    for o in fr.outputs:
        for i in fr.inputs:
            key = f"{o}/{i}"
            one = fr.select(o, i)
            good = one.coherence[:, 0, 0] >= FIT_COHERENCE
            if good.sum() <= len(tf.names):
                out[key] = {"error": f"coherence >= {FIT_COHERENCE} at {int(good.sum())} frequencies only"}
                continue
            band = (float(one.f[good].min()), float(one.f[good].max()))
            try:
                res = tf.fit(one, f_band=band)
            except (EstimationError, np.linalg.LinAlgError, ValueError) as exc:
                out[key] = {"error": str(exc)}
                continue
            d = {
                "band_hz": list(band),
                "J": float(res.extra["J"]),
                "parameters": {n: {"estimate": float(res.params[n]), "std": float(res.std[n])} for n in tf.names},
                "num": [float(x) for x in res.extra["num"]],
                "den": [float(x) for x in res.extra["den"]],
                "tau": float(res.extra["tau"]),
            }
            if order == (1, 2):
                try:
                    d["loes"] = loes_parameters(res)
                except EstimationError as exc:
                    d["loes_error"] = str(exc)
            d["H"] = tf.response(res.values, fr.w)
            out[key] = d
    return out


def response_log(log: Path, out: str | Path | None, opts: ResponseOptions) -> dict[str, Path]:
    """``fsid response`` on ``log`` into ``out`` (module docstring); returns name -> path."""
    from pipeline.outputs.response import write_response  # matplotlib, rerun: on use only

    out = new_run_dir("response", out, inputs=[log, opts.map_path, opts.aircraft])
    chans = list(dict.fromkeys([*opts.inputs, *opts.outputs]))
    pr = Progress(4 + (opts.fit is not None), quiet=opts.quiet)
    pr.stage(f"ingest {log}")
    fd = read_log(log, map=opts.map_path, servo_travel=servo_travel_for(log, opts.aircraft), time_base=opts.time_base)
    pr.done(f"{len(fd.channels)} channels")
    pr.stage("windows")
    spans, what = windows(fd, opts.segments)
    recs, rate = records(fd, chans, spans)
    seconds = sum(len(r) for r in recs) / rate
    pr.done(f"{len(recs)} stretch{'es' if len(recs) != 1 else ''}, {seconds:.1f} s at {rate:g} Hz: {what}")
    pr.stage(f"frequency responses of {', '.join(opts.outputs)} to {', '.join(opts.inputs)}")
    fr = analyse(recs, list(opts.inputs), list(opts.outputs), opts.band, rate)
    pr.done(
        f"{fr.f.size} frequencies {fr.f[0]:.3g}-{fr.f[-1]:.3g} Hz, windows {fr.windows.min():.3g}-{fr.windows.max():.3g} s"
    )
    fits = {}
    if opts.fit is not None:
        pr.stage(f"transfer function {opts.fit[0]}/{opts.fit[1]}{' with delay' if opts.delay else ''}")
        fits = fit_pairs(fr, opts.fit, opts.delay)
        pr.done(", ".join(f"{k} J {v['J']:.3g}" if "J" in v else f"{k}: {v['error']}" for k, v in fits.items()))
    pr.stage("write response.csv, response.json, figures, report.md, report.html, run.rrd")
    meta = {
        "log": str(log),
        "run_id": run_id(out),
        "windows": what,
        "stretches": [[float(r["t"].iloc[0]), float(r["t"].iloc[-1])] for r in recs],
        "seconds": seconds,
        "rate_hz": rate,
    }
    with staged(out, "response.json") as stage:
        paths = write_response(stage, fr, fits, meta, figures=opts.figures, recording_id=run_id(out))
        atomic_write_text(stage / "response.json", json.dumps(response_json(fr, fits, meta), indent=1, allow_nan=False))
    pr.done()
    return {name: out / rel for name, rel in {**paths, "response.json": "response.json"}.items()}


def response_json(fr: FrequencyResponse, fits: dict[str, dict[str, Any]], meta: dict[str, Any]) -> dict[str, Any]:
    """The response as a JSON document: per pair magnitude (dB), phase (deg), coherence and
    random error on f (Hz), the multiple coherence per output, the fits."""
    pairs = {}
    for o in fr.outputs:
        for u in fr.inputs:
            p = fr.pair(o, u)
            pairs[f"{o}/{u}"] = {
                c: num(p[c].to_numpy()) for c in ("magnitude_db", "phase_deg", "coherence", "random_error")
            }
    return {
        **meta,
        "inputs": fr.inputs,
        "outputs": fr.outputs,
        "f_hz": [float(x) for x in fr.f],
        "windows_s": [float(x) for x in fr.windows],
        "pairs": pairs,
        "multiple_coherence": {o: num(fr.multiple_coherence[:, k]) for k, o in enumerate(fr.outputs)},
        "fits": {k: {kk: vv for kk, vv in v.items() if kk != "H"} for k, v in fits.items()},
    }
