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
2. **RANSAC over captures** (optional): closed forms from random 5-capture samples,
   scored by the point-to-plane residuals of all captures, so a capture with a wrong
   plane or wrong returns cannot spoil the start. Both starts (all captures, and RANSAC's)
   are refined, every capture re-classified under the refined pose (chi-square 99.9 %),
   and the fit that explains most captures is kept.
3. **Levenberg-Marquardt** of the 6-DoF pose on point-to-plane distances, whitened per
   capture by their covariance (the range noise along each beam projected on the plane's
   normal, plus the plane's own error, which all returns of a capture share through the
   board's pose from PnP), with the same covariance as the box method
   (``rigcal.calib.refine``'s tangent space) inflated by the residual scale when above 1.
"""

from __future__ import annotations

import contextlib
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import least_squares

from rigcal.errors import CalibrationError
from rigcal.geometry import make_T, rotvec_to_R

FloatArray = NDArray[np.float64]

MIN_CAPTURES = 5
# A set of planes whose normals span less than this (smallest singular value of the
# stacked normals, relative to the largest) leaves the pose unobservable.
MIN_NORMAL_SPREAD = 0.05


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
            (left perturbation in the camera frame); when given, each capture's residuals
            are whitened with the errors they share through the board's pose.
    """

    capture: int
    name: str
    normal_cam: FloatArray
    distance_m: float
    points_laser: FloatArray
    distance_sigma_m: float = 0.001
    board_origin_cam: FloatArray | None = None
    board_pose_cov: FloatArray | None = None


@dataclass(frozen=True)
class PlaneResult:
    """Outcome of a plane-based solve.

    Attributes:
        T_cam_laser: (4, 4) the pose.
        covariance: (6, 6) over [dtheta (rad), t (m)] in the camera frame, as the box method.
        residuals_m: per capture, (M,) signed point-to-plane distances, metres.
        residual_scale: sqrt(chi^2 / dof) of the whitened residuals.
        inlier_captures: (C,) bool, captures RANSAC kept.
    """

    T_cam_laser: FloatArray
    covariance: FloatArray
    residuals_m: tuple[FloatArray, ...]
    residual_scale: float
    inlier_captures: NDArray[np.bool_]


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
            f"no calibration puts the returns of {MIN_CAPTURES} or more captures on their boards; "
            "give the board's segment ids (`rigcal lines`)"
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


def solve_plane(
    observations: Sequence[PlaneObservation],
    range_sigma_m: float = 0.01,
    use_ransac: bool = True,
    seed: int = 0,
) -> PlaneResult:
    """Calibrate T_cam_laser from board planes and laser returns (steps 1-3).

    Raises:
        CalibrationError: too few captures, planes too alike, or no consensus.
    """
    # Start from the closed form on every capture and, when asked, from RANSAC's best
    # sample; refine and re-classify each, and keep the one that explains most captures
    # (then the lowest chi-square). A 5-capture closed form is often poorly conditioned,
    # so RANSAC alone can settle on a wrong pose that a few captures fit.
    _check_observable(observations)
    starts = [(closed_form(observations), np.ones(len(observations), dtype=bool))]
    if use_ransac:
        with contextlib.suppress(CalibrationError):
            starts.append(ransac_closed_form(observations, seed=seed))
    fits = []
    for T0, mask0 in starts:
        try:
            fits.append(_fit_and_classify(T0, mask0, observations, range_sigma_m))
        except CalibrationError as exc:
            failure = exc
    if not fits:
        raise failure
    T, mask, _ = max(fits, key=lambda f: (int(f[1].sum()), -f[2]))
    used = [o for o, keep in zip(observations, mask, strict=True) if keep]
    W = [_whitener(T, o, range_sigma_m) for o in used]
    r, J = _whitened_and_jacobian(T, used, W)
    dof = len(r) - 6
    info = J.T @ J
    evals = np.linalg.eigvalsh(info)
    if evals[0] <= 1e-12 * max(evals[-1], 1e-300):
        raise CalibrationError(
            "the calibration is unobservable from these board poses (singular normal equations)"
        )
    scale2 = max(1.0, float(r @ r) / dof) if dof > 0 else 1.0
    cov = scale2 * np.linalg.inv(info)
    return PlaneResult(
        T,
        0.5 * (cov + cov.T),
        tuple(point_to_plane(T, o) for o in observations),
        float(np.sqrt(float(r @ r) / dof)) if dof > 0 else 1.0,
        mask,
    )


def _fit_and_classify(
    T0: FloatArray, mask: NDArray[np.bool_], observations: Sequence[PlaneObservation], range_sigma_m: float
) -> tuple[FloatArray, NDArray[np.bool_], float]:
    """Refine on the captures in ``mask``, re-classify every capture under the refined
    pose, and repeat until stable. Returns (pose, inlier mask, chi-square per dof)."""
    T = T0
    for _ in range(5):
        used = [o for o, keep in zip(observations, mask, strict=True) if keep]
        if len(used) < MIN_CAPTURES:
            raise CalibrationError(
                f"only {len(used)} captures agree with the calibration; the plane method needs "
                f"{MIN_CAPTURES} (check the segment ids and corners of the others)"
            )
        T = _refine(T, used, range_sigma_m)
        # Every capture's whitened residuals must be plausible for its number of returns
        # (chi-square 99.9 %).
        new = np.array([_capture_chi2_ok(T, o, range_sigma_m) for o in observations])
        if np.array_equal(new, mask):
            break
        mask = new
    used = [o for o, keep in zip(observations, mask, strict=True) if keep]
    z = np.concatenate([_whitener(T, o, range_sigma_m) @ point_to_plane(T, o) for o in used])
    return T, mask, float(z @ z) / max(len(z) - 6, 1)


def _refine(T0: FloatArray, used: Sequence[PlaneObservation], range_sigma_m: float) -> FloatArray:
    """Levenberg-Marquardt on the whitened point-to-plane distances from T0 (step 3)."""
    R0 = T0[:3, :3]

    def pose(x: FloatArray) -> FloatArray:
        return make_T(rotvec_to_R(x[:3]) @ R0, x[3:])

    W = [_whitener(T0, o, range_sigma_m) for o in used]

    def residuals(x: FloatArray) -> FloatArray:
        T = pose(x)
        return np.concatenate([w @ point_to_plane(T, o) for w, o in zip(W, used, strict=True)])

    x0 = np.concatenate([np.zeros(3), T0[:3, 3]])
    sol = least_squares(residuals, x0, method="lm", x_scale="jac")
    return pose(sol.x)


def _capture_chi2_ok(T: FloatArray, o: PlaneObservation, range_sigma_m: float) -> bool:
    """Whether a capture's whitened residuals fit its noise (chi-square 99.9 %, M dof)."""
    from scipy.stats import chi2

    z = _whitener(T, o, range_sigma_m) @ point_to_plane(T, o)
    return bool(float(z @ z) < chi2.ppf(0.999, len(z)))


def _whitener(T: FloatArray, o: PlaneObservation, range_sigma_m: float) -> FloatArray:
    """(M, M) W with W^T W the inverse covariance of a capture's point-to-plane distances:
    each return's range noise along its beam, projected on the plane's normal, plus the
    plane's own error, shared by all returns of the capture (through the board's pose when
    its covariance is known, else through an independent distance error)."""
    p = o.points_laser
    n = np.asarray(o.normal_cam, dtype=float)
    rays = np.column_stack([p, np.zeros(len(p))]) / np.linalg.norm(p, axis=1, keepdims=True)
    along_normal = rays @ T[:3, :3].T @ n
    cov = np.diag((range_sigma_m * along_normal) ** 2)
    if o.board_pose_cov is not None and o.board_origin_cam is not None:
        # res = n . (p - b); d res = w . (n x (p - b)) - n . db for a board pose change (w, db).
        pc = np.column_stack([p, np.zeros(len(p))]) @ T[:3, :3].T + T[:3, 3]
        G = np.column_stack([np.cross(n, pc - o.board_origin_cam), np.broadcast_to(-n, pc.shape)])
        cov = cov + G @ o.board_pose_cov @ G.T
    else:
        cov = cov + o.distance_sigma_m**2
    cov += 1e-18 * np.eye(len(p))
    out: FloatArray = np.linalg.inv(np.linalg.cholesky(cov))
    return out


def _whitened_and_jacobian(
    T: FloatArray, observations: Sequence[PlaneObservation], whiteners: Sequence[FloatArray]
) -> tuple[FloatArray, FloatArray]:
    """Whitened residuals and their Jacobian over [dtheta, t] at dtheta = 0 (left
    perturbation in the camera frame: d(Exp(w) R p)/dw = -[R p]x)."""
    rs, Js = [], []
    for o, W in zip(observations, whiteners, strict=True):
        n = np.asarray(o.normal_cam, dtype=float)
        rp = np.column_stack([o.points_laser, np.zeros(len(o.points_laser))]) @ T[:3, :3].T
        rs.append(W @ (rp @ n + T[:3, 3] @ n - o.distance_m))
        # d(n . (Exp(w) R p))/dw = n . (w x Rp) = w . (Rp x n)
        Js.append(W @ np.column_stack([np.cross(rp, n), np.broadcast_to(n, rp.shape)]))
    return np.concatenate(rs), np.concatenate(Js)


def _check_observable(observations: Sequence[PlaneObservation]) -> None:
    if len(observations) < MIN_CAPTURES:
        raise CalibrationError(
            f"{len(observations)} board capture(s); the plane method needs at least {MIN_CAPTURES} "
            "(each plane gives 2 constraints on the 9 unknowns of its closed form)"
        )
    normals = np.array([np.asarray(o.normal_cam, dtype=float) for o in observations])
    s = np.linalg.svd(normals, compute_uv=False)
    if len(s) < 3 or s[2] < MIN_NORMAL_SPREAD * s[0]:
        names = ", ".join(o.name for o in observations)
        raise CalibrationError(
            f"the board planes of captures {names} are (nearly) parallel or share an axis "
            f"(normals' spread {s[-1] / s[0]:.3f} < {MIN_NORMAL_SPREAD}); tilt the board about "
            "both of its axes between captures"
        )
    for o in observations:
        if len(o.points_laser) < 2:
            raise CalibrationError(f"capture {o.name}: fewer than 2 laser returns on the board")
