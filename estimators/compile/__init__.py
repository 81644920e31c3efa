"""Compiled model kernels: the model's equations and the loops that run them, compiled with numba.

:mod:`.kernels` generates and checks the kernel modules (:func:`kernel_for` gives a
model's), :mod:`.cache` keeps them on disk between runs, :mod:`.numba_jit` imports numba
on demand and compiles the user's functions.
"""

from estimators.compile.cache import (
    PACKAGE_SOURCES,
    cache_dir,
    failed_before,
    kernel_key,
    load_kernels,
    mark_failed,
    prune_kernels,
)
from estimators.compile.kernels import RhsKernel, adapter_source, bound_source, kernel_for, loop_helpers, probe_point
from estimators.compile.numba_jit import HAVE_NUMBA, compile_user_function, first_line, load_numba

__all__ = [
    "HAVE_NUMBA",
    "PACKAGE_SOURCES",
    "RhsKernel",
    "adapter_source",
    "bound_source",
    "cache_dir",
    "compile_user_function",
    "failed_before",
    "first_line",
    "kernel_for",
    "kernel_key",
    "load_kernels",
    "load_numba",
    "loop_helpers",
    "mark_failed",
    "probe_point",
    "prune_kernels",
]
