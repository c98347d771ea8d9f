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
are flagged ``ok = False`` rather than given an arbitrary rotation.

:func:`horn_batch` is vectorised over a batch with ``numpy.linalg.eigh`` and is the
reference; :func:`horn_batch_compiled` runs the same steps one set at a time in a compiled
kernel (:mod:`rigcal.jit`), and :func:`horn_bearings` runs that kernel on P3P's solutions
as they come (depths along bearings), so :func:`rigcal.calib.box.p3p.p3p_poses` gives the
RANSAC full poses without a Python step per hypothesis. The kernel takes step 3 as Horn's
section 4 describes it: N's largest eigenvalue is the largest root of the characteristic
quartic lambda^4 + c2 lambda^2 + c1 lambda + c0 (c2 = -2 tr(S^T S), c1 = -8 det S,
c0 = det N; N is traceless), found by Newton's method from the upper bound
sum (|a_i|^2 + |b_i|^2) / 2 (from above, Newton decreases monotonically to the largest
root of a polynomial whose roots are all real), and its eigenvector is the largest
column of the adjugate of N - lambda I (every column is a multiple of it at a simple
eigenvalue; Theobald's quaternion-characteristic-polynomial method, Acta Cryst. A61,
2005, takes the same two steps). The root carries the quartic's rounding, which the
eigenvector would inherit divided by the eigenvalue gap; where the gap is small against
lambda one more adjugate at the first vector's Rayleigh quotient makes it as accurate as
``eigh``'s. Where the two largest eigenvalues (nearly) coincide the adjugate vanishes;
there the kernel falls back to cyclic Jacobi rotations on N, backward stable like
``eigh``. The two differ by rounding over N's eigengap (~1e-15 on well-spread sets).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from rigcal.arrays import FloatArray
from rigcal.jit import njit

# Sets whose second singular value is below this fraction of the first are collinear.
MIN_SPREAD_RATIO = 1e-3
# The adjugate column of N - lambda I is used when its norm is at least this fraction of
# lambda^3 (the product of the three eigenvalue gaps times the eigenvector's largest
# entry, relative to lambda^3): its relative error is then at most ~1e-16 / this. Below,
# Jacobi rotations.
_ADJUGATE_MIN = 1e-5
# Above this (gaps comparable to lambda) the first eigenvector is already accurate to
# rounding and the Rayleigh-quotient refinement below is skipped.
_ADJUGATE_GOOD = 0.25
_NEWTON_STEPS = 40
_JACOBI_SWEEPS = 30


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


def horn_batch_compiled(
    points_a: ArrayLike, points_b: ArrayLike, min_spread_ratio: float = MIN_SPREAD_RATIO
) -> tuple[FloatArray, FloatArray, NDArray[np.bool_]]:
    """:func:`horn_batch` in a compiled kernel, one set at a time: the same arguments,
    flags and results (to rounding, ~1e-15 on well-spread sets).

    Args:
        points_a: (K, N, 3) target points (N >= 3).
        points_b: (K, N, 3) source points, matched to ``points_a``.
        min_spread_ratio: as in :func:`horn_batch`.

    Returns:
        (R (K, 3, 3), t (K, 3), ok (K,)) with a_i ~ R b_i + t; R is the identity and t
        zero where ``ok`` is False.

    Raises:
        ValueError: the two batches differ in shape or are not (K, N, 3).
    """
    a = np.asarray(points_a, dtype=float)
    b = np.asarray(points_b, dtype=float)
    if a.ndim == 2:
        a, b = a[None], b[None]
    if a.shape != b.shape or a.ndim != 3 or a.shape[2] != 3:
        raise ValueError(f"points_a {a.shape} and points_b {b.shape}: expected (K, N, 3) each")
    K = len(a)
    R = np.empty((K, 3, 3))
    t = np.empty((K, 3))
    ok = np.empty(K, dtype=bool)
    _horn_kernel(np.ascontiguousarray(a), np.ascontiguousarray(b), float(min_spread_ratio), R, t, ok)
    return R, t, ok


