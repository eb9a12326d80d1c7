"""numba kernels compiled eagerly, cached on disk where numba can write its cache.

Shared by the compiled forward kinematics (`batch_fk`) and the fitting tool's mesh kernels
(`fitting_mesh`): both want the machine code loaded from numba's cache on later imports, and both
must still work on a read-only install, only slower to start.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import Any

import numba

__all__ = ["compile_cached"]

log = logging.getLogger(__name__)


def compile_cached(py_func: Callable[..., Any], signature: Any) -> tuple[Any, bool]:
    """`njit(signature, cache=True)(py_func)`, or without the on-disk cache where numba has no
    writable cache directory (it raises RuntimeError then, or OSError when a write fails).
    Returns (kernel, cached)."""
    try:
        return numba.njit(signature, cache=True, nogil=True)(py_func), True
    except (RuntimeError, OSError) as exc:
        log.warning("numba cannot cache %s on disk (%s); compiling it in memory at every start-up", py_func.__name__, exc)
        return numba.njit(signature, cache=False, nogil=True)(py_func), False
