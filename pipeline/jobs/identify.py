"""Every method on every axis a log excites (or on a user model), each fit validated:
:func:`identify`, the one fit loop of the jobs. What is fitted is a list of targets - the
built-in axes (:class:`_Axis`) or a user model (:class:`_UserModel`) - each giving the
problem a method is fitted on, with the validation flights' maneuvers as its held-out
segments when there are some."""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

from estimators import Model
from pipeline.conditioning.flow_angles import rebuilt
from pipeline.conditioning.input_sampling import step_times
from pipeline.errors import FsidError
from pipeline.ingest.constants import AircraftConstants
from pipeline.ingest.flightdata import FlightData
from pipeline.jobs.fit import fit_and_validate, held_refit
from pipeline.jobs.options import AXES, FitOptions
from pipeline.jobs.progress import Progress
from pipeline.jobs.validation_flights import (
    hold_out_count,
    validation_flights,
    validation_prefix,
    with_validation_flight,
)
from pipeline.methods.fitting import filters_process_noise
from pipeline.methods.noise import attach_logged_noise
from pipeline.problems import (
    LAT_OUTPUTS,
    LONG_OUTPUTS,
    Problem,
    lateral_problem,
    longitudinal_problem,
    multi_axis,
    multiaxis_problem,
    sixdof_lateral_problem,
    with_airspeed_offsets,
)
from pipeline.problems.user_model import user_model_problem
from pipeline.registry import SPECS, check_methods, result_key

#: axis -> (control inputs that excite it, its problem builder, its outputs)
BUILDERS = {
    "longitudinal": ({"de"}, longitudinal_problem, LONG_OUTPUTS),
    "lateral": ({"da", "dr"}, lateral_problem, LAT_OUTPUTS),
}


def identified_axes(fd: FlightData, axes: Sequence[str] = AXES) -> int:
    """How many of ``axes`` the log's maneuvers excite (elevator: longitudinal; aileron or
    rudder: lateral): the fits a job makes per method, for its progress count."""
    return planned_axes({sg.axis for sg in fd.segments}, axes)


def planned_axes(surfaces: set[str | None], axes: Sequence[str] = AXES) -> int:
    """How many of ``axes`` maneuvers moving ``surfaces`` (de, da, dr, ...) excite."""
    return sum(1 for name, (moved, _, _) in BUILDERS.items() if name in axes and surfaces & moved)


@dataclass(frozen=True)
class HeldFit:
    """A fit that held another fit's estimates fixed (the 6-DoF lateral output error
    holding the longitudinal derivatives): that fit's ``result``, and ``refit(values)``
    repeating the holding fit with the held values moved (the consider stage)."""

    result: Any
    refit: Callable[[Mapping[str, float]], Any]


@dataclass(frozen=True)
class Identified:
    """What :func:`identify` produced, by key: ``results`` and their ``validations``, the
    ``problems`` fitted (one per axis or user model), and ``held``: the fits that hold
    another axis' estimates (:class:`HeldFit`)."""

    results: dict[str, Any]
    validations: dict[str, dict]
    problems: list[Problem]
    held: dict[str, HeldFit] = field(default_factory=dict)


def identify(
    fd: FlightData,
    ac: AircraftConstants | None,
    methods: Sequence[str],
    truth: Mapping[str, float] | None,
    progress: Progress,
    *,
    axes: Sequence[str] = AXES,
    model: Model | None = None,
    options: FitOptions | None = None,
    starts: Mapping[str, Any] | None = None,
    validation: Any = None,
    fit_all: bool | None = None,
) -> Identified:
    """Estimate and validate every axis of ``axes`` the log excites with the built-in
    models, or the user ``model`` (an :class:`estimators.Model`, see
    :mod:`pipeline.problems.user_model`), with each method. Methods with a common grid get
    the problem on the grid of its slowest output channel. Returns the :class:`Identified`
    record; keys are the method names ("<axis>-<method>" once several axes are fitted).
    ``options``: how the fits are made and proved (default FitOptions()). ``starts`` (key
    -> parameter values or result): refit only, each fit starting there (see
    :func:`pipeline.jobs.fit.fit_and_validate`), no validation and no progress.

    validation: a second flight (FlightData), or several, for the proof of match: each
    model is fitted to every maneuver of ``fd`` and proved on every maneuver of each
    validation flight (built the same way; segments named by
    :func:`pipeline.jobs.validation_flights.validation_prefix`), instead of on the last
    maneuver of ``fd``. ``fit_all`` (default: with a validation flight): hold nothing out
    of ``fd`` - refits of a job with a validation flight pass it."""
    options = options or FitOptions()
    check_methods(methods, user_model=model is not None)
    vflights = validation_flights(validation)
    hold = hold_out_count(vflights, fit_all) if options.hold_out else 0
    if model is not None:
        targets = [_UserModel(fd, model, vflights, hold, starts is not None, options, progress)]
        failed = f"every estimation method failed on the model {model.name!r} (see the notes above)"
    else:
        targets = _axes(fd, ac, axes, vflights, hold, starts is not None, options, progress)
        failed = "every estimation method failed on this log (see the notes above)"
    results, validations, held = _fit_targets(fd, targets, methods, truth, progress, options, starts)
    if not results:
        raise FsidError(failed)
    return Identified(results, validations, [t.base for t in targets], held)


