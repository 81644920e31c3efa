"""``report.md`` and ``report.json``: the human and the machine view of one run.

``report.json`` (schema ``fsid-report/1``)::

    {"schema": "fsid-report/1",
     "meta": {...},                      # as given (scenario, log, seed, versions, ...)
     "checks": {...} | null,             # data-quality summary, as given
     "compatibility": {...} | null,      # sensor-compatibility stage (pipeline.conditioning.compatibility.
                                         # correct_for_estimation): status, parameters, applied
     "truth": {name: value} | null,
     "methods": {
       "<method>": {
         "model", "converged", "iterations", "message", "det_R", "n_samples",
         "outputs": [...], "R": [[...]],
         "parameters": {"<name>": {"estimate", "std", "rel_std_pct", "truth",
                                   "error_in_std", "mk_std", "cluster_std", "at_bound",
                                   "consider_std", "total_std"}},   # last two: see below
         "fixed": {"<name>": value},
         "correlations_flagged": [[a, b, rho], ...],
         "consider_source": str | null,   # what consider_std accounts for
         "std_method": "crb" | "filter-covariance" | "propagated" | "morelli-klein" | ...,  # how std was computed
         "noise_std": {"<output>": float} | null,   # noise fed back (soem, decouple)
         "fit": {"<output>": {"TIC", "UM", "US", "UC", "R2", "RMS", ...}},
         "validation": {...}            # pipeline.validation.validate.validate() minus "arrays", plus
                                        # "problem": {"notes"} (how the data were prepared:
                                        # grid, pseudo-inputs, input smoothing corners, ...)
         "verdict": {"level", "ok", "reasons", "reason_levels", "notes"}}}}
                                        # level PASS / CHECK / FAIL (pipeline.validation.validate.
                                        # REASON_LEVELS), ok == (level == "PASS")

Numbers are SI (per radian for derivatives) with NaN written as ``null``. ``estimate`` and
``std`` are exactly the result's ``params``/``std`` (Cramér-Rao, unless ``std_method``
says otherwise: stabilised OEM and equation decoupling carry the measurement noise they
feed back into the model, :mod:`estimators.output_error.pseudo_input_noise`); ``mk_std`` the
Morelli-Klein corrected std; ``cluster_std`` the maneuver-to-maneuver scatter (each
maneuver a cluster, :mod:`estimators.validation.cluster`; null with one maneuver,
for EKF/UKF, or where one maneuver carries the parameter). When the fit held something uncertain as exact (sensor
corrections applied before it, another axis' estimates), ``consider_std`` is that
uncertainty carried to the parameter and ``total_std`` = sqrt(std^2 + consider_std^2),
which ``error_in_std`` then uses (:mod:`pipeline.uncertainty.consider`;
``compatibility.propagation`` and the validation's ``held_estimates`` say what was done). ``report.md`` shows the same numbers, angles in degrees where a
person reads them (proof-of-match bands and errors). Both files are written atomically.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from estimators import EstimationResult
from estimators.results import std_label
from estimators.validation import NOISE_ALPHA
from pipeline.paths import atomic_write_text
from pipeline.validation.validate import display_unit, is_segment_parameter, json_ready, num, verdict

SCHEMA = "fsid-report/1"


# -- JSON -------------------------------------------------------------------------------------
def method_json(
    result: EstimationResult, validation: Mapping[str, Any] | None, truth: Mapping[str, float] | None
) -> dict[str, Any]:
    """The ``methods.<method>`` entry of report.json for one result and its validation."""
    d = result.to_dict(dict(truth) if truth else None)
    params = {}
    val = json_ready(validation) if validation else {}
    mk = (val.get("uncertainty") or {}).get("per_parameter") or {}
    for name, p in d["parameters"].items():
        p = dict(p)
        p.setdefault("truth", (truth or {}).get(name) if truth else None)
        p.setdefault("error_in_std", None)
        p["mk_std"] = (mk.get(name) or {}).get("mk_std")
        p["cluster_std"] = (mk.get(name) or {}).get("cluster_std")
        params[name] = p
    d["parameters"] = params
    d["fixed"] = num(
        {n: v for n, v, f in zip(result.names, result.values, result.free) if not f and not n.startswith("x0_")}
    )
    d["consider_source"] = result.consider_source or None
    # how std was computed when it is not the Cramér-Rao bound (estimators.output_error.stabilized), and
    # the measurement noise std a fed-back-measurement method inferred per output
    d["std_method"] = result.std_method
    d["noise_std"] = result.extra.get("noise_std")
    d["fit"] = (val.get("fit") or {}).get("per_output", {})
    d["validation"] = val
    d["verdict"] = val.get("verdict") or verdict({"converged": result.converged})
    return num(d)


def report_dict(
    results: Mapping[str, EstimationResult],
    validations: Mapping[str, Mapping[str, Any]],
    *,
    truth: Mapping[str, float] | None = None,
    meta: Mapping[str, Any] | None = None,
    checks: Any = None,
    compatibility: Mapping[str, Any] | None = None,
    agreement: Mapping[str, Any] | None = None,
) -> dict[str, Any]:
    """The full report.json content (see module doc)."""
    return {
        "schema": SCHEMA,
        "meta": num(dict(meta or {})),
        "checks": num(checks),
        "compatibility": num(dict(compatibility)) if compatibility is not None else None,
        "truth": num(dict(truth)) if truth else None,
        "agreement": num(dict(agreement)) if agreement else None,
        "methods": {m: method_json(r, validations.get(m), truth) for m, r in results.items()},
    }


# -- Markdown ---------------------------------------------------------------------------------
def _g(x: Any, fmt: str = ".4g") -> str:
    """A number for a table cell; '-' for missing/NaN."""
    if x is None or isinstance(x, str):
        return x or "-"
    if isinstance(x, (bool, np.bool_)):
        return "yes" if x else "no"
    x = float(x)
    return format(x, fmt) if math.isfinite(x) else "-"


def _table(head: list[str], rows: list[list[str]]) -> list[str]:
    out = ["| " + " | ".join(head) + " |", "|" + "|".join("---" for _ in head) + "|"]
    out += ["| " + " | ".join(r) + " |" for r in rows]
    return out + [""]


def has_total_std(mj: Mapping[str, Any]) -> bool:
    """Whether the method's std has a consider part (sensor corrections, held estimates)."""
    return any(p.get("total_std") is not None for p in mj["parameters"].values())


