"""2D laser ray casting against line segments (room walls, the box's footprint).

Beams leave the laser's origin in its scan plane at angles counter-clockwise from +x; each
returns the range of the nearest segment it crosses (docs/conventions.md).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from rigcal.arrays import FloatArray

# Beams closer to parallel with a segment than this (|sin| of the angle between them)
# graze it and do not return from it.
_PARALLEL_EPS = 1e-12


def cast_scan(segments: ArrayLike, angles_rad: ArrayLike, range_max_m: float) -> FloatArray:
    """Ranges of beams from the origin against segments, nearest hit per beam.

    Vectorised over beams and segments (an (N, S) problem; fine for thousands of beams
    against tens of segments).

    Args:
        segments: (S, 2, 2) segments ``[[x0, y0], [x1, y1]]`` in the laser frame, metres.
        angles_rad: (N,) beam angles, radians, counter-clockwise from the laser's +x.
        range_max_m: hits farther than this do not return.

    Returns:
        (N,) ranges in metres; ``inf`` where a beam hits nothing within ``range_max_m``.
    """
    return cast_scan_hits(segments, angles_rad, range_max_m)[0]


def cast_scan_hits(
    segments: ArrayLike, angles_rad: ArrayLike, range_max_m: float
) -> tuple[FloatArray, NDArray[np.int64]]:
    """Like :func:`cast_scan`, also saying which segment each beam hit.

    Returns:
        ranges: (N,) metres, ``inf`` where nothing is hit within ``range_max_m``.
        hit: (N,) index of the segment hit, -1 where none.
    """
    seg = np.asarray(segments, dtype=float).reshape(-1, 2, 2)
    a = np.asarray(angles_rad, dtype=float).ravel()
    if len(seg) == 0:
        return np.full(len(a), np.inf), np.full(len(a), -1, dtype=np.int64)
    d = np.stack([np.cos(a), np.sin(a)], axis=1)[:, None, :]  # (N, 1, 2)
    p = seg[None, :, 0, :]  # (1, S, 2)
    e = seg[None, :, 1, :] - p  # (1, S, 2)
    # Beam t d meets segment p + s e where t d - s e = p; 2D cross products solve it.
    den = _cross(d, e)  # (N, S)
    ok = np.abs(den) > _PARALLEL_EPS * np.linalg.norm(e, axis=-1)
    safe = np.where(ok, den, 1.0)
    t = _cross(p, e) / safe
    s = _cross(p, d) / safe
    hit = ok & (t > 0.0) & (s >= 0.0) & (s <= 1.0) & (t <= range_max_m)
    t = np.where(hit, t, np.inf)
    nearest = np.argmin(t, axis=1)
    r: FloatArray = t[np.arange(len(a)), nearest]
    index = np.where(np.isfinite(r), nearest, -1).astype(np.int64)
    return r, index


def _cross(a: FloatArray, b: FloatArray) -> FloatArray:
    out: FloatArray = a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]
    return out


def beam_angles(fov_deg: float, increment_deg: float) -> tuple[float, float, FloatArray]:
    """Beams of a scanner whose field of view is symmetric about its +x, both ends included.

    Returns:
        (first angle, step, (N,) angles), radians.
    """
    step = float(np.radians(increment_deg))
    n = round(fov_deg / increment_deg) + 1
    first = -0.5 * step * (n - 1)
    angles: FloatArray = first + step * np.arange(n, dtype=np.float64)
    return first, step, angles


def noisy_ranges(
    rng: np.random.Generator, ranges: FloatArray, sigma_m: float, dropout_fraction: float, decimals: int = 4
) -> FloatArray:
    """Ranges as a scanner reports them: Gaussian noise, returns lost at random, kept to
    ``decimals`` places; lost returns and beams that hit nothing read 0 (invalid)."""
    noisy = ranges + rng.normal(0.0, sigma_m, size=len(ranges))
    lost = rng.uniform(size=len(ranges)) < dropout_fraction
    out: FloatArray = np.where(lost | ~np.isfinite(noisy), 0.0, np.round(noisy, decimals))
    return out
