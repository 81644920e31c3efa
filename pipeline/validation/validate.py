"""Validation of one estimation result: every check of :mod:`estimators.validation` in one call.

:func:`validate` returns a dict whose entries are JSON-ready (plain floats, lists, dicts,
``None`` for NaN) except ``"arrays"``, which holds the numpy arrays the recording plots
(residual spectra, frequency responses, proof-of-match time histories). Use
:func:`json_ready` to drop ``"arrays"`` and convert any stray numpy values.

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
    also ``cluster_std`` (the maneuver-to-maneuver scatter, estimators.validation.cluster;
    NaN where one maneuver carries more than ``limit`` of the parameter's information,
    ``max_share``: 1 where the other maneuvers cannot identify it),
    ``cluster_ratio`` (/ its Cramér-Rao std) per parameter, and ``cluster``: ``n_segments``,
    ``limit``, ``median_ratio``, ``max_ratio``, ``max_parameter`` (over the system
    parameters), ``flagged`` (ratio above ``flag_ratio``); ``widened`` (``threshold``,
    ``confidence``, ``parameters``: ratio) where :func:`widen_by_scatter` made the scatter
    the reported std.
``modes``: ``None`` for a model without states/segments (a regression); else ``trim`` (x0 per state, u0 per input), ``table`` per mode (``real imag wn zeta
    period t_half t_double stable axis``), ``eigenvalues`` (list of [real, imag]).
``proof_of_match``: ``None`` without ``held_out``; else ``mode`` (``simulation`` or
    ``air-data``, see :func:`pom_mode`), ``driven`` (the air-data outputs that drive the
    filter in air-data mode: reported, not judged), ``notes``, ``segments`` (per held-out
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
    model's response (through the same Welch estimator as the data, see :func:`_frequency`)
    against the data's.
``inverse_simulation``: ``None`` without excited inputs; else ``segment``, ``tracked``
    outputs, loop ``bandwidth`` (rad/s) and per input
    ``rms_residual``, ``max_abs_residual``, ``rms_input`` (SI), ``ratio`` (residual over
    flown input, rms), ``unit``/``rms_residual_display`` (deg for surfaces): the inputs the
    linearised model needs beyond the flown ones to follow the first fitted segment.
``plausibility``: ``truth`` (per parameter: ``truth error error_in_std within``) and
    ``apriori`` (per parameter: columns of :func:`estimators.validation.plausibility`).
``agreement``: set by :func:`cross_check_methods` once every method of the run has its
    final std: ``k``, ``flagged`` (per other method of the same axis, the parameters
    where the two estimates differ by more than k combined std, with that z) and
    ``against`` (per flagged method: its ``method`` name and whether it ``converged``).
``verdict``: ``level`` (PASS / CHECK / FAIL, :data:`REASON_LEVELS`), ``ok`` (level PASS),
    ``reasons`` (short sentences) with their ``reason_levels``, ``notes``; see :func:`verdict`.
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

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import pandas as pd

import estimators
from estimators import EstimationResult, Segment, simulate_outputs
from estimators import statistics as st
from estimators import validation as V
from estimators.model import Namespace
from estimators.simulation.integrators import DEFAULT_INPUTS, INTEGRATORS

#: TIC below which a channel's fit counts as good (DESIGN.md section 8)
TIC_LIMIT = 0.1
#: a channel whose residual rms is within this factor of its white measurement noise is fitted
#: as well as its noise allows (the model's own error at most 0.66 of the noise): a TIC at or
#: above TIC_LIMIT there is the noise's, and the verdict notes it instead of failing on it
NOISE_FLOOR_RATIO = 1.2
#: |estimate - truth| / std allowed for a truth check to pass
TRUTH_K = 3.0
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
#:   converged filter-error fit of the same flight (:func:`cross_check_methods`): filter
#:   error is the method to trust in turbulence (DESIGN.md section 8), its noise model
#:   holding calm air as the case without process noise.
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
#:
#: Notes set no level: coloured residuals, correlations, frequency-response mismatch, TIC
#: at an output's noise floor, maneuver scatter, a-priori values (the uncertain knowledge
#: identification replaces) and disagreements between other pairs of methods (neither of
#: which is the one to trust): context that neither proves nor disproves the estimates.
REASON_LEVELS = {
    "not converged": "FAIL",
    "truth": "FAIL",
    "filter error": "FAIL",
    "proof of match beyond": "FAIL",
    "proof of match unweighed": "FAIL",
    "proof of match within": "CHECK",
    "proof of match none judged": "CHECK",
    "TIC": "CHECK",
}
#: why an EKF/UKF that disagrees with filter error fails (DESIGN.md section 8)
FILTER_ERROR_TRUST = (
    "filter error is the method to trust in turbulence (its process noise "
    "model; the EKF/UKF's white process noise biases them in coloured "
    "turbulence)"
)
#: channels shown in degrees (rad -> deg) and degrees per second (rad/s -> deg/s)
ANGLES = frozenset({"alpha", "beta", "phi", "theta", "psi", "de", "da", "dr"})
RATES = frozenset({"p", "q", "r"})
ACCELS = frozenset({"ax", "ay", "az"})
ANG_ACCELS = frozenset({"pdot", "qdot", "rdot"})
_SPEEDS = ("V", "u", "vn", "vd")


# -- small helpers ---------------------------------------------------------------------------
def num(x: Any) -> Any:
    """A JSON-ready copy of x: numpy scalars/arrays to Python, NaN/inf to None."""
    if isinstance(x, Mapping):
        return {str(k): num(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [num(v) for v in x]
    if isinstance(x, np.ndarray):
        return [num(v) for v in x.tolist()]
    if isinstance(x, (bool, np.bool_)):
        return bool(x)
    if x is pd.NA or x is None:
        return None
    if isinstance(x, (int, np.integer)):
        return int(x)
    if isinstance(x, (float, np.floating)):
        return float(x) if math.isfinite(float(x)) else None
    if isinstance(x, complex):
        return [num(x.real), num(x.imag)]
    return x


def json_ready(validation: Mapping[str, Any]) -> dict[str, Any]:
    """The validation dict without ``"arrays"``, every value JSON-serialisable."""
    return num({k: v for k, v in validation.items() if k != "arrays"})


def frame_dict(df: pd.DataFrame) -> dict[str, dict[str, Any]]:
    """{row: {column: value}} of a DataFrame, JSON-ready."""
    return num({str(i): row.to_dict() for i, row in df.iterrows()})


def display_unit(channel: str) -> tuple[float, str]:
    """(factor, unit) turning an SI value of a canonical channel into its human-facing form:
    angles deg, rates deg/s, angular accelerations deg/s^2, specific forces g; else SI."""
    if channel in ANGLES:
        return 180.0 / np.pi, "deg"
    if channel in RATES:
        return 180.0 / np.pi, "deg/s"
    if channel in ANG_ACCELS:
        return 180.0 / np.pi, "deg/s^2"
    if channel in ACCELS:
        return 1.0 / V.match.G0, "g"
    unit = {
        "V": "m/s",
        "u": "m/s",
        "v": "m/s",
        "w": "m/s",
        "h": "m",
        "qbar": "Pa",
        "rho": "kg/m^3",
        "thrust": "N",
        "throttle": "-",
    }.get(channel, "SI")
    return 1.0, unit


# -- pieces ---------------------------------------------------------------------------------
def _measured(result: EstimationResult) -> list[pd.DataFrame]:
    """Measured outputs per fitted segment, DataFrames on t (z = predicted + residual)."""
    return [p + r for p, r in zip(result.predicted, result.residuals)]


def _fit(result: EstimationResult, tic_limit: float) -> dict[str, Any]:
    """The fit metrics per output, and the outputs whose TIC reaches ``tic_limit`` only
    through their measurement noise (``tic_noise_floor``: residual rms within
    NOISE_FLOOR_RATIO of the white-noise level of their own samples' second differences,
    robust to the kinks at control steps; ``noise_std`` per output). Default.toml with 0.5
    deg/s gyro and 0.3 m/s^2 accelerometer noise (seed 1, ad hoc): q, ax, ay of the lateral
    maneuvers, which hardly move them, had TIC >= 0.1 with the model as good as the noise."""
    z = _measured(result)
    df = V.fit_metrics(z, result.predicted, names=result.outputs)
    out = frame_dict(df)
    tic = df["TIC"].to_numpy()
    noise = st.difference_noise_std([f.to_numpy(float) for f in z], robust=True)
    floor = []
    for o, sd, t in zip(result.outputs, noise, tic):
        out[o]["noise_std"] = num(sd)
        if t >= tic_limit and np.isfinite(sd) and sd > 0 and out[o]["RMS"] <= NOISE_FLOOR_RATIO * sd:
            floor.append(o)
    return {
        "per_output": out,
        "det_R": num(df.attrs["det_R"]),
        "max_TIC": num(np.nanmax(tic)) if np.isfinite(tic).any() else None,
        "tic_limit": tic_limit,
        "tic_ok": bool(np.all(tic < tic_limit)),
        "tic_noise_floor": floor,
    }


def _residuals(result: EstimationResult) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    res = [r.to_numpy() for r in result.residuals]
    stats = V.residual_stats(res, names=result.outputs)
    w = V.whiteness(res, names=result.outputs)
    t0 = result.residuals[0].index.to_numpy()
    fs = 1.0 / float(np.median(np.diff(t0)))
    f, P = V.psd(res[int(np.argmax([len(r) for r in res]))], fs)
    return (
        {
            "stats": frame_dict(stats),
            "whiteness": frame_dict(w.to_frame()),
            "max_lag": w.max_lag,
            "all_white": bool(np.all(w.white)),
            "fs_hz": fs,
        },
        {"f": f, "Pxx": P},
    )


def _uncertainty(result: EstimationResult) -> dict[str, Any] | None:
    extra: dict[str, Any] = {}
    if result.sensitivities:
        names = result.free_names
        try:
            u = V.morelli_klein(
                result.sensitivities,
                [r.to_numpy() for r in result.residuals],
                R=result.R,
                info=result.information,
                names=names,
                prior_info=(result.extra or {}).get("prior_information"),
            )
        except (ValueError, np.linalg.LinAlgError) as exc:
            return {"error": str(exc)}
        mk, max_lag = u.std, u.max_lag
    elif "mk_cov" in result.extra:
        # filter error: Morelli-Klein on the innovations, computed by the fit (estimators.filters.filter_error)
        names = list(result.extra["mk_names"])
        mk = np.sqrt(np.clip(np.diag(result.extra["mk_cov"]), 0.0, None))
        max_lag, extra = result.extra.get("mk_max_lag"), {"residuals": "innovations"}
    elif result.extra.get("cluster") is not None:
        # equation error: its regressions' window scatter, no Morelli-Klein
        names = list(result.extra["cluster"].names)
        mk, max_lag = np.full(len(names), np.nan), None
    else:
        return None
    crb = result.std[names].to_numpy()
    if "crb_cov" in result.extra:  # std is not the Cramér-Rao bound (estimators.output_error.stabilized,
        # widen_by_scatter)
        crb = pd.Series(np.sqrt(np.clip(np.diag(result.extra["crb_cov"]), 0.0, None)), index=result.free_names)[
            names
        ].to_numpy()
    df = pd.DataFrame({"crb_std": crb, "mk_std": mk, "ratio": mk / crb}, index=pd.Index(names, name="parameter"))
    cl = V.maneuver_scatter(result)
    if cl is not None:
        c = cl.to_frame().reindex(names)
        df["cluster_std"] = c["cluster_std"].to_numpy()
        df["cluster_ratio"] = c["ratio"].to_numpy()
        df["max_share"] = c["max_share"].to_numpy()
        extra["cluster"] = {
            "n_segments": cl.n_segments,
            "limit": cl.limit,
            "flag_ratio": V.cluster_flag_ratio,
            **cl.ratio_summary(),
        }
    return num({"per_parameter": frame_dict(df), "max_lag": max_lag, **extra})


#: confidence of the test that a parameter's maneuver scatter exceeds its Cramér-Rao bound
SCATTER_CONFIDENCE = 0.95
#: fewest maneuvers whose scatter may widen a bound (two degrees of freedom)
SCATTER_MIN_SEGMENTS = 3
#: ``std_method`` of a result whose bounds the maneuver scatter widened, by the method of
#: the bounds it widened (the Cramér-Rao bound; a Kalman filter's parameter covariance)
SCATTER_STD_METHOD = {"crb": "crb|scatter", "filter-covariance": "filter-covariance|scatter"}


def scatter_threshold(n_segments: int) -> float:
    """The maneuver-scatter / Cramér-Rao ratio that an exact bound exceeds with probability
    1 - SCATTER_CONFIDENCE: sqrt(chi2_q(G - 1) / (G - 1)) for G maneuvers (1.73 for 3,
    1.61 for 4, 1.54 for 5)."""
    from scipy.stats import chi2

    df = n_segments - 1
    return float(np.sqrt(chi2.ppf(SCATTER_CONFIDENCE, df) / df))


def widen_by_scatter(result: EstimationResult, unc: dict[str, Any] | None) -> dict[str, float]:
    """Where the maneuvers of a fit scatter significantly more than its Cramér-Rao bounds
    allow (the ratio of :func:`_uncertainty`'s ``cluster_std`` to the bound above
    :func:`scatter_threshold`, with at least SCATTER_MIN_SEGMENTS maneuvers), report the
    scatter as that parameter's std: the result's covariance is scaled on those rows and
    columns (correlations kept; the Cramér-Rao covariance stays in ``extra["crb_cov"]``,
    ``std_method`` SCATTER_STD_METHOD) and ``unc["widened"]`` lists them. Returns
    {parameter: ratio} (empty: nothing widened; only results whose std is the Cramér-Rao
    bound or, for the EKF and UKF, the filter's parameter covariance, whose scatter the
    filter keeps from each segment's information: estimators.filters.kalman. Their lateral fit
    on multiaxis_multisine_turbulence, seed 31: the EKF's maneuvers scatter 8.3x its P on
    Clp, 6.9x on Clda, which were 28 and 20 P-std off the truth).

    The bound assumes the model exact; flight data scatter more from maneuver to maneuver
    (Jategaonkar: "a fudge factor of 5-10"). Filter error on multiaxis_multisine_turbulence,
    seeds 31-38 (benchmarks/multiaxis_seeds.py): empirical / Cramér-Rao std up to 3.5
    (Cmalphadot), every derivative within 3 Cramér-Rao std on 3/8 seeds, 6/8 with the larger
    of bound and scatter."""
    if result.std_method not in SCATTER_STD_METHOD or not unc or not unc.get("cluster"):
        return {}
    n_seg = int(unc["cluster"]["n_segments"])
    if n_seg < SCATTER_MIN_SEGMENTS:
        return {}
    t = scatter_threshold(n_seg)
    names = result.free_names
    wide = {
        n: float(d["cluster_ratio"])
        for n, d in unc["per_parameter"].items()
        if n in names
        and d.get("cluster_ratio") is not None
        and math.isfinite(d["cluster_ratio"])
        and d["cluster_ratio"] > t
    }
    if not wide:
        return {}
    D = np.ones(len(names))
    for n, r in wide.items():
        D[names.index(n)] = r
    result.replace_cov(D[:, None] * result.cov * D[None, :], SCATTER_STD_METHOD[result.std_method])
    unc["widened"] = {"threshold": t, "confidence": SCATTER_CONFIDENCE, "parameters": wide}
    return wide


def linear_model(
    result: EstimationResult, segment: Segment | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(A, B, C, D, x0, u0): the identified model linearised at the first sample of
    ``segment`` (default: the first fitted segment): x0 its initial state, u0 its first input.
    A (n_x, n_x), B (n_x, n_u), C (n_y, n_x), D (n_y, n_u) in SI per SI."""
    model = result.model_with_estimates()
    seg = segment if segment is not None else result.segments[0]
    x0 = np.asarray(seg.initial_state(model), dtype=float)
    u0 = np.asarray(seg.u[0], dtype=float)
    p = Namespace({pp.name: float(pp.value) for pp in model.parameters})
    c = Namespace(model.constants_for(seg))
    A, B = V.linearize(model.f, x0, u0, p, c)
    C, D = V.linearize(model.g, x0, u0, p, c)
    return A, B, C, D, x0, u0


