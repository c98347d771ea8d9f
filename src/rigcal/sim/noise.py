"""A realistic model of a real scanner in a real room, for the calibration simulators.

The clean model of :func:`rigcal.sim.raycast.noisy_ranges` (Gaussian range noise, random
dropouts, an empty room moved at random for every capture) is what the accuracy figures
of docs/benchmarks.md are measured on. Real captures differ in ways that break methods
tuned on it:

- range noise is heavy-tailed (a few returns are off by several sigma), with 14-20 mm
  scatter on an RPLidar- or Hokuyo-class scanner at room distances;
- at a depth jump the beam's footprint straddles the edge and the return lands between
  the foreground and the background (a *mixed pixel*);
- grazing beams read long (the footprint smears along the surface) and, at the most
  grazing angles, often return nothing;
- the rig stands still while the target moves, in a room full of static furniture,
  boxes and poles, some as long as the target;
- a board is cut from a larger sheet than its printed pattern.

:class:`RealisticNoise` holds the model's parameters; :func:`realistic_ranges` casts a
scan under it; :func:`clutter_segments` furnishes the room; :func:`fixed_room_pose`
places the still rig in it. ``rigcal simulate board-session --noise realistic`` and
``box-session --noise realistic`` use them.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from rigcal.arrays import FloatArray
from rigcal.sim.raycast import cast_scan_hits
from rigcal.sim.render import Room

NOISE_MODELS = ("clean", "realistic")


@dataclass(frozen=True)
class RealisticNoise:
    """Parameters of the realistic scanner and room.

    Attributes:
        range_scale_m: scale of the Student-t range noise, metres.
        range_dof: its degrees of freedom (> 2; smaller is heavier-tailed). The defaults
            (14 mm, 4) give a standard deviation of 19.8 mm and a robust scatter
            (1.4826 x median absolute deviation) of 15.4 mm.
        mixed_pixel_fraction: share of the beam pairs across a depth jump of which one
            beam returns a mixed pixel, uniform between the two depths.
        depth_jump_m: neighbouring true ranges differing by more than this are a depth jump.
        incidence_bias_m: grazing beams read long by ``incidence_bias_m * (1 / cos(i) - 1)``
            at incidence i (0 head-on), at most ``max_incidence_bias_m``.
        max_incidence_bias_m: the cap of that bias.
        dropout_fraction: share of the returns lost at random.
        grazing_dropout_deg: beams beyond this incidence return nothing half of the time.
        n_clutter: static objects (boxes, cabinets, poles) in the room.
        board_border_m: a simulated board's sheet extends this much beyond its printed
            pattern on every side (the pattern being the inner corners plus one square).
    """

    range_scale_m: float = 0.014
    range_dof: float = 4.0
    mixed_pixel_fraction: float = 0.5
    depth_jump_m: float = 0.1
    incidence_bias_m: float = 0.01
    max_incidence_bias_m: float = 0.05
    dropout_fraction: float = 0.02
    grazing_dropout_deg: float = 80.0
    n_clutter: int = 10
    board_border_m: float = 0.05

    def __post_init__(self) -> None:
        checks = [
            (self.range_scale_m >= 0, "range_scale_m must be >= 0"),
            (self.range_dof > 2, "range_dof must be > 2 (a finite variance)"),
            (0 <= self.mixed_pixel_fraction <= 1, "mixed_pixel_fraction must be in [0, 1]"),
            (self.depth_jump_m > 0, "depth_jump_m must be > 0"),
            (0 <= self.incidence_bias_m <= self.max_incidence_bias_m + 1.0, "bad incidence bias"),
            (0 <= self.dropout_fraction < 1, "dropout_fraction must be in [0, 1)"),
            (0 < self.grazing_dropout_deg <= 90, "grazing_dropout_deg must be in (0, 90]"),
            (self.n_clutter >= 0, "n_clutter must be >= 0"),
            (self.board_border_m >= 0, "board_border_m must be >= 0"),
        ]
        for ok, message in checks:
            if not ok:
                raise ValueError(f"RealisticNoise: {message}")

    @property
    def range_sigma_m(self) -> float:
        """Standard deviation of the range noise (before bias, mixed pixels), metres."""
        return float(self.range_scale_m * np.sqrt(self.range_dof / (self.range_dof - 2.0)))

    def as_dict(self) -> dict[str, Any]:
        """The parameters, for a truth file's generator block."""
        return {k: float(v) if isinstance(v, float) else v for k, v in asdict(self).items()}


