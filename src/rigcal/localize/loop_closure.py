"""Loop closure: scan-to-submap closures, verified, and a pose graph with a robust kernel.

The paper names automatic loop closure as its future work (Section VIII). Here, on top of
any odometry (ICP, ICP from the wheels, H-IASM):

1. **Proposals.** Keyframes every :attr:`LoopParams.keyframe_m` of path. A keyframe i
   and an earlier keyframe j are proposed as a closure when the path between them is at
   least ``min_loop_m`` long and the odometry puts them within ``search_m`` plus
   ``drift_fraction`` of that path of each other (the odometry's drift grows with the
   path); each keyframe proposes its nearest such j.
2. **Verification.** Keyframe i's scan is matched by point-to-line ICP to the submap of
   j (j's scan and its neighbours within ``submap_scans``, moved into j's frame by the
   odometry), started from the odometry's relative pose and, since that may be metres
   off after a long loop, from a grid of offsets around it; the closure is accepted when
   the best fit keeps at least ``min_inliers`` of the points as inliers with an RMS
   below ``max_rms_m`` and the scans constrain every direction (degeneracy indicator
   above ``min_degeneracy``: a corridor's length is not a closure).
3. **Pose graph.** The odometry steps between consecutive scans (1-sigma
   ``step_sigmas`` per metre of step plus a floor) and the accepted closures
   (``closure_sigmas``) are the edges; the poses minimise their whitened residuals under
   a Cauchy kernel (Gauss-Newton, iteratively reweighted, on scipy's sparse solver), so
   a false closure that
   passed the verification is down-weighted instead of bending the map. A closure whose
   whitened residual stays above ``reject_whitened`` after the optimisation contradicts
   the others and is reported as rejected by the kernel.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray
from scipy.sparse import csr_matrix, diags
from scipy.sparse.linalg import spsolve

from rigcal.geometry import pose_of, se2
from rigcal.localize.icp import IcpParams, icp
from rigcal.scan import Scan

FloatArray = NDArray[np.float64]


# The Cauchy kernel's scale (whitened residual) and the Gauss-Newton iterations at most.
KERNEL_SCALE = 3.0
MAX_ITERATIONS = 30


@dataclass(frozen=True)
class LoopParams:
    """Loop closure's settings (module docstring)."""

    keyframe_m: float = 1.0
    min_loop_m: float = 10.0
    search_m: float = 2.0
    drift_fraction: float = 0.05
    submap_scans: int = 2
    min_inliers: float = 0.8
    max_rms_m: float = 0.06
    min_degeneracy: float = 0.05
    grid_m: float = 0.5
    step_sigmas: tuple[float, float, float] = (0.002, 0.002, 0.001)  # m, m, rad (floor)
    step_sigma_per_m: float = 0.02
    closure_sigmas: tuple[float, float, float] = (0.05, 0.05, 0.02)
    reject_whitened: float = 5.0


@dataclass(frozen=True)
class Closure:
    """A proposed closure: keyframe scan i matched to scan j; T_j_i (x, y, yaw) when it
    passed the verification, and why not otherwise."""

    i: int
    j: int
    T_j_i: FloatArray | None
    inliers: float = 0.0
    rms_m: float = float("nan")
    why_not: str = ""
    kernel_rejected: bool = False


@dataclass(frozen=True)
class LoopResult:
    """The optimised poses (N, 3) and the closures proposed (accepted and not)."""

    poses: FloatArray
    closures: list[Closure] = field(default_factory=list)

    @property
    def counts(self) -> dict[str, int]:
        verified = [c for c in self.closures if c.T_j_i is not None]
        return {
            "proposed": len(self.closures),
            "accepted": sum(1 for c in verified if not c.kernel_rejected),
            "rejected_by_verification": len(self.closures) - len(verified),
            "rejected_by_kernel": sum(1 for c in verified if c.kernel_rejected),
        }


