"""Pairing streams in time: the stamp nearest a time, and a planar pose interpolated at a
time (the laser odometry at an image's stamp; paper Fig. 7, the sensors are not
synchronised).
"""

from __future__ import annotations

import numpy as np

from rigcal.arrays import FloatArray


def nearest_index(stamps: FloatArray, t: float) -> int:
    """Index of the stamp nearest t (stamps increasing)."""
    k = int(np.searchsorted(stamps, t))
    if k == 0:
        return 0
    if k >= len(stamps):
        return len(stamps) - 1
    return k if stamps[k] - t < t - stamps[k - 1] else k - 1


def pose_at(stamps: FloatArray, poses: FloatArray, t: float) -> FloatArray:
    """A planar pose (x, y, yaw) interpolated linearly at t (yaw unwrapped), held at the ends."""
    yaw = np.unwrap(poses[:, 2])
    return np.array(
        [np.interp(t, stamps, poses[:, 0]), np.interp(t, stamps, poses[:, 1]), np.interp(t, stamps, yaw)]
    )
