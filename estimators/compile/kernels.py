"""Right-hand-side kernels for the integrators, compiled with numba when the model allows.

Time marching is a loop over samples that numpy cannot vectorise; in plain Python the
per-step overhead of a model function (~40 small array operations) dominates an output-
error fit. numba compiles the user's ``f`` together with the integrator loop, so a fit of
600 samples x 12 perturbed parameter sets integrates in milliseconds.

How: ``f`` is compiled as written. A generated adapter loops over the batch columns and
calls ``f`` on scalars: the states of one column as a tuple of floats (so ``V, alpha,
theta, q = x`` works), the inputs as a tuple of floats, the parameters of that column as a
namedtuple (so ``p.CD0`` works); constants are a namedtuple of floats. Compiled for
scalars, ``f`` has no array temporaries, and numba compiles it (and the integrator loops,
written as element loops too: :mod:`estimators.simulation.integrators`) in a fraction of the time
array expressions take - a fresh installation's first fit waits for that compile. An
``f`` that needs whole rows (e.g. reads ``V.shape``) gets the adapter that passes them.
The compiled kernel is checked once against the numpy evaluation; when ``f`` does not
compile either way (e.g. it uses Python objects numba does not know) or disagrees, the
numpy path is used and a warning says so. ``FSID_JIT=0`` switches compilation off. numba
itself is imported on the first compile, not with the package.

Compiled code is kept on disk between runs (:func:`load_kernels`): compiling a model with
its integrator loops takes seconds (most of a short ``fsid`` run), loading it back a
fraction of that (``benchmarks/first_fit.py`` measures both). The adapters and the loops
that call them are written as a small module into ``$FSID_CACHE_DIR`` (default
``~/.cache/fsid``) under ``kernels/``, named by a hash of everything the compiled code
depends on: that generated source, the source files of ``f`` and ``g`` and of every
function they call, the values of the module globals and closure cells they read, the
package files with the loops they run (integrators.py, jit.py, fem.py for the filter loop),
and the numba and Python versions. Any edit there gives a new name, so a stale kernel is
never loaded; the folder may be deleted at any time. Each process that writes a new module
first prunes the folder (:func:`prune_kernels`): modules unused for ``FSID_CACHE_DAYS``
days (default 30) go, then the least recently used until the folder is below
``FSID_CACHE_MB`` (default 500). ``FSID_JIT_CACHE=0`` keeps everything in memory. A model
whose functions have no source file (typed at a prompt, built with ``exec``) or read
globals that cannot be fingerprinted is compiled in memory every run, as before. A kernel
module that did not compile or disagreed with numpy is marked ``<name>.failed``, so later
runs go straight to the way that worked instead of failing the same way again.
"""

from __future__ import annotations

import hashlib
import importlib.util
import inspect
import os
import re
import sys
import textwrap
import time
import types
import warnings
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from estimators.errors import ModelDefinitionError
from estimators.model import Model, Namespace, stack_rows
from estimators.simulation import integrators as _integ

#: numba, imported by :func:`load_numba` on the first compile (its import takes a few
#: tenths of a second that a process which never compiles need not pay); None until then
#: and when it is not installed
numba = None
_HAVE_NUMBA = importlib.util.find_spec("numba") is not None


def load_numba():
    """The numba module (imported now if it was not yet), or None when not installed."""
    global numba
    if numba is None and _HAVE_NUMBA:
        import numba as nb

        numba = nb
    return numba


_KERNELS: dict[tuple, RhsKernel] = {}
#: the package's source files every generated kernel module runs (their bytes enter the hash)
_PACKAGE_SOURCES = ("simulation/integrators.py", "compile/kernels.py")


def compile_user_function(fn: Callable, _done: dict | None = None, inline: bool = False) -> Callable:
    """``fn`` compiled with numba, together with the plain Python functions it calls by a
    global name (a helper such as ``coefs(x, u, p, c)`` shared by f and g, recursively):
    each is recompiled in a copy of its globals where those names are compiled too, so
    numba's nopython mode can call them. The user's function objects are not changed.
    ``inline``: numba inlines each into its caller (``inline="always"``) instead of
    compiling it as a function of its own, which saves a compile pipeline per function."""
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


