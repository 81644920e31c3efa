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
         "validation": {...}            # pipeline.validation.validate() minus "arrays", plus
                                        # "problem": {"notes"} (how the data were prepared:
                                        # grid, pseudo-inputs, input smoothing corners, ...)
         "verdict": {"level", "ok", "reasons", "reason_levels", "notes"}}}}
                                        # level PASS / CHECK / FAIL (pipeline.validation.
                                        # REASON_LEVELS), ok == (level == "PASS")

Numbers are SI (per radian for derivatives) with NaN written as ``null``. ``estimate`` and
``std`` are exactly the result's ``params``/``std`` (Cramér-Rao, unless ``std_method``
says otherwise: stabilised OEM and equation decoupling carry the measurement noise they
feed back into the model, :mod:`estimators.output_error.pseudo_input_noise`); ``mk_std`` the
Morelli-Klein corrected std; ``cluster_std`` the maneuver-to-maneuver scatter (each
maneuver a cluster, :mod:`estimators.covariance.cluster`; null with one maneuver,
for EKF/UKF, or where one maneuver carries the parameter). When the fit held something uncertain as exact (sensor
corrections applied before it, another axis' estimates), ``consider_std`` is that
uncertainty carried to the parameter and ``total_std`` = sqrt(std^2 + consider_std^2),
which ``error_in_std`` then uses (:mod:`pipeline.uncertainty.consider`;
``compatibility.propagation`` and the validation's ``held_estimates`` say what was done). ``report.md`` shows the same numbers, angles in degrees where a
person reads them (proof-of-match bands and errors). Both files are written atomically.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from estimators import EstimationResult
from pipeline.outputs.figures import FigureRef, render_figures, section_markdown
from pipeline.outputs.markdown import md_text
from pipeline.outputs.method_section import method_md
from pipeline.outputs.run_sections import agreement_md, checks_md, compat_md, summary_md
from pipeline.paths import atomic_write_text
from pipeline.validation import json_ready, num, verdict

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
    d["structure"] = result.extra.get("structure")  # equation error's structure search, when asked
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


def report_markdown(rep: Mapping[str, Any], figures: Mapping[str, list[FigureRef]] | None = None) -> str:
    """report.md text from the report dict of :func:`report_dict`; ``figures``: per method
    its figures (:func:`pipeline.outputs.figures.render_figures`), linked in its section."""
    meta = rep.get("meta") or {}
    L = ["# System-identification report", ""]
    for k, x in meta.items():
        if isinstance(x, (str, int, float, bool)) or x is None:
            L.append(f"- {md_text(k)}: {md_text(x)}")
    if meta:
        L.append("")
    with_truth = bool(rep.get("truth"))
    L += summary_md(rep["methods"])
    L += agreement_md(rep.get("agreement"))
    L += checks_md(rep.get("checks"))
    L += compat_md(rep.get("compatibility"))
    for m, mj in rep["methods"].items():
        L += method_md(m, mj, with_truth, section_markdown((figures or {}).get(m, [])))
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
    figures: bool = False,
) -> tuple[Path, Path]:
    """Write ``out_dir/report.md`` and then ``out_dir/report.json`` atomically, with
    ``figures`` the PNG figures in ``out_dir/figures/`` linked from report.md.

    results: method name -> result; validations: method name -> :func:`pipeline.validation.validate`
    output (missing ones are fine); truth: true parameter values; meta: flat
    facts shown at the top (scenario, log, seed, ...); checks: the checks.json document
    (dict or its JSON text from :func:`pipeline.conditioning.checks.findings_to_json`): its ``summary``
    and non-pass ``findings`` are listed in report.md, the whole is kept in report.json;
    compatibility: the sensor-compatibility stage's document (a "Sensor compatibility"
    section in report.md, key ``compatibility`` in report.json); agreement: the methods'
    cross-check (:func:`pipeline.validation.cross_check_methods`; a "Method agreement" section,
    key ``agreement``). Returns (md path, json path).
    """
    out = Path(out_dir)
    if isinstance(checks, (str, bytes)):
        checks = json.loads(checks)
    rep = report_dict(
        results, validations, truth=truth, meta=meta, checks=checks, compatibility=compatibility, agreement=agreement
    )
    figs = render_figures(out / "figures", results, validations, truth) if figures else None
    pm = atomic_write_text(out / "report.md", report_markdown(rep, figs))
    pj = atomic_write_text(out / "report.json", json.dumps(rep, indent=2, allow_nan=False) + "\n")
    return pm, pj
