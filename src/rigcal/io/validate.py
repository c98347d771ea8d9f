"""One place for the checks every number and name from outside goes through.

Readers of files call :func:`real`, :func:`whole`, :func:`finite_array` and
:func:`path_component` / :func:`relative_inside`; every option's rule is a :class:`Real`,
:class:`Whole` or :class:`OneOf`, which the command line's option types
(:mod:`rigcal.cli.types`) and the Python API's keyword checks both apply. Each failure is
one :class:`~rigcal.errors.InputError` line naming the file, the key, the value and what
was expected (or, for options, click's usage error, exit code 2), so NaN, infinities,
400-digit integers, negative sizes and names that would lead outside a folder stop at the
boundary instead of deep inside a solver.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path, PurePosixPath, PureWindowsPath
from typing import TYPE_CHECKING, Any

from rigcal.errors import InputError

if TYPE_CHECKING:  # numpy is imported where used: the command line's --help stays instant
    import numpy as np
    from numpy.typing import NDArray

Where = str | Path | None


def _expected(positive: bool, nonneg: bool, lo: float | None, hi: float | None) -> str:
    if positive:
        what = "a finite number > 0"
    elif nonneg:
        what = "a finite number >= 0"
    else:
        what = "a finite number"
    if positive and hi is not None:
        return f"{what[:-4]} in (0, {hi:g}]"
    if lo is not None and hi is not None:
        return f"{what} in [{lo:g}, {hi:g}]"
    if lo is not None:
        return f"{what} >= {lo:g}"
    if hi is not None:
        return f"{what} <= {hi:g}"
    return what


def real(
    value: Any,
    where: Where,
    key: str,
    *,
    positive: bool = False,
    nonneg: bool = False,
    lo: float | None = None,
    hi: float | None = None,
) -> float:
    """``value`` as a finite float, rejecting booleans, strings, NaN, infinities and
    integers too large for a float; optionally > 0, >= 0 or within [lo, hi].

    Raises:
        InputError: ``WHERE: KEY: got VALUE; expected ...``.
    """
    import numpy as np

    expected = _expected(positive, nonneg, lo, hi)
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise InputError.at(where, key, value, expected)
    try:
        out = float(value)
    except OverflowError:
        raise InputError.at(where, key, value, expected) from None
    if (
        not math.isfinite(out)
        or (positive and not out > 0)
        or (nonneg and not out >= 0)
        or (lo is not None and out < lo)
        or (hi is not None and out > hi)
    ):
        raise InputError.at(where, key, value, expected)
    return out


def is_real(value: Any) -> bool:
    """True for an int or float (not a boolean) that is a finite float."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return False
    try:
        return math.isfinite(value)
    except OverflowError:  # an integer beyond the float range
        return False


def parse_real(text: str, where: Where, key: str, **limits: Any) -> float:
    """A number written as text (a log's field), checked as :func:`real`."""
    try:
        value = float(text)
    except (ValueError, OverflowError):
        raise InputError.at(where, key, text, _expected(**_limits(limits))) from None
    return real(value, where, key, **limits)


def _limits(limits: dict[str, Any]) -> dict[str, Any]:
    return {
        "positive": limits.get("positive", False),
        "nonneg": limits.get("nonneg", False),
        "lo": limits.get("lo"),
        "hi": limits.get("hi"),
    }


def whole(value: Any, where: Where, key: str, *, lo: int = 0, hi: int = 10**9) -> int:
    """``value`` as an integer in [lo, hi] (booleans, floats and digit strings rejected)."""
    import numpy as np

    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or not lo <= value <= hi:
        raise InputError.at(where, key, value, f"an integer in [{lo}, {hi}]")
    return int(value)


def parse_whole(text: str, where: Where, key: str, *, lo: int = 0, hi: int = 10**9) -> int:
    """An integer written as text in ASCII digits (no sign, no superscripts), in [lo, hi]."""
    if not (text.isascii() and text.isdigit()) or len(text) > len(str(hi)) or not lo <= int(text) <= hi:
        raise InputError.at(where, key, text, f"an integer in [{lo}, {hi}]")
    return int(text)