def close_loops(
    scans: list[Scan] | tuple[Scan, ...], poses: FloatArray, params: LoopParams | None = None
) -> LoopResult:
    """Loop closure over an odometry's poses (N, 3) of the scans (module docstring)."""
    params = params or LoopParams()
    proposals = propose(poses, params)
    closures = [verify(scans, poses, i, j, params) for i, j in proposals]
    accepted = [c for c in closures if c.T_j_i is not None]
    if not accepted:
        return LoopResult(poses.copy(), closures)
    optimised, whitened = optimise(poses, accepted, params)
    flags = iter(whitened > params.reject_whitened)
    out = []
    for c in closures:
        if c.T_j_i is not None and next(flags):
            c = Closure(c.i, c.j, c.T_j_i, c.inliers, c.rms_m, "contradicts the other edges", True)
        out.append(c)
    return LoopResult(optimised, out)


def propose(poses: FloatArray, params: LoopParams) -> list[tuple[int, int]]:
    """(i, j) pairs, j < i, of keyframes the odometry puts close after a long path."""
    along = np.r_[0.0, np.cumsum(np.hypot(*np.diff(poses[:, :2], axis=0).T))]
    keys = [0]
    for k in range(1, len(poses)):
        if along[k] - along[keys[-1]] >= params.keyframe_m:
            keys.append(k)
    kf = np.array(keys)
    out = []
    for a, i in enumerate(kf):
        earlier = kf[:a]
        path = along[i] - along[earlier]
        ok = path >= params.min_loop_m
        if not ok.any():
            continue
        d = np.hypot(*(poses[earlier, :2] - poses[i, :2]).T)
        reach = params.search_m + params.drift_fraction * path
        near = np.flatnonzero(ok & (d <= reach))
        if len(near):
            out.append((int(i), int(earlier[near[np.argmin(d[near])]])))
    return out


def verify(
    scans: list[Scan] | tuple[Scan, ...], poses: FloatArray, i: int, j: int, params: LoopParams
) -> Closure:
    """Match scan i to scan j's submap; the closure T_j_i when the fit passes the test."""
    T_j = se2(poses[j])
    parts = []
    for k in range(max(0, j - params.submap_scans), min(len(scans), j + params.submap_scans + 1)):
        pts = scans[k].points[scans[k].valid]
        T = np.linalg.inv(T_j) @ se2(poses[k])
        parts.append(pts @ T[:2, :2].T + T[:2, 2])
    submap = np.vstack(parts)
    data = scans[i].points[scans[i].valid]
    if len(submap) < 20 or len(data) < 20:
        return Closure(i, j, None, why_not="too few returns")
    guess = pose_of(np.linalg.inv(T_j) @ se2(poses[i]))
    icp_params = IcpParams(method="point-to-line")
    best = None
    g = params.grid_m
    for dx, dy in [(0, 0), (g, 0), (-g, 0), (0, g), (0, -g), (g, g), (-g, -g), (g, -g), (-g, g)]:
        res = icp(submap, data, initial=guess + np.array([dx, dy, 0.0]), params=icp_params)
        if best is None or (res.inlier_fraction, -res.rms_m) > (best.inlier_fraction, -best.rms_m):
            best = res
    assert best is not None
    if best.inlier_fraction < params.min_inliers:
        why = f"inliers {best.inlier_fraction:.2f} < {params.min_inliers:g}"
    elif not best.rms_m <= params.max_rms_m:
        why = f"RMS {best.rms_m:.3f} m > {params.max_rms_m:g} m"
    elif best.degeneracy < params.min_degeneracy:
        why = f"degenerate ({best.degeneracy:.3f})"
    else:
        return Closure(i, j, best.pose, best.inlier_fraction, best.rms_m)
    return Closure(i, j, None, best.inlier_fraction, best.rms_m, why)


