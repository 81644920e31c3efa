"""The section of report.md on one method: its verdict, parameter table, fit and
residuals, modes, proof of match, frequency response, inverse simulation and
plausibility, from its ``methods.<method>`` entry of report.json."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from estimators.results import std_label
from estimators.validation import NOISE_ALPHA
from pipeline.outputs.markdown import cell, table
from pipeline.validation import display_unit, is_segment_parameter


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
        r = [name, cell(p["estimate"], ".6g"), cell(p["std"]), cell(p["rel_std_pct"], ".2f")]
        if total:
            r.append(cell(p.get("total_std")))
        if with_truth:
            r += [cell(p.get("truth"), ".6g"), cell(p.get("error_in_std"), ".2f")]
        r += [cell(p.get("mk_std"))] + ([cell(p.get("cluster_std"))] if scatter else [])
        r += ["at bound" if p.get("at_bound") else ""]
        rows.append(r)
    return rows


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


def method_md(
    m: str, mj: Mapping[str, Any], with_truth: bool, figures: Mapping[str, list[str]] | None = None
) -> list[str]:
    """The lines of method ``m``'s section from its report.json entry ``mj``; ``with_truth``:
    the parameter table has the truth columns; ``figures``: report.md lines of its figures
    per subsection ("parameters", "fit", "modes", "proof_of_match", "frequency",
    :func:`pipeline.outputs.figures.section_markdown`), placed after that subsection."""
    v = mj.get("validation") or {}
    fig = figures or {}
    L = _header_md(m, mj, v)
    L += _parameters_md(mj, v, with_truth) + fig.get("parameters", [])
    err = v.get("errors") or {}
    L += _fit_md(mj, v) + _failed_md(err, "fit", "residuals", "uncertainty") + fig.get("fit", [])
    L += _modes_md(v.get("modes") or {}) + fig.get("modes", [])
    L += (_failed_md(err, "proof_of_match") or _match_md(v.get("proof_of_match"))) + fig.get("proof_of_match", [])
    L += (_failed_md(err, "frequency") or _frequency_md(v.get("frequency"))) + fig.get("frequency", [])
    L += _failed_md(err, "inverse_simulation") or _inverse_md(v.get("inverse_simulation"))
    L += _failed_md(err, "truth", "plausibility") + _apriori_md((v.get("plausibility") or {}).get("apriori"))
    L += _structure_md(mj.get("structure"))
    return L


def _structure_md(st: Mapping[str, Any] | None) -> list[str]:
    """What structure each coefficient's data ask for (``--structure``)."""
    if not st:
        return []
    rows = []
    for coef, d in st.items():
        if "error" in d:
            rows.append([coef, "-", "-", "-", d["error"]])
            continue
        how = "F to enter" if d["method"] == "stepwise" else "PSE after"
        entered = [s for s in d["steps"] if s.get("action", "add") == "add" and s.get("term") not in ("bias", "")]
        why = ", ".join(
            f"{s['term']} {s['F']:.3g}" if d["method"] == "stepwise" else f"{s['term']} {s['PSE']:.3g}" for s in entered
        )
        rows.append(
            [
                coef,
                ", ".join(d["selected"]) or "-",
                ", ".join(d["added"]) or "-",
                ", ".join(d["not_needed"]) or "-",
                f"{how}: {why}",
            ]
        )
    method = next((d["method"] for d in st.values() if "method" in d), "")
    return [
        f"### Model structure ({'stepwise regression' if method == 'stepwise' else 'multivariate orthogonal functions'})",
        "",
        "The equation-error regressions searched over the model's terms and nonlinear ones of the same variables; "
        "'the model lacks' are terms the data select that the built-in model has not, 'not needed' its terms the "
        "data do not select.",
        "",
        *table(["coefficient", "selected", "the model lacks", "not needed", "why"], rows),
        "",
    ]