def _fit_targets(
    fd: FlightData,
    targets: Sequence[_Axis | _UserModel],
    methods: Sequence[str],
    truth: Mapping[str, float] | None,
    progress: Progress,
    options: FitOptions,
    starts: Mapping[str, Any] | None,
) -> tuple[dict, dict, dict[str, HeldFit]]:
    """Every method on every target, in that order: (results, validations, the fits that
    hold another axis' estimates) by key."""
    results, validations, held = {}, {}, {}
    filter_q: dict[str, Any] = {}  # axis -> the fit the EKF/UKF take their noise from
    several = len(targets) > 1
    for target in targets:
        for m in methods:
            spec = SPECS[m]
            lon = results.get(result_key("longitudinal", m, True)) if spec.lateral == "sixdof" else None
            pb = target.problem_for(m, lon)
            key = result_key(pb.axis, m, several)
            if spec.logged_noise:  # its R; the Kalman filters keep the grid's
                attach_logged_noise(fd, pb)
            source = results.get(result_key(pb.axis, spec.noise_from, several)) if spec.noise_from else None
            q, pb, noise = filters_process_noise(
                fd,
                pb,
                m,
                source,
                filter_q,
                progress,
                quiet=starts is not None,
                earlier=None if starts is None else starts.get(key),
            )
            done = fit_and_validate(
                pb,
                m,
                target.what(pb),
                truth,
                progress,
                options=options,
                start=None if starts is None else starts.get(key, {}),
                process_noise=q,
                calm_air=target.calm,
                held_alphadot=source.extra.get("alphadot_held") if source else None,
            )
            if done is None:
                continue
            results[key], validations[key] = done
            if noise is not None:
                results[key] = results[key].with_extra(filters_noise=noise)
            if starts is None and pb.model.name.startswith("sixdof") and lon is not None:
                # the longitudinal estimates this fit holds: their uncertainty is carried to
                # it after the fits (pipeline.jobs.consider_stage)
                held[key] = HeldFit(lon, held_refit(fd, target.ac, options, results[key], target.hold_out))
    return results, validations, held


