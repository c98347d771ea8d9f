"""Compiled kernels: numba's ``njit`` with an on-disk cache when one can be written.

The hot loops (P3P per triple, ICP's correspondences and normal equations, IASM's SAD
matching) are written once as plain loops and compiled to machine code on first call.
Compiling costs a second or two per kernel; ``cache=True`` keeps the machine code in
``__pycache__`` beside the source (or under ``NUMBA_CACHE_DIR`` when that is set) so later
processes load it instead. Where no cache location is writable (a read-only install) the
kernels are compiled in each process instead. Each kernel has a numpy reference it is
tested against.

A kernel compiled (not loaded from the cache) logs one ``note`` line on the ``rigcal.jit``
logger when its compilation ends, with the time it took and where it was cached, so a
slow first run says why; :data:`COMPILED` keeps the same records for the process.

Division by zero and the square root of a negative number give inf/NaN as in numpy
(``error_model="numpy"``), so a kernel follows its numpy reference on degenerate input.
"""

from __future__ import annotations

import logging
import time
import weakref
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, cast

NOTE = 25
"""The log level of a compile line: above info (shown without ``-v``), below warning."""
logging.addLevelName(NOTE, "NOTE")
log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Compiled:
    """One kernel compiled in this process (the kernels it calls are counted in it)."""

    kernel: str
    seconds: float
    cache_dir: str | None


COMPILED: list[Compiled] = []
"""Every kernel compiled (rather than loaded from the cache) in this process, in order."""


def njit[F: Callable[..., Any]](fn: F) -> F:
    """Compile ``fn`` with numba in nopython mode, cached on disk when possible."""
    import numba

    _listen()
    try:
        out = numba.njit(cache=True, nogil=True, error_model="numpy")(fn)
    except RuntimeError:  # no writable cache location: compile in each process
        out = numba.njit(cache=False, nogil=True, error_model="numpy")(fn)
    _KERNELS.add(out)
    return cast(F, out)


def loaded(kernel: Callable[..., Any]) -> bool:
    """Whether the kernel has machine code in this process (compiled or loaded from the
    cache): a call then sets nothing up."""
    return bool(getattr(kernel, "signatures", ()))


def cache_dir(dispatcher: Any) -> str | None:
    """The folder a kernel's compiled code is cached in, or None if it is not cached."""
    cache = getattr(dispatcher, "_cache", None)
    path = getattr(cache, "cache_path", None)
    return str(path) if path else None


_listening: list[bool] = []
_KERNELS: weakref.WeakSet[Any] = weakref.WeakSet()  # the dispatchers njit made


def _listen() -> None:
    """Install the compile listener once per process (at the first kernel defined)."""
    if _listening:
        return
    from numba.core import event

    class CompileLog(event.Listener):
        """numba's ``numba:compile`` events (sent only when a kernel is compiled, not when
        it is loaded from the cache) of rigcal's kernels as one log line per outermost
        kernel: a kernel calling others compiles them inside its own compilation."""

        def __init__(self) -> None:
            self.depth = 0
            self.started = 0.0

        def on_start(self, event: Any) -> None:
            if _ours(event):
                if self.depth == 0:
                    self.started = time.perf_counter()
                self.depth += 1

        def on_end(self, event: Any) -> None:
            if _ours(event):
                self.depth -= 1
                if self.depth == 0:
                    _compiled(event.data["dispatcher"], time.perf_counter() - self.started)

    event.register("numba:compile", CompileLog())
    _listening.append(True)


def _ours(event: Any) -> bool:
    return event.data.get("dispatcher") in _KERNELS


def _compiled(dispatcher: Any, seconds: float) -> None:
    fn = dispatcher.py_func
    rec = Compiled(f"{fn.__module__}.{fn.__qualname__}", seconds, cache_dir(dispatcher))
    COMPILED.append(rec)
    where = (
        f"cached in {rec.cache_dir} for later runs"
        if rec.cache_dir
        else "not cached (no writable cache folder: set NUMBA_CACHE_DIR)"
    )
    log.log(NOTE, "compiled %s on first use in %.1f s; %s", rec.kernel, rec.seconds, where)