def horn_bearings(
    bearings: ArrayLike,
    triple: ArrayLike,
    depths: ArrayLike,
    points: ArrayLike,
    min_spread_ratio: float = MIN_SPREAD_RATIO,
) -> tuple[FloatArray, FloatArray, NDArray[np.bool_]]:
    """Horn's method on P3P's solutions (paper Algorithm 1, step 6), compiled: for each
    solution s the camera-frame points ``depths[s, i] * bearings[triple[s], i]`` are
    aligned with ``points[triple[s], i]``, without gathering them into new arrays.

    Args:
        bearings: (n, M, 3) bearings, camera frame (unit when ``depths`` are distances).
        triple: (K,) int, the set (in ``bearings`` and ``points``) of each solution.
        depths: (K, M) the solutions' depths along the bearings.
        points: (n, M, 3) the source points, metres.
        min_spread_ratio: as in :func:`horn_batch`.

    Returns:
        (R (K, 3, 3), t (K, 3), ok (K,)): the same as :func:`horn_batch` on the gathered
        sets, with camera point = R point + t.

    Raises:
        ValueError: the shapes do not match.
    """
    y = np.ascontiguousarray(bearings, dtype=float)
    x = np.ascontiguousarray(points, dtype=float)
    idx = np.ascontiguousarray(triple, dtype=np.int64)
    lam = np.ascontiguousarray(depths, dtype=float)
    K = len(idx)
    if (
        y.shape != x.shape
        or y.ndim != 3
        or y.shape[2] != 3
        or lam.shape != (K, y.shape[1])
        or (K and (idx.min() < 0 or idx.max() >= len(y)))
    ):
        raise ValueError(
            f"bearings {y.shape}, points {x.shape}, triple {idx.shape}, depths {lam.shape}: expected "
            "(n, M, 3), (n, M, 3), (K,) indices below n and (K, M)"
        )
    R = np.empty((K, 3, 3))
    t = np.empty((K, 3))
    ok = np.empty(K, dtype=bool)
    _horn_bearings_kernel(y, idx, lam, x, float(min_spread_ratio), R, t, ok)
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


# The compiled kernel: the steps of horn_batch for one point set at a time, in scalar
# arithmetic (no temporary arrays: scratch arrays would cost more than the arithmetic).


@njit
def _horn_kernel(
    a: FloatArray, b: FloatArray, min_ratio: float, R: FloatArray, t: FloatArray, ok: NDArray[np.bool_]
) -> None:
    """Fill R[k], t[k], ok[k] for each set k of the (K, N, 3) batches a, b."""
    work = np.empty((2, 4, 4))
    ones = np.ones((1, a.shape[1]))
    for k in range(a.shape[0]):
        ok[k] = _k_horn(a, k, ones, 0, b, k, min_ratio, R, t, k, work)


@njit
def _horn_bearings_kernel(
    y: FloatArray,
    triple: NDArray[np.int64],
    depths: FloatArray,
    x: FloatArray,
    min_ratio: float,
    R: FloatArray,
    t: FloatArray,
    ok: NDArray[np.bool_],
) -> None:
    """Fill R[s], t[s], ok[s] for the points depths[s, i] * y[triple[s], i] against
    x[triple[s], i]."""
    work = np.empty((2, 4, 4))
    for s in range(len(triple)):
        ok[s] = _k_horn(y, triple[s], depths, s, x, triple[s], min_ratio, R, t, s, work)


