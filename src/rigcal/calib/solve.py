"""Laser-camera extrinsic calibration from box-target picks (paper Section II, Algorithm 1).

:func:`solve` reads like the algorithm: measurements from the picks (steps 1-2), RANSAC
over P3P + Horn hypotheses (steps 3-8), Levenberg-Marquardt refinement with covariance
(step 9), then the residual report. The whole input is one :class:`CalibProblem`, so a
solve can be re-run and explained.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from rigcal.calib.picks import BoxObservation
from rigcal.calib.ransac import RansacParams, RansacResult, ransac_pose, reprojection_errors
from rigcal.calib.refine import (
    EndpointSet,
    NoiseModel,
    RefineParams,
    RefineResult,
    endpoint_set,
    refine_pose,
    whitening,
)
from rigcal.camera import Camera
from rigcal.errors import CalibrationError

FloatArray = NDArray[np.float64]

MIN_CAPTURES = 3
# After refinement a box end is an inlier when its squared whitened reprojection error
# (Mahalanobis distance under its own pixel covariance) is under the chi-square 99.9%
# point for 2 dof, times the robust noise scale of the inliers (at least 1).
INLIER_GATE_CHI2 = 13.815510557964274
_CHI2_2DOF_MEDIAN = 1.3862943611198906


@dataclass(frozen=True)
class SolveSettings:
    """Every tunable of a solve (recorded in the rig file)."""

    ransac: RansacParams = field(default_factory=RansacParams)
    refine: RefineParams = field(default_factory=RefineParams)
    noise: NoiseModel = field(default_factory=NoiseModel)

    def to_dict(self) -> dict[str, object]:
        """Plain form for provenance records."""
        from dataclasses import asdict

        return {"ransac": asdict(self.ransac), "refine": asdict(self.refine), "noise": asdict(self.noise)}


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
        covariance: (6, 6) see :mod:`rigcal.calib.refine`.
        measurements: every box end (inliers and outliers).
        inliers: (P,) bool over ``measurements``.
        errors_px: (P,) reprojection error of every box end under the final pose.
        errors_sigma: (P,) the same, whitened by each end's pixel covariance (Mahalanobis
            distance, in sigmas).
        ransac: the RANSAC stage's result.
        refine: the refinement's result.
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


def solve(problem: CalibProblem) -> CalibResult:
    """Run Algorithm 1 on a problem.

    Raises:
        CalibrationError: too few captures, degenerate geometry, or no consensus.
    """
    _check_enough(problem.observations)
    meas = endpoint_set(problem.observations, problem.settings.noise, problem.settings.refine.use_side_points)
    _check_not_collinear(meas)
    ransac = ransac_pose(problem.camera, meas.points_laser, meas.pixels, problem.settings.ransac)
    refined, inliers, errors, sigmas = _refine_with_reclassification(problem, meas, ransac)
    return CalibResult(
        problem, refined.T_cam_laser, refined.covariance, meas, inliers, errors, ransac, refined, sigmas
    )


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
    problem: CalibProblem, meas: EndpointSet, ransac: RansacResult
) -> tuple[RefineResult, NDArray[np.bool_], FloatArray, FloatArray]:
    """Refine on RANSAC's inliers; re-classify every end under the refined pose by its
    Mahalanobis distance (:data:`INLIER_GATE_CHI2`) and refine again until stable."""
    noise = problem.settings.noise
    inliers = ransac.inliers
    T = ransac.T_cam_laser
    refined: RefineResult | None = None
    for _ in range(4):
        if int(inliers.sum()) < 4 or len(np.unique(meas.capture[inliers])) < 2:
            raise CalibrationError(
                f"only {int(inliers.sum())} box end(s) agree with the calibration; "
                "the solve needs at least 4 from 2 captures (check the picks)"
            )
        refined = refine_pose(problem.camera, T, meas.subset(inliers), noise, problem.settings.refine)
        T = refined.T_cam_laser
        z2 = _whitened_sq_errors(problem.camera, T, meas, noise)
        scale2 = max(1.0, float(np.median(z2[inliers])) / _CHI2_2DOF_MEDIAN)
        new = z2 < INLIER_GATE_CHI2 * scale2
        if np.array_equal(new, inliers):
            break
        inliers = new
    assert refined is not None
    errors = reprojection_errors(problem.camera, T[:3, :3], T[:3, 3], meas.points_laser, meas.pixels)
    sigmas = np.sqrt(_whitened_sq_errors(problem.camera, T, meas, noise))
    return refined, inliers, errors, sigmas


def _whitened_sq_errors(camera: Camera, T: FloatArray, meas: EndpointSet, noise: NoiseModel) -> FloatArray:
    """(P,) squared Mahalanobis reprojection errors of every end (inf behind the camera)."""
    W = whitening(camera, T, meas, noise)
    q = camera.project(
        np.column_stack([meas.points_laser, np.zeros(len(meas.points_laser))]) @ T[:3, :3].T + T[:3, 3]
    )
    z = np.einsum("pij,pj->pi", W, q - meas.pixels)
    out: FloatArray = np.where(np.isfinite(z).all(axis=1), (z**2).sum(axis=1), np.inf)
    return out