def _modes(result: EstimationResult, lin) -> dict[str, Any]:
    A, B, C, D, x0, u0 = lin
    model = result.model
    speed = next((abs(x0[model.states.index(s)]) for s in _SPEEDS if s in model.states), None)
    scales = {s: speed for s in _SPEEDS if speed} if speed else None
    ma = V.modes(A, model.states, scales=scales)
    tab = ma.table.drop(columns=["eigenvalue"])
    return {
        "trim": {"x0": num(dict(zip(model.states, x0))), "u0": num(dict(zip(model.inputs, u0)))},
        "table": frame_dict(tab),
        "eigenvalues": [[float(v.real), float(v.imag)] for v in ma.eigenvalues],
    }


def _frequency(
    result: EstimationResult,
    lin,
    *,
    mag_bound_db: float,
    phase_bound_deg: float,
    min_coherence: float,
    input_power_fraction: float,
    integrator: str,
) -> tuple[dict[str, Any] | None, dict[str, Any] | None]:
    """Model vs data in the frequency domain on the longest fitted segment.

    The data's response H_data is a Welch spectral estimate from the measured inputs and
    outputs. The model is put through the SAME estimator (its simulated outputs with the same
    inputs), so window leakage, the short record and the maneuver's transient affect both
    alike and the mismatch shows the model alone. The model's outputs are a fresh simulation
    of the identified model held fixed (not a filter's one-step predictions, which lean on
    the data). The analytic G(jw) = C (jwI - A)^-1 B + D of
    the model linearised at the first sample is kept alongside for the plots."""
    A, B, C, D, _, _ = lin
    k = int(np.argmax([s.t.size for s in result.segments]))
    seg = result.segments[k]
    dt = np.diff(seg.t)
    if seg.t.size < 64 or np.ptp(dt) > 1e-6 * np.median(dt):
        return None, None  # needs uniform sampling
    excited = [i for i in range(seg.u.shape[1]) if np.std(seg.u[:, i]) > 1e-12]
    if not excited:
        return None, None
    z = seg.z
    keep = np.all(np.isfinite(z), axis=0)
    outs = [o for o, kk in zip(result.outputs, keep) if kk]
    fs = 1.0 / float(np.median(dt))
    u = seg.u[:, excited]
    se = V.spectral_estimate(u, z[:, keep], fs)
    y_sim = simulate_outputs(
        result.model_with_estimates(), seg, integrator=integrator, inputs=result.settings.get("inputs", DEFAULT_INPUTS)
    )
    sm = V.spectral_estimate(u, y_sim.to_numpy()[:, keep], fs)
    w = se.w[1:]  # drop DC
    Hd, coh = se.H[1:], se.coherence[1:]
    Hm = sm.H[1:]
    G = V.freq_response(A, B[:, excited], C[keep], D[keep][:, excited], w)
    # judge only where the input carries power: Welch coherence from a few averages is
    # biased high, so spectral nulls of the input would otherwise count as evidence
    suu = np.real(np.diagonal(se.Suu[1:], axis1=1, axis2=2))  # (n_f, n_in)
    weak = suu < input_power_fraction * suu.max(axis=0, keepdims=True)
    coh_used = np.where(weak[:, None, :], 0.0, coh)
    ins = [result.model.inputs[i] for i in excited]
    mm = V.mismatch(
        Hm,
        Hd,
        w,
        coh_used,
        mag_bound_db=mag_bound_db,
        phase_bound_deg=phase_bound_deg,
        min_coherence=min_coherence,
        outputs=outs,
        inputs=ins,
    )
    tab = {f"{o}/{i}": num(row.to_dict()) for (o, i), row in mm.table.iterrows()}
    judged = mm.table[mm.table["n_used"] > 0]
    out = {
        "inputs": ins,
        "outputs": outs,
        "segment": seg.name or f"segment {k}",
        "table": tab,
        "bounds": {
            "mag_db": mag_bound_db,
            "phase_deg": phase_bound_deg,
            "min_coherence": min_coherence,
            "input_power_fraction": input_power_fraction,
        },
        "n_judged": int(len(judged)),
        "all_pass": bool(len(judged) and judged["pass"].all()),
    }
    arrays = {
        "f": w / (2 * np.pi),
        "H_model": Hm,
        "H_analytic": G,
        "H_data": Hd,
        "coherence": coh,
        "used": mm.used,
        "inputs": ins,
        "outputs": outs,
    }
    return out, arrays


