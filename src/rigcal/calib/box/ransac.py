"""RANSAC over triples of laser-camera correspondences (paper Algorithm 1, steps 3-8).

Each hypothesis follows the paper: three (laser point, image bearing) pairs; the 3-point
algorithm gives the points' depths along the bearings, so their camera-frame positions
(step 5); Horn's method aligns those with the laser points (step 6); all laser points are
reprojected and scored in pixels (step 7). Instead of stopping at the first hypothesis
under a threshold (step 8) we keep the best MSAC score and stop adaptively once the
inlier ratio seen so far makes a better hypothesis unlikely (the usual RANSAC bound).
Hypotheses are generated and scored in vectorised batches.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from rigcal.arrays import FloatArray
from rigcal.calib.box.p3p import p3p_poses
from rigcal.camera import Camera
from rigcal.errors import CalibrationError
from rigcal.geometry import make_T


@dataclass(frozen=True)
class RansacParams:
    """RANSAC settings (recorded in the rig file's provenance).

    Attributes:
        threshold_px: reprojection error under which an endpoint counts as an inlier.
        confidence: probability of drawing at least one all-inlier triple, for the
            adaptive iteration count.
        min_iterations, max_iterations: bounds on the number of triples drawn.
        batch_size: triples drawn and solved together.
        min_triangle_ratio: a triple whose laser triangle has 2*area / longest_side^2 under
            this is nearly collinear (P3P and Horn are ill-posed on it) and is redrawn.
        min_inliers: a consensus needs this many box ends. A triple always explains its own
            three, and with 6 px thresholds a 4th or 5th random pick agreeing by chance is
            likely over thousands of hypotheses; a 6th is not.
        seed: seed of the random generator, so a solve can be reproduced.
    """

    threshold_px: float = 6.0
    confidence: float = 0.999
    min_iterations: int = 64
    max_iterations: int = 5000
    batch_size: int = 64
    min_triangle_ratio: float = 0.05
    min_inliers: int = 6
    seed: int = 0


@dataclass(frozen=True)
class RansacResult:
    """Best hypothesis and its consensus.

    Attributes:
        T_cam_laser: (4, 4) best pose.
        inliers: (P,) bool over the correspondences.
        errors_px: (P,) reprojection errors under the best pose (inf behind the camera).
        triples_drawn: number of triples drawn.
        hypotheses: number of P3P solutions scored.
    """

    T_cam_laser: FloatArray
    inliers: NDArray[np.bool_]
    errors_px: FloatArray
    triples_drawn: int
    hypotheses: int


def reprojection_errors(
    camera: Camera, R: FloatArray, t: FloatArray, points_laser: FloatArray, pixels: FloatArray
) -> FloatArray:
    """Reprojection errors of laser points under one or many poses (paper Eq. (3) then (1)).

    Args:
        camera: the camera model.
        R: (K, 3, 3) or (3, 3) rotations R_cam_laser.
        t: (K, 3) or (3,) translations t_cam_laser, metres.
        points_laser: (P, 2) laser points, metres (z = 0 in the laser frame).
        pixels: (P, 2) observed pixels.

    Returns:
        (K, P) or (P,) errors in pixels; inf where the point is behind the camera.
    """
    single = np.ndim(R) == 2
    R3 = R[None] if single else R
    t2 = np.atleast_2d(t)
    p = np.column_stack([points_laser, np.zeros(len(points_laser))])
    pc = np.einsum("kij,pj->kpi", R3, p) + t2[:, None, :]
    q = camera.project(pc.reshape(-1, 3)).reshape(len(R3), len(p), 2)
    err = np.linalg.norm(q - pixels[None], axis=2)
    err[~np.isfinite(err)] = np.inf
    return err[0] if single else err


def ransac_pose(
    camera: Camera,
    points_laser: FloatArray,
    pixels: FloatArray,
    params: RansacParams | None = None,
) -> RansacResult:
    """Robustly estimate T_cam_laser from laser-point / pixel correspondences.

    Args:
        camera: the camera model (bearings through its lens model, paper Eq. (2)).
        points_laser: (P, 2) laser points, metres, laser frame (the box ends of all captures).
        pixels: (P, 2) the matching picked pixels.
        params: RANSAC settings.

    Raises:
        CalibrationError: fewer than 3 correspondences, no non-collinear triple, or no
            hypothesis with at least ``params.min_inliers`` inliers.
    """
    params = params or RansacParams()
    P = len(points_laser)
    if P < 3:
        raise CalibrationError(f"RANSAC needs at least 3 correspondences; got {P}")
    rng = np.random.default_rng(params.seed)
    bearings = camera.bearings(pixels)
    pts3 = np.column_stack([points_laser, np.zeros(P)])
    thr2 = params.threshold_px**2

    best_score = np.inf
    best: tuple[FloatArray, FloatArray] | None = None
    best_inliers = np.zeros(P, dtype=bool)
    needed = params.max_iterations
    drawn = scored = rejected = 0
    while drawn < max(params.min_iterations, min(needed, params.max_iterations)):
        idx = _draw_triples(rng, P, params.batch_size)
        good = _non_collinear(points_laser[idx], params.min_triangle_ratio)
        drawn += len(idx)
        rejected += int((~good).sum())
        if rejected > 50 * params.max_iterations:
            break
        idx = idx[good]
        if len(idx) == 0:
            continue
        # Step 5: depths along the bearings from the 3-point algorithm; step 6: Horn's
        # method aligns the camera-frame points with the laser points (both compiled).
        sol = p3p_poses(bearings[idx], pts3[idx])
        R, t = sol.R[sol.ok], sol.t[sol.ok]
        if len(R) == 0:
            continue
        # Step 7: reproject every laser point and score (MSAC: truncated squared error).
        err = reprojection_errors(camera, R, t, points_laser, pixels)
        scores = np.minimum(err**2, thr2).sum(axis=1)
        scored += len(R)
        k = int(np.argmin(scores))
        if scores[k] < best_score:
            best_score = float(scores[k])
            best = (R[k], t[k])
            best_inliers = err[k] < params.threshold_px
            w = best_inliers.mean()
            needed = _iterations_needed(w, params.confidence)
    if best is None or best_inliers.sum() < params.min_inliers:
        n = int(best_inliers.sum())
        raise CalibrationError(
            f"RANSAC found no consensus: the best of {scored} hypotheses explains {n} of {P} box ends "
            f"within {params.threshold_px:g} px (at least {params.min_inliers} needed); check the picks "
            "(order of the two ends, segment ids) and the camera model"
        )
    T = make_T(*best)
    errors = reprojection_errors(camera, best[0], best[1], points_laser, pixels)
    return RansacResult(T, errors < params.threshold_px, errors, drawn, scored)


def _draw_triples(rng: np.random.Generator, P: int, n: int) -> NDArray[np.int64]:
    """n triples of distinct indices in [0, P)."""
    # argsort of uniform keys = a random permutation per row; the first 3 are distinct.
    keys = rng.random((n, P))
    return np.argpartition(keys, 2, axis=1)[:, :3].astype(np.int64)


def _non_collinear(tri: FloatArray, min_ratio: float) -> NDArray[np.bool_]:
    """(n,) mask of laser triangles (n, 3, 2) that are far enough from collinear."""
    a = tri[:, 1] - tri[:, 0]
    b = tri[:, 2] - tri[:, 0]
    area2 = np.abs(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0])
    sides = np.stack(
        [np.linalg.norm(a, axis=1), np.linalg.norm(b, axis=1), np.linalg.norm(tri[:, 2] - tri[:, 1], axis=1)]
    )
    longest = sides.max(axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        ratio = area2 / longest**2
    out: NDArray[np.bool_] = np.nan_to_num(ratio) > min_ratio
    return out


def _iterations_needed(inlier_ratio: float, confidence: float) -> int:
    """RANSAC's bound: triples to draw for one all-inlier triple with this confidence."""
    w3 = inlier_ratio**3
    if w3 >= 1.0:
        return 0
    if w3 <= 0.0:
        return 10**9
    return int(np.ceil(np.log(1.0 - confidence) / np.log(1.0 - w3)))