@njit
def _k_horn(
    A: FloatArray,
    ka: int,
    D: FloatArray,
    kd: int,
    B: FloatArray,
    kb: int,
    min_ratio: float,
    R: FloatArray,
    t: FloatArray,
    ko: int,
    work: FloatArray,
) -> bool:
    """Horn's method for one pair of point sets, a_i = D[kd, i] A[ka, i] ~ R B[kb, i] + t
    (A, B (n, N, 3), D (m, N): the scale lets P3P's depths and bearings be passed as they
    are): fills R[ko] and t[ko] (the identity and zero when the sets are flagged, as
    :func:`horn_batch`) and returns whether they are usable. ``work`` (2, 4, 4) is
    scratch. Indices rather than views of the batches: a view passed to a function costs
    reference counting, more than Horn's arithmetic on three points."""
    n = A.shape[1]
    # Step 1: centroids.
    a0 = a1 = a2 = b0 = b1 = b2 = 0.0
    for i in range(n):
        a0 += D[kd, i] * A[ka, i, 0]
        a1 += D[kd, i] * A[ka, i, 1]
        a2 += D[kd, i] * A[ka, i, 2]
        b0 += B[kb, i, 0]
        b1 += B[kb, i, 1]
        b2 += B[kb, i, 2]
    good = n > 0 and np.isfinite(a0 + a1 + a2 + b0 + b1 + b2)  # NaN or inf anywhere
    # Step 2: the cross-covariance S = sum b_i a_i^T of the centred points, and each set's
    # scatter matrix for the collinearity test.
    sxx = sxy = sxz = syx = syy = syz = szx = szy = szz = 0.0
    pxx = pxy = pxz = pyy = pyz = pzz = 0.0  # source points B
    qxx = qxy = qxz = qyy = qyz = qzz = 0.0  # target points A
    if good:
        a0, a1, a2, b0, b1, b2 = a0 / n, a1 / n, a2 / n, b0 / n, b1 / n, b2 / n
        for i in range(n):
            x0, x1, x2 = D[kd, i] * A[ka, i, 0] - a0, D[kd, i] * A[ka, i, 1] - a1, D[kd, i] * A[ka, i, 2] - a2
            y0, y1, y2 = B[kb, i, 0] - b0, B[kb, i, 1] - b1, B[kb, i, 2] - b2
            sxx += y0 * x0
            sxy += y0 * x1
            sxz += y0 * x2
            syx += y1 * x0
            syy += y1 * x1
            syz += y1 * x2
            szx += y2 * x0
            szy += y2 * x1
            szz += y2 * x2
            pxx += y0 * y0
            pxy += y0 * y1
            pxz += y0 * y2
            pyy += y1 * y1
            pyz += y1 * y2
            pzz += y2 * y2
            qxx += x0 * x0
            qxy += x0 * x1
            qxz += x0 * x2
            qyy += x1 * x1
            qyz += x1 * x2
            qzz += x2 * x2
        good = _k_spread_ok(pxx, pxy, pxz, pyy, pyz, pzz, min_ratio) and _k_spread_ok(
            qxx, qxy, qxz, qyy, qyz, qzz, min_ratio
        )
    if not good:
        for r in range(3):
            t[ko, r] = 0.0
            for c in range(3):
                R[ko, r, c] = 1.0 if r == c else 0.0
        return False
    # Horn's symmetric N (his Eq. (37)), traceless.
    n00 = sxx + syy + szz
    n01 = syz - szy
    n02 = szx - sxz
    n03 = sxy - syx
    n11 = sxx - syy - szz
    n12 = sxy + syx
    n13 = szx + sxz
    n22 = -sxx + syy - szz
    n23 = syz + szy
    n33 = -sxx - syy + szz
    # Step 3: the eigenvector of N's largest eigenvalue, the rotation's quaternion. Horn's
    # section 4: the characteristic quartic l^4 + c2 l^2 + c1 l + c0.
    c2 = -2.0 * (sxx**2 + sxy**2 + sxz**2 + syx**2 + syy**2 + syz**2 + szx**2 + szy**2 + szz**2)
    c1 = -8.0 * (
        sxx * (syy * szz - syz * szy) - sxy * (syx * szz - syz * szx) + sxz * (syx * szy - syy * szx)
    )
    nn = (n00, n01, n02, n03, n11, n12, n13, n22, n23, n33)
    c0 = _k_sym4_det(nn)
    bound = 0.5 * (pxx + pyy + pzz + qxx + qyy + qzz)  # sum (|a_i|^2 + |b_i|^2) / 2 >= l_max
    lam = _k_largest_root(c2, c1, c0, bound)
    w, x, y, z, conditioning = _k_adjugate_column(nn, lam)
    if _ADJUGATE_MIN <= conditioning < _ADJUGATE_GOOD:
        # The root carries the quartic's rounding (~1e-16 l^4 over the product of the
        # gaps), which the eigenvector would inherit divided by the gap once more; its
        # Rayleigh quotient is exact to rounding plus the square of the eigenvector's
        # error, so a second adjugate from it is as accurate as eigh's eigenvector.
        rq = (
            n00 * w * w
            + n11 * x * x
            + n22 * y * y
            + n33 * z * z
            + 2.0 * (n01 * w * x + n02 * w * y + n03 * w * z + n12 * x * y + n13 * x * z + n23 * y * z)
        )
        w, x, y, z, conditioning = _k_adjugate_column(nn, rq)
    if not conditioning >= _ADJUGATE_MIN:
        # The two largest eigenvalues (nearly) coincide: Jacobi rotations instead.
        W = work[0]
        W[0, 0], W[0, 1], W[0, 2], W[0, 3] = n00, n01, n02, n03
        W[1, 0], W[1, 1], W[1, 2], W[1, 3] = n01, n11, n12, n13
        W[2, 0], W[2, 1], W[2, 2], W[2, 3] = n02, n12, n22, n23
        W[3, 0], W[3, 1], W[3, 2], W[3, 3] = n03, n13, n23, n33
        w, x, y, z = _k_top_eigenvector_jacobi(W, work[1])
    _k_quaternion_to_R(w, x, y, z, R, ko)
    # Step 4: t = mean(a) - R mean(b).
    t[ko, 0] = a0 - (R[ko, 0, 0] * b0 + R[ko, 0, 1] * b1 + R[ko, 0, 2] * b2)
    t[ko, 1] = a1 - (R[ko, 1, 0] * b0 + R[ko, 1, 1] * b1 + R[ko, 1, 2] * b2)
    t[ko, 2] = a2 - (R[ko, 2, 0] * b0 + R[ko, 2, 1] * b1 + R[ko, 2, 2] * b2)
    return True