#: the validation's checks (its ``errors`` keys) as report.md names them; those with a
#: section of their own get its heading over the line saying why they failed
CHECK_TITLES = {
    "fit": "Fit metrics",
    "residuals": "Residual analysis",
    "uncertainty": "Morelli-Klein and maneuver-scatter std",
    "proof_of_match": "### Proof of match",
    "frequency": "### Frequency response (model vs spectral estimate)",
    "inverse_simulation": "### Inverse simulation",
    "truth": "Comparison with the truth",
    "plausibility": "Plausibility (signs, a-priori values)",
}


def _failed_md(errors: Mapping[str, str], *stages: str) -> list[str]:
    """One line per check of ``stages`` that raised (the validation's ``errors``): what
    failed and why, where its result would be; [] when none did."""
    L: list[str] = []
    for stage in (s for s in stages if s in errors):
        title = CHECK_TITLES.get(stage, stage)
        head, name = ([title, ""], title.lstrip("# ")) if title.startswith("#") else ([], title)
        L += head + [f"**{name}: not computed** - {errors[stage]}", ""]
    return L


def _header_md(m: str, mj: Mapping[str, Any], v: Mapping[str, Any]) -> list[str]:
    """Title, verdict with its reasons and notes, convergence, and how the data were prepared."""
    vd = mj["verdict"]
    L = [f"## {m.upper()} ({mj['model']})", ""]
    L.append(f"**Verdict: {verdict_level(vd)}**" + _verdict_reasons(vd))
    L += [f"- note: {n}" for n in vd.get("notes", [])]
    L += [
        "",
        f"Converged: {'yes' if mj['converged'] else 'NO'} after {mj['iterations']} "
        f"iterations; det(R) = {cell(mj['det_R'], '.4e')}; {mj['n_samples']} samples."
        + (f" {mj['message']}" if mj.get("message") else ""),
        "",
    ]
    notes = (v.get("problem") or {}).get("notes") or []
    L += ["Data preparation:", ""] + [f"- {n}" for n in notes] + [""] if notes else []
    return L


