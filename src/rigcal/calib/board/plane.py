"""Laser-camera calibration from a plane seen by both sensors (a checkerboard, say).

Beyond the paper's box target: in each capture the camera gives the board's plane in the
camera frame, n . p = d (n unit, d > 0, e.g. from the board's corners by PnP), and the
scanner gives returns p_l on the board (the line where the board cuts the scan plane).
Every such return, mapped into the camera frame, must lie on the plane (Zhang and Pless,
"Extrinsic calibration of a camera and laser range finder", IROS 2004):

    n_i^T (R p_l + t) = d_i

1. **Closed form** (no initial guess). With laser points in their z = 0 plane,
   R p_l + t = H [x, y, 1]^T for H = [r1 r2 t], so each return gives one equation that is
   linear in H's 9 entries. A capture's returns lie on one line and so give 2 independent
   equations: 5 captures with planes of different orientations determine H. R is the
   rotation nearest [h1, h2, h1 x h2], t = h3.
2. **Each capture reduced to its line.** Under range noise the least-squares line through
   a capture's returns carries all they say about the pose, so every capture becomes the
   two ends of its cut on a robust line fit (:func:`rigcal.calib.noise.fit_line_robust`:
   mixed pixels at the board's edges and stray returns are trimmed), with the covariance
   of the line's offset there. The range noise itself is estimated from the lines'
   residuals unless it is given.
3. **RANSAC over captures** (optional): closed forms from random 5-capture samples,
   scored by the point-to-plane residuals of all captures, so a capture with a wrong
   plane or wrong returns cannot spoil the start. Both starts (all captures, and RANSAC's)
   are refined and the fit that explains most captures is kept.
4. **Robust refinement** of the 6-DoF pose on the cut ends' point-to-plane distances,
   whitened per capture by their covariance: the line's offset through the range noise,
   the plane's own error (shared through the board's pose from PnP) and a per-capture
   error estimated from the data where the captures disagree beyond chance (a range bias
   by incidence, a warped board). A Cauchy loss (by default; ``loss`` chooses another,
   or "linear" for none) bends at 3 sigmas, so no capture is thrown out by a hard
   threshold while it pulls; the explicit verdict is a chi-square
   gate (99.99 %, 2 dof, times the captures' robust scale) on each same-pose group's
   median, so captures taken at one pose share it. The covariance is the box method's
   (``rigcal.calib.box.refine``'s tangent space), checked against the spread over captures
   and the sensitivity to the noise settings (:mod:`rigcal.calib.spread`), and widened
   for the noise scale being estimated from few board poses (F instead of chi-square:
   :func:`rigcal.calib.spread.few_dof_factor`, with 2 dof per pose less the fitted
   parameters).

A capture hundreds of sigmas off the others (a unit mistake) is set aside before any of
this (:func:`gross_outliers`). Every result depends on the set of returns, not on the
order they are given in.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import least_squares

from rigcal.arrays import FloatArray
from rigcal.calib.box.refine import loss_weights, robust_cost
from rigcal.calib.noise import (
    CLIP_CHI2,
    MIN_COS_INCIDENCE,
    LineFit,
    RangeNoise,
    canonical_order,
    connected_groups,
    fit_line_robust,
    grouped_verdicts,
    line_offset_covariance,
    matching_noise,
    range_noise_from_lines,
    robust_scale,
)
from rigcal.calib.spread import (
    Sensitivity,
    Spread,
    expected_jackknife,
    few_dof_factor,
    honest_covariance,
    leave_one_out,
    sensitivity,
)
from rigcal.errors import CalibrationError
from rigcal.geometry import make_T, rotvec_to_R
from rigcal.stats import chi2_ppf

MIN_CAPTURES = 5
# A set of planes whose normals span less than this (smallest singular value of the
# stacked normals, relative to the largest) leaves the pose unobservable.
MIN_NORMAL_SPREAD = 0.05
# Below this the pose is observable but weak along the normals' least-covered direction
# (a warning says which and what captures to add).
WEAK_NORMAL_SPREAD = 0.1


@dataclass(frozen=True)
class PlaneObservation:
    """One capture: the board plane in the camera frame and the laser returns on it.

    Attributes:
        capture: index of the capture.
        name: its name.
        normal_cam: (3,) unit normal of the plane, camera frame, with distance_m > 0.
        distance_m: distance from the camera centre to the plane.
        points_laser: (M, 2) laser returns on the board, metres, laser frame (z = 0).
        distance_sigma_m: 1-sigma uncertainty of the plane's distance, used when the board's
            pose covariance is not known.
        board_origin_cam: (3,) a point of the plane (the board's origin), camera frame, and
        board_pose_cov: (6, 6) covariance of the board's pose from PnP over [w (rad), dt (m)]
            (left perturbation in the camera frame, the rotation about ``board_origin_cam``);
            when given, each capture's residuals are whitened with the errors they share
            through the board's pose.
        pose_key: observations with one key are planes of one rigid target posed by one
            PnP (the marker target's faces): they carry the same ``board_pose_cov`` about the
            same ``board_origin_cam`` (a point on each of their planes), so their errors from
            that pose are one error, and they are whitened together (their joint
            covariance, :func:`_joint_cov`). None: the capture's plane is its own.
    """

    capture: int
    name: str
    normal_cam: FloatArray
    distance_m: float
    points_laser: FloatArray
    distance_sigma_m: float = 0.001
    board_origin_cam: FloatArray | None = None
    board_pose_cov: FloatArray | None = None
    pose_key: str | None = None


def closed_form(observations: Sequence[PlaneObservation]) -> FloatArray:
    """T_cam_laser from the linear point-on-plane equations (step 1).

    Raises:
        CalibrationError: fewer than MIN_CAPTURES captures, or planes too alike in
            orientation for the equations to determine the pose.
    """
    _check_observable(observations)
    rows = []
    rhs = []
    for o in observations:
        n = np.asarray(o.normal_cam, dtype=float)
        q = np.column_stack([o.points_laser, np.ones(len(o.points_laser))])  # (M, 3)
        # n^T H q = sum_ij n_i H_ij q_j: coefficient of H_ij (row-major) is n_i q_j.
        rows.append((n[None, :, None] * q[:, None, :]).reshape(len(q), 9))
        rhs.append(np.full(len(q), o.distance_m))
    A = np.concatenate(rows)
    b = np.concatenate(rhs)
    h, *_ = np.linalg.lstsq(A, b, rcond=None)
    H = h.reshape(3, 3)
    r1, r2, t = H[:, 0], H[:, 1], H[:, 2]
    M = np.column_stack([r1, r2, np.cross(r1, r2)])
    U, _, Vt = np.linalg.svd(M)
    R = U @ np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))]) @ Vt
    return make_T(R, t)


def choose_candidates(
    planes: Sequence[tuple[FloatArray, float]],
    candidates: Sequence[Sequence[FloatArray]],
    threshold_m: float = 0.03,
    iterations: int = 20000,
    seed: int = 0,
) -> list[int]:
    """For each capture, which of its candidate laser segments lies on its board plane
    (:func:`candidate_consensus`'s choice)."""
    return candidate_consensus(planes, candidates, threshold_m, iterations, seed)[1]


def candidate_consensus(
    planes: Sequence[tuple[FloatArray, float]],
    candidates: Sequence[Sequence[FloatArray]],
    threshold_m: float = 0.03,
    iterations: int = 20000,
    seed: int = 0,
    confidence: float = 0.999,
    advice: str = "give the board's segment ids (`rigcal lines`)",
) -> tuple[FloatArray, list[int], NDArray[np.bool_]]:
    """RANSAC over captures and candidates: draw MIN_CAPTURES captures and one candidate of
    each, solve the closed form, and count the captures that have a candidate within
    ``threshold_m`` RMS of their plane; the hypothesis with most such captures (then the
    lowest summed RMS) picks each capture's closest candidate. Captures with one candidate
    (given segments) take part as they are.

    Sampling stops once, with probability ``confidence``, a sample of agreeing captures
    and their right candidates would have been drawn (the usual adaptive RANSAC bound,
    with the chance of the right candidate 1 / the capture's candidates), or after
    ``iterations`` draws.

    Args:
        planes: per capture, (unit normal (3,), distance m) of its board in the camera frame.
        candidates: per capture, a non-empty list of (M, 2) laser point sets.
        advice: what the error tells the user to do when no hypothesis holds.

    Returns:
        (the hypothesis' T_cam_laser, per capture the index of the chosen candidate,
        (C,) bool: the captures whose chosen candidate is within ``threshold_m`` RMS).

    Raises:
        CalibrationError: fewer than MIN_CAPTURES captures agree on any hypothesis.
    """
    rng = np.random.default_rng(seed)
    C = len(planes)
    if C < MIN_CAPTURES:
        raise CalibrationError(f"{C} captures; at least {MIN_CAPTURES} are needed")
    obs_all = [
        [
            PlaneObservation(i, str(i), np.asarray(planes[i][0], dtype=float), float(planes[i][1]), p)
            for p in cands
        ]
        for i, cands in enumerate(candidates)
    ]
    # Every candidate's points in one array, for scoring a hypothesis in one pass.
    owner = [(i, k) for i, cands in enumerate(candidates) for k in range(len(cands))]
    pts = np.concatenate([np.asarray(p, dtype=float).reshape(-1, 2) for cands in candidates for p in cands])
    which = np.repeat(np.arange(len(owner)), [len(candidates[i][k]) for i, k in owner])
    counts = np.bincount(which, minlength=len(owner))
    normals = np.array([planes[i][0] for i, _ in owner], dtype=float)[which]
    dists = np.array([planes[i][1] for i, _ in owner], dtype=float)[which]
    cap_of = np.array([i for i, _ in owner])
    n_cands = np.array([len(c) for c in candidates], dtype=float)

    def rms_per_candidate(T: FloatArray) -> FloatArray:
        p = pts @ T[:3, :2].T + T[:3, 3]
        r = np.einsum("ij,ij->i", p, normals) - dists
        out: FloatArray = np.sqrt(np.bincount(which, r * r, minlength=len(owner)) / counts)
        return out

    def best_per_capture(rms: FloatArray) -> FloatArray:
        out = np.full(C, np.inf)
        np.minimum.at(out, cap_of, rms)
        return out

    best: tuple[int, float] = (-1, np.inf)
    best_T: FloatArray | None = None
    needed = float(iterations)
    done = 0
    while done < min(iterations, needed):
        done += 1
        idx = rng.choice(C, size=MIN_CAPTURES, replace=False)
        sample = [obs_all[i][int(rng.integers(len(obs_all[i])))] for i in idx]
        s = np.linalg.svd(np.array([o.normal_cam for o in sample]), compute_uv=False)
        if s[2] < MIN_NORMAL_SPREAD * s[0]:
            continue
        T = closed_form(sample)
        rms = best_per_capture(rms_per_candidate(T))
        score = (int((rms < threshold_m).sum()), float(np.minimum(rms, threshold_m).sum()))
        if score[0] > best[0] or (score[0] == best[0] and score[1] < best[1]):
            best, best_T = score, T
            agree = rms < threshold_m
            # Chance that one draw is all agreeing captures with their right candidates.
            if agree.any():
                good = (best[0] / C) ** MIN_CAPTURES * float(np.mean(1.0 / n_cands[agree])) ** MIN_CAPTURES
                needed = np.log(1.0 - confidence) / np.log1p(-min(good, 1.0 - 1e-12))
        if best[0] == C:
            break
    if best_T is None or best[0] < MIN_CAPTURES:
        raise CalibrationError(
            f"no calibration puts the returns of {MIN_CAPTURES} or more captures on their planes; {advice}"
        )
    rms_all = rms_per_candidate(best_T)
    chosen = []
    for i in range(C):
        mine = np.flatnonzero(cap_of == i)
        chosen.append(int(np.argmin(rms_all[mine])))
    agree = best_per_capture(rms_all) < threshold_m
    return best_T, chosen, agree


def point_to_plane(T: FloatArray, o: PlaneObservation) -> FloatArray:
    """(M,) signed distances of the capture's returns from its plane, metres."""
    p = np.column_stack([o.points_laser, np.zeros(len(o.points_laser))]) @ T[:3, :3].T + T[:3, 3]
    out: FloatArray = p @ np.asarray(o.normal_cam, dtype=float) - o.distance_m
    return out


def ransac_closed_form(
    observations: Sequence[PlaneObservation],
    threshold_m: float = 0.03,
    iterations: int = 200,
    seed: int = 0,
) -> tuple[FloatArray, NDArray[np.bool_]]:
    """Closed forms from random MIN_CAPTURES-capture samples; a capture is an inlier when
    the RMS of its point-to-plane distances is under ``threshold_m``. Returns the best
    pose (re-solved on its inliers) and the inlier mask (step 2)."""
    _check_observable(observations)
    rng = np.random.default_rng(seed)
    C = len(observations)
    best_mask = np.zeros(C, dtype=bool)
    best_cost = np.inf
    for _ in range(iterations if C > MIN_CAPTURES else 1):
        idx = rng.choice(C, size=MIN_CAPTURES, replace=False) if C > MIN_CAPTURES else np.arange(C)
        sample = [observations[i] for i in idx]
        try:
            T = closed_form(sample)
        except CalibrationError:
            continue
        rms = np.array([np.sqrt(np.mean(point_to_plane(T, o) ** 2)) for o in observations])
        cost = float(np.minimum(rms, threshold_m).sum())
        if cost < best_cost:
            best_cost, best_mask = cost, rms < threshold_m
    if best_mask.sum() < MIN_CAPTURES:
        raise CalibrationError(
            f"no {MIN_CAPTURES} captures agree on a calibration within {threshold_m * 1000:g} mm RMS; "
            "check the board planes and the laser returns chosen on the board"
        )
    inliers = [o for o, keep in zip(observations, best_mask, strict=True) if keep]
    return closed_form(inliers), best_mask


# The robust loss on the whitened residuals of the capture lines (scipy's Cauchy loss,
# bending at LOSS_SCALE sigmas): a capture far off its plane pulls the pose with a weight
# that falls as the square of its distance instead of rising with it.
LOSS = "cauchy"
LOSS_SCALE = 3.0
LOSSES = ("linear", "huber", "soft_l1", "cauchy")
# The most reweighted Gauss-Newton steps that polish a robust fit (:func:`_polish`).
POLISH_STEPS = 10
# A capture is an outlier when its chi-square (2 dof) exceeds the 99.99 % point times the
# robust scale of all captures' chi-squares (median over the chi-square median, at least 1).
OUTLIER_GATE_CHI2 = 18.420680743952367
# Captures whose boards are this close in pose were taken at one pose and share one
# verdict: a hand-held board's repeats lie 1-3 deg and 2-5 cm apart (the image's board
# pose: normals within SAME_POSE_NORMAL_DEG, distances within SAME_POSE_DISTANCE_M, or 4
# sigma of the poses' noise where that is larger; the laser's cut: lines within
# SAME_POSE_CUT_DEG of each other, each one's centre within SAME_POSE_CUT_M of the other's
# line, their extents overlapping by at least half the shorter).
SAME_POSE_NORMAL_DEG = 5.0
SAME_POSE_DISTANCE_M = 0.06
SAME_POSE_CUT_M = 0.06
SAME_POSE_CUT_DEG = 5.0


@dataclass(frozen=True)
class PlaneNoise:
    """The noise model of a plane solve (1 sigma).

    Attributes:
        range_sigma_m: range noise of one return.
        capture_sigma_m: an error every capture's cut carries on its own beyond the range
            noise and the board pose's (a range bias by incidence, a warped board): added to
            the point-to-plane distance of each end of the cut. Estimated from the data.
        pose_cov_scale: factor on every board pose covariance (a corner noise other than
            the one the poses were computed with, squared).
        fit_range_bias: estimate ``range_bias_m`` with the pose.
        range_bias_m: the scanner's range bias by incidence: a return at incidence i
            (between its beam and the board's normal) reads long by
            range_bias_m * (1 / cos(i) - 1) (the footprint smears along a slanted board);
            estimated with the pose when ``fit_range_bias``, its uncertainty then entering
            the pose's covariance.
        loss: the shape assumed for the whitened errors' tails: scipy's robust loss
            (``LOSSES``), bending at LOSS_SCALE sigmas; "linear" is plain least squares
            (Gaussian errors: every capture pulls in proportion to its distance; the outlier
            gate still rejects captures beyond it).
    """

    range_sigma_m: float
    capture_sigma_m: float = 0.0
    pose_cov_scale: float = 1.0
    fit_range_bias: bool = False
    range_bias_m: float = 0.0
    loss: str = LOSS


@dataclass(frozen=True)
class CaptureLine:
    """A capture's returns reduced to the line of the board's cut.

    Under range noise the least-squares line carries all the returns say about the pose
    (each return only says where the line is), so the solve works on the line's two ends
    (the extreme kept returns along it, whatever their order, projected on it) with the
    covariance of the line's offset there; returns the robust fit trimmed (mixed pixels at
    the board's edges, strays) drop out.

    Attributes:
        fit: the robust line fit (:func:`rigcal.calib.noise.fit_line_robust`) of the returns
            in :func:`rigcal.calib.noise.canonical_order` (its per-return arrays follow that
            order, not the order given).
        ends: (2, 2) the cut's two ends on the line, laser frame.
        offset_cov: (2, 2) covariance of the line's offset across itself at the ends, per
            unit range variance (times range_sigma_m^2 gives metres^2).
        bias_shift: (2,) how far a unit range bias by incidence (every return reading
            long by 1 / cos(i) - 1 metres) moves the fitted line across itself at the ends,
            along its normal.
    """

    fit: LineFit
    ends: FloatArray
    offset_cov: FloatArray
    bias_shift: FloatArray

    def ends_corrected(self, range_bias_m: float) -> FloatArray:
        """(2, 2) the ends with a range bias by incidence taken out."""
        out: FloatArray = self.ends - range_bias_m * self.bias_shift[:, None] * self.fit.normal
        return out


def capture_line(points_laser: FloatArray) -> CaptureLine:
    """Reduce a capture's returns on the board to its :class:`CaptureLine`."""
    # The returns in a fixed order: the line (and so the solve) is the same to the last bit
    # whatever order they were given in.
    points = np.asarray(points_laser, dtype=float)
    points = points[canonical_order(points)]
    fit = fit_line_robust(points)
    k = fit.kept
    sigma_across = float(np.sqrt(np.mean(fit.cos_incidence[k] ** 2)))
    at = fit.extent_m
    # A bias b_j along each return's ray u_j moves it across the line by b_j (u_j . n); the
    # least-squares line through those moves is the line's own.
    p = points[k]
    u = p / np.linalg.norm(p, axis=1, keepdims=True)
    across = u @ fit.normal
    g = 1.0 / np.maximum(np.abs(across), MIN_COS_INCIDENCE) - 1.0
    slope, offset = np.polyfit(fit.along_m[k], g * across, 1) if k.sum() >= 2 else (0.0, 0.0)
    return CaptureLine(
        fit, fit.ends, line_offset_covariance(fit.along_m[k], sigma_across, at), offset + slope * at
    )


@dataclass(frozen=True)
class PlaneResult:
    """Outcome of a plane-based solve.

    Attributes:
        T_cam_laser: (4, 4) the pose.
        covariance: (6, 6) over [dtheta (rad), t (m)] in the camera frame, as the box
            method: the model's, scaled up to cover the spread over captures when that is
            larger (:mod:`rigcal.calib.spread`), times ``few_poses_factor``.
        residuals_m: per capture, (M,) signed point-to-plane distances, metres.
        residual_scale: sqrt(chi^2 / dof) of the whitened residuals of the used captures.
        inlier_captures: (C,) bool, the captures' verdicts (grouped by pose).
        covariance_model: (6, 6) the noise model's covariance.
        chi2: (C,) each capture's chi-square (2 dof) under the final pose and noise.
        weights: (C,) each capture's robust weight in the final fit (0 for outliers).
        lines: per capture, its returns reduced to a line.
        noise: the noise model used.
        range_noise: the range noise estimated from the captures' lines.
        pose_group: (C,) index of each capture's same-pose group.
        spread: leave-one-capture-out spread (None with too few captures).
        sensitivity: moves of the answer when a noise setting is halved or doubled.
        range_bias_sigma_m: 1-sigma of the fitted range bias by incidence
            (``noise.range_bias_m``), None when it was not fitted.
        screened_out: (C,) bool, captures set aside before the solve as gross outliers
            (:func:`gross_outliers`: off the others' consensus by far more than any noise,
            a unit mistake or another scan's returns); their verdict is False.
        screen_rms_m: (C,) each capture's RMS distance from its plane under the others'
            consensus pose (nan when no consensus was formed).
        screen_limit_m: the distance beyond which a capture was set aside.
        poses_used: the board poses (same-pose groups) among the used captures.
        noise_dof: the degrees of freedom the noise scale and per-capture error are
            estimated with: 2 per pose less the fitted parameters.
        few_poses_factor: the factor ``covariance`` carries for that estimate
            (:func:`rigcal.calib.spread.few_dof_factor`; 1 for a large session).
    """

    T_cam_laser: FloatArray
    covariance: FloatArray
    residuals_m: tuple[FloatArray, ...]
    residual_scale: float
    inlier_captures: NDArray[np.bool_]
    covariance_model: FloatArray
    chi2: FloatArray
    weights: FloatArray
    lines: tuple[CaptureLine, ...]
    noise: PlaneNoise
    range_noise: RangeNoise | None
    pose_group: NDArray[np.int64]
    spread: Spread | None
    sensitivity: tuple[Sensitivity, ...]
    range_bias_sigma_m: float | None
    screened_out: NDArray[np.bool_] | None = None
    screen_rms_m: FloatArray | None = None
    screen_limit_m: float = np.inf
    poses_used: int = 0
    noise_dof: int = 0
    few_poses_factor: float = 1.0


def solve_plane(
    observations: Sequence[PlaneObservation],
    range_sigma_m: float | None = None,
    use_ransac: bool = True,
    seed: int = 0,
    corner_sigma_px: float | None = None,
    uncertainty_checks: bool = True,
    fit_range_bias: bool = False,
    loss: str = LOSS,
) -> PlaneResult:
    """Calibrate T_cam_laser from board planes and laser returns (steps 1-4).

    Args:
        observations: one per capture.
        range_sigma_m: the range noise to assume; None estimates it from the captures'
            lines (:func:`rigcal.calib.noise.range_noise_from_lines`).
        use_ransac: also start from RANSAC's best closed form.
        seed: RANSAC seed.
        corner_sigma_px: the corner noise the board pose covariances were computed with,
            for the sensitivity to it (None: no such check).
        uncertainty_checks: run the leave-one-capture-out spread and the sensitivity.
        fit_range_bias: estimate the scanner's range bias by incidence with the pose
            (:class:`PlaneNoise`), its uncertainty entering the pose's covariance.
        loss: the robust loss of the refinement (:class:`PlaneNoise`), one of LOSSES.

    Raises:
        ValueError: an unknown loss.
        CalibrationError: too few captures, planes too alike, or no consensus.
    """
    if loss not in LOSSES:
        raise ValueError(f"loss must be one of {LOSSES}, not {loss!r}")
    _check_observable(observations)
    # The captures in a fixed order (their content's), so that the answer is the same to the
    # last bit whatever order the session lists them in; the result in the order given.
    order = capture_order(observations)
    result = _solve_plane(
        [observations[i] for i in order],
        range_sigma_m,
        use_ransac,
        seed,
        corner_sigma_px,
        uncertainty_checks,
        fit_range_bias,
        loss,
    )
    return _in_given_order(result, order)


def capture_order(observations: Sequence[PlaneObservation]) -> NDArray[np.int64]:
    """(C,) a fixed order of the captures, from what they hold and not where they are
    listed: by the board plane's distance and normal, then the board's origin, then the
    returns (their count and sums, in :func:`rigcal.calib.noise.canonical_order`). Captures
    equal in all of these are interchangeable."""
    keys = []
    for o in observations:
        p = np.asarray(o.points_laser, dtype=float).reshape(-1, 2)
        p = p[canonical_order(p)]
        origin = np.zeros(3) if o.board_origin_cam is None else np.asarray(o.board_origin_cam, dtype=float)
        keys.append([o.distance_m, *np.asarray(o.normal_cam, dtype=float), *origin, len(p), *p.sum(axis=0)])
    k = np.array(keys, dtype=float).reshape(len(observations), -1)
    return np.lexsort(k.T[::-1]).astype(np.int64)


def _in_given_order(result: PlaneResult, order: NDArray[np.int64]) -> PlaneResult:
    """A result solved on the captures in ``order`` ((C,): the given index of each), its
    per-capture figures put back in the order given (pose groups numbered by first
    appearance, the spread's captures listed in that order)."""
    at = np.argsort(order)  # the solved position of each given capture

    def per(x: NDArray[Any] | None) -> NDArray[Any] | None:
        return None if x is None else np.asarray(x)[at]

    _, first, labels = np.unique(result.pose_group[at], return_index=True, return_inverse=True)
    rank = np.argsort(np.argsort(first))
    spread = result.spread
    if spread is not None:
        used_given = order[np.flatnonzero(result.inlier_captures)]
        by = np.argsort(used_given, kind="stable")
        spread = replace(spread, captures=tuple(spread.captures[i] for i in by), shifts=spread.shifts[by])
    return replace(
        result,
        residuals_m=tuple(result.residuals_m[i] for i in at),
        inlier_captures=result.inlier_captures[at],
        chi2=result.chi2[at],
        weights=result.weights[at],
        lines=tuple(result.lines[i] for i in at),
        pose_group=rank[labels].astype(np.int64),
        spread=spread,
        screened_out=per(result.screened_out),
        screen_rms_m=per(result.screen_rms_m),
    )


def _solve_plane(
    observations: Sequence[PlaneObservation],
    range_sigma_m: float | None,
    use_ransac: bool,
    seed: int,
    corner_sigma_px: float | None,
    uncertainty_checks: bool,
    fit_range_bias: bool,
    loss: str,
) -> PlaneResult:
    """:func:`solve_plane` on captures in a fixed order."""

    lines = tuple(capture_line(o.points_laser) for o in observations)
    screen = gross_outliers(observations, lines, seed)
    gross = screen.gross
    kept = np.flatnonzero(~gross)
    noise, estimated = start_noise([lines[i] for i in kept], range_sigma_m, fit_range_bias, loss)
    reduced = [replace(o, points_laser=ln.ends) for o, ln in zip(observations, lines, strict=True)]
    # Start from the closed form on every capture and, when asked, from RANSAC's best
    # sample; keep the robust fit that explains most captures (then the lowest cost). A
    # 5-capture closed form is often poorly conditioned, so RANSAC alone can settle on a
    # wrong pose that a few captures fit.
    reduced = [reduced[i] for i in kept]
    starts = [closed_form(reduced)]
    if use_ransac:
        threshold = max(0.03, 6.0 * noise.range_sigma_m)
        with contextlib.suppress(CalibrationError):
            starts.append(ransac_closed_form(reduced, threshold_m=threshold, seed=seed)[0])
    groups = same_pose_groups(observations, lines)
    fits = [_robust_fit(T0, observations, lines, noise, groups, gross) for T0 in starts]
    T, noise, mask, _ = max(fits, key=lambda f: (int(f[2].sum()), -f[3]))
    if mask.sum() < MIN_CAPTURES:
        raise CalibrationError(
            f"only {int(mask.sum())} captures agree with the calibration; the plane method needs "
            f"{MIN_CAPTURES} (check the segment ids and corners of the others)"
        )
    used = np.flatnonzero(mask)
    cov_full, r_used, weights_used, blocks, scale2 = _covariance(T, observations, lines, noise, used)
    cov_model = cov_full[:6, :6]
    bias_sigma = float(np.sqrt(cov_full[6, 6])) if noise.fit_range_bias else None
    chi2 = _chi2(T, observations, lines, noise)
    weights = np.zeros(len(observations))
    weights[used] = weights_used
    spread = None
    sens: list[Sensitivity] = []
    cov = cov_model
    if uncertainty_checks:
        names = [observations[int(i)].name for i in used]

        def without(k: int) -> FloatArray:
            return _fit(T, observations, lines, noise, np.delete(used, k))[0]

        spread = leave_one_out(without, T, names, cov_model, scale2 * expected_jackknife(blocks)[:6, :6])
        cov = honest_covariance(cov_model, spread)
        settings = {"range_sigma_m": noise.range_sigma_m}
        if corner_sigma_px is not None and observations[0].board_pose_cov is not None:
            settings["corner_sigma_px"] = corner_sigma_px

        def changed(name: str, value: float) -> FloatArray:
            if name == "range_sigma_m":
                return _fit(T, observations, lines, replace(noise, range_sigma_m=value), used)[0]
            assert corner_sigma_px is not None
            scale = noise.pose_cov_scale * (value / corner_sigma_px) ** 2
            return _fit(T, observations, lines, replace(noise, pose_cov_scale=scale), used)[0]

        sens = sensitivity(changed, settings, T, cov)
    # The per-capture error, the residual scale and the range bias are estimated from the
    # captures themselves: with few board poses they are poorly known, and a covariance
    # that takes them as exact is too small. Repeats at one pose share its board-pose error,
    # so the dof count poses, not captures.
    poses = len(np.unique(groups[used]))
    noise_dof = 2 * poses - (7 if noise.fit_range_bias else 6)
    factor = few_dof_factor(noise_dof)
    cov = cov * factor
    dof = len(r_used) - 6
    return PlaneResult(
        T,
        cov,
        tuple(point_to_plane(T, o) for o in observations),
        float(np.sqrt(float(r_used @ r_used) / dof)) if dof > 0 else 1.0,
        mask,
        cov_model,
        chi2,
        weights,
        lines,
        noise,
        estimated,
        groups,
        spread,
        tuple(sens),
        bias_sigma,
        gross,
        screen.rms_m,
        screen.limit_m,
        poses,
        noise_dof,
        factor,
    )


def start_noise(
    lines: Sequence[CaptureLine], range_sigma_m: float | None, fit_range_bias: bool, loss: str
) -> tuple[PlaneNoise, RangeNoise | None]:
    """The noise model a solve starts from: the range noise given, else the one estimated
    from the captures' lines (:func:`rigcal.calib.noise.range_noise_from_lines`, also
    returned, None when no line has enough returns), with a 0.1 mm floor.

    Raises:
        CalibrationError: no range noise given and none can be estimated.
    """
    try:
        estimated = range_noise_from_lines([ln.fit for ln in lines])
    except ValueError:
        estimated = None
    if range_sigma_m is None:
        if estimated is None:
            raise CalibrationError(
                "no capture has 3 or more returns on its board to estimate the range noise"
            )
        range_sigma_m = estimated.sigma_m
    return PlaneNoise(max(range_sigma_m, 1e-4), fit_range_bias=fit_range_bias, loss=loss), estimated


def refit_pose(result: PlaneResult, observations: Sequence[PlaneObservation]) -> FloatArray:
    """T_cam_laser re-solved from ``result``'s pose with other board planes (the same
    returns, noise model and verdicts): how the answer follows the planes, e.g. under other
    camera intrinsics."""
    used = np.flatnonzero(result.inlier_captures)
    return _fit(result.T_cam_laser, observations, result.lines, result.noise, used)[0]


# A capture is a gross outlier, set aside before the solve, when the consensus of the
# others puts its cut farther from its board plane than GROSS_SIGMAS range sigmas (the
# captures' median own scatter), and at least GROSS_FLOOR_M: no noise explains that, only
# a mistake (returns in millimetres, another scan's returns). Closer ones are left to the
# robust loss and the chi-square gate.
GROSS_SIGMAS = 100.0
GROSS_FLOOR_M = 0.5


@dataclass(frozen=True)
class GrossScreen:
    """The screen for gross outliers before a solve.

    Attributes:
        gross: (C,) bool, the captures set aside.
        rms_m: (C,) each capture's RMS distance of its cut's ends from its plane under
            the consensus pose (nan when none was formed).
        limit_m: the distance beyond which a capture is set aside (inf: no screen).
    """

    gross: NDArray[np.bool_]
    rms_m: FloatArray
    limit_m: float


def gross_outliers(
    observations: Sequence[PlaneObservation], lines: Sequence[CaptureLine], seed: int = 0
) -> GrossScreen:
    """Captures that disagree with all the others by far more than any noise.

    A robust loss caps a capture's pull, but a capture hundreds of sigmas off (returns in
    millimetres read as metres, or 140 m away) still wrecks the closed-form start and the
    range noise estimate, and so steers the solve before any verdict. RANSAC over captures
    (:func:`ransac_closed_form`, threshold 6 range sigmas, at least 3 cm) finds the pose
    most captures agree on; a capture outside that consensus whose cut lies farther than
    max(GROSS_SIGMAS range sigmas, GROSS_FLOOR_M) from its plane is set aside. The range
    sigma here is the median over captures of their own robust scatter, which one bad
    capture cannot move. Nothing is set aside unless at least half of the captures (and
    MIN_CAPTURES) agree and MIN_CAPTURES remain.
    """
    C = len(observations)
    none = GrossScreen(np.zeros(C, dtype=bool), np.full(C, np.nan), float("inf"))
    own = [robust_scale(ln.fit.range_residuals_m) for ln in lines if ln.fit.kept.sum() >= 4]
    sigma = float(np.median(own)) if own else 0.0
    limit = max(GROSS_FLOOR_M, GROSS_SIGMAS * sigma)
    if C <= MIN_CAPTURES:
        return none
    reduced = [replace(o, points_laser=ln.ends) for o, ln in zip(observations, lines, strict=True)]
    try:
        T, agree = ransac_closed_form(reduced, threshold_m=max(0.03, 6.0 * sigma), seed=seed)
    except CalibrationError:
        return none
    if agree.sum() < max(MIN_CAPTURES, 0.5 * C):
        return none
    rms = np.array([float(np.sqrt(np.mean(point_to_plane(T, o) ** 2))) for o in reduced])
    gross = (rms > limit) & ~agree
    if (~gross).sum() < MIN_CAPTURES:
        return none
    return GrossScreen(gross, rms, limit)


def same_pose_groups(
    observations: Sequence[PlaneObservation], lines: Sequence[CaptureLine]
) -> NDArray[np.int64]:
    """(C,) a group index per capture: captures whose boards have the same pose share one,
    so that they get one verdict, and count as one pose. Two boards have the same pose when
    what the image shows and what the laser shows agree together: their planes within
    max(SAME_POSE_NORMAL_DEG, 4 sigma) in normal and max(SAME_POSE_DISTANCE_M, 4 sigma) in
    distance (sigmas from the board poses' covariances), and their cuts on nearly one line
    (within SAME_POSE_CUT_DEG, each centre within SAME_POSE_CUT_M of the other's line)
    over a shared stretch (extents overlapping by half the shorter). The floors are a
    hand-held board's repeats (1-3 deg, 2-5 cm apart); the relation is closed transitively."""
    C = len(observations)
    sig_angle = np.zeros(C)
    sig_dist = np.zeros(C)
    for i, o in enumerate(observations):
        if o.board_pose_cov is not None:
            n = np.asarray(o.normal_cam, dtype=float)
            # A rotation w turns the normal by |w x n|; the distance n . origin moves only
            # with the translation (a rotation about the camera keeps it).
            P = np.eye(3) - np.outer(n, n)
            sig_angle[i] = float(np.sqrt(np.linalg.eigvalsh(P @ o.board_pose_cov[:3, :3] @ P)[-1]))
            sig_dist[i] = float(np.sqrt(n @ o.board_pose_cov[3:, 3:] @ n))
        else:
            sig_dist[i] = o.distance_sigma_m
    same = np.eye(C, dtype=bool)
    for i in range(C):
        for j in range(i + 1, C):
            a, b = observations[i], observations[j]
            angle_max = max(np.radians(SAME_POSE_NORMAL_DEG), 4.0 * np.hypot(sig_angle[i], sig_angle[j]))
            dist_max = max(SAME_POSE_DISTANCE_M, 4.0 * np.hypot(sig_dist[i], sig_dist[j]))
            same[i, j] = same[j, i] = (
                float(np.dot(a.normal_cam, b.normal_cam)) >= np.cos(angle_max)
                and abs(a.distance_m - b.distance_m) <= dist_max
                and _same_cut(lines[i], lines[j])
            )
    return connected_groups(same)


def _same_cut(a: CaptureLine, b: CaptureLine) -> bool:
    """Whether two captures' cuts lie on nearly one line over a shared stretch (see
    :func:`same_pose_groups`)."""
    fa, fb = a.fit, b.fit
    if abs(float(fa.direction @ fb.direction)) < np.cos(np.radians(SAME_POSE_CUT_DEG)):
        return False
    mid_a, mid_b = a.ends.mean(axis=0), b.ends.mean(axis=0)
    if abs(float((mid_b - fa.centroid) @ fa.normal)) > SAME_POSE_CUT_M:
        return False
    if abs(float((mid_a - fb.centroid) @ fb.normal)) > SAME_POSE_CUT_M:
        return False
    sa = np.sort((a.ends - fa.centroid) @ fa.direction)
    sb = np.sort((b.ends - fa.centroid) @ fa.direction)
    overlap = min(sa[1], sb[1]) - max(sa[0], sb[0])
    return bool(overlap >= 0.5 * min(sa[1] - sa[0], sb[1] - sb[0]))


def _robust_fit(
    T0: FloatArray,
    observations: Sequence[PlaneObservation],
    lines: Sequence[CaptureLine],
    noise: PlaneNoise,
    groups: NDArray[np.int64],
    gross: NDArray[np.bool_],
) -> tuple[FloatArray, PlaneNoise, NDArray[np.bool_], float]:
    """From T0: a robust fit on every capture but the ``gross`` ones, the per-capture error
    estimated from the captures' chi-squares, the verdicts, and a robust fit on the
    inliers; twice over, as the verdicts and the estimate settle. Returns (pose, noise,
    inliers, robust cost)."""
    mask = ~gross

    def refit(T: FloatArray, noise: PlaneNoise, estimate: bool) -> tuple[FloatArray, PlaneNoise]:
        """The pose (and range bias) on the captures in ``mask``; with ``estimate``, the
        per-capture error re-estimated under it."""
        T, bias = _fit(
            T, observations, lines, noise, np.flatnonzero(mask if mask.sum() >= MIN_CAPTURES else ~gross)
        )
        noise = replace(noise, range_bias_m=bias)
        if estimate:
            noise = replace(noise, capture_sigma_m=_capture_sigma(T, observations, lines, noise, mask))
        return T, noise

    T = T0
    for _ in range(3):
        T, noise = refit(T, noise, True)
        new = grouped_verdicts(_chi2(T, observations, lines, noise), groups, mask, OUTLIER_GATE_CHI2) & ~gross
        if np.array_equal(new, mask):
            break
        mask = new
    # The pose and the per-capture error on the settled verdicts.
    for _ in range(2):
        T, noise = refit(T, noise, True)
    T, noise = refit(T, noise, False)
    chi2 = _chi2(T, observations, lines, noise)
    z = np.sqrt(chi2[mask])
    return T, noise, mask, robust_cost(z, noise.loss, LOSS_SCALE)


def capture_cov(T: FloatArray, o: PlaneObservation, line: CaptureLine, noise: PlaneNoise) -> FloatArray:
    """(2, 2) covariance of the point-to-plane distances of a capture's two cut ends: the
    line's offset through the range noise, the board plane's own error (through the board's
    pose when its covariance is known, else an independent distance error) and the
    per-capture error."""
    n = np.asarray(o.normal_cam, dtype=float)
    # A shift d of the line across itself (along its normal in the laser plane) moves each
    # end's distance from the plane by d (R n_line) . n.
    a = float(T[:3, :2] @ line.fit.normal @ n)
    cov = (a * noise.range_sigma_m) ** 2 * line.offset_cov
    if o.board_pose_cov is not None and o.board_origin_cam is not None:
        G = _pose_jacobian(T, o, line)
        cov = cov + noise.pose_cov_scale * G @ o.board_pose_cov @ G.T
    else:
        cov = cov + o.distance_sigma_m**2
    out: FloatArray = cov + (noise.capture_sigma_m**2 + 1e-18) * np.eye(2)
    return out


def _whiteners(
    T: FloatArray, observations: Sequence[PlaneObservation], lines: Sequence[CaptureLine], noise: PlaneNoise
) -> list[FloatArray]:
    """Per capture, the inverse Cholesky factor of its own (marginal) covariance."""
    return [
        np.linalg.inv(np.linalg.cholesky(capture_cov(T, o, ln, noise)))
        for o, ln in zip(observations, lines, strict=True)
    ]


def pose_units(observations: Sequence[PlaneObservation]) -> list[NDArray[np.int64]]:
    """The observations grouped by ``pose_key`` (each without a key on its own), in order of
    first appearance: the units whose errors are whitened together."""
    units: dict[object, list[int]] = {}
    for i, o in enumerate(observations):
        units.setdefault(i if o.pose_key is None else o.pose_key, []).append(i)
    return [np.array(u, dtype=np.int64) for u in units.values()]


def _pose_jacobian(T: FloatArray, o: PlaneObservation, line: CaptureLine) -> FloatArray:
    """(2, 6) how the cut ends' point-to-plane distances move with the board's pose
    [w, db] (rotation about ``board_origin_cam``): res = n . (p - b), so
    d res = w . (n x (p - b)) - n . db."""
    n = np.asarray(o.normal_cam, dtype=float)
    assert o.board_origin_cam is not None
    pc = np.column_stack([line.ends, np.zeros(2)]) @ T[:3, :3].T + T[:3, 3]
    return np.column_stack([np.cross(n, pc - o.board_origin_cam), np.broadcast_to(-n, pc.shape)])


def _joint_cov(
    T: FloatArray, observations: Sequence[PlaneObservation], lines: Sequence[CaptureLine], noise: PlaneNoise
) -> FloatArray:
    """(2m, 2m) covariance of the cut ends' distances of m observations of one rigid
    target's pose: each one's own (:func:`capture_cov`) on the diagonal, and between two
    the error they share through the one pose, G_i C G_j^T."""
    m = len(observations)
    cov = np.zeros((2 * m, 2 * m))
    G = [
        _pose_jacobian(T, o, ln) if o.board_pose_cov is not None and o.board_origin_cam is not None else None
        for o, ln in zip(observations, lines, strict=True)
    ]
    for i, (o, ln) in enumerate(zip(observations, lines, strict=True)):
        cov[2 * i : 2 * i + 2, 2 * i : 2 * i + 2] = capture_cov(T, o, ln, noise)
        for j in range(i):
            Gi, Gj = G[i], G[j]
            if Gi is None or Gj is None or o.board_pose_cov is None:
                continue
            c = noise.pose_cov_scale * Gi @ o.board_pose_cov @ Gj.T
            cov[2 * i : 2 * i + 2, 2 * j : 2 * j + 2] = c
            cov[2 * j : 2 * j + 2, 2 * i : 2 * i + 2] = c.T
    return cov


def _unit_whiteners(
    T: FloatArray, observations: Sequence[PlaneObservation], lines: Sequence[CaptureLine], noise: PlaneNoise
) -> list[tuple[NDArray[np.int64], FloatArray]]:
    """Per unit (:func:`pose_units`), its observations' positions and the inverse Cholesky
    factor of their joint covariance: lower triangular, so each observation's two whitened
    rows depend on it and the unit's earlier ones only."""
    out = []
    for u in pose_units(observations):
        obs = [observations[i] for i in u]
        lns = [lines[i] for i in u]
        cov = _joint_cov(T, obs, lns, noise) if len(u) > 1 else capture_cov(T, obs[0], lns[0], noise)
        out.append((u, np.linalg.inv(np.linalg.cholesky(cov))))
    return out


def end_residuals(T: FloatArray, o: PlaneObservation, line: CaptureLine, range_bias_m: float) -> FloatArray:
    """(2,) the point-to-plane distances of a capture's cut ends, range bias taken out."""
    n = np.asarray(o.normal_cam, dtype=float)
    out: FloatArray = (line.ends_corrected(range_bias_m) @ T[:3, :2].T + T[:3, 3]) @ n - o.distance_m
    return out


def _chi2(
    T: FloatArray, observations: Sequence[PlaneObservation], lines: Sequence[CaptureLine], noise: PlaneNoise
) -> FloatArray:
    """(C,) each capture's squared whitened distance of its cut from its plane (2 dof)."""
    W = _whiteners(T, observations, lines, noise)
    return np.array(
        [
            float(np.sum((w @ end_residuals(T, o, ln, noise.range_bias_m)) ** 2))
            for w, o, ln in zip(W, observations, lines, strict=True)
        ]
    )


def _capture_sigma(
    T: FloatArray,
    observations: Sequence[PlaneObservation],
    lines: Sequence[CaptureLine],
    noise: PlaneNoise,
    mask: NDArray[np.bool_],
    params: int = 6,
) -> float:
    """The per-capture error that makes the captures in ``mask`` as far off their planes
    as the noise model predicts (:func:`rigcal.calib.noise.matching_noise`; 0 when the range
    noise and the board poses already explain them); ``params``: the parameters fitted
    (6, or the level solve's 3 observed ones)."""
    obs = [o for o, k in zip(observations, mask, strict=True) if k]
    lns = [ln for ln, k in zip(lines, mask, strict=True) if k]
    dof = 2 * len(obs) - params
    # No per-capture error unless the captures disagree beyond chance (90 %): an estimate
    # from chance alone would only widen the covariance.
    if dof <= 0 or float(np.sum(np.minimum(_chi2(T, obs, lns, noise), CLIP_CHI2))) < chi2_ppf(0.9, dof):
        return 0.0
    return matching_noise(
        lambda s: _chi2(T, obs, lns, replace(noise, capture_sigma_m=s)),
        max(1.0 - params / (2 * len(obs)), 0.1),
        0.0,
        1.0,
    )


def _fit(
    T0: FloatArray,
    observations: Sequence[PlaneObservation],
    lines: Sequence[CaptureLine],
    noise: PlaneNoise,
    used: NDArray[np.int64] | None,
) -> tuple[FloatArray, float]:
    """Robust fit (scipy trust region, ``noise.loss``) of the whitened cut-end distances of the
    captures ``used`` (all when None) from T0 (step 4); with ``noise.fit_range_bias`` the
    range bias by incidence is fitted too. Returns (pose, range bias)."""
    idx = np.arange(len(observations)) if used is None else used
    obs = [observations[i] for i in idx]
    lns = [lines[i] for i in idx]
    W = _unit_whiteners(T0, obs, lns, noise)
    R0 = T0[:3, :3]

    def pose(x: FloatArray) -> FloatArray:
        return make_T(rotvec_to_R(x[:3]) @ R0, x[3:6])

    def residuals(x: FloatArray) -> FloatArray:
        T = pose(x)
        bias = float(x[6]) if noise.fit_range_bias else noise.range_bias_m
        return np.concatenate(
            [w @ np.concatenate([end_residuals(T, obs[i], lns[i], bias) for i in u]) for u, w in W]
        )

    x0 = np.concatenate([np.zeros(3), T0[:3, 3], [noise.range_bias_m] if noise.fit_range_bias else []])
    # Converged well below any noise (scipy's default tolerances, 1e-8, leave the answer to
    # depend at ~1e-9 on where the iterations started and on rounding in the inputs).
    sol = least_squares(residuals, x0, method="trf", loss=noise.loss, f_scale=LOSS_SCALE, x_scale="jac")
    x = _polish(residuals, sol.x, noise.loss)
    return pose(x), float(x[6]) if noise.fit_range_bias else noise.range_bias_m


def _polish(residuals: Callable[[FloatArray], FloatArray], x: FloatArray, loss: str) -> FloatArray:
    """The robust fit's minimum to the last bits: iteratively reweighted Gauss-Newton steps
    (weights rho' of ``loss``, an exact least-squares solve each, central-difference
    Jacobian) from scipy's answer until a step is below 1e-11 of the parameters. scipy stops
    at its tolerances (1e-8), where the answer still depends at ~1e-9 on where its iterations
    began and on rounding in the inputs; the minimum itself does not."""
    x = np.array(x, dtype=float)
    for _ in range(POLISH_STEPS):
        r = residuals(x)
        # Steps of 1e-4: rounding in the differences stays near 1e-12 (smaller steps
        # leave the iterations wandering at 1e-9), the truncation only slows convergence.
        h = 1e-4 * (1.0 + np.abs(x))
        J = np.column_stack(
            [
                (residuals(x + h[k] * e) - residuals(x - h[k] * e)) / (2.0 * h[k])
                for k, e in enumerate(np.eye(len(x)))
            ]
        )
        w = np.sqrt(loss_weights(r, loss, LOSS_SCALE))
        dx = np.linalg.lstsq(J * w[:, None], r * w, rcond=None)[0]
        x = x - dx
        if np.abs(dx).max() <= 1e-11 * (1.0 + np.abs(x).max()):
            break
    return x


def _covariance(
    T: FloatArray,
    observations: Sequence[PlaneObservation],
    lines: Sequence[CaptureLine],
    noise: PlaneNoise,
    used: NDArray[np.int64],
) -> tuple[FloatArray, FloatArray, FloatArray, list[FloatArray], float]:
    """The model covariance at T from the robust fit's information (IRLS weights), inflated
    by the weighted residual scale when above 1; also the used captures' whitened residuals,
    each capture's robust weight (the mean of its two ends'), its weighted whitened
    Jacobian rows and the inflation factor (squared residual scale, at least 1)."""
    obs = [observations[i] for i in used]
    lns = [lines[i] for i in used]
    raw_r, raw_J = [], []
    for o, ln in zip(obs, lns, strict=True):
        n = np.asarray(o.normal_cam, dtype=float)
        rp = np.column_stack([ln.ends_corrected(noise.range_bias_m), np.zeros(2)]) @ T[:3, :3].T
        raw_r.append(end_residuals(T, o, ln, noise.range_bias_m))
        # d(n . (Exp(w) R p))/dw = n . (w x Rp) = w . (Rp x n)
        cols = [np.cross(rp, n), np.broadcast_to(n, rp.shape)]
        if noise.fit_range_bias:
            # d/db of n . (R (e - b s n_line)) = -s (R n_line) . n
            cols.append((-ln.bias_shift * float(T[:3, :2] @ ln.fit.normal @ n))[:, None])
        raw_J.append(np.column_stack(cols))
    # Whitened per unit; an observation's rows are its two rows of its unit's whitened rows.
    rs: list[FloatArray] = [np.zeros(2)] * len(obs)
    Js: list[FloatArray] = [np.zeros((2, raw_J[0].shape[1]))] * len(obs)
    for u, w in _unit_whiteners(T, obs, lns, noise):
        ru = w @ np.concatenate([raw_r[i] for i in u])
        Ju = w @ np.concatenate([raw_J[i] for i in u])
        for k, i in enumerate(u):
            rs[i], Js[i] = ru[2 * k : 2 * k + 2], Ju[2 * k : 2 * k + 2]
    r, J = np.concatenate(rs), np.concatenate(Js)
    wts = loss_weights(r, noise.loss, LOSS_SCALE)
    blocks = [b * np.sqrt(w)[:, None] for b, w in zip(Js, wts.reshape(-1, 2), strict=True)]
    info = (J * wts[:, None]).T @ J
    evals = np.linalg.eigvalsh(info)
    if evals[0] <= 1e-12 * max(evals[-1], 1e-300):
        raise CalibrationError(
            "the calibration is unobservable from these board poses (singular normal equations)"
        )
    dof = len(r) - J.shape[1]
    scale2 = max(1.0, float(np.sum(wts * r**2)) / dof) if dof > 0 else 1.0
    # The pose's covariance with the range bias (when fitted) marginalised out.
    cov = scale2 * np.linalg.inv(info)
    return 0.5 * (cov + cov.T), r, wts.reshape(-1, 2).mean(axis=1), blocks, scale2


def check_normals(observations: Sequence[PlaneObservation]) -> None:
    """Whether the boards' planes (what the images alone show) can fix all six degrees of
    freedom: their normals must span 3D (MIN_NORMAL_SPREAD).

    Raises:
        CalibrationError: the normals are (nearly) parallel or share a plane (a board
            upright against a wall, turned but never tilted), saying in words how far
            they spread and which views to add.
    """
    normals = np.array([np.asarray(o.normal_cam, dtype=float) for o in observations]).reshape(-1, 3)
    if len(normals) == 0:
        raise CalibrationError("no board planes to calibrate from")
    _, s, Vt = np.linalg.svd(normals)
    s = np.concatenate([s, np.zeros(3 - len(s))])
    if s[2] >= MIN_NORMAL_SPREAD * s[0]:
        return
    names = ", ".join(o.name for o in observations)
    mean = normals.sum(axis=0)
    mean /= max(float(np.linalg.norm(mean)), 1e-12)
    turned = float(np.degrees(np.arccos(np.clip(np.abs(normals @ mean).min(), 0.0, 1.0))))
    if s[1] < MIN_NORMAL_SPREAD * s[0]:
        raise CalibrationError(
            f"the boards of captures {names} all face one way (their planes are parallel: every normal "
            f"within {turned:.1f} deg of their mean; normals' spread {s[2] / s[0]:.3f} < "
            f"{MIN_NORMAL_SPREAD}), as the images show before any laser return is looked at: turn "
            "the board left and right (by 20-40 deg) and tilt it forward and back between captures"
        )
    out = np.abs(normals @ Vt[2])
    lean = float(np.degrees(np.arcsin(np.clip(out.max(), 0.0, 1.0))))
    raise CalibrationError(
        f"the boards of captures {names} never tilt: every board normal is within {lean:.1f} deg of "
        f"one plane (normals' spread {s[2] / s[0]:.3f} < {MIN_NORMAL_SPREAD}; the boards are turned "
        f"up to {turned:.0f} deg), as an upright board turned against a wall gives. The images alone "
        "show this, before any laser return: such planes cannot fix the laser's height, roll and "
        "pitch. Add captures with the board tilted forward and back by 20-40 deg (top towards and "
        "away from the camera) and rolled, or, for a level scanner, give the level priors (roll, "
        "pitch and the camera's height above the scan plane, each with its 1-sigma: the session's "
        "level: or `rigcal solve --level-prior`) for the reduced solve of the yaw and the "
        "horizontal translations"
    )


def weak_normals_warning(observations: Sequence[PlaneObservation]) -> str | None:
    """A warning when the boards' normals span 3D (:func:`check_normals`) but thinly
    (spread under WEAK_NORMAL_SPREAD): which camera direction no board faces along, and how
    to turn the board to cover it; None otherwise."""
    normals = np.array([np.asarray(o.normal_cam, dtype=float) for o in observations]).reshape(-1, 3)
    if len(normals) < 3:
        return None
    _, s, Vt = np.linalg.svd(normals)
    spread = float(s[2] / s[0])
    if spread >= WEAK_NORMAL_SPREAD:
        return None
    v = Vt[2] * np.sign(Vt[2][np.argmax(np.abs(Vt[2]))])
    how = {
        0: "turned left and right (about its vertical axis) by 20-45 deg",
        1: "tilted forward and back (about its horizontal axis) by 20-45 deg",
        2: "facing the camera more squarely in some captures",
    }[int(np.argmax(np.abs(v)))]
    return (
        f"weak geometry: the board normals' spread is {spread:.3f} (under {WEAK_NORMAL_SPREAD}; "
        f"{MIN_NORMAL_SPREAD} is refused): no board faces along camera direction "
        f"({v[0]:+.2f}, {v[1]:+.2f}, {v[2]:+.2f}) (x right, y down, z forward), so the pose is weak "
        f"there; add captures with the board {how}"
    )


def _check_observable(observations: Sequence[PlaneObservation]) -> None:
    if len(observations) < MIN_CAPTURES:
        raise CalibrationError(
            f"{len(observations)} board capture(s); the plane method needs at least {MIN_CAPTURES} "
            "(each plane gives 2 constraints on the 9 unknowns of its closed form)"
        )
    check_normals(observations)
    for o in observations:
        if len(o.points_laser) < 2:
            raise CalibrationError(f"capture {o.name}: fewer than 2 laser returns on the board")