def _inverse(result: EstimationResult, lin, bandwidth: float) -> tuple[dict[str, Any] | None, dict[str, Any] | None]:
    """Inverse simulation on the first fitted segment: the inputs the linearised model needs
    to follow the measured outputs, and the residual inputs (needed minus flown) per excited
    input, in perturbations about the first sample (trim). The loop tracks the outputs that
    are also states (falling back to all outputs) at ``bandwidth`` rad/s, halved up to three
    times while the sampled loop is unstable. A higher bandwidth feeds more measurement
    noise into the residual inputs; compare methods at the same bandwidth."""
    A, B, C, D, x0, u0 = lin
    seg = result.segments[0]
    excited = [i for i in range(seg.u.shape[1]) if np.std(seg.u[:, i]) > 1e-12]
    finite = np.all(np.isfinite(seg.z), axis=0)
    keep = finite & np.array([o in result.model.states for o in result.outputs])
    if not keep.any():
        keep = finite
    if not excited or not keep.any():
        return None, None
    model = result.model_with_estimates()
    p = Namespace({pp.name: float(pp.value) for pp in model.parameters})
    rows = model.g(x0[:, None], u0[:, None], p, Namespace(model.constants_for(seg)))
    y0 = np.array([float(np.asarray(r, dtype=float).ravel()[0]) for r in rows])
    du = seg.u[:, excited] - u0[excited]
    # scipy.signal.dlsim (inside inverse_simulation) takes floor(t[-1] / dt) + 1 samples, one
    # short when rounding leaves t[-1] a hair below (N-1) dt (seen on resampled log times):
    # march on an exact grid kept just above (N-1) dt
    dt = float(np.median(np.diff(seg.t)))
    t_loop = np.arange(seg.t.size) * dt
    t_loop[-1] += 1e-9 * dt
    bw = bandwidth
    for attempt in range(4):
        try:
            inv = V.inverse_simulation(
                A,
                B[:, excited],
                C[keep],
                D[keep][:, excited],
                t_loop,
                seg.z[:, keep] - y0[keep],
                u_ref=du,
                bandwidth=bw,
            )
            break
        except ValueError as exc:
            if "unstable" not in str(exc) or attempt == 3:
                raise
            bw /= 2.0
    per = {}
    for j, i in enumerate(excited):
        name = result.model.inputs[i]
        fac, unit = display_unit(name)
        r = inv.residual_inputs[:, j]
        rms_r, rms_u = float(np.sqrt(np.mean(r**2))), float(np.sqrt(np.mean(du[:, j] ** 2)))
        per[name] = num(
            {
                "rms_residual": rms_r,
                "max_abs_residual": float(np.max(np.abs(r))),
                "rms_input": rms_u,
                "ratio": rms_r / rms_u if rms_u > 0 else math.nan,
                "unit": unit,
                "rms_residual_display": rms_r * fac,
            }
        )
    ins = [result.model.inputs[i] for i in excited]
    tracked = [o for o, k in zip(result.outputs, keep) if k]
    return (
        {"segment": seg.name or "segment 0", "tracked": tracked, "bandwidth": bw, "per_input": per},
        {"t": seg.t, "name": seg.name or "#0", "inputs": ins, "residual_inputs": inv.residual_inputs},
    )


