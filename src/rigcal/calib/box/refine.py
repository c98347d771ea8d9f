"""Levenberg-Marquardt refinement of T_cam_laser and its covariance (paper Algorithm 1, step 9).

The refinement minimises the reprojection error of the laser box ends over all inlier
captures. Beyond the paper, each residual is whitened by the 2x2 covariance of that box
end in the image: the pick noise (isotropic, ``pick_sigma_px``) plus the laser end's own
uncertainty pushed through the projection. With ``use_side_points`` the laser ends come
from a line fitted to every return on the box side (accurate across the side, uncertain
along it by the beam spacing), so the refinement trusts the across-the-side direction more;
without it, the first and last returns are taken as they are, as in the paper.

Parameters: ``x = [dtheta (3), t (3)]`` with ``R = Exp(dtheta) R0`` (a left perturbation in the
camera frame) and ``t`` in metres. The covariance is reported in the same tangent space at
the solution: ``R_true = Exp(d) R_est`` with ``d ~ N(0, C[:3, :3])`` (rad) and
``t_true = t_est + e``, ``e ~ N(0, C[3:, 3:])`` (m).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import least_squares

from rigcal.arrays import FloatArray
from rigcal.calib.box.picks import BoxObservation
from rigcal.calib.options import LOSSES
from rigcal.camera import Camera
from rigcal.errors import CalibrationError
from rigcal.geometry import make_T, rotvec_to_R


@dataclass(frozen=True)
class NoiseModel:
    """Measurement noise assumed by the refinement (1 sigma).

    Attributes:
        pick_sigma_px: noise of a picked pixel, per axis.
        range_sigma_m: range noise of one laser return.
    """

    pick_sigma_px: float = 1.0
    range_sigma_m: float = 0.01


@dataclass(frozen=True)
class RefineParams:
    """Refinement settings.

    Attributes:
        use_side_points: fit the box side to all its laser returns and weight residuals by
            the resulting end uncertainty (beyond the paper); False uses the raw first and
            last returns with isotropic weights, as the paper does.
        loss: scipy robust loss: "linear" (plain LM), "huber", "soft_l1" or "cauchy".
        loss_scale: where the robust loss starts to bend, in units of whitened residual
            (i.e. sigmas).
    """

    use_side_points: bool = True
    loss: str = "cauchy"
    loss_scale: float = 3.0


@dataclass(frozen=True)
class EndpointSet:
    """The refinement's measurements: one row per box end.

    Attributes:
        points_laser: (P, 2) laser box ends, metres.
        pixels: (P, 2) picked pixels.
        cov_laser: (P, 2, 2) covariance of each laser end, m^2.
        capture: (P,) index of the capture (picking-file order) each end came from.
        end: (P,) 0 or 1, which end of its capture.
        cross_laser: (P, 2, 2) covariance between each end and the other end of its capture
            (both come from one fitted line), m^2; None when the ends are independent.
    """

    points_laser: FloatArray
    pixels: FloatArray
    cov_laser: FloatArray
    capture: NDArray[np.int64]
    end: NDArray[np.int64]
    cross_laser: FloatArray | None = None

    def subset(self, mask: NDArray[np.bool_]) -> EndpointSet:
        """The ends selected by a (P,) mask."""
        cross = None if self.cross_laser is None else self.cross_laser[mask]
        return EndpointSet(
            self.points_laser[mask],
            self.pixels[mask],
            self.cov_laser[mask],
            self.capture[mask],
            self.end[mask],
            cross,
        )


@dataclass(frozen=True)
class RefineResult:
    """Refined pose, its covariance and the fit statistics.

    Attributes:
        T_cam_laser: (4, 4) refined pose.
        covariance: (6, 6) over [dtheta (rad), t (m)], see the module docstring.
        residual_scale: sqrt(chi^2 / dof) of the whitened residuals (about 1 when the noise
            model is right); when above 1 the covariance is inflated by its square (the
            data are noisier than the model says), when below it is left as it is.
        chi2: sum of squared whitened residuals.
        dof: number of residuals minus 6.
        information_eigen: eigenvalues (ascending) of the information matrix J^T J, scaled to
            unit covariance, with its eigenvectors (6, 6) in columns.
        nfev: function evaluations.
    """

    T_cam_laser: FloatArray
    covariance: FloatArray
    residual_scale: float
    chi2: float
    dof: int
    information_eigen: tuple[FloatArray, FloatArray]
    nfev: int


def endpoint_set(
    observations: Sequence[BoxObservation], noise: NoiseModel, use_side_points: bool
) -> EndpointSet:
    """Build the measurement set, with each laser end's covariance.

    With side points each end is where a ray half a beam step outside the outermost return
    meets the line fitted to the M returns of the side (picks.py). Two errors move it:

    - the fitted line's offset at its end, about 2 sigma_r / sqrt(M) across the side,
      slides the end along that ray by offset / cos(incidence), where incidence is the
      angle between the ray and the side's normal;
    - the true box end lies anywhere within the beam step's footprint on the side,
      w = k * range * step / cos(incidence) along it, sigma = w / sqrt(12), where k is
      the end's interval in beam steps (``end_gap_steps``: 1 at a clean depth jump, more
      at a corner or next to missing returns).

    Without side points (the paper), the raw first/last return has the range noise in
    every direction plus the same along-side quantisation (with the footprint measured
    between the two outermost returns).
    """
    pts, px, covs, cross, cap, end = [], [], [], [], [], []
    for obs in observations:
        side = obs.side_points
        if use_side_points and len(side) >= 3:
            ends = obs.laser_endpoints
            c_end, x_end = _side_end_covariances(obs, noise.range_sigma_m)
            covs += list(c_end)
            cross += list(x_end)
        else:
            ends = side[[0, -1]] if len(side) >= 2 else obs.laser_endpoints
            spacing = _end_spacings(side) if len(side) >= 2 else np.zeros(2)
            for j in range(2):
                s2 = noise.range_sigma_m**2 + spacing[j] ** 2 / 12.0
                covs.append(s2 * np.eye(2))
                cross.append(np.zeros((2, 2)))
        pts.append(ends)
        px.append(obs.image_endpoints_px)
        cap += [obs.capture, obs.capture]
        end += [0, 1]
    return EndpointSet(
        np.concatenate(pts),
        np.concatenate(px),
        np.array(covs),
        np.array(cap, dtype=np.int64),
        np.array(end, dtype=np.int64),
        np.array(cross),
    )


def _side_end_covariances(obs: BoxObservation, range_sigma_m: float) -> tuple[FloatArray, FloatArray]:
    """Covariances (2, 2, 2) of a capture's two box ends and their cross-covariances
    (2, 2, 2): [cov(e0, e1), cov(e1, e0)].

    The fitted line's offset d across the side at along-side position s has variance
    sigma^2 (1/M + s^2 / S) and cov(d(s0), d(s1)) = sigma^2 (1/M + s0 s1 / S) (least
    squares: offset at the centroid and slope independent; S = sum of the returns' squared
    along-side positions; sigma the returns' noise across the side, the range noise times
    the cosine of each beam's incidence). An offset d moves the end along its ray r by
    d / (r . n); the quantisation of the end along the side (``end_gap_steps``) is
    independent per end.
    """
    ends = obs.laser_endpoints
    side = obs.side_points
    u = ends[1] - ends[0]
    u = u / np.linalg.norm(u)
    n = np.array([-u[1], u[0]])
    centroid = side.mean(axis=0)
    along = (side - centroid) @ u
    rays = side / np.linalg.norm(side, axis=1, keepdims=True)
    sigma = range_sigma_m * float(np.sqrt(np.mean((rays @ n) ** 2)))
    M = len(side)
    S = max(float(along @ along), 1e-12)
    s_end = (ends - centroid) @ u
    a = []
    quant = []
    for j in range(2):
        rng = float(np.linalg.norm(ends[j]))
        ray = ends[j] / rng
        cos_inc = max(abs(float(ray @ n)), 0.1)
        a.append(ray / cos_inc)
        footprint = obs.end_gap_steps[j] * rng * obs.beam_step_rad / cos_inc
        quant.append((footprint**2 / 12.0) * np.outer(u, u))
    var_d = sigma**2 * (1.0 / M + s_end**2 / S)
    cov_d01 = sigma**2 * (1.0 / M + s_end[0] * s_end[1] / S)
    covs = np.array([var_d[j] * np.outer(a[j], a[j]) + quant[j] for j in range(2)])
    x01 = cov_d01 * np.outer(a[0], a[1])
    return covs, np.array([x01, x01.T])


def _end_spacings(side: FloatArray) -> FloatArray:
    """Distance between the two outermost returns at each end of the side."""
    if len(side) < 2:
        return np.zeros(2)
    return np.array([np.linalg.norm(side[1] - side[0]), np.linalg.norm(side[-1] - side[-2])])


def _laser_to_pixel_jacobians(camera: Camera, T_cam_laser: FloatArray, meas: EndpointSet) -> FloatArray:
    """(P, 2, 2): pixels per metre of laser-frame motion of each end."""
    R = T_cam_laser[:3, :3]
    p = np.column_stack([meas.points_laser, np.zeros(len(meas.points_laser))]) @ R.T + T_cam_laser[:3, 3]
    _, dq_dp = camera.project_with_gradient(p)
    out: FloatArray = dq_dp @ R[:, :2]
    return out


def whitening(camera: Camera, T_cam_laser: FloatArray, meas: EndpointSet, noise: NoiseModel) -> FloatArray:
    """(P, 2, 2) matrices W with W^T W = inverse covariance of each end's pixel residual
    (each end on its own: the marginal, for per-end tests such as the inlier gate)."""
    J = _laser_to_pixel_jacobians(camera, T_cam_laser, meas)
    out: FloatArray = np.linalg.inv(np.linalg.cholesky(_end_pixel_covariances(J, meas, noise)))
    return out


def _end_pixel_covariances(J: FloatArray, meas: EndpointSet, noise: NoiseModel) -> FloatArray:
    """(P, 2, 2) each end's pixel covariance: pick noise plus its laser covariance projected."""
    out: FloatArray = noise.pick_sigma_px**2 * np.eye(2) + J @ meas.cov_laser @ np.transpose(J, (0, 2, 1))
    return out


def pixel_covariance(
    camera: Camera, T_cam_laser: FloatArray, meas: EndpointSet, noise: NoiseModel
) -> FloatArray:
    """(2P, 2P) covariance of all the ends' pixel residuals [u0, v0, u1, v1, ...]: pick
    noise plus the laser ends' covariance through the projection, with the cross terms
    between the two ends of a capture."""
    J = _laser_to_pixel_jacobians(camera, T_cam_laser, meas)
    cov = _block_diagonal(_end_pixel_covariances(J, meas, noise))
    if meas.cross_laser is not None:
        for k in range(len(J)):
            for m in np.flatnonzero((meas.capture == meas.capture[k]) & (meas.end != meas.end[k])):
                cov[2 * k : 2 * k + 2, 2 * m : 2 * m + 2] = J[k] @ meas.cross_laser[k] @ J[m].T
    return cov


def whitening_matrix(
    camera: Camera, T_cam_laser: FloatArray, meas: EndpointSet, noise: NoiseModel
) -> FloatArray:
    """(2P, 2P) W with W^T W = inverse of :func:`pixel_covariance`."""
    L = np.linalg.cholesky(pixel_covariance(camera, T_cam_laser, meas, noise))
    out: FloatArray = np.linalg.inv(L)
    return out


def refine_pose(
    camera: Camera,
    T0: FloatArray,
    meas: EndpointSet,
    noise: NoiseModel | None = None,
    params: RefineParams | None = None,
) -> RefineResult:
    """Minimise the whitened reprojection error of the box ends over T_cam_laser.

    Args:
        camera: camera model.
        T0: (4, 4) starting pose (RANSAC's).
        meas: the inlier box ends.
        noise: noise model for the whitening.
        params: refinement settings.

    Raises:
        CalibrationError: fewer than 4 box ends (6 unknowns need at least 8 residuals), or the
            problem is singular (degenerate geometry).
    """
    noise = noise or NoiseModel()
    params = params or RefineParams()
    if params.loss not in LOSSES:
        raise ValueError(f"loss must be one of {LOSSES}")
    P = len(meas.points_laser)
    if P < 4:
        raise CalibrationError(f"refinement needs at least 4 box ends (2 captures); got {P}")
    R0 = T0[:3, :3]
    t0 = T0[:3, 3]
    p3 = np.column_stack([meas.points_laser, np.zeros(P)])
    W = whitening_matrix(camera, T0, meas, noise)

    def residuals(x: FloatArray) -> FloatArray:
        R = rotvec_to_R(x[:3]) @ R0
        q = camera.project(p3 @ R.T + x[3:])
        r = W @ (q - meas.pixels).ravel()
        # A point behind the camera gets a large finite residual so LM can back away.
        return np.nan_to_num(r, nan=1e6)

    x0 = np.concatenate([np.zeros(3), t0])
    method = "lm" if params.loss == "linear" else "trf"
    sol = least_squares(
        residuals, x0, method=method, loss=params.loss, f_scale=params.loss_scale, x_scale="jac"
    )
    R = rotvec_to_R(sol.x[:3]) @ R0
    T = make_T(R, sol.x[3:])
    # Re-whiten at the solution (the projection Jacobians moved a little) and linearise there.
    W = whitening_matrix(camera, T, meas, noise)
    r, J = whitened_residuals_and_jacobian(camera, T, meas, W)
    weights = loss_weights(r, params.loss, params.loss_scale)
    Jw = J * np.sqrt(weights)[:, None]
    info = Jw.T @ Jw
    dof = len(r) - 6
    chi2 = float(np.sum(weights * r**2))
    # Inflate the covariance when the residuals say the data are noisier than the noise
    # model, never shrink it: a small chi-square over a few dozen residuals is mostly
    # chance, and shrinking on it makes the reported uncertainty optimistic.
    scale2 = max(1.0, chi2 / dof) if dof > 0 else 1.0
    evals, evecs = np.linalg.eigh(info)
    if evals[0] <= 1e-12 * max(evals[-1], 1e-300):
        raise CalibrationError(
            "the calibration is unobservable from these captures (singular normal equations); "
            "add captures at other distances and angles"
        )
    cov = scale2 * np.linalg.inv(info)
    return RefineResult(T, 0.5 * (cov + cov.T), float(np.sqrt(scale2)), chi2, dof, (evals, evecs), sol.nfev)


def capture_jacobian_blocks(
    camera: Camera, T: FloatArray, meas: EndpointSet, noise: NoiseModel, params: RefineParams
) -> list[FloatArray]:
    """Each capture's rows of the whitened Jacobian at T, weighted by the robust loss's
    IRLS weights (for the spread's expected jackknife, :mod:`rigcal.calib.spread`). The
    whitening couples only the two ends of one capture, so the rows split by capture."""
    W = whitening_matrix(camera, T, meas, noise)
    r, J = whitened_residuals_and_jacobian(camera, T, meas, W)
    Jw = J * np.sqrt(loss_weights(r, params.loss, params.loss_scale))[:, None]
    rows = np.repeat(meas.capture, 2)
    return [Jw[rows == c] for c in np.unique(meas.capture)]


def whitened_residuals_and_jacobian(
    camera: Camera, T: FloatArray, meas: EndpointSet, W: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """Whitened residuals (2P,) and their analytic Jacobian (2P, 6) at dtheta = 0.

    ``W`` is the (2P, 2P) whitening matrix, or (P, 2, 2) per-end blocks.
    """
    if W.ndim == 3:
        W = _block_diagonal(W)
    R = T[:3, :3]
    p = np.column_stack([meas.points_laser, np.zeros(len(meas.points_laser))])
    rp = p @ R.T
    q, dq_dp = camera.project_with_gradient(rp + T[:3, 3])
    r = W @ (q - meas.pixels).ravel()
    # d(Exp(d) R p + t)/dd at d = 0 is -[R p]x ; d/dt is I.
    skew = np.zeros((len(p), 3, 3))
    skew[:, 0, 1], skew[:, 0, 2] = -rp[:, 2], rp[:, 1]
    skew[:, 1, 0], skew[:, 1, 2] = rp[:, 2], -rp[:, 0]
    skew[:, 2, 0], skew[:, 2, 1] = -rp[:, 1], rp[:, 0]
    dp_dx = np.concatenate([-skew, np.broadcast_to(np.eye(3), skew.shape)], axis=2)  # (P, 3, 6)
    J = (dq_dp @ dp_dx).reshape(-1, 6)  # (2P, 6) unwhitened
    return r, W @ J


def _block_diagonal(blocks: FloatArray) -> FloatArray:
    """(2P, 2P) block-diagonal matrix from (P, 2, 2) blocks."""
    P = len(blocks)
    out = np.zeros((2 * P, 2 * P))
    for k in range(P):
        out[2 * k : 2 * k + 2, 2 * k : 2 * k + 2] = blocks[k]
    return out


def robust_cost(r: FloatArray, loss: str, scale: float) -> float:
    """sum of scale^2 rho((r / scale)^2) for scipy's robust ``loss`` (the cost least_squares
    minimises, times 2), so fits under one loss can be compared by it."""
    z = (np.asarray(r, dtype=float) / scale) ** 2
    if loss == "huber":
        rho = np.where(z <= 1.0, z, 2.0 * np.sqrt(z) - 1.0)
    elif loss == "soft_l1":
        rho = 2.0 * (np.sqrt(1.0 + z) - 1.0)
    elif loss == "cauchy":
        rho = np.log1p(z)
    else:
        rho = z
    return float(scale**2 * np.sum(rho))


def loss_weights(r: FloatArray, loss: str, scale: float) -> FloatArray:
    """IRLS weights rho'(z) of scipy's robust ``loss`` bending at ``scale`` (1 for linear)."""
    z = (r / scale) ** 2
    if loss == "huber":
        return np.where(z <= 1.0, 1.0, 1.0 / np.sqrt(np.maximum(z, 1e-300)))
    if loss == "soft_l1":
        return 1.0 / np.sqrt(1.0 + z)
    if loss == "cauchy":
        return 1.0 / (1.0 + z)
    return np.ones_like(r)