def calls_unknown_helpers(fn: Callable) -> bool:
    """True when ``fn`` calls by a global name a plain Python function numba does not know
    (not compiled, not registered with ``register_jitable``): compiled as written it fails
    to type, so :class:`RhsKernel` compiles its helpers with it (:func:`compile_user_function`)
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
        for name in _code_names(fn.__code__)
    )


def probe_point(model: Model) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A made-up point at which a compiled kernel is checked against the numpy
    evaluation: states x (n, 2) 1 + 0.1 N(0, 1), inputs u (n_in,) 0.1 N(0, 1), the
    parameter matrix P (n_p, 2) at the model's values."""
    rng = np.random.default_rng(0)
    x = rng.standard_normal((len(model.states), 2)) * 0.1 + 1.0
    u = rng.standard_normal(len(model.inputs)) * 0.1
    P = np.repeat(np.array([[p.value] for p in model.parameters], dtype=float), 2, axis=1)
    return x, u, P


def first_line(exc: BaseException) -> str:
    """The first line of an exception's message (numba's run on), else its type's name."""
    text = str(exc).strip()
    return text.splitlines()[0] if text else type(exc).__name__


# -- kernels kept on disk -------------------------------------------------------------------
def cache_dir() -> Path | None:
    """The folder of generated kernel modules, created when missing; None when caching is
    off (``FSID_JIT_CACHE=0``) or the folder cannot be written."""
    if os.environ.get("FSID_JIT_CACHE", "1") == "0":
        return None
    base = os.environ.get("FSID_CACHE_DIR") or os.path.join(
        os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache"), "fsid"
    )
    d = Path(base) / "kernels"
    try:
        d.mkdir(parents=True, exist_ok=True)
    except OSError:
        return None
    return d if os.access(d, os.W_OK) else None


_SCALARS = (bool, int, float, complex, str, bytes, type(None))


#: days a kernel module may go unused, and the folder's size in MB, before pruning removes it
CACHE_DAYS, CACHE_MB = 30.0, 500.0
_PRUNED: set[str] = set()  # folders pruned by this process


def _env_number(name: str, default: float) -> float:
    try:
        v = float(os.environ.get(name, default))
    except ValueError:
        warnings.warn(f"{name}={os.environ[name]!r} is not a number: using {default:g}", RuntimeWarning, stacklevel=3)
        return default
    return v if v >= 0 else default


def _module_of(fname: str) -> str | None:
    """The kernel module a cache file belongs to: ``fsid_rhs_<hash>`` for its ``.py``, its
    ``.used`` stamp, a ``.<pid>.tmp`` being written and numba's ``.<fn>-<line>.py311.nbi/nbc``."""
    head = fname.split(".", 1)[0]
    return head if head.startswith("fsid_") and "_" in head[5:] else None


def prune_kernels(
    root: Path,
    max_age_days: float | None = None,
    max_mb: float | None = None,
    keep: Sequence[str] = (),
    now: float | None = None,
) -> list[str]:
    """Delete the kernel modules in ``root`` (a :func:`cache_dir`) not used for
    ``max_age_days`` (default ``FSID_CACHE_DAYS`` or 30), then the least recently used until
    the folder holds at most ``max_mb`` megabytes (``FSID_CACHE_MB`` or 500): each module
    with its numba index and object files. A module's last use is the time of its ``.used``
    stamp (set on every load; the ``.py`` itself keeps its time, which numba's index
    checks), else of its newest file. ``keep``: module names never removed (those this
    process loaded). Files of other programs are left alone. Returns the removed names,
    oldest first; a file another process removed meanwhile is no error."""
    days = _env_number("FSID_CACHE_DAYS", CACHE_DAYS) if max_age_days is None else max_age_days
    mb = _env_number("FSID_CACHE_MB", CACHE_MB) if max_mb is None else max_mb
    now = time.time() if now is None else now
    files: dict[str, list[Path]] = {}
    for folder in (root, root / "__pycache__"):
        try:
            entries = list(folder.iterdir())
        except OSError:
            continue
        for p in entries:
            name = _module_of(p.name)
            if name is not None and p.is_file():
                files.setdefault(name, []).append(p)
    used: dict[str, float] = {}
    size: dict[str, int] = {}
    for name, paths in files.items():
        stamps = {}
        for p in paths:
            try:
                st = p.stat()
            except OSError:
                continue
            stamps[p] = st.st_mtime
            size[name] = size.get(name, 0) + st.st_size
        stamp = root / f"{name}.used"
        used[name] = stamps.get(stamp, max(stamps.values(), default=now))
    order = sorted((n for n in files if n not in keep), key=used.__getitem__)
    total = sum(size.values())
    removed = []
    for name in order:
        if now - used[name] <= days * 86400.0 and total <= mb * 1e6:
            continue
        for p in files[name]:
            try:
                p.unlink()
            except FileNotFoundError:
                pass
            except OSError:
                break
        else:
            total -= size.get(name, 0)
            removed.append(name)
    return removed


