"""The 3-point algorithm (P3P), vectorised over many triples (paper Algorithm 1, step 5).

Given three unit bearings y_i from the camera centre and the three points x_i they see
(any frame), P3P finds the depths lambda_i > 0 with lambda_i y_i at mutual distances
|x_i - x_j|. This is the Lambda Twist formulation (Persson and Nordberg, ECCV 2018):

1. The law of cosines for the three pairs, lambda_i^2 + lambda_j^2 - 2 b_ij lambda_i lambda_j
   = a_ij (b_ij = y_i . y_j, a_ij = |x_i - x_j|^2), written as quadratic forms
   Lambda^T M_ij Lambda = a_ij.
2. Two homogeneous forms D1 = a_23 M_12 - a_12 M_23 and D2 = a_23 M_13 - a_13 M_23 vanish on
   every solution; a member of their pencil D0 = D1 + g D2 with det(D0) = 0 (a cubic in g)
   is a pair of planes through the origin: D0 = s1 e1 e1^T + s2 e2 e2^T with s1 s2 < 0, so
   (e1 +/- sqrt(-s2/s1) e2) . Lambda = 0.
3. In each plane, D1 restricted to the plane is a binary quadratic form whose two null
   directions, scaled by the sum of the three distance equations, give the solutions.
4. A few Gauss-Newton steps on the three original equations polish the depths.

Where Lambda Twist solves a 2x2 quadratic for a ratio, we parametrise the plane by an
orthonormal basis and solve for an angle, which has no division by a small plane
coefficient; the cubic's real roots come from batched companion-matrix eigenvalues, and
of them the one whose plane pair is best conditioned is used. The pose follows from the
camera-frame points lambda_i y_i by Horn's method (:mod:`rigcal.calib.box.horn`), as the
paper's step 6 does.

:func:`p3p` runs a compiled kernel (:mod:`rigcal.jit`) that solves one triple at a time
in scalar arithmetic, with no temporary arrays; :func:`p3p_numpy`, the same steps
vectorised over the batch in numpy, is its reference in the tests. :func:`p3p_poses`
follows the kernel with Horn's method compiled (:func:`rigcal.calib.box.horn.horn_bearings`)
on each solution, so a batch of triples gives full poses without a Python step per solution; its
reference is :func:`p3p` followed by :func:`rigcal.calib.box.horn.horn_batch`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from rigcal.arrays import FloatArray
from rigcal.calib.box.horn import MIN_SPREAD_RATIO, horn_bearings
from rigcal.jit import njit

_GAUSS_NEWTON_STEPS = 2
# A solution is kept when its three distance equations hold to this relative error.
_RELATIVE_TOLERANCE = 1e-6


@dataclass(frozen=True)
class P3PSolutions:
    """All real P3P solutions of a batch of triples.

    Attributes:
        triple: (K,) index of the triple (in the batch) each solution belongs to; a triple
            has 0 to 4 solutions.
        depths: (K, 3) metres: the distances lambda_i along the bearings, so the camera-frame
            points are ``depths[k, i] * bearings[triple[k], i]``.
    """

    triple: NDArray[np.int64]
    depths: FloatArray


@dataclass(frozen=True)
class P3PPoses:
    """All real P3P solutions of a batch of triples, with their poses.

    Attributes:
        triple: (K,) index of the triple (in the batch) each solution belongs to.
        depths: (K, 3) metres along the bearings, as in :class:`P3PSolutions`.
        R: (K, 3, 3) rotations and
        t: (K, 3) translations, metres, with camera point = R point + t (the identity and
            zero where ``ok`` is False).
        ok: (K,) False where Horn's method flags the solution's camera-frame points or
            the triple's points as (nearly) collinear.
    """

    triple: NDArray[np.int64]
    depths: FloatArray
    R: FloatArray
    t: FloatArray
    ok: NDArray[np.bool_]


def p3p_poses(bearings: ArrayLike, points: ArrayLike, min_spread_ratio: float = MIN_SPREAD_RATIO) -> P3PPoses:
    """Full poses from three bearings and points per triple (paper Algorithm 1, steps 5-6):
    :func:`p3p`'s depths, then Horn's absolute orientation (Horn 1987) aligning the
    camera-frame points ``depths[k, i] * bearings[triple[k], i]`` with the points, both in
    compiled kernels.

    Args:
        bearings: (n, 3, 3) unit bearings, camera frame: ``bearings[k, i]`` sees point i.
        points: (n, 3, 3) the points, metres, in any frame.
        min_spread_ratio: Horn's collinearity flag, as in
            :func:`rigcal.calib.box.horn.horn_batch`.

    Returns:
        Every real solution with positive depths and its pose: the same as :func:`p3p`
        followed by :func:`rigcal.calib.box.horn.horn_batch` (to ~1e-15 on well-spread sets).
    """
    y = np.ascontiguousarray(bearings, dtype=float)
    x = np.ascontiguousarray(points, dtype=float)
    if y.ndim == 2:
        y, x = y[None], x[None]
    sol = p3p(y, x)
    R, t, ok = horn_bearings(y, sol.triple, sol.depths, x, min_spread_ratio)
    return P3PPoses(sol.triple, sol.depths, R, t, ok)


def p3p(bearings: ArrayLike, points: ArrayLike) -> P3PSolutions:
    """Solve P3P for every triple of a batch (compiled kernel).

    Args:
        bearings: (n, 3, 3) unit bearings, camera frame: ``bearings[k, i]`` sees point i.
        points: (n, 3, 3) the points, metres, in any frame.

    Returns:
        Every real solution with positive depths, as :func:`p3p_numpy` finds them.
    """
    y = np.asarray(bearings, dtype=float)
    x = np.asarray(points, dtype=float)
    if y.ndim == 2:
        y, x = y[None], x[None]
    if y.shape != x.shape or y.shape[1:] != (3, 3):
        raise ValueError(f"bearings {y.shape} and points {x.shape}: expected (n, 3, 3) each")
    n = len(y)
    idx = np.empty(4 * n, dtype=np.int64)
    lam = np.empty((4 * n, 3))
    count = _p3p_kernel(np.ascontiguousarray(y), np.ascontiguousarray(x), idx, lam)
    return P3PSolutions(idx[:count].copy(), lam[:count].copy())


def p3p_numpy(bearings: ArrayLike, points: ArrayLike) -> P3PSolutions:
    """Solve P3P for every triple of a batch, vectorised in numpy (the kernel's reference).

    Args:
        bearings: (n, 3, 3) unit bearings, camera frame: ``bearings[k, i]`` sees point i.
        points: (n, 3, 3) the points, metres, in any frame.

    Returns:
        Every real solution with positive depths. Collinear or coincident points, or
        coincident bearings, give no solution rather than a wrong one.
    """
    y = np.asarray(bearings, dtype=float)
    x = np.asarray(points, dtype=float)
    if y.ndim == 2:
        y, x = y[None], x[None]
    n = len(y)
    if n == 0:
        return P3PSolutions(np.zeros(0, dtype=np.int64), np.zeros((0, 3)))
    y = y / np.linalg.norm(y, axis=2, keepdims=True)

    a12 = _sq(x[:, 0] - x[:, 1])
    a13 = _sq(x[:, 0] - x[:, 2])
    a23 = _sq(x[:, 1] - x[:, 2])
    b12 = np.einsum("ki,ki->k", y[:, 0], y[:, 1])
    b13 = np.einsum("ki,ki->k", y[:, 0], y[:, 2])
    b23 = np.einsum("ki,ki->k", y[:, 1], y[:, 2])

    M12 = _form(n, (0, 1), b12)
    M13 = _form(n, (0, 2), b13)
    M23 = _form(n, (1, 2), b23)
    # Step 2: two homogeneous forms that vanish on every solution.
    D1 = a23[:, None, None] * M12 - a12[:, None, None] * M23
    D2 = a23[:, None, None] * M13 - a13[:, None, None] * M23
    # A triple with no usable pencil member (coincident or collinear points) has D0 = NaN;
    # zero gives it no opposite-sign eigenvalues below, hence no solution.
    D0, s1, s2 = _degenerate_member(D1, D2)
    D0 = np.where(np.isfinite(D0), D0, 0.0)
    # Eigenvectors of the two non-zero eigenvalues (closed form: D0 - s I is singular).
    e1 = _null_vector(D0 - s1[:, None, None] * np.eye(3))
    e2 = _null_vector(D0 - s2[:, None, None] * np.eye(3))
    E = np.stack([e1, e2], axis=2)
    with np.errstate(invalid="ignore", divide="ignore"):
        ratio = np.sqrt(np.where(s1 * s2 < 0, -s2 / s1, np.nan))
    Msum = M12 + M13 + M23
    asum = a12 + a13 + a23
    scale = np.maximum(asum, np.finfo(float).tiny)

    triples = []
    depths = []
    for sign in (1.0, -1.0):
        normal = E[:, :, 0] + sign * ratio[:, None] * E[:, :, 1]  # (n, 3), plane normal
        p, q = _plane_basis(normal)
        # Step 3: D1 restricted to the plane (D2 when D1 vanishes there: on the plane
        # D1 = -g D2, so either carries the same null directions).
        A1, B1, C1 = _restrict(D1, p, q)
        A2, B2, C2 = _restrict(D2, p, q)
        use1 = A1 * A1 + 2 * B1 * B1 + C1 * C1 >= A2 * A2 + 2 * B2 * B2 + C2 * C2
        A, B, C = np.where(use1, A1, A2), np.where(use1, B1, B2), np.where(use1, C1, C2)
        # A c^2 + 2 B c s + C s^2 = 0 with (c, s) = (cos t, sin t):
        # (A + C)/2 + R cos(2t - phi) = 0.
        R = np.hypot(0.5 * (A - C), B)
        phi = np.arctan2(B, 0.5 * (A - C))
        with np.errstate(invalid="ignore", divide="ignore"):
            arg = -0.5 * (A + C) / R
        arg = np.where(np.abs(arg) <= 1.0 + 1e-9, np.clip(arg, -1.0, 1.0), np.nan)
        for branch in (1.0, -1.0):
            t = 0.5 * (phi + branch * np.arccos(arg))
            u = np.cos(t)[:, None] * p + np.sin(t)[:, None] * q  # (n, 3) direction of Lambda
            quad = _quad(Msum, u)
            with np.errstate(invalid="ignore", divide="ignore"):
                k = np.sqrt(asum / quad)
            lam = k[:, None] * u
            flip = (lam[:, 0] + lam[:, 1] + lam[:, 2]) < 0  # Lambda and -Lambda
            lam = np.where(flip[:, None], -lam, lam)
            triples.append(np.arange(n))
            depths.append(lam)
    idx = np.concatenate(triples)
    lam = np.concatenate(depths)
    ok = np.isfinite(lam).all(axis=1) & (lam > 0).all(axis=1)
    idx, lam = idx[ok], lam[ok]
    # Step 4: Gauss-Newton on the three distance equations.
    bb = np.column_stack([b12, b13, b23])[idx]
    aa = np.column_stack([a12, a13, a23])[idx]
    for _ in range(_GAUSS_NEWTON_STEPS):
        lam = _gauss_newton_step(lam, bb, aa)
    res = np.abs(_residuals(lam, bb) - aa).max(axis=1) / scale[idx]
    ok = np.isfinite(res) & (res < _RELATIVE_TOLERANCE) & (lam > 0).all(axis=1)
    idx, lam = idx[ok], lam[ok]
    idx, lam = _unique(idx, lam)
    return P3PSolutions(idx.astype(np.int64), lam)


def _sq(v: FloatArray) -> FloatArray:
    out: FloatArray = np.einsum("ki,ki->k", v, v)
    return out


def _form(n: int, pair: tuple[int, int], b: FloatArray) -> FloatArray:
    """(n, 3, 3) M with Lambda^T M Lambda = l_i^2 + l_j^2 - 2 b l_i l_j."""
    i, j = pair
    M = np.zeros((n, 3, 3))
    M[:, i, i] = 1.0
    M[:, j, j] = 1.0
    M[:, i, j] = -b
    M[:, j, i] = -b
    return M


def _degenerate_member(D1: FloatArray, D2: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
    """A singular D0 = D1 + g D2 per triple (or D2 itself), chosen among the real roots of
    det(D1 + g D2) = 0 as the one whose two remaining eigenvalues are best balanced with
    opposite signs (the best-conditioned pair of planes).

    Returns:
        (D0 (n, 3, 3), s1 (n,), s2 (n,)): the member and its two non-zero eigenvalues,
        |s1| >= |s2|; NaN where no member has eigenvalues of opposite signs.
    """
    n = len(D1)
    # det(D1 + g D2) = c3 g^3 + c2 g^2 + c1 g + c0
    c0 = _det(D1)
    c3 = _det(D2)
    # tr(adj(D1) D2) and tr(D1 adj(D2)); every matrix here is symmetric.
    c1 = _sum9(_adjugate(D1) * D2)
    c2 = _sum9(D1 * _adjugate(D2))
    lead = np.abs(c3) > 1e-12 * (np.abs(c0) + np.abs(c1) + np.abs(c2) + 1e-300)
    safe_c3 = np.where(lead, c3, 1.0)
    roots = _cubic_real_roots(c2 / safe_c3, c1 / safe_c3, c0 / safe_c3)
    best = np.full((n, 3, 3), np.nan)
    best_s = np.full((n, 2), np.nan)
    best_quality = np.full(n, -1.0)
    candidates = [(D2, ~lead)]  # g = infinity: D2 is singular itself when c3 = 0
    for r in range(3):
        g = _polish_root(np.where(lead, roots[:, r], np.nan), c3, c2, c1, c0)
        candidates.append((D1 + g[:, None, None] * D2, lead & np.isfinite(g)))
    for D, usable in candidates:
        # Non-zero eigenvalues of a singular symmetric 3x3: roots of s^2 - tr s + m = 0,
        # m the sum of its principal 2x2 minors; opposite signs iff m < 0.
        tr = D[:, 0, 0] + D[:, 1, 1] + D[:, 2, 2]
        m = (
            D[:, 0, 0] * D[:, 1, 1]
            - D[:, 0, 1] ** 2
            + D[:, 0, 0] * D[:, 2, 2]
            - D[:, 0, 2] ** 2
            + D[:, 1, 1] * D[:, 2, 2]
            - D[:, 1, 2] ** 2
        )
        with np.errstate(invalid="ignore"):
            root = np.sqrt(np.maximum(tr * tr - 4.0 * m, 0.0))
            big = 0.5 * (tr + np.where(tr >= 0, root, -root))  # the larger in magnitude
            small = np.where(big != 0, m / np.where(big != 0, big, 1.0), 0.0)
            quality = np.where(usable & (m < 0), np.abs(small) / np.abs(big), -1.0)
        take = quality > best_quality
        best[take] = D[take]
        best_s[take] = np.column_stack([big, small])[take]
        best_quality[take] = quality[take]
    return best, best_s[:, 0], best_s[:, 1]


def _cubic_real_roots(a: FloatArray, b: FloatArray, c: FloatArray) -> FloatArray:
    """(n, 3) real roots of x^3 + a x^2 + b x + c (NaN for complex ones), in closed form."""
    p = b - a * a / 3.0
    q = 2.0 * a**3 / 27.0 - a * b / 3.0 + c
    shift = -a / 3.0
    disc = (q / 2.0) ** 2 + (p / 3.0) ** 3
    out = np.full((len(a), 3), np.nan)
    with np.errstate(invalid="ignore", divide="ignore"):
        # One real root (Cardano).
        sq = np.sqrt(np.maximum(disc, 0.0))
        one = np.cbrt(-q / 2.0 + sq) + np.cbrt(-q / 2.0 - sq)
        # Three real roots (trigonometric form).
        rho = 2.0 * np.sqrt(np.maximum(-p / 3.0, 0.0))
        arg = np.clip(3.0 * q / (p * rho), -1.0, 1.0)
        phi = np.arccos(arg) / 3.0
    three = disc < 0
    out[:, 0] = np.where(three, rho * np.cos(phi), one) + shift
    out[:, 1] = np.where(three, rho * np.cos(phi - 2.0 * np.pi / 3.0) + shift, np.nan)
    out[:, 2] = np.where(three, rho * np.cos(phi - 4.0 * np.pi / 3.0) + shift, np.nan)
    return out


def _null_vector(A: FloatArray) -> FloatArray:
    """(n, 3) unit vectors spanning the null space of rank-2 (n, 3, 3) matrices: the
    longest cross product of two of their rows."""
    c = np.stack([np.cross(A[:, 0], A[:, 1]), np.cross(A[:, 0], A[:, 2]), np.cross(A[:, 1], A[:, 2])], axis=1)
    norms = np.einsum("kij,kij->ki", c, c)
    pick = np.argmax(norms, axis=1)
    v = c[np.arange(len(A)), pick]
    with np.errstate(invalid="ignore", divide="ignore"):
        out: FloatArray = v / np.sqrt(norms[np.arange(len(A)), pick])[:, None]
    return out


def _det(M: FloatArray) -> FloatArray:
    """Determinants of (n, 3, 3) matrices, by cofactors."""
    out: FloatArray = (
        M[:, 0, 0] * (M[:, 1, 1] * M[:, 2, 2] - M[:, 1, 2] * M[:, 2, 1])
        - M[:, 0, 1] * (M[:, 1, 0] * M[:, 2, 2] - M[:, 1, 2] * M[:, 2, 0])
        + M[:, 0, 2] * (M[:, 1, 0] * M[:, 2, 1] - M[:, 1, 1] * M[:, 2, 0])
    )
    return out


def _polish_root(g: FloatArray, c3: FloatArray, c2: FloatArray, c1: FloatArray, c0: FloatArray) -> FloatArray:
    """Two Newton steps on the cubic (the companion eigenvalues are accurate to ~1e-10)."""
    for _ in range(2):
        f = ((c3 * g + c2) * g + c1) * g + c0
        df = (3.0 * c3 * g + 2.0 * c2) * g + c1
        with np.errstate(invalid="ignore", divide="ignore"):
            step = np.where(np.abs(df) > 0, f / df, 0.0)
        g = g - step
    return g


def _adjugate(M: FloatArray) -> FloatArray:
    """Adjugate of (n, 3, 3) matrices (exists for singular ones, unlike the inverse)."""
    a = M
    adj = np.empty_like(a)
    adj[:, 0, 0] = a[:, 1, 1] * a[:, 2, 2] - a[:, 1, 2] * a[:, 2, 1]
    adj[:, 0, 1] = a[:, 0, 2] * a[:, 2, 1] - a[:, 0, 1] * a[:, 2, 2]
    adj[:, 0, 2] = a[:, 0, 1] * a[:, 1, 2] - a[:, 0, 2] * a[:, 1, 1]
    adj[:, 1, 0] = a[:, 1, 2] * a[:, 2, 0] - a[:, 1, 0] * a[:, 2, 2]
    adj[:, 1, 1] = a[:, 0, 0] * a[:, 2, 2] - a[:, 0, 2] * a[:, 2, 0]
    adj[:, 1, 2] = a[:, 0, 2] * a[:, 1, 0] - a[:, 0, 0] * a[:, 1, 2]
    adj[:, 2, 0] = a[:, 1, 0] * a[:, 2, 1] - a[:, 1, 1] * a[:, 2, 0]
    adj[:, 2, 1] = a[:, 0, 1] * a[:, 2, 0] - a[:, 0, 0] * a[:, 2, 1]
    adj[:, 2, 2] = a[:, 0, 0] * a[:, 1, 1] - a[:, 0, 1] * a[:, 1, 0]
    return adj


def _plane_basis(normal: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Orthonormal (p, q), each (n, 3), spanning the planes with the given normals."""
    nrm = normal / np.linalg.norm(normal, axis=1, keepdims=True)
    # Cross with the axis least aligned with the normal.
    axis = np.eye(3)[np.argmin(np.abs(nrm), axis=1)]
    p = np.cross(nrm, axis)
    p /= np.linalg.norm(p, axis=1, keepdims=True)
    q = np.cross(nrm, p)
    return p, q


def _restrict(D: FloatArray, p: FloatArray, q: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
    """The form D on the plane spanned by (p, q): (p^T D p, p^T D q, q^T D q), each (n,)."""
    Dp = _mv(D, p)
    Dq = _mv(D, q)
    return _dot(p, Dp), _dot(q, Dp), _dot(q, Dq)


def _quad(M: FloatArray, u: FloatArray) -> FloatArray:
    """(n,) u^T M u for (n, 3, 3) M and (n, 3) u."""
    return _dot(u, _mv(M, u))


# Small fixed-size products written out: numpy's reductions over axes of length 3 cost
# more than the arithmetic itself.
def _mv(M: FloatArray, v: FloatArray) -> FloatArray:
    """(n, 3): M @ v for (n, 3, 3) M and (n, 3) v."""
    out: FloatArray = np.stack(
        [M[:, i, 0] * v[:, 0] + M[:, i, 1] * v[:, 1] + M[:, i, 2] * v[:, 2] for i in range(3)], axis=1
    )
    return out


def _dot(a: FloatArray, b: FloatArray) -> FloatArray:
    out: FloatArray = a[:, 0] * b[:, 0] + a[:, 1] * b[:, 1] + a[:, 2] * b[:, 2]
    return out


def _sum9(M: FloatArray) -> FloatArray:
    """(n,) sums of (n, 3, 3) matrices' entries."""
    out: FloatArray = M.reshape(len(M), 9) @ np.ones(9)
    return out


def _residuals(lam: FloatArray, bb: FloatArray) -> FloatArray:
    """(K, 3) left-hand sides of the distance equations for pairs (12), (13), (23)."""
    l1, l2, l3 = lam[:, 0], lam[:, 1], lam[:, 2]
    return np.column_stack(
        [
            l1 * l1 + l2 * l2 - 2.0 * bb[:, 0] * l1 * l2,
            l1 * l1 + l3 * l3 - 2.0 * bb[:, 1] * l1 * l3,
            l2 * l2 + l3 * l3 - 2.0 * bb[:, 2] * l2 * l3,
        ]
    )


def _gauss_newton_step(lam: FloatArray, bb: FloatArray, aa: FloatArray) -> FloatArray:
    l1, l2, l3 = lam[:, 0], lam[:, 1], lam[:, 2]
    J = np.zeros((len(lam), 3, 3))
    J[:, 0, 0] = 2.0 * l1 - 2.0 * bb[:, 0] * l2
    J[:, 0, 1] = 2.0 * l2 - 2.0 * bb[:, 0] * l1
    J[:, 1, 0] = 2.0 * l1 - 2.0 * bb[:, 1] * l3
    J[:, 1, 2] = 2.0 * l3 - 2.0 * bb[:, 1] * l1
    J[:, 2, 1] = 2.0 * l2 - 2.0 * bb[:, 2] * l3
    J[:, 2, 2] = 2.0 * l3 - 2.0 * bb[:, 2] * l2
    r = _residuals(lam, bb) - aa
    det = _det(J)
    good = np.abs(det) > 1e-12 * np.maximum(np.abs(lam).max(axis=1), 1.0) ** 3
    step = _mv(_adjugate(J), r) / np.where(good, det, 1.0)[:, None]
    return np.where(good[:, None], lam - step, lam)


def _unique(idx: NDArray[np.int64], lam: FloatArray) -> tuple[NDArray[np.int64], FloatArray]:
    """Drop repeated solutions of one triple (the two planes can share a solution).

    A triple has at most 4 candidates, so after a stable sort by triple a repeat lies at
    most 3 places after its twin.
    """
    if len(idx) == 0:
        return idx, lam
    order = np.argsort(idx, kind="stable")
    idx, lam = idx[order], lam[order]
    scale = np.maximum(lam.max(axis=1), 1.0)
    dup = np.zeros(len(idx), dtype=bool)
    for shift in (1, 2, 3):
        if shift >= len(idx):
            break
        same = (idx[shift:] == idx[:-shift]) & (
            np.abs(lam[shift:] - lam[:-shift]).max(axis=1) <= 1e-7 * scale[shift:]
        )
        dup[shift:] |= same & ~dup[:-shift]
    return idx[~dup], lam[~dup]


# The compiled kernel: the steps of p3p_numpy for one triple at a time.


@njit
def _p3p_kernel(y: FloatArray, x: FloatArray, out_idx: NDArray[np.int64], out_lam: FloatArray) -> int:
    """Solve each triple; write its solutions to ``out_idx``/``out_lam`` (room for 4 per
    triple) and return how many there are."""
    Y = np.empty((3, 3))
    M12 = np.zeros((3, 3))
    M13 = np.zeros((3, 3))
    M23 = np.zeros((3, 3))
    D1 = np.empty((3, 3))
    D2 = np.empty((3, 3))
    D0 = np.empty((3, 3))
    T = np.empty((3, 3))
    Msum = np.empty((3, 3))
    J = np.zeros((3, 3))
    e1 = np.empty(3)
    e2 = np.empty(3)
    normal = np.empty(3)
    p = np.empty(3)
    q = np.empty(3)
    lam = np.empty(3)
    found = np.empty((4, 3))
    count = 0
    for k in range(y.shape[0]):
        for i in range(3):
            nr = np.sqrt(y[k, i, 0] ** 2 + y[k, i, 1] ** 2 + y[k, i, 2] ** 2)
            for j in range(3):
                Y[i, j] = y[k, i, j] / nr
        a12 = _k_sqdist(x, k, 0, 1)
        a13 = _k_sqdist(x, k, 0, 2)
        a23 = _k_sqdist(x, k, 1, 2)
        b12 = Y[0, 0] * Y[1, 0] + Y[0, 1] * Y[1, 1] + Y[0, 2] * Y[1, 2]
        b13 = Y[0, 0] * Y[2, 0] + Y[0, 1] * Y[2, 1] + Y[0, 2] * Y[2, 2]
        b23 = Y[1, 0] * Y[2, 0] + Y[1, 1] * Y[2, 1] + Y[1, 2] * Y[2, 2]
        _k_form(M12, 0, 1, b12)
        _k_form(M13, 0, 2, b13)
        _k_form(M23, 1, 2, b23)
        for i in range(3):
            for j in range(3):
                D1[i, j] = a23 * M12[i, j] - a12 * M23[i, j]
                D2[i, j] = a23 * M13[i, j] - a13 * M23[i, j]
                Msum[i, j] = M12[i, j] + M13[i, j] + M23[i, j]
        s1, s2 = _k_degenerate_member(D1, D2, D0, T)
        if not s1 * s2 < 0:  # NaN too: no usable pair of planes
            continue
        for i in range(3):
            for j in range(3):
                T[i, j] = D0[i, j] - (s1 if i == j else 0.0)
        _k_null_vector(T, e1)
        for i in range(3):
            T[i, i] = D0[i, i] - s2
        _k_null_vector(T, e2)
        ratio = np.sqrt(-s2 / s1)
        asum = a12 + a13 + a23
        scale = max(asum, 2.2250738585072014e-308)
        n_found = 0
        for sign in (1.0, -1.0):
            for i in range(3):
                normal[i] = e1[i] + sign * ratio * e2[i]
            _k_plane_basis(normal, p, q)
            A1, B1, C1 = _k_restrict(D1, p, q)
            A2, B2, C2 = _k_restrict(D2, p, q)
            if A1 * A1 + 2 * B1 * B1 + C1 * C1 >= A2 * A2 + 2 * B2 * B2 + C2 * C2:
                A, B, C = A1, B1, C1
            else:
                A, B, C = A2, B2, C2
            R = np.hypot(0.5 * (A - C), B)
            phi = np.arctan2(B, 0.5 * (A - C))
            arg = -0.5 * (A + C) / R
            if not abs(arg) <= 1.0 + 1e-9:
                continue
            arg = min(max(arg, -1.0), 1.0)
            for branch in (1.0, -1.0):
                t = 0.5 * (phi + branch * np.arccos(arg))
                c, sn = np.cos(t), np.sin(t)
                for i in range(3):
                    lam[i] = c * p[i] + sn * q[i]
                quad = 0.0
                for i in range(3):
                    quad += lam[i] * (Msum[i, 0] * lam[0] + Msum[i, 1] * lam[1] + Msum[i, 2] * lam[2])
                kk = np.sqrt(asum / quad)
                if lam[0] + lam[1] + lam[2] < 0:
                    kk = -kk
                good = True
                for i in range(3):
                    lam[i] *= kk
                    good = good and np.isfinite(lam[i]) and lam[i] > 0
                if not good:
                    continue
                for _ in range(_GAUSS_NEWTON_STEPS):
                    _k_gauss_newton_step(lam, b12, b13, b23, a12, a13, a23, J, T)
                r12, r13, r23 = _k_residuals(lam, b12, b13, b23)
                res = max(abs(r12 - a12), abs(r13 - a13), abs(r23 - a23)) / scale
                if not (np.isfinite(res) and res < _RELATIVE_TOLERANCE):
                    continue
                if not (lam[0] > 0 and lam[1] > 0 and lam[2] > 0):
                    continue
                tol = 1e-7 * max(lam[0], lam[1], lam[2], 1.0)
                dup = False
                for m in range(n_found):
                    d = max(abs(lam[0] - found[m, 0]), abs(lam[1] - found[m, 1]), abs(lam[2] - found[m, 2]))
                    dup = dup or d <= tol
                if dup:
                    continue
                for i in range(3):
                    found[n_found, i] = lam[i]
                    out_lam[count, i] = lam[i]
                out_idx[count] = k
                n_found += 1
                count += 1
    return count


@njit
def _k_sqdist(x: FloatArray, k: int, i: int, j: int) -> float:
    d0 = x[k, i, 0] - x[k, j, 0]
    d1 = x[k, i, 1] - x[k, j, 1]
    d2 = x[k, i, 2] - x[k, j, 2]
    return float(d0 * d0 + d1 * d1 + d2 * d2)


@njit
def _k_form(M: FloatArray, i: int, j: int, b: float) -> None:
    M[i, i] = 1.0
    M[j, j] = 1.0
    M[i, j] = -b
    M[j, i] = -b


@njit
def _k_det(M: FloatArray) -> float:
    return float(
        M[0, 0] * (M[1, 1] * M[2, 2] - M[1, 2] * M[2, 1])
        - M[0, 1] * (M[1, 0] * M[2, 2] - M[1, 2] * M[2, 0])
        + M[0, 2] * (M[1, 0] * M[2, 1] - M[1, 1] * M[2, 0])
    )


@njit
def _k_adj_dot(a: FloatArray, b: FloatArray) -> float:
    """Sum of the entries of adj(a) * b (elementwise)."""
    return float(
        (a[1, 1] * a[2, 2] - a[1, 2] * a[2, 1]) * b[0, 0]
        + (a[0, 2] * a[2, 1] - a[0, 1] * a[2, 2]) * b[0, 1]
        + (a[0, 1] * a[1, 2] - a[0, 2] * a[1, 1]) * b[0, 2]
        + (a[1, 2] * a[2, 0] - a[1, 0] * a[2, 2]) * b[1, 0]
        + (a[0, 0] * a[2, 2] - a[0, 2] * a[2, 0]) * b[1, 1]
        + (a[0, 2] * a[1, 0] - a[0, 0] * a[1, 2]) * b[1, 2]
        + (a[1, 0] * a[2, 1] - a[1, 1] * a[2, 0]) * b[2, 0]
        + (a[0, 1] * a[2, 0] - a[0, 0] * a[2, 1]) * b[2, 1]
        + (a[0, 0] * a[1, 1] - a[0, 1] * a[1, 0]) * b[2, 2]
    )


@njit
def _k_degenerate_member(
    D1: FloatArray, D2: FloatArray, D0: FloatArray, D: FloatArray
) -> tuple[float, float]:
    """:func:`_degenerate_member` for one triple: fills D0, returns (s1, s2) (NaN: none)."""
    c0 = _k_det(D1)
    c3 = _k_det(D2)
    c1 = _k_adj_dot(D1, D2)
    c2 = _k_adj_dot(D2, D1)
    lead = abs(c3) > 1e-12 * (abs(c0) + abs(c1) + abs(c2) + 1e-300)
    best_quality = -1.0
    s1 = np.nan
    s2 = np.nan
    roots = _k_cubic_real_roots(c2 / c3, c1 / c3, c0 / c3) if lead else (np.nan, np.nan, np.nan)
    for r in range(4):
        if r == 0:
            if lead:
                continue
            for i in range(3):
                for j in range(3):
                    D[i, j] = D2[i, j]
        else:
            g = roots[r - 1]
            if not np.isfinite(g):
                continue
            for _ in range(2):  # Newton steps on the cubic, as _polish_root
                f = ((c3 * g + c2) * g + c1) * g + c0
                df = (3.0 * c3 * g + 2.0 * c2) * g + c1
                if abs(df) > 0:
                    g = g - f / df
            if not np.isfinite(g):
                continue
            for i in range(3):
                for j in range(3):
                    D[i, j] = D1[i, j] + g * D2[i, j]
        tr = D[0, 0] + D[1, 1] + D[2, 2]
        m = (
            D[0, 0] * D[1, 1]
            - D[0, 1] ** 2
            + D[0, 0] * D[2, 2]
            - D[0, 2] ** 2
            + D[1, 1] * D[2, 2]
            - D[1, 2] ** 2
        )
        if not m < 0:
            continue
        root = np.sqrt(max(tr * tr - 4.0 * m, 0.0))
        big = 0.5 * (tr + (root if tr >= 0 else -root))
        small = m / big if big != 0 else 0.0
        quality = abs(small) / abs(big)
        if quality > best_quality:
            best_quality = quality
            s1, s2 = big, small
            for i in range(3):
                for j in range(3):
                    D0[i, j] = D[i, j]
    return s1, s2


@njit
def _k_cubic_real_roots(a: float, b: float, c: float) -> tuple[float, float, float]:
    """:func:`_cubic_real_roots` for one cubic."""
    p = b - a * a / 3.0
    q = 2.0 * a**3 / 27.0 - a * b / 3.0 + c
    shift = -a / 3.0
    disc = (q / 2.0) ** 2 + (p / 3.0) ** 3
    if disc < 0:
        rho = 2.0 * np.sqrt(max(-p / 3.0, 0.0))
        phi = np.arccos(min(max(3.0 * q / (p * rho), -1.0), 1.0)) / 3.0
        return (
            rho * np.cos(phi) + shift,
            rho * np.cos(phi - 2.0 * np.pi / 3.0) + shift,
            rho * np.cos(phi - 4.0 * np.pi / 3.0) + shift,
        )
    sq = np.sqrt(max(disc, 0.0))
    return np.cbrt(-q / 2.0 + sq) + np.cbrt(-q / 2.0 - sq) + shift, np.nan, np.nan


@njit
def _k_null_vector(A: FloatArray, out: FloatArray) -> None:
    """:func:`_null_vector` for one matrix."""
    best = -1.0
    for r1, r2 in ((0, 1), (0, 2), (1, 2)):
        c0 = A[r1, 1] * A[r2, 2] - A[r1, 2] * A[r2, 1]
        c1 = A[r1, 2] * A[r2, 0] - A[r1, 0] * A[r2, 2]
        c2 = A[r1, 0] * A[r2, 1] - A[r1, 1] * A[r2, 0]
        nn = c0 * c0 + c1 * c1 + c2 * c2
        if nn > best or best < 0:
            best = nn
            out[0], out[1], out[2] = c0, c1, c2
    nr = np.sqrt(best)
    for i in range(3):
        out[i] /= nr


@njit
def _k_plane_basis(normal: FloatArray, p: FloatArray, q: FloatArray) -> None:
    """:func:`_plane_basis` for one plane."""
    nr = np.sqrt(normal[0] ** 2 + normal[1] ** 2 + normal[2] ** 2)
    n0, n1, n2 = normal[0] / nr, normal[1] / nr, normal[2] / nr
    a = 0
    if abs(n1) < abs(n0):
        a = 1
    if abs(n2) < min(abs(n0), abs(n1)):
        a = 2
    # p = n x e_a
    if a == 0:
        p0, p1, p2 = 0.0, n2, -n1
    elif a == 1:
        p0, p1, p2 = -n2, 0.0, n0
    else:
        p0, p1, p2 = n1, -n0, 0.0
    pn = np.sqrt(p0 * p0 + p1 * p1 + p2 * p2)
    p[0], p[1], p[2] = p0 / pn, p1 / pn, p2 / pn
    q[0] = n1 * p[2] - n2 * p[1]
    q[1] = n2 * p[0] - n0 * p[2]
    q[2] = n0 * p[1] - n1 * p[0]


@njit
def _k_restrict(D: FloatArray, p: FloatArray, q: FloatArray) -> tuple[float, float, float]:
    A = 0.0
    B = 0.0
    C = 0.0
    for i in range(3):
        Dp = D[i, 0] * p[0] + D[i, 1] * p[1] + D[i, 2] * p[2]
        Dq = D[i, 0] * q[0] + D[i, 1] * q[1] + D[i, 2] * q[2]
        A += p[i] * Dp
        B += q[i] * Dp
        C += q[i] * Dq
    return A, B, C


@njit
def _k_residuals(lam: FloatArray, b12: float, b13: float, b23: float) -> tuple[float, float, float]:
    l1, l2, l3 = lam[0], lam[1], lam[2]
    return (
        l1 * l1 + l2 * l2 - 2.0 * b12 * l1 * l2,
        l1 * l1 + l3 * l3 - 2.0 * b13 * l1 * l3,
        l2 * l2 + l3 * l3 - 2.0 * b23 * l2 * l3,
    )


@njit
def _k_gauss_newton_step(
    lam: FloatArray,
    b12: float,
    b13: float,
    b23: float,
    a12: float,
    a13: float,
    a23: float,
    J: FloatArray,
    adj: FloatArray,
) -> None:
    """:func:`_gauss_newton_step` for one solution, in place."""
    l1, l2, l3 = lam[0], lam[1], lam[2]
    J[0, 0] = 2.0 * l1 - 2.0 * b12 * l2
    J[0, 1] = 2.0 * l2 - 2.0 * b12 * l1
    J[1, 0] = 2.0 * l1 - 2.0 * b13 * l3
    J[1, 2] = 2.0 * l3 - 2.0 * b13 * l1
    J[2, 1] = 2.0 * l2 - 2.0 * b23 * l3
    J[2, 2] = 2.0 * l3 - 2.0 * b23 * l2
    r12, r13, r23 = _k_residuals(lam, b12, b13, b23)
    r0, r1, r2 = r12 - a12, r13 - a13, r23 - a23
    det = _k_det(J)
    if not abs(det) > 1e-12 * max(abs(l1), abs(l2), abs(l3), 1.0) ** 3:
        return
    a = J
    adj[0, 0] = a[1, 1] * a[2, 2] - a[1, 2] * a[2, 1]
    adj[0, 1] = a[0, 2] * a[2, 1] - a[0, 1] * a[2, 2]
    adj[0, 2] = a[0, 1] * a[1, 2] - a[0, 2] * a[1, 1]
    adj[1, 0] = a[1, 2] * a[2, 0] - a[1, 0] * a[2, 2]
    adj[1, 1] = a[0, 0] * a[2, 2] - a[0, 2] * a[2, 0]
    adj[1, 2] = a[0, 2] * a[1, 0] - a[0, 0] * a[1, 2]
    adj[2, 0] = a[1, 0] * a[2, 1] - a[1, 1] * a[2, 0]
    adj[2, 1] = a[0, 1] * a[2, 0] - a[0, 0] * a[2, 1]
    adj[2, 2] = a[0, 0] * a[1, 1] - a[0, 1] * a[1, 0]
    for i in range(3):
        lam[i] -= (adj[i, 0] * r0 + adj[i, 1] * r1 + adj[i, 2] * r2) / det