def has_cluster_std(mj: Mapping[str, Any]) -> bool:
    """Whether the method's validation has the maneuver-scatter std."""
    return bool(((mj.get("validation") or {}).get("uncertainty") or {}).get("cluster"))


def param_rows(mj: Mapping[str, Any], with_truth: bool, *, segment: bool | None = False) -> list[list[str]]:
    """Rows of the parameter table: name, estimate, std, rel std %, (std total when the
    result has a consider part), (truth, |error|/std), Morelli-Klein std, (maneuver-scatter
    std, system parameters, when the validation has it), note. segment: False system
    parameters only, True per-segment ones only, None all."""
    rows = []
    total = has_total_std(mj)
    scatter = has_cluster_std(mj) and segment is False
    for name, p in mj["parameters"].items():
        if segment is not None and is_segment_parameter(name) != segment:
            continue
        r = [name, _g(p["estimate"], ".6g"), _g(p["std"]), _g(p["rel_std_pct"], ".2f")]
        if total:
            r.append(_g(p.get("total_std")))
        if with_truth:
            r += [_g(p.get("truth"), ".6g"), _g(p.get("error_in_std"), ".2f")]
        r += [_g(p.get("mk_std"))] + ([_g(p.get("cluster_std"))] if scatter else [])
        r += ["at bound" if p.get("at_bound") else ""]
        rows.append(r)
    return rows