#: proof-of-match modes (see :func:`validate`)
POM_MODES = ("auto", "simulation", "air-data")


def _process_noise(result: EstimationResult) -> np.ndarray | None:
    """The process noise F (n, n) a result identified or used (FEM, EKF, UKF); None for
    methods without one (output error and its stabilised forms, equation error)."""
    F = result.extra.get("F", result.extra.get("process_noise"))
    return None if F is None else np.asarray(F, dtype=float)


def pom_mode(result: EstimationResult, lin=None, calm_air: bool = False) -> str:
    """The proof of match that suits a result: ``air-data`` (the model driven by its
    measured air data, :func:`estimators.validation.air_data_prediction`) when the method
    modelled process noise (it was chosen for turbulence: an open-loop simulation cannot
    follow the gusts) unless the held-out maneuvers are known to be flown in calm air
    (``calm_air``), or when the identified model is unstable (its open-loop simulation
    diverges from any error in the initial state), provided the model has an air-data
    state to drive; ``simulation`` (open loop, the classic proof of match) otherwise."""
    if not V.driving_states(result.model):
        return "simulation"
    F = _process_noise(result)
    if F is not None and np.any(F != 0) and not calm_air:
        return "air-data"
    if lin is not None and np.max(np.linalg.eigvals(lin[0]).real) > 1e-3:
        return "air-data"
    return "simulation"


def _proof_of_match(
    result: EstimationResult,
    held_out: Sequence[Segment],
    tolerances: Mapping[str, float] | None,
    allowed_bias: Mapping[str, float] | None,
    integrator: str,
    mode: str,
    step_times: Sequence[Mapping[str, Any]] | None = None,
) -> tuple[dict[str, Any], list[dict[str, Any]]]:
    model = result.model_with_estimates()
    segs, arrays = [], []
    driven: list[str] = []
    notes: list[str] = []
    for k, seg in enumerate(held_out):
        y, sens = None, None
        if mode == "air-data":
            try:
                dp = _air_data_prediction(result, seg, integrator)
                y, driven = dp.predicted, dp.driven
                sens = _air_data_sensitivity(result, seg, integrator, y)
            except (estimators.EstimationError, np.linalg.LinAlgError) as exc:
                # reported, and the classic proof of match run instead of none
                notes.append(f"air-data prediction of {seg.name or k} failed ({exc}); open-loop simulation instead")
                driven = []
        seg_mode = "air-data" if y is not None else "simulation"
        if y is None:
            y, fit = _held_out_fit(result, seg, integrator)
            sens = _prediction_sensitivity(result, seg, fit, integrator)
        name = seg.name or f"held-out {k}"
        steps = (step_times or [{}] * len(held_out))[k] or {}
        envelope, timing = _timing_envelope(result, seg, steps, seg_mode, integrator, y, notes, name)
        z = pd.DataFrame(seg.z, index=y.index, columns=model.outputs)
        # the channels that drive the filter are its one-step predictions: not judged
        tol = {**(tolerances or {}), **{c: math.nan for c in driven}}
        # the measurement noise of the held-out data, so that it alone does not fail a
        # channel somewhere in a long segment: the white level of the second differences of
        # its error against the prediction (robust: the kinks at control steps aside). The
        # data's own second differences carry the signal's curvature on a slow channel
        # (default.toml at ArduPilot's rates with 10 Hz surfaces, seed 1, ad hoc: the 5 Hz
        # rebuilt beta 0.45 deg from the data, 0.22 from the error; 25 Hz p 0.15 and 0.13
        # for a 0.10 deg/s gyro noise)
        noise = {
            c: float(v)
            for c, v in zip(model.outputs, st.difference_noise_std([seg.z - y.to_numpy(float)], robust=True))
            if np.isfinite(v) and v > 0
        }
        pm = V.proof_of_match(z, y, tolerances=tol, allowed_bias=allowed_bias, envelope=envelope, noise_std=noise)
        tic = V.theil(z.to_numpy(), y.to_numpy()).U
        chans = {}
        for (ch, row), u in zip(pm.iterrows(), tic):
            fac, unit = display_unit(ch)
            d = num(row.to_dict())
            d.update(
                unit=unit,
                tolerance_display=num(row["tolerance"] * fac),
                max_abs_error_display=num(row["max_abs_error"] * fac),
                rms_error_display=num(row["rms_error"] * fac),
                TIC=num(u),
                noise_allowance_display=num(row["noise_allowance"] * fac),
                role="drives the filter" if ch in driven else "predicted",
            )
            if envelope is not None:
                d.update(
                    nominal_max_abs_error_display=num(row["nominal_max_abs_error"] * fac),
                    envelope_max_width_display=num(row["envelope_max_width"] * fac),
                )
            chans[ch] = d
        arr = {
            "name": name,
            "t": seg.t,
            "measured": z,
            "predicted": y,
            "excess": pm.attrs["excess"],
            "sensitivity": sens,
            "tolerance": pm["tolerance"].to_numpy(float),
            "envelope": None
            if envelope is None
            else tuple(pd.DataFrame(a, index=y.index, columns=y.columns) for a in envelope),
        }
        _prediction_entries(chans, arr, None if sens is None else _band_covariance(result, sens[0]))
        segs.append(
            {
                "name": name,
                "mode": seg_mode,
                "channels": chans,
                "input_timing": timing,
                "all_pass": bool(pm.attrs["all_pass"]),
                "prediction_uncertainty": None if sens is None else {"parameters": len(sens[0]), "k": V.PREDICTION_K},
            }
        )
        arrays.append(arr)
    if segs and all(sg["mode"] == "simulation" for sg in segs):
        mode = "simulation"
    return {
        "mode": mode,
        "driven": driven,
        "segments": segs,
        "notes": notes,
        "all_pass": bool(segs) and all(s["all_pass"] for s in segs),
    }, arrays


