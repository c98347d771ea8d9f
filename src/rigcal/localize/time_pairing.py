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


def pose_at(stamps: FloatArray, poses: FloatArray, t: float, *, unwrapped: bool = False) -> FloatArray:
    """A planar pose (x, y, yaw) interpolated linearly at t (yaw unwrapped), held at the ends.
    ``unwrapped``: the poses' yaw is unwrapped already (saves unwrapping all of them per call)."""
    yaw = poses[:, 2] if unwrapped else np.unwrap(poses[:, 2])
    return np.array(
        [np.interp(t, stamps, poses[:, 0]), np.interp(t, stamps, poses[:, 1]), np.interp(t, stamps, yaw)]
    )


def poses_at(stamps: FloatArray, poses: FloatArray, t: FloatArray) -> FloatArray:
    """(M, 3) the planar poses interpolated as :func:`pose_at` at each of the times t (M,)."""
    yaw = np.unwrap(poses[:, 2])
    return np.column_stack(
        [np.interp(t, stamps, poses[:, 0]), np.interp(t, stamps, poses[:, 1]), np.interp(t, stamps, yaw)]
    )