#: what the levels mean (pipeline.validation.validate.REASON_LEVELS), under the summary table
VERDICT_LEGEND = (
    "Verdict FAIL: the run shows the estimates wrong or unfinished (not converged, "
    "off the truth, an EKF/UKF disagreeing with filter error, a proof-of-match "
    "miss beyond the prediction's own uncertainty or with none to weigh it); "
    "CHECK: not proven right (a TIC over the limit, a miss within that "
    "uncertainty); PASS: neither."
)


def verdict_level(vd: Mapping[str, Any]) -> str:
    """PASS / CHECK / FAIL of a verdict dict; one written before the levels (``ok`` only)
    reads PASS or CHECK, as it was reported then."""
    return vd.get("level") or ("PASS" if vd.get("ok") else "CHECK")


def _verdict_reasons(vd: Mapping[str, Any]) -> str:
    """The reasons after the verdict's level: " - a; b", the milder ones of a FAIL after
    "to check too:"."""
    reasons = list(vd.get("reasons") or [])
    if not reasons:
        return ""
    levels = list(vd.get("reason_levels") or [])
    if len(levels) != len(reasons) or verdict_level(vd) != "FAIL":
        return " - " + "; ".join(reasons)
    fail = [r for r, lv in zip(reasons, levels) if lv == "FAIL"]
    rest = [r for r, lv in zip(reasons, levels) if lv != "FAIL"]
    return " - " + "; ".join(fail) + ("; to check too: " + "; ".join(rest) if rest else "")


