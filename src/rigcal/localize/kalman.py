"""Kalman filter fusion of laser and visual odometry (paper Section VI, Eq. (11)).

State S = [x, y, yaw, vx, vy, yaw_rate] (Eq. (11)): the laser's planar pose in the world
and its velocity, world frame. Process model: a constant-velocity particle driven by
white acceleration noise. Measurements: each odometry increment (dx, dy, dyaw) over
[t0, t1], expressed in the rig's frame at t0, becomes a velocity measurement at t1,

    v_world = R(yaw_mid) (dx, dy) / (t1 - t0),   yaw_rate = dyaw / (t1 - t0),

with a fixed covariance given in the rig's frame (forward, cross-track, yaw rate) and
turned into the world frame with the filter's heading. As the paper sets them, ICP's
forward translation and rotation weigh less than visual odometry's, and visual
odometry's cross-track translation weighs less than ICP's (:data:`ICP_SIGMAS`,
:data:`VO_SIGMAS`; documented in docs/localization.md). Beyond the paper, an ICP step
the walls do not constrain (its degeneracy indicator below
:data:`rigcal.localize.odometry.DEGENERATE_BELOW`: along a corridor whose ends are out of
the laser's range) measures no forward speed (:data:`OPEN_FORWARD_SIGMA`): its step
along the corridor is only the motion ICP started from. Likewise a visual odometry run
without a scale (status ``no-scale``: its length is the last measured speed's guess)
measures no forward speed, and a failed run (a constant-velocity guess) measures
nothing and is left out.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from rigcal.geometry import pose_of, se2

FloatArray = NDArray[np.float64]

# 1-sigma velocity measurement noise in the rig's frame: forward (m/s), cross-track (m/s),
# yaw rate (rad/s).
ICP_SIGMAS = (0.10, 0.03, 0.05)
VO_SIGMAS = (0.03, 0.15, 0.02)
# Wheel odometry (beyond the paper): its forward speed is good to a few percent of a
# walking pace, a wheeled base barely slides sideways, and its heading drifts most
# (wheel slip in turns).
WHEEL_SIGMAS = (0.05, 0.02, 0.08)
# Forward speed noise (m/s) of an ICP step the walls do not constrain: in effect none.
OPEN_FORWARD_SIGMA = 10.0


@dataclass(frozen=True)
class Increment:
    """One odometry step: the motion (dx, dy, dyaw) from t0 to t1 in the rig's frame at t0."""

    t0: float
    t1: float
    motion: FloatArray
    sigmas: tuple[float, float, float]


@dataclass(frozen=True)
class KfParams:
    """Process noise: white acceleration (m/s^2) and angular acceleration (rad/s^2)."""

    accel_sigma: float = 0.5
    yaw_accel_sigma: float = 1.0


def increments(
    stamps: FloatArray,
    poses: FloatArray,
    sigmas: tuple[float, float, float],
    open_forward: NDArray[np.bool_] | None = None,
    measured: NDArray[np.bool_] | None = None,
) -> list[Increment]:
    """The steps of an odometry trajectory (poses (N, 3) at stamps (N,)); where
    ``open_forward`` (N,) is True, the step ending there measures no forward speed
    (:data:`OPEN_FORWARD_SIGMA`); where ``measured`` (N,) is False, the step ending there
    was not measured at all (a guess of the odometry's own) and is left out."""
    out = []
    for k in range(1, len(stamps)):
        dt = float(stamps[k] - stamps[k - 1])
        if dt <= 0 or (measured is not None and not measured[k]):
            continue
        local = pose_of(np.linalg.inv(se2(poses[k - 1])) @ se2(poses[k]))
        sig = sigmas
        if open_forward is not None and open_forward[k]:
            sig = (OPEN_FORWARD_SIGMA, sigmas[1], sigmas[2])
        out.append(Increment(float(stamps[k - 1]), float(stamps[k]), local, sig))
    return out


def vo_increments(stamps: FloatArray, poses: FloatArray, statuses: Sequence[str]) -> list[Increment]:
    """Visual odometry's runs as measurements: poses (N, 3) at stamps (N,), and each run's
    status (N - 1,) (:class:`rigcal.localize.vo.VoStep`). A run without a scale
    (``no-scale``: its length is a guess) measures no forward speed; a failed run (a
    constant-velocity guess) measures nothing and is left out."""
    if len(statuses) != len(stamps) - 1:
        raise ValueError(f"{len(statuses)} run statuses for {len(stamps)} poses (expected one per run)")
    status = np.array(["ok", *statuses])  # the first pose ends no run
    guessed, failed = status == "no-scale", status == "failed"
    return increments(stamps, poses, VO_SIGMAS, open_forward=guessed, measured=~failed)


def fuse(measurements: list[Increment], params: KfParams | None = None) -> tuple[FloatArray, FloatArray]:
    """Run the filter over the increments in time order (by their end stamps).

    Returns:
        stamps (M,) and poses (M, 3): the filtered pose after each update, starting with
        the origin at the earliest stamp.
    """
    params = params or KfParams()
    ms = sorted(measurements, key=lambda m: m.t1)
    if not ms:
        return np.zeros(0), np.zeros((0, 3))
    t = min(m.t0 for m in ms)
    x = np.zeros(6)
    P = np.diag([1e-9, 1e-9, 1e-9, 1.0, 1.0, 1.0])
    stamps, poses = [t], [x[:3].copy()]
    H = np.zeros((3, 6))
    H[:, 3:] = np.eye(3)
    for m in ms:
        dt = m.t1 - t
        if dt > 0:
            x, P = _predict(x, P, dt, params)
            t = m.t1
        span = m.t1 - m.t0
        yaw_mid = x[2] - 0.5 * m.motion[2]
        c, s = np.cos(yaw_mid), np.sin(yaw_mid)
        R = np.array([[c, -s], [s, c]])
        z = np.concatenate([R @ m.motion[:2], [m.motion[2]]]) / span
        Rm = np.zeros((3, 3))
        Rm[:2, :2] = R @ np.diag(np.square(m.sigmas[:2])) @ R.T
        Rm[2, 2] = m.sigmas[2] ** 2
        y = z - H @ x
        S = H @ P @ H.T + Rm
        K = P @ H.T @ np.linalg.inv(S)
        x = x + K @ y
        P = (np.eye(6) - K @ H) @ P
        if stamps[-1] == t:
            poses[-1] = x[:3].copy()
        else:
            stamps.append(t)
            poses.append(x[:3].copy())
    return np.array(stamps), np.array(poses)


def _predict(x: FloatArray, P: FloatArray, dt: float, params: KfParams) -> tuple[FloatArray, FloatArray]:
    F = np.eye(6)
    F[:3, 3:] = dt * np.eye(3)
    q = np.array([params.accel_sigma, params.accel_sigma, params.yaw_accel_sigma]) ** 2
    # White-acceleration noise integrated over dt, per axis: [[dt^3/3, dt^2/2], [dt^2/2, dt]].
    Q = np.zeros((6, 6))
    Q[:3, :3] = np.diag(q * dt**3 / 3.0)
    Q[:3, 3:] = Q[3:, :3] = np.diag(q * dt**2 / 2.0)
    Q[3:, 3:] = np.diag(q * dt)
    return F @ x, F @ P @ F.T + Q