@njit
def _k_largest_root(c2: float, c1: float, c0: float, bound: float) -> float:
    """The largest root of l^4 + c2 l^2 + c1 l + c0 (all roots real), by Newton's method
    from an upper bound: from above it decreases monotonically to that root. NaN when it
    does not settle within the step limit (a double root converges only linearly)."""
    lam = bound
    for _ in range(_NEWTON_STEPS):
        p = ((lam * lam + c2) * lam + c1) * lam + c0
        if not p > 0:  # at the root to rounding
            return lam
        dp = (4.0 * lam * lam + 2.0 * c2) * lam + c1
        if not dp > 0:
            return np.nan
        step = p / dp
        lam -= step
        if step <= 1e-16 * bound:
            return lam
    return np.nan


@njit
def _k_adjugate_column(m: tuple[float, ...], lam: float) -> tuple[float, float, float, float, float]:
    """The unit largest column of adj(M - lam I) for a symmetric 4x4 M given by its upper
    triangle m (row-major: 00, 01, 02, 03, 11, 12, 13, 22, 23, 33): the eigenvector of the
    eigenvalue lam. adj(M - lam I) = sum_i prod_{j != i} (l_j - lam) v_i v_i^T, so at an
    eigenvalue every column is a multiple of its eigenvector v, and the column of the
    largest diagonal entry (~ v_i^2) is the longest. Also returns that column's length
    over |lam|^3, about the product of the gaps relative to lam: small (below
    ``_ADJUGATE_MIN`` it is not trusted) for a (near-)repeated eigenvalue, NaN for no
    root (lam NaN)."""
    m00, m01, m02, m03, m11, m12, m13, m22, m23, m33 = m
    s0, s1, s2, s3, s4, s5, _c0, c1, c2, c3, c4, c5 = _k_sym4_minors(m, lam)
    m00 -= lam
    m11 -= lam
    m22 -= lam
    m33 -= lam
    d0 = m11 * c5 - m12 * c4 + m13 * c3
    d1 = m00 * c5 - m02 * c2 + m03 * c1
    d2 = m03 * s4 - m13 * s2 + m33 * s0
    d3 = m02 * s3 - m12 * s1 + m22 * s0
    big = max(abs(d0), abs(d1), abs(d2), abs(d3))
    # The other entries of that column (adj is symmetric).
    if abs(d0) == big:
        w, x, y, z = (
            d0,
            -m01 * c5 + m02 * c4 - m03 * c3,
            m13 * s5 - m23 * s4 + m33 * s3,
            -m12 * s5 + m22 * s4 - m23 * s3,
        )
    elif abs(d1) == big:
        w, x, y, z = (
            -m01 * c5 + m02 * c4 - m03 * c3,
            d1,
            -m03 * s5 + m23 * s2 - m33 * s1,
            m02 * s5 - m22 * s2 + m23 * s1,
        )
    elif abs(d2) == big:
        w, x, y, z = (
            m13 * s5 - m23 * s4 + m33 * s3,
            -m03 * s5 + m23 * s2 - m33 * s1,
            d2,
            -m02 * s4 + m12 * s2 - m23 * s0,
        )
    else:
        w, x, y, z = (
            -m12 * s5 + m22 * s4 - m23 * s3,
            m02 * s5 - m22 * s2 + m23 * s1,
            -m02 * s4 + m12 * s2 - m23 * s0,
            d3,
        )
    norm = np.sqrt(w * w + x * x + y * y + z * z)
    return w / norm, x / norm, y / norm, z / norm, norm / abs(lam) ** 3