def _band_covariance(result: EstimationResult, names: Sequence[str]) -> np.ndarray:
    """The covariance of ``names`` among the result's free shared parameters (total:
    with its consider part), for the held-out prediction's std."""
    have, cov = _shared_covariance(result)
    idx = [have.index(n) for n in names]
    return cov[np.ix_(idx, idx)]


def _prediction_entries(chans: dict[str, dict[str, Any]], arr: dict[str, Any], cov: np.ndarray | None) -> None:
    """Set each proof-of-match channel's entries of the prediction's own uncertainty
    (display units, in place): ``prediction_std_max_display`` (its largest std),
    ``beyond_prediction_display`` (how far the misses reach beyond PREDICTION_K of it) and,
    on a failed channel, ``prediction_std_from`` (the derivatives carrying at least a tenth
    of the variance at its worst miss, :func:`estimators.validation.variance_shares`, at
    most 3: the ones better maneuvers should pin down); and the segment's ``arrays`` entry
    ``arr``'s ``prediction_std`` (N, n_out) DataFrame. From ``arr``: ``excess`` (N, n_out)
    each sample's error beyond its band, ``predicted`` (its columns and index) and
    ``sensitivity`` (names, S (N, n_out, n_p)) with ``cov`` their covariance, or None (no
    band: the entries None)."""
    sens, excess, columns = arr["sensitivity"], arr["excess"], arr["predicted"].columns
    ps = None if sens is None else V.prediction_std(sens[1], cov)
    arr["prediction_std"] = None if ps is None else pd.DataFrame(ps, index=arr["predicted"].index, columns=columns)
    top, beyond = V.prediction_uncertainty(excess, ps) if ps is not None else (np.full(len(columns), np.nan),) * 2
    for j, ch in enumerate(columns):
        d = chans.get(ch)
        if d is None:
            continue
        fac = display_unit(ch)[0]
        d.update(prediction_std_max_display=num(top[j] * fac), beyond_prediction_display=num(beyond[j] * fac))
        if ps is not None and d.get("pass") is False and np.isfinite(excess[:, j]).any():
            n = int(np.nanargmax(excess[:, j]))
            share = V.variance_shares(sens[1][n, j], cov)
            d["prediction_std_from"] = {
                sens[0][i]: num(round(float(share[i]), 3)) for i in np.argsort(-share)[:3] if share[i] >= 0.1
            }


def refresh_prediction_uncertainty(validation: dict[str, Any], result: EstimationResult) -> None:
    """Redo the proof of match's prediction-uncertainty entries of ``validation`` (in
    place) with the result's current covariance (a ``consider_cov`` set after validation),
    from the sensitivities and per-sample misses kept in its ``arrays``."""
    pm = validation.get("proof_of_match")
    arrays = (validation.get("arrays") or {}).get("match") or []
    if not pm:
        return
    for sg, a in zip(pm["segments"], arrays):
        if a.get("sensitivity") is None:
            continue
        _prediction_entries(sg["channels"], a, _band_covariance(result, a["sensitivity"][0]))
    validation["verdict"] = verdict(validation)


def _timing_envelope(
    result: EstimationResult,
    seg: Segment,
    steps: Mapping[str, Any],
    mode: str,
    integrator: str,
    y: pd.DataFrame,
    notes: list[str],
    name: str,
) -> tuple[tuple[np.ndarray, np.ndarray] | None, dict[str, Any] | None]:
    """The range of the held-out prediction ``y`` over the unknown times of the segment's
    control-input steps between slow samples (``steps``: input -> [(start, end, std), ...]
    s, :func:`pipeline.conditioning.input_sampling.step_times`): the model, as held, predicts the
    segment again with every such step moved through the range of its time - an untimed
    one anywhere in its interval, a timed one within TIMED_RANGE_STD of its std
    (:func:`pipeline.conditioning.input_sampling.timing_variants`) - in ``mode`` as ``y`` was; (lower,
    upper) over those and ``y``, and what was done. (None, None) when no step moves a grid
    sample of the segment; (None, doc) with a note when a prediction fails. Why: with the
    surfaces at 10 Hz (scenarios/default.toml at ArduPilot's rates, seed 1, ad hoc) a
    cross-controlled rudder step left untimed was a 100 ms ramp in the prediction, and p
    and r missed the 1.5 deg/s band by 14 deg/s at that step; at 25 Hz (seed 3) the steps
    were all timed, and one sample of p and r, at an aileron doublet's reversal where p
    moves 900 deg/s^2, missed the band by 0.08 and 0.02 deg/s."""
    from pipeline.conditioning.input_sampling import TIMED_RANGE_STD, TIMING_FRACTIONS, timing_variants

    variants = timing_variants(seg, result.model.inputs, steps) if steps else []
    if not variants:
        return None, None
    inside = [sd for c in result.model.inputs for a, b, sd in steps.get(c, ()) if seg.t[0] < a and b < seg.t[-1]]
    doc: dict[str, Any] = {
        "steps": len(inside),
        "untimed": sum(sd is None for sd in inside),
        "timed_range_std": TIMED_RANGE_STD,
        "fractions": list(TIMING_FRACTIONS),
        "envelope": False,
    }
    ys = []
    for v in variants:
        try:
            ys.append(
                _air_data_prediction(result, v, integrator).predicted
                if mode == "air-data"
                else _held_out_prediction(result, v, integrator)
            )
        except (estimators.EstimationError, np.linalg.LinAlgError) as exc:
            notes.append(
                f"{name}: the prediction with its control-input steps moved within "
                f"their timing uncertainty failed ({exc}); judged on the steps as fitted"
            )
            return None, doc
    stack = np.stack([y.to_numpy(float)] + [a.to_numpy(float) for a in ys])
    doc["envelope"] = True
    return (np.min(stack, axis=0), np.max(stack, axis=0)), doc