def _method_md(m: str, mj: Mapping[str, Any], with_truth: bool) -> list[str]:
    v = mj.get("validation") or {}
    vd = mj["verdict"]
    L = [f"## {m.upper()} ({mj['model']})", ""]
    L.append(f"**Verdict: {verdict_level(vd)}**" + _verdict_reasons(vd))
    L += [f"- note: {n}" for n in vd.get("notes", [])]
    L += [
        "",
        f"Converged: {'yes' if mj['converged'] else 'NO'} after {mj['iterations']} "
        f"iterations; det(R) = {_g(mj['det_R'], '.4e')}; {mj['n_samples']} samples."
        + (f" {mj['message']}" if mj.get("message") else ""),
        "",
    ]
    notes = (v.get("problem") or {}).get("notes") or []
    L += ["Data preparation:", ""] + [f"- {n}" for n in notes] + [""] if notes else []
    L += ["### Parameters", ""]
    std_col = std_label(mj.get("std_method") or "crb")
    head = ["parameter", "estimate", std_col, "rel std %"]
    total = ["std (total)"] if has_total_std(mj) else []
    head += total
    if with_truth:
        head += ["truth", "abs(error)/std"]
    head += ["std (Morelli-Klein)"] + (["std (maneuver scatter)"] if has_cluster_std(mj) else []) + [""]
    L += _table(head, param_rows(mj, with_truth))
    cl = (v.get("uncertainty") or {}).get("cluster") or {}
    if cl:
        L += [
            f"std (maneuver scatter): how much the {cl['n_segments']} maneuvers disagree, each "
            "maneuver a cluster of the fit (estimators.validation.cluster; about "
            f"{cl['n_segments'] - 1} degrees of freedom: a rough figure per parameter; '-' where "
            f"one maneuver carries more than {cl['limit']:.0%} of the parameter). Scatter / "
            f"Cramér-Rao: median {_g(cl.get('median_ratio'), '.2f')}, largest "
            f"{_g(cl.get('max_ratio'), '.2f')} ({cl.get('max_parameter')}); above "
            f"{_g(cl.get('flag_ratio'))} the bound understates the uncertainty.",
            "",
        ]
    if total:
        L += [
            "std (total) = sqrt(CRB^2 + consider^2), the consider part from what the fit "
            f"held as exact ({mj.get('consider_source') or '-'}; each moved by one std, the "
            "fit repeated); abs(error)/std uses it.",
            "",
        ]
    seg_rows = param_rows(mj, False, segment=True)
    if seg_rows:
        L += ["Per-segment parameters (biases, initial states; `[k]` is the segment):", ""]
        L += _table(["parameter", "estimate", std_col, "rel std %", *total, "std (Morelli-Klein)", ""], seg_rows)
    if mj.get("fixed"):
        L += ["Fixed: " + ", ".join(f"{n} = {_g(x)}" for n, x in mj["fixed"].items()), ""]
    if mj.get("correlations_flagged"):
        L += [
            "Correlation |rho| > 0.9: " + ", ".join(f"{a}~{b} ({r:+.3f})" for a, b, r in mj["correlations_flagged"]),
            "",
        ]
    fit = mj.get("fit") or {}
    white = ((v.get("residuals") or {}).get("whiteness")) or {}
    if fit:
        L += [
            "### Fit and residuals",
            "",
            "TIC: Theil inequality coefficient with bias (UM), variance (US) and covariance "
            "(UC) proportions; residual RMS and mean in the unit shown (report.json: SI); "
            "Ljung-Box whiteness of the residuals and its p-value.",
            "",
        ]
        rows = []
        for o, f in fit.items():
            w = white.get(o, {})
            fac, unit = display_unit(o)
            scale = lambda x, fac=fac: None if x is None else x * fac
            rows.append(
                [
                    o,
                    unit,
                    _g(f["TIC"], ".4f"),
                    _g(f["UM"], ".3f"),
                    _g(f["US"], ".3f"),
                    _g(f["UC"], ".3f"),
                    _g(f["R2"], ".4f"),
                    _g(scale(f["RMS"])),
                    _g(scale(f["mean"])),
                    _g(w.get("white")),
                    _g(w.get("p_value"), ".3f"),
                ]
            )
        L += _table(["output", "unit", "TIC", "UM", "US", "UC", "R2", "RMS", "mean", "white", "p"], rows)
    modes = v.get("modes") or {}
    if modes.get("table"):
        L += ["### Modes (model linearised at the first sample)", ""]
        rows = []
        for name, d in modes["table"].items():
            rows.append(
                [
                    name,
                    f"{_g(d['real'])} {'+' if (d['imag'] or 0) >= 0 else '-'} {_g(abs(d['imag'] or 0))}j",
                    _g(d["wn"]),
                    _g(d["zeta"], ".3f"),
                    _g(d["period"]),
                    _g(d["t_half"]),
                    _g(d["t_double"]),
                    "yes" if d["stable"] else "NO",
                ]
            )
        L += _table(
            ["mode", "eigenvalue (1/s)", "wn (rad/s)", "zeta", "period (s)", "t_half (s)", "t_double (s)", "stable"],
            rows,
        )
    elif modes.get("error"):
        L += [f"Modes: not computed ({modes['error']}).", ""]
    pm = v.get("proof_of_match")
    L += ["### Proof of match", ""]
    if not pm:
        L += ["No held-out maneuver: not run.", ""]
    else:
        if pm.get("mode") == "air-data":
            L += [
                f"Mode **air-data**: the identified model, every parameter held, is driven by "
                f"the measured {', '.join(pm['driven'])} through a Kalman filter that sees only "
                "those channels (the gusts enter where the air data measure them; an unstable "
                "model stays anchored); the other channels are the model's prediction and are "
                "judged. Driving channels are not judged.",
                "",
            ]
        else:
            L += [
                "Mode **simulation**: open-loop simulation of the held-out maneuver, every "
                "derivative held, initial state and output biases fitted.",
                "",
            ]
        L += [f"Note: {n}." for n in pm.get("notes") or ()] + ([""] if pm.get("notes") else [])
        for s in pm["segments"]:
            L += [f"Held-out segment **{s['name']}**: {'PASS' if s['all_pass'] else 'FAIL'}", ""]
            allow = {
                c: d
                for c, d in s["channels"].items()
                if d.get("pass") is not None and (d.get("noise_allowance_display") or 0) > 0
            }
            if allow:
                L += [
                    "Each band is widened by what the channel's measurement noise (its white "
                    "level in this segment, from the second differences of the error against "
                    "the prediction) reaches over the "
                    f"segment's samples with {100 * (1 - NOISE_ALPHA):g} % probability: "
                    + ", ".join(f"{c} +{_g(d['noise_allowance_display'])} {d['unit']}" for c, d in allow.items())
                    + ".",
                    "",
                ]
            timing = s.get("input_timing") or {}
            if timing.get("envelope"):
                wide = {
                    c: d
                    for c, d in s["channels"].items()
                    if d.get("pass") is not None and (d.get("envelope_max_width_display") or 0) > 0
                }
                L += [
                    f"Control-input steps between two slow samples: {timing['steps']} "
                    f"({timing['untimed']} untimed). The model also predicted the segment with "
                    "each moved through the range of its time (an untimed one across its "
                    f"interval, a timed one {timing['timed_range_std']:g} std either side, at "
                    f"{', '.join(f'{f:g}' for f in timing['fractions'])} of that range), and a "
                    "sample's error is its distance from the range of those predictions and "
                    "the fitted one. Without that, the largest errors were: "
                    + ", ".join(
                        f"{c} {_g(d.get('nominal_max_abs_error_display'))} {d['unit']} "
                        f"(range up to {_g(d.get('envelope_max_width_display'))})"
                        for c, d in wide.items()
                    )
                    + ".",
                    "",
                ]
            elif timing:
                L += [
                    f"{timing['steps']} control-input step(s) between slow samples: the "
                    "predictions with them moved failed (see the notes); judged on the "
                    "steps as fitted.",
                    "",
                ]
            pu = s.get("prediction_uncertainty")
            if pu:
                L += [
                    "\"model std\": the prediction's own std from the covariance of the "
                    f"{pu['parameters']} estimated derivatives (pointwise, its largest value; "
                    + (
                        "the segment's initial state and biases refitted"
                        if s.get("mode") == "simulation"
                        else "the filter's gain moving with them"
                    )
                    + "); \"beyond\": how far "
                    f"the misses reach beyond {pu['k']:g} of it on a failed channel (0: the "
                    "estimates' imprecision explains them).",
                    "",
                ]
            rows = []
            for c, d in s["channels"].items():
                judged = d.get("pass")
                rows.append(
                    [
                        c,
                        d["unit"],
                        _g(d.get("tolerance_display")),
                        _g(d.get("max_abs_error_display")),
                        _g(d.get("rms_error_display")),
                        _g(d.get("fraction_within"), ".3f"),
                        _g(d.get("TIC"), ".4f"),
                    ]
                    + (
                        [
                            _g(d.get("prediction_std_max_display")),
                            _g(d.get("beyond_prediction_display")) if judged is False else "-",
                        ]
                        if pu
                        else []
                    )
                    + [
                        "driving"
                        if d.get("role") == "drives the filter"
                        else "-"
                        if judged is None
                        else ("pass" if judged else "FAIL")
                    ]
                )
            L += _table(
                ["channel", "unit", "tolerance", "max abs error", "rms error", "fraction within", "TIC"]
                + (["model std", "beyond"] if pu else [])
                + ["result"],
                rows,
            )
    fr = v.get("frequency")
    if fr and fr.get("table"):
        b = fr["bounds"]
        L += [
            "### Frequency response (model vs spectral estimate)",
            "",
            f"Segment {fr['segment']}; bounds {b['mag_db']} dB / {b['phase_deg']} deg where "
            f"coherence >= {b['min_coherence']} and the input carries power.",
            "",
        ]
        rows = [
            [
                k,
                _g(d["max_mag_db"], ".2f"),
                _g(d["max_phase_deg"], ".1f"),
                str(d["n_used"]),
                ("pass" if d["pass"] else "FAIL") if d["n_used"] else "-",
            ]
            for k, d in fr["table"].items()
        ]
        L += _table(["output/input", "max abs mag (dB)", "max abs phase (deg)", "points", "result"], rows)
    inv = v.get("inverse_simulation")
    if inv and inv.get("per_input"):
        L += [
            "### Inverse simulation",
            "",
            f"Inputs the linearised model needs beyond the flown ones to follow "
            f"{', '.join(inv.get('tracked', []))} on segment {inv['segment']} (feedback "
            f"bandwidth {_g(inv.get('bandwidth'))} rad/s; small residual inputs: the model "
            "explains the response).",
            "",
        ]
        rows = [
            [i, d["unit"], _g(d["rms_residual_display"]), _g(d["ratio"], ".3f")] for i, d in inv["per_input"].items()
        ]
        L += _table(["input", "unit", "rms residual input", "rms residual / rms flown input"], rows)
    ap = (v.get("plausibility") or {}).get("apriori")
    if ap:
        L += ["### Plausibility against a-priori values", ""]
        rows = [
            [
                n,
                _g(d["estimate"]),
                _g(d["apriori"]),
                _g(d["combined_std"]),
                _g(d["z"], ".2f"),
                "FLAG" if d["flag"] else "",
            ]
            for n, d in ap.items()
        ]
        L += _table(["parameter", "estimate", "a priori", "combined std", "z", ""], rows)
    return L