@njit
def _k_sym4_det(m: tuple[float, ...]) -> float:
    """det M for a symmetric 4x4 M given by its upper triangle (as
    :func:`_k_adjugate_column`), by Laplace expansion along rows (0, 1)."""
    s0, s1, s2, s3, s4, s5, c0, c1, c2, c3, c4, c5 = _k_sym4_minors(m, 0.0)
    return float(s0 * c5 - s1 * c4 + s2 * c3 + s3 * c2 - s4 * c1 + s5 * c0)


@njit
def _k_sym4_minors(m: tuple[float, ...], lam: float) -> tuple[float, ...]:
    """The 2x2 minors of rows (0, 1) (s0..s5) and rows (2, 3) (c0..c5) of M - lam I for a
    symmetric 4x4 M given by its upper triangle; the determinant and the adjugate are
    sums of their products."""
    m00, m01, m02, m03, m11, m12, m13, m22, m23, m33 = m
    m00 -= lam
    m11 -= lam
    m22 -= lam
    m33 -= lam
    return (
        m00 * m11 - m01 * m01,
        m00 * m12 - m01 * m02,
        m00 * m13 - m01 * m03,
        m01 * m12 - m11 * m02,
        m01 * m13 - m11 * m03,
        m02 * m13 - m12 * m03,
        m02 * m13 - m03 * m12,
        m02 * m23 - m03 * m22,
        m02 * m33 - m03 * m23,
        m12 * m23 - m13 * m22,
        m12 * m33 - m13 * m23,
        m22 * m33 - m23 * m23,
    )


@njit
def _k_top_eigenvector_jacobi(W: FloatArray, V: FloatArray) -> tuple[float, float, float, float]:
    """The unit eigenvector of the largest eigenvalue of a symmetric (4, 4) W (destroyed)
    by cyclic Jacobi rotations (Numerical Recipes' ``jacobi``); V (4, 4) is scratch.
    Backward stable like ``eigh``, so also where the top eigenvalues nearly coincide."""
    for r in range(4):
        for c in range(4):
            V[r, c] = 1.0 if r == c else 0.0
    for _ in range(_JACOBI_SWEEPS):
        off = 0.0
        diag = 0.0
        for r in range(4):
            diag += W[r, r] * W[r, r]
            for c in range(r + 1, 4):
                off += W[r, c] * W[r, c]
        if not off > 1e-36 * diag:
            break
        for p in range(3):
            for s in range(p + 1, 4):
                apq = W[p, s]
                if apq == 0.0:
                    continue
                theta = (W[s, s] - W[p, p]) / (2.0 * apq)
                if abs(theta) > 1e150:
                    tan = 0.5 / theta
                else:
                    tan = 1.0 / (abs(theta) + np.sqrt(theta * theta + 1.0))
                    if theta < 0:
                        tan = -tan
                cos = 1.0 / np.sqrt(tan * tan + 1.0)
                sin = tan * cos
                W[p, p] -= tan * apq
                W[s, s] += tan * apq
                W[p, s] = W[s, p] = 0.0
                for r in range(4):
                    if r != p and r != s:
                        arp = W[r, p]
                        ars = W[r, s]
                        W[r, p] = W[p, r] = cos * arp - sin * ars
                        W[r, s] = W[s, r] = sin * arp + cos * ars
                for r in range(4):
                    vrp = V[r, p]
                    vrs = V[r, s]
                    V[r, p] = cos * vrp - sin * vrs
                    V[r, s] = sin * vrp + cos * vrs
    top = 0
    for r in range(1, 4):
        if W[r, r] > W[top, top]:
            top = r
    return V[0, top], V[1, top], V[2, top], V[3, top]


