"""Model, Parameter and Segment: the objects every estimator works on.

A model is a pair of vectorised Python functions (DESIGN.md section 4)::

    def f(x, u, p, c):   # state equations -> dx/dt, one entry per state
    def g(x, u, p, c):   # observation equations -> one entry per output

``x`` unpacks by rows into the states (each row an array over the trailing batch/time
dimensions), ``u`` into the inputs, ``p.NAME`` is a parameter value broadcasting against
the trailing dimensions, ``c.NAME`` a constant. Functions written with numpy ufuncs and
arithmetic are compiled with numba when possible (see :mod:`estimators.compile.kernels`); anything else
still runs through numpy.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from estimators.defaults import GAP_FACTOR
from estimators.errors import BoundsError, ModelDefinitionError, UnknownNameError

ModelFunction = Callable[[Any, Any, Any, Any], Any]


@dataclass
class Parameter:
    """One model parameter.

    Attributes
    ----------
    name : identifier used in the model functions (``p.name``) and in results.
    value : start value (or the fixed value when ``free=False``), in the model's units.
    free : estimated when True, held at ``value`` when False.
    bounds : (lower, upper); ``-inf``/``inf`` for none. A start outside raises BoundsError.
    per_segment : one value per data segment, reported as ``name[k]`` (biases, trim offsets).
    unit : free text for reports (derivatives are per radian, see DESIGN.md section 3).
    """

    name: str
    value: float
    free: bool = True
    bounds: tuple[float, float] = (-math.inf, math.inf)
    per_segment: bool = False
    unit: str = ""

    def __post_init__(self) -> None:
        if not self.name.isidentifier():
            raise ModelDefinitionError(
                f"parameter name {self.name!r} is not a Python identifier; model functions "
                "read it as p.<name>: rename it (letters, digits, underscores)"
            )
        self.value = float(self.value)
        lo, hi = (float(b) if b is not None else s * math.inf for b, s in zip(self.bounds, (-1, 1)))
        if lo > hi:
            raise ModelDefinitionError(
                f"parameter {self.name!r} has lower bound {lo} above upper bound {hi}: swap them"
            )
        self.bounds = (lo, hi)
        check_in_bounds(self.name, self.value, lo, hi)


def check_in_bounds(name: str, value: float, lo: float, hi: float) -> None:
    """Raise :class:`BoundsError` when ``value`` is not inside ``[lo, hi]`` or not finite."""
    if not np.isfinite(value):
        raise BoundsError(f"parameter {name!r} has a non-finite start value {value}: give a number")
    if not lo <= value <= hi:
        raise BoundsError(
            f"start value of parameter {name!r} = {value:g} lies outside its bounds "
            f"[{lo:g}, {hi:g}]: move the start inside the bounds or widen them"
        )


def check_outputs_measured(model: Model, segments: Sequence[Segment], method: str) -> None:
    """Raise ModelDefinitionError naming the outputs with no finite sample in any segment:
    a likelihood with a per-output noise variance cannot weigh an output never measured
    (the Kalman filters skip such outputs sample by sample and need no check)."""
    never = [o for j, o in enumerate(model.outputs) if not any(np.any(np.isfinite(seg.z[:, j])) for seg in segments)]
    if never:
        raise ModelDefinitionError(
            f"{method}: output{'s' if len(never) > 1 else ''} {never} "
            f"{'have' if len(never) > 1 else 'has'} no finite sample in any segment: drop "
            "{} from the model's outputs (g) or give the data".format("them" if len(never) > 1 else "it")
        )


class Namespace:
    """Attribute access to a mapping of arrays or floats (``p.CD0``, ``c.rho``); item
    access (``c["rho"]``) works too, on the numpy path."""

    __slots__ = ("__dict__",)

    def __init__(self, values: Mapping[str, Any]) -> None:
        self.__dict__.update(values)

    def __getitem__(self, name: str) -> Any:
        try:
            return self.__dict__[name]
        except KeyError:
            raise self._unknown(name) from None

    def __getattr__(self, name: str) -> Any:
        # only called for names not in __dict__: a misspelt p.<parameter> or c.<constant>
        if name.startswith("__"):
            raise AttributeError(name)
        raise self._unknown(name)

    def _unknown(self, name: str) -> UnknownNameError:
        return UnknownNameError(
            f"f or g uses {name!r}, which is not among the names here ({', '.join(self.__dict__)}): "
            "check its spelling, or add it to the model's parameters (p.<name>) or "
            "constants (c.<name>)"
        )

    def __repr__(self) -> str:
        return f"Namespace({', '.join(self.__dict__)})"


@dataclass
class Model:
    """A dynamic system x' = f(x, u, p, c), y = g(x, u, p, c).

    Parameters
    ----------
    states, inputs, outputs : names, in the order f's rows, u's rows and g's rows take.
    parameters : :class:`Parameter` list (order kept in results).
    constants : mass, inertia, geometry, density ... (floats), read as ``c.NAME``.
    f, g : the state and observation functions (vectorised, see module docstring).
    output_biases : outputs that get an additive per-segment bias parameter
        ``bias_<output>`` (start 0, free) without writing it into ``g``.
    name : label used in reports.
    """

    states: Sequence[str]
    inputs: Sequence[str]
    outputs: Sequence[str]
    parameters: Sequence[Parameter]
    f: ModelFunction
    g: ModelFunction
    constants: Mapping[str, float] = field(default_factory=dict)
    output_biases: Sequence[str] = ()
    name: str = "model"

    def __post_init__(self) -> None:
        self.states = list(self.states)
        self.inputs = list(self.inputs)
        self.outputs = list(self.outputs)
        self.parameters = [p if isinstance(p, Parameter) else Parameter(*p) for p in self.parameters]
        self.constants = dict(self.constants)
        self.output_biases = list(self.output_biases)
        for label, names in (("state", self.states), ("input", self.inputs), ("output", self.outputs)):
            if len(set(names)) != len(names):
                raise ModelDefinitionError(f"duplicate {label} names in {names}")
        unknown = [o for o in self.output_biases if o not in self.outputs]
        if unknown:
            raise ModelDefinitionError(f"output_biases {unknown} are not outputs of the model {self.outputs}")
        for o in self.output_biases:
            if f"bias_{o}" not in self.parameter_names:
                self.parameters.append(Parameter(f"bias_{o}", 0.0, per_segment=True))
        names = self.parameter_names
        dup = sorted({n for n in names if names.count(n) > 1})
        if dup:
            raise ModelDefinitionError(f"duplicate parameter names {dup}")
        clash = sorted(set(names) & set(self.constants))
        if clash:
            raise ModelDefinitionError(f"{clash} are both parameters and constants: keep one")

    # -- names -------------------------------------------------------------------------
    @property
    def parameter_names(self) -> list[str]:
        return [p.name for p in self.parameters]

    def parameter(self, name: str) -> Parameter:
        for p in self.parameters:
            if p.name == name:
                return p
        raise KeyError(f"model {self.name!r} has no parameter {name!r}; it has {self.parameter_names}")

    def with_values(self, values: Mapping[str, float] | Any, *, free: bool | None = None) -> Model:
        """A copy with parameter start values replaced from ``values`` (name -> value;
        a pandas Series from a result works). Per-segment names ``x[k]`` are ignored."""
        new = []
        for p in self.parameters:
            v = values[p.name] if p.name in values else p.value
            new.append(Parameter(p.name, float(v), p.free if free is None else free, p.bounds, p.per_segment, p.unit))
        return Model(
            self.states, self.inputs, self.outputs, new, self.f, self.g, self.constants, self.output_biases, self.name
        )

    def hold(self, values: Mapping[str, float]) -> Model:
        """A copy with the parameters named in ``values`` fixed at those values (name ->
        value; the others unchanged)."""
        unknown = sorted(set(values) - set(self.parameter_names))
        if unknown:
            raise ModelDefinitionError(f"model {self.name!r} has no parameter {unknown}")
        return self.with_values(values).fixed(values)

    def select_outputs(self, names: Sequence[str]) -> Model:
        """A copy observing only ``names`` (a subset of the outputs, any order): for data
        that lack a channel of the built-in model (e.g. no angular acceleration)."""
        missing = [n for n in names if n not in self.outputs]
        if missing:
            raise ModelDefinitionError(f"{missing} are not outputs of {self.name!r} ({self.outputs})")
        idx = [self.outputs.index(n) for n in names]
        g0 = self.g
        if hasattr(g0, "selects"):  # a selection of a selection
            g0, rows = g0.selects
            idx = [rows[i] for i in idx]

        def g(x, u, p, c):
            out = g0(x, u, p, c)
            return tuple(out[i] for i in idx)

        # the compiled filter loop (estimators.filters.kernels.output_kernel) calls g0 and picks these
        # rows itself: numba cannot build a tuple with a generator
        g.selects = (g0, tuple(idx))

        params = [
            p
            for p in self.parameters
            if not (p.name.startswith("bias_") and p.name[5:] in self.output_biases and p.name[5:] not in names)
        ]
        return Model(
            self.states,
            self.inputs,
            list(names),
            params,
            self.f,
            g,
            self.constants,
            [o for o in self.output_biases if o in names],
            self.name,
        )

    def fixed(self, names: Iterable[str]) -> Model:
        """A copy with the named parameters held at their values."""
        names = set(names)
        new = [
            Parameter(p.name, p.value, p.free and p.name not in names, p.bounds, p.per_segment, p.unit)
            for p in self.parameters
        ]
        return Model(
            self.states, self.inputs, self.outputs, new, self.f, self.g, self.constants, self.output_biases, self.name
        )

    # -- evaluation helpers ---------------------------------------------------------------
    def constants_for(self, segment: Segment | None = None) -> dict[str, float]:
        c = dict(self.constants)
        if segment is not None and segment.constants:
            c.update(segment.constants)
        return c

    def eval_g(self, X: np.ndarray, U: np.ndarray, P: np.ndarray, constants: Mapping[str, float]) -> np.ndarray:
        """Outputs for states X (n_states, N, B), inputs U (n_inputs, N, 1) and the
        parameter matrix P (n_params, B); returns (n_outputs, N, B)."""
        p = Namespace(dict(zip(self.parameter_names, P)))
        out = self.g(X, U, p, Namespace(constants))
        shape = X.shape[1:]
        Y = stack_rows(out, len(self.outputs), shape, "g", self.outputs)
        if self.output_biases:
            idx = {n: i for i, n in enumerate(self.parameter_names)}
            for o in self.output_biases:
                Y[self.outputs.index(o)] += P[idx[f"bias_{o}"]]
        return Y

    def eval_f(self, x: np.ndarray, u: np.ndarray, P: np.ndarray, constants: Mapping[str, float]) -> np.ndarray:
        """State derivatives for x (n_states, ...), u (n_inputs, ...), P (n_params, ...)."""
        p = Namespace(dict(zip(self.parameter_names, P)))
        out = self.f(x, u, p, Namespace(constants))
        return stack_rows(out, len(self.states), np.broadcast_shapes(x.shape[1:], P.shape[1:]), "f", self.states)


def stack_rows(out: Any, n: int, shape: tuple[int, ...], which: str, names: Sequence[str]) -> np.ndarray:
    rows = list(out) if isinstance(out, (tuple, list)) else list(np.asarray(out))
    if len(rows) != n:
        raise ModelDefinitionError(
            f"{which}() returned {len(rows)} rows but the model has {n} {names}: return one entry per name, in order"
        )
    Y = np.empty((n,) + tuple(shape))
    for i, r in enumerate(rows):
        Y[i] = r
    return Y


@dataclass
class Segment:
    """One stretch of flight data.

    Attributes
    ----------
    t : (N,) sample times in s, strictly increasing.
    u : (N, n_inputs) measured inputs, columns in the model's input order.
    z : (N, n_outputs) measured outputs, columns in the model's output order
        (NaN marks a missing sample; it gets zero weight).
    x0 : (n_states,) initial state; None takes states that are also outputs from their
        first measured (finite) sample.
    constants : per-segment overrides of the model constants (e.g. rho, mass).
    name : label used in results.
    """

    t: np.ndarray
    u: np.ndarray
    z: np.ndarray
    x0: np.ndarray | None = None
    constants: Mapping[str, float] | None = None
    name: str = ""

    def __post_init__(self) -> None:
        self.t = np.asarray(self.t, dtype=float).ravel()
        self.u = np.atleast_2d(np.asarray(self.u, dtype=float))
        self.z = np.atleast_2d(np.asarray(self.z, dtype=float))
        if self.u.shape[0] != self.t.size and self.u.shape[1] == self.t.size:
            self.u = self.u.T
        if self.z.shape[0] != self.t.size and self.z.shape[1] == self.t.size:
            self.z = self.z.T
        n = self.t.size
        where = f"segment {self.name!r}" if self.name else "segment"
        if n < 2:
            raise ModelDefinitionError(f"{where} has {n} samples; a fit needs at least 2")
        if self.u.shape[0] != n or self.z.shape[0] != n:
            raise ModelDefinitionError(
                f"{where}: t has {n} samples but u has {self.u.shape[0]} and z {self.z.shape[0]} rows"
            )
        dt = np.diff(self.t)
        if not np.all(np.isfinite(self.t)) or np.any(dt <= 0):
            k = int(np.argmax(~(dt > 0))) if np.any(~(dt > 0)) else 0
            raise ModelDefinitionError(
                f"{where}: time is not strictly increasing (at sample {k}, t={self.t[k]:.6g} s): "
                "sort the data and drop duplicate stamps"
            )
        if not np.all(np.isfinite(self.u)):
            k = int(np.argwhere(~np.isfinite(self.u))[0, 0])
            raise ModelDefinitionError(
                f"{where}: input has NaN/Inf at sample {k} (t={self.t[k]:.6g} s): interpolate or cut the segment there"
            )
        if self.x0 is not None:
            self.x0 = np.asarray(self.x0, dtype=float).ravel()

    @property
    def n(self) -> int:
        return self.t.size

    def _gap_index(self, factor: float = GAP_FACTOR) -> np.ndarray:
        """Indices i whose interval t[i] -> t[i+1] is a gap (see :data:`estimators.defaults.GAP_FACTOR`; :meth:`split_at_gaps` cuts a segment there)."""
        if not factor > 1.0:
            raise ModelDefinitionError(f"gap factor {factor!r} must exceed 1 (times the median interval)")
        dt = np.diff(self.t)
        return np.flatnonzero(dt > factor * float(np.median(dt)))

    def gaps(self, factor: float = GAP_FACTOR) -> list[tuple[float, float]]:
        """(start time, length) in s of each gap in ``t``: an interval longer than
        ``factor`` times the segment's median interval."""
        return [(float(self.t[i]), float(self.t[i + 1] - self.t[i])) for i in self._gap_index(factor)]

    def split_at_gaps(self, factor: float = GAP_FACTOR) -> list[Segment]:
        """The stretches between gaps (see :meth:`gaps`) as segments, in time order.

        Each piece keeps its rows of ``t``, ``u``, ``z``, the segment's ``constants`` and
        any other field, and is named ``<name>.<j>`` (``segment.<j>`` without a name). The
        first piece keeps ``x0``; the later ones get ``x0=None``: the state after a gap
        is unknown, so each starts from its first measured sample or, with
        ``estimate_x0="auto"`` (OutputError's default), is estimated; give ``piece.x0``
        for a model whose states are not all measured. A lone sample between two gaps
        is dropped (a segment needs two). Without a gap: ``[self]``.
        """
        idx = self._gap_index(factor)
        if not idx.size:
            return [self]
        bounds = np.concatenate([[0], idx + 1, [self.n]])
        base = self.name or "segment"
        consts = None if self.constants is None else dict(self.constants)
        pieces = []
        for j, (a, b) in enumerate(zip(bounds[:-1], bounds[1:])):
            if b - a < 2:
                continue
            pieces.append(
                replace(
                    self,
                    t=self.t[a:b].copy(),
                    u=self.u[a:b].copy(),
                    z=self.z[a:b].copy(),
                    x0=(None if self.x0 is None else self.x0.copy()) if a == 0 else None,
                    constants=None if consts is None else dict(consts),
                    name=f"{base}.{j}",
                )
            )
        return pieces

    def check_no_gaps(self, k: int | None = None, factor: float = GAP_FACTOR) -> None:
        """Raise ModelDefinitionError naming the first gap in ``t`` (its start time and
        length) and how many there are; ``k`` labels an unnamed segment by its index.
        Every estimator calls it (through :meth:`estimators.layout.Layout.build`)."""
        idx = self._gap_index(factor)
        if not idx.size:
            return
        i = int(idx[0])
        h = float(np.median(np.diff(self.t)))
        length = float(self.t[i + 1] - self.t[i])
        label = self.name or (str(k) if k is not None else "")
        where = f"segment {label!r}" if label else "segment"
        more = f" (and {idx.size - 1} more)" if idx.size > 1 else ""
        raise ModelDefinitionError(
            f"{where}: the time has a gap of {length:.4g} s from t={self.t[i]:.6g} s{more}, "
            f"{length / h:.0f} times the median sample interval {h:.4g} s (over {factor:g} "
            "times it counts as a gap): the model would be integrated across it in one step. "
            "Call Segment.split_at_gaps() and fit the pieces as a list of segments"
        )

    def check_against(self, model: Model) -> None:
        where = f"segment {self.name!r}" if self.name else "segment"
        if self.u.shape[1] != len(model.inputs):
            raise ModelDefinitionError(f"{where}: u has {self.u.shape[1]} columns, model inputs are {model.inputs}")
        if self.z.shape[1] != len(model.outputs):
            raise ModelDefinitionError(f"{where}: z has {self.z.shape[1]} columns, model outputs are {model.outputs}")
        if self.x0 is not None and self.x0.size != len(model.states):
            raise ModelDefinitionError(f"{where}: x0 has {self.x0.size} entries, model states are {model.states}")

    def initial_state(self, model: Model) -> np.ndarray:
        """x0 as given, or taken from the first measured (finite) sample of each state that
        is also an output."""
        if self.x0 is not None:
            return self.x0.copy()
        cols = {s: self.z[:, model.outputs.index(s)] for s in model.states if s in model.outputs}
        bad = [s for s in model.states if s not in cols or not np.any(np.isfinite(cols[s]))]
        if bad:
            raise ModelDefinitionError(
                f"segment {self.name!r} has no x0 and states {bad} are not measured "
                "(not outputs, or no finite sample): pass Segment(..., x0=...)"
            )
        return np.array([cols[s][np.isfinite(cols[s])][0] for s in model.states])

    @classmethod
    def from_frame(
        cls, df: Any, model: Model, *, x0: Mapping[str, float] | None = None, time: str | None = None, **kw
    ) -> Segment:
        """Build a segment from a DataFrame whose columns carry the model's input and
        output names (time in column ``time`` or the index)."""
        t = df[time].to_numpy() if time else df.index.to_numpy()
        missing = [c for c in list(model.inputs) + list(model.outputs) if c not in df.columns]
        if missing:
            raise ModelDefinitionError(f"data have no columns {missing} needed by the model")
        xv = None if x0 is None else np.array([x0[s] for s in model.states])
        return cls(t=t, u=df[model.inputs].to_numpy(), z=df[model.outputs].to_numpy(), x0=xv, **kw)
