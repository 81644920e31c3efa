"""Validation of one estimation result: every check of :mod:`estimators.validation` in one call.

:func:`validate` returns a dict whose entries are JSON-ready (plain floats, lists, dicts,
``None`` for NaN) except ``"arrays"``, which holds the numpy arrays the recording plots
(residual spectra, frequency responses, proof-of-match time histories). Use
:func:`~pipeline.validation.json_values.json_ready` to drop ``"arrays"`` and convert any
stray numpy values.

Units: everything numeric is SI (rad, rad/s, m/s, m/s^2, s, Hz, rad/s for angular
frequency) unless a key says otherwise: ``*_deg``, ``*_deg_s``, ``*_g`` and ``*_db`` keys
are the human-facing forms (degrees, degrees per second, g, decibels).

Keys of the returned dict
-------------------------
``method``, ``converged``, ``det_R``
``fit``: per output ``TIC UM US UC R2 RMS NRMS mean std`` (see
    :func:`estimators.validation.fit_metrics`) and ``noise_std`` (the white-noise level of
    its samples' second differences), on all fitted segments together; plus ``max_TIC``,
    ``tic_ok`` (every TIC < ``tic_limit``) and ``tic_noise_floor`` (the outputs whose TIC
    is not below it only through their noise: residual rms within NOISE_FLOOR_RATIO of
    ``noise_std``; the verdict notes them instead of failing).
``residuals``: ``stats`` per output (mean, std, rms, mean_over_std), ``whiteness`` per output
    (Q, threshold, p_value, white, frac_outside), ``max_lag``, ``all_white``.
``uncertainty``: per free parameter ``crb_std``, ``mk_std`` (Morelli-Klein corrected),
    ``ratio``; for filter error the same on its innovations (``residuals``: ``innovations``,
    estimators.filters.filter_error); ``None`` when the result kept neither. With 2 or more maneuvers
    also ``cluster_std`` (the maneuver-to-maneuver scatter, estimators.covariance.cluster;
    NaN where one maneuver carries more than ``limit`` of the parameter's information,
    ``max_share``: 1 where the other maneuvers cannot identify it),
    ``cluster_ratio`` (/ its Cramér-Rao std) per parameter, and ``cluster``: ``n_segments``,
    ``limit``, ``median_ratio``, ``max_ratio``, ``max_parameter`` (over the system
    parameters), ``flagged`` (ratio above ``flag_ratio``); ``widened`` (``threshold``,
    ``confidence``, ``parameters``: ratio) where
    :func:`~pipeline.validation.uncertainty.widen_by_scatter` made the scatter the reported std.
``modes``: ``None`` for a model without states/segments (a regression); else ``trim`` (x0
    per state, u0 per input), ``table`` per mode (``real imag wn zeta period t_half
    t_double stable axis``), ``eigenvalues`` (list of [real, imag]).
``proof_of_match``: ``None`` without ``held_out``; else ``mode`` (``simulation`` or
    ``air-data``, see :func:`~pipeline.validation.proof_of_match.pom_mode`), ``driven``
    (the air-data outputs that drive the filter in air-data mode: reported, not judged),
    ``notes``, ``segments`` (per held-out
    segment: ``name``, ``mode``, ``channels`` per output with ``tolerance max_abs_error
    rms_error fraction_within pass`` (SI) and the same in display units ``*_display`` with
    ``unit``, ``TIC``, ``role`` (predicted / drives the filter),
    ``prediction_std_max_display`` and ``beyond_prediction_display`` (the prediction's own
    std from the estimates' covariance and how far the misses reach beyond
    ``estimators.validation.PREDICTION_K`` of it; on a failed channel
    ``prediction_std_from``, the derivatives' shares of that variance at its worst miss;
    ``prediction_uncertainty`` per segment: ``parameters``, ``k``), ``all_pass``) and
    ``all_pass`` over all segments.
``frequency``: ``None`` when no input is excited; else ``inputs`` used, ``table`` per
    ``"<output>/<input>"`` (``max_mag_db max_phase_deg n_used pass``), ``bounds``: the
    model's response (through the same Welch estimator as the data, see
    :func:`~pipeline.validation.linear.frequency_check`) against the data's.
``inverse_simulation``: ``None`` without excited inputs; else ``segment``, ``tracked``
    outputs, loop ``bandwidth`` (rad/s) and per input
    ``rms_residual``, ``max_abs_residual``, ``rms_input`` (SI), ``ratio`` (residual over
    flown input, rms), ``unit``/``rms_residual_display`` (deg for surfaces): the inputs the
    linearised model needs beyond the flown ones to follow the first fitted segment.
``plausibility``: ``truth`` (per parameter: ``truth error error_in_std within``),
    ``k``, ``signs`` (per derivative whose sign is fixed: columns of
    :func:`estimators.validation.sign_check`) and ``apriori`` (per parameter: columns of
    :func:`estimators.validation.plausibility`), both on the total std.
``agreement``: set by :func:`~pipeline.validation.agreement.cross_check_methods` once every
    method of the run has its final std: ``k``, ``flagged`` (per other method of the same
    axis, the parameters where the two estimates differ by more than k combined std, with
    that z) and ``against`` (per flagged method: its ``method`` name and whether it
    ``converged``).
``errors``: stage -> "<type>: <message>" for each check that raised (``fit``, ``residuals``,
    ``uncertainty``, ``modes``, ``frequency``, ``inverse_simulation``, ``proof_of_match``,
    ``truth``, ``plausibility``); that check's entry is then None (``{"error": ...}`` for
    the linearised model's), the others stand, and report.md says it where its result
    would be.
``verdict``: ``level`` (PASS / CHECK / FAIL, :data:`~pipeline.validation.verdict.REASON_LEVELS`),
    ``ok`` (level PASS), ``reasons`` (short sentences) with their ``reason_levels``,
    ``notes``; see :func:`~pipeline.validation.verdict.verdict`.
``arrays``: ``psd`` (``f`` (n_f,) Hz, ``Pxx`` (n_f, n_out) units^2/Hz),
    ``freq`` (``f`` (n_f,) Hz; complex ``H_data`` (spectral estimate from the data),
    ``H_model`` (the same estimator on the fixed model's simulated outputs), ``H_analytic`` (G(jw)
    of the linearised model), real ``coherence`` and bool ``used``, all (n_f, n_out, n_in_used);
    ``inputs``, ``outputs``), ``match`` (list per held-out segment of
    ``t`` (N,), ``measured``/``predicted`` (N, n_out) DataFrames, ``tolerance`` (n_out,),
    ``excess`` (N, n_out) each sample's error beyond its band, ``sensitivity`` (names, S
    (N, n_out, n_names)) and ``prediction_std`` (N, n_out) DataFrame, or None),
    ``inverse`` (``t`` (N,), ``inputs``, ``residual_inputs`` (N, n_in_used) SI).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import replace
from typing import Any

from estimators import EstimationResult, Segment
from estimators import validation as V
from estimators.integrators import INTEGRATORS
from pipeline.validation.fit import fit_summary, residual_analysis
from pipeline.validation.json_values import num
from pipeline.validation.linear import Linearisation, frequency_check, inverse_check, linear_model, mode_table
from pipeline.validation.plausibility import plausibility_checks
from pipeline.validation.proof_of_match import POM_MODES, match_held_out, pom_mode
from pipeline.validation.settings import ValidationSettings
from pipeline.validation.truth import truth_check
from pipeline.validation.uncertainty import parameter_uncertainty, widen_by_scatter
from pipeline.validation.verdict import verdict


def validate(
    result: EstimationResult,
    settings: ValidationSettings | None = None,
    *,
    held_out: Sequence[Segment] | None = None,
    step_times: Sequence[Mapping[str, Any]] | None = None,
    truth: Mapping[str, float] | None = None,
    apriori: Any = None,
    signs: Mapping[str, int] | None = None,
    **options: Any,
) -> dict[str, Any]:
    """Run the validation of :mod:`estimators.validation` on one result (see module doc).
    Where the fit's maneuvers scatter significantly beyond its Cramér-Rao bounds, the
    checks after the uncertainty judge the result with its covariance widened to that
    scatter (:func:`~pipeline.validation.uncertainty.widen_by_scatter`), and the output's
    ``uncertainty["widened"]`` says where: :func:`~pipeline.validation.uncertainty.widened`
    gives that result (``std_method`` saying so, the bound kept as a view).

    settings: the bands, bounds and proof-of-match mode (:class:`ValidationSettings`);
        ``options``: any of its fields by keyword, over ``settings``.
    held_out: segments NOT used in the fit (same model input/output columns); the
        identified model, all parameters held fixed, predicts each from its measured
        initial condition (``Segment.x0`` or the states read from z[0]) and is judged
        against ``settings.tolerances``. How the prediction is made: ``simulation`` - open
        loop, only the initial state and per-segment biases fitted to the held-out data
        (the classic proof of match, for calm air and stable models); ``air-data`` - the
        model driven by its measured air data through a Kalman filter that sees only
        V/alpha/beta (see :mod:`estimators.validation.prediction`; those channels are then
        not judged); ``auto`` (default) -
        :func:`~pipeline.validation.proof_of_match.pom_mode`.
    step_times: per held-out segment, the control-input steps of its flight between two
        slow samples (input -> [(start, end, std or None), ...] s,
        :func:`pipeline.conditioning.input_sampling.step_times`): the held-out prediction is
        also made with each moved through the range of its time (untimed: its interval;
        timed: 2 std either side), and a sample is judged by its distance from the range of
        those predictions (the step's time is as uncertain as a sensor bias;
        ``input_timing`` of the segment and the channels' nominal error and envelope width
        say what it did).
    truth: true parameter values by name; apriori: a-priori values (TOML path, mapping or
        DataFrame of :func:`estimators.validation.load_apriori`); signs: derivative ->
        expected sign +1/-1 (default :func:`estimators.validation.expected_signs` with the
        truth's signs declared; :func:`~pipeline.validation.plausibility.plausibility_checks`).
    """
    s = replace(settings or ValidationSettings(), **options)
    integ = s.integrator or result.settings.get("integrator", "rk4")
    if integ not in INTEGRATORS:  # filter error's linear form: "transition matrix"
        integ = "rk4"
    out: dict[str, Any] = {
        "method": result.method,
        "converged": bool(result.converged),
        "not_settled": result.extra.get("not_settled"),
        "det_R": num(result.cost),
        "correlations_flagged": num([list(f) for f in result.flagged_correlations]),
    }
    if s.proof_of_match not in POM_MODES:
        raise ValueError(f"proof_of_match={s.proof_of_match!r}: use one of {', '.join(POM_MODES)}")
    arrays: dict[str, Any] = {}
    errors: dict[str, str] = {}
    out["fit"] = _attempt("fit", errors, lambda: fit_summary(result, s.tic_limit))
    out["residuals"], arrays["psd"] = _attempt("residuals", errors, lambda: residual_analysis(result), (None, None))
    out["uncertainty"] = _attempt("uncertainty", errors, lambda: parameter_uncertainty(result))
    if out["uncertainty"] is not None:
        result = _attempt("uncertainty", errors, lambda: widen_by_scatter(result, out["uncertainty"]), result)
    lin = _linear_checks(result, s, integ, out, arrays)
    errors.update({k: out[k]["error"] for k in LINEAR_CHECKS if isinstance(out[k], dict) and "error" in out[k]})
    out["proof_of_match"], arrays["match"] = None, []
    if held_out:

        def match() -> tuple[dict[str, Any], list]:
            mode = pom_mode(result, lin, s.calm_air) if s.proof_of_match == "auto" else s.proof_of_match
            return match_held_out(result, list(held_out), s, integ, mode, step_times)

        out["proof_of_match"], arrays["match"] = _attempt("proof_of_match", errors, match, (None, []))
    plaus: dict[str, Any] = {}
    if truth:
        plaus["truth"] = _attempt("truth", errors, lambda: truth_check(result, truth, s.truth_k))
    expected = V.expected_signs(declared=truth) if signs is None else signs
    plaus.update(_attempt("plausibility", errors, lambda: plausibility_checks(result, apriori, expected), {}))
    out["plausibility"] = {k: x for k, x in plaus.items() if x is not None}
    out["errors"] = errors
    out["verdict"] = verdict(out)
    out["arrays"] = arrays
    return out


#: the checks on the linearised model (:func:`_linear_checks`), each ``{"error": ...}`` when it failed
LINEAR_CHECKS = ("modes", "frequency", "inverse_simulation")


def _attempt(stage: str, errors: dict[str, str], run: Callable[[], Any], fallback: Any = None) -> Any:
    """``run()``, or ``fallback`` when it raises, with ``errors[stage]`` saying what failed
    ("<type>: <message>"): one check that fails on a flight costs its own result, which
    the report replaces by that line, not the validation's other results."""
    try:
        return run()
    except Exception as exc:  # noqa: BLE001 - recorded and reported where its result would be
        errors[stage] = f"{type(exc).__name__}: {exc}"
        return fallback


def _linear_checks(
    result: EstimationResult, s: ValidationSettings, integ: str, out: dict[str, Any], arrays: dict[str, Any]
) -> Linearisation | None:
    """Set ``modes``, ``frequency`` and ``inverse_simulation`` of ``out`` (and their
    ``arrays``) from the model linearised at the first fitted sample; a check that fails
    is reported as ``{"error": ...}``, not raised. Returns the linearisation, None for a
    model without states or segments (a regression)."""
    lin = None
    out["modes"] = None  # not applicable: no states or no segments
    if result.segments and result.model.states:
        try:
            lin = linear_model(result)
            out["modes"] = mode_table(result, lin)
        except Exception as exc:  # noqa: BLE001 - reported, not fatal
            out["modes"] = {"error": f"{type(exc).__name__}: {exc}"}
    out["frequency"], arrays["freq"] = (None, None)
    if lin is not None:
        try:
            out["frequency"], arrays["freq"] = frequency_check(result, lin, s, integ)
        except Exception as exc:  # noqa: BLE001 - reported, not fatal
            out["frequency"] = {"error": f"{type(exc).__name__}: {exc}"}
    out["inverse_simulation"], arrays["inverse"] = None, None
    if lin is not None:
        try:
            out["inverse_simulation"], arrays["inverse"] = inverse_check(result, lin, s.inverse_bandwidth)
        except Exception as exc:  # noqa: BLE001 - reported, not fatal
            out["inverse_simulation"] = {"error": f"{type(exc).__name__}: {exc}"}
    return lin
