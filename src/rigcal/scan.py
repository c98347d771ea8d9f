"""The 2D laser scan record and its YAML file (docs/formats/scan.md).

A scan is one sweep of a horizontal 2D scanner: beam angles (radians, counter-clockwise
from the laser's +x, strictly increasing) and ranges (metres). Returns that are 0, NaN,
inf, below ``range_min_m`` or at or above ``range_max_m`` are invalid: they are kept in
the record (beam indices stay those of the file) and masked by :attr:`Scan.valid`, never
crashed on. A range of exactly ``range_max_m`` is what drivers (ROS's, CARMEN's, SICK's
and Hokuyo's) write for a beam that saw nothing: one rule, here, for every reader (scan
files, sequences, the importers), so that it never becomes a ring of points at the
scanner's range.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from rigcal.arrays import MAD_TO_SIGMA, FloatArray
from rigcal.errors import InputError
from rigcal.io.files import atomic_write_text, check_keys, get_float, load_yaml
from rigcal.io.validate import is_real, real

# No scanner steps finer than this (a microradian); a smaller step is a broken file, and
# its beams' angles would not increase in floating point.
MIN_ANGLE_INCREMENT_RAD = 1e-6

SCAN_SCHEMA_VERSION = 1
# Versions read: 2 adds the optional ``laser: {clockwise: BOOL}`` mapping.
SCAN_SCHEMA_VERSIONS = (1, 2)


@dataclass(frozen=True, eq=False)
class Scan:
    """One 2D laser scan.

    Attributes:
        angles_rad: (N,) beam angles, radians, laser frame, strictly increasing.
        ranges_m: (N,) measured ranges, metres; invalid returns as they were recorded.
        range_min_m, range_max_m: the scanner's valid range interval, metres.
        stamp_s: time of the scan, seconds (None when unknown).
        angle_increment_rad: the step when the angles are exactly
            ``angles_rad[0] + i * angle_increment_rad`` (set by :meth:`from_uniform`), else None.
    """

    angles_rad: FloatArray
    ranges_m: FloatArray
    range_min_m: float
    range_max_m: float
    stamp_s: float | None = None
    angle_increment_rad: float | None = None

    def __post_init__(self) -> None:
        a = np.array(self.angles_rad, dtype=float).reshape(-1)
        r = np.array(self.ranges_m, dtype=float).reshape(-1)
        if a.shape != r.shape:
            raise ValueError(f"Scan: {len(a)} angles but {len(r)} ranges")
        if len(a) > 1 and not np.all(np.diff(a) > 0):
            raise ValueError("Scan: angles must be strictly increasing")
        if not 0.0 <= self.range_min_m < self.range_max_m:
            raise ValueError("Scan: need 0 <= range_min_m < range_max_m")
        valid, pts = _valid_points(a, r, self.range_min_m, self.range_max_m)
        self._set_arrays(a, r, valid, pts)

    def _set_arrays(self, a: FloatArray, r: FloatArray, valid: NDArray[np.bool_], pts: FloatArray) -> None:
        for x in (a, r, valid, pts):
            x.setflags(write=False)
        object.__setattr__(self, "angles_rad", a)
        object.__setattr__(self, "ranges_m", r)
        object.__setattr__(self, "_valid", valid)
        object.__setattr__(self, "_points", pts)

    @classmethod
    def from_uniform(
        cls,
        angle_min_rad: float,
        angle_increment_rad: float,
        ranges_m: ArrayLike,
        range_min_m: float,
        range_max_m: float,
        stamp_s: float | None = None,
    ) -> Scan:
        """A scan whose beam i points at ``angle_min_rad + i * angle_increment_rad``."""
        r: FloatArray = np.asarray(ranges_m, dtype=float).reshape(-1)
        angles: FloatArray = angle_min_rad + angle_increment_rad * np.arange(len(r), dtype=np.float64)
        return cls(angles, r, range_min_m, range_max_m, stamp_s, float(angle_increment_rad))

    @classmethod
    def _checked(
        cls,
        arrays: tuple[FloatArray, FloatArray, NDArray[np.bool_], FloatArray],
        range_min_m: float,
        range_max_m: float,
        stamp_s: float | None,
        angle_increment_rad: float | None,
    ) -> Scan:
        """A scan of (angles, ranges, valid, points) already checked and computed as
        ``__post_init__`` would (:func:`uniform_scans`)."""
        scan = object.__new__(cls)
        object.__setattr__(scan, "range_min_m", range_min_m)
        object.__setattr__(scan, "range_max_m", range_max_m)
        object.__setattr__(scan, "stamp_s", stamp_s)
        object.__setattr__(scan, "angle_increment_rad", angle_increment_rad)
        scan._set_arrays(*arrays)
        return scan

    @property
    def valid(self) -> NDArray[np.bool_]:
        """(N,) bool: the returns that are finite, > 0 and within [range_min_m, range_max_m)."""
        out: NDArray[np.bool_] = self._valid  # type: ignore[attr-defined]
        return out

    @property
    def points(self) -> FloatArray:
        """(N, 2) metres, laser frame (z = 0): x = r cos(angle), y = r sin(angle); NaN where invalid."""
        out: FloatArray = self._points  # type: ignore[attr-defined]
        return out

    @property
    def step_rad(self) -> float:
        """The median angular step between beams (0 for a single beam)."""
        return float(np.median(np.diff(self.angles_rad))) if len(self.angles_rad) > 1 else 0.0


class ScanArrayError(ValueError):
    """Scan ``index`` of :func:`uniform_scans`' arrays is not a scan: ``key`` names the
    argument at fault."""

    def __init__(self, index: int, key: str, expected: str) -> None:
        super().__init__(f"scan {index}: {key}: expected {expected}")
        self.index = index
        self.key = key
        self.expected = expected


def _valid_points(
    a: FloatArray, r: FloatArray, range_min_m: float | FloatArray, range_max_m: float | FloatArray
) -> tuple[NDArray[np.bool_], FloatArray]:
    """The valid returns (shape of r) and the points (r's shape, 2) of angles a and ranges
    r (any shape; the range limits broadcast against r)."""
    with np.errstate(invalid="ignore"):
        # At range_max: the driver's no return (the module's rule).
        valid = np.isfinite(r) & (r > 0.0) & (r >= range_min_m) & (r < range_max_m)
    # The directions from angles in one range, -pi..pi, whichever range the scan lists
    # them in (0..2pi, say): the same beam gives the same point.
    if (np.abs(a) > np.pi).any():
        a = np.where(a > np.pi, a - 2.0 * np.pi, np.where(a < -np.pi, a + 2.0 * np.pi, a))
    pts = np.empty((*r.shape, 2))
    with np.errstate(invalid="ignore"):  # inf * 0 where a beam has no return
        np.multiply(r, np.cos(a), out=pts[..., 0])
        np.multiply(r, np.sin(a), out=pts[..., 1])
    pts[~valid] = np.nan
    return valid, pts


def uniform_scans(
    angle_min_rad: FloatArray,
    angle_increment_rad: FloatArray,
    ranges_m: FloatArray,
    n_beams: NDArray[np.integer],
    range_min_m: FloatArray,
    range_max_m: FloatArray,
    stamps_s: FloatArray,
    clockwise: bool = False,
) -> list[Scan]:
    """N scans at once, each as ``Scan.from_uniform(angle_min_rad[i],
    angle_increment_rad[i], ranges_m[i, :n_beams[i]], range_min_m[i], range_max_m[i],
    stamps_s[i])`` makes it (and with ``clockwise`` as :func:`counter_clockwise` then
    turns it), bit for bit, with the arithmetic done on (N, B) arrays instead of scan by
    scan: a sequence's thousands of scans read in a fraction of the time. Each scan's
    arrays are rows of those (read-only) arrays.

    Args:
        ranges_m: (N, B) ranges, metres; beams from n_beams[i] on are ignored.
        n_beams: (N,) beams of each scan, 1 to B.
        the rest: (N,) per scan.

    Raises:
        ScanArrayError: a scan whose angles do not increase, or whose range limits are
            not 0 <= range_min_m < range_max_m (the first such scan).
    """
    r_all = np.asarray(ranges_m, dtype=float)
    width = r_all.shape[1]
    nb = np.asarray(n_beams, dtype=np.int64)
    lo, hi = np.asarray(range_min_m, dtype=float), np.asarray(range_max_m, dtype=float)
    step = np.asarray(angle_increment_rad, dtype=float)
    a0 = np.asarray(angle_min_rad, dtype=float)
    beam = np.arange(width, dtype=np.float64)
    inside = beam[None, :] < nb[:, None]
    if clockwise:  # counter_clockwise(): the beams reversed, from -(the last angle)
        first = -(a0 + step * beam[0] + step * (nb - 1))
        src = np.clip(nb[:, None] - 1 - np.arange(width)[None, :], 0, width - 1)
        r_all, a0 = np.where(inside, np.take_along_axis(r_all, src, axis=1), np.nan), first
    bad = np.flatnonzero(~((lo >= 0.0) & (lo < hi)))
    if len(bad):
        raise ScanArrayError(int(bad[0]), "range_min_m", "0 <= range_min_m < range_max_m")
    a = a0[:, None] + step[:, None] * beam[None, :]
    rising = (np.diff(a, axis=1) > 0) | ~inside[:, 1:]
    bad = np.flatnonzero(~rising.all(axis=1))
    if len(bad):
        raise ScanArrayError(
            int(bad[0]), "angle_increment_rad", "a step that makes the beams' angles increase (rad)"
        )
    r = np.array(r_all, dtype=float)  # a copy the scans own (as Scan's own copy)
    valid, pts = _valid_points(a, r, lo[:, None], hi[:, None])
    valid &= inside
    pts[~inside] = np.nan
    stamps = np.asarray(stamps_s, dtype=float)
    return [
        Scan._checked(
            (a[i, :k], r[i, :k], valid[i, :k], pts[i, :k]),
            float(lo[i]),
            float(hi[i]),
            float(stamps[i]),
            float(step[i]),
        )
        for i, k in enumerate(nb.tolist())
    ]


# --- file ------------------------------------------------------------------------------------
def read_scan(path: str | Path) -> Scan:
    """Read and validate a scan file (docs/formats/scan.md).

    Raises:
        InputError: missing or unreadable file, malformed YAML, unknown or missing keys,
            wrong types, angles not strictly increasing, or lengths that disagree.
    """
    path = Path(path)
    if path.suffix.lower() == ".pcd":
        return read_pcd(path)
    data = load_yaml(path, "scan file")
    d = check_keys(
        data,
        path,
        "",
        ["schema_version", "range_min_m", "range_max_m", "ranges_m"],
        ["stamp_s", "frame", "angle_min_rad", "angle_increment_rad", "angles_rad", "laser"],
        SCAN_SCHEMA_VERSIONS,
    )
    clockwise = laser_clockwise(d, path, SCAN_SCHEMA_VERSIONS)
    if "frame" in d and d["frame"] != "laser":
        raise InputError.at(path, "frame", d["frame"], "'laser'")
    range_min = get_float(d, "range_min_m", path)
    range_max = get_float(d, "range_max_m", path, positive=True)
    if not 0.0 <= range_min < range_max:
        raise InputError.at(path, "range_min_m", range_min, f"a number in [0, range_max_m = {range_max:g})")
    ranges = _ranges(d["ranges_m"], path)
    stamp = get_float(d, "stamp_s", path) if "stamp_s" in d else None
    uniform = "angle_min_rad" in d or "angle_increment_rad" in d
    if uniform == ("angles_rad" in d):
        raise InputError(
            f"{path}: angles: expected either angle_min_rad and angle_increment_rad, or angles_rad (not both)"
        )
    if uniform:
        for key in ("angle_min_rad", "angle_increment_rad"):
            if key not in d:
                raise InputError(f"{path}: {key}: missing; angle_min_rad needs angle_increment_rad")
        a0 = real(d["angle_min_rad"], path, "angle_min_rad", lo=-2 * math.pi, hi=2 * math.pi)
        step_given = d["angle_increment_rad"]
        if is_real(step_given) and float(step_given) < 0:  # a ROS LaserScan sweeping clockwise
            raise InputError.at(
                path,
                "angle_increment_rad",
                float(step_given),
                f"a step > 0 (a scanner sweeping clockwise: angle_min_rad {-a0:g} and angle_increment_rad "
                f"{-float(step_given):g}, negated, with schema_version: 2 and laser: {{clockwise: true}})",
            )
        step = real(
            d["angle_increment_rad"], path, "angle_increment_rad", lo=MIN_ANGLE_INCREMENT_RAD, hi=2 * math.pi
        )
        scan = Scan.from_uniform(a0, step, ranges, range_min, range_max, stamp)
        return counter_clockwise(scan) if clockwise else scan
    angles = _finite_list(d["angles_rad"], path, "angles_rad")
    if len(angles) != len(ranges):
        raise InputError.at(
            path, "angles_rad", f"{len(angles)} angles", f"one angle per range ({len(ranges)})"
        )
    bad = np.flatnonzero(np.diff(angles) <= 0)
    if len(bad):
        i = int(bad[0]) + 1
        raise InputError.at(path, f"angles_rad[{i}]", float(angles[i]), f"an angle > angles_rad[{i - 1}]")
    scan = Scan(angles, ranges, range_min, range_max, stamp)
    return counter_clockwise(scan) if clockwise else scan


def read_pcd(path: str | Path) -> Scan:
    """A PCD file's sweep as a scan (:mod:`rigcal.io.pcd`; docs/formats/scan.md): each
    return at its own angle atan2(y, x), ordered counter-clockwise, no-return points
    (stored as 0 0 0) kept as invalid beams in their place; no range limits beyond the
    data's (range_min_m 0, range_max_m inf).

    Raises:
        InputError: a malformed PCD file (:func:`rigcal.io.pcd.read_pcd_scan`).
    """
    from rigcal.io.pcd import read_pcd_scan

    pcd = read_pcd_scan(path)
    return Scan(pcd.angles_rad, pcd.ranges_m, 0.0, math.inf)


def laser_clockwise(d: Any, path: Path, versions: tuple[int, ...], since: int | None = None) -> bool:
    """Check ``schema_version`` (one of ``versions``; ``since``, by default the last, adds
    ``laser``) and return the file's ``laser.clockwise`` (False when absent).

    Raises:
        InputError: a version not read, ``laser`` in a version that does not define it, or
            ``laser`` not a mapping ``{clockwise: true|false}``.
    """
    v = d["schema_version"]
    if type(v) is not int or v not in versions:
        expected = ", ".join(str(x) for x in versions)
        raise InputError.at(path, "schema_version", v, f"one of {expected} (the versions this rigcal reads)")
    if "laser" not in d:
        return False
    since = versions[-1] if since is None else since
    if v < since:
        need = f"no laser key in schema_version {v} (laser needs {since})"
        raise InputError.at(path, "laser", d["laser"], need)
    laser = check_keys(d["laser"], path, "laser", [], ["clockwise"])
    cw = laser.get("clockwise", False)
    if not isinstance(cw, bool):
        raise InputError.at(path, "laser.clockwise", cw, "true (angles grow clockwise) or false")
    return cw


def counter_clockwise(scan: Scan) -> Scan:
    """A scan whose angles were measured clockwise (looking down on the scanner), as the
    counter-clockwise scan of the same returns: angles negated and the beams reversed, so
    that angles still increase. Beam i of the result is beam N - 1 - i of the input."""
    ranges = scan.ranges_m[::-1]
    step = scan.angle_increment_rad
    if step is not None:
        first = -(float(scan.angles_rad[0]) + step * (len(ranges) - 1))
        return Scan.from_uniform(first, step, ranges, scan.range_min_m, scan.range_max_m, scan.stamp_s)
    return Scan(-scan.angles_rad[::-1], ranges, scan.range_min_m, scan.range_max_m, scan.stamp_s)


def _ranges(value: Any, path: Path) -> FloatArray:
    """ranges_m: a non-empty list of numbers; .nan and .inf are allowed (invalid returns)."""
    if not isinstance(value, list) or not value:
        raise InputError.at(path, "ranges_m", value, "a non-empty list of ranges in metres")
    for i, x in enumerate(value):
        if isinstance(x, bool) or not isinstance(x, (int, float)) or (isinstance(x, int) and not is_real(x)):
            raise InputError.at(path, f"ranges_m[{i}]", x, "a number (0, .nan or .inf for no return)")
        if x < 0:
            raise InputError.at(path, f"ranges_m[{i}]", x, "a range >= 0")
    return np.array(value, dtype=float)


def _finite_list(value: Any, path: Path, key: str) -> FloatArray:
    if not isinstance(value, list) or not value:
        raise InputError.at(path, key, value, "a non-empty list of numbers")
    for i, x in enumerate(value):
        if not is_real(x):
            raise InputError.at(path, f"{key}[{i}]", x, "a finite number")
    return np.array(value, dtype=float)


def _num(x: float) -> str:
    """A float as YAML that reads back to the same float (repr round-trips)."""
    if math.isnan(x):
        return ".nan"
    if math.isinf(x):
        return ".inf" if x > 0 else "-.inf"
    text = repr(float(x))
    # YAML 1.1 reads an exponent form without a '.' (repr's 1e-05, 1e+16) as a string.
    return text if "." in text else text.replace("e", ".0e")


def scan_to_text(scan: Scan) -> str:
    """The YAML text of a scan file; every number reads back bit for bit."""
    lines = ["# rigcal scan (docs/formats/scan.md)", f"schema_version: {SCAN_SCHEMA_VERSION}", "frame: laser"]
    if scan.stamp_s is not None:
        lines.append(f"stamp_s: {_num(scan.stamp_s)}")
    step = scan.angle_increment_rad
    if step is not None:
        lines += [f"angle_min_rad: {_num(scan.angles_rad[0])}", f"angle_increment_rad: {_num(step)}"]
    else:
        lines.append("angles_rad: [" + ", ".join(_num(a) for a in scan.angles_rad) + "]")
    lines += [
        f"range_min_m: {_num(scan.range_min_m)}",
        f"range_max_m: {_num(scan.range_max_m)}",
        "ranges_m: [" + ", ".join(_num(r) for r in scan.ranges_m) + "]",
    ]
    return "\n".join(lines) + "\n"


def write_scan(path: str | Path, scan: Scan, force: bool = False) -> Path:
    """Write a scan file atomically (refuses to overwrite unless ``force``)."""
    return atomic_write_text(path, scan_to_text(scan), force=force)


# --- still moments -----------------------------------------------------------------------------
# A return is left out of its beam's mean when it lies farther than this many robust sigmas
# from the beam's median (and farther than STILL_FLOOR_M): a mixed pixel flickering to the
# background, a heavy-tailed outlier.
STILL_OUTLIER_SIGMAS = 4.0
STILL_FLOOR_M = 0.002


def mean_scan(scans: list[Scan]) -> Scan:
    """The per-beam robust mean of scans taken while nothing moved (one still moment).

    Independent range noise averages down over the K scans (by sqrt(K)); what every scan
    repeats (a range bias by incidence, a mixed pixel that stays mixed) does not, and the
    mean keeps it, so a line fitted to the mean's returns shows the noise left. Per beam:
    the median of its valid returns, the returns farther from it than STILL_OUTLIER_SIGMAS
    robust sigmas (the scan's pooled median absolute deviation about the beams' medians,
    times 1.4826; at least STILL_FLOOR_M) left out, the mean of the others. A beam is
    valid in the mean when at least half of the scans gave it a kept return; otherwise
    its range is NaN. One scan is returned as it is.

    Raises:
        ValueError: no scans, or scans whose beams differ (angles or range limits).
    """
    if not scans:
        raise ValueError("mean_scan: no scans")
    first = scans[0]
    if len(scans) == 1:
        return first
    for s in scans[1:]:
        if (
            s.angles_rad.shape != first.angles_rad.shape
            or not np.allclose(s.angles_rad, first.angles_rad, atol=1e-9)
            or s.range_min_m != first.range_min_m
            or s.range_max_m != first.range_max_m
        ):
            raise ValueError("mean_scan: the scans' beams differ (angles or range limits)")
    R = np.array([np.where(s.valid, s.ranges_m, np.nan) for s in scans])
    ok = np.isfinite(R)
    any_ok = ok.any(axis=0)
    med = np.full(R.shape[1], np.nan)
    med[any_ok] = np.nanmedian(R[:, any_ok], axis=0)
    dev = np.abs(R - med)
    spread = dev[ok & (ok.sum(axis=0) >= 3)]
    sigma = MAD_TO_SIGMA * float(np.median(spread)) if len(spread) else 0.0
    keep = ok & (dev <= max(STILL_OUTLIER_SIGMAS * sigma, STILL_FLOOR_M))
    n = keep.sum(axis=0)
    mean = np.where(n > 0, np.where(keep, R, 0.0).sum(axis=0) / np.maximum(n, 1), np.nan)
    mean[n < 0.5 * len(scans)] = np.nan
    stamps = [s.stamp_s for s in scans if s.stamp_s is not None]
    return Scan(
        first.angles_rad,
        mean,
        first.range_min_m,
        first.range_max_m,
        float(np.mean(stamps)) if stamps else None,
        first.angle_increment_rad,
    )
