"""Stamps of real logs: equal stamps, small backward steps and gaps, repaired by one rule.

Real laser logs break the rule that stamps increase: a log printed with few significant
digits gives neighbouring scans equal stamps; a host clock corrected by NTP steps back a
fraction of a second once; a stamp that is wrong on its own jumps ahead and the next ones
look like a step back. Rule (``stamps="repair"``, the importers' default):

1. The stamps that keep their value are the **longest strictly increasing subsequence**
   of the stamps (of equal stamps, the earliest is kept): the fewest stamps are changed.
2. Every other stamp is placed **evenly between its kept neighbours** (a run of k
   changed stamps between kept stamps a and b: a + j (b - a) / (k + 1), j = 1..k); a run
   after the last kept stamp (or before the first) continues it one scan period apart
   (the kept stamps' mean spacing per scan).
3. A stamp moved by more than ``max_shift_s`` (1 s by default) is not a glitch but a
   broken clock: the import stops, naming the stamp's line.

Gaps (a step longer than :data:`GAP_PERIODS` scan periods: dropped scans, a paused
logger) are counted and reported, not filled: nothing was measured there.

``stamps="strict"`` refuses the first stamp that is not after the previous one, as the
importers did before. The importers print one warning saying how many stamps were
repaired and how (:meth:`StampRepair.message`); docs/formats/sequence.md documents it.
"""

from __future__ import annotations

import bisect
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from rigcal.arrays import FloatArray
from rigcal.errors import InputError

STAMP_MODES = ("repair", "strict")
# A stamp moved further than this (s) by the repair is a broken clock, not a glitch.
MAX_SHIFT_S = 1.0
# A step longer than this many scan periods is a gap (reported).
GAP_PERIODS = 5.0


@dataclass(frozen=True)
class StampRepair:
    """What the repair did: the stamps, and the counts of each case.

    Attributes:
        stamps_s: (N,) strictly increasing stamps.
        equal: stamps equal to the previous kept one (low-precision printing), spread.
        backward: stamps before the previous kept one (a step back, or after a stamp
            that jumped ahead), placed between their neighbours.
        max_shift_s: the largest change made to a stamp (s).
        gaps: steps longer than GAP_PERIODS scan periods (left as they are).
        longest_gap_s: the longest of them (0 without gaps).
        period_s: the scan period (median positive step).
    """

    stamps_s: FloatArray
    equal: int = 0
    backward: int = 0
    max_shift_s: float = 0.0
    gaps: int = 0
    longest_gap_s: float = 0.0
    period_s: float = 0.0

    @property
    def repaired(self) -> int:
        return self.equal + self.backward

    def record(self, mode: str) -> dict[str, Any]:
        """What the repair did, for a sequence's ``source``."""
        return {
            "mode": mode,
            "equal_spread": self.equal,
            "backward_placed": self.backward,
            "max_shift_s": round(self.max_shift_s, 6),
            "gaps": self.gaps,
        }

    def message(self, what: str) -> str | None:
        """The one-line warning about ``what`` (e.g. "scan stamps"), None when nothing
        was repaired and there are no gaps."""
        parts = []
        if self.repaired:
            how = []
            if self.equal:
                how.append(f"{self.equal} equal to the previous one")
            if self.backward:
                how.append(f"{self.backward} stepping back")
            parts.append(
                f"repaired {self.repaired} {what} ({', '.join(how)}): placed evenly between "
                f"their increasing neighbours, moved at most {self.max_shift_s:.3g} s"
            )
        if self.gaps:
            parts.append(
                f"{self.gaps} gap(s) longer than {GAP_PERIODS:g} scan periods "
                f"({self.period_s:.3g} s), the longest {self.longest_gap_s:.3g} s, kept as they are"
            )
        return "; ".join(parts) if parts else None


