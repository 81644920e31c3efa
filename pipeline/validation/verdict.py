"""The verdict on one fit: PASS / CHECK / FAIL with its reasons and notes, from the
validation dict (:func:`pipeline.validation.validate`)."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from estimators import validation as V
from estimators.defaults import PLAUSIBILITY_K
from estimators.validation.plausibility import SIGN_REASONS
from pipeline.validation.fit import NOISE_FLOOR_RATIO
from pipeline.validation.names import is_method

#: verdict levels, mildest first; a fit's level is the worst of its reasons' (PASS: none)
LEVELS = ("PASS", "CHECK", "FAIL")
#: The level each kind of verdict reason sets (:func:`verdict`). A verdict is never milder
#: than its evidence: FAIL where the run itself shows the estimates wrong or unfinished,
#: CHECK where it shows only that they are not proven right.
#:
#: - ``not converged`` FAIL: the optimiser stopped short or diverged, or the filter passes
#:   did not settle: the numbers are not the method's estimate, nor their std its bound.
#: - ``truth`` FAIL: a simulated run knows the truth; an estimate more than TRUTH_K of its
#:   own std from it is wrong by the tool's own measure.
#: - ``filter error`` FAIL: an EKF/UKF more than the agreement's k combined std from a
#:   converged filter-error fit of the same flight
#:   (:func:`~pipeline.validation.agreement.cross_check_methods`): filter error is the
#:   method to trust in turbulence (DESIGN.md section 8), its noise model holding calm
#:   air as the case without process noise.
#: - ``proof of match beyond`` FAIL: a held-out miss beyond PREDICTION_K std of the
#:   prediction's own uncertainty is not explained by the estimates' imprecision: the
#:   model's form, its inputs or estimates biased beyond their std.
#: - ``proof of match unweighed`` FAIL: a miss with no prediction uncertainty to set it
#:   against: nothing in the run excuses it.
#: - ``proof of match within`` CHECK: every miss within PREDICTION_K std of the
#:   prediction's own uncertainty: the estimates too imprecise for the band, not shown wrong.
#: - ``proof of match none judged`` CHECK: no channel could be judged: unproven, not failed.
#: - ``TIC`` CHECK: an output followed poorly (weakly excited or modelled) is a question for
#:   the engineer, not evidence that the estimates are wrong.
#: - ``wrong sign`` FAIL: a derivative whose sign physics or the declared control sign
#:   convention fixes (:func:`estimators.validation.expected_signs`) estimated on the
#:   wrong side of zero by more than k of its own std: no aircraft flies with it.
#: - ``a priori`` FAIL: an estimate more than k combined std (its own and the a-priori
#:   value's) from an a-priori value the aircraft file gives: the two cannot both hold.
#:
#: Notes set no level: coloured residuals, correlations, frequency-response mismatch, TIC
#: at an output's noise floor, maneuver scatter and disagreements between other pairs of
#: methods (neither of which is the one to trust): context that neither proves nor
#: disproves the estimates.
REASON_LEVELS = {
    "not converged": "FAIL",
    "truth": "FAIL",
    "filter error": "FAIL",
    "proof of match beyond": "FAIL",
    "proof of match unweighed": "FAIL",
    "proof of match within": "CHECK",
    "proof of match none judged": "CHECK",
    "validation error": "CHECK",
    "TIC": "CHECK",
    "wrong sign": "FAIL",
    "a priori": "FAIL",
}
#: why an EKF/UKF that disagrees with filter error fails (DESIGN.md section 8)
FILTER_ERROR_TRUST = (
    "filter error is the method to trust in turbulence (its process noise "
    "model; the EKF/UKF's white process noise biases them in coloured "
    "turbulence)"
)

#: checks whose failure to run is a note, not a reason: they inform, they do not prove
NOTE_ONLY_CHECKS = ("modes", "frequency", "inverse_simulation")
#: (kind of :data:`REASON_LEVELS`, sentence) of a verdict reason
Reason = tuple[str, str]


def verdict(v: Mapping[str, Any]) -> dict[str, Any]:
    """The verdict on one fit from its validation dict: ``level`` (PASS / CHECK / FAIL, the
    worst of its reasons' levels, :data:`REASON_LEVELS`), ``ok`` (level PASS), ``reasons``
    with their ``reason_levels``, and ``notes`` that set no level.

    Reasons: not converged; TIC over the limit; a failed proof of match, by whether its
    misses are within the prediction's own uncertainty; truth beyond k std (when known); a
    derivative of the wrong sign or an a-priori value disagreeing beyond k std
    (:func:`_plausibility_reasons`); an EKF/UKF disagreeing with filter error
    (``agreement`` from :func:`~pipeline.validation.agreement.cross_check_methods`).
    Notes: residual colour, correlations, frequency mismatch, other methods' disagreement, and for an output-error method with coloured residuals and
    scattering maneuvers the advice to fit filter error."""
    reasons: list[Reason] = []
    notes: list[str] = []
    if not v.get("converged", True):
        why = v.get("not_settled")
        reasons.append(
            ("not converged", f"the filter passes did not settle: {why}" if why else "the optimiser did not converge")
        )
    _judge_tic(v.get("fit") or {}, reasons, notes)
    pm = v.get("proof_of_match")
    if pm is not None and not pm["all_pass"]:
        reasons += _match_reasons(pm)
        notes += _prediction_notes(pm)
    tr = (v.get("plausibility") or {}).get("truth")
    if tr and tr["per_parameter"] and not tr["all_within"]:
        bad = [n for n, d in tr["per_parameter"].items() if not d["within"]]
        reasons.append(("truth", f"{', '.join(bad)} more than {tr['k']:g} std from the truth"))
    reasons += _plausibility_reasons(v.get("plausibility") or {})
    _judge_agreement(v, reasons, notes)
    notes += _uncertainty_notes(v)
    for stage, why in (v.get("errors") or {}).items():  # a check that could not run (validate's errors)
        if stage in NOTE_ONLY_CHECKS:
            notes.append(f"{stage.replace('_', ' ')} not computed: {why}")
        else:
            reasons.append(("validation error", f"{stage.replace('_', ' ')} could not be computed ({why})"))
    if v.get("correlations_flagged"):
        notes.append("highly correlated: " + ", ".join(f"{a}~{b}" for a, b, _ in v["correlations_flagged"]))
    fr = v.get("frequency")
    if fr and fr.get("n_judged") and not fr["all_pass"]:
        bad = [k for k, d in fr["table"].items() if d["n_used"] and not d["pass"]]
        notes.append(f"frequency-response mismatch beyond bounds on {', '.join(bad)}")
    levels = [REASON_LEVELS[kind] for kind, _ in reasons]
    level = max(levels, key=LEVELS.index, default="PASS")
    return {
        "ok": level == "PASS",
        "level": level,
        "reasons": [r for _, r in reasons],
        "reason_levels": levels,
        "notes": notes,
    }


def _plausibility_reasons(pl: Mapping[str, Any]) -> list[Reason]:
    """A ``wrong sign`` reason per derivative flagged by the sign check (``signs``) and an
    ``a priori`` reason per estimate flagged against its a-priori value (``apriori``),
    each naming the derivative, its value and std and the rule broken (k: ``pl["k"]``)."""
    k = float(pl.get("k", PLAUSIBILITY_K))
    reasons: list[Reason] = []
    for n, d in (pl.get("signs") or {}).items():
        if d.get("flag"):
            rel = ">" if d["expected"] > 0 else "<"
            reasons.append(
                (
                    "wrong sign",
                    f"{n} = {d['estimate']:.4g} +- {d['std']:.2g} has the wrong sign: {n} {rel} 0 "
                    f"({SIGN_REASONS.get(n, 'declared')}), and it lies {-d['margin']:.1f} std beyond zero "
                    f"(more than {k:g})",
                )
            )
    for n, d in (pl.get("apriori") or {}).items():
        if d.get("flag"):
            reasons.append(
                (
                    "a priori",
                    f"{n} = {d['estimate']:.4g} +- {d['std']:.2g} disagrees with its a-priori value "
                    f"{d['apriori']:.4g} +- {d['apriori_std']:.2g} by "
                    f"{'infinitely many' if d['z'] is None else format(d['z'], '.1f')} combined std (more than {k:g})",
                )
            )
    return reasons


def _judge_tic(fit: Mapping[str, Any], reasons: list[Reason], notes: list[str]) -> None:
    """A TIC reason for the outputs over the limit, a note for those at their noise floor."""
    if not fit or fit.get("tic_ok", True):
        return
    floor = fit.get("tic_noise_floor") or []
    bad = [
        o
        for o, d in fit["per_output"].items()
        if (d.get("TIC") is None or d["TIC"] >= fit["tic_limit"]) and o not in floor
    ]
    if bad:
        reasons.append(("TIC", f"TIC >= {fit['tic_limit']} on {', '.join(bad)}"))
    if floor:
        notes.append(
            f"TIC >= {fit['tic_limit']} on {', '.join(floor)} at their noise floor: "
            f"residuals within {NOISE_FLOOR_RATIO:g}x their measurement noise (the "
            "maneuvers hardly move them)"
        )


def _match_reasons(pm: Mapping[str, Any]) -> list[Reason]:
    """The reasons of a failed proof of match, by how its misses compare with the
    prediction's own uncertainty (:func:`_pom_channels`)."""
    k, within, beyond, unweighed = _pom_channels(pm)
    reasons = []
    if beyond:
        reasons.append(
            (
                "proof of match beyond",
                f"proof of match failed on {', '.join(beyond)} beyond {k:g} std of the prediction's own uncertainty",
            )
        )
    if unweighed:
        reasons.append(
            (
                "proof of match unweighed",
                f"proof of match failed on {', '.join(unweighed)} (no prediction uncertainty to weigh the miss)",
            )
        )
    if within:
        reasons.append(
            (
                "proof of match within",
                f"proof of match failed on {', '.join(within)} within {k:g} std of the prediction's own uncertainty",
            )
        )
    if not (beyond or unweighed or within):
        reasons.append(("proof of match none judged", "proof of match failed on every channel (none judged)"))
    return reasons


def _trusted_over(method: Any, other: Any, converged: bool = True) -> bool:
    """Whether ``other`` is the method to trust where it and ``method`` disagree: a
    converged filter-error fit (fem, fem-nl) over an EKF or UKF of the same flight."""
    return converged and is_method(other, "fem") and any(is_method(method, m) for m in ("ekf", "ukf"))


def _judge_agreement(v: Mapping[str, Any], reasons: list[Reason], notes: list[str]) -> None:
    """Per other method the fit disagrees with (``agreement``): a FAIL reason when that is
    the method to trust (:func:`_trusted_over`), else a note."""
    ag = v.get("agreement") or {}
    for other, bad in (ag.get("flagged") or {}).items():
        on = ", ".join(f"{n} ({z:.1f})" for n, z in bad.items())
        against = (ag.get("against") or {}).get(other) or {}
        if _trusted_over(v.get("method"), against.get("method", other), bool(against.get("converged", True))):
            reasons.append(
                (
                    "filter error",
                    f"disagrees with filter error ({other}) by more than {ag['k']:g} combined std on {on}: {FILTER_ERROR_TRUST}",
                )
            )
        else:
            notes.append(f"disagrees with {other} by more than {ag['k']:g} combined std on {on}")


def _uncertainty_notes(v: Mapping[str, Any]) -> list[str]:
    """Notes on coloured residuals, maneuvers that scatter beyond the bound, the std
    widened to that scatter, and for output error with both the advice to fit filter error."""
    notes = []
    res = v.get("residuals") or {}
    if res and not res.get("all_white", True):
        col = [o for o, d in res["whiteness"].items() if not d.get("white")]
        notes.append(f"coloured residuals on {', '.join(col)} (see Morelli-Klein std)")
    cl = (v.get("uncertainty") or {}).get("cluster") or {}
    if cl.get("flagged"):
        notes.append(
            f"the {cl['n_segments']} maneuvers scatter more than {cl['flag_ratio']:g}x "
            "the Cramér-Rao bound on "
            + ", ".join(f"{n} ({r:.1f}x)" for n, r in cl["flagged"].items())
            + ": the bound understates their uncertainty (see the maneuver-scatter std)"
        )
    wide = (v.get("uncertainty") or {}).get("widened") or {}
    if wide:
        notes.append(
            "std is the maneuver scatter on "
            + ", ".join(f"{n} ({r:.1f}x the Cramér-Rao bound)" for n, r in wide["parameters"].items())
            + f": more than an exact bound's {wide['confidence']:.0%} limit of "
            f"{wide['threshold']:.2f}x with {cl.get('n_segments')} maneuvers"
        )
    # output error and its stabilised forms ("oem-..."): no process noise in the model
    if (
        str(v.get("method", "")).startswith("oem")
        and res
        and not res.get("all_white", True)
        and (cl.get("flagged") or wide)
    ):
        notes.append(
            "output error leaves process noise out: coloured residuals and maneuvers "
            "that scatter beyond the bound are what turbulence does to it; fit filter "
            "error too (--method fem) and compare"
        )
    return notes


def _prediction_k(pm: Mapping[str, Any]) -> float:
    """The k (PREDICTION_K) of the proof of match's prediction uncertainty."""
    return next(
        (sg["prediction_uncertainty"]["k"] for sg in pm["segments"] if sg.get("prediction_uncertainty")), V.PREDICTION_K
    )


def _pom_channels(pm: Mapping[str, Any]) -> tuple[float, list[str], list[str], list[str]]:
    """(k, within, beyond, unweighed): the failed proof-of-match channels by how their
    misses compare with k (PREDICTION_K) std of the prediction's own uncertainty, the
    worst segment deciding (beyond on any segment, else no uncertainty on any, else within)."""
    k = _prediction_k(pm)
    worst: dict[str, int] = {}  # 0 within, 1 unweighed, 2 beyond
    for sg in pm["segments"]:
        for c, d in sg["channels"].items():
            if d.get("pass") is not False:
                continue
            b, top = d.get("beyond_prediction_display"), d.get("prediction_std_max_display")
            w = 1 if b is None or top is None else 2 if b > 0 else 0
            worst[c] = max(worst.get(c, 0), w)
    names = sorted(worst)
    return (
        k,
        [c for c in names if worst[c] == 0],
        [c for c in names if worst[c] == 2],
        [c for c in names if worst[c] == 1],
    )


def _prediction_notes(pm: Mapping[str, Any]) -> list[str]:
    """Verdict notes on the failed channels of a proof of match whose prediction has its
    own uncertainty from the estimates: are the misses within k (PREDICTION_K) std of it
    (the estimates' precision limits the match) or beyond (the model's form, its inputs or
    biased estimates)?"""
    within, beyond = {}, {}
    k = _prediction_k(pm)
    for sg in pm["segments"]:
        for c, d in sg["channels"].items():
            b, top = d.get("beyond_prediction_display"), d.get("prediction_std_max_display")
            if d.get("pass") is not False or b is None or top is None:
                continue
            if b > 0:
                beyond[c] = max(beyond.get(c, (0.0, ""))[0], b), d["unit"]
            elif top >= within.get(c, (-1.0,))[0]:
                within[c] = top, d["unit"], d.get("prediction_std_from") or {}
    within = {c: w for c, w in within.items() if c not in beyond}  # beyond on some segment
    notes = []
    if within:
        notes.append(
            "proof of match: the misses on " + ", ".join(within) + f" are within {k:g} "
            "std of the prediction's own uncertainty from the estimates' covariance (its std "
            "up to "
            + ", ".join(
                f"{v:.3g} {u} on {c}"
                + (
                    "; at its worst miss mostly "
                    + ", ".join(f"{n} {100 * x:.0f} %" for n, x in src.items())
                    + " of its variance"
                    if src
                    else ""
                )
                for c, (v, u, src) in within.items()
            )
            + "): the estimates are too imprecise for the band, not shown wrong; more "
            "or richer maneuvers narrow them"
        )
    if beyond:
        notes.append(
            "proof of match: "
            + ", ".join(f"{c} by {v:.3g} {u}" for c, (v, u) in beyond.items())
            + f" beyond {k:g} std of the prediction's own uncertainty from the estimates: "
            "not explained by their stated uncertainty - the model's form, its inputs, "
            "or estimates biased beyond their std"
        )
    return notes
