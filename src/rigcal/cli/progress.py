"""Progress bars and log output for every command: one style, on stderr.

Bars are tqdm's (counts, totals, rates, time left), drawn only when stderr is a terminal
and ``-q`` was not given; when they are off, a stage that ends still gets one plain line
(``stage: N/N in S s``) unless ``-q``. ``-v``/``-q`` on the ``rigcal`` group set the
level of the ``rigcal`` loggers (warnings and notes by default: a kernel compiled on first
use says so, rigcal.jit).
"""

from __future__ import annotations

import logging
import sys
import threading
import time
from typing import Any

import click


def configure(verbose: int, quiet: bool) -> None:
    """The ``rigcal`` loggers' level and handler for ``-v`` (info), ``-vv`` (debug), ``-q``."""
    from rigcal.jit import NOTE

    level = logging.ERROR if quiet else (NOTE, logging.INFO, logging.DEBUG)[min(verbose, 2)]
    log = logging.getLogger("rigcal")
    log.setLevel(level)
    if not any(isinstance(h, _StderrHandler) for h in log.handlers):
        handler = _StderrHandler()
        handler.setFormatter(logging.Formatter("%(levelname)s: %(name)s: %(message)s"))
        log.addHandler(handler)
        log.propagate = False


class _StderrHandler(logging.Handler):
    """Log lines to whatever ``sys.stderr`` is when they are written (not when the
    handler was made), so a redirected or replaced stderr gets them."""

    def emit(self, record: logging.LogRecord) -> None:
        try:
            sys.stderr.write(self.format(record) + "\n")
        except Exception:  # pragma: no cover - logging's own policy for a failed write
            self.handleError(record)


def quiet() -> bool:
    """Whether ``-q`` was given to the ``rigcal`` group of the running command."""
    ctx = click.get_current_context(silent=True)
    obj = ctx.find_root().obj if ctx is not None else None
    return bool(isinstance(obj, dict) and obj.get("quiet"))


class Progress:
    """tqdm bars on stderr, one per stage; stages may run side by side (the laser
    odometry beside the feature tracking), each on its own line.

    Call it as ``progress(stage, done, total)`` (the library's stage callbacks), or get a
    one-stage counter with :meth:`counter`. Use as a context manager, or call :meth:`close`.
    """

    def __init__(self, unit: str = "it", disable: bool | None = None) -> None:
        self.quiet = quiet() if disable is None else disable
        self.live = not self.quiet and sys.stderr.isatty()
        self.unit = unit
        self.bars: dict[str, Any] = {}
        self.started: dict[str, float] = {}
        self.done: dict[str, int] = {}  # tqdm keeps no count while disabled
        self.lock = threading.Lock()

    def __enter__(self) -> Progress:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _bar(self, stage: str, total: int | None) -> Any:
        self.started[stage] = time.perf_counter()
        if not self.live:  # nothing drawn: no need to import tqdm
            return _Count(total)
        from tqdm import tqdm  # type: ignore[import-untyped]

        return tqdm(
            total=total,
            desc=stage,
            unit=self.unit,
            file=sys.stderr,
            position=len(self.bars),
            leave=True,
            dynamic_ncols=True,
        )

    def __call__(self, stage: str, done: int, total: int | None) -> None:
        with self.lock:
            bar = self.bars.get(stage)
            if bar is None:
                if total is not None and done >= total and stage in self.started:
                    return  # a stage reported again after it ended
                bar = self.bars[stage] = self._bar(stage, total)
            if total is not None and bar.total != total:
                bar.total = total
            if done > self.done.get(stage, 0):
                bar.update(done - self.done.get(stage, 0))
                self.done[stage] = done
            if total is not None and done >= total:
                self._end(stage)

    def counter(self, stage: str, total: int | None = None) -> Any:
        """A callback taking the count done so far (``total`` may be unknown)."""
        return lambda done: self(stage, done, total)

    def _end(self, stage: str) -> None:
        bar = self.bars.pop(stage)
        n = self.done.pop(stage, 0)
        bar.close()
        if not self.live and not self.quiet:
            total = bar.total if bar.total is not None else n
            sys.stderr.write(f"{stage}: {n}/{total} in {time.perf_counter() - self.started[stage]:.1f} s\n")
            sys.stderr.flush()

    def close(self) -> None:
        """End every stage still open (e.g. a count whose total was not known)."""
        with self.lock:
            for stage in sorted(self.bars):
                self._end(stage)


class _Count:
    """A stage where no bar is drawn (``-q``, or stderr not a terminal): the total a
    bar would show, and tqdm's update and close as no-ops (:class:`Progress` keeps the
    counts)."""

    def __init__(self, total: int | None) -> None:
        self.total = total

    def update(self, n: int) -> None:
        pass

    def close(self) -> None:
        pass
