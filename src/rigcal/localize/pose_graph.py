"""A 2D pose graph and its robust optimum, on scipy (the default) or on GTSAM.

The nodes are laser poses (x, y, yaw) in the world frame; each edge measures T_a_b, the
pose of node b in node a's frame, with a 1-sigma per component or a full covariance
(ICP's from its Hessian; :func:`rigcal.localize.icp.icp_covariance`). The error of an
edge is the components of z^-1 a^-1 b (x, y in z's frame, the yaw difference wrapped),
whitened by its covariance (e -> U e with U^T U = Sigma^-1, U the upper Cholesky factor
of the information); edges marked robust (loop closures) are weighed by the Cauchy kernel,
rho(r) = c^2/2 log(1 + |r|^2/c^2), so that a false closure that passed the verification
is down-weighted instead of bending the map (Sunderhauf and Protzel 2012; Agarwal et al.
2013 compare it with switchable constraints). The first pose is held.

- ``scipy``: Gauss-Newton by iteratively reweighted least squares (each robust edge
  weighs 1 / (1 + |r|^2 / c^2), the Cauchy kernel's weight), the sparse normal equations
  assembled in 3 x 3 blocks per edge and solved as symmetric positive definite by
  scipy's SuperLU, until a step moves no pose by ``STEP_TOLERANCE``.
- ``gtsam``: GTSAM's Levenberg-Marquardt on ``BetweenFactorPose2`` factors, robust
  edges under ``noiseModel.Robust`` with its Cauchy m-estimator (the same weight); needs
  the optional extra ``rigcal[gtsam]``.

Both reach the same optimum (the tests hold them to each other); GTSAM's Pose2 measures
an edge's error on SE(2)'s chart rather than by components, which moves the optimum by the
second order of the residuals (well under a millimetre at centimetre residuals).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.sparse import csc_matrix, csr_matrix, diags
from scipy.sparse.linalg import splu, spsolve

from rigcal.arrays import FloatArray
from rigcal.errors import InputError

BACKENDS = ("scipy", "gtsam")
# The Cauchy kernel's scale (whitened residual) and the iterations at most.
KERNEL_SCALE = 3.0
MAX_ITERATIONS = 30
# The scipy back end stops when a step moves no pose by this (m, rad): a micrometre, far
# below any edge's sigma; the Cauchy kernel's reweighting converges linearly, and each
# further digit costs several more solves of the whole graph.
STEP_TOLERANCE = 1e-6
# The first pose's prior in GTSAM (held, as the scipy back end leaves it out).
_HELD_SIGMA = 1e-9


@dataclass(frozen=True)
class PoseGraph:
    """Nodes and edges (module docstring).

    Attributes:
        poses: (N, 3) the initial poses (x, y, yaw; m, rad), world frame.
        a, b: (M,) the nodes of each edge.
        z: (M, 3) each edge's measurement T_a_b (x, y, yaw).
        sigmas: (M, 3) its 1-sigma (m, m, rad).
        robust: (M,) bool, the edges under the Cauchy kernel.
        covariances: (M, 3, 3) each edge's full covariance of (x, y, yaw), or None; an
            edge whose covariance is not finite (or not positive definite) takes
            ``sigmas`` instead.
    """

    poses: FloatArray
    a: NDArray[np.intp]
    b: NDArray[np.intp]
    z: FloatArray
    sigmas: FloatArray
    robust: NDArray[np.bool_]
    covariances: FloatArray | None = None

    def whiteners(self) -> FloatArray:
        """(M, 3, 3) each edge's square-root information U (U^T U = Sigma^-1): the
        whitened error is U e."""
        out = np.zeros((len(self.a), 3, 3))
        idx = np.arange(3)
        out[:, idx, idx] = 1.0 / self.sigmas
        if self.covariances is None:
            return out
        cov = self.covariances
        ok = np.flatnonzero(np.isfinite(cov).all(axis=(1, 2)))
        ok = ok[np.linalg.eigvalsh(cov[ok])[:, 0] > 0]
        # Sigma = L L^T -> Sigma^-1 = L^-T L^-1: U = L^-1.
        out[ok] = np.linalg.inv(np.linalg.cholesky(cov[ok]))
        return out


def gtsam_available() -> bool:
    """Whether GTSAM imports (the optional extra ``rigcal[gtsam]``)."""
    try:
        import gtsam  # noqa: F401
    except ImportError:
        return False
    return True


def optimise(graph: PoseGraph, backend: str = "scipy") -> tuple[FloatArray, FloatArray]:
    """The graph's optimum (N, 3), the first pose held and each yaw kept continuous with
    the initial one, and each edge's whitened residual norm there (M,).

    Raises:
        InputError: an unknown back end, or ``gtsam`` where GTSAM is not installed.
    """
    if backend == "scipy":
        out = _scipy_optimum(graph)
    elif backend == "gtsam":
        if not gtsam_available():
            raise InputError.at(
                None,
                "--pose-graph",
                backend,
                "a back end installed here: GTSAM needs `pip install rigcal[gtsam]`",
            )
        out = _gtsam_optimum(graph)
    else:
        raise InputError.at(None, "--pose-graph", backend, f"one of {', '.join(BACKENDS)}")
    r = np.einsum("mij,mj->mi", graph.whiteners(), edge_errors(out[graph.a], out[graph.b], graph.z))
    return out, np.linalg.norm(r, axis=1)


def _scipy_optimum(g: PoseGraph) -> FloatArray:
    """Gauss-Newton by IRLS (module docstring): the normal equations H dx = -g assembled
    edge by edge in 3 x 3 blocks (edge (a, b) adds A^T w A, A^T w B, B^T w A, B^T w B,
    A and B its whitened Jacobians by pose a and b, w its kernel weight) into a sparsity
    pattern found once, and solved as the symmetric positive definite system it is
    (SuperLU on the minimum-degree ordering of H, without pivoting): the same steps as
    :func:`_scipy_optimum_reference`'s generic sparse least squares at a fraction of the
    cost; a loop closure run re-optimises its graph at each correction."""
    n = len(g.poses)
    if n < 2:
        return g.poses.copy()
    W = g.whiteners()  # (M, 3, 3)
    pattern = _BlockPattern(g.a, g.b, n)
    p = g.poses.copy()
    for _ in range(MAX_ITERATIONS):
        r = np.einsum("mij,mj->mi", W, edge_errors(p[g.a], p[g.b], g.z))
        weight = np.where(g.robust, 1.0 / (1.0 + np.sum(r**2, axis=1) / KERNEL_SCALE**2), 1.0)
        Ja, Jb = edge_jacobians(p[g.a], p[g.b], g.z)
        A, B = W @ Ja, W @ Jb
        wA, wB = weight[:, None, None] * A, weight[:, None, None] * B
        wr = weight[:, None] * r
        H = pattern.matrix(
            np.einsum("mki,mkj->mij", A, wA),
            np.einsum("mki,mkj->mij", A, wB),
            np.einsum("mki,mkj->mij", B, wB),
        )
        grad = pattern.vector(np.einsum("mki,mk->mi", A, wr), np.einsum("mki,mk->mi", B, wr))
        lu = splu(H, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0, options={"SymmetricMode": True})
        step = lu.solve(-grad)
        p[1:] += step.reshape(-1, 3)
        if np.abs(step).max() < STEP_TOLERANCE:
            break
    return p


class _BlockPattern:
    """The normal equations' sparsity of a graph's edges (a, b) over poses 1..n-1 (pose 0
    held): where each edge's four 3 x 3 blocks go in H (CSC, summed where edges share a
    block) and its two 3-blocks in the gradient."""

    def __init__(self, a: NDArray[np.intp], b: NDArray[np.intp], n: int) -> None:
        i3 = np.arange(3)
        rows, cols = [], []
        for u, v in ((a, a), (a, b), (b, a), (b, b)):
            rows.append((3 * (u[:, None, None] - 1) + i3[None, :, None]).repeat(3, axis=2))
            cols.append((3 * (v[:, None, None] - 1) + i3[None, None, :]).repeat(3, axis=1))
        row, col = np.stack(rows), np.stack(cols)  # (4, M, 3, 3)
        self.keep = (row >= 0) & (col >= 0)
        size = 3 * (n - 1)
        # CSC order: by column, then row.
        key = col[self.keep].astype(np.int64) * size + row[self.keep]
        unique, self.slot = np.unique(key, return_inverse=True)
        self.indices = (unique % size).astype(np.int32)
        self.indptr = np.searchsorted(unique // size, np.arange(size + 1)).astype(np.int32)
        self.size = size
        self.ga, self.gb = 3 * (a[:, None] - 1) + i3, 3 * (b[:, None] - 1) + i3  # (M, 3)

    def matrix(self, aa: FloatArray, ab: FloatArray, bb: FloatArray) -> csc_matrix:
        """H (size, size) from the edges' blocks A^T w A, A^T w B, B^T w B (M, 3, 3)."""
        vals = np.stack([aa, ab, ab.transpose(0, 2, 1), bb])[self.keep]
        data = np.bincount(self.slot, weights=vals, minlength=len(self.indices))
        return csc_matrix((data, self.indices, self.indptr), shape=(self.size, self.size))

    def vector(self, ga: FloatArray, gb: FloatArray) -> FloatArray:
        """The gradient (size,) from the edges' 3-blocks A^T w r, B^T w r (M, 3)."""
        idx, vals = (
            np.concatenate([self.ga.ravel(), self.gb.ravel()]),
            np.concatenate([ga.ravel(), gb.ravel()]),
        )
        keep = idx >= 0
        return np.bincount(idx[keep], weights=vals[keep], minlength=self.size)


