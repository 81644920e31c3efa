"""numba on demand: its import on the first compile, and the user's model functions compiled with it.

numba is imported by :func:`load_numba` when something is first compiled, not with the
package: a process that never compiles does not pay for its import. ``FSID_JIT=0``
switches compilation off (:class:`estimators.compile.kernels.RhsKernel` reads it).
"""

from __future__ import annotations

import atexit
import gc
import importlib.util
import types
from collections.abc import Callable

#: numba, imported by :func:`load_numba` on the first compile (a process that never
#: compiles does not import it); None until then and when it is not installed
numba = None
HAVE_NUMBA = importlib.util.find_spec("numba") is not None


def load_numba():
    """The numba module (imported now if it was not yet), or None when not installed."""
    global numba
    if numba is None and HAVE_NUMBA:
        import numba as nb

        numba = nb
        # numba's start leaves a great many objects that the interpreter's last garbage
        # collection at exit would walk through for nothing: frozen at exit, they are left
        # to the process's end (benchmarks/first_fit.py measures the cost)
        atexit.register(gc.freeze)
    return numba


def compile_user_function(fn: Callable, _done: dict | None = None, inline: bool = False) -> Callable:
    """``fn`` compiled with numba, together with the plain Python functions it calls by a
    global name (a helper such as ``coefs(x, u, p, c)`` shared by f and g, recursively):
    each is recompiled in a copy of its globals where those names are compiled too, so
    numba's nopython mode can call them. The user's function objects are not changed.
    ``inline``: numba inlines each into its caller (``inline="always"``) instead of
    compiling it as a function of its own, which saves a compilation per function."""
    done = {} if _done is None else _done
    if fn in done:
        return done[fn]
    if not isinstance(fn, types.FunctionType):  # already compiled, or a builtin
        return fn
    done[fn] = None  # recursion guard
    load_numba()
    key, glb = fn, fn.__globals__
    helpers = {
        name: glb[name]
        for name in fn.__code__.co_names
        if isinstance(glb.get(name), types.FunctionType) and glb[name] is not fn
    }
    if helpers:
        env = dict(glb)
        for name, h in helpers.items():
            env[name] = compile_user_function(h, done, inline) or h
        fn = types.FunctionType(fn.__code__, env, fn.__name__, fn.__defaults__, fn.__closure__)
    done[key] = out = numba.njit(error_model="numpy", inline="always" if inline else "never")(fn)
    return out


def calls_unknown_helpers(fn: Callable) -> bool:
    """True when ``fn`` calls by a global name a plain Python function numba does not know
    (not compiled, not registered with ``register_jitable``): compiled as written it fails
    to type, so :class:`estimators.compile.kernels.RhsKernel` compiles its helpers with it (:func:`compile_user_function`)
    first and does not spend a failed compile on each run."""
    fn = getattr(fn, "py_func", fn)
    if not isinstance(fn, types.FunctionType) or load_numba() is None:
        return False
    try:
        from numba.core.typing.templates import builtin_registry

        known = {id(v) for v, _ in builtin_registry.globals}
    except Exception:  # pragma: no cover - numba internals moved: try as written first
        return False
    glb = fn.__globals__
    return any(
        isinstance(glb.get(name), types.FunctionType) and glb[name] is not fn and id(glb[name]) not in known
        for name in code_names(fn.__code__)
    )


def code_names(code: types.CodeType) -> set[str]:
    """Global names a code object and the code objects nested in it read."""
    names = set(code.co_names)
    for const in code.co_consts:
        if isinstance(const, types.CodeType):
            names |= code_names(const)
    return names


def first_line(exc: BaseException) -> str:
    """The first line of an exception's message (numba's run on), else its type's name."""
    text = str(exc).strip()
    return text.splitlines()[0] if text else type(exc).__name__