@dataclass
class _Axis:
    """One axis of one flight for the built-in models: ``base``, its problem on the default
    grid (built by ``build``; ``outs`` its outputs), and the problem each method is fitted
    on (:meth:`method_problem`). ``multiaxis``: the flight moves all axes at once;
    ``turbulent``: it may be in turbulence (not known to be calm);
    ``say`` reports a model that could not be set up; ``hold_out``: maneuvers kept for the
    proof of match; ``vals``: (flight number, this axis on that validation flight);
    ``n_flights``: the validation flights; ``calm``: they are known to be in calm air."""

    fd: FlightData
    ac: AircraftConstants
    base: Problem
    build: Callable[..., Problem]
    outs: Sequence[str]
    say: Callable[[str], None]
    hold_out: int
    multiaxis: bool
    turbulent: bool
    options: FitOptions
    vals: list[tuple[int, _Axis]] = field(default_factory=list)
    n_flights: int = 0
    calm: bool = False
    cache: dict = field(default_factory=dict)

    def what(self, pb: Problem) -> str:
        return f"{pb.axis} axis"

    def problem_for(self, m: str, lon: Any) -> Problem:
        """The problem method ``m`` is fitted on (``lon``: the longitudinal fit of ``m``
        the lateral 6-DoF model holds, if any), proved on the validation flights' maneuvers
        when there are some (a model that cannot be set up there proves nothing there)."""
        pb = self.method_problem(m, lon)
        pb.step_times = step_times(self.fd.meta)  # the flight's: the cached problem's too
        if not self.n_flights:
            return pb
        vpbs, numbers = [], []
        for k, vax in self.vals:
            vpb = vax.method_problem(m, lon)
            if vpb.model.name == pb.model.name:
                vpb.step_times = step_times(vax.fd.meta)
                vpbs.append(vpb)
                numbers.append(k)
            else:
                vax.say(
                    f"{pb.model.name} model not set up there; it proves nothing for {m.upper()} on the {pb.axis} axis"
                )
        if not vpbs:
            return replace(pb, held_out=[], held_specs=[])
        return with_validation_flight(pb, vpbs, self.options.validation_calm, numbers, self.n_flights)

    def method_problem(self, m: str, lon: Any) -> Problem:
        """``base`` itself, or the same axis on the grid of its slowest output (common-grid
        methods; built once), or a richer model of the axis: all axes moving at once (or a
        filter in turbulence) -> each axis' model driven by the other axis' measured
        variables, the filters with the Dryden gust states (the aerodynamics see p - p_turb,
        q - q_turb whatever the maneuver); the lateral output error -> the nonlinear 6-DoF
        model with the longitudinal estimates held (the linear model's frozen airspeed and
        small-angle kinematics bias the estimates), or without them the lateral model driven
        by the measured V, alpha, theta, q (output error also with per-maneuver airspeed
        corrections under an a-priori penalty; equation error's validation simulates it)."""
        spec, base, fd = SPECS[m], self.base, self.fd
        slowest = min(fd[c].rate_hz for c in self.outs) if spec.common_grid else base.rate_hz
        rate = slowest if slowest < 0.9 * base.rate_hz else base.rate_hz
        pb = base
        if (
            (self.multiaxis or (self.turbulent and spec.common_grid))
            and not spec.regressions
            and (base.axis == "longitudinal" or spec.common_grid)
        ):
            pb = self._multiaxis_problem(spec, rate)
        elif spec.common_grid:
            pb = self._own(rate)
        elif pb.axis == "lateral" and spec.lateral == "sixdof" and lon is not None:
            try:
                pb = sixdof_lateral_problem(
                    fd,
                    self.ac,
                    longitudinal={n: float(v) for n, v in lon.params.items() if "[" not in n},
                    smooth_inputs=self.options.smooth_inputs,
                    hold_out=self.hold_out,
                )
            except FsidError as exc:
                self.say(f"6-DoF lateral model not set up ({exc}); linear model used")
        elif pb.axis == "lateral" and spec.lateral != "linear" and "q" in fd:
            try:
                pb = lateral_problem(
                    fd,
                    self.ac,
                    measured_longitudinal=True,
                    kinematic=True,
                    smooth_inputs=self.options.smooth_inputs,
                    hold_out=self.hold_out,
                )
                pb = with_airspeed_offsets(pb, fd) if spec.lateral == "sixdof" else pb
            except FsidError as exc:
                self.say(f"lateral model with measured longitudinal inputs not set up ({exc}); linear model used")
        pb.inputs = self.options.inputs
        return pb

    def _multiaxis_problem(self, spec: Any, rate: float) -> Problem:
        """The axis' multi-axis model (the gust model for common-grid methods). Filter
        error's gust models measure an angle rebuilt from the flight path as the rigid
        body's: its grid is that of the slowest other output, the rebuilt angles at their
        own samples. Falls back to the axis' own problem when it cannot be set up."""
        fd = self.fd
        try:
            return multiaxis_problem(
                fd,
                self.ac,
                self.base.axis,
                gust_states=spec.common_grid,
                rate_hz=(
                    min((fd[c].rate_hz for c in self.outs if not rebuilt(fd, c)), default=rate)
                    if spec.own_samples_grid
                    else rate
                ),
                smooth_inputs=self.options.smooth_inputs,
                hold_out=self.hold_out,
            )
        except FsidError as exc:
            pb = self._own(rate)
            self.say(f"multi-axis {pb.axis} model not set up ({exc}); {pb.model.name} model used")
            return pb

    def _own(self, rate: float) -> Problem:
        """The axis' own problem on the grid of ``rate`` (the common grid built once)."""
        if rate == self.base.rate_hz:
            return self.base
        if "common" not in self.cache:
            self.cache["common"] = self.build(
                self.fd, self.ac, rate_hz=rate, smooth_inputs=self.options.smooth_inputs, hold_out=self.hold_out
            )
            self.cache["common"].inputs = self.options.inputs
        return self.cache["common"]


