"""Right-hand-side kernels for the integrators, compiled with numba when the model allows.

Time marching is a loop over samples that numpy cannot vectorise; in plain Python the
per-step overhead of a model function (tens of small array operations) dominates an
output-error fit. numba compiles the user's ``f`` together with the integrator loop, so
a batch of perturbed parameter sets integrates without Python overhead per sample.

How: ``f`` is compiled as written. A generated adapter loops over the batch columns and
calls ``f`` on scalars: the states of one column as a tuple of floats (so ``V, alpha,
theta, q = x`` works), the inputs as a tuple of floats, the parameters of that column as a
namedtuple (so ``p.CD0`` works); constants are a namedtuple of floats. Compiled for
scalars, ``f`` has no array temporaries, and numba compiles it (and the integrator loops,
written as element loops too: :mod:`estimators.integrators`) much faster than
array expressions; a fresh installation's first fit waits for that compile. An ``f``
that needs whole rows (e.g. reads ``V.shape``) gets the adapter that passes them. The
compiled kernel is checked once against the numpy evaluation; when ``f`` does not
compile either way (e.g. it uses Python objects numba does not know) or disagrees, the
numpy path is used and a warning says so. ``FSID_JIT=0`` switches compilation off. numba
itself is imported on the first compile (:mod:`estimators.compile.numba_jit`). The
generated modules are kept on disk between runs (:mod:`estimators.compile.cache`).

Why source text (``inspect.getsource`` here, ``exec`` or an import in the cache): numba
caches a compiled function on disk only when it holds no Python object, and a loop that
takes the model's ``f`` as an argument holds it as one; a closure over ``f`` is compiled
anew in every process. Written as a module whose globals are the model's compiled
functions, the integrator loop calls them directly, and numba's own cache keeps the
compiled module between runs (keyed by the file :mod:`estimators.compile.cache` names by a
hash of everything it depends on). :func:`bound_source` takes the package's loops from
their source, so each loop is written once, in :mod:`estimators.integrators`.
"""

from __future__ import annotations

import inspect
import os
import re
import textwrap
import types
import warnings
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np

from estimators import integrators as _integ
from estimators.compile.cache import failed_before, load_kernels, mark_failed
from estimators.compile.numba_jit import (
    HAVE_NUMBA,
    calls_unknown_helpers,
    compile_user_function,
    first_line,
    load_numba,
)
from estimators.defaults import ATOL, JIT_CHECK_ATOL, JIT_CHECK_RTOL, RTOL
from estimators.errors import ModelDefinitionError
from estimators.model import Model, Namespace, stack_rows

_KERNELS: dict[tuple, RhsKernel] = {}


def _tuple_source(items: Sequence[str]) -> str:
    """``(a, b, )``: a tuple display of the given expressions (one element included)."""
    return "(" + "".join(f"{s}, " for s in items) + ")"


def adapter_source(
    name: str,
    call: str,
    n_states: int,
    n_inputs: int,
    n_params: int,
    rows: Sequence[int],
    extra: Sequence[str] = (),
    scalar: bool = False,
) -> list[str]:
    """Lines of a compiled adapter ``name(x2d, u1d, P, c, out)`` in the integrators'
    calling convention: the state rows unpacked into a tuple, the inputs into a tuple of
    floats, the parameter rows into the module's ``Params`` namedtuple, ``call(x, u, p, c)``
    and row ``rows[j]`` of its result into ``out[j]``; ``extra`` lines after that.
    ``scalar``: a loop over the batch columns instead, ``call`` on the floats of one column
    (states, parameters) at a time, which numba compiles several times faster than the
    same arithmetic on rows (no array expressions) and runs without temporaries."""
    if not scalar:
        return [
            "@numba.njit(error_model='numpy', cache=CACHE)",
            f"def {name}(x2d, u1d, P, c, out):",
            f"    x = {_tuple_source([f'x2d[{i}]' for i in range(n_states)])}",
            f"    u = {_tuple_source([f'u1d[{i}]' for i in range(n_inputs)])}",
            f"    p = Params({', '.join(f'P[{i}]' for i in range(n_params))})",
            f"    r = {call}(x, u, p, c)",
            *[f"    out[{j}, :] = r[{r}]" for j, r in enumerate(rows)],
            *extra,
        ]
    return [
        "@numba.njit(error_model='numpy', cache=CACHE)",
        f"def {name}(x2d, u1d, P, c, out):",
        f"    u = {_tuple_source([f'u1d[{i}]' for i in range(n_inputs)])}",
        "    for b in range(x2d.shape[1]):",
        f"        x = {_tuple_source([f'x2d[{i}, b]' for i in range(n_states)])}",
        f"        p = Params({', '.join(f'P[{i}, b]' for i in range(n_params))})",
        f"        r = {call}(x, u, p, c)",
        *[f"        out[{j}, b] = r[{r}]" for j, r in enumerate(rows)],
        *extra,
    ]


