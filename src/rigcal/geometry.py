"""Rigid transforms with frame-carrying names.

``T_a_b`` is a 4x4 homogeneous matrix that maps points from frame b into frame a:
``p_a = T_a_b @ p_b``, so ``T_a_c = T_a_b @ T_b_c``. Rotations are stored on disk as
rotation vectors (axis times angle, radians; mrcal's ``r``). See docs/conventions.md.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike

from rigcal.arrays import FloatArray


def se2(pose: FloatArray) -> FloatArray:
    """(3, 3) homogeneous matrix of a planar pose (x, y, yaw)."""
    x, y, yaw = pose
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([[c, -s, x], [s, c, y], [0.0, 0.0, 1.0]])


def pose_of(M: FloatArray) -> FloatArray:
    """(x, y, yaw) of a (3, 3) homogeneous matrix."""
    return np.array([M[0, 2], M[1, 2], np.arctan2(M[1, 0], M[0, 0])])


def line_intersection(
    p: FloatArray, u: FloatArray, q: FloatArray, v: FloatArray, parallel_below: float = 1e-6
) -> FloatArray | None:
    """(2,) where the plane's lines p + s u and q + t v cross; None when |u x v| is below
    ``parallel_below`` (nearly parallel; u and v unit directions)."""
    den = u[0] * v[1] - u[1] * v[0]
    if abs(den) < parallel_below:
        return None
    d = q - p
    s = (d[0] * v[1] - d[1] * v[0]) / den
    out: FloatArray = p + s * u
    return out


def make_T(R: ArrayLike, t: ArrayLike) -> FloatArray:
    """Homogeneous 4x4 transform from a (3, 3) rotation and a (3,) translation."""
    T = np.eye(4)
    T[:3, :3] = np.asarray(R, dtype=float)
    T[:3, 3] = np.asarray(t, dtype=float)
    return T


def inv_T(T: ArrayLike) -> FloatArray:
    """Inverse of a rigid transform, using R^T rather than a general inverse."""
    T = np.asarray(T, dtype=float)
    R = T[:3, :3]
    t = T[:3, 3]
    return make_T(R.T, -R.T @ t)


def transform_points(T_a_b: ArrayLike, points_b: ArrayLike) -> FloatArray:
    """Apply T_a_b to points.

    Args:
        T_a_b: (4, 4) transform from frame b to frame a.
        points_b: (N, 3) points in frame b, or (N, 2) points in a plane z = 0 of frame b
            (laser points).

    Returns:
        (N, 3) points in frame a.
    """
    T_a_b = np.asarray(T_a_b, dtype=float)
    p = np.atleast_2d(np.asarray(points_b, dtype=float))
    if p.shape[1] == 2:
        p = np.column_stack([p, np.zeros(len(p))])
    out: FloatArray = p @ T_a_b[:3, :3].T + T_a_b[:3, 3]
    return out


def rotvec_to_R(rotvec: ArrayLike) -> FloatArray:
    """(3,) rotation vector (axis * angle, rad) to a (3, 3) rotation matrix (Rodrigues'
    formula; (N, 3) vectors give (N, 3, 3))."""
    w = np.asarray(rotvec, dtype=float)
    if w.shape != (3,):
        from scipy.spatial.transform import Rotation

        out: FloatArray = Rotation.from_rotvec(w).as_matrix()
        return out
    wx, wy, wz = float(w[0]), float(w[1]), float(w[2])
    t2 = wx * wx + wy * wy + wz * wz
    if t2 < 1e-12:  # series: sin(t)/t and (1 - cos(t))/t^2 to second order
        a, b = 1.0 - t2 / 6.0, 0.5 - t2 / 24.0
    else:
        t = math.sqrt(t2)
        a, b = math.sin(t) / t, (1.0 - math.cos(t)) / t2
    return np.array(
        [
            [1.0 - b * (wy * wy + wz * wz), b * wx * wy - a * wz, b * wx * wz + a * wy],
            [b * wx * wy + a * wz, 1.0 - b * (wx * wx + wz * wz), b * wy * wz - a * wx],
            [b * wx * wz - a * wy, b * wy * wz + a * wx, 1.0 - b * (wx * wx + wy * wy)],
        ]
    )


def R_to_rotvec(R: ArrayLike) -> FloatArray:
    """(3, 3) rotation matrix to a (3,) rotation vector (axis * angle, rad)."""
    from scipy.spatial.transform import Rotation

    out: FloatArray = Rotation.from_matrix(np.asarray(R, dtype=float)).as_rotvec()
    return out


def rt_from_T(T: ArrayLike) -> FloatArray:
    """4x4 transform to (6,) [rotation vector (rad), translation]."""
    T = np.asarray(T, dtype=float)
    return np.concatenate([R_to_rotvec(T[:3, :3]), T[:3, 3]])


def rotation_angle_rad(R: ArrayLike) -> float:
    """Angle of a rotation matrix, in [0, pi] radians."""
    R = np.asarray(R, dtype=float)
    # atan2 of sin and cos stays accurate near 0 and pi, where arccos of the trace alone
    # cannot resolve angles below ~1e-8 rad.
    c = (np.trace(R) - 1.0) / 2.0
    s = 0.5 * np.linalg.norm([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    return float(np.arctan2(s, c))


def tangent_delta(T: ArrayLike, T_ref: ArrayLike) -> FloatArray:
    """(6,) [d (rad), e (m)] with R = Exp(d) R_ref, t = t_ref + e: the difference of two
    transforms in the tangent space of rigcal's covariances (docs/conventions.md)."""
    T = np.asarray(T, dtype=float)
    T_ref = np.asarray(T_ref, dtype=float)
    return np.concatenate([R_to_rotvec(T[:3, :3] @ T_ref[:3, :3].T), T[:3, 3] - T_ref[:3, 3]])


def pose_error(T_est: ArrayLike, T_ref: ArrayLike) -> tuple[float, float]:
    """Rotation (deg) and translation (m) difference between two transforms of the same frames."""
    T_est = np.asarray(T_est, dtype=float)
    T_ref = np.asarray(T_ref, dtype=float)
    dR = T_est[:3, :3] @ T_ref[:3, :3].T
    return float(np.degrees(rotation_angle_rad(dR))), float(np.linalg.norm(T_est[:3, 3] - T_ref[:3, 3]))


def random_rotation(rng: np.random.Generator, max_angle_rad: float | None = None) -> FloatArray:
    """A random rotation, uniform on SO(3), or with a uniform angle up to max_angle_rad."""
    if max_angle_rad is None:
        from scipy.spatial.transform import Rotation

        q = rng.normal(size=4)
        out: FloatArray = Rotation.from_quat(q / np.linalg.norm(q)).as_matrix()
        return out
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    return rotvec_to_R(axis * rng.uniform(0.0, max_angle_rad))