def repair_stamps(
    stamps_s: FloatArray | list[float] | list[float | None],
    where: str,
    mode: str = "repair",
    lines: NDArray[np.int64] | list[int] | None = None,
    max_shift_s: float = MAX_SHIFT_S,
) -> StampRepair:
    """The stamps made strictly increasing by the module's rule (``mode="repair"``), or
    checked as they are (``mode="strict"``). ``where`` names the file (and the stamp
    field); ``lines`` (N,) gives each stamp's line in it for the error.

    Raises:
        InputError: a stamp that is not finite; in strict mode, a stamp not after the
            previous one; in repair mode, a stamp the repair would move by more than
            ``max_shift_s``.
    """
    t = np.asarray(stamps_s, dtype=float)
    n = len(t)

    def at(i: int) -> str:
        return f"{where}: line {int(lines[i])}" if lines is not None else f"{where}[{i}]"

    if mode not in STAMP_MODES:
        raise InputError.at(None, "--stamps", mode, f"one of {', '.join(STAMP_MODES)}")
    bad = np.flatnonzero(~np.isfinite(t))
    if len(bad):
        raise InputError(f"{at(int(bad[0]))}: got stamp {float(t[bad[0]])!r}; expected a finite stamp (s)")
    steps = np.diff(t)
    period = float(np.median(steps[steps > 0])) if (steps > 0).any() else 0.0
    if mode == "strict" or n < 2 or (steps > 0).all():
        back = np.flatnonzero(steps <= 0)
        if len(back):
            i = int(back[0]) + 1
            raise InputError(
                f"{at(i)}: got stamp {float(t[i])!r}; expected a stamp after the previous one "
                f"{float(t[i - 1])!r} (--stamps repair mends equal stamps and small steps back)"
            )
        return _with_gaps(StampRepair(t.copy(), period_s=period))
    keep = _longest_increasing(t)
    kept = np.zeros(n, dtype=bool)
    kept[keep] = True
    out = t.copy()
    k = np.flatnonzero(kept)
    # Beyond the kept stamps: their mean spacing per scan (a median of printed steps
    # would be the printing's resolution).
    period = float((t[k[-1]] - t[k[0]]) / (k[-1] - k[0])) if len(k) > 1 else period
    for m in np.flatnonzero(~kept):
        j = int(np.searchsorted(k, m))  # kept neighbours k[j - 1] < m < k[j]
        if j == 0:  # before the first kept stamp: one period before it per stamp
            out[m] = t[k[0]] - (k[0] - m) * period
        elif j == len(k):
            out[m] = t[k[-1]] + (m - k[-1]) * period
        else:
            a, b = k[j - 1], k[j]
            out[m] = t[a] + (m - a) * (t[b] - t[a]) / (b - a)
    shift = np.abs(out - t)
    worst: int = int(np.argmax(shift))
    if shift[worst] > max_shift_s:
        raise InputError(
            f"{at(int(worst))}: got stamp {float(t[worst])!r}; expected stamps that increase but for "
            f"glitches of at most {max_shift_s:g} s (repairing it would move it "
            f"{float(shift[worst]):.3g} s: a broken clock)"
        )
    # A changed stamp equal to its kept predecessor came from low-precision printing.
    prev_kept = np.maximum.accumulate(np.where(kept, np.arange(n), -1))
    changed = np.flatnonzero(~kept)
    equal = sum(1 for i in changed if prev_kept[i] >= 0 and t[i] == t[prev_kept[i]])
    return _with_gaps(StampRepair(out, equal, len(changed) - equal, float(shift[worst]), period_s=period))


def _with_gaps(r: StampRepair) -> StampRepair:
    steps = np.diff(r.stamps_s)
    if r.period_s <= 0 or not len(steps):
        return r
    long = steps[steps > GAP_PERIODS * r.period_s]
    return StampRepair(
        r.stamps_s, r.equal, r.backward, r.max_shift_s, len(long), float(long.max(initial=0.0)), r.period_s
    )


