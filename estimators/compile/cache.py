"""Generated kernel modules kept on disk between runs, named by a fingerprint of what they compile.

Compiling a model with its integrator loops takes seconds, loading it back a fraction of
that. :func:`load_kernels` writes a generated kernel module into ``$FSID_CACHE_DIR``
(default ``~/.cache/fsid``) under ``kernels/`` and imports it, so numba loads its compiled
functions back in the next process. The module is named by a hash of everything the
compiled code depends on (:func:`kernel_key`): the generated source, the source files of
``f`` and ``g`` and of every function they call, the values of the module globals and
closure cells they read, the package files whose loops the module runs
(:data:`PACKAGE_SOURCES` and the caller's), and the numba and Python versions. Any edit
there gives a new name, so a stale kernel is never loaded; the folder may be deleted at
any time. Each process that writes a new module first prunes the folder
(:func:`prune_kernels`): modules unused for ``FSID_CACHE_DAYS`` days (default 30) go, then
the least recently used until the folder is below ``FSID_CACHE_MB`` (default 500).
``FSID_JIT_CACHE=0`` keeps everything in memory. A model whose functions have no source
file (typed at a prompt, built with ``exec``) or read globals that cannot be fingerprinted
is compiled in memory every run. A kernel module that did not compile or disagreed with
numpy is marked ``<name>.failed`` (:func:`mark_failed`), so later runs go straight to the
way that worked instead of failing the same way again.
"""

from __future__ import annotations

import hashlib
import importlib.util
import os
import sys
import time
import types
import warnings
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from estimators.compile import numba_jit
from estimators.compile.numba_jit import code_names, load_numba
from estimators.defaults import CACHE_DAYS, CACHE_MB

#: the package's source files every generated kernel module runs, relative to the
#: estimators folder (their bytes enter the hash)
PACKAGE_SOURCES = ("integrators.py", "compile/kernels.py", "compile/numba_jit.py")


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
    for name in sorted(code_names(fn.__code__)):
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
    the package's source files the module runs, as paths relative to the estimators
    folder (e.g. ``"filters/filter_error.py"``)."""
    h = hashlib.sha256(source.encode())
    nb = numba_jit.numba
    h.update(f"{nb.__version__ if nb else ''} {sys.version}".encode())
    here = Path(__file__).resolve().parents[1]  # the estimators folder
    for name in (*PACKAGE_SOURCES, *package):
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
    nb = load_numba()
    root = cache_dir() if nb is not None else None
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
                warnings.simplefilter("ignore", getattr(nb, "NumbaWarning", Warning))
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
