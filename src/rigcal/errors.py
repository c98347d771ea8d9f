"""One error hierarchy for rigcal.

The library raises these; only the CLI boundary (``rigcal.cli.main``) turns them into a
one-line ``Error: ...`` on stderr and the exit code each class carries. Anything that is
not a :class:`RigcalError` is a bug and keeps its traceback.

Exit codes (documented in docs/cli.md):

===  ==========================================================
 0   success
 1   a check ran and its verdict is negative (e.g. drift found)
 2   command-line usage error (click)
 3   bad input: missing, unreadable, malformed or invalid file (or API argument)
 4   calibration failed: too few data, degenerate geometry, no consensus
 5   output refused or failed: file exists without --force, write error
 6   a check ran and cannot tell (rigcal check --sequence: too short, no overlap, no motion)
===  ==========================================================
"""

from __future__ import annotations

import reprlib
from pathlib import Path
from typing import Any

_short = reprlib.Repr(
    maxlevel=3, maxlist=8, maxdict=8, maxtuple=8, maxset=8, maxstring=80, maxother=80, maxlong=60
)


def _small(value: Any, budget: int = 1000) -> bool:
    """True if ``value`` holds at most ``budget`` items, nested ones counted (stops early)."""
    stack = [value]
    while stack:
        v = stack.pop()
        if isinstance(v, dict):
            budget -= len(v)
            stack.extend(v.values())
        elif isinstance(v, (list, tuple, set)):
            budget -= len(v)
            stack.extend(v)
        if budget < 0:
            return False
    return True


class RigcalError(Exception):
    """Base of every error rigcal raises on purpose."""

    exit_code = 1


class InputError(RigcalError):
    """A file or value given by the user is missing, unreadable or invalid."""

    exit_code = 3

    @classmethod
    def at(cls, path: str | Path | None, key: str, value: Any, expected: str) -> InputError:
        """Build the standard message: ``FILE: KEY: got VALUE; expected EXPECTED``.

        Args:
            path: the file the value came from (None when it came from elsewhere).
            key: the key path inside the file, e.g. ``captures[3].scan``.
            value: the offending value; long values are shortened.
            expected: what would have been accepted.
        """
        # A huge or deeply nested value (a YAML alias bomb) gets a bounded repr.
        shown = repr(value) if _small(value) else _short.repr(value)
        if len(shown) > 80:  # keep both ends: a path's file name, a list's last items
            shown = shown[:38] + "..." + shown[-39:]
        where = f"{path}: " if path is not None else ""
        return cls(f"{where}{key}: got {shown}; expected {expected}")


class CalibrationError(RigcalError):
    """The data are valid but cannot determine a calibration."""

    exit_code = 4


class OutputError(RigcalError):
    """A result could not or must not be written."""

    exit_code = 5


class ArgumentError(InputError):
    """An argument of a Python API call (``rigcal.solve_box``, ...) is invalid: the wrong
    type, or a value the command line's option would refuse. The message names the
    function, the argument and the value: ``rigcal.solve_box: range_sigma_m: got nan;
    expected a finite number x>=1e-05``. A subclass of :class:`InputError` (exit code 3
    at the command line's boundary)."""
