"""The covariance of an ICP step (paper Eq. (4)'s Gauss-Newton Hessian at the solution, the
residuals' robust spread), inflated along a direction the scans do not constrain; the
Kalman filter's laser input (Section VI, Eq. (11)).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

from rigcal.arrays import MAD_TO_SIGMA, FloatArray

# icp_covariance: 1-sigma (m) of the translation along a direction the scans do not
# constrain, and the least residual 1-sigma (m) it takes (a noise-free scan).
OPEN_SIGMA_M = 10.0


COVARIANCE_SIGMA_FLOOR_M = 1e-4


def icp_covariance(
    model: FloatArray,
    data: FloatArray,
    pose: FloatArray,
    nearest: NDArray[np.intp],
    normals: FloatArray | None,
    reject_m: float,
    open_below: float,
) -> FloatArray:
    """The covariance (3, 3) of ICP's T_model_data (x m, y m, yaw rad) at its solution
    ``pose``: the Gauss-Newton Hessian of Eq. (4)'s cost (point-to-line: the residuals
    n . (R d + t - m) along the model's ``normals`` (M, 2), NaN off a line; point-to-point
    without them) over the inlier pairs (each data point and its ``nearest`` model point,
    pairs farther apart than max(``reject_m``, 3 x median) left out, as ICP leaves them),

        Sigma = sigma^2 (J^T J)^-1,   sigma = 1.4826 MAD(residuals)  (robust),

    inflated along a direction the scans do not constrain: when the translation block of
    J^T J has its smaller eigenvalue below ``open_below`` times its larger (the
    degeneracy indicator of :func:`icp`; a corridor whose ends are out of reach), the
    translation along that eigenvector gets 1-sigma OPEN_SIGMA_M, for ICP's step along it
    is only its initial guess. NaN (3, 3) with fewer than 3 pairs."""
    out = np.full((3, 3), np.nan)
    c, s = math.cos(pose[2]), math.sin(pose[2])
    moved = data @ np.array([[c, s], [-s, c]]) + pose[:2]
    m = model.take(nearest, axis=0)
    diff = moved - m
    dist = np.hypot(diff[:, 0], diff[:, 1])
    keep = dist < max(reject_m, 3.0 * float(np.median(dist))) if len(dist) else dist > 0
    # d(R(yaw) d + t) / d yaw = perp(R d) = (-(y - ty), x - tx).
    arm = np.column_stack([-(moved[:, 1] - pose[1]), moved[:, 0] - pose[0]])
    if normals is not None:
        n = normals.take(nearest, axis=0)
        keep &= np.isfinite(n[:, 0])
        n, arm, diff = n[keep], arm[keep], diff[keep]
        J = np.column_stack([n, np.einsum("ij,ij->i", n, arm)])
        r = np.einsum("ij,ij->i", n, diff)
    else:
        arm, diff = arm[keep], diff[keep]
        ones, zeros = np.ones(len(arm)), np.zeros(len(arm))
        J = np.vstack([np.column_stack([ones, zeros, arm[:, 0]]), np.column_stack([zeros, ones, arm[:, 1]])])
        r = diff.T.ravel()
    if len(arm) < 3:  # pairs
        return out
    sigma = _residual_sigma(model, normals, moved[keep], nearest[keep], r)
    info = J.T @ J
    w, v = np.linalg.eigh(info[:2, :2])
    weak = np.zeros((3, 3))
    if w[1] <= 0 or w[0] < open_below * w[1]:
        e = np.array([v[0, 0], v[1, 0], 0.0])
        weak = OPEN_SIGMA_M**2 * np.outer(e, e)
        # The unconstrained direction out of the Hessian before its inversion.
        info = info + (w[1] if w[1] > 0 else 1.0) * np.outer(e, e)
    try:
        cov = sigma**2 * np.linalg.inv(info)
    except np.linalg.LinAlgError:
        return out
    return 0.5 * (cov + cov.T) + weak


def _mad_sigma(r: FloatArray) -> float:
    """1.4826 x the median absolute deviation: a robust 1-sigma."""
    return MAD_TO_SIGMA * float(np.median(np.abs(r - np.median(r)))) if len(r) else 0.0


def _residual_sigma(
    model: FloatArray, normals: FloatArray | None, moved: FloatArray, pairs: NDArray[np.intp], r: FloatArray
) -> float:
    """The 1-sigma of a residual n . (R d + t - m): with line normals (one normal per line,
    shared by its returns), the data returns' spread about the model's lines (each line's
    offset the mean n . m of its returns) and the model returns' own, added in quadrature;
    a residual's spread about its nearest model return would understate both, for the
    nearest of a wall's returns is the one whose noise brought it nearest. Else (nearest-
    neighbour normals, point-to-point) the residuals' robust spread. At least
    COVARIANCE_SIGMA_FLOOR_M."""
    sigma = _mad_sigma(r)
    if normals is not None:
        on = np.flatnonzero(np.isfinite(normals[:, 0]))
        _, line, count = np.unique(normals[on], axis=0, return_inverse=True, return_counts=True)
        if len(count) <= len(on) // 3:  # each line shared by its returns: line normals
            dot = np.einsum("ij,ij->i", normals[on], model[on])
            offset = np.bincount(line, weights=dot) / count
            model_res = dot - offset[line]
            of_line = np.full(len(model), -1)
            of_line[on] = line
            n = normals.take(pairs, axis=0)
            data_res = np.einsum("ij,ij->i", n, moved) - offset[of_line.take(pairs)]
            sigma = float(np.hypot(_mad_sigma(data_res), _mad_sigma(model_res)))
    return max(sigma, COVARIANCE_SIGMA_FLOOR_M)
