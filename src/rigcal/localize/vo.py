"""Visual odometry with the laser's scale (paper Section IV).

The camera's motion between two images, up to scale, from feature tracks:

1. Features (Shi-Tomasi corners; the paper's SIFT keypoints as an option) are tracked
   across frames (:mod:`rigcal.localize.tracks`); a *run*
   goes on from its first frame while at least ``min_tracked`` of that frame's tracks are
   still alive, up to ``max_run_frames`` frames, so that the epipolar geometry is
   computed over enough motion (Section IV).
2. The essential matrix E between the run's first and last frame by the five-point
   algorithm inside robust sampling (OpenCV's ``findEssentialMat`` with MAGSAC++, which
   in turns picks the right one of two near-equal solutions where plain RANSAC does
   not), on normalised image coordinates from the camera model (lens distortion removed
   exactly), Eq. (5): ``p2^T E p1 = 0``.
3. E is decomposed into the rotation R_c and the unit translation t_c (OpenCV's
   ``recoverPose``, the cheirality check), then polished by Gauss-Newton on the Sampson
   distance of the inliers (the "iterative refinement" of Section IV).
4. The scale s of the translation from the laser, Eq. (6): laser points P seen in the
   run's first image are found again in its last image by a patch search (sum of absolute
   differences, as IASM's patches, Section III-A) along their epipolar lines, which is a
   one-parameter search over s since the point moves to ``R_c P + s t_c``; each match is a
   triangulation of P with the current pose, and s = |P| / |P_hat|. The median over the
   laser points that agree with each other is the run's scale; too few votes, or votes
   that disagree, leave the run without a scale (it then keeps the last measured speed).

Conventions: a relative pose ``(R, t)`` maps first-camera coordinates into the second
camera's, ``x2 = R x1 + t`` (OpenCV's). Laser-frame points are (x, y, 0).
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import cv2
import numpy as np
from numpy.typing import NDArray

from rigcal.arrays import MAD_TO_SIGMA, FloatArray
from rigcal.camera import Camera
from rigcal.geometry import R_to_rotvec, make_T, rotvec_to_R
from rigcal.localize.icp_covariance import OPEN_SIGMA_M
from rigcal.localize.patches import sample_patches
from rigcal.localize.tracks import FrameTracks, common, gain_between

Gray = NDArray[np.uint8]


@dataclass(frozen=True)
class VoParams:
    """Visual odometry settings.

    Attributes:
        min_tracked: a run ends when fewer tracks than this stay alive from its first frame.
        max_run_frames: a run ends after this many frames at the latest.
        ransac_threshold_px: five-point RANSAC inlier threshold (pixels, via the focal length).
        min_inliers: fewer essential-matrix inliers than this and the step fails.
        min_inlier_ratio: so does a smaller fraction of inliers among the matches.
        still_px: median motion of the matches (after removing the rotation) below this
            means the rig stood still: the translation is zero.
        patch_radius_px: the scale search compares (2r+1)^2 patches.
        max_speed_mps: the scale search covers translations up to this speed over the run.
        scale_steps: samples of the scale search.
        min_scale_votes: a scale needs at least this many laser points that agree on it...
        scale_agreement: ... within this fraction of their median, and at least half of
            the voting points must agree.
        min_parallax_deg: a track carries the scale from the run before
            (:func:`carried_scale`) only when its two rays meet at least at this angle
            in both runs.
    """

    min_tracked: int = 120
    max_run_frames: int = 5
    ransac_threshold_px: float = 1.0
    min_inliers: int = 25
    min_inlier_ratio: float = 0.4
    still_px: float = 0.6
    patch_radius_px: int = 4
    max_speed_mps: float = 2.0
    scale_steps: int = 81
    min_scale_votes: int = 8
    scale_agreement: float = 0.2
    min_parallax_deg: float = 0.5


@dataclass(frozen=True)
class RelativePose:
    """The camera's motion between two frames: ``x2 = R x1 + scale * t_unit``."""

    R: FloatArray
    t_unit: FloatArray
    inliers: int
    still: bool
    bearings1: FloatArray = field(repr=False)
    bearings2: FloatArray = field(repr=False)
    # (5, 5) of (rotation vector applied on the left of R, t_unit's two tangent steps):
    # :func:`essential_covariance`; a still camera's (3, 3) of its rotation alone.
    covariance: FloatArray | None = field(default=None, repr=False)


def _normalised(bearings: FloatArray) -> FloatArray:
    return bearings[:, :2] / bearings[:, 2:3]


def rotation_between(b1: FloatArray, b2: FloatArray) -> FloatArray:
    """The rotation R minimising sum |b2 - R b1|^2 (Kabsch), for a camera that only turned."""
    U, _, Vt = np.linalg.svd(b2.T @ b1)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    out: FloatArray = U @ D @ Vt
    return out


