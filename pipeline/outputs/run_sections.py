"""The sections of report.md on the whole run: the summary table of the methods, their
agreement, the data checks and the sensor-compatibility stage."""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

from pipeline.outputs.markdown import cell, md_text, table
from pipeline.outputs.method_section import verdict_level

#: what the levels mean (pipeline.validation.REASON_LEVELS), under the summary table
VERDICT_LEGEND = (
    "*What the verdicts mean.* FAIL: the run shows the estimates wrong or unfinished (not "
    "converged, off the truth, an EKF/UKF disagreeing with filter error, a proof-of-match "
    "miss beyond the prediction's own uncertainty or with none to weigh it); "
    "CHECK: not proven right (a TIC over the limit, a miss within that "
    "uncertainty); PASS: neither."
)


def summary_md(methods: Mapping[str, Mapping[str, Any]]) -> list[str]:
    """The summary table: per method its verdict, convergence, det(R), largest TIC and
    proof of match, then what the verdict levels mean; nothing without methods."""
    if not methods:
        return []
    rows = []
    for m, mj in methods.items():
        fit = mj.get("fit") or {}
        tics = [d["TIC"] for d in fit.values() if d.get("TIC") is not None]
        pm = (mj.get("validation") or {}).get("proof_of_match")
        rows.append(
            [
                m,
                verdict_level(mj["verdict"]),
                "yes" if mj["converged"] else "NO",
                cell(mj["det_R"], ".4e"),
                cell(max(tics) if tics else None, ".4f"),
                _pom_cell(pm),
            ]
        )
    L = ["## Summary", ""]
    L += table(["method", "verdict", "converged", "det(R)", "max TIC", "proof of match"], rows)
    return L + [VERDICT_LEGEND, ""]


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


def agreement_md(agreement: Mapping[str, Any] | None) -> list[str]:
    """The "Method agreement" section: per axis, each parameter's estimate +- std by method
    and the largest pairwise difference in combined std (see
    :func:`pipeline.validation.cross_check_methods`)."""
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
                    f"{cell(r[f'estimate_{side}'], '.5g')} +- {cell(r[f'std_{side}'], '.2g')}"
                )
            z = r["z"] if r["z"] is not None else math.nan
            if n not in worst or z > worst[n][0]:
                worst[n] = (z, f"{r['method_a']} / {r['method_b']}")
        rows = [
            [n]
            + [cells[n].get(m, "-") for m in methods]
            + [cell(worst[n][0], ".2f"), worst[n][1], "FLAG" if worst[n][0] > g["k"] else ""]
            for n in cells
        ]
        L += table(["parameter", *methods, "largest z", "pair", ""], rows)
    return L


def checks_md(checks: Any) -> list[str]:
    """The data-checks section: a checks.json document's summary counts and every finding
    that is not a pass (status, check, channel, message); several such documents (or
    summaries) keyed by log name are listed one after another; scalars as they are."""
    if not isinstance(checks, Mapping) or not checks:
        return []
    return ["## Data checks", ""] + _checks_body(checks) + [""]


def _checks_body(checks: Mapping[str, Any]) -> list[str]:
    """The lines of one checks document: summary counts, a table of the findings that are
    not a pass, then its other entries (nested documents in turn)."""
    L: list[str] = []
    summary = checks.get("summary")
    if isinstance(summary, Mapping):
        L += [", ".join(f"{md_text(k)}: {md_text(x)}" for k, x in summary.items()), ""]
    findings = checks.get("findings")
    if isinstance(findings, list):
        bad = [f for f in findings if isinstance(f, Mapping) and f.get("status") != "pass"]
        if bad:
            L += table(
                ["status", "check", "channel", "message"],
                [
                    [
                        md_text(f.get("status")),
                        md_text(f.get("check")),
                        md_text(f.get("channel") or "-"),
                        md_text(f.get("message")),
                    ]
                    for f in bad
                ],
            )
    for k, x in checks.items():
        if k in ("summary", "findings"):
            continue
        if isinstance(x, (str, int, float, bool)):
            L.append(f"- {md_text(k)}: {md_text(x)}")
        elif isinstance(x, Mapping) and ("summary" in x or "findings" in x):
            L += ["", f"**{md_text(k)}**: "] + _checks_body(x)
        elif isinstance(x, Mapping) and all(isinstance(y, (str, int, float, bool)) for y in x.values()):
            L.append(f"- {md_text(k)}: " + ", ".join(f"{md_text(a)}: {md_text(b)}" for a, b in x.items()))
    return L


def compat_md(comp: Any) -> list[str]:
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
        + (f", {cell(comp.get('seconds'), '.1f')} s" if comp.get("seconds") is not None else "")
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
            "data): " + ", ".join(f"{c} {cell(x, '.2f')}" for c, x in rn.items()) + ".",
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
            cell(est, ".5g"),
            cell(sd, ".3g"),
            cell(abs(est) / sd if est is not None and sd else None, ".1f"),
        ]
        if with_truth:
            e = p.get("error_std")
            r += [cell(p.get("truth"), ".5g"), cell(abs(e) if e is not None else None, ".2f")]
        r.append(cell(applied[n]["estimate"], ".5g") if n in applied else "no")
        rows.append(r)
    L += table(head, rows)
    prop = comp.get("propagation") or {}
    if prop:
        done = [k for k, v in prop.get("methods", {}).items() if v == "propagated"]
        left = {k: v for k, v in prop.get("methods", {}).items() if v != "propagated"}
        L += [
            f"Uncertainty of the applied corrections carried to the estimates: "
            f"{prop.get('refits')} refits ({prop.get('perturbation')}), "
            f"{cell(prop.get('seconds'), '.1f')} s; 'std (total)' in the parameter tables of "
            f"{', '.join(done) or 'no method'}." + "".join(f" {k}: {v}." for k, v in left.items()),
            "",
        ]
    return L