def _air_data_prediction(
    result: EstimationResult, seg: Segment, integrator: str, shift: Mapping[str, float] | None = None
):
    """The identified model driven by the held-out segment's air data: every derivative
    held; per-segment parameters (output biases) at their mean over the fitted segments
    (sensor biases persist through a flight); the filter's process noise on the air-data
    states is the one the method identified or used (FEM, EKF, UKF), else the data
    default; the measurement noise is the method's (its R). ``shift``: amounts added to
    shared parameters (the sensitivities of :func:`_air_data_sensitivity`)."""
    vals = {n: v + (shift or {}).get(n, 0.0) for n, v in zip(result.names, result.values) if "[" not in n}
    per_seg: dict[str, list[float]] = {}
    for n, v in zip(result.names, result.values):
        if "[" in n and not n.startswith("x0_"):
            per_seg.setdefault(n.split("[")[0], []).append(float(v))
    vals.update({n: float(np.mean(v)) for n, v in per_seg.items()})
    R = result.extra.get("measurement_noise", result.R)
    return V.air_data_prediction(
        result.model.with_values(vals),
        seg,
        process_noise=_process_noise(result),
        measurement_noise=R,
        integrator=integrator,
        inputs=result.settings.get("inputs", DEFAULT_INPUTS),
    )


def _air_data_sensitivity(
    result: EstimationResult, seg: Segment, integrator: str, y: pd.DataFrame, rel_step: float = 1e-5
) -> tuple[list[str], np.ndarray] | None:
    """(names, S) as :func:`_prediction_sensitivity`, for the air-data-driven prediction
    ``y``: forward differences, one filter pass per free shared model parameter (the
    filter's gain moves with them too; nothing is refitted to the segment). None when a
    pass fails."""
    names = _band_parameters(result)
    if not names:
        return None
    vals = result.params
    cols = []
    for n in names:
        h = rel_step * max(abs(float(vals[n])), 1.0)
        try:
            yp = _air_data_prediction(result, seg, integrator, {n: h}).predicted
        except (estimators.EstimationError, np.linalg.LinAlgError):
            return None
        cols.append((yp.to_numpy(float) - y.to_numpy(float)) / h)
    S = np.stack(cols, axis=2)
    return (names, S) if np.all(np.isfinite(S)) else None


def _held_out_prediction(result: EstimationResult, seg: Segment, integrator: str) -> pd.DataFrame:
    """The identified model's prediction of a held-out segment (:func:`_held_out_fit`)."""
    return _held_out_fit(result, seg, integrator)[0]


def _held_out_fit(
    result: EstimationResult, seg: Segment, integrator: str
) -> tuple[pd.DataFrame, EstimationResult | None]:
    """The identified model's prediction of a held-out segment: every derivative held at
    its estimate; only the segment's initial state and the model's per-segment biases are
    adjusted to the data (the usual proof of match - a noisy first sample as initial
    condition would excite the phugoid and fail the angles for no fault of the model).
    Falls back to a plain simulation from the segment's x0 when that fit fails (None for
    the fit)."""
    shared = {n: v for n, v in zip(result.names, result.values) if "[" not in n}
    model = result.model.with_values(shared).fixed([n for n in result.free_names if "[" not in n])
    inputs = result.settings.get("inputs", DEFAULT_INPUTS)
    try:
        fit = estimators.OutputError(model, integrator=integrator, inputs=inputs, fallback="never").fit(
            seg, estimate_x0=True
        )
        return fit.predicted[0], fit
    except estimators.EstimationError:
        return simulate_outputs(result.model_with_estimates(), seg, integrator=integrator, inputs=inputs), None


def _shared_covariance(result: EstimationResult) -> tuple[list[str], np.ndarray]:
    """(names, covariance) of the result's free shared parameters (no per-segment ones):
    its covariance plus its ``consider_cov`` when it has one (the total uncertainty)."""
    free = result.free_names
    keep = [i for i, n in enumerate(free) if not is_segment_parameter(n)]
    cov = np.asarray(result.cov, dtype=float)
    if result.consider_cov is not None:
        cov = cov + np.asarray(result.consider_cov, dtype=float)
    return [free[i] for i in keep], cov[np.ix_(keep, keep)]


def _band_parameters(result: EstimationResult) -> list[str]:
    """The free shared parameters of the result's model that its predictions depend on
    (filter error's process-noise F_<state>, G_<output> are not the model's)."""
    return [n for n in _shared_covariance(result)[0] if n in result.model.parameter_names]


def _prediction_sensitivity(
    result: EstimationResult, seg: Segment, fit: EstimationResult | None, integrator: str
) -> tuple[list[str], np.ndarray] | None:
    """(names, S) with S (N, n_out, n_names) the held-out prediction's sensitivity to the
    result's free shared parameters, the segment's initial state and output biases refitted
    as the proof of match fits them (:func:`estimators.validation.parameter_sensitivity`,
    weighted by that fit's residual variance); None without that fit or when the
    simulation fails. Parameters the result held (another axis' estimates a 6-DoF model
    holds) add nothing here: their uncertainty is not in its covariance."""
    if fit is None:
        return None
    names = _band_parameters(result)
    if not names:
        return None
    values = {n: float(v) for n, v in zip(fit.names, fit.values)}
    w = 1.0 / np.diag(np.atleast_2d(fit.R))
    w = np.where(np.isfinite(w) & (w > 0), w, 0.0)
    try:
        S = V.parameter_sensitivity(
            fit.model,
            seg,
            values,
            names,
            fit.free_names,
            weights=w,
            integrator=integrator,
            inputs=result.settings.get("inputs", DEFAULT_INPUTS),
        )
    except (estimators.EstimationError, np.linalg.LinAlgError, ValueError):
        return None
    return (names, S) if np.all(np.isfinite(S)) else None