def probe_point(model: Model) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A made-up point at which a compiled kernel is checked against the numpy
    evaluation: states x (n, 2) 1 + 0.1 N(0, 1), inputs u (n_in,) 0.1 N(0, 1), the
    parameter matrix P (n_p, 2) at the model's values."""
    rng = np.random.default_rng(0)
    x = rng.standard_normal((len(model.states), 2)) * 0.1 + 1.0
    u = rng.standard_normal(len(model.inputs)) * 0.1
    P = np.repeat(np.array([[p.value] for p in model.parameters], dtype=float), 2, axis=1)
    return x, u, P


def _spaced(text: str) -> str:
    """A regular expression for ``text`` that also matches it as a formatter may lay it
    out: any whitespace, line breaks included, after an opening bracket or a comma."""
    pattern = re.escape(text.strip())
    return re.sub(r"(\\\(|,)(\\ )*", lambda m: m.group(1) + r"\s*", pattern) + (r"\s*" if text.endswith(" ") else "")


def bound_source(fn: Callable, drop: str, replace: Mapping[str, str] | None = None) -> str:
    """The source of one of the package's loop functions with the callable arguments named
    in ``drop`` (e.g. ``"rhs, "``) taken out of its signature and calls, and the other
    ``replace`` substitutions made, for a generated kernel module where those callables
    are module globals. Passed as arguments, numba holds them as Python object pointers,
    and a function holding one cannot be cached; called as globals they can."""
    src = textwrap.dedent(inspect.getsource(fn))
    for a, b in ((drop, ""), *(replace or {}).items()):
        src = re.sub(_spaced(a), lambda _m, b=b: b, src) if a else src
    names = {d.strip(" ,") for d in drop.split(",") if d.strip()}
    code = compile(src, "<bound>", "exec").co_consts
    fcode = next(c for c in code if isinstance(c, types.CodeType))
    left = names & set(fcode.co_varnames)
    if left:  # the package's loop was edited in a way this substitution misses
        raise RuntimeError(f"{fn.__name__}: {sorted(left)} still passed as arguments")
    return src


_LOOPS: dict[str, Any] = {}


def loop_helpers() -> dict[str, Any]:
    """The integrators' array helpers as numba functions of their element loops
    (:data:`estimators.integrators.LOOP_HELPERS`), made once per process and shared by every
    kernel module (compiled when a module's loop first needs them; a loop loaded from the
    disk cache carries its own copy)."""
    if not _LOOPS:
        nb = load_numba()
        _LOOPS.update(
            {name: nb.njit(error_model="numpy", inline="always")(fn) for name, fn in _integ.LOOP_HELPERS.items()}
        )
    return _LOOPS


def _scheme_source() -> str:
    """The integrators of a kernel module: every scheme of :mod:`estimators.integrators`
    with ``rhs`` the module's global, compiled (and cached) as ``integrate_<scheme>(x0, U,
    t, P, c, rtol, atol, mode)``; the module's globals must hold the array helpers' loops
    (``_LOOPS``, :func:`loop_helpers`)."""
    parts = [
        "globals().update(_LOOPS)",
        bound_source(_integ._explicit_rk, "rhs, "),
        "_explicit_rk = numba.njit(error_model='numpy', inline='always')(_explicit_rk)",
    ]
    for s in _integ.INTEGRATORS:
        parts += [
            bound_source(_integ.PY_SCHEMES[s], "rhs, "),
            f"integrate_{s} = numba.njit(error_model='numpy', cache=CACHE)({s})",
        ]
    return "\n".join(parts)