def relative_pose(
    b1: FloatArray, b2: FloatArray, focal_px: float, params: VoParams, forward: FloatArray | None = None
) -> RelativePose | None:
    """R_c and unit t_c from matched bearings (Eq. (5)), or None when too few inliers.

    A rig standing still (the matches move less than ``still_px`` once the rotation is
    removed) gets the rotation alone and a zero translation.

    The five-point solutions found by robust sampling, and, when ``forward`` (the rig's
    direction of travel in the camera frame) is given, the pure-rotation fit with a
    translation along it, are each refined (Sampson distance); the one with the lowest
    robust cost over all matches wins. A narrow field of view makes a turn while moving
    forward look much like a larger turn while moving sideways (the bas-relief
    ambiguity), and sampling alone picks the wrong one of the two now and then.
    """
    front = (b1[:, 2] > 0.05) & (b2[:, 2] > 0.05)
    b1, b2 = b1[front], b2[front]
    if len(b1) < max(params.min_inliers, 5):
        return None
    R_rot = rotation_between(b1, b2)
    moved = np.linalg.norm(b2 - b1 @ R_rot.T, axis=1) * focal_px
    if float(np.median(moved)) < params.still_px:
        cov = rotation_covariance(R_rot, b1, b2, focal_px)
        return RelativePose(R_rot, np.zeros(3), len(b1), True, b1, b2, cov)
    p1, p2 = _normalised(b1), _normalised(b2)
    E, mask = cv2.findEssentialMat(
        p1, p2, np.eye(3), method=cv2.USAC_MAGSAC, prob=0.999, threshold=params.ransac_threshold_px / focal_px
    )
    if E is None or mask is None or int(mask.sum()) < params.min_inliers:
        return None
    sampled = mask.ravel() > 0
    starts = []
    # Several solutions may come back stacked; recoverPose decomposes each.
    for k in range(E.shape[0] // 3):
        _, R, t, _ = cv2.recoverPose(E[3 * k : 3 * k + 3], p1, p2, np.eye(3), mask=mask.copy())
        starts.append((np.asarray(R, float), np.asarray(t, float).ravel()))
    if forward is not None:
        starts.append((R_rot, np.asarray(forward, float)))
    x1, x2 = _homogeneous(b1), _homogeneous(b2)
    cap = (2.0 * params.ransac_threshold_px / focal_px) ** 2
    best: tuple[float, FloatArray, FloatArray] | None = None
    for R0, t0 in starts:
        R, t = refine_essential(R0, t0, b1[sampled], b2[sampled])
        cost = float(np.minimum(_sampson(R, t, x1, x2) ** 2, cap).mean())
        if best is None or cost < best[0]:
            best = (cost, R, t)
    assert best is not None
    _, R, t = best
    R = _nearer_of_twisted_pair(R, t, R_rot)
    inl = np.abs(_sampson(R, t, x1, x2)) < params.ransac_threshold_px / focal_px
    # E fixes t up to its sign: the sign that puts the points in front of both cameras.
    if _in_front(R, t, b1[inl], b2[inl]) < _in_front(R, -t, b1[inl], b2[inl]):
        t = -t
    n = int(inl.sum())
    # Few inliers among many matches: a repeating pattern or a moving scene fooled the
    # matching, and E is not to be trusted.
    if n < params.min_inliers or n < params.min_inlier_ratio * len(b1):
        return None
    R, t = refine_essential(R, t, b1[inl], b2[inl])
    cov = essential_covariance(R, t, b1[inl], b2[inl], focal_px)
    return RelativePose(R, t, n, False, b1[inl], b2[inl], cov)


def _nearer_of_twisted_pair(R: FloatArray, t: FloatArray, R_rot: FloatArray) -> FloatArray:
    """R or its twin ``Rot(t, 180 deg) R``, whichever is nearer the turn-only fit R_rot.

    The two give the same essential matrix up to sign, ``[t]x Rot(t, pi) = -[t]x`` (Eq.
    (5) cannot tell them apart), and only cheirality separates them: the twin puts the
    points behind one camera. Over a short baseline (a rig that barely moved, or far
    points) a few noisy bearings decide that vote, and the camera comes out turned half
    a circle. The twins are 180 degrees apart, so the one nearer the rotation fitted as
    if the camera had only turned, which errs by the parallax (a few degrees), is right.
    """
    axis = t / np.linalg.norm(t)
    twin: FloatArray = (2.0 * np.outer(axis, axis) - np.eye(3)) @ R
    if _angle(twin @ R_rot.T) < _angle(R @ R_rot.T):
        return twin
    return R


def _angle(R: FloatArray) -> float:
    """A rotation's angle (radians)."""
    return float(np.arccos(np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0)))


def _homogeneous(b: FloatArray) -> FloatArray:
    return np.column_stack([_normalised(b), np.ones(len(b))])


def _sampson(R: FloatArray, t: FloatArray, x1: FloatArray, x2: FloatArray) -> FloatArray:
    """Sampson distances of Eq. (5), ``x2^T E x1 = 0`` with E = [t]x R (normalised units)."""
    out: FloatArray = _sampson_of((_skew(t) @ R)[None], x1, x2)[0]
    return out


def _sampson_of(E: FloatArray, x1: FloatArray, x2: FloatArray) -> FloatArray:
    """(K, N) the Sampson distances of the matches under each of K essential matrices (K, 3, 3)."""
    Ex1 = x1 @ E.transpose(0, 2, 1)  # (K, N, 3)
    Etx2 = x2 @ E
    num = np.einsum("nj,knj->kn", x2, Ex1)
    den = np.sqrt(Ex1[..., 0] ** 2 + Ex1[..., 1] ** 2 + Etx2[..., 0] ** 2 + Etx2[..., 1] ** 2) + 1e-15
    out: FloatArray = num / den
    return out


def _in_front(R: FloatArray, t: FloatArray, b1: FloatArray, b2: FloatArray) -> int:
    """How many matches triangulate in front of both cameras (cheirality)."""
    l1, l2, _ = _ray_depths(R, t, b1, b2)
    return int(((l1 > 0) & (l2 > 0)).sum())