def _truth_check(result: EstimationResult, truth: Mapping[str, float], k: float) -> dict[str, Any]:
    """Each free parameter with a truth: |error| against k x its total std (the Cramér-Rao
    bound plus what the result's ``consider_cov`` adds, e.g. the sensor corrections)."""
    out = {}
    std = result.total_std
    for name in result.free_names:
        if name not in truth:
            continue
        est, sd, tr = float(result.params[name]), float(std[name]), float(truth[name])
        err = est - tr
        ins = abs(err) / sd if sd > 0 and math.isfinite(sd) else math.nan
        out[name] = num(
            {"estimate": est, "std": sd, "truth": tr, "error": err, "error_in_std": ins, "within": bool(ins <= k)}
        )
    return {"k": k, "per_parameter": out, "all_within": bool(out) and all(v["within"] for v in out.values())}


def _is_method(name: Any, base: str) -> bool:
    """Whether a method name or result key is of method ``base``: "fem" for "fem",
    "fem-nl" and "lateral-fem"; "ukf" for "ukf-aug"."""
    return base in str(name or "").split("-")


def _trusted_over(method: Any, other: Any, converged: bool = True) -> bool:
    """Whether ``other`` is the method to trust where it and ``method`` disagree: a
    converged filter-error fit (fem, fem-nl) over an EKF or UKF of the same flight."""
    return converged and _is_method(other, "fem") and any(_is_method(method, m) for m in ("ekf", "ukf"))


def _pom_channels(pm: Mapping[str, Any]) -> tuple[float, list[str], list[str], list[str]]:
    """(k, within, beyond, unweighed): the failed proof-of-match channels by how their
    misses compare with k (PREDICTION_K) std of the prediction's own uncertainty, the
    worst segment deciding (beyond on any segment, else no uncertainty on any, else within)."""
    k = next(
        (sg["prediction_uncertainty"]["k"] for sg in pm["segments"] if sg.get("prediction_uncertainty")), V.PREDICTION_K
    )
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


def verdict(v: Mapping[str, Any]) -> dict[str, Any]:
    """The verdict on one fit from its validation dict: ``level`` (PASS / CHECK / FAIL, the
    worst of its reasons' levels, :data:`REASON_LEVELS`), ``ok`` (level PASS), ``reasons``
    with their ``reason_levels``, and ``notes`` that set no level.

    Reasons: not converged; TIC over the limit; a failed proof of match, by whether its
    misses are within the prediction's own uncertainty; truth beyond k std (when known); an
    EKF/UKF disagreeing with filter error (``agreement`` from :func:`cross_check_methods`).
    Notes: residual colour, correlations, frequency mismatch, a-priori values, other
    methods' disagreement, and for an output-error method with coloured residuals and
    scattering maneuvers the advice to fit filter error."""
    reasons: list[tuple[str, str]] = []  # (kind, sentence)
    notes: list[str] = []
    if not v.get("converged", True):
        why = v.get("not_settled")
        reasons.append(
            ("not converged", f"the filter passes did not settle: {why}" if why else "the optimiser did not converge")
        )
    fit = v.get("fit") or {}
    if fit and not fit.get("tic_ok", True):
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
    pm = v.get("proof_of_match")
    if pm is not None and not pm["all_pass"]:
        k, within, beyond, unweighed = _pom_channels(pm)
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
        notes += _prediction_notes(pm)
    tr = (v.get("plausibility") or {}).get("truth")
    if tr and tr["per_parameter"] and not tr["all_within"]:
        bad = [n for n, d in tr["per_parameter"].items() if not d["within"]]
        reasons.append(("truth", f"{', '.join(bad)} more than {tr['k']:g} std from the truth"))
    ap = (v.get("plausibility") or {}).get("apriori")
    if ap:
        flagged = [n for n, d in ap.items() if d.get("flag")]
        if flagged:
            notes.append(f"disagree with a-priori values: {', '.join(flagged)}")
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


def _prediction_notes(pm: Mapping[str, Any]) -> list[str]:
    """Verdict notes on the failed channels of a proof of match whose prediction has its
    own uncertainty from the estimates: are the misses within k (PREDICTION_K) std of it
    (the estimates' precision limits the match) or beyond (the model's form, its inputs or
    biased estimates)?"""
    within, beyond = {}, {}
    k = next(
        (sg["prediction_uncertainty"]["k"] for sg in pm["segments"] if sg.get("prediction_uncertainty")), V.PREDICTION_K
    )
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


def refresh_truth_check(
    validation: dict[str, Any], result: EstimationResult, truth: Mapping[str, float] | None, truth_k: float = TRUTH_K
) -> None:
    """Redo the truth check and the verdict of ``validation`` (in place) after the result's
    uncertainty changed (a ``consider_cov`` set after validation)."""
    if not truth:
        return
    validation.setdefault("plausibility", {})["truth"] = _truth_check(result, truth, truth_k)
    validation["verdict"] = verdict(validation)


def is_segment_parameter(name: str) -> bool:
    """Per-segment parameters (``bias_az[0]``, ``x0_V[1]``): biases and initial states."""
    return name.endswith("]") and "[" in name


def method_group(key: str) -> str:
    """The axis a result key belongs to: "lateral" for "lateral-fem", "" for a bare method
    name (one axis fitted, or a user model)."""
    return key.rsplit("-", 1)[0] if "-" in key else ""


def cross_check_methods(
    results: Mapping[str, EstimationResult], validations: dict[str, dict[str, Any]], k: float = TRUTH_K
) -> dict[str, Any]:
    """Every pair of methods fitted to the same axis, compared on the parameters both
    estimate (:func:`estimators.validation.agreement`, with each result's total std: the
    Cramér-Rao bound plus its consider part). Run it once all uncertainties are final.
    Without a truth this is the run's own check of its estimates: a flag means a method's
    assumptions do not hold for the flight (e.g. output error in turbulence, or an EKF whose
    process noise carries the response it should leave to the parameters).

    Sets ``agreement`` in each compared method's validation and redoes its verdict: a FAIL
    reason for an EKF/UKF that disagrees with a converged filter-error fit (the method to
    trust in turbulence, :data:`REASON_LEVELS`), a note for any other disagreeing pair.
    The test is |a - b| / sqrt(std_a^2 + std_b^2) > k, k = TRUTH_K (3). Returns, per axis with at least two methods (key "" when the
    keys carry no axis): ``methods``, ``k``, ``table`` (one record per parameter and pair,
    the columns of :func:`~estimators.validation.agreement`), ``n_flagged`` and
    ``odd_one_out``: the method that disagrees with every other one while those agree among
    themselves (three methods or more; None otherwise) - the one whose assumptions to doubt
    first (output error in turbulence: longitudinal_3211_turbulence)."""
    groups: dict[str, list[str]] = {}
    for key in results:
        groups.setdefault(method_group(key), []).append(key)
    out = {}
    for axis, keys in groups.items():
        if len(keys) < 2:
            continue
        est = {}
        for key in keys:
            r = results[key]
            names = [n for n in r.free_names if not n.startswith("x0_") and not is_segment_parameter(n)]
            est[key] = (r.params[names], r.total_std[names])
        table = V.agreement(est, k)
        for key in keys:
            flagged: dict[str, dict[str, float]] = {}
            for row in table[table["flag"]].itertuples():
                if key in (row.method_a, row.method_b):
                    other = row.method_b if key == row.method_a else row.method_a
                    flagged.setdefault(other, {})[row.parameter] = float(row.z)
            if key in validations:
                validations[key]["agreement"] = {
                    "k": k,
                    "flagged": flagged,
                    "against": {
                        o: {"method": results[o].method, "converged": bool(results[o].converged)} for o in flagged
                    },
                }
                validations[key]["verdict"] = verdict(validations[key])
        pairs = {frozenset((r.method_a, r.method_b)) for r in table[table["flag"]].itertuples()}
        odd = [
            m
            for m in keys
            if len(keys) > 2
            and all(frozenset((m, o)) in pairs for o in keys if o != m)
            and not any(m not in pr for pr in pairs)
        ]
        out[axis] = {
            "methods": keys,
            "k": k,
            "n_flagged": int(table["flag"].sum()),
            "odd_one_out": odd[0] if odd else None,
            "table": num(table.to_dict(orient="records")),
        }
    return out


