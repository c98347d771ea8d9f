"""Laser-camera extrinsic calibration from box-target picks (paper Section II, Algorithm 1).

:func:`solve` reads like the algorithm: measurements from the picks (steps 1-2), RANSAC
over P3P + Horn hypotheses (steps 3-8), Levenberg-Marquardt refinement with covariance
(step 9), then the residual report. The whole input is one :class:`CalibProblem`, so a
solve can be re-run and explained.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import NDArray

from rigcal.arrays import FloatArray
from rigcal.calib.box.picks import BoxObservation
from rigcal.calib.box.ransac import RansacParams, RansacResult, ransac_pose, reprojection_errors
from rigcal.calib.box.refine import (
    EndpointSet,
    NoiseModel,
    RefineParams,
    RefineResult,
    capture_jacobian_blocks,
    endpoint_set,
    refine_pose,
    whitening,
)
from rigcal.calib.noise import (
    RangeNoise,
    connected_groups,
    fit_line_robust,
    grouped_verdicts,
    matching_noise,
    range_noise_from_lines,
)
from rigcal.calib.options import NOISE_MODES
from rigcal.calib.spread import (
    Sensitivity,
    Spread,
    expected_jackknife,
    honest_covariance,
    leave_one_out,
    sensitivity,
)
from rigcal.camera import Camera
from rigcal.errors import CalibrationError

MIN_CAPTURES = 3
# After refinement a box end is an inlier when its squared whitened reprojection error
# (Mahalanobis distance under its own pixel covariance) is under the chi-square 99.99%
# point for 2 dof, times the robust noise scale of the inliers (at least 1).
INLIER_GATE_CHI2 = 18.420680743952367


# Box ends of captures this close (laser ends, picked pixels) were taken at one pose and
# share one verdict.
SAME_POSE_LASER_M = 0.03
SAME_POSE_PIXELS = 5.0


@dataclass(frozen=True)
class SolveSettings:
    """Every tunable of a solve (recorded in the rig file).

    Attributes:
        noise_mode: "auto" estimates the range noise from the box sides' line fits and
            the pick noise from the reprojection residuals and uses them (``noise`` is
            then what was assumed, reported beside them); "assumed" uses ``noise``.
        uncertainty_checks: run the leave-one-capture-out spread and the sensitivity to
            the noise settings.
    """

    ransac: RansacParams = field(default_factory=RansacParams)
    refine: RefineParams = field(default_factory=RefineParams)
    noise: NoiseModel = field(default_factory=NoiseModel)
    noise_mode: str = "auto"
    uncertainty_checks: bool = True

    def to_dict(self) -> dict[str, object]:
        """Plain form for provenance records."""
        from dataclasses import asdict

        return {
            "ransac": asdict(self.ransac),
            "refine": asdict(self.refine),
            "noise": {"mode": self.noise_mode} | asdict(self.noise),
        }


@dataclass(frozen=True)
class CalibProblem:
    """The whole input of a solve: camera, resolved observations and settings."""

    camera: Camera
    observations: tuple[BoxObservation, ...]
    settings: SolveSettings = field(default_factory=SolveSettings)


@dataclass(frozen=True)
class CalibResult:
    """Outcome of a solve.

    Attributes:
        problem: the input.
        T_cam_laser: (4, 4) refined pose.
        covariance: (6, 6) see :mod:`rigcal.calib.box.refine`.
        measurements: every box end (inliers and outliers).
        inliers: (P,) bool over ``measurements``.
        errors_px: (P,) reprojection error of every box end under the final pose.
        errors_sigma: (P,) the same, whitened by each end's pixel covariance (Mahalanobis
            distance, in sigmas).
        ransac: the RANSAC stage's result.
        refine: the refinement's result.
        noise: the noise model used (estimated from the data with noise_mode "auto").
        range_noise: the range noise estimated from the box sides' line fits (None when
            no side has 3 or more returns).
        pick_sigma_estimated: the pick noise estimated from the reprojection residuals.
        covariance_model: (6, 6) the noise model's covariance (``covariance`` is it scaled
            up to the spread over captures where that is clearly larger).
        spread: leave-one-capture-out spread (None with too few captures or when not run).
        sensitivity: moves of the answer when a noise setting is halved or doubled.
        end_group: (P,) same-pose group of every box end (one verdict per group).
    """

    problem: CalibProblem
    T_cam_laser: FloatArray
    covariance: FloatArray
    measurements: EndpointSet
    inliers: NDArray[np.bool_]
    errors_px: FloatArray
    ransac: RansacResult
    refine: RefineResult
    errors_sigma: FloatArray
    noise: NoiseModel
    range_noise: RangeNoise | None
    pick_sigma_estimated: float
    covariance_model: FloatArray
    spread: Spread | None
    sensitivity: tuple[Sensitivity, ...]
    end_group: NDArray[np.int64]


def solve(problem: CalibProblem) -> CalibResult:
    """Run Algorithm 1 on a problem.

    With ``noise_mode`` "auto" the range noise comes from the box sides' line fits before
    anything else, and the pick noise from the reprojection residuals of a first solve, which
    is then solved again with it.

    Raises:
        CalibrationError: too few captures, degenerate geometry, or no consensus.
    """
    _check_enough(problem.observations)
    settings = problem.settings
    if settings.noise_mode not in NOISE_MODES:
        raise ValueError(f"noise_mode must be one of {NOISE_MODES}")
    fits = [fit_line_robust(o.side_points) for o in problem.observations if len(o.side_points) >= 3]
    try:
        range_noise: RangeNoise | None = range_noise_from_lines(fits)
    except ValueError:
        range_noise = None
    noise = settings.noise
    if settings.noise_mode == "auto" and range_noise is not None:
        noise = replace(noise, range_sigma_m=max(range_noise.sigma_m, 1e-4))
    meas = endpoint_set(problem.observations, noise, settings.refine.use_side_points)
    _check_not_collinear(meas)
    groups = same_pose_groups(meas)
    ransac = ransac_pose(problem.camera, meas.points_laser, meas.pixels, settings.ransac)
    refined, inliers = _refine_with_reclassification(
        problem, meas, ransac.inliers, ransac.T_cam_laser, noise, groups
    )
    inl = meas.subset(inliers)
    pick_est = matching_noise(
        lambda s: _whitened_sq_errors(
            problem.camera, refined.T_cam_laser, inl, replace(noise, pick_sigma_px=s)
        ),
        1.0 - 6.0 / (2 * len(inl.pixels)),
        0.05,
        50.0,
    )
    if settings.noise_mode == "auto":
        noise = replace(noise, pick_sigma_px=pick_est)
        refined, inliers = _refine_with_reclassification(
            problem, meas, inliers, refined.T_cam_laser, noise, groups
        )
    T = refined.T_cam_laser
    errors = reprojection_errors(problem.camera, T[:3, :3], T[:3, 3], meas.points_laser, meas.pixels)
    sigmas = np.sqrt(_whitened_sq_errors(problem.camera, T, meas, noise))
    spread: Spread | None = None
    sens: list[Sensitivity] = []
    cov = refined.covariance
    if settings.uncertainty_checks:
        spread, sens, cov = _uncertainty(problem, meas, inliers, refined, noise)
    return CalibResult(
        problem,
        T,
        cov,
        meas,
        inliers,
        errors,
        ransac,
        refined,
        sigmas,
        noise,
        range_noise,
        pick_est,
        refined.covariance,
        spread,
        tuple(sens),
        groups,
    )


def same_pose_groups(meas: EndpointSet) -> NDArray[np.int64]:
    """(P,) a group index per box end: the same end of captures whose box ends agree in the
    laser (SAME_POSE_LASER_M) and the image (SAME_POSE_PIXELS) share one, so that ends taken
    at one pose get one verdict."""
    laser = np.linalg.norm(meas.points_laser[:, None] - meas.points_laser[None], axis=2)
    pixels = np.linalg.norm(meas.pixels[:, None] - meas.pixels[None], axis=2)
    same = (meas.end[:, None] == meas.end[None]) & (laser <= SAME_POSE_LASER_M) & (pixels <= SAME_POSE_PIXELS)
    return connected_groups(same)


def _uncertainty(
    problem: CalibProblem,
    meas: EndpointSet,
    inliers: NDArray[np.bool_],
    refined: RefineResult,
    noise: NoiseModel,
) -> tuple[Spread | None, list[Sensitivity], FloatArray]:
    """The spread over captures and the sensitivity to the noise settings
    (:mod:`rigcal.calib.spread`), and the covariance scaled to the spread."""
    camera, T, params = problem.camera, refined.T_cam_laser, problem.settings.refine
    used = np.unique(meas.capture[inliers])
    names = {o.capture: o.name for o in problem.observations}
    blocks = capture_jacobian_blocks(camera, T, meas.subset(inliers), noise, params)
    scale2 = refined.residual_scale**2

    def without(i: int) -> FloatArray:
        keep = inliers & (meas.capture != used[i])
        return refine_pose(camera, T, meas.subset(keep), noise, params).T_cam_laser

    spread = leave_one_out(
        without, T, [names[int(c)] for c in used], refined.covariance, scale2 * expected_jackknife(blocks)
    )
    cov = honest_covariance(refined.covariance, spread)

    def changed(name: str, value: float) -> FloatArray:
        n = replace(noise, **{name: value})
        # The laser ends' covariances depend on the range noise only.
        m = endpoint_set(problem.observations, n, params.use_side_points) if name == "range_sigma_m" else meas
        return refine_pose(camera, T, m.subset(inliers), n, params).T_cam_laser

    sens = sensitivity(
        changed, {"pick_sigma_px": noise.pick_sigma_px, "range_sigma_m": noise.range_sigma_m}, T, cov
    )
    return spread, sens, cov


def _check_enough(observations: Sequence[BoxObservation]) -> None:
    if len(observations) < MIN_CAPTURES:
        raise CalibrationError(
            f"{len(observations)} capture(s) given; the solve needs at least {MIN_CAPTURES} "
            "(10 or more at different distances and angles are recommended)"
        )


def _check_not_collinear(meas: EndpointSet) -> None:
    """All box ends on one line of the laser plane leave rotation about it unobservable."""
    centred = meas.points_laser - meas.points_laser.mean(axis=0)
    s = np.linalg.svd(centred, compute_uv=False)
    if s[0] == 0 or s[1] / s[0] < 1e-3:
        raise CalibrationError(
            "all box ends lie on one line in the laser plane (spread across it "
            f"{s[1] / np.sqrt(len(centred)) * 1000:.1f} mm); move the box to other distances and angles"
        )


def _refine_with_reclassification(
    problem: CalibProblem,
    meas: EndpointSet,
    inliers: NDArray[np.bool_],
    T: FloatArray,
    noise: NoiseModel,
    groups: NDArray[np.int64],
) -> tuple[RefineResult, NDArray[np.bool_]]:
    """Refine on the given inliers from T; re-classify every end under the refined pose by
    its Mahalanobis distance (:data:`INLIER_GATE_CHI2`, one verdict per same-pose group, from
    the group's median) and refine again until stable."""
    refined: RefineResult | None = None
    for _ in range(4):
        if int(inliers.sum()) < 4 or len(np.unique(meas.capture[inliers])) < 2:
            raise CalibrationError(
                f"only {int(inliers.sum())} box end(s) agree with the calibration; "
                "the solve needs at least 4 from 2 captures (check the picks)"
            )
        refined = refine_pose(problem.camera, T, meas.subset(inliers), noise, problem.settings.refine)
        T = refined.T_cam_laser
        new = grouped_verdicts(
            _whitened_sq_errors(problem.camera, T, meas, noise), groups, inliers, INLIER_GATE_CHI2
        )
        if np.array_equal(new, inliers):
            break
        inliers = new
    assert refined is not None
    return refined, inliers


def _whitened_sq_errors(camera: Camera, T: FloatArray, meas: EndpointSet, noise: NoiseModel) -> FloatArray:
    """(P,) squared Mahalanobis reprojection errors of every end (inf behind the camera)."""
    W = whitening(camera, T, meas, noise)
    q = camera.project(
        np.column_stack([meas.points_laser, np.zeros(len(meas.points_laser))]) @ T[:3, :3].T + T[:3, 3]
    )
    z = np.einsum("pij,pj->pi", W, q - meas.pixels)
    out: FloatArray = np.where(np.isfinite(z).all(axis=1), (z**2).sum(axis=1), np.inf)
    return out