@njit
def _k_quaternion_to_R(w: float, x: float, y: float, z: float, R: FloatArray, k: int) -> None:
    """:func:`quaternion_to_R` for one quaternion (w, x, y, z), normalised here, into R[k]."""
    nr = np.sqrt(w * w + x * x + y * y + z * z)
    w, x, y, z = w / nr, x / nr, y / nr, z / nr
    R[k, 0, 0] = w * w + x * x - y * y - z * z
    R[k, 0, 1] = 2 * (x * y - w * z)
    R[k, 0, 2] = 2 * (x * z + w * y)
    R[k, 1, 0] = 2 * (x * y + w * z)
    R[k, 1, 1] = w * w - x * x + y * y - z * z
    R[k, 1, 2] = 2 * (y * z - w * x)
    R[k, 2, 0] = 2 * (x * z - w * y)
    R[k, 2, 1] = 2 * (y * z + w * x)
    R[k, 2, 2] = w * w - x * x - y * y + z * z


@njit
def _k_spread_ok(
    s00: float, s01: float, s02: float, s11: float, s12: float, s22: float, min_ratio: float
) -> bool:
    """:func:`_spread_ok` for one set, from its symmetric scatter matrix's upper triangle.

    With the eigenvalues l1 >= l2 >= l3 >= 0, the trace I1 and the sum of the principal
    2x2 minors I2 = l1 l2 + l1 l3 + l2 l3 bound l2 from both sides: I1 / 3 <= l1 <= I1
    and l1 l2 <= I2 <= 3 l1 l2, so I2 > 3 rho I1^2 proves l2 > rho l1 and 9 I2 <= rho I1^2
    disproves it (rho = min_ratio^2). Only between the two, rarely, are the eigenvalues
    taken, by :func:`sym3_eigvalsh`'s closed form (its arithmetic, so the same decision).
    """
    rho = min_ratio**2
    i1 = s00 + s11 + s22
    i2 = s00 * s11 - s01 * s01 + s00 * s22 - s02 * s02 + s11 * s22 - s12 * s12
    if i2 > 3.0 * rho * i1 * i1:
        return True
    if 9.0 * i2 <= rho * i1 * i1:
        return False
    p1 = s01**2 + s02**2 + s12**2
    q = (s00 + s11 + s22) / 3.0
    p2 = (s00 - q) ** 2 + (s11 - q) ** 2 + (s22 - q) ** 2 + 2.0 * p1
    p = np.sqrt(p2 / 6.0)
    safe = p if p > 0 else 1.0
    b00, b01, b02 = (s00 - q) / safe, s01 / safe, s02 / safe
    b11, b12, b22 = (s11 - q) / safe, s12 / safe, (s22 - q) / safe
    r = 0.5 * (b00 * (b11 * b22 - b12 * b12) - b01 * (b01 * b22 - b12 * b02) + b02 * (b01 * b12 - b11 * b02))
    r = min(max(r, -1.0), 1.0)
    phi = np.arccos(r) / 3.0
    hi = q + 2.0 * p * np.cos(phi)
    lo = q + 2.0 * p * np.cos(phi + 2.0 * np.pi / 3.0)
    mid = 3.0 * q - hi - lo
    top = max(hi, 2.2250738585072014e-308)
    return bool(max(mid, 0.0) > rho * top)
