"""How the envelope's kernels are compiled: the decorators of their helpers, and the entry points'
compilation with numba's on-disk cache keyed on every source compiled into them.

numba's cache checks only the file that defines an entry point: a helper edited in another module
(`predicates`, `sample`, `robot/batch_fk.py`'s `_fk_into`) would leave stale machine code in use.
So each entry point is cached under a name that carries a digest of all those sources: an edit to
any of them compiles afresh (the old files stay in `__pycache__` until deleted).
"""

from __future__ import annotations

import hashlib
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numba

from armwarden.robot import batch_fk
from armwarden.robot.jit_compile import compile_cached

__all__ = ["COMPILED_SOURCES", "SOURCES_DIGEST", "compile_entry", "helper", "inlined", "sources_digest"]

# Compiled into the entry points below (no signatures of their own; `cache=False`: the entry
# points' cache holds them). Every array a function binds (an argument, a row view, a tuple's
# element) costs an atomic reference-count pair, ~10 ns: the hot helpers take the whole arrays and
# indices rather than rows, and the ones that loop or branch are real calls, not inlined, whose
# counting numba can prune (an inlined body's bindings it often cannot).
helper = numba.njit(nogil=True, cache=False)
# numba types an int constant passed to a function as a literal and compiles a specialisation of
# the callee for each value (minutes of compile time for `evaluate_sample`): values passed on are made
# plain with np.int64(...) or float(...), and the tiny table look-ups, called with literal table
# ids, are inlined in numba's IR instead.
inlined = numba.njit(nogil=True, cache=False, inline="always")


def sources_digest(paths: list[Path]) -> str:
    """A digest of the text of `paths` (in the order given): what the entry points' cache names carry."""
    digest = hashlib.sha256()
    for path in paths:
        digest.update(path.name.encode())
        digest.update(path.read_bytes())
    return digest.hexdigest()[:16]


#: every module compiled into the entry points: this package's and batch_fk's
COMPILED_SOURCES = (*sorted(Path(__file__).parent.glob("*.py")), Path(batch_fk.__file__))
#: their digest, carried by the entry points' cache names
SOURCES_DIGEST = sources_digest(list(COMPILED_SOURCES))


def compile_entry(py_func: Callable[..., Any], signature: Any) -> tuple[Any, bool]:
    """`compile_cached`: eager compilation with the on-disk cache (or in memory where none is
    writable), under a name that carries `SOURCES_DIGEST`. Returns (kernel, cached)."""
    py_func.__qualname__ = f"{py_func.__name__}_{SOURCES_DIGEST}"
    return compile_cached(py_func, signature)