def _checks_body(checks: Mapping[str, Any]) -> list[str]:
    L: list[str] = []
    summary = checks.get("summary")
    if isinstance(summary, Mapping):
        L += [", ".join(f"{k}: {x}" for k, x in summary.items()), ""]
    findings = checks.get("findings")
    if isinstance(findings, list):
        bad = [f for f in findings if isinstance(f, Mapping) and f.get("status") != "pass"]
        if bad:
            L += _table(
                ["status", "check", "channel", "message"],
                [
                    [
                        str(f.get("status")),
                        str(f.get("check")),
                        str(f.get("channel") or "-"),
                        str(f.get("message")).replace("|", "/"),
                    ]
                    for f in bad
                ],
            )
    for k, x in checks.items():
        if k in ("summary", "findings"):
            continue
        if isinstance(x, (str, int, float, bool)):
            L.append(f"- {k}: {x}")
        elif isinstance(x, Mapping) and ("summary" in x or "findings" in x):
            L += ["", f"**{k}**: "] + _checks_body(x)
        elif isinstance(x, Mapping) and all(isinstance(y, (str, int, float, bool)) for y in x.values()):
            L.append(f"- {k}: " + ", ".join(f"{a}: {b}" for a, b in x.items()))
    return L


def _checks_md(checks: Any) -> list[str]:
    """The data-checks section: a checks.json document's summary counts and every finding
    that is not a pass (status, check, channel, message); several such documents (or
    summaries) keyed by log name are listed one after another; scalars as they are."""
    if not isinstance(checks, Mapping) or not checks:
        return []
    return ["## Data checks", ""] + _checks_body(checks) + [""]