def realistic_ranges(
    rng: np.random.Generator,
    segments: ArrayLike,
    angles_rad: FloatArray,
    range_max_m: float,
    noise: RealisticNoise,
    decimals: int = 4,
) -> tuple[FloatArray, NDArray[np.int64]]:
    """Ranges of a scan of ``segments`` as the realistic scanner reports them.

    Args:
        rng: the generator.
        segments: (S, 2, 2) the scene's segments in the laser frame, metres.
        angles_rad: (N,) beam angles.
        range_max_m: the scanner's range.
        noise: the model.
        decimals: ranges are kept to this many places.

    Returns:
        ranges (N,) metres, 0 where no return; hit (N,) the segment each beam's true ray
        hits (-1: none), for the ground truth.
    """
    seg = np.asarray(segments, dtype=float).reshape(-1, 2, 2)
    true, hit = cast_scan_hits(seg, angles_rad, range_max_m)
    n = len(true)
    hits = hit >= 0
    # Incidence: angle between the beam and the surface's normal.
    e = seg[np.maximum(hit, 0), 1] - seg[np.maximum(hit, 0), 0]
    e /= np.linalg.norm(e, axis=1, keepdims=True)
    d = np.column_stack([np.cos(angles_rad), np.sin(angles_rad)])
    cos_inc = np.abs(d[:, 0] * e[:, 1] - d[:, 1] * e[:, 0])
    cos_inc = np.clip(cos_inc, 1e-3, 1.0)
    bias = np.minimum(noise.incidence_bias_m * (1.0 / cos_inc - 1.0), noise.max_incidence_bias_m)
    r = true + np.where(hits, bias, 0.0) + noise.range_scale_m * rng.standard_t(noise.range_dof, size=n)
    # Mixed pixels: one beam of a pair across a depth jump lands between the two surfaces.
    pair = hits[:-1] & hits[1:] & (np.abs(np.diff(np.where(hits, true, 0.0))) > noise.depth_jump_m)
    mixed = np.flatnonzero(pair & (rng.uniform(size=n - 1) < noise.mixed_pixel_fraction))
    which = mixed + (rng.uniform(size=len(mixed)) < 0.5)
    lo, hi = np.minimum(true[mixed], true[mixed + 1]), np.maximum(true[mixed], true[mixed + 1])
    r[which] = lo + rng.uniform(size=len(mixed)) * (hi - lo)
    grazing = cos_inc < np.cos(np.radians(noise.grazing_dropout_deg))
    lost = (rng.uniform(size=n) < noise.dropout_fraction) | (grazing & (rng.uniform(size=n) < 0.5))
    out: FloatArray = np.where(lost | ~hits | ~np.isfinite(r) | (r <= 0), 0.0, np.round(r, decimals))
    return out, hit


def clutter_segments(
    rng: np.random.Generator,
    n: int,
    room_contains: Callable[[FloatArray], bool],
    keep_out: Callable[[FloatArray], bool],
    distance_m: tuple[float, float] = (0.8, 6.0),
) -> FloatArray:
    """Static objects around the rig, as (S, 2, 2) segments in the laser frame.

    A third are poles (5-12 cm square), the rest boxes and cabinets (0.3-1.2 m by
    0.3-0.6 m, some as long as a board's cut), at random places and headings.

    Args:
        rng: the generator.
        n: number of objects.
        room_contains: whether (K, 2) laser-frame points lie inside the room with clearance.
        keep_out: whether (K, 2) points intrude where the target will be placed.
        distance_m: objects' centres lie this far from the laser.
    """
    out: list[FloatArray] = []
    placed: list[FloatArray] = []
    for k in range(n):
        for _ in range(100):
            if k % 3 == 0:
                w = h = rng.uniform(0.05, 0.12)
            else:
                w, h = rng.uniform(0.3, 1.2), rng.uniform(0.3, 0.6)
            dist = rng.uniform(*distance_m)
            bearing = rng.uniform(-np.pi, np.pi)
            centre = dist * np.array([np.cos(bearing), np.sin(bearing)])
            yaw = rng.uniform(-np.pi, np.pi)
            c, s = np.cos(yaw), np.sin(yaw)
            corners = np.array([[-w, -h], [w, -h], [w, h], [-w, h]]) * 0.5 @ np.array([[c, s], [-s, c]])
            corners = corners + centre
            if not room_contains(corners) or keep_out(corners):
                continue
            if any(np.linalg.norm(centre - p) < 0.9 for p in placed):
                continue
            placed.append(centre)
            out.append(np.stack([corners, np.roll(corners, -1, axis=0)], axis=1))
            break
    return np.concatenate(out) if out else np.zeros((0, 2, 2))


# Clutter keeps this far out of the targets' region (metres, radians).
_KEEP_OUT_M, _KEEP_OUT_RAD = 0.6, 0.25


def static_scene(
    rng: np.random.Generator,
    room: Room,
    clearance_m: float,
    bearings_rad: tuple[float, float],
    far_m: float,
    n_clutter: int,
) -> tuple[tuple[float, float, float], FloatArray]:
    """The room of a rig that stays put while its target moves, and its static segments.

    The room holds the laser and the targets' region (bearings within ``bearings_rad``,
    up to ``far_m`` away, with a margin); its pose is drawn once (a random place and
    heading, :meth:`Room.pose_holding`); ``n_clutter`` objects (:func:`clutter_segments`)
    stand anywhere else in it.

    Returns:
        (the room's pose in the laser frame (x, y, yaw), (S, 2, 2) its walls then the
        clutter, laser frame).

    Raises:
        ValueError: the targets' region does not fit in the room.
    """
    lo, hi = bearings_rad[0] - _KEEP_OUT_RAD, bearings_rad[1] + _KEEP_OUT_RAD
    far = far_m + _KEEP_OUT_M
    b = np.linspace(lo, hi, 9)
    region = np.vstack([[0.0, 0.0], far * np.column_stack([np.cos(b), np.sin(b)])])
    room_pose = room.pose_holding(rng, region, clearance_m, tries=200)
    if room_pose is None:
        raise ValueError(f"targets up to {far_m:g} m away do not fit in the room")

    def keep_out(pts: FloatArray) -> bool:
        r = np.linalg.norm(pts, axis=1)
        a = np.arctan2(pts[:, 1], pts[:, 0])
        return bool(np.any(r < _KEEP_OUT_M) or np.any((r < far) & (a > lo) & (a < hi)))

    clutter = clutter_segments(
        rng,
        n_clutter,
        lambda pts: room.contains(room_pose, pts, 0.05),
        keep_out,
        (0.8, 0.5 * min(room.size_m) + far),
    )
    return room_pose, np.concatenate([room.wall_segments(room_pose), clutter])
