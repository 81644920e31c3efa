"""The registry of the estimation methods the pipeline runs, one :class:`Method` per name:
what it is (help text), on which grid and model it is fitted, where its start values and
noise levels come from, how a refit of it starts, where its fit is and its colour; and
:class:`FitKey`, what a fit's key ("lateral-oem") says. Adding a method is one entry here
and its fit function.

Light on purpose (standard library only) and beside the layers (like errors.py and
paths.py): the command line takes its ``--method`` choices and help text from here without
loading the numerical packages, and every layer - jobs, methods, validation, figures,
recordings - reads methods and keys from this one place.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Mapping, Sequence
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
    fitter: where its fit is, "module:function" ((problem, model, settings) -> result),
        imported on first use (:meth:`fit_function`): the command line reads this table
        without loading the numerical packages.
    colour: its colour in the figures and the recordings (RGB 0-255; None: the palette's).
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
    fitter: str = ""
    colour: tuple[int, int, int] | None = None

    def fit_function(self) -> Callable[..., Any]:
        """The function that fits a problem with this method (imported on first use)."""
        module, _, name = self.fitter.partition(":")
        return getattr(importlib.import_module(module), name)


#: the module holding the methods' fits
FITS = "pipeline.methods.fitting:"

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
        fitter=FITS + "_output_error",
        colour=(31, 119, 180),
    ),
    Method(
        "ls",
        "equation error: least squares on the coefficients from measured accelerations",
        "ls: equation error",
        start_free=True,
        unclamped_starts=False,
        regressions="equation error (ls) regresses the built-in models' force and moment coefficients",
        lateral="measured",
        fitter=FITS + "_equation_error",
        colour=(148, 103, 189),
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
        fitter=FITS + "_filter_error",
        colour=(255, 127, 14),
    ),
    Method(
        "ekf",
        "extended Kalman filter with the parameters in the state",
        "ekf/ukf: extended/unscented Kalman filter",
        common_grid=True,
        noise_from="fem",
        fitter=FITS + "_ekf",
        colour=(44, 160, 44),
    ),
    Method(
        "ukf",
        "unscented Kalman filter with the parameters in the state",
        None,
        common_grid=True,
        noise_from="fem",
        fitter=FITS + "_ukf",
        colour=(214, 39, 40),
    ),
    Method(
        "fdoe",
        "output error in the frequency domain (band from the inputs' spectra; model linearised at each maneuver)",
        "fdoe: frequency-domain output error",
        start_free=True,
        unclamped_starts=False,
        lateral="measured",
        fitter="pipeline.methods.frequency:frequency_output_error",
        colour=(23, 190, 207),
    ),
    Method(
        "fdls",
        "equation error in the frequency domain: the coefficient regressions over the inputs' band",
        "fdls: frequency-domain equation error",
        start_free=True,
        unclamped_starts=False,
        regressions="frequency-domain equation error (fdls) regresses the built-in models' force and moment coefficients",
        lateral="measured",
        fitter="pipeline.methods.frequency:frequency_equation_error",
        colour=(188, 189, 34),
    ),
    Method(
        "soem",
        "stabilised output error (unstable aircraft)",
        "soem: stabilised output error",
        start_free=True,
        fitter=FITS + "_stabilized_output_error",
    ),
    Method(
        "eigen",
        "output error with eigenvalue transformation (unstable aircraft)",
        "eigen: eigenvalue transformation",
        start_free=True,
        fitter=FITS + "_eigenvalue_transformation",
    ),
    Method(
        "decouple",
        "output error with equation decoupling (unstable aircraft)",
        "decouple: equation decoupling",
        start_free=True,
        fitter=FITS + "_equation_decoupling",
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


@dataclass(frozen=True)
class FitKey:
    """Which fit a result is: its ``axis`` ("" when one axis or a user model is fitted)
    and its ``method`` (a catalogue name, or a variant such as "fem-nl"). As text
    (:meth:`__str__`, the results' and report.json's key) "lateral-oem" or "oem";
    :meth:`parse` reads it back - the one place that splits a key."""

    axis: str
    method: str

    def __str__(self) -> str:
        return f"{self.axis}-{self.method}" if self.axis else self.method

    @classmethod
    def parse(cls, key: str) -> FitKey:
        """The key written by :meth:`__str__`: "axis-method" where the first part is an
        axis (AXES) or any other group a caller chose ("long-oem") - not a method of the
        catalogue, whose variants carry a "-" of their own ("fem-nl", "ukf-aug")."""
        head, sep, rest = str(key).partition("-")
        if sep and rest and (head in AXES or head not in SPECS):
            return cls(head, rest)
        return cls("", str(key))

    @property
    def base(self) -> str:
        """The catalogue method it is a variant of ("fem" for "fem-nl")."""
        return self.method.split("-")[0]


#: the axes a built-in fit can be of (the first part of a result key)
AXES = ("longitudinal", "lateral", "sixdof")


def result_key(axis: str, method: str, several_axes: bool) -> str:
    """The key of a fit in the results and the report: the method's name, prefixed with the
    axis ("lateral-oem") when several axes are fitted (:class:`FitKey` as text)."""
    return str(FitKey(axis if several_axes else "", method))


#: colours of methods without one of their own, in turn (RGB)
PALETTE = [(140, 86, 75), (227, 119, 194), (127, 127, 127), (188, 189, 34), (23, 190, 207)]


def method_colour(key: str, order: Sequence[str] = ()) -> tuple[int, int, int]:
    """The colour (RGB 0-255) of a method or result key ("lateral-fem" is fem's), the
    figures' and the recordings' alike: the method's own, else the palette's by the key's
    place in ``order``."""
    spec = SPECS.get(FitKey.parse(key).base)
    if spec is not None and spec.colour is not None:
        return spec.colour
    return PALETTE[list(order).index(key) % len(PALETTE)] if key in order else PALETTE[0]


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