def _axes(
    fd: FlightData,
    ac: AircraftConstants,
    axes: Sequence[str],
    vflights: list[FlightData],
    hold: int,
    refit: bool,
    options: FitOptions,
    progress: Progress,
) -> list[_Axis]:
    """The axes of ``axes`` the log excites, each with its problem on every validation
    flight; an axis that cannot be set up is left out with a note (FsidError when none
    can)."""

    def note(msg: str) -> None:
        print(f"note: {msg}", file=progress.stream)

    def val_note(k: int) -> Callable[[str], None]:
        return lambda msg: note(f"{validation_prefix(k, len(vflights))}{msg}")

    flown = {s.axis for s in fd.segments}
    built, skipped = [], []
    for axis, (surfaces, build, outs) in BUILDERS.items():
        if axis not in axes or not flown & surfaces:
            continue
        try:
            problem = build(fd, ac, smooth_inputs=options.smooth_inputs, hold_out=hold)
        except FsidError as exc:  # e.g. one maneuver only: say so, fit the other axis
            skipped.append(str(exc))
            continue
        vbases = []  # (flight number, its problem of this axis)
        for k, vfd in enumerate(vflights):
            try:
                vb = build(vfd, ac, smooth_inputs=options.smooth_inputs, hold_out=0)
                vb.inputs = options.inputs
                vbases.append((k, vfd, vb))
            except FsidError as exc:
                val_note(k)(f"the {problem.axis} axis cannot be set up there ({exc}); it proves nothing on that axis")
        problem.inputs = options.inputs
        built.append((problem, build, outs, vbases))
    if not built:
        raise FsidError(
            "no axis can be identified from this log: "
            + (
                "; ".join(skipped)
                or "no control-input activity found (fly doublets/3-2-1-1s on the elevator, aileron or rudder, or give segments)"
            )
        )
    for msg in skipped:
        note(msg)
    multiaxis = multi_axis(fd)
    common = dict(multiaxis=multiaxis, turbulent=not options.calm, options=options)
    return [
        _Axis(
            fd,
            ac,
            problem,
            build,
            outs,
            note,
            hold,
            vals=[(k, _Axis(vfd, ac, vb, build, outs, val_note(k), 0, **common)) for k, vfd, vb in vbases],
            n_flights=0 if refit else len(vflights),
            calm=options.validation_calm and bool(vbases),
            **common,
        )
        for problem, build, outs, vbases in built
    ]


class _UserModel:
    """A user model on one flight: its problem (on the common grid for the methods that
    need one, built once), proved on the validation flights' maneuvers when there are
    some."""

    calm = False

    def __init__(
        self,
        fd: FlightData,
        model: Model,
        vflights: list[FlightData],
        hold: int,
        refit: bool,
        options: FitOptions,
        progress: Progress,
    ) -> None:
        self.fd, self.model, self.vflights, self.hold_out = fd, model, vflights, hold
        self.refit, self.options, self.ac = refit, options, None
        self.base = self._proved(user_model_problem(fd, model, smooth_inputs=options.smooth_inputs, hold_out=hold))
        self.base.inputs = options.inputs
        for n in self.base.notes:
            if not progress.quiet:
                print(f"note: {n}", file=progress.stream)
        self.common: Problem | None = None

    def what(self, pb: Problem) -> str:
        return f"user model {self.model.name!r}"

    def _proved(self, pb: Problem) -> Problem:
        """``pb`` with the validation flights' maneuvers (on its grid) held out."""
        if not self.vflights or self.refit:
            return pb
        vals = []
        for k, vfd in enumerate(self.vflights):
            try:
                vals.append(
                    user_model_problem(
                        vfd, self.model, smooth_inputs=self.options.smooth_inputs, hold_out=0, rate_hz=pb.rate_hz
                    )
                )
            except FsidError as exc:
                raise FsidError(f"{validation_prefix(k, len(self.vflights))}{exc}") from None
        return with_validation_flight(pb, vals, calm=False)

    def problem_for(self, m: str, lon: Any) -> Problem:
        """The problem method ``m`` is fitted on."""
        if not SPECS[m].common_grid:
            return self.base
        rate = min(self.fd[c].rate_hz for c in self.model.outputs)
        if rate >= 0.9 * self.base.rate_hz:
            return self.base
        if self.common is None:
            self.common = self._proved(
                user_model_problem(
                    self.fd, self.model, rate_hz=rate, smooth_inputs=self.options.smooth_inputs, hold_out=self.hold_out
                )
            )
            self.common.inputs = self.options.inputs
        return self.common