class _FailedBefore(RuntimeError):
    """A kernel module marked failed by an earlier run (:func:`failed_before`)."""


class _Disagrees(ValueError):
    """A compiled kernel that disagrees with the numpy evaluation."""


class RhsKernel:
    """The model's state equations in the form the integrators call.

    ``integrate(scheme, x0 (n, B), U (N, n_in), t (N,), P (n_p, B), constants, inputs=...)``
    returns X (N, n, B); ``inputs`` is "linear" or "hold" (integrators.INPUT_MODES).
    ``module`` holds the compiled ``rhs`` and ``integrate_<scheme>`` once compiled.
    """

    def __init__(self, model: Model) -> None:
        self.model = model
        self.n = len(model.states)
        self.names = model.parameter_names
        self.const_names = tuple(sorted(model.constants))
        f = model.f
        names = self.names
        n = self.n

        states = model.states

        def rhs_py(x2d, u1d, P, c, out):
            r = f(x2d, u1d, Namespace(dict(zip(names, P))), c)
            out[:] = stack_rows(r, n, out.shape[1:], "f", states)

        self.rhs_py = rhs_py
        self.module = None
        self._jit_state = "untried" if (HAVE_NUMBA and os.environ.get("FSID_JIT", "1") != "0") else "off"

    # -- compiled path -------------------------------------------------------------------
    def source(self, helpers: bool, scalar: bool = True) -> str:
        """The kernel module's source: the rhs adapter (``scalar``: f called per batch
        column on floats, see :func:`adapter_source`) and the integrator entry points."""
        m = self.model
        return "\n".join(
            [
                f"# fsid compiled kernels of model {m.name!r} (generated by estimators.compile.kernels; safe to delete)",
                f"# f: {getattr(m.f, '__module__', '?')}.{getattr(m.f, '__qualname__', '?')}, "
                f"helpers compiled: {helpers}, f on {'scalars' if scalar else 'rows'}",
                "from collections import namedtuple",
                "import numba",
                "from estimators import integrators as _I",
                "globals().update({k: v for k, v in vars(_I).items() if not k.startswith('__')})",
                f"Params = namedtuple('Params', {list(self.names)!r})",
                f"Constants = namedtuple('Constants', {list(self.const_names)!r})",
                *adapter_source("rhs", "_f", self.n, len(m.inputs), len(self.names), range(self.n), scalar=scalar),
                _scheme_source(),
                "",
            ]
        )

    def _build_jit(self, helpers: bool = False, scalar: bool = True) -> None:
        # f and its helpers inlined into the scalar adapter (one compile instead of one
        # each); the rows adapter, the fallback for what the scalar one cannot take, keeps
        # them as functions of their own
        m = self.model
        nb = load_numba()
        fj = (
            compile_user_function(m.f, inline=scalar)
            if helpers
            else nb.njit(error_model="numpy", inline="always" if scalar else "never")(m.f)
        )
        self.module = load_kernels(
            self.source(helpers, scalar), {"_f": fj, "_LOOPS": loop_helpers()}, [m.f], "fsid_rhs"
        )

    def _c_jit(self, constants: Mapping[str, float]):
        if not self.const_names:
            return ()
        return self.module.Constants(*[float(constants[k]) for k in self.const_names])

    def _try_jit(self, x0: np.ndarray, U: np.ndarray, P: np.ndarray, constants: Mapping[str, float]) -> None:
        """Compile and check the kernel once against the numpy evaluation: f on scalars,
        else on rows (:func:`adapter_source`); each as written (helpers decorated for numba,
        as in :mod:`estimators.models`, are inlined) and with the plain helper functions it
        calls compiled too (:func:`compile_user_function`), the latter first when f calls
        such helpers (:func:`calls_unknown_helpers`). A way that failed in an earlier run
        (:func:`failed_before`) is not tried again; one that fails now is marked."""
        exc: Exception | None = None
        f = self.model.f
        glb = getattr(f, "__globals__", {})
        if not any(
            isinstance(glb.get(n), types.FunctionType) and glb[n] is not f
            for n in getattr(getattr(f, "__code__", None), "co_names", ())
        ):
            order = (False,)  # no helpers: compiling them too is the same
        elif calls_unknown_helpers(f):
            order = (True, False)
        else:
            order = (False, True)
        for scalar, helpers in [(s, h) for s in (True, False) for h in order]:
            self.module = None
            try:
                self._build_jit(helpers, scalar)
                why = failed_before(self.module)
                if why is not None:
                    raise _FailedBefore(why)
                c = self._c_jit(constants)
                u = np.ascontiguousarray(U[0], dtype=float)
                a = np.empty_like(x0)
                self.module.rhs(np.ascontiguousarray(x0), u, np.ascontiguousarray(P), c, a)
                b = np.empty_like(x0)
                self.rhs_py(x0, u, P, Namespace(constants), b)
                if not np.allclose(a, b, rtol=JIT_CHECK_RTOL, atol=JIT_CHECK_ATOL, equal_nan=True):
                    raise _Disagrees("compiled and numpy state derivatives differ")
                self._jit_state = "on"
                return
            except Exception as e:  # any failure -> next way, then the numpy path, said once
                exc = e
                # numba's refusal and a disagreement are the code's: the same next run
                if self.module is not None and (isinstance(e, _Disagrees) or type(e).__module__.startswith("numba")):
                    mark_failed(self.module, first_line(e))
        self.module = None
        self._jit_state = "failed"
        warnings.warn(
            f"model {self.model.name!r}: f could not be compiled with numba ({first_line(exc)}); "
            "integrating with numpy, which is slower. Write f with numpy functions and "
            "arithmetic on the unpacked rows to get the compiled path.",
            RuntimeWarning,
            stacklevel=4,
        )

    @property
    def compiled(self) -> bool:
        return self._jit_state == "on"

    def prepare(self) -> bool:
        """Compile (or load) the kernel now if that was not tried yet, checked at
        :func:`probe_point`; True when the compiled path is on."""
        if self._jit_state == "untried":
            x0, u, P = probe_point(self.model)
            self._try_jit(x0, u[None, :], P, self.model.constants)
        return self.compiled

    def integrate(
        self,
        scheme: str,
        x0: np.ndarray,
        U: np.ndarray,
        t: np.ndarray,
        P: np.ndarray,
        constants: Mapping[str, float],
        *,
        rtol: float = RTOL,
        atol: float = ATOL,
        inputs: str = _integ.DEFAULT_INPUTS,
    ) -> np.ndarray:
        if scheme not in _integ.PY_SCHEMES:
            raise ModelDefinitionError(f"unknown integrator {scheme!r}: choose one of {', '.join(_integ.INTEGRATORS)}")
        if inputs not in _integ.INPUT_MODES:
            raise ModelDefinitionError(
                f"unknown input interpolation {inputs!r}: choose one of {', '.join(_integ.INPUT_MODES)}"
            )
        mode = _integ.INPUT_MODES[inputs]
        x0 = np.ascontiguousarray(x0, dtype=float)
        U = np.ascontiguousarray(U, dtype=float)
        if U.ndim == 1:
            U = U[:, None]
        t = np.ascontiguousarray(t, dtype=float)
        P = np.ascontiguousarray(P, dtype=float)
        if self._jit_state == "untried":
            self._try_jit(x0, U, P, constants)
        if self._jit_state == "on":
            return getattr(self.module, f"integrate_{scheme}")(
                x0, U, t, P, self._c_jit(constants), float(rtol), float(atol), mode
            )
        with np.errstate(all="ignore"):
            return _integ.PY_SCHEMES[scheme](self.rhs_py, x0, U, t, P, Namespace(constants), rtol, atol, mode)


def kernel_for(model: Model) -> RhsKernel:
    """The (cached) kernel of a model. Models sharing f, names and constant names share
    one compiled kernel, so building a new Model object does not recompile."""
    key = (
        model.f,
        tuple(model.states),
        tuple(model.inputs),
        tuple(model.parameter_names),
        tuple(sorted(model.constants)),
    )
    k = _KERNELS.get(key)
    if k is None:
        k = _KERNELS[key] = RhsKernel(model)
    return k
