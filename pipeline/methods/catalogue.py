"""The estimation methods the pipeline runs, one :class:`Method` per name: what it is (help
text), on which grid and model it is fitted, where its start values and noise levels come
from, and how a refit of it starts. The fits themselves are :mod:`pipeline.methods.fitting`.

Light on purpose (standard library only): the command line takes its ``--method`` choices
and help text from here without loading the numerical packages.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from pipeline.errors import FsidError


@dataclass(frozen=True)
class Method:
    """One estimation method of the pipeline.

    name: the ``--method`` value and the report's key.
    help: what it runs (the report and ``--help``).
    listing: its entry in the ``--method`` help (None: listed with the method before it).
    start_free: its estimate does not depend on the start values once converged (maximum
        likelihood, least squares): a refit may start from an earlier estimate.
    unclamped_starts: starts from the equation-error estimates without the problem's
        "flyable" sign clamps (the stabilised methods and the filters keep their predictions
        bounded and need an unstable sign where the data show it).
    common_grid: fitted on the grid of the slowest output channel (filter error's
        steady-state gain is that of every output; the Kalman filters would update on some
        outputs only) and with the gust models of the axis in turbulence.
    logged_noise: its measurement noise starts from the log's native samples
        (:func:`pipeline.methods.noise.attach_logged_noise`).
    own_samples_grid: with a gust model, the air-data angles rebuilt from the flight path are
        measured at their own samples and the grid is that of the slowest other output
        (filter error's per-pattern gains).
    noise_from: the method whose fit of the same problem gives the process noise when no
        turbulence level is known, and whose held alphadot derivatives this one holds too.
    refit_carry: a refit from an earlier result starts from its free values and from the
        expanded names with these prefixes (None: from the model's values only).
    one_step_refit: a refit moves the earlier estimate by one Gauss-Newton step with that
        fit's sensitivities instead of refitting.
    regressions: the method is the built-in models' coefficient regressions (why it needs
        them; None: it takes any model).
    lateral: the lateral model of a built-in fit: "sixdof" (the 6-DoF model holding the
        longitudinal estimates of this method when there are some, else the linear model
        driven by the measured longitudinal states with per-maneuver airspeed offsets),
        "measured" (driven by the measured longitudinal states) or "linear".
    """

    name: str
    help: str
    listing: str | None
    start_free: bool = False
    unclamped_starts: bool = True
    common_grid: bool = False
    logged_noise: bool = False
    own_samples_grid: bool = False
    noise_from: str | None = None
    refit_carry: tuple[str, ...] | None = None
    one_step_refit: bool = False
    regressions: str | None = None
    lateral: str = "linear"


#: every method, in the order of ``--method``'s choices
CATALOGUE: tuple[Method, ...] = (
    Method(
        "oem",
        "output error (calm air)",
        "oem: output error",
        start_free=True,
        unclamped_starts=False,
        refit_carry=("x0_",),
        one_step_refit=True,
        lateral="sixdof",
    ),
    Method(
        "ls",
        "equation error: least squares on the coefficients from measured accelerations",
        "ls: equation error",
        start_free=True,
        unclamped_starts=False,
        regressions="equation error (ls) regresses the built-in models' force and moment coefficients",
        lateral="measured",
    ),
    Method(
        "fem",
        "filter error (process and measurement noise; turbulence)",
        "fem: filter error",
        start_free=True,
        common_grid=True,
        logged_noise=True,
        own_samples_grid=True,
        refit_carry=("x0_", "F_"),
    ),
    Method(
        "ekf",
        "extended Kalman filter with the parameters in the state",
        "ekf/ukf: extended/unscented Kalman filter",
        common_grid=True,
        noise_from="fem",
    ),
    Method("ukf", "unscented Kalman filter with the parameters in the state", None, common_grid=True, noise_from="fem"),
    Method("soem", "stabilised output error (unstable aircraft)", "soem: stabilised output error", start_free=True),
    Method(
        "eigen",
        "output error with eigenvalue transformation (unstable aircraft)",
        "eigen: eigenvalue transformation",
        start_free=True,
    ),
    Method(
        "decouple",
        "output error with equation decoupling (unstable aircraft)",
        "decouple: equation decoupling",
        start_free=True,
    ),
)
#: name -> method
SPECS: dict[str, Method] = {m.name: m for m in CATALOGUE}
#: the method names, in the order of ``--method``'s choices
METHODS: tuple[str, ...] = tuple(SPECS)
#: name -> what it runs (for --help and the report)
METHOD_HELP: dict[str, str] = {m.name: m.help for m in CATALOGUE}
#: the methods for the ``--method`` help text
METHOD_LIST: str = "; ".join(m.listing for m in CATALOGUE if m.listing)


def method_spec(name: str) -> Method:
    """The :class:`Method` called ``name``; FsidError naming the known ones otherwise."""
    try:
        return SPECS[name]
    except KeyError:
        raise FsidError(f"unknown method {name!r}: use one of {', '.join(METHODS)}") from None


def check_methods(methods: Sequence[str], user_model: bool = False) -> None:
    """FsidError for a name that is no method, or (``user_model``) for a method that needs a
    built-in model's regressions."""
    bad = [m for m in methods if m not in SPECS]
    if bad:
        raise FsidError(f"unknown method(s) {bad}: use some of {', '.join(METHODS)}")
    needs = [m for m in methods if SPECS[m].regressions] if user_model else []
    if needs:
        raise FsidError(
            f"method {', '.join(needs)} is not available for a user model: {SPECS[needs[0]].regressions}; "
            "use oem, fem, ekf or ukf"
        )


def result_key(axis: str, method: str, several_axes: bool) -> str:
    """The key of a fit in the results and the report: the method's name, prefixed with the
    axis ("lateral-oem") when several axes are fitted."""
    return f"{axis}-{method}" if several_axes else method


def scenario_methods(truth: Mapping[str, Any] | None) -> list[str]:
    """The methods that suit a flight plan (truth.json's ``sas`` and ``turbulence``): a
    statically unstable aircraft flown with a SAS -> stabilised output error, equation
    decoupling, FEM, EKF, UKF (the eigenvalue transformation is exact for linear models only
    and the built-in longitudinal model is nonlinear); turbulence -> OEM (kept to show its
    bias), FEM, EKF, UKF; calm air -> OEM and equation error."""
    truth = truth or {}
    if truth.get("sas"):
        return ["soem", "decouple", "fem", "ekf", "ukf"]
    if (truth.get("turbulence") or {}).get("model", "off") not in ("off", None, ""):
        return ["oem", "fem", "ekf", "ukf"]
    return ["oem", "ls"]
