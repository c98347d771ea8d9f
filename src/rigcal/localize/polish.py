"""The joint polish of an image step and its keyframes (beyond the paper).

The paper ends each step with RANSAC's winner; IASM and H-IASM here fit it by least
squares (Eq. (4)) to the winner's inlier correspondences
(:func:`rigcal.localize.iasm.robust_motion`) and then, by default, :func:`joint_polish`
fits the laser's point-to-line alignment and the correspondences together: the walls
make the motion precise where the scene's geometry constrains it, the correspondences
hold it where it does not (along a corridor), each weighted by the Cauchy weight of its
residual (:func:`match_weights`). It aligns scan t+1 with a keyframe's scan
(:func:`keyframe_reference`, a new keyframe by :func:`new_keyframe`) rather than scan
t's, so that the laser's heading error does not add up step by step
(``benchmarks/bench_matching.py``, part 3).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from rigcal.arrays import MAD_TO_SIGMA, FloatArray
from rigcal.geometry import pose_of, se2
from rigcal.localize.line_normals import pairing_normals

if TYPE_CHECKING:
    from rigcal.localize.iasm import Frame, IasmParams


@dataclass(frozen=True)
class LaserReference:
    """The returns, and their line normals (NaN off a line), that the joint polish aligns
    scan t+1 with, in the frame of scan t: scan t's own, or a keyframe's
    (:func:`keyframe_reference`)."""

    points: FloatArray
    normals: FloatArray


def keyframe_reference(key: Frame, T_key_t: FloatArray) -> LaserReference:
    """A keyframe's returns and line normals in the frame of scan t, from T_key_t (3, 3):
    the pose of scan t in the keyframe's frame."""
    T = np.linalg.inv(T_key_t)
    return LaserReference(key.points @ T[:2, :2].T + T[:2, 2], key.normals @ T[:2, :2].T)


def joint_polish(
    pose: FloatArray,
    a: FloatArray,
    b: FloatArray,
    scan1: FloatArray,
    scan2: FloatArray,
    params: IasmParams,
    normals1: FloatArray | None = None,
    prior: FloatArray | None = None,
) -> FloatArray:
    """Gauss-Newton on the scans' point-to-line alignment and the image correspondences
    together, from the RANSAC winner: the laser makes the motion precise where the scene's
    geometry constrains it, the correspondences hold it where it does not (along a
    corridor), each weighted by its noise (``sigma_laser_m``, ``sigma_match_m``).

    ``normals1``: scan 1's normals from its lines (NaN off a line: such returns are not
    paired), as the laser odometry uses them (:mod:`rigcal.localize.line_normals`); without it, or
    with too few returns on a line, nearest-neighbour normals. ``prior``: a motion the
    result is held to within ``fallback_sigma_m`` and ``fallback_sigma_deg`` (the laser
    odometry's, when a step falls back to it).
    """
    from scipy.spatial import cKDTree

    tree = cKDTree(scan1)
    normals, usable = pairing_normals(scan1, tree, 5, normals1)
    x = np.asarray(pose, dtype=float).copy()
    for _ in range(5):
        c, s = np.cos(x[2]), np.sin(x[2])
        R = np.array([[c, -s], [s, c]])
        moved = scan2 @ R.T + x[:2]
        d, idx = tree.query(moved, distance_upper_bound=params.truncate_m)
        ok = np.isfinite(d)
        if usable is not None:
            ok[ok] &= usable[idx[ok]]
        src, n = moved[ok], normals[idx[ok]]
        res_l = np.einsum("ij,ij->i", n, src - scan1[idx[ok]])
        if params.laser_reject_m > 0:
            # A return paired with the wrong wall (across a corner, an opening) lies
            # decimetres off that wall's line, and a few of them turn the scan.
            keep = np.abs(res_l) < params.laser_reject_m
            src, n, res_l = src[keep], n[keep], res_l[keep]
        r_l = res_l / params.sigma_laser_m
        J_l = np.column_stack([n[:, 0], n[:, 1], n[:, 1] * src[:, 0] - n[:, 0] * src[:, 1]])
        J_l /= params.sigma_laser_m
        cb = b @ R.T + x[:2]
        w = np.repeat(match_weights(cb - a, params.match_cauchy), 2) / params.sigma_match_m
        r_c = (cb - a).ravel() * w
        J_c = np.zeros((2 * len(b), 3))
        J_c[0::2, 0] = 1.0
        J_c[1::2, 1] = 1.0
        J_c[0::2, 2] = -cb[:, 1]
        J_c[1::2, 2] = cb[:, 0]
        J_c *= w[:, None]
        J = np.vstack([J_l, J_c])
        r = np.concatenate([r_l, r_c])
        if prior is not None:
            # A weak pull towards the prior motion keeps what the walls leave open.
            w = np.array(
                [params.fallback_sigma_m, params.fallback_sigma_m, np.radians(params.fallback_sigma_deg)]
            )
            J_p = np.array([[1.0, 0.0, -x[1]], [0.0, 1.0, x[0]], [0.0, 0.0, 1.0]]) / w[:, None]
            J = np.vstack([J, J_p])
            r = np.concatenate([r, (x - prior) / w])
        step = -np.linalg.solve(J.T @ J + 1e-9 * np.eye(3), J.T @ r)
        x = pose_of(se2(step) @ se2(x))
        if np.hypot(step[0], step[1]) < 1e-5 and abs(step[2]) < 1e-6:
            break
    return x


def match_weights(e: FloatArray, c: float) -> FloatArray:
    """Square roots of the Cauchy weights of correspondence residuals e (N, 2), 1 / (1 +
    (|e| / (c s))^2) with s their robust scatter (1.4826 x the median |e|, over at least 8;
    ones with ``c`` 0 or fewer): the inliers' tails (far returns on walls seen at a
    slant) lean to one side and would shift the motion along a corridor."""
    n = np.linalg.norm(e, axis=1)
    if c <= 0 or len(n) < 8:
        return np.ones(len(n))
    s = max(MAD_TO_SIGMA * float(np.median(n)), 1e-4)
    out: FloatArray = 1.0 / np.sqrt(1.0 + (n / (c * s)) ** 2)
    return out


def new_keyframe(T_key_t: FloatArray, params: IasmParams) -> bool:
    """Whether frame t (pose T_key_t in the keyframe's frame) starts a new keyframe: it
    is more than ``keyframe_m`` or ``keyframe_deg`` from the keyframe (always, with
    ``keyframe_m`` 0)."""
    return bool(
        params.keyframe_m <= 0
        or np.hypot(T_key_t[0, 2], T_key_t[1, 2]) > params.keyframe_m
        or abs(np.degrees(np.arctan2(T_key_t[1, 0], T_key_t[0, 0]))) > params.keyframe_deg
    )