def _parameters_md(mj: Mapping[str, Any], v: Mapping[str, Any], with_truth: bool) -> list[str]:
    """The parameter tables (system, per-segment), what the scatter and total std mean,
    the fixed parameters and the high correlations."""
    L = ["### Parameters", ""]
    std_col = std_label(mj.get("std_method") or "crb")
    head = ["parameter", "estimate", std_col, "rel std %"]
    total = ["std (total)"] if has_total_std(mj) else []
    head += total
    if with_truth:
        head += ["truth", "abs(error)/std"]
    head += ["std (Morelli-Klein)"] + (["std (maneuver scatter)"] if has_cluster_std(mj) else []) + [""]
    L += table(head, param_rows(mj, with_truth))
    cl = (v.get("uncertainty") or {}).get("cluster") or {}
    if cl:
        L += [
            f"std (maneuver scatter): how much the {cl['n_segments']} maneuvers disagree, each "
            "maneuver a cluster of the fit (estimators.covariance.cluster; about "
            f"{cl['n_segments'] - 1} degrees of freedom: a rough figure per parameter; '-' where "
            f"one maneuver carries more than {cl['limit']:.0%} of the parameter). Scatter / "
            f"Cramér-Rao: median {cell(cl.get('median_ratio'), '.2f')}, largest "
            f"{cell(cl.get('max_ratio'), '.2f')} ({cl.get('max_parameter')}); above "
            f"{cell(cl.get('flag_ratio'))} the bound understates the uncertainty.",
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
        L += table(["parameter", "estimate", std_col, "rel std %", *total, "std (Morelli-Klein)", ""], seg_rows)
    if mj.get("fixed"):
        L += ["Fixed: " + ", ".join(f"{n} = {cell(x)}" for n, x in mj["fixed"].items()), ""]
    if mj.get("correlations_flagged"):
        L += [
            "Correlation |rho| > 0.9: " + ", ".join(f"{a}~{b} ({r:+.3f})" for a, b, r in mj["correlations_flagged"]),
            "",
        ]
    return L


def _fit_md(mj: Mapping[str, Any], v: Mapping[str, Any]) -> list[str]:
    """The fit metrics and residual whiteness per output, RMS and mean in display units."""
    fit = mj.get("fit") or {}
    white = ((v.get("residuals") or {}).get("whiteness")) or {}
    if not fit:
        return []
    L = [
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

        def scale(x, fac=fac):
            return None if x is None else x * fac

        rows.append(
            [
                o,
                unit,
                cell(f["TIC"], ".4f"),
                cell(f["UM"], ".3f"),
                cell(f["US"], ".3f"),
                cell(f["UC"], ".3f"),
                cell(f["R2"], ".4f"),
                cell(scale(f["RMS"])),
                cell(scale(f["mean"])),
                cell(w.get("white")),
                cell(w.get("p_value"), ".3f"),
            ]
        )
    return L + table(["output", "unit", "TIC", "UM", "US", "UC", "R2", "RMS", "mean", "white", "p"], rows)


def _modes_md(modes: Mapping[str, Any]) -> list[str]:
    """The modes of the linearised model, or why they were not computed."""
    if modes.get("table"):
        rows = []
        for name, d in modes["table"].items():
            rows.append(
                [
                    name,
                    f"{cell(d['real'])} {'+' if (d['imag'] or 0) >= 0 else '-'} {cell(abs(d['imag'] or 0))}j",
                    cell(d["wn"]),
                    cell(d["zeta"], ".3f"),
                    cell(d["period"]),
                    cell(d["t_half"]),
                    cell(d["t_double"]),
                    "yes" if d["stable"] else "NO",
                ]
            )
        return ["### Modes (model linearised at the first sample)", ""] + table(
            ["mode", "eigenvalue (1/s)", "wn (rad/s)", "zeta", "period (s)", "t_half (s)", "t_double (s)", "stable"],
            rows,
        )
    if modes.get("error"):
        return [f"Modes: not computed ({modes['error']}).", ""]
    return []


def _match_md(pm: Mapping[str, Any] | None) -> list[str]:
    """The proof of match: its mode, notes, and per held-out segment its channels."""
    L = ["### Proof of match", ""]
    if not pm:
        return L + ["No held-out maneuver: not run.", ""]
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
        L += _match_segment_md(s)
    return L


def _match_segment_md(s: Mapping[str, Any]) -> list[str]:
    """One held-out segment: its result, how its bands were widened, what "model std"
    means, and the table of its channels."""
    L = [f"Held-out segment **{s['name']}**: {'PASS' if s['all_pass'] else 'FAIL'}", ""]
    L += _allowance_md(s) + _timing_md(s)
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
            + '); "beyond": how far '
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
                cell(d.get("tolerance_display")),
                cell(d.get("max_abs_error_display")),
                cell(d.get("rms_error_display")),
                cell(d.get("fraction_within"), ".3f"),
                cell(d.get("TIC"), ".4f"),
            ]
            + (
                [
                    cell(d.get("prediction_std_max_display")),
                    cell(d.get("beyond_prediction_display")) if judged is False else "-",
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
    return L + table(
        ["channel", "unit", "tolerance", "max abs error", "rms error", "fraction within", "TIC"]
        + (["model std", "beyond"] if pu else [])
        + ["result"],
        rows,
    )


def _allowance_md(s: Mapping[str, Any]) -> list[str]:
    """How much each judged channel's band was widened for the segment's measurement noise."""
    allow = {
        c: d
        for c, d in s["channels"].items()
        if d.get("pass") is not None and (d.get("noise_allowance_display") or 0) > 0
    }
    if not allow:
        return []
    return [
        "Each band is widened by what the channel's measurement noise (its white "
        "level in this segment, from the second differences of the error against "
        "the prediction) reaches over the "
        f"segment's samples with {100 * (1 - NOISE_ALPHA):g} % probability: "
        + ", ".join(f"{c} +{cell(d['noise_allowance_display'])} {d['unit']}" for c, d in allow.items())
        + ".",
        "",
    ]


def _timing_md(s: Mapping[str, Any]) -> list[str]:
    """What the control-input steps between slow samples did to the segment's judgement."""
    timing = s.get("input_timing") or {}
    if timing.get("envelope"):
        wide = {
            c: d
            for c, d in s["channels"].items()
            if d.get("pass") is not None and (d.get("envelope_max_width_display") or 0) > 0
        }
        return [
            f"Control-input steps between two slow samples: {timing['steps']} "
            f"({timing['untimed']} untimed). The model also predicted the segment with "
            "each moved through the range of its time (an untimed one across its "
            f"interval, a timed one {timing['timed_range_std']:g} std either side, at "
            f"{', '.join(f'{f:g}' for f in timing['fractions'])} of that range), and a "
            "sample's error is its distance from the range of those predictions and "
            "the fitted one. Without that, the largest errors were: "
            + ", ".join(
                f"{c} {cell(d.get('nominal_max_abs_error_display'))} {d['unit']} "
                f"(range up to {cell(d.get('envelope_max_width_display'))})"
                for c, d in wide.items()
            )
            + ".",
            "",
        ]
    if timing:
        return [
            f"{timing['steps']} control-input step(s) between slow samples: the "
            "predictions with them moved failed (see the notes); judged on the "
            "steps as fitted.",
            "",
        ]
    return []


def _frequency_md(fr: Mapping[str, Any] | None) -> list[str]:
    """The model's frequency response against the spectral estimate, per output/input."""
    if not (fr and fr.get("table")):
        return []
    b = fr["bounds"]
    segs = fr.get("segments") or [fr.get("segment", "?")]
    L = [
        "### Frequency response (model vs data, each input's response conditioned on the others)",
        "",
        f"{'Segment' if len(segs) == 1 else 'Segments'} {', '.join(map(str, segs))}; bounds {b['mag_db']} dB / "
        f"{b['phase_deg']} deg, or {b.get('random_errors', 3):g} random errors of the data's estimate where that "
        f"is wider, where the partial coherence is >= {b['min_coherence']}, the input carries power and the "
        f"estimate rests on {b.get('min_averages', 0):g} averages or more.",
        "",
    ]
    rows = [
        [
            k,
            cell(d["max_mag_db"], ".2f"),
            cell(d["max_phase_deg"], ".1f"),
            str(d["n_used"]),
            ("pass" if d["pass"] else "FAIL") if d["n_used"] else "-",
        ]
        for k, d in fr["table"].items()
    ]
    return L + table(["output/input", "max abs mag (dB)", "max abs phase (deg)", "points", "result"], rows)


def _inverse_md(inv: Mapping[str, Any] | None) -> list[str]:
    """The residual inputs of the inverse simulation, per input."""
    if not (inv and inv.get("per_input")):
        return []
    L = [
        "### Inverse simulation",
        "",
        f"Inputs the linearised model needs beyond the flown ones to follow "
        f"{', '.join(inv.get('tracked', []))} on segment {inv['segment']} (feedback "
        f"bandwidth {cell(inv.get('bandwidth'))} rad/s; small residual inputs: the model "
        "explains the response).",
        "",
    ]
    rows = [
        [i, d["unit"], cell(d["rms_residual_display"]), cell(d["ratio"], ".3f")] for i, d in inv["per_input"].items()
    ]
    return L + table(["input", "unit", "rms residual input", "rms residual / rms flown input"], rows)


def _apriori_md(ap: Mapping[str, Any] | None) -> list[str]:
    """The estimates against their a-priori values."""
    if not ap:
        return []
    rows = [
        [
            n,
            cell(d["estimate"]),
            cell(d["apriori"]),
            cell(d["combined_std"]),
            cell(d["z"], ".2f"),
            "FLAG" if d["flag"] else "",
        ]
        for n, d in ap.items()
    ]
    return ["### Plausibility against a-priori values", ""] + table(
        ["parameter", "estimate", "a priori", "combined std", "z", ""], rows
    )