# -- entry point ------------------------------------------------------------------------------
def validate(
    result: EstimationResult,
    *,
    held_out: Sequence[Segment] | None = None,
    tolerances: Mapping[str, float] | None = None,
    apriori: Any = None,
    truth: Mapping[str, float] | None = None,
    allowed_bias: Mapping[str, float] | None = None,
    tic_limit: float = TIC_LIMIT,
    truth_k: float = TRUTH_K,
    mag_bound_db: float = 3.0,
    phase_bound_deg: float = 20.0,
    min_coherence: float = 0.6,
    input_power_fraction: float = 0.1,
    inverse_bandwidth: float = 5.0,
    integrator: str | None = None,
    proof_of_match: str = "auto",
    calm_air: bool = False,
    step_times: Sequence[Mapping[str, Any]] | None = None,
) -> dict[str, Any]:
    """Run the validation of :mod:`estimators.validation` on one result (see module doc).
    Where the fit's maneuvers scatter significantly beyond its Cramér-Rao bounds, the
    result's covariance is widened in place to that scatter (:func:`widen_by_scatter`;
    ``result.std_method`` then says so, the bound stays in ``extra["crb_cov"]``).

    held_out: segments NOT used in the fit (same model input/output columns); the
        identified model, all parameters held fixed, predicts each from its measured
        initial condition (``Segment.x0`` or the states read from z[0]) and is judged
        against ``tolerances`` (SI per channel, merged over the defaults: 1.5 deg/s on
        rates, 0.1 g on specific forces, 1.5 deg on angles).
    proof_of_match: how the held-out prediction is made (:data:`POM_MODES`):
        ``simulation`` - open loop, only the initial state and per-segment biases fitted
        to the held-out data (the classic proof of match, for calm air and stable models);
        ``air-data`` - the model driven by its measured air data through a Kalman filter
        that sees only V/alpha/beta (see :mod:`estimators.validation.prediction`; those
        channels are then not judged); ``auto`` (default) - :func:`pom_mode`.
    calm_air: the held-out maneuvers are known to be flown in calm air (a simulated
        validation flight): ``auto`` then picks the simulation for every stable model.
    step_times: per held-out segment, the control-input steps of its flight between two
        slow samples (input -> [(start, end, std or None), ...] s,
        :func:`pipeline.conditioning.input_sampling.step_times`): the held-out prediction is also made
        with each moved through the range of its time (untimed: its interval; timed: 2 std
        either side), and a sample is judged by its distance from the range of those
        predictions (the step's time is as uncertain as a sensor bias; ``input_timing`` of
        the segment and the channels' nominal error and envelope width say what it did).
    allowed_bias: largest constant offset per channel (SI) removed before judging.
    apriori: a-priori values (TOML path, mapping or DataFrame of
        :func:`estimators.validation.load_apriori`); truth: true parameter values by name.
    mag_bound_db, phase_bound_deg, min_coherence: frequency-response mismatch bounds; only
        frequencies where an input's auto-spectrum reaches input_power_fraction of its peak
        and the coherence reaches min_coherence are judged.
    inverse_bandwidth: loop bandwidth (rad/s) of the inverse simulation.
    integrator: for the proof-of-match simulation (default: the one used in the fit).
    """
    integ = integrator or result.settings.get("integrator", "rk4")
    if integ not in INTEGRATORS:  # filter error's linear form: "transition matrix"
        integ = "rk4"
    out: dict[str, Any] = {
        "method": result.method,
        "converged": bool(result.converged),
        "not_settled": result.extra.get("not_settled"),
        "det_R": num(result.cost),
        "correlations_flagged": num([list(f) for f in result.flagged_correlations]),
    }
    arrays: dict[str, Any] = {}
    out["fit"] = _fit(result, tic_limit)
    out["residuals"], arrays["psd"] = _residuals(result)
    out["uncertainty"] = _uncertainty(result)
    widen_by_scatter(result, out["uncertainty"])
    lin = None
    out["modes"] = None  # not applicable: no states or no segments
    if result.segments and result.model.states:
        try:
            lin = linear_model(result)
            out["modes"] = _modes(result, lin)
        except Exception as exc:  # noqa: BLE001 - reported, not fatal
            out["modes"] = {"error": f"{type(exc).__name__}: {exc}"}
    out["frequency"], arrays["freq"] = (None, None)
    if lin is not None:
        try:
            out["frequency"], arrays["freq"] = _frequency(
                result,
                lin,
                mag_bound_db=mag_bound_db,
                phase_bound_deg=phase_bound_deg,
                min_coherence=min_coherence,
                input_power_fraction=input_power_fraction,
                integrator=integ,
            )
        except (ValueError, np.linalg.LinAlgError, estimators.EstimationError) as exc:
            out["frequency"] = {"error": f"{type(exc).__name__}: {exc}"}
    out["inverse_simulation"], arrays["inverse"] = None, None
    if lin is not None:
        try:
            out["inverse_simulation"], arrays["inverse"] = _inverse(result, lin, inverse_bandwidth)
        except (ValueError, np.linalg.LinAlgError) as exc:
            out["inverse_simulation"] = {"error": f"{type(exc).__name__}: {exc}"}
    out["proof_of_match"], arrays["match"] = None, []
    if proof_of_match not in POM_MODES:
        raise ValueError(f"proof_of_match={proof_of_match!r}: use one of {', '.join(POM_MODES)}")
    if held_out:
        mode = pom_mode(result, lin, calm_air) if proof_of_match == "auto" else proof_of_match
        out["proof_of_match"], arrays["match"] = _proof_of_match(
            result, list(held_out), tolerances, allowed_bias, integ, mode, step_times
        )
    plaus: dict[str, Any] = {}
    if truth:
        plaus["truth"] = _truth_check(result, truth, truth_k)
    if apriori is not None:
        names = result.free_names
        pl = V.plausibility(result.params[names], result.std[names], apriori)
        plaus["apriori"] = frame_dict(pl)
    out["plausibility"] = plaus
    out["verdict"] = verdict(out)
    out["arrays"] = arrays
    return out
