"""Horn's closed-form absolute orientation with unit quaternions (paper Algorithm 1, step 6).

Given matched points a_i (the target frame, e.g. camera-frame points from P3P) and b_i
(the source frame, e.g. laser points), find R, t minimising sum |a_i - (R b_i + t)|^2
(B. K. P. Horn, "Closed-form solution of absolute orientation using unit quaternions",
JOSA A 4(4), 1987):

1. centre both sets on their centroids;
2. build the cross-covariance S = sum b_i a_i^T and from it Horn's symmetric 4x4 matrix N;
3. the unit quaternion of R is the eigenvector of N's largest eigenvalue;
4. t = mean(a) - R mean(b).

A quaternion is always a proper rotation, so reflections (which an SVD solution must
correct for) cannot arise. When the source points are (nearly) collinear the rotation
about their line is not determined: N's two largest eigenvalues coincide, and such sets
are flagged ``ok = False`` rather than given an arbitrary rotation. Vectorised over a
batch with ``numpy.linalg.eigh``.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

FloatArray = NDArray[np.float64]

# Sets whose second singular value is below this fraction of the first are collinear.
MIN_SPREAD_RATIO = 1e-3


def horn_batch(
    points_a: ArrayLike, points_b: ArrayLike, min_spread_ratio: float = MIN_SPREAD_RATIO
) -> tuple[FloatArray, FloatArray, NDArray[np.bool_]]:
    """Absolute orientation for a batch of matched point sets.

    Args:
        points_a: (K, N, 3) target points (N >= 3).
        points_b: (K, N, 3) source points, matched to ``points_a``.
        min_spread_ratio: sets whose source or target points have a second singular value
            (after centring) below this fraction of the first are near-collinear and
            flagged.

    Returns:
        (R (K, 3, 3), t (K, 3), ok (K,)) with a_i ~ R b_i + t; R is the identity and t
        zero where ``ok`` is False.
    """
    a = np.asarray(points_a, dtype=float)
    b = np.asarray(points_b, dtype=float)
    if a.ndim == 2:
        a, b = a[None], b[None]
    K = len(a)
    if K == 0:
        return np.zeros((0, 3, 3)), np.zeros((0, 3)), np.zeros(0, dtype=bool)
    with np.errstate(invalid="ignore"):  # inf input: flagged below
        ca = a.mean(axis=1)
        cb = b.mean(axis=1)
        A = a - ca[:, None]
        B = b - cb[:, None]
    ok = _spread_ok(A, min_spread_ratio) & _spread_ok(B, min_spread_ratio)
    ok &= np.isfinite(a).all(axis=(1, 2)) & np.isfinite(b).all(axis=(1, 2))
    S = np.einsum("kni,knj->kij", np.where(ok[:, None, None], B, 0.0), np.where(ok[:, None, None], A, 0.0))
    Sxx, Sxy, Sxz = S[:, 0, 0], S[:, 0, 1], S[:, 0, 2]
    Syx, Syy, Syz = S[:, 1, 0], S[:, 1, 1], S[:, 1, 2]
    Szx, Szy, Szz = S[:, 2, 0], S[:, 2, 1], S[:, 2, 2]
    N = np.empty((K, 4, 4))
    N[:, 0, 0] = Sxx + Syy + Szz
    N[:, 0, 1] = N[:, 1, 0] = Syz - Szy
    N[:, 0, 2] = N[:, 2, 0] = Szx - Sxz
    N[:, 0, 3] = N[:, 3, 0] = Sxy - Syx
    N[:, 1, 1] = Sxx - Syy - Szz
    N[:, 1, 2] = N[:, 2, 1] = Sxy + Syx
    N[:, 1, 3] = N[:, 3, 1] = Szx + Sxz
    N[:, 2, 2] = -Sxx + Syy - Szz
    N[:, 2, 3] = N[:, 3, 2] = Syz + Szy
    N[:, 3, 3] = -Sxx - Syy + Szz
    _, V = np.linalg.eigh(N)
    q = V[:, :, -1]  # eigenvector of the largest eigenvalue: (w, x, y, z)
    R = quaternion_to_R(q)
    R[~ok] = np.eye(3)
    t = ca - np.einsum("kij,kj->ki", R, cb)
    t[~ok] = 0.0
    return R, t, ok


def horn(points_a: ArrayLike, points_b: ArrayLike) -> tuple[FloatArray, FloatArray]:
    """R, t with a_i ~ R b_i + t for one pair of (N, 3) point sets.

    Raises:
        ValueError: the points are (nearly) collinear, so the rotation is not determined.
    """
    R, t, ok = horn_batch(np.asarray(points_a, dtype=float)[None], np.asarray(points_b, dtype=float)[None])
    if not ok[0]:
        raise ValueError("horn: the points are (nearly) collinear; the rotation about their line is free")
    return R[0], t[0]


def quaternion_to_R(q: ArrayLike) -> FloatArray:
    """(K, 4) unit quaternions (w, x, y, z) to (K, 3, 3) rotation matrices."""
    qa: FloatArray = np.asarray(q, dtype=float)
    qa = qa / np.linalg.norm(qa, axis=-1, keepdims=True)
    w, x, y, z = qa[..., 0], qa[..., 1], qa[..., 2], qa[..., 3]
    R = np.empty((*qa.shape[:-1], 3, 3))
    R[..., 0, 0] = w * w + x * x - y * y - z * z
    R[..., 0, 1] = 2 * (x * y - w * z)
    R[..., 0, 2] = 2 * (x * z + w * y)
    R[..., 1, 0] = 2 * (x * y + w * z)
    R[..., 1, 1] = w * w - x * x + y * y - z * z
    R[..., 1, 2] = 2 * (y * z - w * x)
    R[..., 2, 0] = 2 * (x * z - w * y)
    R[..., 2, 1] = 2 * (y * z + w * x)
    R[..., 2, 2] = w * w - x * x - y * y + z * z
    return R


def _spread_ok(C: FloatArray, min_ratio: float) -> NDArray[np.bool_]:
    """(K,) whether centred point sets (K, N, 3) span more than a line: the second singular
    value is at least min_ratio times the first.

    The singular values are the square roots of the eigenvalues of the 3x3 scatter
    matrix C^T C, taken in closed form (the trigonometric solution of its characteristic
    cubic), which is faster than a batched SVD.
    """
    Cz: FloatArray = np.where(np.isfinite(C), C, 0.0)
    S = np.einsum("kni,knj->kij", Cz, Cz)
    w = sym3_eigvalsh(S)  # ascending
    top = np.maximum(w[:, 2], np.finfo(float).tiny)
    out: NDArray[np.bool_] = np.maximum(w[:, 1], 0.0) > min_ratio**2 * top
    return out


def sym3_eigvalsh(S: FloatArray) -> FloatArray:
    """(K, 3) eigenvalues, ascending, of symmetric (K, 3, 3) matrices, in closed form."""
    p1 = S[:, 0, 1] ** 2 + S[:, 0, 2] ** 2 + S[:, 1, 2] ** 2
    q = (S[:, 0, 0] + S[:, 1, 1] + S[:, 2, 2]) / 3.0
    p2 = (S[:, 0, 0] - q) ** 2 + (S[:, 1, 1] - q) ** 2 + (S[:, 2, 2] - q) ** 2 + 2.0 * p1
    p = np.sqrt(p2 / 6.0)
    safe = np.where(p > 0, p, 1.0)
    B = (S - q[:, None, None] * np.eye(3)) / safe[:, None, None]
    r = np.clip(
        0.5
        * (
            B[:, 0, 0] * (B[:, 1, 1] * B[:, 2, 2] - B[:, 1, 2] * B[:, 2, 1])
            - B[:, 0, 1] * (B[:, 1, 0] * B[:, 2, 2] - B[:, 1, 2] * B[:, 2, 0])
            + B[:, 0, 2] * (B[:, 1, 0] * B[:, 2, 1] - B[:, 1, 1] * B[:, 2, 0])
        ),
        -1.0,
        1.0,
    )
    phi = np.arccos(r) / 3.0
    hi = q + 2.0 * p * np.cos(phi)
    lo = q + 2.0 * p * np.cos(phi + 2.0 * np.pi / 3.0)
    mid = 3.0 * q - hi - lo
    out: FloatArray = np.column_stack([lo, mid, hi])
    return out
