"""Compiled kernels: numba's ``njit`` with an on-disk cache when one can be written.

The hot loops (P3P per triple, ICP's correspondences and normal equations, IASM's SAD
matching) are written once as plain loops and compiled to machine code on first call.
Compiling costs a second or two per kernel; ``cache=True`` keeps the machine code in
``__pycache__`` beside the source (or numba's user cache, ``NUMBA_CACHE_DIR``) so later
processes load it instead. Where no cache location is writable (a read-only install) the
kernels are compiled in each process instead. Each kernel has a numpy reference it is
tested against.

Division by zero and the square root of a negative number give inf/NaN as in numpy
(``error_model="numpy"``), so a kernel follows its numpy reference on degenerate input.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, cast


def njit[F: Callable[..., Any]](fn: F) -> F:
    """Compile ``fn`` with numba in nopython mode, cached on disk when possible."""
    import numba

    try:
        out = numba.njit(cache=True, nogil=True, error_model="numpy")(fn)
    except RuntimeError:  # no writable cache location: compile in each process
        out = numba.njit(cache=False, nogil=True, error_model="numpy")(fn)
    return cast(F, out)