def _longest_increasing(t: FloatArray) -> NDArray[np.int64]:
    """Indices of a longest strictly increasing subsequence of t (patience sorting,
    O(N log N)), preferring the earliest stamps where several are as long: run backwards
    as a longest decreasing subsequence, a later (in the file, earlier) stamp replacing an
    equal one."""
    n = len(t)
    tails: list[float] = []  # tails[L]: the smallest last value of an increasing run of L + 1
    tail_at: list[int] = []
    parent = np.full(n, -1, dtype=np.int64)
    for i, v in enumerate((-t[::-1]).tolist()):
        L = bisect.bisect_left(tails, v)
        if len(tails) == L:
            tails.append(v)
            tail_at.append(i)
        else:
            tails[L] = v
            tail_at[L] = i
        parent[i] = tail_at[L - 1] if L > 0 else -1
    out = []
    i = tail_at[-1] if tail_at else -1
    while i >= 0:
        out.append(n - 1 - i)
        i = int(parent[i])
    return np.array(out, dtype=np.int64)


# Seconds since 1970 stay below this until the year 5138; a stamp above it is in another
# unit (Unix milliseconds are about 1.7e12, microseconds 1.7e15, nanoseconds 1.7e18).
MAX_STAMP_S = 1e11
# A laser scans several times a second, and wheel odometry is logged as often; a stream
# whose own steps are this far apart (median) is stamped in another unit (a 10 Hz
# scanner's milliseconds step by 100, a 50 Hz odometry's by 20), not seconds.
MAX_SCAN_PERIOD_S = 10.0
# What each stream's step is, for the message: (its element, the rate it is logged at).
STEPS = {
    "scan": ("a scan", "a laser scans several times a second"),
    "pose": ("a pose", "wheel odometry is logged several times a second"),
    "sample": ("a sample", "a gyroscope is sampled many times a second"),
}
_UNITS = ((3, "milliseconds"), (6, "microseconds"), (9, "nanoseconds"))


def unit_hint(span: float, other_span: float) -> str:
    """ " (one stream in milliseconds, the other in seconds?)" when two streams' time spans
    differ by about 1e3, 1e6 or 1e9 (the other units loggers stamp in), else "". Only a
    hint in the message of streams that do not overlap: a span ratio never refuses a
    stream by itself (odometry logged for an hour beside a minute of scans is real)."""
    if not (span > 0 and other_span > 0):
        return ""
    ratio = abs(float(np.log10(span / other_span)))
    unit = next((name for k, name in _UNITS if abs(ratio - k) < 0.3), None)
    return f" (one stream in {unit}, the other in seconds?)" if unit else ""


def check_increasing(stamps_s: FloatArray, where: str, name: str) -> None:
    """Refuse stamps (N,) that do not increase: the first one at or before its predecessor
    is named ``{name} k``.

    Raises:
        InputError: ``where: {name} k: got T; expected a stamp after the previous one ...``.
    """
    t = np.asarray(stamps_s, dtype=float)
    back = np.flatnonzero(np.diff(t) <= 0)
    if len(back):
        k = int(back[0]) + 1
        raise InputError.at(
            where, f"{name} {k}", float(t[k]), f"a stamp after the previous one {float(t[k - 1])!r}"
        )


def check_overlap(stamps_s: FloatArray, where: str, key: str, scan_stamps_s: FloatArray | None) -> None:
    """Refuse a stream (stamps (N,), increasing) whose time span misses the scans' (given,
    not empty): it is on another clock or in another unit (:func:`unit_hint`).

    Raises:
        InputError: ``where: key: got 'A to B'; expected a span overlapping the scans' ...``.
    """
    if scan_stamps_s is None or not len(scan_stamps_s):
        return
    t = np.asarray(stamps_s, dtype=float)
    lo, hi = float(scan_stamps_s[0]), float(scan_stamps_s[-1])
    if t[-1] < lo or t[0] > hi:
        raise InputError.at(
            where,
            key,
            f"{float(t[0])!r} to {float(t[-1])!r}",
            f"a span overlapping the scans' ({lo!r} to {hi!r}): the same clock"
            + unit_hint(float(t[-1] - t[0]), hi - lo),
        )


