"""The gyroscope: the rig's yaw rate about the laser's z axis, sampled on the scans' clock.

A sequence folder keeps it as ``gyro.csv`` (``stamp_s,yaw_rate_rad_s`` per line: the
IMU's angular velocity rotated into the laser's frame, its z component, rad/s) and
``gyro: {file}`` in sequence.yaml (schema 4; docs/formats/sequence.md). Every source goes
through :func:`checked`: stamps finite and increasing, rates finite, and a time span that
overlaps the scans', else a one-line error naming the file or topic.

Each sample is the mean rate over the period since the sample before (as an IMU's
filtered output or delta angle over its period), so the yaw turned between two stamps
(:meth:`Gyro.yaw_between`) is the rate held back from each stamp to the one before,
integrated; across a gap in the samples (:data:`MAX_GAP_S`) nothing is measured.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from rigcal.arrays import FloatArray
from rigcal.errors import InputError
from rigcal.io.files import csv_fields, read_text, text_lines
from rigcal.io.stamps import check_increasing, check_overlap, check_seconds

# A pause between two samples longer than this (s) and than GAP_PERIODS of the gyro's own
# period (median step) is a gap (a logger paused, a driver restarted): no yaw is taken
# from the gyro across it.
MAX_GAP_S = 0.5
GAP_PERIODS = 5.0
HEADER = "stamp_s,yaw_rate_rad_s"
# A MEMS gyro's full scale is a few thousand deg/s; beyond this (rad/s) a sample is not a
# yaw rate (degrees taken for radians, a counter's raw value).
MAX_RATE_RAD_S = 40.0


@dataclass(frozen=True)
class Gyro:
    """Yaw rate samples (N,) rad/s about the laser's z axis at stamps (N,) s."""

    stamps_s: FloatArray
    rates_rad_s: FloatArray

    def angles(self, at: FloatArray) -> FloatArray:
        """(K,) the yaw turned from the first sample to each stamp of ``at`` (each
        sample's rate over the period ending at its stamp; held at the ends)."""
        s, r = self.stamps_s, self.rates_rad_s
        cum = np.r_[0.0, np.cumsum(r[1:] * np.diff(s))]
        out: FloatArray = np.interp(at, s, cum)
        return out

    def yaw_between(self, stamps_s: FloatArray) -> FloatArray:
        """(K - 1,) the yaw turned from each stamp to the next; NaN for a step outside the
        samples' span or across a gap."""
        t = np.asarray(stamps_s, dtype=float)
        out = np.diff(self.angles(t))
        s = self.stamps_s
        gap = max(MAX_GAP_S, GAP_PERIODS * float(np.median(np.diff(s))))
        gaps = np.r_[0, np.cumsum(np.diff(s) > gap)]
        before = np.clip(np.searchsorted(s, t[:-1], side="right") - 1, 0, len(s) - 1)
        after = np.clip(np.searchsorted(s, t[1:], side="left"), 0, len(s) - 1)
        outside = (t[:-1] < s[0]) | (t[1:] > s[-1])
        out[outside | (gaps[after] > gaps[before])] = np.nan
        return out


def checked(
    stamps_s: FloatArray, rates_rad_s: FloatArray, where: str, scan_stamps_s: FloatArray | None = None
) -> Gyro:
    """A gyro from its stamps (N,) and yaw rates (N,), validated; ``where`` names the file
    or topic it came from.

    Raises:
        InputError: fewer than 2 samples, a stamp or rate that is not finite (or beyond
            :data:`MAX_RATE_RAD_S`), stamps not increasing, or (given the scans' stamps) a
            span that does not overlap theirs.
    """
    t = np.asarray(stamps_s, dtype=float).ravel()
    r = np.asarray(rates_rad_s, dtype=float).ravel()
    if len(t) < 2 or len(r) != len(t):
        raise InputError.at(where, "gyro", f"{len(t)} stamps, {len(r)} rates", "at least 2 gyro samples")
    bad = np.flatnonzero(~np.isfinite(t) | ~np.isfinite(r) | (np.abs(r) > MAX_RATE_RAD_S))
    if len(bad):
        k = int(bad[0])
        raise InputError.at(
            where,
            f"gyro sample {k}",
            [float(t[k]), float(r[k])],
            f"a finite stamp and a yaw rate within +-{MAX_RATE_RAD_S:g} rad/s",
        )
    check_increasing(t, where, "gyro stamp")
    check_seconds(t, where, "gyro stamps", step="sample")
    check_overlap(t, where, "gyro stamps", scan_stamps_s)
    return Gyro(t, r)


def gyro_csv(gyro: Gyro) -> str:
    """The samples as gyro.csv text (full precision)."""
    rows = "".join(
        f"{t!r},{r!r}\n" for t, r in zip(gyro.stamps_s.tolist(), gyro.rates_rad_s.tolist(), strict=True)
    )
    return HEADER + "\n" + rows


def read_gyro_csv(path: str | Path, scan_stamps_s: FloatArray | None) -> Gyro:
    """A gyro.csv file, every line whole, checked (:func:`checked`).

    Raises:
        InputError: a missing file, a wrong header, a line that is not two numbers,
            naming the file and line; or what :func:`checked` refuses.
    """
    text = read_text(path, "gyro file")
    lines = text_lines(text)
    if not lines or ",".join(csv_fields(lines[0])) != HEADER:
        got = lines[0].strip() if lines else ""
        raise InputError.at(path, "line 1", got, f"the header {HEADER!r}")
    t, r = [], []
    for n, line in enumerate(lines[1:], start=2):
        if not line.strip():
            continue
        parts = csv_fields(line)
        try:
            a, b = (float(p) for p in parts)
        except ValueError:
            raise InputError.at(
                path, f"line {n}", line.strip(), "stamp_s,yaw_rate_rad_s: two numbers"
            ) from None
        t.append(a)
        r.append(b)
    return checked(np.array(t), np.array(r), str(path), scan_stamps_s)