def _value_bytes(v: Any) -> bytes | None:
    """A fingerprint of a global or closure value that numba freezes into compiled code;
    None when it cannot be had."""
    if isinstance(v, _SCALARS) or isinstance(v, np.generic):
        return repr(v).encode()
    if isinstance(v, np.ndarray):
        return str((v.dtype, v.shape)).encode() + np.ascontiguousarray(v).tobytes()
    if isinstance(v, tuple):
        parts = [_value_bytes(x) for x in v]
        return None if any(p is None for p in parts) else b"(" + b",".join(parts) + b")"
    return None


def _code_names(code: types.CodeType) -> set[str]:
    """Global names a code object and the code objects nested in it read."""
    names = set(code.co_names)
    for const in code.co_consts:
        if isinstance(const, types.CodeType):
            names |= _code_names(const)
    return names


def _fingerprint_function(fn: Any, h: hashlib._Hash, seen: set, files: set) -> bool:
    """Feed ``fn``'s source file, name, closure values and the globals it reads (functions
    recursively) into ``h``; False when something it depends on cannot be fingerprinted."""
    fn = getattr(fn, "py_func", fn)  # a numba dispatcher: its Python function
    if id(fn) in seen:
        return True
    seen.add(id(fn))
    if not isinstance(fn, types.FunctionType):
        return isinstance(fn, (types.BuiltinFunctionType, np.ufunc))
    path = fn.__code__.co_filename
    if not os.path.isfile(path):
        return False
    if path not in files:
        files.add(path)
        h.update(Path(path).read_bytes())
    h.update(f"{fn.__module__}.{fn.__qualname__}".encode())
    for cell in fn.__closure__ or ():
        v = cell.cell_contents
        if isinstance(v, types.FunctionType) or hasattr(v, "py_func"):
            if not _fingerprint_function(v, h, seen, files):
                return False
        elif (b := _value_bytes(v)) is not None:
            h.update(b)
        else:
            return False
    glb = fn.__globals__
    for name in sorted(_code_names(fn.__code__)):
        if name not in glb:
            continue  # a builtin or an attribute name
        v = glb[name]
        if isinstance(v, types.ModuleType) or isinstance(v, type):
            h.update(f"{name}={getattr(v, '__name__', '')}".encode())
        elif isinstance(v, types.FunctionType) or hasattr(v, "py_func"):
            if not _fingerprint_function(v, h, seen, files):
                return False
        elif (b := _value_bytes(v)) is not None:
            h.update(name.encode() + b"=" + b)
        elif callable(v):
            h.update(f"{name}={type(v).__name__}".encode())  # a ufunc or builtin: by name
        else:
            return False
    return True


def kernel_key(source: str, functions: Sequence[Callable], package: Sequence[str] = ()) -> str | None:
    """The hash naming a generated kernel module (hex), or None when one of ``functions``
    cannot be fingerprinted (no source file, unknown global values). ``package``: more of
    the package's source files (names in this folder) the module runs."""
    h = hashlib.sha256(source.encode())
    h.update(f"{numba.__version__ if numba else ''} {sys.version}".encode())
    here = Path(__file__).resolve().parents[1]  # the estimators folder
    for name in (*_PACKAGE_SOURCES, *package):
        h.update((here / name).read_bytes())
    seen: set = set()
    files: set = set()
    for fn in functions:
        if not _fingerprint_function(fn, h, seen, files):
            return None
    return h.hexdigest()[:32]


