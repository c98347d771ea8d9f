"""The reduced board solve for a level scanner and boards that never tilt.

A common course procedure stands the board upright (against a wall, say) and turns it
between captures, with the scanner level. Every board normal is then horizontal, and the
point-on-plane equations of :mod:`rigcal.calib.board.plane` (n_i^T (R p + t) = d_i) say nothing
about three of T_cam_laser's six degrees of freedom: with n_i and the laser plane both
perpendicular to the vertical u, a rotation w moves a residual by w . (R p x n_i), and
R p x n_i is parallel to u, so only the rotation about u (yaw) shows; a translation moves it
by n_i . dt, so only the horizontal translation shows. The laser's roll and pitch (its
tilt from level) and its height are unobservable, whatever the number of captures.

What such data support: solve yaw and the two horizontal translations, with the roll,
the pitch and the height given as measured priors (a spirit level, a tape) with their
1-sigmas, so that T_cam_laser's covariance carries their uncertainty.

Frames and parameters (docs/calibration.md, "Boards that never tilt"):

- **up**, u (camera frame): the direction the boards' normals are all perpendicular to
  (the boards stand upright, so their normals are horizontal), fitted to the normals from
  the image poses alone (the smallest singular vector of the stacked normals). How far
  the normals scatter out of that plane (the boards' lean) gives u's own uncertainty,
  which adds to the roll and pitch priors': the priors are the scanner's tilt from the
  vertical, and the vertical is known only through the boards.
- **level frame** L: z = s u (s = +1 or -1, the laser's z axis up or down: both are tried,
  the data choose), x the camera's optical axis projected on the level plane, y = z x x.
- R_cam_laser = R_cam_L Rz(yaw) Ry(pitch) Rx(roll): yaw about the vertical from the
  camera's optical axis to the laser's x axis, then pitch about the laser's y and roll
  about its x (the scanner's tilt from level; 0 for a level scanner).
- the camera centre in the laser frame, c_laser = (x, y, h) = -R^T t: x and y where the
  camera sits in the scan plane's axes (observed), h its height above the scan plane
  along the laser's z axis (a prior).

The solve is :mod:`rigcal.calib.board.plane`'s (each capture reduced to its cut's two ends,
whitened by the range noise, the board pose's covariance and a per-capture error; the
robust loss on the data, not on the priors; one verdict per same-pose group; a range bias
by incidence when asked) on these six parameters plus three prior residuals, so a
capture that fits no level pose is still rejected. The covariance is the Gauss-Newton
one of data and priors together, the data's part widened for the noise estimated from
few poses (:func:`rigcal.calib.spread.few_dof_factor`, on the 3 observed parameters).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import least_squares

from rigcal.arrays import FloatArray
from rigcal.calib.board.plane import (
    LOSS,
    LOSS_SCALE,
    LOSSES,
    OUTLIER_GATE_CHI2,
    CaptureLine,
    PlaneNoise,
    PlaneObservation,
    PlaneResult,
    _capture_sigma,
    _chi2,
    _whiteners,
    capture_line,
    end_residuals,
    point_to_plane,
    same_pose_groups,
    start_noise,
)
from rigcal.calib.box.refine import loss_weights, robust_cost
from rigcal.calib.noise import CLIP_CHI2, grouped_verdicts
from rigcal.calib.spread import few_dof_factor
from rigcal.errors import CalibrationError
from rigcal.geometry import make_T

# The reduced solve needs captures whose normals span the horizontal plane (yaw and the
# two horizontal translations): the second singular value of the stacked normals, relative
# to the first, at least this.
MIN_HORIZONTAL_SPREAD = 0.1
MIN_LEVEL_CAPTURES = 3
# The parameters, in order: what the data fix, then what the priors hold.
PARAMETERS = ("yaw_rad", "camera_x_m", "camera_y_m", "roll_rad", "pitch_rad", "camera_height_m")
OBSERVED = (0, 1, 2)
# Index of each parameter in the solver's vector x = [yaw, roll, pitch, cx, cy, cz].
_X = {"yaw_rad": 0, "roll_rad": 1, "pitch_rad": 2, "camera_x_m": 3, "camera_y_m": 4, "camera_height_m": 5}


@dataclass(frozen=True)
class LevelPriors:
    """The measured values of what upright boards cannot show, each (value, 1-sigma).

    Attributes:
        roll_deg: the scanner's roll from level (about its x axis), degrees.
        pitch_deg: its pitch from level (about its y axis), degrees.
        camera_height_m: the camera centre's height above the scan plane, along the laser's
            z axis (up for a scanner mounted upright), metres.
    """

    roll_deg: tuple[float, float]
    pitch_deg: tuple[float, float]
    camera_height_m: tuple[float, float]

    def __post_init__(self) -> None:
        for name in ("roll_deg", "pitch_deg", "camera_height_m"):
            value, sigma = getattr(self, name)
            if not (np.isfinite(value) and np.isfinite(sigma) and sigma > 0):
                raise ValueError(f"LevelPriors.{name}: needs a finite value and a sigma > 0")

    def to_dict(self) -> dict[str, dict[str, float]]:
        return {
            k: {"value": float(getattr(self, k)[0]), "sigma": float(getattr(self, k)[1])}
            for k in ("roll_deg", "pitch_deg", "camera_height_m")
        }


@dataclass(frozen=True)
class Vertical:
    """What the boards' normals (the images alone) say about the vertical.

    Attributes:
        up_cam: (3,) unit, camera frame: the normal of the plane the board normals lie in,
            signed to point up in the image (-y of the camera) where that is defined.
        tilt_cov_rad2: (2, 2) covariance of up's error as a rotation about the level
            frame's x and y axes (for z = +up), from the normals' scatter out of the plane.
        max_tilt_deg: the largest angle of a board normal out of that plane (the boards'
            largest lean), degrees.
        spread: the normals' smallest singular value over their largest (how far they are
            from sharing a plane; MIN_NORMAL_SPREAD and more fixes all six dof).
        horizontal_spread: the middle singular value over the largest (how differently the
            boards are turned).
    """

    up_cam: FloatArray
    tilt_cov_rad2: FloatArray
    max_tilt_deg: float
    spread: float
    horizontal_spread: float


def board_vertical(normals_cam: FloatArray) -> Vertical:
    """The vertical from (C, 3) board normals (camera frame), C >= 3 (:class:`Vertical`)."""
    N = np.asarray(normals_cam, dtype=float).reshape(-1, 3)
    _, s, Vt = np.linalg.svd(N)
    up = Vt[2]
    if up[1] > 0:  # up in the image is the camera's -y
        up = -up
    ex, ey = _level_axes(up)
    out = N @ up
    J = np.column_stack([N @ ex, N @ ey])
    dof = max(len(N) - 2, 1)
    # The scatter's scale is estimated from few normals: widened as an F bound, not a
    # chi-square one (rigcal.calib.spread.few_dof_factor, 2 parameters).
    s2 = float(out @ out) / dof * few_dof_factor(dof, params=2)
    JtJ = J.T @ J
    # up + da ex + db ey is up turned about ey by da and about -ex by db.
    P = np.array([[0.0, -1.0], [1.0, 0.0]])
    ok = np.linalg.cond(JtJ) < 1e12
    tilt_cov = P @ (s2 * np.linalg.inv(JtJ)) @ P.T if ok else np.full((2, 2), np.inf)
    return Vertical(
        up,
        tilt_cov,
        float(np.degrees(np.arcsin(np.clip(np.abs(out).max(), 0.0, 1.0)))),
        float(s[2] / s[0]),
        float(s[1] / s[0]),
    )


def _level_axes(z: FloatArray) -> tuple[FloatArray, FloatArray]:
    """The level frame's x (the camera's optical axis on the level plane; its x axis when
    it looks straight along z) and y = z x x."""
    for a in (np.array([0.0, 0.0, 1.0]), np.array([1.0, 0.0, 0.0])):
        x = a - (a @ z) * z
        if np.linalg.norm(x) > 0.1:
            x = x / np.linalg.norm(x)
            return x, np.cross(z, x)
    raise AssertionError("unreachable: two orthogonal axes cannot both be parallel to z")


@dataclass(frozen=True)
class LevelFrame:
    """The level frame of one solve: R_cam_L (columns x, y, z = sign up) and the sign."""

    R_cam_L: FloatArray
    sign: int

    @classmethod
    def from_up(cls, up_cam: FloatArray, sign: int) -> LevelFrame:
        z = sign * np.asarray(up_cam, dtype=float)
        x, y = _level_axes(z)
        return cls(np.column_stack([x, y, z]), sign)

    def pose(self, x: FloatArray) -> FloatArray:
        """T_cam_laser from x = [yaw, roll, pitch, cx, cy, cz] (module docstring)."""
        R = self.R_cam_L @ _Rz(x[0]) @ _Ry(x[2]) @ _Rx(x[1])
        return make_T(R, -R @ x[3:6])

    def parameters(self, T: FloatArray) -> FloatArray:
        """x = [yaw, roll, pitch, cx, cy, cz] of a T_cam_laser (the inverse of :meth:`pose`)."""
        from scipy.spatial.transform import Rotation

        R_L_laser = self.R_cam_L.T @ T[:3, :3]
        yaw, pitch, roll = Rotation.from_matrix(R_L_laser).as_euler("ZYX")
        c = -T[:3, :3].T @ T[:3, 3]
        return np.array([yaw, roll, pitch, *c])


def _Rz(a: float) -> FloatArray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _Ry(a: float) -> FloatArray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def _Rx(a: float) -> FloatArray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


@dataclass(frozen=True)
class LevelSolution:
    """The reduced solve's own account, beside its :class:`PlaneResult`.

    Attributes:
        priors: the priors given.
        vertical: the boards' vertical.
        frame: the level frame chosen (its sign: the laser's z up, +1, or down, -1).
        x: (6,) [yaw, roll, pitch, cx, cy, cz] solved (rad, m).
        x_cov: (6, 6) their covariance (data and priors; the data's part widened for few poses).
        prior_cov: (3, 3) the priors' covariance over [roll, pitch, cz] as used (the
            roll and pitch priors' with the vertical's own uncertainty added).
    """

    priors: LevelPriors
    vertical: Vertical
    frame: LevelFrame
    x: FloatArray
    x_cov: FloatArray
    prior_cov: FloatArray

    def estimates(self) -> dict[str, tuple[float, float]]:
        """Each parameter's (value, 1-sigma), in PARAMETERS' order and units."""
        sig = np.sqrt(np.clip(np.diag(self.x_cov), 0.0, None))
        return {name: (float(self.x[_X[name]]), float(sig[_X[name]])) for name in PARAMETERS}


def check_level_geometry(vertical: Vertical, names: Sequence[str]) -> None:
    """Whether the boards are turned enough for the reduced solve (yaw and the horizontal
    translations need normals in two horizontal directions).

    Raises:
        CalibrationError: the boards all face (nearly) one way.
    """
    if vertical.horizontal_spread < MIN_HORIZONTAL_SPREAD:
        raise CalibrationError(
            f"the boards of captures {', '.join(names)} all face nearly one way (normals' spread in "
            f"the level plane {vertical.horizontal_spread:.3f} < {MIN_HORIZONTAL_SPREAD}): the level "
            "solve needs the board turned about the vertical between captures, e.g. by -30, 0 and +30 deg"
        )


def solve_level(
    observations: Sequence[PlaneObservation],
    priors: LevelPriors,
    range_sigma_m: float | None = None,
    fit_range_bias: bool = False,
    loss: str = LOSS,
) -> tuple[PlaneResult, LevelSolution]:
    """Yaw and the horizontal translations from upright boards, with roll, pitch and
    height from ``priors`` (module docstring).

    Args:
        observations: one per capture (at least MIN_LEVEL_CAPTURES).
        priors: the roll, pitch and camera height with their 1-sigmas.
        range_sigma_m: the range noise to assume; None estimates it from the captures' lines.
        fit_range_bias: estimate the range bias by incidence too.
        loss: the robust loss on the data (LOSSES); the priors are always quadratic.

    Returns:
        (the result in :func:`rigcal.calib.board.plane.solve_plane`'s form, its T covariance
        carrying the priors' uncertainty; the reduced solve's own account).

    Raises:
        ValueError: an unknown loss.
        CalibrationError: too few captures, boards all facing one way, or no capture set
            fits a level pose.
    """
    if loss not in LOSSES:
        raise ValueError(f"loss must be one of {LOSSES}, not {loss!r}")
    C = len(observations)
    if C < MIN_LEVEL_CAPTURES:
        raise CalibrationError(f"{C} board capture(s); the level solve needs at least {MIN_LEVEL_CAPTURES}")
    for o in observations:
        if len(o.points_laser) < 2:
            raise CalibrationError(f"capture {o.name}: fewer than 2 laser returns on the board")
    vertical = board_vertical(np.array([o.normal_cam for o in observations]))
    check_level_geometry(vertical, [o.name for o in observations])
    lines = tuple(capture_line(o.points_laser) for o in observations)
    noise, estimated = start_noise(lines, range_sigma_m, fit_range_bias, loss)
    groups = same_pose_groups(observations, lines)
    fits = []
    for sign in (1, -1):
        frame = LevelFrame.from_up(vertical.up_cam, sign)
        x0 = _start(frame, observations, lines, priors)
        prior = _Prior.make(priors, vertical, frame, float(x0[0]))
        fits.append((frame, prior, *_robust_level_fit(frame, prior, x0, observations, lines, noise, groups)))
    # The laser's z up or down: a mirrored scan can fit as well once its misfit is taken
    # for a large per-capture error, so the two are compared under one noise model (the
    # smaller per-capture error of the two), by the captures' clipped chi-squares.
    common = min(f[3].capture_sigma_m for f in fits)

    def misfit(f: tuple[LevelFrame, _Prior, FloatArray, PlaneNoise, NDArray[np.bool_], float]) -> float:
        chi2 = _chi2(f[0].pose(f[2][:6]), observations, lines, replace(f[3], capture_sigma_m=common))
        return float(np.minimum(chi2, CLIP_CHI2).sum())

    frame, prior, x, noise, mask, _ = min(fits, key=misfit)
    if mask.sum() < MIN_LEVEL_CAPTURES:
        raise CalibrationError(
            f"only {int(mask.sum())} captures agree with a level pose; the level solve needs "
            f"{MIN_LEVEL_CAPTURES} (is the scanner level, and are the boards upright?)"
        )
    used = np.flatnonzero(mask)
    poses = len(np.unique(groups[used]))
    observed = 3 + (1 if fit_range_bias else 0)
    noise_dof = 2 * poses - observed
    factor = few_dof_factor(noise_dof, params=3)
    x_cov_model, r_used, wts, _ = _x_covariance(frame, prior, x, observations, lines, noise, used, 1.0)
    x_cov, _, _, _ = _x_covariance(frame, prior, x, observations, lines, noise, used, factor)
    T = frame.pose(x[:6])
    G = _tangent_jacobian(frame, x[:6])
    cov_T = G @ x_cov[:6, :6] @ G.T
    cov_T_model = G @ x_cov_model[:6, :6] @ G.T
    chi2 = _chi2(T, observations, lines, noise)
    weights = np.zeros(C)
    weights[used] = wts.reshape(-1, 2).mean(axis=1)
    dof = len(r_used) - observed
    result = PlaneResult(
        T,
        0.5 * (cov_T + cov_T.T),
        tuple(point_to_plane(T, o) for o in observations),
        float(np.sqrt(float(r_used @ r_used) / dof)) if dof > 0 else 1.0,
        mask,
        0.5 * (cov_T_model + cov_T_model.T),
        chi2,
        weights,
        lines,
        noise,
        estimated,
        groups,
        None,
        (),
        float(np.sqrt(x_cov[6, 6])) if fit_range_bias else None,
        np.zeros(C, dtype=bool),
        np.full(C, np.nan),
        float("inf"),
        poses,
        noise_dof,
        factor,
    )
    return result, LevelSolution(priors, vertical, frame, x[:6], x_cov[:6, :6], prior.cov)


@dataclass(frozen=True)
class _Prior:
    """The prior residuals' mean and whitening over [roll, pitch, cz]."""

    mean: FloatArray
    cov: FloatArray
    whiten: FloatArray

    @classmethod
    def make(cls, priors: LevelPriors, vertical: Vertical, frame: LevelFrame, yaw: float) -> _Prior:
        mean = np.array(
            [np.radians(priors.roll_deg[0]), np.radians(priors.pitch_deg[0]), priors.camera_height_m[0]]
        )
        cov = np.diag([np.radians(priors.roll_deg[1]) ** 2, np.radians(priors.pitch_deg[1]) ** 2, 0.0])
        cov[2, 2] = priors.camera_height_m[1] ** 2
        # The vertical's own error, a rotation about the level x and y axes, seen about the
        # laser's x (roll) and y (pitch): turned by the yaw.
        tilt = vertical.tilt_cov_rad2 if np.isfinite(vertical.tilt_cov_rad2).all() else np.zeros((2, 2))
        if frame.sign < 0:  # the level frame's y axis is flipped with its z
            tilt = tilt * np.array([[1.0, -1.0], [-1.0, 1.0]])
        M = _Rz(yaw)[:2, :2].T
        cov[:2, :2] += M @ tilt @ M.T
        return cls(mean, cov, np.linalg.inv(np.linalg.cholesky(cov)))

    def residuals(self, x: FloatArray) -> FloatArray:
        out: FloatArray = self.whiten @ (np.array([x[1], x[2], x[5]]) - self.mean)
        return out

    def jacobian(self, n: int) -> FloatArray:
        J = np.zeros((3, n))
        J[:, [1, 2, 5]] = self.whiten
        return J


def _start(
    frame: LevelFrame,
    observations: Sequence[PlaneObservation],
    lines: Sequence[CaptureLine],
    priors: LevelPriors,
) -> FloatArray:
    """x0 by linear least squares: roll, pitch and height at their priors, the cut ends'
    point-on-plane equations are linear in (cos yaw, sin yaw) and the horizontal
    translation (in the level frame)."""
    roll, pitch, h = (
        np.radians(priors.roll_deg[0]),
        np.radians(priors.pitch_deg[0]),
        priors.camera_height_m[0],
    )
    tilt = _Ry(pitch) @ _Rx(roll)
    rows, rhs = [], []
    for o, ln in zip(observations, lines, strict=True):
        m = frame.R_cam_L.T @ np.asarray(o.normal_cam, dtype=float)
        for p in ln.ends:
            q = tilt @ np.array([p[0], p[1], 0.0])
            rows.append([m[0] * q[0] + m[1] * q[1], m[1] * q[0] - m[0] * q[1], m[0], m[1]])
            # The height enters through the translation's vertical part, -h (level laser).
            rhs.append(o.distance_m - m[2] * q[2] + m[2] * h)
    u, *_ = np.linalg.lstsq(np.array(rows), np.array(rhs), rcond=None)
    yaw = float(np.arctan2(u[1], u[0]))
    T0 = make_T(frame.R_cam_L @ _Rz(yaw) @ tilt, frame.R_cam_L @ np.array([u[2], u[3], -h]))
    x0 = frame.parameters(T0)
    x0[1], x0[2], x0[5] = roll, pitch, h
    return x0


def _mixed_loss(loss: str, n_data: int) -> Callable[[FloatArray], FloatArray]:
    """scipy's ``loss`` on the first ``n_data`` residuals and none (quadratic) on the rest
    (the priors: a robust loss on a prior would let the data pull it away for free)."""

    def rho(z: FloatArray) -> FloatArray:
        out = np.empty((3, len(z)))
        out[0], out[1], out[2] = z, 1.0, 0.0
        d = z[:n_data]
        if loss == "cauchy":
            out[0, :n_data], out[1, :n_data], out[2, :n_data] = np.log1p(d), 1 / (1 + d), -1 / (1 + d) ** 2
        elif loss == "soft_l1":
            t = 1 + d
            out[0, :n_data], out[1, :n_data], out[2, :n_data] = 2 * (t**0.5 - 1), t**-0.5, -0.5 * t**-1.5
        elif loss == "huber":
            big = d > 1
            sq = np.sqrt(np.maximum(d, 1e-300))
            out[0, :n_data] = np.where(big, 2 * sq - 1, d)
            out[1, :n_data] = np.where(big, 1 / sq, 1.0)
            out[2, :n_data] = np.where(big, -0.5 / np.maximum(d, 1e-300) ** 1.5, 0.0)
        return out

    return rho


def _data_residuals(
    frame: LevelFrame,
    x: FloatArray,
    obs: Sequence[PlaneObservation],
    lns: Sequence[CaptureLine],
    W: Sequence[FloatArray],
    noise: PlaneNoise,
) -> FloatArray:
    T = frame.pose(x[:6])
    bias = float(x[6]) if noise.fit_range_bias else noise.range_bias_m
    return np.concatenate([w @ end_residuals(T, o, ln, bias) for w, o, ln in zip(W, obs, lns, strict=True)])


def _fit(
    frame: LevelFrame,
    prior: _Prior,
    x0: FloatArray,
    observations: Sequence[PlaneObservation],
    lines: Sequence[CaptureLine],
    noise: PlaneNoise,
    used: NDArray[np.int64],
) -> tuple[FloatArray, PlaneNoise]:
    """The robust fit of the used captures' whitened cut-end distances and the priors;
    x0 and the result are [yaw, roll, pitch, cx, cy, cz] (+ the range bias when fitted)."""
    obs = [observations[i] for i in used]
    lns = [lines[i] for i in used]
    W = _whiteners(frame.pose(x0[:6]), obs, lns, noise)
    n_data = 2 * len(obs)

    def residuals(x: FloatArray) -> FloatArray:
        return np.concatenate([_data_residuals(frame, x, obs, lns, W, noise), prior.residuals(x)])

    x0 = x0[:6] if not noise.fit_range_bias else np.append(x0[:6], noise.range_bias_m)
    sol = least_squares(residuals, x0, method="trf", loss=_mixed_loss(noise.loss, n_data), f_scale=LOSS_SCALE)
    if noise.fit_range_bias:
        noise = replace(noise, range_bias_m=float(sol.x[6]))
    return np.asarray(sol.x, dtype=float), noise


def _robust_level_fit(
    frame: LevelFrame,
    prior: _Prior,
    x0: FloatArray,
    observations: Sequence[PlaneObservation],
    lines: Sequence[CaptureLine],
    noise: PlaneNoise,
    groups: NDArray[np.int64],
) -> tuple[FloatArray, PlaneNoise, NDArray[np.bool_], float]:
    """As :func:`rigcal.calib.board.plane._robust_fit`: fit, per-capture error, verdicts by
    same-pose group, until the verdicts settle. Returns (x, noise, inliers, robust cost)."""
    C = len(observations)
    mask = np.ones(C, dtype=bool)
    x = x0
    for _ in range(4):
        x, noise = _fit(frame, prior, x, observations, lines, noise, np.flatnonzero(mask))
        sigma = _capture_sigma(frame.pose(x[:6]), observations, lines, noise, mask, params=3)
        noise = replace(noise, capture_sigma_m=sigma)
        chi2 = _chi2(frame.pose(x[:6]), observations, lines, noise)
        new = grouped_verdicts(chi2, groups, mask, OUTLIER_GATE_CHI2)
        if np.array_equal(new, mask) or new.sum() < MIN_LEVEL_CAPTURES:
            break
        mask = new
    x, noise = _fit(frame, prior, x, observations, lines, noise, np.flatnonzero(mask))
    z = np.sqrt(_chi2(frame.pose(x[:6]), observations, lines, noise)[mask])
    return x, noise, mask, robust_cost(z, noise.loss, LOSS_SCALE)


def _x_covariance(
    frame: LevelFrame,
    prior: _Prior,
    x: FloatArray,
    observations: Sequence[PlaneObservation],
    lines: Sequence[CaptureLine],
    noise: PlaneNoise,
    used: NDArray[np.int64],
    factor: float,
) -> tuple[FloatArray, FloatArray, FloatArray, float]:
    """The parameters' covariance from the data's information (IRLS weights, scaled by
    the weighted residual scale when above 1, divided by ``factor``) plus the priors';
    also the used captures' whitened residuals, their weights and the scale squared."""
    obs = [observations[i] for i in used]
    lns = [lines[i] for i in used]
    W = _whiteners(frame.pose(x[:6]), obs, lns, noise)
    r = _data_residuals(frame, x, obs, lns, W, noise)
    J = np.empty((len(r), len(x)))
    for k in range(len(x)):
        h = 1e-6
        dx = np.zeros(len(x))
        dx[k] = h
        J[:, k] = (
            _data_residuals(frame, x + dx, obs, lns, W, noise)
            - _data_residuals(frame, x - dx, obs, lns, W, noise)
        ) / (2 * h)
    wts = loss_weights(r, noise.loss, LOSS_SCALE)
    observed = 3 + (1 if noise.fit_range_bias else 0)
    dof = len(r) - observed
    scale2 = max(1.0, float(np.sum(wts * r**2)) / dof) if dof > 0 else 1.0
    Jp = prior.jacobian(len(x))
    info = (J * wts[:, None]).T @ J / (scale2 * factor) + Jp.T @ Jp
    cov = np.linalg.inv(info)
    return 0.5 * (cov + cov.T), r, wts, scale2


def _tangent_jacobian(frame: LevelFrame, x: FloatArray) -> FloatArray:
    """(6, 6) d[dtheta, dt]/dx at x: how the parameters move T_cam_laser in the covariance's
    tangent space (R' = Exp(dtheta) R, t' = t + dt; rigcal.rig.COVARIANCE_PARAMETERS)."""
    from scipy.spatial.transform import Rotation

    T = frame.pose(x)
    G = np.empty((6, 6))
    for k in range(6):
        h = 1e-7
        dx = np.zeros(6)
        dx[k] = h
        Tp, Tm = frame.pose(x + dx), frame.pose(x - dx)
        wp = Rotation.from_matrix(Tp[:3, :3] @ T[:3, :3].T).as_rotvec()
        wm = Rotation.from_matrix(Tm[:3, :3] @ T[:3, :3].T).as_rotvec()
        G[:3, k] = (wp - wm) / (2 * h)
        G[3:, k] = (Tp[:3, 3] - Tm[:3, 3]) / (2 * h)
    return G


def level_errors(solution: LevelSolution, T_truth: FloatArray) -> dict[str, float]:
    """The solve's error against a known T_cam_laser, in the level parameters: the yaw
    (deg) and the horizontal translation (mm) errors, and the squared Mahalanobis distance
    of the three observed parameters (d2_observed, 3 dof) and of all six (d2_all, 6 dof)."""
    xt = solution.frame.parameters(np.asarray(T_truth, dtype=float))
    e = solution.x - xt
    e[0] = float(np.angle(np.exp(1j * e[0])))
    idx = [_X[p] for p in PARAMETERS]
    ep = e[idx]
    cov = solution.x_cov[np.ix_(idx, idx)]
    obs = list(OBSERVED)
    return {
        "yaw_error_deg": float(np.degrees(ep[0])),
        "horizontal_error_mm": float(1000.0 * np.hypot(ep[1], ep[2])),
        "d2_observed": float(ep[obs] @ np.linalg.solve(cov[np.ix_(obs, obs)], ep[obs])),
        "d2_all": float(ep @ np.linalg.solve(cov, ep)),
    }


def refit_level(
    result: PlaneResult, solution: LevelSolution, observations: Sequence[PlaneObservation]
) -> FloatArray:
    """T_cam_laser re-solved by the level solve with other board planes (the same returns,
    noise model, verdicts and priors; the vertical re-fitted to the new normals, the laser's
    z kept on its side): how the answer follows the planes, e.g. under other camera
    intrinsics."""
    vertical = board_vertical(np.array([o.normal_cam for o in observations]))
    frame = LevelFrame.from_up(vertical.up_cam, solution.frame.sign)
    prior = _Prior.make(solution.priors, vertical, frame, float(solution.x[0]))
    x0 = frame.parameters(solution.frame.pose(solution.x))
    used = np.flatnonzero(result.inlier_captures)
    x, _ = _fit(frame, prior, x0, observations, result.lines, result.noise, used)
    return frame.pose(x[:6])


def level_section(
    solution: LevelSolution, result: PlaneResult, cov_camera: FloatArray | None
) -> dict[str, Any]:
    """The report's and rig file's ``reduced`` section (docs/formats/rig.md): what was
    solved, what the priors hold, and the level frame."""
    est = solution.estimates()
    prior_sig = np.sqrt(np.diag(solution.prior_cov))
    given = solution.priors.to_dict()
    # The camera's share, when propagated, adds to the parameters' own covariance.
    G = _tangent_jacobian(solution.frame, solution.x)
    x_cov = solution.x_cov
    if cov_camera is not None:
        Gi = np.linalg.inv(G)
        x_cov = x_cov + Gi @ cov_camera @ Gi.T
    sig = np.sqrt(np.clip(np.diag(x_cov), 0.0, None))

    def entry(name: str, deg: bool) -> dict[str, float]:
        k = _X[name]
        f = np.degrees if deg else (lambda v: 1000.0 * v)
        return {"value": round(float(f(est[name][0])), 4), "sigma": round(float(f(sig[k])), 4)}

    solved = {
        "yaw_deg": entry("yaw_rad", True),
        "camera_x_mm": entry("camera_x_m", False),
        "camera_y_mm": entry("camera_y_m", False),
    }
    bound = {}
    for j, (name, key, deg) in enumerate(
        (
            ("roll_rad", "roll_deg", True),
            ("pitch_rad", "pitch_deg", True),
            ("camera_height_m", "camera_height_mm", False),
        )
    ):
        g = given[key.replace("_mm", "_m")]
        scale = 1000.0 if not deg else 1.0
        bound[key] = entry(name, deg) | {
            "prior": round(g["value"] * scale, 4),
            "prior_sigma": round(g["sigma"] * scale, 4),
            "prior_sigma_with_vertical": round(
                float(np.degrees(prior_sig[j]) if deg else 1000.0 * prior_sig[j]), 4
            ),
        }
    v = solution.vertical
    vsig = np.degrees(np.sqrt(np.clip(np.diag(v.tilt_cov_rad2), 0.0, None)))
    return {
        "model": "level scanner, upright boards",
        "solved": solved,
        "prior_bound": bound,
        "level_frame": {
            "up_cam": [round(float(a), 6) for a in v.up_cam],
            "laser_z": "up" if solution.frame.sign > 0 else "down",
            "vertical_sigma_deg": [round(float(a), 4) for a in vsig],
            "boards_max_lean_deg": round(v.max_tilt_deg, 3),
            "normals_spread": round(v.spread, 4),
        },
        "noise_dof": result.noise_dof,
    }


def reduced_warning(section: dict[str, Any]) -> str:
    """The report's first warning for a reduced solve: what is measured and what is not."""
    b = section["prior_bound"]
    return (
        "reduced solve (level scanner, upright boards): only the yaw and the camera's position in "
        "the scan plane come from the data; the roll "
        f"({b['roll_deg']['prior']:g} +- {b['roll_deg']['prior_sigma']:g} deg), pitch "
        f"({b['pitch_deg']['prior']:g} +- {b['pitch_deg']['prior_sigma']:g} deg) and the camera's "
        f"height above the scan plane ({b['camera_height_mm']['prior']:g} +- "
        f"{b['camera_height_mm']['prior_sigma']:g} mm) are the priors given, not measured "
        "(T_cam_laser's covariance carries their sigmas, the roll's and pitch's widened by the "
        "boards' vertical); tilt the board between captures to measure them"
    )
