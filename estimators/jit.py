"""Right-hand-side kernels for the integrators, compiled with numba when the model allows.

Time marching is a loop over samples that numpy cannot vectorise; in plain Python the
per-step overhead of a model function (~40 small array operations) dominates an output-
error fit. numba compiles the user's ``f`` together with the integrator loop, so a fit of
600 samples x 12 perturbed parameter sets integrates in milliseconds.

How: ``f`` is compiled as written. A generated adapter packs the state rows into a tuple
(so ``V, alpha, theta, q = x`` works), the inputs into a tuple of floats, and the
parameter rows into a namedtuple (so ``p.CD0`` works); constants become a namedtuple of
floats. The compiled kernel is checked once against the numpy evaluation; when ``f``
does not compile (e.g. it uses Python objects numba does not know) or disagrees, the
numpy path is used and a warning says so. ``FSID_JIT=0`` switches compilation off.
"""
from __future__ import annotations

import os
import types
import warnings
from collections import namedtuple
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from estimators import integrators as _integ
from estimators.errors import ModelDefinitionError
from estimators.model import Model, Namespace, stack_rows

try:
    import numba
except ImportError:  # pragma: no cover
    numba = None

_JIT_SCHEMES: dict[str, Callable] = {}
_KERNELS: dict[tuple, "RhsKernel"] = {}


def _jit_scheme(name: str) -> Callable:
    if name not in _JIT_SCHEMES:
        _JIT_SCHEMES[name] = numba.njit(error_model="numpy", cache=False)(_integ.PY_SCHEMES[name])
    return _JIT_SCHEMES[name]


def compile_user_function(fn: Callable, _done: dict | None = None) -> Callable:
    """``fn`` compiled with numba, together with the plain Python functions it calls by a
    global name (a helper such as ``coefs(x, u, p, c)`` shared by f and g, recursively):
    each is recompiled in a copy of its globals where those names are compiled too, so
    numba's nopython mode can call them. The user's function objects are not changed."""
    done = {} if _done is None else _done
    if fn in done:
        return done[fn]
    if not isinstance(fn, types.FunctionType):          # already compiled, or a builtin
        return fn
    done[fn] = None                                    # recursion guard
    key, glb = fn, fn.__globals__
    helpers = {name: glb[name] for name in fn.__code__.co_names
               if isinstance(glb.get(name), types.FunctionType) and glb[name] is not fn}
    if helpers:
        env = dict(glb)
        for name, h in helpers.items():
            env[name] = compile_user_function(h, done) or h
        fn = types.FunctionType(fn.__code__, env, fn.__name__, fn.__defaults__, fn.__closure__)
    done[key] = out = numba.njit(error_model="numpy")(fn)
    return out


def _tuple_src(items: Sequence[str]) -> str:
    return "(" + "".join(f"{s}, " for s in items) + ")"


class RhsKernel:
    """The model's state equations in the form the integrators call.

    ``integrate(scheme, x0 (n, B), U (N, n_in), t (N,), P (n_p, B), constants, inputs=...)``
    returns X (N, n, B); ``inputs`` is "average", "linear" or "hold" (integrators.INPUT_MODES).
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
        self.rhs_jit = None
        self._jit_state = "untried" if (numba is not None and os.environ.get("FSID_JIT", "1") != "0") \
            else "off"
        self._ConstT = None

    # -- compiled path -------------------------------------------------------------------
    def _build_jit(self, helpers: bool = False) -> None:
        m = self.model
        PT = namedtuple("Params", self.names)
        fj = compile_user_function(m.f) if helpers else numba.njit(error_model="numpy")(m.f)
        src = "\n".join([
            "def rhs(x2d, u1d, P, c, out):",
            f"    x = {_tuple_src([f'x2d[{i}]' for i in range(self.n)])}",
            f"    u = {_tuple_src([f'u1d[{i}]' for i in range(len(m.inputs))])}",
            f"    p = _PT({', '.join(f'P[{i}]' for i in range(len(self.names)))})",
            "    r = _f(x, u, p, c)",
            *[f"    out[{i}, :] = r[{i}]" for i in range(self.n)],
        ])
        ns: dict[str, Any] = {"_PT": PT, "_f": fj}
        exec(compile(src, f"<fsid rhs adapter for {m.name}>", "exec"), ns)
        self.rhs_jit = numba.njit(error_model="numpy")(ns["rhs"])
        if self.const_names:
            self._ConstT = namedtuple("Constants", self.const_names)

    def _c_jit(self, constants: Mapping[str, float]):
        if self._ConstT is None:
            return ()
        return self._ConstT(*[float(constants[k]) for k in self.const_names])

    def _try_jit(self, x0: np.ndarray, U: np.ndarray, P: np.ndarray,
                 constants: Mapping[str, float]) -> None:
        """Compile and check the kernel once against the numpy evaluation: f as written
        (helpers decorated for numba, as in :mod:`estimators.models`, are inlined), else with
        the plain helper functions it calls compiled too (:func:`compile_user_function`)."""
        exc: Exception | None = None
        for helpers in (False, True):
            try:
                self._build_jit(helpers)
                c = self._c_jit(constants)
                u = np.ascontiguousarray(U[0], dtype=float)
                a = np.empty_like(x0)
                self.rhs_jit(np.ascontiguousarray(x0), u, np.ascontiguousarray(P), c, a)
                b = np.empty_like(x0)
                self.rhs_py(x0, u, P, Namespace(constants), b)
                if not np.allclose(a, b, rtol=1e-9, atol=1e-12, equal_nan=True):
                    raise ValueError("compiled and numpy state derivatives differ")
                self._jit_state = "on"
                return
            except Exception as e:  # any failure -> next way, then the numpy path, said once
                exc = e
        self.rhs_jit = None
        self._jit_state = "failed"
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        warnings.warn(
            f"model {self.model.name!r}: f could not be compiled with numba ({first}); "
            "integrating with numpy, which is slower. Write f with numpy functions and "
            "arithmetic on the unpacked rows to get the compiled path.",
            RuntimeWarning, stacklevel=4)

    @property
    def compiled(self) -> bool:
        return self._jit_state == "on"

    def integrate(self, scheme: str, x0: np.ndarray, U: np.ndarray, t: np.ndarray,
                  P: np.ndarray, constants: Mapping[str, float], *,
                  rtol: float = 1e-8, atol: float = 1e-10, inputs: str = "average") -> np.ndarray:
        if scheme not in _integ.PY_SCHEMES:
            raise ModelDefinitionError(
                f"unknown integrator {scheme!r}: choose one of {', '.join(_integ.INTEGRATORS)}")
        if inputs not in _integ.INPUT_MODES:
            raise ModelDefinitionError(
                f"unknown input interpolation {inputs!r}: choose one of {', '.join(_integ.INPUT_MODES)}")
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
            return _jit_scheme(scheme)(self.rhs_jit, x0, U, t, P, self._c_jit(constants),
                                       float(rtol), float(atol), mode)
        with np.errstate(all="ignore"):
            return _integ.PY_SCHEMES[scheme](self.rhs_py, x0, U, t, P, Namespace(constants),
                                             rtol, atol, mode)


def kernel_for(model: Model) -> RhsKernel:
    """The (cached) kernel of a model. Models sharing f, names and constant names share
    one compiled kernel, so building a new Model object does not recompile."""
    key = (model.f, tuple(model.states), tuple(model.inputs), tuple(model.parameter_names),
           tuple(sorted(model.constants)))
    k = _KERNELS.get(key)
    if k is None:
        k = _KERNELS[key] = RhsKernel(model)
    return k