def load_kernels(
    source: str, inject: Mapping[str, Any], functions: Sequence[Callable], prefix: str, package: Sequence[str] = ()
) -> types.ModuleType | types.SimpleNamespace:
    """Run a generated kernel ``source`` whose numba functions read ``CACHE`` for their
    ``cache=`` option, with the names in ``inject`` (compiled user functions, other
    kernels) set first. Kept on disk as ``<cache_dir>/<prefix>_<hash>.py`` and imported,
    so numba loads its compiled functions back in the next process; run in memory
    (``CACHE`` False) when caching is off or ``functions`` cannot be fingerprinted.
    ``package``: the package's source files the module runs beyond the integrators and
    this module, as paths relative to the estimators folder (e.g.
    ``("filters/filter_error.py",)``)."""
    root = cache_dir() if load_numba() is not None else None
    key = kernel_key(source, functions, package) if root is not None else None
    if key is None:
        ns: dict[str, Any] = {**inject, "CACHE": False}
        exec(compile(source, f"<fsid {prefix}>", "exec"), ns)
        return types.SimpleNamespace(**{k: v for k, v in ns.items() if not k.startswith("__")})
    name = f"{prefix}_{key}"
    mod = sys.modules.get(name)
    if mod is not None:
        return mod
    path = root / f"{name}.py"
    if not path.is_file():
        if str(root) not in _PRUNED:  # the folder grows: once per process
            _PRUNED.add(str(root))
            prune_kernels(root, keep=[n for n in sys.modules if _module_of(n) == n])
        _write_module(path, source)
    try:
        (root / f"{name}.used").touch()  # last use, for prune_kernels
    except OSError:
        pass
    for attempt in (0, 1):
        spec = importlib.util.spec_from_file_location(name, path)
        mod = importlib.util.module_from_spec(spec)
        mod.__dict__.update(inject, CACHE=True)
        sys.modules[name] = mod  # numba's cache index pickles its types
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", getattr(numba, "NumbaWarning", Warning))
                spec.loader.exec_module(mod)
            return mod
        except FileNotFoundError:  # pruned by another process meanwhile
            sys.modules.pop(name, None)
            if attempt:
                raise
            _write_module(path, source)
        except BaseException:
            sys.modules.pop(name, None)
            raise
    raise AssertionError("unreachable")  # pragma: no cover


def failed_before(mod: Any) -> str | None:
    """The reason a kernel module kept on disk failed in an earlier run (its
    ``<name>.failed`` mark, see :func:`mark_failed`), or None."""
    path = getattr(mod, "__file__", None)
    if not path:
        return None
    try:
        return Path(path).with_suffix(".failed").read_text() or "failed before"
    except OSError:
        return None


def mark_failed(mod: Any, why: str) -> None:
    """Mark a kernel module kept on disk as failed (it did not compile, or disagreed with
    the numpy evaluation), so later runs skip it; nothing for one in memory."""
    path = getattr(mod, "__file__", None)
    if path:
        try:
            Path(path).with_suffix(".failed").write_text(why)
        except OSError:
            pass


def _write_module(path: Path, source: str) -> None:
    """Write a generated module atomically (another process may race: same text)."""
    tmp = path.with_suffix(f".{os.getpid()}.tmp")
    tmp.write_text(source)
    os.replace(tmp, path)


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
    (:data:`estimators.simulation.integrators.LOOP_HELPERS`), made once per process and shared by every
    kernel module (compiled when a module's loop first needs them; a loop loaded from the
    disk cache carries its own copy)."""
    if not _LOOPS:
        nb = load_numba()
        _LOOPS.update(
            {name: nb.njit(error_model="numpy", inline="always")(fn) for name, fn in _integ.LOOP_HELPERS.items()}
        )
    return _LOOPS


def _scheme_source() -> str:
    """The integrators of a kernel module: every scheme of :mod:`estimators.simulation.integrators`
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
        self._jit_state = "untried" if (_HAVE_NUMBA and os.environ.get("FSID_JIT", "1") != "0") else "off"

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
                "from estimators.simulation import integrators as _I",
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
        # them as functions of their own, as before
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
                if not np.allclose(a, b, rtol=1e-9, atol=1e-12, equal_nan=True):
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
        rtol: float = 1e-8,
        atol: float = 1e-10,
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