def check_seconds(stamps_s: FloatArray, where: str, key: str, step: str | None = None) -> None:
    """Refuse stamps that cannot be seconds, judged by the stream's own stamps: a
    magnitude above :data:`MAX_STAMP_S`, or (``step``: ``"scan"`` for a laser's stamps,
    ``"pose"`` for wheel odometry's, :data:`STEPS`) a median step over
    :data:`MAX_SCAN_PERIOD_S`, naming the unit they look like.

    Raises:
        InputError: ``where: key: got ...; expected seconds ...``.
    """
    t = np.asarray(stamps_s, dtype=float)
    if len(t) and float(np.abs(t).max()) > MAX_STAMP_S:
        big = float(np.abs(t).max())
        unit = next((name for k, name in reversed(_UNITS) if big > 10.0 ** (k + 8)), "another unit")
        raise InputError.at(
            where,
            key,
            big,
            f"seconds (Unix time is about 1.7e9 s; this looks like {unit}: convert to seconds)",
        )
    if step is not None and len(t) > 2:
        period = float(np.median(np.diff(t)))
        if period > MAX_SCAN_PERIOD_S:
            one, rate = STEPS[step]
            raise InputError.at(
                where,
                key,
                f"{one} every {period:g} (median)",
                f"seconds: {rate} (stamps in milliseconds?)",
            )


# Wheel odometry logged less often than this (s, median step) is slow; see
# :func:`check_beside_scans`.
SLOW_POSE_S = 1.0


def check_beside_scans(stamps_s: FloatArray, scan_stamps_s: FloatArray, where: str, key: str) -> None:
    """Refuse wheel odometry stamped in milliseconds from its start and logged faster than
    100 Hz (steps under 10, which :func:`check_seconds` takes for seconds) beside scans
    stamped in seconds. Read as seconds, such odometry is two things at once that real
    odometry is not: logged less than once a second (median step over
    :data:`SLOW_POSE_S`: a 200 Hz logger's 5 ms) **and** over about 1000 times the scans'
    span (:func:`unit_hint`: a minute of driving becomes 17 hours). Either alone is real (a
    slow logger; an hour of odometry around a minute of scans) and is read as it is.

    Raises:
        InputError: ``where: key: got 'a pose every 5 (median) over 59995'; expected ...``.
    """
    t, s = np.asarray(stamps_s, dtype=float), np.asarray(scan_stamps_s, dtype=float)
    if len(t) < 3 or len(s) < 2:
        return
    period = float(np.median(np.diff(t)))
    span, scan_span = float(t[-1] - t[0]), float(s[-1] - s[0])
    if period > SLOW_POSE_S and "milliseconds" in unit_hint(span, scan_span):
        raise InputError.at(
            where,
            key,
            f"a pose every {period:g} (median) over {span:g}",
            f"seconds: wheel odometry is logged several times a second, and over about the scans' "
            f"span ({scan_span:.3g} s), not 1000 times it (stamps in milliseconds from the start?)",
        )


def within_scans(image_stamps_s: FloatArray, scan_stamps_s: FloatArray) -> NDArray[np.bool_]:
    """(M,) whether each image is stamped within the scans' span, give or take one scan
    period (median step): beyond it the laser's pose is not known, so no image method can
    place the image (the rule :func:`outside_scans` counts by)."""
    t, s = np.asarray(image_stamps_s, dtype=float), np.asarray(scan_stamps_s, dtype=float)
    if not len(t) or not len(s):
        return np.ones(len(t), dtype=bool)
    period = float(np.median(np.diff(s))) if len(s) > 1 else 0.0
    return (t >= s[0] - period) & (t <= s[-1] + period)


def outside_scans(image_stamps_s: FloatArray, scan_stamps_s: FloatArray) -> dict[str, int]:
    """How many images are stamped before the first scan and after the last, by more than
    one scan period (:func:`within_scans`): the laser's pose is not known there, so no image
    method can place them (``{"before": n, "after": m}``)."""
    t, s = np.asarray(image_stamps_s, dtype=float), np.asarray(scan_stamps_s, dtype=float)
    out = ~within_scans(t, s)
    if not out.any():
        return {"before": 0, "after": 0}
    return {"before": int((out & (t < s[0])).sum()), "after": int((out & (t > s[-1])).sum())}