def _compat_md(comp: Any) -> list[str]:
    """The sensor-compatibility section: status, the estimated sensor errors with std (and
    truth) and which were removed from the data estimation saw."""
    if not isinstance(comp, Mapping) or not comp:
        return []
    L = ["## Sensor compatibility", ""]
    st = comp.get("status")
    if st in ("skipped", "failed"):
        return L + [f"{st}: {comp.get('reason', '')}. Estimation used the data as logged.", ""]
    params = comp.get("parameters") or {}
    applied = comp.get("applied") or {}
    L += [
        f"Flight path reconstruction ({comp.get('method', 'oem')}): {st}, "
        f"{comp.get('iterations', '-')} iterations, {len(comp.get('segments') or [])} segments"
        + (f", {_g(comp.get('seconds'), '.1f')} s" if comp.get("seconds") is not None else "")
        + f". Data for estimation: {comp.get('data_for_estimation', '-')}.",
        "",
    ]
    if comp.get("rule"):
        L += [f"Rule: {comp['rule']}." + (f" Note: {comp['note']}." if comp.get("note") else ""), ""]
    for key, label in (("scope", "Scope"), ("wind_note", "Wind"), ("std_note", "Std")):
        if comp.get(key):
            L += [f"{label}: {comp[key]}.", ""]
    rn = comp.get("residual_to_noise") or {}
    if rn:
        L += [
            "Residual std / noise std per output (about 1: the kinematic model explains the "
            "data): " + ", ".join(f"{c} {_g(x, '.2f')}" for c, x in rn.items()) + ".",
            "",
        ]
    with_truth = any(p.get("truth") is not None for p in params.values())
    head = ["sensor error", "unit", "estimate", "std", "abs(estimate)/std"]
    head += ["truth", "abs(error)/std"] if with_truth else []
    head += ["applied"]
    rows = []
    for n, p in params.items():
        est, sd = p.get("estimate"), p.get("std")
        r = [
            n,
            str(p.get("unit") or "-"),
            _g(est, ".5g"),
            _g(sd, ".3g"),
            _g(abs(est) / sd if est is not None and sd else None, ".1f"),
        ]
        if with_truth:
            e = p.get("error_std")
            r += [_g(p.get("truth"), ".5g"), _g(abs(e) if e is not None else None, ".2f")]
        r.append(_g(applied[n]["estimate"], ".5g") if n in applied else "no")
        rows.append(r)
    L += _table(head, rows)
    prop = comp.get("propagation") or {}
    if prop:
        done = [k for k, v in prop.get("methods", {}).items() if v == "propagated"]
        left = {k: v for k, v in prop.get("methods", {}).items() if v != "propagated"}
        L += [
            f"Uncertainty of the applied corrections carried to the estimates: "
            f"{prop.get('refits')} refits ({prop.get('perturbation')}), "
            f"{_g(prop.get('seconds'), '.1f')} s; 'std (total)' in the parameter tables of "
            f"{', '.join(done) or 'no method'}." + "".join(f" {k}: {v}." for k, v in left.items()),
            "",
        ]
    return L


