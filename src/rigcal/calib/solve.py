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
)
from rigcal.camera import Camera
from rigcal.errors import CalibrationError

FloatArray = NDArray[np.float64]

MIN_CAPTURES = 3


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


def solve(problem: CalibProblem) -> CalibResult:
    """Run Algorithm 1 on a problem.

    Raises:
        CalibrationError: too few captures, degenerate geometry, or no consensus.
    """
    _check_enough(problem.observations)
    meas = endpoint_set(problem.observations, problem.settings.noise, problem.settings.refine.use_side_points)
    _check_not_collinear(meas)
    ransac = ransac_pose(problem.camera, meas.points_laser, meas.pixels, problem.settings.ransac)
    refined, inliers, errors = _refine_with_reclassification(problem, meas, ransac)
    return CalibResult(
        problem, refined.T_cam_laser, refined.covariance, meas, inliers, errors, ransac, refined
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
) -> tuple[RefineResult, NDArray[np.bool_], FloatArray]:
    """Refine on RANSAC's inliers; re-classify under the refined pose and refine again if needed."""
    thr = problem.settings.ransac.threshold_px
    inliers = ransac.inliers
    T = ransac.T_cam_laser
    refined: RefineResult | None = None
    for _ in range(3):
        if int(inliers.sum()) < 4 or len(np.unique(meas.capture[inliers])) < 2:
            raise CalibrationError(
                f"only {int(inliers.sum())} box end(s) agree within {thr:g} px; "
                "the solve needs at least 4 from 2 captures (check the picks)"
            )
        refined = refine_pose(
            problem.camera, T, _subset(meas, inliers), problem.settings.noise, problem.settings.refine
        )
        T = refined.T_cam_laser
        errors = reprojection_errors(problem.camera, T[:3, :3], T[:3, 3], meas.points_laser, meas.pixels)
        new = errors < thr
        if np.array_equal(new, inliers):
            break
        inliers = new
    assert refined is not None
    errors = reprojection_errors(problem.camera, T[:3, :3], T[:3, 3], meas.points_laser, meas.pixels)
    return refined, inliers, errors


def _subset(meas: EndpointSet, mask: NDArray[np.bool_]) -> EndpointSet:
    return EndpointSet(
        meas.points_laser[mask], meas.pixels[mask], meas.cov_laser[mask], meas.capture[mask], meas.end[mask]
    )
