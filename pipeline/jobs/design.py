"""``fsid design``: inputs designed for the flight (mutually orthogonal multisines,
:func:`sim.maneuvers.orthogonal_multisines`) with the accuracy they will give.

The predicted accuracy: the built-in model of each axis the inputs move (longitudinal for
the elevator, lateral-directional for aileron and rudder) with the aircraft file's geometry,
mass and a-priori derivatives (the models' defaults where it gives none), trimmed at the
flight's airspeed and flown with the designed inputs; its Cramér-Rao bounds at those values
with the simulated sensors' default noise (:func:`sim.sensors.default_noise_si`) are each
derivative's predicted std for one such maneuver. Writes inputs.csv, design.json,
fsid_player.lua (an ArduPilot Lua script that flies the design:
:mod:`pipeline.outputs.lua_player`), figures/inputs.png, report.md and report.html,
published whole with design.json last.
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from estimators import EstimationError, OutputError, Segment, simulate_outputs
from estimators.datasets import trim_level
from estimators.models.lateral import lateral_directional
from estimators.models.longitudinal import longitudinal
from pipeline.errors import FsidError
from pipeline.ingest.aircraft_file import read_aircraft_file
from pipeline.ingest.constants import isa_density
from pipeline.ingest.maps import DEFAULT_TRAVEL_DEG
from pipeline.jobs.progress import Progress
from pipeline.outputs.lua_player import PITCH_LIMIT_DEG, ROLL_LIMIT_DEG, SWITCH_OPTION
from pipeline.paths import atomic_write_text, new_run_dir, run_id, staged
from pipeline.validation.json_values import num
from sim.maneuvers import orthogonal_multisines
from sim.sensors import default_noise_si

#: the surfaces a design may move, and the axis model that predicts each one's accuracy
SURFACES = {"de": "longitudinal", "da": "lateral", "dr": "lateral"}


@dataclass(frozen=True)
class DesignOptions:
    """``fsid design``'s settings: the aircraft file, the ``inputs`` (de, da, dr), the
    ``band`` (Hz), ``duration`` (s), the output ``rate`` (Hz), each input's peak
    ``amplitude`` (rad), the trim ``speed`` (m/s) and ``altitude`` (m, ISA density); ``log``:
    a previous flight whose information the new one adds to (:func:`with_previous`)."""

    aircraft: str | Path
    inputs: Sequence[str]
    band: tuple[float, float]
    duration: float
    rate: float = 50.0
    amplitude: Mapping[str, float] | None = None
    speed: float | None = None
    altitude: float = 100.0
    log: str | Path | None = None
    quiet: bool = False


def predicted_accuracy(
    U: pd.DataFrame, ac: Any, speed: float, rho: float, noise: Mapping[str, float]
) -> dict[str, dict[str, Any]]:
    """Axis -> {derivative -> {value, std, rel_std_pct}} predicted for the designed inputs
    ``U`` (module docstring), with what was assumed."""
    apriori = {**{k: float(v) for k, v in (ac.derivatives or {}).items()}}
    apriori.update({k: float(v["value"]) for k, v in (ac.apriori or {}).items()})
    t = U.index.to_numpy()
    out = {}
    if "de" in U:
        c = {"m": ac.mass, "Iyy": ac.Iyy, "S": ac.S, "cbar": ac.cbar, "rho": rho}
        model = longitudinal(c)
        model = model.with_values({k: v for k, v in apriori.items() if k in model.parameter_names})
        x0, u0 = trim_level(model, speed)
        u = np.column_stack([u0[0] + U["de"].to_numpy(), np.full(t.size, u0[1])])
        out["longitudinal"] = _bounds(model, t, u, x0, noise)
    if {"da", "dr"} & set(U.columns):
        c = {"m": ac.mass, "Ixx": ac.Ixx, "Izz": ac.Izz, "Ixz": ac.Ixz, "S": ac.S, "b": ac.b, "rho": rho, "V": speed}
        model = lateral_directional(c)
        model = model.with_values({k: v for k, v in apriori.items() if k in model.parameter_names})
        u = np.column_stack([U[s].to_numpy() if s in U else np.zeros(t.size) for s in ("da", "dr")])
        out["lateral"] = _bounds(model, t, u, np.zeros(4), noise)
    return out


def _bounds(model: Any, t: np.ndarray, u: np.ndarray, x0: np.ndarray, noise: Mapping[str, float]) -> dict[str, Any]:
    """The Cramér-Rao std of ``model``'s free parameters at its values for one flight of
    inputs ``u`` from ``x0``, measured with ``noise`` (output -> std)."""
    seg = Segment(t=t, u=u, z=np.zeros((t.size, len(model.outputs))), x0=x0)
    values = {p.name: p.value for p in model.parameters}
    y = simulate_outputs(model, seg, values).to_numpy()
    if not np.all(np.isfinite(y)):
        raise FsidError("the aircraft diverges under the designed inputs at these derivatives; lower the amplitude")
    sd = np.array([noise.get(o, np.nan) for o in model.outputs])
    keep = np.isfinite(sd) & (sd > 0)
    m = model.select_outputs([o for o, k in zip(model.outputs, keep) if k])
    seg = Segment(t=t, u=u, z=y[:, keep], x0=x0)
    try:
        res = OutputError(m, fallback="never").fit(seg, estimate_x0=False, R=np.diag(sd[keep] ** 2), start=values)
    except EstimationError as exc:
        raise FsidError(f"the predicted accuracy cannot be computed: {exc}") from None
    params = {
        n: {"value": float(res.params[n]), "std": num(res.std[n]), "rel_std_pct": num(res.rel_std[n])}
        for n in res.free_names
    }
    return {
        "model": model.name,
        "outputs": list(m.outputs),
        "noise_std": dict(zip(m.outputs, sd[keep].tolist())),
        "parameters": params,
        "_cov": (list(res.free_names), np.asarray(res.cov)),
    }


def with_previous(pred: dict[str, dict[str, Any]], log: str | Path, aircraft: str | Path) -> str:
    """Add to each axis's prediction what a previous flight ``log`` already knows and what
    the new one adds: output error on the log (``fsid estimate``'s job), its covariance of
    the derivatives both fits share, and per derivative its std, the std of both flights
    together (their information added: (C_log^-1 + C_design^-1)^-1 over the shared ones, each
    marginal over its own other parameters) and the gain std_log / std_both. Returns a note."""
    from pipeline.jobs.estimate import estimate  # the estimate job: on use only
    from pipeline.jobs.options import EstimateOptions

    try:
        est = estimate(log, EstimateOptions(aircraft=aircraft, methods=["oem"], quiet=True, figures=False))
    except FsidError as exc:
        return f"the previous log {log} gives no estimate to add to: {exc}"
    notes = []
    for axis, d in pred.items():
        names, Cd = d["_cov"]
        fits = [r for r in est.results.values() if r.converged]
        best = max(fits, key=lambda r: len(set(r.free_names) & set(names)), default=None)
        common = [n for n in names if best is not None and n in best.free_names]
        if not common:
            notes.append(f"{axis}: the previous log has no fit of these derivatives")
            continue
        i_d = [names.index(n) for n in common]
        i_p = [best.free_names.index(n) for n in common]
        Cp = np.asarray(best.cov)[np.ix_(i_p, i_p)]
        Cd_c = Cd[np.ix_(i_d, i_d)]
        both = np.linalg.inv(np.linalg.inv(Cp) + np.linalg.inv(Cd_c))
        for k, n in enumerate(common):
            p = d["parameters"][n]
            p["previous_estimate"] = float(best.params[n])
            p["previous_std"] = num(float(np.sqrt(Cp[k, k])))
            p["combined_std"] = num(float(np.sqrt(both[k, k])))
            p["gain"] = num(float(np.sqrt(Cp[k, k] / both[k, k])))
        d["previous"] = {"log": str(log), "fit": best.method, "derivatives": common}
    return "; ".join(notes)


def _player(inputs: Sequence[str], servo_travel: Mapping[str, tuple[float, str]]) -> dict[str, Any]:
    """The Lua player's document: its file, each surface's travel (deg at full servo throw)
    and where that came from, its switch and attitude limits."""
    travel = {u: servo_travel[u][0] if u in servo_travel else DEFAULT_TRAVEL_DEG for u in inputs}
    missing = [u for u in inputs if u not in servo_travel]
    return {
        "file": "fsid_player.lua",
        "travel_deg": travel,
        "travel_from": (
            "the aircraft file's [servos]"
            if not missing
            else f"assumed {DEFAULT_TRAVEL_DEG:g} deg for {', '.join(missing)}, which the aircraft file's [servos] "
            f"does not give ({missing[0]}_travel_deg = ...): the played deflections scale with it"
        ),
        "switch_option": SWITCH_OPTION,
        "roll_limit_deg": ROLL_LIMIT_DEG,
        "pitch_limit_deg": PITCH_LIMIT_DEG,
    }


def design(out: str | Path | None, opts: DesignOptions) -> dict[str, Path]:
    """``fsid design`` into ``out`` (module docstring); returns name -> path."""
    from pipeline.outputs.design import write_design  # matplotlib: on use only

    out = new_run_dir("design", out, inputs=[opts.aircraft])
    bad = [u for u in opts.inputs if u not in SURFACES]
    if bad:
        raise FsidError(f"--inputs {', '.join(bad)}: design inputs are {', '.join(SURFACES)}")
    pr = Progress(3 + (opts.log is not None), quiet=opts.quiet)
    pr.stage(f"design {', '.join(opts.inputs)} in {opts.band[0]:g}-{opts.band[1]:g} Hz over {opts.duration:g} s")
    amp = {u: (opts.amplitude or {}).get(u, np.radians(3.0)) for u in opts.inputs}
    try:
        U = orthogonal_multisines(list(opts.inputs), opts.band, opts.duration, 1.0 / opts.rate, amp)
    except ValueError as exc:
        raise FsidError(f"input design: {exc}") from None
    pr.done(", ".join(f"{u} RPF {r:.3f}" for u, r in U.attrs["rpf"].items()))
    ac_file = read_aircraft_file(opts.aircraft)
    ac = ac_file.constants
    speed = opts.speed or (1.4 * ac.stall_speed if ac.stall_speed else None)
    if not speed:
        raise FsidError("give the trim airspeed with --speed M/S (the aircraft file gives no stall_speed_mps)")
    pr.stage(f"predicted accuracy at {speed:g} m/s, {opts.altitude:g} m")
    rho = float(isa_density(opts.altitude))
    pred = predicted_accuracy(U, ac, speed, rho, default_noise_si())
    pr.done(", ".join(f"{a}: {len(d['parameters'])} derivatives" for a, d in pred.items()))
    previous_note = ""
    if opts.log is not None:
        pr.stage(f"what the previous flight {Path(opts.log).name} knows, and what this one adds")
        previous_note = with_previous(pred, opts.log, opts.aircraft)
        pr.done(previous_note or "output error on it, the information of both flights added")
    for d in pred.values():
        d.pop("_cov", None)
    pr.stage("write inputs.csv, design.json, figures, report.md, report.html")
    doc = {
        "run_id": run_id(out),
        "aircraft": str(opts.aircraft),
        "inputs": list(opts.inputs),
        "band_hz": list(opts.band),
        "duration_s": opts.duration,
        "rate_hz": opts.rate,
        "amplitude_rad": amp,
        "frequencies_hz": {u: [float(x) for x in f] for u, f in U.attrs["frequencies"].items()},
        "rpf": {u: float(r) for u, r in U.attrs["rpf"].items()},
        "trim": {"speed_mps": speed, "altitude_m": opts.altitude, "rho_kgm3": rho},
        "apriori_from": "the aircraft file's [apriori] (a truth set's [derivatives]) where given, else the built-in "
        "models' defaults",
        "predicted": pred,
        **({"previous_log": str(opts.log), "previous_note": previous_note} if opts.log is not None else {}),
        "player": _player(opts.inputs, ac_file.servo_travel),
    }
    with staged(out, "design.json") as stage:
        paths = write_design(stage, U, doc)
        atomic_write_text(stage / "design.json", json.dumps(doc, indent=1, allow_nan=False))
    pr.done()
    return {name: out / rel for name, rel in {**paths, "design.json": "design.json"}.items()}