def _ray_depths(
    R: FloatArray, t: FloatArray, b1: FloatArray, b2: FloatArray
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Triangulation of unit bearings under ``x2 = R x1 + t``: the distances l1, l2 along
    b1 (first camera) and b2 (second) minimising |l2 b2 - (l1 R b1 + t)|, and the cosine
    of the angle between the two rays (the parallax; near 1: the depth is ill-posed)."""
    Rb = b1 @ R.T
    m = np.einsum("ij,ij->i", Rb, b2)
    det = np.maximum(1.0 - m * m, 1e-12)
    rt, bt = Rb @ t, b2 @ t
    l1 = (m * bt - rt) / det
    l2 = (bt - m * rt) / det
    return l1, l2, m


def planar_motion(R: FloatArray, t_unit: FloatArray, up_cam: FloatArray, max_tilt_deg: float = 10.0) -> bool:
    """Whether a camera motion is one a ground rig can make: turning about the vertical
    (``up_cam``, the laser's z axis in the camera frame) and moving horizontally."""
    from rigcal.geometry import R_to_rotvec

    w = R_to_rotvec(R)
    angle = float(np.linalg.norm(w))
    if angle > np.radians(1.0) and abs(w @ up_cam) / angle < np.cos(np.radians(max_tilt_deg)):
        return False
    return bool(abs(t_unit @ up_cam) < np.sin(np.radians(3.0 * max_tilt_deg)))


# The forward-difference step of refine_essential's Jacobian, and the rotations by it
# about each camera axis.
_EPS = 1e-7
# The least 1-sigma (pixels) a fit's residuals are taken to have (noise-free images).
MIN_PIXEL_SIGMA_PX = 0.1
_NUDGES = np.stack([rotvec_to_R(_EPS * e) for e in np.eye(3)])
_X, _Y = np.eye(3)[:2]


def refine_essential(
    R: FloatArray, t: FloatArray, b1: FloatArray, b2: FloatArray, iterations: int = 5
) -> tuple[FloatArray, FloatArray]:
    """Gauss-Newton on the Sampson distance of Eq. (5) over (rotation, unit translation).

    Parametrisation: R <- Exp(w) R, t <- normalise(t + a u1 + b u2) with u1, u2 spanning
    the plane orthogonal to t: five parameters, E's degrees of freedom. The Jacobian is
    by forward differences, the five nudged essential matrices' residuals in one pass.
    """
    x1, x2 = _homogeneous(b1), _homogeneous(b2)
    t = t / np.linalg.norm(t)
    r = _sampson(R, t, x1, x2)
    cost = float(r @ r)
    for _ in range(iterations):
        J, u1, u2 = _sampson_jacobian(R, t, x1, x2, r)
        try:
            step = -np.linalg.solve(J.T @ J + 1e-9 * np.eye(5), J.T @ r)
        except np.linalg.LinAlgError:
            break
        tn = t + step[3] * u1 + step[4] * u2
        R_new, t_new = rotvec_to_R(step[:3]) @ R, tn / np.linalg.norm(tn)
        r_new = _sampson(R_new, t_new, x1, x2)
        if float(r_new @ r_new) >= cost:
            break
        R, t, r, cost = R_new, t_new, r_new, float(r_new @ r_new)
    return R, t


def _sampson_jacobian(
    R: FloatArray, t: FloatArray, x1: FloatArray, x2: FloatArray, r: FloatArray
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """(N, 5) Jacobian of the Sampson distances ``r`` at (R, t) over :func:`refine_essential`'s
    parameters (forward differences), and the tangent directions u1, u2 of t."""
    E_t = _skew(t)  # also t's cross products
    u1, u2 = _tangents(t)
    ta, tb = t + _EPS * u1, t + _EPS * u2
    E = np.concatenate(
        [
            E_t @ (_NUDGES @ R),  # the three rotations
            np.stack([_skew(ta / np.linalg.norm(ta)) @ R, _skew(tb / np.linalg.norm(tb)) @ R]),
        ]
    )
    J: FloatArray = ((_sampson_of(E, x1, x2) - r) / _EPS).T
    return J, u1, u2


def _tangents(t: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Two unit directions orthogonal to the unit vector t (and to each other)."""
    u1 = _skew(t) @ (_X if abs(t[0]) < 0.9 else _Y)
    u1 /= np.linalg.norm(u1)
    return u1, _skew(t) @ u1


def run_covariance(
    R: FloatArray,
    t: FloatArray,
    rel_covariance: FloatArray,
    scale_sigma_m: float,
    T_cam_laser: FloatArray,
    still_sigma_m: float = 0.0,
) -> FloatArray:
    """The covariance (3, 3) of a run's planar laser motion (dx, dy, dyaw; Section VI's
    reduction to two dimensions) from the camera's (``x2 = R x1 + t``, t metric):

    - moving (``rel_covariance`` (5, 5), :func:`essential_covariance`): the rotation and
      the translation's direction from the tracks' fit, scaled by |t|, and the length's
      1-sigma ``scale_sigma_m`` (the scale votes', :meth:`ScaleEstimate.sigma`; OPEN_SIGMA_M
      for a run without a scale);
    - still (``rel_covariance`` (3, 3), :func:`rotation_covariance`; t = 0): the rotation,
      and a translation of 1-sigma ``still_sigma_m`` in every direction (what the
      still test lets through);

    propagated to first order through T_l1_l2 = T_cam_laser^-1 [R | t]^-1 T_cam_laser
    (forward differences)."""
    length = float(np.linalg.norm(t))
    if rel_covariance.shape == (5, 5) and length > 0:
        unit = t / length
        u1, u2 = _tangents(unit)
        A = np.zeros((6, 6))
        A[:3, :3] = np.eye(3)
        A[3:, 3], A[3:, 4], A[3:, 5] = length * u1, length * u2, unit
        inner = np.zeros((6, 6))
        inner[:5, :5], inner[5, 5] = rel_covariance, scale_sigma_m**2
        cov6 = A @ inner @ A.T
    else:
        cov6 = np.zeros((6, 6))
        cov6[:3, :3] = rel_covariance[:3, :3]
        cov6[3:, 3:] = still_sigma_m**2 * np.eye(3)
    T_laser_cam = np.linalg.inv(T_cam_laser)

    def planar(d: FloatArray) -> FloatArray:
        T = T_laser_cam @ np.linalg.inv(make_T(rotvec_to_R(d[:3]) @ R, t + d[3:])) @ T_cam_laser
        return _planar(T)

    base = planar(np.zeros(6))
    step = 1e-6
    diffs = np.column_stack([planar(step * e) - base for e in np.eye(6)])
    diffs[2] = np.angle(np.exp(1j * diffs[2]))  # yaw differences across +-pi
    J = diffs / step
    out: FloatArray = J @ cov6 @ J.T
    return 0.5 * (out + out.T)


def still_rotation_covariance(
    covariance: FloatArray, focal_px: float, params: VoParams | None = None
) -> FloatArray:
    """A still run's planar covariance (3, 3) (:func:`run_covariance`) with the rotation
    the still test lets through added to its yaw: the rotation-only fit takes the flow of
    a translation the test passes (median flow up to ``still_px`` once the rotation is
    removed) for a rotation of up to still_px / focal, which its own fit, from the
    bearings' scatter about it, does not see (on the simulated laps its yaw errors were
    up to 6 times the fit's 1-sigma). The added variance is that of a uniform error over
    +-still_px / focal."""
    params = params or VoParams()
    out = np.array(covariance, dtype=float)
    out[2, 2] += (params.still_px / focal_px) ** 2 / 3.0
    return out


def essential_covariance(
    R: FloatArray, t: FloatArray, b1: FloatArray, b2: FloatArray, focal_px: float
) -> FloatArray:
    """The covariance (5, 5) of (R, t_unit) fitted to the inlier bearings (Eq. (5)), in
    :func:`refine_essential`'s parameters: sigma^2 (J^T J)^-1 at the solution, sigma the
    Sampson distances' robust spread (1.4826 MAD, at least ``MIN_PIXEL_SIGMA_PX``)."""
    x1, x2 = _homogeneous(b1), _homogeneous(b2)
    r = _sampson(R, t, x1, x2)
    J, _, _ = _sampson_jacobian(R, t, x1, x2, r)
    sigma = max(MAD_TO_SIGMA * float(np.median(np.abs(r - np.median(r)))), MIN_PIXEL_SIGMA_PX / focal_px)
    out: FloatArray = sigma**2 * np.linalg.pinv(J.T @ J)
    return out


def rotation_covariance(R: FloatArray, b1: FloatArray, b2: FloatArray, focal_px: float) -> FloatArray:
    """The covariance (3, 3) of a still camera's rotation (:func:`rotation_between`) as a
    rotation vector on the left of R: sigma^2 (sum_i [b2_i]x^T [b2_i]x)^-1, sigma the
    bearings' residual spread per axis (at least ``MIN_PIXEL_SIGMA_PX``)."""
    res = b2 - b1 @ R.T
    sigma = max(float(np.sqrt(np.mean(np.sum(res**2, axis=1)) / 2.0)), MIN_PIXEL_SIGMA_PX / focal_px)
    info = sum((_skew(b).T @ _skew(b) for b in b2), np.zeros((3, 3)))
    out: FloatArray = sigma**2 * np.linalg.pinv(info)
    return out


def _skew(v: FloatArray) -> FloatArray:
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


@dataclass(frozen=True)
class ScaleEstimate:
    """Eq. (6) over the laser points: the median scale and how many points voted."""

    scale: float
    used: int
    per_point: FloatArray

    def sigma(self, quantum: float) -> float:
        """1-sigma of the scale: the median's of the agreeing votes (1.253 x 1.4826 MAD /
        sqrt(votes)), at least the search's ``quantum`` (the spacing of its samples) over
        sqrt(12); NaN without a scale."""
        if not np.isfinite(self.scale) or self.used == 0:
            return float("nan")
        # The agreeing votes: the ``used`` nearest the scale (their median).
        off = np.sort(np.abs(self.per_point - self.scale))[: self.used]
        mad = float(np.median(off)) if len(off) else 0.0
        return max(1.253 * MAD_TO_SIGMA * mad / np.sqrt(self.used), quantum / np.sqrt(12.0))


def laser_scale(
    gray1: Gray,
    gray2: Gray,
    camera: Camera,
    R: FloatArray,
    t_unit: FloatArray,
    P1: FloatArray,
    max_scale_m: float,
    params: VoParams,
    gain: float = 1.0,
) -> ScaleEstimate:
    """The translation's scale from laser points, Eq. (6).

    Args:
        gray1, gray2: the run's first and last image.
        R, t_unit: the relative pose from the essential matrix.
        P1: (N, 3) laser points in the first camera's frame, metres (seen at the first image's time).
        max_scale_m: the largest translation searched.
        gain: the second image's exposure gain against the first's (``gray2 ~ gain *
            gray1``, :func:`~rigcal.localize.tracks.gain_between`): the second image's
            patches are divided by it before they are compared.

    Each point's patch in the first image is compared (SAD) with patches along its epipolar
    line in the second image, at ``project(R P + s t_unit)`` for s in [0, max_scale_m];
    the best s triangulates P to P_hat with |P_hat| = |P| / s, so Eq. (6)'s
    s = |P| / |P_hat| is read off directly. Points whose image position barely moves over
    the searched range (far away, or near the epipole), ambiguous matches (a second
    minimum almost as good, as on a repeating pattern) and texture-less patches do not vote.
    """
    r = params.patch_radius_px
    ok = P1[:, 2] > 0.2
    P1 = P1[ok]
    none = ScaleEstimate(float("nan"), 0, np.zeros(0))
    if len(P1) == 0:
        return none
    u1 = camera.project(P1)
    inside = camera.in_image(u1, margin_px=r + 1)
    P1, u1 = P1[inside], u1[inside]
    if len(P1) == 0:
        return none
    ref = sample_patches(gray1, u1, r)
    texture = ref.std(axis=1)
    keep = texture > 4.0
    P1, u1, ref = P1[keep], u1[keep], ref[keep]
    if len(P1) == 0:
        return none
    s = np.linspace(0.0, max_scale_m, params.scale_steps)
    moved = (P1 @ R.T)[:, None, :] + s[None, :, None] * t_unit[None, None, :]  # (N, S, 3)
    front = moved[..., 2] > 0.05
    u2 = camera.project(np.where(front[..., None], moved, np.array([0.0, 0.0, 1.0])).reshape(-1, 3))
    u2 = u2.reshape(len(P1), len(s), 2)
    cand = sample_patches(gray2, u2.reshape(-1, 2), r).reshape(len(P1), len(s), -1)
    if gain != 1.0:
        cand /= np.float32(gain)
    sad = np.abs(cand - ref[:, None, :]).mean(axis=2)
    sad = np.where(
        front & camera.in_image(u2.reshape(-1, 2), margin_px=r + 1).reshape(sad.shape), sad, np.nan
    )
    valid = np.isfinite(sad).sum(axis=1) >= 5
    span = np.linalg.norm(u2[:, -1] - u2[:, 0], axis=1)
    sad_f = np.where(np.isfinite(sad), sad, np.inf)
    best = np.argmin(sad_f, axis=1)
    rows = np.arange(len(P1))
    best_val = sad_f[rows, best]
    # A distinct minimum: the best outside +-2 samples of it is clearly worse.
    far = np.abs(np.arange(len(s))[None, :] - best[:, None]) > 2
    second = np.where(far, sad_f, np.inf).min(axis=1)
    distinct = best_val < 0.8 * second
    # Sub-sample refinement of the minimum by a parabola through its neighbours.
    lo = np.clip(best - 1, 0, len(s) - 1)
    hi = np.clip(best + 1, 0, len(s) - 1)
    a, b, c = sad_f[rows, lo], best_val, sad_f[rows, hi]
    with np.errstate(invalid="ignore", divide="ignore"):
        den = a - 2 * b + c
        frac = np.where((lo < best) & (hi > best) & np.isfinite(den) & (den > 0), 0.5 * (a - c) / den, 0.0)
    est = s[best] + np.clip(frac, -0.5, 0.5) * (s[1] - s[0])
    interior = (best > 0) & (best < len(s) - 1)
    vote = valid & distinct & (span > 2.0 * (2 * r + 1)) & np.isfinite(best_val) & interior
    return _agreed(est[vote], params)


def carried_scale(
    before: FrameTracks,
    first: FrameTracks,
    last: FrameTracks,
    T_before: tuple[FloatArray, FloatArray],
    run: tuple[FloatArray, FloatArray],
    focal_px: float,
    params: VoParams,
) -> ScaleEstimate:
    """A run's scale carried by the tracks from the run before it (relative scale).

    Args:
        before, first, last: the tracks of the run before's first frame, and of this
            run's first and last frames (the run before ends where this one starts).
        T_before: (R, t) of the run before, metric: ``x_first = R x_before + t``.
        run: (R, t_unit) of this run, the unit translation: ``x_last = R x_first + t_unit``.

    Each track alive in the three frames is triangulated twice in the first camera: by
    the run before, at the distance d (metres), and by this run, at d1 (in units of the
    run's translation), so that s = d / d1: the length whose Eq. (6) the laser could not
    measure (a texture-less wall under the scan line) follows from the scene that the
    tracks see. Only tracks consistent with both poses (Sampson distance under the
    RANSAC threshold), in front of the cameras, and seen with at least
    ``min_parallax_deg`` between the two rays in both runs vote; the votes are agreed on
    as the laser's are (:func:`laser_scale`).
    """
    return _relative_scale((before, first, last), T_before, run, True, focal_px, params)


def carried_back_scale(
    first: FrameTracks,
    last: FrameTracks,
    after: FrameTracks,
    run: tuple[FloatArray, FloatArray],
    T_after: tuple[FloatArray, FloatArray],
    focal_px: float,
    params: VoParams,
) -> ScaleEstimate:
    """A run's scale carried back by the tracks from the run after it: as
    :func:`carried_scale`, the tracks triangulated in this run's last camera (the next
    run's first) by the next run (metric, ``T_after``: ``x_after = R x_last + t``) and by
    this run (``run``: (R, t_unit), ``x_last = R x_first + t_unit``)."""
    return _relative_scale((first, last, after), run, T_after, False, focal_px, params)


def _relative_scale(
    frames: tuple[FrameTracks, FrameTracks, FrameTracks],
    T_ab: tuple[FloatArray, FloatArray],
    T_bc: tuple[FloatArray, FloatArray],
    forward: bool,
    focal_px: float,
    params: VoParams,
) -> ScaleEstimate:
    """The scale of one of two consecutive runs a -> b -> c from the other's metric
    translation: of b -> c from a -> b (``forward``), else of a -> b from b -> c. Each
    track alive in the three frames is triangulated in camera b by both runs."""
    a, b, c = frames
    ids = np.intersect1d(a.ids, b.ids, assume_unique=True)
    ids = np.intersect1d(ids, c.ids, assume_unique=True)
    if len(ids) < params.min_scale_votes:
        return ScaleEstimate(float("nan"), 0, np.zeros(0))
    ba, bb, bc = (f.bearings[np.searchsorted(f.ids, ids)] for f in (a, b, c))
    (R0, t0), (R1, t1) = T_ab, T_bc
    tol = params.ransac_threshold_px / focal_px
    la, in_b0, cos0 = _ray_depths(R0, t0, ba, bb)  # depths in a and in b, by a -> b
    in_b1, lc, cos1 = _ray_depths(R1, t1, bb, bc)  # depths in b and in c, by b -> c
    steep = np.cos(np.radians(params.min_parallax_deg))
    xa, xb, xc = _homogeneous(ba), _homogeneous(bb), _homogeneous(bc)
    unit0, unit1 = (t / max(float(np.linalg.norm(t)), 1e-12) for t in (t0, t1))
    far = lc if forward else la  # the other depth of the run whose scale is sought
    ok = (
        (np.abs(_sampson(R0, unit0, xa, xb)) < tol)
        & (np.abs(_sampson(R1, unit1, xb, xc)) < tol)
        & (in_b0 > 0)
        & (in_b1 > 0)
        & (far > 0)
        & (cos0 < steep)
        & (cos1 < steep)
    )
    per = in_b0[ok] / in_b1[ok] if forward else in_b1[ok] / in_b0[ok]
    return _agreed(per, params)


def _agreed(per: FloatArray, params: VoParams) -> ScaleEstimate:
    """The scale the votes agree on: the median of those within ``scale_agreement`` of
    their median, when they are at least half of the votes (else no scale)."""
    if len(per) == 0:
        return ScaleEstimate(float("nan"), 0, per)
    med = float(np.median(per))
    agree = per[np.abs(per - med) <= params.scale_agreement * med]
    if len(agree) < 0.5 * len(per):
        return ScaleEstimate(float("nan"), 0, per)  # the points disagree: no scale
    return ScaleEstimate(float(np.median(agree)), len(agree), per)


@dataclass(frozen=True)
class VoStep:
    """One run of the odometry: frames (first, last), inliers, scale, how it ended."""

    first: int
    last: int
    inliers: int
    scale_points: int
    status: str  # "ok", "carried", "still", "no-scale", "failed"
    # (3, 3): the run's planar laser motion's covariance (:func:`run_covariance`), NaN
    # for a failed run (a constant-velocity guess).
    covariance: FloatArray | None = field(default=None, repr=False, compare=False)


@dataclass(frozen=True)
class VoResult:
    """Laser poses (x, y, yaw) at the frames where runs ended (frame indices), and the runs."""

    frames: NDArray[np.intp]
    poses: FloatArray
    steps: tuple[VoStep, ...]


def visual_odometry(
    tracks: list[FrameTracks],
    image: Callable[[int], Gray],
    stamps_s: FloatArray,
    camera: Camera,
    T_cam_laser: FloatArray,
    laser_points: Callable[[int], FloatArray],
    params: VoParams | None = None,
    progress: Callable[[int], None] | None = None,
    workers: int = 2,
    gain_compensation: bool = True,
) -> VoResult:
    """Chain the camera's runs into the laser's planar trajectory.

    Args:
        tracks: the feature tracks of every frame (:mod:`rigcal.localize.tracks`).
        image: frame index -> grey image (for the scale's patches).
        stamps_s: (n_frames,) image stamps.
        T_cam_laser: the rig's calibration.
        laser_points: frame index -> (N, 2) laser points in the laser frame at that frame's time.
        progress: called with the frames done so far.
        workers: threads measuring the runs (the result does not depend on it).
        gain_compensation: each run's exposure gain, measured on its tracks
            (:func:`~rigcal.localize.tracks.gain_between`), is divided out of the scale
            search's patches (``TrackParams(equalize="gain")``, the default).

    A run goes from its first frame to the last frame, at most ``max_run_frames`` on, that
    still shares ``min_tracked`` tracks with it (Section IV); the next run starts there.
    A run whose laser points give no scale takes the one its tracks carry from the run
    before (:func:`carried_scale`, status "carried") when that run had a scale (or
    stood still after one that had), else the one they carry back from the run after
    (:func:`carried_back_scale`) when that one has a scale (after a turn on the spot no
    track is alive across it: a loop side begun without a laser scale gets its scale
    from the first run along it that has one), else
    moves along its own direction at the last measured speed ("no-scale"). A failed run
    (too few inliers) keeps the previous run's velocity (a constant-velocity guess). Each
    run's status is reported in ``steps``.

    The steps: the runs (:func:`_runs`), each measured (:func:`_measure`: its relative pose,
    Eq. (5), and its laser scale, Eq. (6)), chained in order (:func:`_chained_run`), the
    runs left without a scale given one back from the run after (:func:`_carry_back`),
    and the chain integrated into the laser's poses (:func:`_integrated`).
    """
    params = params or VoParams()
    focal = float(np.mean(camera.intrinsics[:2]))
    forward = T_cam_laser[:3, 0]  # the laser's x axis (the rig's travel) in the camera frame
    inputs = _VoInputs(
        tracks, image, stamps_s, camera, T_cam_laser, laser_points, params, focal, forward, gain_compensation
    )
    state = _ChainState()
    chain: list[_Chained] = []
    # The runs are measured independently (OpenCV and numpy release the interpreter), on
    # ``workers`` threads, in order; giving them their scales is sequential.
    with ThreadPoolExecutor(max_workers=max(workers, 1), thread_name_prefix="vo-run") as pool:
        for m in pool.map(functools.partial(_measure, inputs), _runs(tracks, params)):
            if progress is not None:
                progress(m.last + 1)
            chain.append(_chained_run(m, inputs, state))
    _carry_back(chain, inputs)
    return _integrated(chain, T_cam_laser)


@dataclass(frozen=True)
class _VoInputs:
    """What :func:`visual_odometry` measures and chains its runs with (its arguments, the
    camera's mean focal length in px and the laser's x axis in the camera frame)."""

    tracks: list[FrameTracks]
    image: Callable[[int], Gray]
    stamps_s: FloatArray
    camera: Camera
    T_cam_laser: FloatArray
    laser_points: Callable[[int], FloatArray]
    params: VoParams
    focal: float
    forward: FloatArray
    gain_compensation: bool


@dataclass
class _ChainState:
    """What the chaining carries from one run to the next."""

    # (rotvec/s, translation/s) camera, of the last run that did not fail.
    last_velocity: tuple[FloatArray, FloatArray] | None = None
    speed: float = 0.0  # m/s, of the last run with a scale
    # The last run with a scale, (first frame, R, t) up to this run's first frame.
    scaled: tuple[int, FloatArray, FloatArray] | None = None


def _measure(inp: _VoInputs, run: tuple[int, int, NDArray[np.intp], NDArray[np.intp]]) -> _Measured:
    """One run measured on its own: the relative pose of its last frame to its first from
    the common tracks (Eq. (5)) and, when it moved, the laser scale (Eq. (6)); a still run's
    laser points' median distance."""
    tracks, params, T_cam_laser = inp.tracks, inp.params, inp.T_cam_laser
    kf, j, ia, ib = run
    dt = float(inp.stamps_s[j] - inp.stamps_s[kf])
    rel = relative_pose(tracks[kf].bearings[ia], tracks[j].bearings[ib], inp.focal, params, inp.forward)
    if rel is None:
        return _Measured(kf, j, dt, rel, None)
    P1 = _to_cam(T_cam_laser, inp.laser_points(kf))
    if rel.still:
        depth = float(np.median(np.linalg.norm(P1, axis=1))) if len(P1) else float("nan")
        return _Measured(kf, j, dt, rel, None, depth)
    g1, g2 = inp.image(kf), inp.image(j)
    gain = gain_between(g1, tracks[kf].pixels[ia], g2, tracks[j].pixels[ib]) if inp.gain_compensation else 1.0
    est = laser_scale(g1, g2, inp.camera, rel.R, rel.t_unit, P1, params.max_speed_mps * dt, params, gain)
    return _Measured(kf, j, dt, rel, est)


def _chained_run(m: _Measured, inp: _VoInputs, state: _ChainState) -> _Chained:
    """A measured run's status, metric motion and scale's 1-sigma, given what the runs
    before left in ``state`` (which it updates): a scale carried from the run before when
    its own laser points give none, a constant-velocity guess for a failed run, the last
    speed for a run with no scale."""
    tracks, params, focal = inp.tracks, inp.params, inp.focal
    kf, j, dt, rel = m.first, m.last, m.dt, m.rel
    status, scale_pts = "ok", 0
    # The run's length's 1-sigma (m): the scale search's sample spacing at least.
    quantum = params.max_speed_mps * dt / max(params.scale_steps - 1, 1)
    scale_sigma = OPEN_SIGMA_M
    if rel is None:
        status = "failed"
    elif rel.still:
        status = "still"
        R, t = rel.R, np.zeros(3)
    else:
        assert m.scale is not None
        est = m.scale
        if est.used < params.min_scale_votes or not np.isfinite(est.scale):
            status = "no-scale"
            if state.scaled is not None:
                b0, b1, b2 = tracks[state.scaled[0]], tracks[kf], tracks[j]
                carried = carried_scale(b0, b1, b2, state.scaled[1:], (rel.R, rel.t_unit), focal, params)
                if _within_reach(carried, params, dt):
                    status, est = "carried", carried
        scale_pts = est.used
        if status != "no-scale":
            scale_sigma = est.sigma(quantum)
        R, t = rel.R, est.scale * rel.t_unit
    if status == "failed":
        # Constant velocity: the previous run's motion rates over this run's time.
        last_velocity = state.last_velocity
        R = np.eye(3) if last_velocity is None else rotvec_to_R(last_velocity[0] * dt)
        t = np.zeros(3) if last_velocity is None else last_velocity[1] * dt
    elif status == "no-scale":
        # The direction is known, the length not: the last measured speed (a moving
        # run's, so that a stop does not leave the rig standing still ever after).
        assert rel is not None
        R, t = rel.R, state.speed * dt * rel.t_unit
    else:
        state.last_velocity = (R_to_rotvec(R) / max(dt, 1e-6), t / max(dt, 1e-6))
        if status in ("ok", "carried"):
            state.speed = float(np.linalg.norm(t)) / max(dt, 1e-6)
    if status in ("ok", "carried"):
        state.scaled = (kf, R, t)
    elif status == "still" and state.scaled is not None:
        # A turn on the spot keeps each point's distance: the run before still
        # carries its scale, through this run's rotation.
        state.scaled = (state.scaled[0], R @ state.scaled[1], R @ state.scaled[2])
    else:
        state.scaled = None
    if status == "still":
        # What the still test lets through: still_px at the laser points' distance.
        scale_sigma = params.still_px / focal * (m.depth_m if np.isfinite(m.depth_m) else 1.0)
    return _Chained(kf, j, dt, rel, status, R, t, scale_pts, scale_sigma)


def _carry_back(chain: list[_Chained], inp: _VoInputs) -> None:
    """Runs left without a scale before one that has it (after a stop, say, nothing carried
    the scale into them) take it back from the run after, last first (in place)."""
    tracks, params, focal = inp.tracks, inp.params, inp.focal
    for k in range(len(chain) - 2, -1, -1):
        c, nxt = chain[k], chain[k + 1]
        if c.status != "no-scale" or nxt.status not in ("ok", "carried"):
            continue
        assert c.rel is not None
        back = carried_back_scale(
            tracks[c.first],
            tracks[c.last],
            tracks[nxt.last],
            (c.rel.R, c.rel.t_unit),
            (nxt.R, nxt.t),
            focal,
            params,
        )
        if _within_reach(back, params, c.dt):
            quantum = params.max_speed_mps * c.dt / max(params.scale_steps - 1, 1)
            chain[k] = dataclasses.replace(
                c,
                status="carried",
                t=back.scale * c.rel.t_unit,
                scale_points=back.used,
                scale_sigma_m=back.sigma(quantum),
            )


def _integrated(chain: list[_Chained], T_cam_laser: FloatArray) -> VoResult:
    """The chained runs' camera motions as the laser's planar poses from the first (the
    origin), with each run's covariance (:func:`run_covariance`)."""
    T_w_c = np.linalg.inv(T_cam_laser)  # the first laser pose is the origin
    frames = [0]
    poses = [_planar(T_w_c @ T_cam_laser)]
    steps: list[VoStep] = []
    for c in chain:
        T_w_c = T_w_c @ np.linalg.inv(make_T(c.R, c.t))
        frames.append(c.last)
        poses.append(_planar(T_w_c @ T_cam_laser))
        cov = np.full((3, 3), np.nan)
        if c.rel is not None and c.rel.covariance is not None and c.status != "failed":
            still_m = c.scale_sigma_m if c.status == "still" else 0.0
            cov = run_covariance(c.R, c.t, c.rel.covariance, c.scale_sigma_m, T_cam_laser, still_m)
        inliers = 0 if c.rel is None else c.rel.inliers
        steps.append(VoStep(c.first, c.last, inliers, c.scale_points, c.status, cov))
    return VoResult(np.array(frames, dtype=np.intp), np.array(poses), tuple(steps))


def _within_reach(est: ScaleEstimate, params: VoParams, dt: float) -> bool:
    """A carried scale with enough votes, and no farther than the laser's search goes."""
    return est.used >= params.min_scale_votes and 0.0 < est.scale <= params.max_speed_mps * dt


@dataclass(frozen=True)
class _Chained:
    """One run with its metric motion (``x_last = R x_first + t``, camera frames), its
    status and the points its scale came from."""

    first: int
    last: int
    dt: float
    rel: RelativePose | None
    status: str
    R: FloatArray
    t: FloatArray
    scale_points: int
    scale_sigma_m: float = OPEN_SIGMA_M  # the length's 1-sigma (still: the translation's)


@dataclass(frozen=True)
class _Measured:
    """One run measured: frames (first, last), its duration, the relative pose (None:
    failed) and, when it moved, the laser scale's estimate."""

    first: int
    last: int
    dt: float
    rel: RelativePose | None
    scale: ScaleEstimate | None
    depth_m: float = float("nan")  # a still run's laser points' median distance


def _runs(
    tracks: list[FrameTracks], params: VoParams
) -> list[tuple[int, int, NDArray[np.intp], NDArray[np.intp]]]:
    """The runs (first frame, last frame, the common tracks' indices in each): from its
    first frame to the last frame, at most ``max_run_frames`` on, that still shares
    ``min_tracked`` tracks with it; the next run starts there."""
    n_frames = len(tracks)
    out = []
    kf = 0
    while kf < n_frames - 1:
        j = kf + 1
        ia, ib = common(tracks[kf], tracks[j])
        for c in range(kf + 2, min(kf + params.max_run_frames, n_frames - 1) + 1):
            pairs = common(tracks[kf], tracks[c])
            if len(pairs[0]) < params.min_tracked:
                break
            j, (ia, ib) = c, pairs
        out.append((kf, j, ia, ib))
        kf = j
    return out


def _to_cam(T_cam_laser: FloatArray, pts2: FloatArray) -> FloatArray:
    P = np.column_stack([pts2, np.zeros(len(pts2))])
    out: FloatArray = P @ T_cam_laser[:3, :3].T + T_cam_laser[:3, 3]
    return out


def _planar(T_w_l: FloatArray) -> FloatArray:
    """(x, y, yaw) of a 3D laser pose, dropping the third dimension (Section VI)."""
    return np.array([T_w_l[0, 3], T_w_l[1, 3], np.arctan2(T_w_l[1, 0], T_w_l[0, 0])])