def optimise(poses: FloatArray, closures: list[Closure], params: LoopParams) -> tuple[FloatArray, FloatArray]:
    """The pose graph's optimum (N, 3), the first pose held, and each closure's whitened
    residual norm there."""
    n = len(poses)
    steps = np.array([pose_of(np.linalg.inv(se2(poses[k])) @ se2(poses[k + 1])) for k in range(n - 1)])
    length = np.hypot(steps[:, 0], steps[:, 1])
    step_sig = np.array(params.step_sigmas)[None, :] + params.step_sigma_per_m * length[:, None]
    a = np.r_[np.arange(n - 1), [c.j for c in closures]].astype(int)
    b = np.r_[np.arange(1, n), [c.i for c in closures]].astype(int)
    measured = [np.asarray(c.T_j_i, dtype=float) for c in closures if c.T_j_i is not None]
    z = np.vstack([steps, *measured]) if measured else steps
    sig = np.vstack([step_sig, np.tile(params.closure_sigmas, (len(closures), 1))])

    w = 1.0 / sig  # (M, 3) whitening

    def residuals(x: FloatArray) -> FloatArray:
        p = np.vstack([poses[:1], x.reshape(-1, 3)])
        return (_edge_errors(p[a], p[b], z) * w).ravel()

    def jacobian(x: FloatArray) -> csr_matrix:
        p = np.vstack([poses[:1], x.reshape(-1, 3)])
        Ja, Jb = _edge_jacobians(p[a], p[b], z)
        rows, cols, vals = [], [], []
        r = np.repeat(np.arange(3 * len(a)).reshape(-1, 3, 1), 3, axis=2)  # (M, 3, 3) row index
        for v, J in ((a, Ja), (b, Jb)):
            c = 3 * (v[:, None, None] - 1) + np.arange(3)[None, None, :]  # column of pose v - 1
            keep = np.broadcast_to((v > 0)[:, None, None], J.shape)
            rows.append(r[keep])
            cols.append(np.broadcast_to(c, J.shape)[keep])
            vals.append((J * w[:, :, None])[keep])
        return csr_matrix(
            (np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
            shape=(3 * len(a), 3 * (n - 1)),
        )

    # Gauss-Newton on the Cauchy kernel by iteratively reweighted least squares: each
    # edge weighs 1 / (1 + |r|^2 / c^2) of its whitened residual r (c = KERNEL_SCALE).
    x = poses[1:].ravel().copy()
    for _ in range(MAX_ITERATIONS):
        r = residuals(x)
        weight = 1.0 / (1.0 + np.sum(r.reshape(-1, 3) ** 2, axis=1) / KERNEL_SCALE**2)
        J = jacobian(x)
        Wd = diags(np.repeat(weight, 3))
        H = (J.T @ Wd @ J).tocsc()
        step = spsolve(H, -(J.T @ (np.repeat(weight, 3) * r)))
        x += step
        if np.abs(step).max() < 1e-7:
            break
    out = np.vstack([poses[:1], x.reshape(-1, 3)])
    r = residuals(x).reshape(-1, 3)[n - 1 :]
    return out, np.linalg.norm(r, axis=1)


def _edge_jacobians(pa: FloatArray, pb: FloatArray, z: FloatArray) -> tuple[FloatArray, FloatArray]:
    """(M, 3, 3) the derivatives of :func:`_edge_errors` by pose a and by pose b (x, y, yaw)."""
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


def _edge_errors(pa: FloatArray, pb: FloatArray, z: FloatArray) -> FloatArray:
    """(M, 3) the error of each edge's measurement z (T_a_b) at poses a, b: z^-1 a^-1 b,
    vectorised."""
    c, s = np.cos(pa[:, 2]), np.sin(pa[:, 2])
    dx, dy = pb[:, 0] - pa[:, 0], pb[:, 1] - pa[:, 1]
    rel = np.column_stack([c * dx + s * dy, -s * dx + c * dy, pb[:, 2] - pa[:, 2]])
    cz, sz = np.cos(z[:, 2]), np.sin(z[:, 2])
    ex, ey = rel[:, 0] - z[:, 0], rel[:, 1] - z[:, 1]
    yaw = np.angle(np.exp(1j * (rel[:, 2] - z[:, 2])))
    return np.column_stack([cz * ex + sz * ey, -sz * ex + cz * ey, yaw])