def _agreement_md(agreement: Mapping[str, Any] | None) -> list[str]:
    """The "Method agreement" section: per axis, each parameter's estimate +- std by method
    and the largest pairwise difference in combined std (see
    :func:`pipeline.validation.validate.cross_check_methods`)."""
    L: list[str] = []
    for axis, g in (agreement or {}).items():
        L += [
            f"## Method agreement{f' ({axis})' if axis else ''}",
            "",
            f"Each pair of methods on the parameters both estimate: |difference| / "
            f"sqrt(std_a^2 + std_b^2), flagged above {g['k']:g} (conservative: the fits "
            f"share the flight's noise). {g['n_flagged']} of {len(g['table'])} pairs flagged."
            + (
                f" **{g['odd_one_out']}** disagrees with every other method, which agree among "
                f"themselves: its assumptions are the first to doubt."
                if g.get("odd_one_out")
                else ""
            ),
            "",
        ]
        methods = list(g["methods"])
        cells: dict[str, dict[str, str]] = {}
        worst: dict[str, tuple[float, str]] = {}
        for r in g["table"]:
            n = r["parameter"]
            for side in ("a", "b"):
                cells.setdefault(n, {})[r[f"method_{side}"]] = (
                    f"{_g(r[f'estimate_{side}'], '.5g')} +- {_g(r[f'std_{side}'], '.2g')}"
                )
            z = r["z"] if r["z"] is not None else math.nan
            if n not in worst or z > worst[n][0]:
                worst[n] = (z, f"{r['method_a']} / {r['method_b']}")
        rows = [
            [n]
            + [cells[n].get(m, "-") for m in methods]
            + [_g(worst[n][0], ".2f"), worst[n][1], "FLAG" if worst[n][0] > g["k"] else ""]
            for n in cells
        ]
        L += _table(["parameter", *methods, "largest z", "pair", ""], rows)
    return L