def finite_array(
    values: Any,
    where: Where,
    key: str,
    *,
    shape: tuple[int | None, ...] | None = None,
    nonneg: bool = False,
    positive: bool = False,
    allow_nan: bool = False,
    lo: float | None = None,
    hi: float | None = None,
) -> NDArray[np.float64]:
    """``values`` as a float64 array of the given shape (None: any length), every entry
    finite (NaN allowed where ``allow_nan``: "no value"), optionally >= 0 or > 0.

    Raises:
        InputError: naming the first bad entry by its index.
    """
    import numpy as np

    try:
        a = np.asarray(values, dtype=np.float64)
    except (TypeError, ValueError, OverflowError):
        raise InputError.at(where, key, values, "an array of numbers") from None
    if shape is not None and (
        a.ndim != len(shape) or any(s is not None and s != n for s, n in zip(shape, a.shape, strict=True))
    ):
        want = "x".join("N" if s is None else str(s) for s in shape)
        raise InputError.at(where, key, f"an array of shape {a.shape}", f"shape ({want})")
    bad = np.isinf(a) if allow_nan else ~np.isfinite(a)
    with np.errstate(invalid="ignore"):
        if nonneg:
            bad |= a < 0
        if positive:
            bad |= a <= 0
        if lo is not None:
            bad |= a < lo
        if hi is not None:
            bad |= a > hi
    if bad.any():
        i = tuple(int(k) for k in np.argwhere(bad)[0])
        index = "".join(f"[{k}]" for k in i)
        what = "finite numbers" + (" > 0" if positive else " >= 0" if nonneg else "")
        if lo is not None or hi is not None:
            what += f" in [{lo if lo is not None else '-inf'}, {hi if hi is not None else 'inf'}]"
        raise InputError.at(
            where, f"{key}{index}", float(a[i]), what + (" (or NaN: none)" if allow_nan else "")
        )
    return a


# Unicode categories a name must not hold: controls (C0, DEL, C1), format characters (the
# bidi overrides and isolates U+202A-U+202E, U+2066-U+2069 that make a terminal show
# "evil\u202egnp.exe" as "evilexe.png", zero-width characters), line and paragraph
# separators, lone surrogates.
_HIDDEN_CATEGORIES = frozenset({"Cc", "Cf", "Zl", "Zp", "Cs"})
# A name that becomes a file name is at most this many UTF-8 bytes (file systems allow 255;
# rigcal appends suffixes and temporary-name parts).
MAX_NAME_BYTES = 200


def hidden_char(text: str) -> str | None:
    """The first character of ``text`` that a terminal or an editor would not show as it
    is (:data:`_HIDDEN_CATEGORIES`), or None."""
    if text.isascii():
        return next((c for c in text if ord(c) < 32 or ord(c) == 127), None)
    import unicodedata

    return next((c for c in text if unicodedata.category(c) in _HIDDEN_CATEGORIES), None)


def path_component(name: Any, where: Where, key: str) -> str:
    """``name`` as one file-name component: non-empty text without a slash, a backslash, a
    NUL byte, control or bidi characters (:func:`hidden_char`), not ``.`` or ``..`` and at
    most :data:`MAX_NAME_BYTES` bytes, so that it can never name a file outside the folder
    it is joined to, nor one the file system refuses."""
    expected = (
        f"a name of at most {MAX_NAME_BYTES} bytes without '/', '\\', '..', NUL, control or bidi characters"
    )
    if (
        not isinstance(name, str)
        or name in ("", ".", "..")
        or any(c in name for c in "/\\")
        or hidden_char(name) is not None
        or len(name.encode("utf-8", "surrogatepass")) > MAX_NAME_BYTES
    ):
        raise InputError.at(where, key, name, expected)
    return name


def relative_inside(rel: Any, where: Where, key: str) -> str:
    """``rel`` as a relative path that stays inside the folder it is joined to: no absolute
    path, no drive, no ``..`` component, no NUL or control characters. Returned with its
    backslashes as ``/`` (:func:`slashed`)."""
    expected = "a relative path inside the folder (no '..', no leading '/', no NUL, control or bidi chars)"
    if not isinstance(rel, str) or not rel.strip() or hidden_char(rel) is not None:
        raise InputError.at(where, key, rel, expected)
    posix, win = PurePosixPath(slashed(rel)), PureWindowsPath(rel)
    if posix.is_absolute() or win.is_absolute() or win.drive or ".." in posix.parts or ".." in win.parts:
        raise InputError.at(where, key, rel, expected)
    return slashed(rel)


def slashed(rel: str) -> str:
    """A relative path read from a file with its backslashes as ``/``: a list or session
    written on Windows (``images\\cap00.png``) names the file it would there. (No name
    rigcal reads or writes holds a backslash of its own.)"""
    return rel.replace("\\", "/")