def _scipy_optimum_reference(g: PoseGraph) -> FloatArray:
    """:func:`_scipy_optimum`'s reference: the whitened Jacobian as a generic sparse
    matrix J, H = J^T diag(w) J, solved by SuperLU with partial pivoting."""
    n, m = len(g.poses), len(g.a)
    W = g.whiteners()  # (M, 3, 3)
    rows3 = np.repeat(np.arange(3 * m).reshape(-1, 3, 1), 3, axis=2)  # (M, 3, 3) row index

    def jacobian(p: FloatArray) -> csr_matrix:
        Ja, Jb = edge_jacobians(p[g.a], p[g.b], g.z)
        rows, cols, vals = [], [], []
        for v, J in ((g.a, Ja), (g.b, Jb)):
            c = 3 * (v[:, None, None] - 1) + np.arange(3)[None, None, :]  # column of pose v - 1
            keep = np.broadcast_to((v > 0)[:, None, None], J.shape)
            rows.append(rows3[keep])
            cols.append(np.broadcast_to(c, J.shape)[keep])
            vals.append(np.einsum("mij,mjk->mik", W, J)[keep])
        return csr_matrix(
            (np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(3 * m, 3 * (n - 1))
        )

    p = g.poses.copy()
    for _ in range(MAX_ITERATIONS):
        r = np.einsum("mij,mj->mi", W, edge_errors(p[g.a], p[g.b], g.z))
        weight = np.where(g.robust, 1.0 / (1.0 + np.sum(r**2, axis=1) / KERNEL_SCALE**2), 1.0)
        J = jacobian(p)
        wr = np.repeat(weight, 3)
        H = (J.T @ diags(wr) @ J).tocsc()
        step = spsolve(H, -(J.T @ (wr * r.ravel())))
        p[1:] += step.reshape(-1, 3)
        if np.abs(step).max() < STEP_TOLERANCE:
            break
    return p


def _gtsam_optimum(g: PoseGraph) -> FloatArray:
    import gtsam

    graph = gtsam.NonlinearFactorGraph()
    values = gtsam.Values()
    for k, p in enumerate(g.poses):
        values.insert(k, gtsam.Pose2(*p))
    graph.add(
        gtsam.PriorFactorPose2(0, gtsam.Pose2(*g.poses[0]), gtsam.noiseModel.Isotropic.Sigma(3, _HELD_SIGMA))
    )
    cauchy = gtsam.noiseModel.mEstimator.Cauchy.Create(KERNEL_SCALE)
    for a, b, z, U, robust in zip(g.a, g.b, g.z, g.whiteners(), g.robust, strict=True):
        noise: Any = gtsam.noiseModel.Gaussian.Information(U.T @ U)
        if robust:
            noise = gtsam.noiseModel.Robust.Create(cauchy, noise)
        graph.add(gtsam.BetweenFactorPose2(int(a), int(b), gtsam.Pose2(*z), noise))
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(100)
    params.setRelativeErrorTol(1e-12)
    params.setAbsoluteErrorTol(1e-12)
    result = gtsam.LevenbergMarquardtOptimizer(graph, values, params).optimize()
    out = np.array([[q.x(), q.y(), q.theta()] for q in (result.atPose2(k) for k in range(len(g.poses)))])
    # Pose2 wraps the yaw into (-pi, pi]: keep it continuous with the initial poses.
    out[:, 2] = g.poses[:, 2] + np.angle(np.exp(1j * (out[:, 2] - g.poses[:, 2])))
    return out


def edge_errors(pa: FloatArray, pb: FloatArray, z: FloatArray) -> FloatArray:
    """(M, 3) the error of each edge's measurement z (T_a_b) at poses a, b: the components
    of z^-1 a^-1 b, vectorised."""
    c, s = np.cos(pa[:, 2]), np.sin(pa[:, 2])
    dx, dy = pb[:, 0] - pa[:, 0], pb[:, 1] - pa[:, 1]
    rel = np.column_stack([c * dx + s * dy, -s * dx + c * dy, pb[:, 2] - pa[:, 2]])
    cz, sz = np.cos(z[:, 2]), np.sin(z[:, 2])
    ex, ey = rel[:, 0] - z[:, 0], rel[:, 1] - z[:, 1]
    yaw = np.angle(np.exp(1j * (rel[:, 2] - z[:, 2])))
    return np.column_stack([cz * ex + sz * ey, -sz * ex + cz * ey, yaw])


def edge_jacobians(pa: FloatArray, pb: FloatArray, z: FloatArray) -> tuple[FloatArray, FloatArray]:
    """(M, 3, 3) the derivatives of :func:`edge_errors` by pose a and by pose b (x, y, yaw)."""
    c, s = np.cos(pa[:, 2]), np.sin(pa[:, 2])
    cz, sz = np.cos(z[:, 2]), np.sin(z[:, 2])
    dx, dy = pb[:, 0] - pa[:, 0], pb[:, 1] - pa[:, 1]
    # e_xy = Rz^T Ra^T (tb - ta) - Rz^T tz; M = Rz^T Ra^T = R(-(yaw_a + yaw_z)).
    cm, sm = np.cos(pa[:, 2] + z[:, 2]), np.sin(pa[:, 2] + z[:, 2])
    M = np.stack([np.stack([cm, sm], -1), np.stack([-sm, cm], -1)], 1)  # (M, 2, 2)
    # d(Ra^T d)/dyaw_a = (-s dx + c dy, -c dx - s dy), then Rz^T.
    gx, gy = -s * dx + c * dy, -c * dx - s * dy
    dyaw = np.column_stack([cz * gx + sz * gy, -sz * gx + cz * gy])
    Ja = np.zeros((len(pa), 3, 3))
    Jb = np.zeros((len(pa), 3, 3))
    Ja[:, :2, :2] = -M
    Ja[:, :2, 2] = dyaw
    Ja[:, 2, 2] = -1.0
    Jb[:, :2, :2] = M
    Jb[:, 2, 2] = 1.0
    return Ja, Jb