def _pom_cell(pm: Mapping[str, Any] | None) -> str:
    """The summary table's proof-of-match cell: pass, or FAIL with whether the failed
    channels' misses are within 2 std of the prediction's own uncertainty ("within model
    std": the estimates too imprecise for the band) or some beyond it."""
    if not pm:
        return "-"
    if pm["all_pass"]:
        return "pass"
    beyond = [
        d.get("beyond_prediction_display")
        for sg in pm["segments"]
        for d in sg["channels"].values()
        if d.get("pass") is False
    ]
    if not beyond or any(b is None for b in beyond):
        return "FAIL"
    return "FAIL (beyond model std)" if any(b > 0 for b in beyond) else "FAIL (within model std)"


def report_markdown(rep: Mapping[str, Any]) -> str:
    """report.md text from the report dict of :func:`report_dict`."""
    meta = rep.get("meta") or {}
    L = ["# System-identification report", ""]
    for k, x in meta.items():
        if isinstance(x, (str, int, float, bool)) or x is None:
            L.append(f"- {k}: {x}")
    if meta:
        L.append("")
    with_truth = bool(rep.get("truth"))
    if rep["methods"]:
        L += ["## Summary", ""]
        rows = []
        for m, mj in rep["methods"].items():
            fit = mj.get("fit") or {}
            tics = [d["TIC"] for d in fit.values() if d.get("TIC") is not None]
            pm = (mj.get("validation") or {}).get("proof_of_match")
            rows.append(
                [
                    m,
                    verdict_level(mj["verdict"]),
                    "yes" if mj["converged"] else "NO",
                    _g(mj["det_R"], ".4e"),
                    _g(max(tics) if tics else None, ".4f"),
                    _pom_cell(pm),
                ]
            )
        L += _table(["method", "verdict", "converged", "det(R)", "max TIC", "proof of match"], rows)
        L += [VERDICT_LEGEND, ""]
    L += _agreement_md(rep.get("agreement"))
    L += _checks_md(rep.get("checks"))
    L += _compat_md(rep.get("compatibility"))
    for m, mj in rep["methods"].items():
        L += _method_md(m, mj, with_truth)
    return "\n".join(L).rstrip() + "\n"


def write_report(
    out_dir: str | Path,
    results: Mapping[str, EstimationResult],
    validations: Mapping[str, Mapping[str, Any]],
    *,
    truth: Mapping[str, float] | None = None,
    meta: Mapping[str, Any] | None = None,
    checks: Any = None,
    compatibility: Mapping[str, Any] | None = None,
    agreement: Mapping[str, Any] | None = None,
) -> tuple[Path, Path]:
    """Write ``out_dir/report.md`` and ``out_dir/report.json`` atomically.

    results: method name -> result; validations: method name -> :func:`pipeline.validation.validate.
    validate` output (missing ones are fine); truth: true parameter values; meta: flat
    facts shown at the top (scenario, log, seed, ...); checks: the checks.json document
    (dict or its JSON text from :func:`pipeline.conditioning.checks.findings_to_json`): its ``summary``
    and non-pass ``findings`` are listed in report.md, the whole is kept in report.json;
    compatibility: the sensor-compatibility stage's document (a "Sensor compatibility"
    section in report.md, key ``compatibility`` in report.json); agreement: the methods'
    cross-check (:func:`pipeline.validation.validate.cross_check_methods`; a "Method agreement" section,
    key ``agreement``). Returns (md path, json path).
    """
    out = Path(out_dir)
    if isinstance(checks, (str, bytes)):
        checks = json.loads(checks)
    rep = report_dict(
        results, validations, truth=truth, meta=meta, checks=checks, compatibility=compatibility, agreement=agreement
    )
    pj = atomic_write_text(out / "report.json", json.dumps(rep, indent=2, allow_nan=False) + "\n")
    pm = atomic_write_text(out / "report.md", report_markdown(rep))
    return pm, pj