def file_inside(folder: Path, rel: Any, where: Where, key: str) -> Path:
    """``folder / rel`` for a ``rel`` that :func:`relative_inside` accepts and that, with
    its symlinks followed, is still inside ``folder``: a list's entry that is a symlink
    to a file elsewhere would copy that file's bytes into an output."""
    path = folder / relative_inside(rel, where, key)
    try:
        real_path, real_folder = path.resolve(), folder.resolve()
    except (OSError, RuntimeError):  # a symlink loop
        raise InputError.at(where, key, rel, "a file, not a symlink loop") from None
    if not real_path.is_relative_to(real_folder):
        raise InputError.at(
            where, key, rel, f"a file inside {folder} (it is a symlink to {real_path}, outside)"
        )
    return path


class Real:
    """A float option's rule: finite (no ``nan``, ``inf``), optionally within a range
    (``min``/``max``, each bound open or closed). The command line's option type
    (:class:`rigcal.cli.types.Real`) and the Python API's keyword checks apply the same
    rule, so the two cannot drift apart."""

    def __init__(
        self,
        min: float | None = None,
        max: float | None = None,
        min_open: bool = False,
        max_open: bool = False,
    ) -> None:
        self.min, self.max, self.min_open, self.max_open = min, max, min_open, max_open

    def describe(self) -> str:
        """The range as click writes it: ``x>=0.1``, ``0.0<x``, ``1e-06<=x<=0.5``."""
        if self.min is None and self.max is None:
            return ""
        if self.min is None:
            return f"x{'<' if self.max_open else '<='}{self.max}"
        if self.max is None:
            return f"x{'>' if self.min_open else '>='}{self.min}"
        return f"{self.min}{'<' if self.min_open else '<='}x{'<' if self.max_open else '<='}{self.max}"

    def holds(self, x: float) -> bool:
        """Whether the finite number ``x`` is within the range."""
        lo = self.min is None or (x > self.min if self.min_open else x >= self.min)
        hi = self.max is None or (x < self.max if self.max_open else x <= self.max)
        return lo and hi

    def check(self, value: Any, where: Where, key: str) -> float:
        """``value`` (a Python number, not text) checked as the option checks its text.

        Raises:
            InputError: ``WHERE: KEY: got VALUE; expected a finite number RANGE``.
        """
        import numpy as np

        expected = f"a finite number {self.describe()}".rstrip()
        if isinstance(value, (bool, np.bool_)) or not isinstance(
            value, (int, float, np.integer, np.floating)
        ):
            raise InputError.at(where, key, value, expected)
        try:
            x = float(value)
        except OverflowError:
            raise InputError.at(where, key, value, expected) from None
        if not math.isfinite(x) or not self.holds(x):
            raise InputError.at(where, key, value, expected)
        return x


class Whole:
    """An integer option's rule, within ``min``..``max`` (both included)."""

    def __init__(self, min: int | None = None, max: int | None = None) -> None:
        self.min, self.max = min, max

    def describe(self) -> str:
        """The range as click writes it: ``x>=0``, ``1<=x<=12``."""
        return Real(self.min, self.max).describe()

    def check(self, value: Any, where: Where, key: str) -> int:
        """``value`` (a Python integer) checked as the option checks its text (booleans,
        floats and text refused).

        Raises:
            InputError: ``WHERE: KEY: got VALUE; expected an integer RANGE``.
        """
        import numpy as np

        expected = f"an integer {self.describe()}".rstrip()
        if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)):
            raise InputError.at(where, key, value, expected)
        n = int(value)
        if (self.min is not None and n < self.min) or (self.max is not None and n > self.max):
            raise InputError.at(where, key, value, expected)
        return n


class OneOf:
    """A choice option's rule: one of ``choices``, exact and case-sensitive."""

    def __init__(self, choices: Sequence[str]) -> None:
        self.choices = tuple(choices)

    def check(self, value: Any, where: Where, key: str) -> str:
        """``value`` checked as the option checks its text.

        Raises:
            InputError: ``WHERE: KEY: got VALUE; expected one of A, B, ...``.
        """
        if not isinstance(value, str) or value not in self.choices:
            raise InputError.at(where, key, value, "one of " + ", ".join(self.choices))
        return value


def flag(value: Any, where: Where, key: str) -> bool:
    """``value`` as a boolean: True or False only (a flag of the command line)."""
    import numpy as np

    if not isinstance(value, (bool, np.bool_)):
        raise InputError.at(where, key, value, "True or False")
    return bool(value)
