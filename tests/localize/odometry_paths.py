"""Synthetic drives and odometries with known errors, for the Kalman filter's tests."""

from __future__ import annotations

import numpy as np

from rigcal.geometry import pose_of, se2


def line(n, dt, v=0.5):
    """A straight drive along x at v m/s: stamps (n,), poses (n, 3)."""
    t = np.arange(n) * dt
    return t, np.column_stack([v * t, np.zeros(n), np.zeros(n)])


def with_errors(poses, errors):
    """Odometry whose step k (ending at pose k + 1) errs by errors[k] (3,) in its frame."""
    out = [poses[0]]
    for k in range(1, len(poses)):
        step = pose_of(np.linalg.inv(se2(poses[k - 1])) @ se2(poses[k])) + errors[k - 1]
        out.append(pose_of(se2(out[-1]) @ se2(step)))
    return np.array(out)
