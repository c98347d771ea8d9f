"""IASM: image-augmented scan matching (paper Section III).

Both find which return of one scan is which return of the next from the camera images,
then the 2D rigid motion between the scans from those pairs by RANSAC.

IASM (Section III):

1. Each scan, paired with its image (moved to the image's time), is projected into the
   image with the rig's T_cam_laser and the camera model (Section III-A).
2. Correspondences by bidirectional SAD: every projected return of scan t is compared
   with the returns of scan t+1 projected within the search area around its own pixel
   (``search_u_px`` x ``search_v_px``), on (2r+1)^2 grey patches; a pair is kept when
   each is the other's best match (mutual minimum SAD). The match is refined between
   neighbouring returns of scan t+1 by a parabola through the SADs (sub-beam).
3. Lines of scan t (the shared extraction, Section III-B) and their angle histogram in
   10 deg bins: lines in more than two neighbouring bins select the laser metric (the
   second scan's alignment to the first, moved by the hypothesis), otherwise the image
   metric (mean SAD between the first image's patches and the second image's patches at
   the first scan moved by the hypothesis and projected) (Section III-C).
4. RANSAC over pairs of correspondences: each pair gives a rigid motion; the hypothesis
   with the best metric wins; a least-squares fit (Eq. (4)) on its inliers polishes it,
   then (``IasmParams.joint_polish``, the default) the joint polish with the scans
   (:mod:`rigcal.localize.polish`).

H-IASM (Section V, :mod:`rigcal.localize.hiasm`) is the same with a small search window
around where the homography of each return's plane puts it; the settings of both are
:class:`IasmParams`.

Conventions: a step's motion is T_t_t1 (x, y, yaw): the pose of the laser at image t+1
in its frame at image t, so that points map as a = T b (a in scan t, b in scan t+1).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from rigcal.arrays import FloatArray
from rigcal.camera import Camera
from rigcal.geometry import transform_points
from rigcal.jit import njit
from rigcal.lines import Segment, extract_lines, return_labels
from rigcal.localize.icp_steps import point_to_point
from rigcal.localize.line_normals import line_fits
from rigcal.localize.nearest import Grid
from rigcal.localize.patches import sample_patches
from rigcal.localize.polish import LaserReference, joint_polish
from rigcal.scan import Scan

IntArray = NDArray[np.intp]
Gray = NDArray[np.uint8]


@dataclass(frozen=True)
class IasmParams:
    """Settings of IASM and H-IASM (docs/localization.md).

    Attributes:
        patch_radius_px: SAD patches are (2r+1)^2 pixels (11 x 11).
        min_texture: patches whose grey-level standard deviation is below this are not matched.
        search_u_px, search_v_px: IASM's search area: half-width across and half-height
            down the image around a return's own pixel.
        window_px: H-IASM's search radius around the homography's prediction.
        window_step_px: H-IASM's dense search tries a point on the wall every this many
            pixels (:func:`window_search`).
        hypotheses: RANSAC hypotheses per step.
        inlier_m: a correspondence is an inlier when the motion maps it within this.
        min_correspondences, min_inliers: below these the step fails (falls back).
        bin_deg: angle histogram bin (Section III-C).
        min_line_m: lines shorter than this do not fill a histogram bin.
        score_points: returns used to score each hypothesis.
        truncate_m: the laser metric's per-point distance is capped at this.
        min_spread_m: the inliers must spread at least this far (1 sigma along their
            main direction), or the rotation is undetermined and the step fails.
        joint_polish: finish with :func:`joint_polish` (laser alignment and correspondences
            together) instead of the correspondences alone.
        sigma_laser_m, sigma_match_m: the joint polish's weights: range noise of a return
            and the weight of a correspondence, as a noise. The correspondences are
            weighted far below their scatter (2 cm): their residual bias (0.11-0.16 %
            of each step's length, forward, on the simulated loops) then stays out of
            what the walls determine, and they still hold what the walls leave open
            (the motion along a featureless corridor).
        match_cauchy: the joint polish weighs each correspondence by the Cauchy weight of
            its residual, with this many robust scatters as the scale (0: all alike)
            (:func:`rigcal.localize.polish.match_weights`).
        snap_max_m: when above 0, each frame's returns are moved onto their lines
            (:func:`snap_to_lines`) when that moves them at most this far (0: as
            measured). The walls' lines are then free of the returns' range noise: over
            ten seeds it halves both loops' mean loop closure and average error
            (``benchmarks/bench_matching.py``, part 4).
        dense_window: H-IASM searches its window densely along the wall
            (:func:`window_search`) instead of among scan t+1's returns. Off by default
            (``benchmarks/bench_matching.py``).
        keyframe_m, keyframe_deg: the joint polish aligns scan t+1 with a keyframe's scan
            instead of scan t's; a new keyframe starts once the rig is more than
            ``keyframe_m`` or ``keyframe_deg`` from the last (each step's motion still
            comes from the correspondences of the two successive images). Scans far
            apart in time then fix each other directly, and the laser's heading error no
            longer adds up step by step: ``benchmarks/bench_matching.py`` (part 3). 0:
            every step against scan t.
        fallback_sigma_m, fallback_sigma_deg: when a step falls back to the laser
            odometry's motion while a keyframe is older than scan t, that motion is aligned
            with the keyframe's scan too, held to the odometry's within these (what the
            walls leave open, along a corridor, stays the odometry's).
        laser_reject_m: the joint polish leaves out returns farther than this from the
            line they are paired with (0: none left out): returns paired with the wrong
            wall, across a corner (more often against a keyframe), lie 0.1-0.2 m off and
            a handful of them turn the step (``benchmarks/bench_matching.py``, part 3).
        support_fraction: only hypotheses with at least this fraction of the best
            hypothesis's inliers are scored by the metric.
        min_alignment: with the laser metric, a result whose alignment score (1 minus the
            mean capped distance over ``truncate_m``) is below this fails.
        odometry_scale: H-IASM's homography (Eq. (10)) takes the translation's scale from
            the laser odometry's motion between the two images; False: the previous
            step's, carried over as in the paper, which puts every window in the wrong
            place when the rig stops or starts between two images
            (``benchmarks/bench_matching.py``, part 5).
        odometry_gate_m: an IASM or H-IASM step whose translation lies farther than this
            from the laser odometry's between the same two images fails (falls back),
            where every scan step between them constrains the odometry (0: no check).
            The walls cannot tell a repeating pattern's wrong copy from the truth along
            a corridor, but the laser odometry, with the corridor's ends in view,
            can: a step matched a period off (0.5 m) lies decimetres from it, a right
            one millimetres; a step whose few inliers agree on a wrong motion (IASM
            with a 5 Hz camera, 76 mm off) centimetres (``benchmarks/bench_matching.py``,
            part 5).
    """

    patch_radius_px: int = 5
    min_texture: float = 3.0
    search_u_px: float = 80.0
    search_v_px: float = 30.0
    window_px: float = 8.0
    window_step_px: float = 0.5
    hypotheses: int = 150
    inlier_m: float = 0.04
    min_correspondences: int = 12
    min_inliers: int = 10
    bin_deg: float = 10.0
    min_line_m: float = 0.3
    score_points: int = 200
    truncate_m: float = 0.1
    support_fraction: float = 0.3
    min_alignment: float = 0.7
    min_spread_m: float = 0.25
    joint_polish: bool = True
    sigma_laser_m: float = 0.01
    sigma_match_m: float = 0.2
    match_cauchy: float = 2.385
    snap_max_m: float = 0.03
    dense_window: bool = False
    keyframe_m: float = 2.0
    keyframe_deg: float = 20.0
    fallback_sigma_m: float = 0.02
    fallback_sigma_deg: float = 0.5
    laser_reject_m: float = 0.03
    odometry_scale: bool = True
    odometry_gate_m: float = 0.05


@dataclass
class Frame:
    """One image with its scan: the returns at the image's time and where they project.

    Attributes:
        gray: the image.
        points: (N, 2) returns in the laser frame at the image's time, beam order.
        cam: (N, 3) the same in the camera frame.
        pixels: (N, 2) their projections.
        visible: (N,) in front of the camera, inside the image, textured enough.
        patches: (N, K) SAD patches (rows of invisible returns unused).
        lines: the scan's lines; ``line_of`` (N,) the line index of each return, -1 for none.
        normals, centres: (N, 2) each return's line (fitted to the moved returns): its
            unit normal and centroid, NaN off a line.
    """

    gray: Gray
    points: FloatArray
    cam: FloatArray
    pixels: FloatArray
    visible: NDArray[np.bool_]
    patches: NDArray[np.float32]
    lines: list[Segment]
    line_of: IntArray
    normals: FloatArray
    centres: FloatArray


def snap_to_lines(points: FloatArray, labels: IntArray, max_move_m: float) -> FloatArray:
    """Returns on a line moved along their beams (from the laser at the origin) onto the
    line fitted through all its returns: the range noise taken out.

    Left where they are: returns on no line, the two returns at either end of a line (at
    a corner they may be the other wall's), and returns their line would move more than
    ``max_move_m`` (a beam grazing the line, or a return off the wall)."""
    centres, normals = line_fits(points, labels)
    out = points.copy()
    on = np.flatnonzero(labels >= 0)
    if len(on) == 0:
        return out
    # p + (lam - 1) p lies on the line n.(x - c) = 0: lam = n.c / n.p
    along = np.einsum("ij,ij->i", normals[on], points[on])
    lam = np.einsum("ij,ij->i", normals[on], centres[on]) / np.where(along == 0.0, np.nan, along)
    snapped = points[on] * lam[:, None]
    ok = np.linalg.norm(snapped - points[on], axis=1) <= max_move_m  # False where NaN
    lab = labels[on]
    first = np.r_[True, lab[1:] != lab[:-1]]
    last = np.r_[lab[1:] != lab[:-1], True]
    ok &= ~(first | last | np.r_[False, first[:-1]] | np.r_[last[1:], False])
    out[on[ok]] = snapped[ok]
    return out


def make_frame(
    gray: Gray,
    scan: Scan,
    camera: Camera,
    T_cam_laser: FloatArray,
    params: IasmParams,
    lines: list[Segment] | None = None,
    T_image_scan: FloatArray | None = None,
) -> Frame:
    """Project a scan's returns, moved to the image's time, into its image (Section III-A).

    With ``params.snap_max_m`` > 0, the returns on a line are first moved along their
    beams onto the line fitted through them (:func:`snap_to_lines`): a match then pairs
    points on the walls, without each return's range noise (1 cm, much of it along the
    wall where a beam meets it at a slant).

    Args:
        lines: the scan's lines when already extracted (the laser odometry's).
        T_image_scan: (3, 3) SE(2) pose of the laser at the scan's stamp in its frame at
            the image's stamp (identity when not given).
    """
    if lines is None:
        lines = extract_lines(scan)
    line_of = return_labels(scan, lines)
    points = scan.points[scan.valid]
    if params.snap_max_m > 0:
        points = snap_to_lines(points, line_of, params.snap_max_m)
    if T_image_scan is not None:
        points = points @ T_image_scan[:2, :2].T + T_image_scan[:2, 2]
    P = transform_points(T_cam_laser, points)
    front = P[:, 2] > 0.1
    px = np.full((len(P), 2), np.nan)
    if front.any():
        px[front] = camera.project(P[front])
    r = params.patch_radius_px
    vis = front & camera.in_image(np.nan_to_num(px, nan=-1e6), margin_px=r + 1)
    patches = np.full((len(P), (2 * r + 1) ** 2), np.nan, dtype=np.float32)
    if vis.any():
        patches[vis] = sample_patches(gray, px[vis], r)
        flat = np.zeros(len(P), dtype=bool)
        flat[vis] = patches[vis].std(axis=1) < params.min_texture
        vis &= ~flat
    centres, normals = line_fits(points, line_of)
    return Frame(gray, points, P, px, vis, patches, lines, line_of, normals, centres)


@dataclass(frozen=True)
class Matches:
    """Correspondences a[k] (return i1[k] of scan t) <-> b[k] (near return i2[k] of scan
    t+1, refined between its neighbours), and their SAD."""

    i1: IntArray
    i2: IntArray
    a: FloatArray
    b: FloatArray
    sad: FloatArray

    @staticmethod
    def none() -> Matches:
        """No correspondences."""
        return Matches(
            np.zeros(0, np.intp), np.zeros(0, np.intp), np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0)
        )


def sad_rows(
    a: NDArray[np.float32], ia: IntArray, b: NDArray[np.float32], ib: IntArray, *, kernel: bool = True
) -> FloatArray:
    """(P,) SAD (mean absolute difference) between patches ``a[ia[p]]`` and ``b[ib[p]]``;
    NaN where a patch has NaN samples (off the image). Compiled kernel, or with
    ``kernel=False`` its numpy reference."""
    if not kernel:
        out: FloatArray = np.abs(a[ia] - b[ib]).mean(axis=1, dtype=np.float64)
        return out
    res = np.empty(len(ia))
    _sad_kernel(a, np.asarray(ia, dtype=np.int64), b, np.asarray(ib, dtype=np.int64), res)
    return res


@njit
def _sad_kernel(
    a: NDArray[np.float32], ia: IntArray, b: NDArray[np.float32], ib: IntArray, out: FloatArray
) -> None:
    k = a.shape[1]
    for p in range(ia.shape[0]):
        acc = 0.0
        for j in range(k):
            acc += abs(a[ia[p], j] - b[ib[p], j])  # float32 differences, as numpy
        out[p] = acc / k


def match_returns(
    f1: Frame,
    f2: Frame,
    predicted: FloatArray,
    half_u: float,
    half_v: float,
    *,
    kernel: bool = True,
) -> Matches:
    """Bidirectional SAD correspondences between the visible returns of two frames.

    Args:
        predicted: (N1, 2) where each return of f1 is expected in image 2 (IASM: its own
            pixel; H-IASM: the homography's prediction).
        half_u, half_v: the search area's half-width and half-height around the prediction.
        kernel: SADs by the compiled kernel (False: by numpy, the reference).
    """
    i1 = np.flatnonzero(f1.visible & np.isfinite(predicted[:, 0]))
    i2 = np.flatnonzero(f2.visible)
    if len(i1) == 0 or len(i2) == 0:
        return Matches.none()
    du = np.abs(f2.pixels[i2, 0][None, :] - predicted[i1, 0][:, None])
    dv = np.abs(f2.pixels[i2, 1][None, :] - predicted[i1, 1][:, None])
    ra, rb = np.nonzero((du <= half_u) & (dv <= half_v))
    if len(ra) == 0:
        return Matches.none()
    sad = sad_rows(f1.patches, i1[ra], f2.patches, i2[rb], kernel=kernel)
    S = np.full((len(i1), len(i2)), np.inf)
    S[ra, rb] = sad
    best_b = np.argmin(S, axis=1)
    best_a = np.argmin(S, axis=0)
    rows = np.arange(len(i1))
    mutual = np.isfinite(S[rows, best_b]) & (best_a[best_b] == rows)
    ka, kb = rows[mutual], best_b[mutual]
    j = i2[kb]
    # Sub-beam refinement: a parabola through the SADs of the neighbouring returns of scan
    # t+1 on the same line moves the match between them.
    b = f2.points[j].copy()
    n2 = len(f2.points)
    inner = (j > 0) & (j < n2 - 1)
    jl, jr = np.clip(j - 1, 0, n2 - 1), np.clip(j + 1, 0, n2 - 1)
    on_line = (
        inner
        & (f2.line_of[j] >= 0)
        & f2.visible[jl]
        & f2.visible[jr]
        & (f2.line_of[jl] == f2.line_of[j])
        & (f2.line_of[jr] == f2.line_of[j])
    )
    k = np.flatnonzero(on_line)
    if len(k):
        s0 = sad_rows(f1.patches, i1[ka[k]], f2.patches, jl[k], kernel=kernel)
        s1 = S[ka[k], kb[k]]
        s2 = sad_rows(f1.patches, i1[ka[k]], f2.patches, jr[k], kernel=kernel)
        x = parabola_offset(s0, s1, s2)
        k, x = k[np.isfinite(x)], x[np.isfinite(x)]
        other = np.where((x > 0)[:, None], f2.points[jr[k]], f2.points[jl[k]])
        b[k] = f2.points[j[k]] + np.abs(x)[:, None] * (other - f2.points[j[k]])
    return Matches(i1[ka], j, f1.points[i1[ka]], b, S[ka, kb])


def parabola_offset(s_lo: FloatArray, s_mid: FloatArray, s_hi: FloatArray) -> FloatArray:
    """Where the parabola through three evenly spaced SADs (at -1, 0, 1) has its minimum,
    within [-0.5, 0.5]; NaN where they make no minimum (or one is not finite)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        den = s_lo - 2.0 * s_mid + s_hi
        x = np.where(den > 0, 0.5 * (s_lo - s_hi) / den, np.nan)
    out: FloatArray = np.clip(x, -0.5, 0.5)
    return out


def laser_metric_wanted(lines: list[Segment], params: IasmParams) -> bool:
    """Section III-C: lines filling more than one or two neighbouring 10 deg bins of the
    angle histogram select the laser metric; otherwise the image metric."""
    nb = round(180.0 / params.bin_deg)
    filled = sorted(
        {
            int(np.floor((np.degrees(s.angle_rad) + 90.0) / params.bin_deg)) % nb
            for s in lines
            if s.length_m >= params.min_line_m
        }
    )
    if len(filled) == 0:
        return False
    if len(filled) == 1:
        return False
    if len(filled) == 2:
        gap = (filled[1] - filled[0]) % nb
        return not (gap == 1 or gap == nb - 1)
    return True


def hypotheses_from_pairs(a: FloatArray, b: FloatArray, rng: np.random.Generator, n: int) -> FloatArray:
    """(n, 3) rigid motions (x, y, yaw), each mapping two random correspondences b -> a."""
    m = len(a)
    i = rng.integers(0, m, n)
    j = (i + 1 + rng.integers(0, m - 1, n)) % m
    da, db = a[j] - a[i], b[j] - b[i]
    yaw = np.arctan2(da[:, 1], da[:, 0]) - np.arctan2(db[:, 1], db[:, 0])
    c, s = np.cos(yaw), np.sin(yaw)
    t = a[i] - np.column_stack([c * b[i, 0] - s * b[i, 1], s * b[i, 0] + c * b[i, 1]])
    ok = (np.linalg.norm(da, axis=1) > 0.1) & (
        np.abs(np.linalg.norm(da, axis=1) - np.linalg.norm(db, axis=1)) < 0.1
    )
    out: FloatArray = np.column_stack([t, yaw])[ok]
    return out


def _apply(poses: FloatArray, pts: FloatArray) -> FloatArray:
    """(H, N, 2) points moved by each motion."""
    c, s = np.cos(poses[:, 2])[:, None], np.sin(poses[:, 2])[:, None]
    x = c * pts[None, :, 0] - s * pts[None, :, 1] + poses[:, 0:1]
    y = s * pts[None, :, 0] + c * pts[None, :, 1] + poses[:, 1:2]
    return np.stack([x, y], axis=2)


def _inverse(poses: FloatArray) -> FloatArray:
    c, s = np.cos(poses[:, 2]), np.sin(poses[:, 2])
    x = -(c * poses[:, 0] + s * poses[:, 1])
    y = -(-s * poses[:, 0] + c * poses[:, 1])
    return np.column_stack([x, y, -poses[:, 2]])


def laser_scores(
    hyp: FloatArray,
    f1: Frame,
    f2: Frame,
    params: IasmParams,
    rng: np.random.Generator,
    *,
    kernel: bool = True,
) -> FloatArray:
    """Scan alignment metric: minus the mean (capped) distance of scan t, moved into scan
    t+1's frame by each hypothesis, to scan t+1's nearest returns. The distances come from
    the compiled grid search (:mod:`rigcal.localize.nearest`); ``kernel=False``: from a
    k-d tree (the reference)."""
    pts = f1.points[rng.permutation(len(f1.points))[: params.score_points]]
    moved = _apply(_inverse(hyp), pts).reshape(-1, 2)  # (H n, 2) in frame t+1
    if kernel:
        d = Grid(f2.points).distances(moved, params.truncate_m)
    else:
        from scipy.spatial import cKDTree

        d = cKDTree(f2.points).query(moved, distance_upper_bound=params.truncate_m)[0]
    d = np.minimum(d, params.truncate_m).reshape(len(hyp), -1)
    out: FloatArray = -d.mean(axis=1)
    return out


def image_scores(
    hyp: FloatArray,
    f1: Frame,
    f2: Frame,
    camera: Camera,
    T_cam_laser: FloatArray,
    params: IasmParams,
    rng: np.random.Generator,
    *,
    kernel: bool = True,
) -> FloatArray:
    """Image metric: minus the mean SAD between scan t's patches in image t and the patches
    at scan t moved by each hypothesis and projected into image t+1 (``kernel``: as in
    :func:`match_returns`)."""
    vis = np.flatnonzero(f1.visible)
    idx = vis[rng.permutation(len(vis))[: params.score_points]]
    moved = _apply(_inverse(hyp), f1.points[idx])  # (H, n, 2)
    H, n = moved.shape[:2]
    P = (
        np.concatenate([moved, np.zeros((H, n, 1))], axis=2).reshape(-1, 3) @ T_cam_laser[:3, :3].T
        + T_cam_laser[:3, 3]
    )
    ok = P[:, 2] > 0.1
    px = np.full((len(P), 2), -1e6)
    px[ok] = camera.project(P[ok])
    r = params.patch_radius_px
    ok &= camera.in_image(px, margin_px=r + 1)
    sad = np.full(len(P), np.nan)
    if ok.any():
        cand = sample_patches(f2.gray, px[ok], r)
        sad[ok] = sad_rows(cand, np.arange(len(cand)), f1.patches, np.tile(idx, H)[ok], kernel=kernel)
    per = sad.reshape(H, n)  # one row per hypothesis
    # Hypotheses that move most returns out of the image get the worst score.
    finite = np.isfinite(per)
    count = finite.sum(axis=1)
    total = np.where(finite, per, 0.0).sum(axis=1)
    mean = np.where(count >= max(3, n // 4), total / np.maximum(count, 1), np.inf)
    out: FloatArray = -mean
    return out


@dataclass(frozen=True)
class StepResult:
    """A scan-matching step: the motion T_t_t1, which metric scored it, the counts."""

    motion: FloatArray
    metric: str
    correspondences: int
    inliers: int
    inlier_mask: NDArray[np.bool_]


def robust_motion(
    m: Matches,
    f1: Frame,
    f2: Frame,
    camera: Camera,
    T_cam_laser: FloatArray,
    params: IasmParams,
    rng: np.random.Generator,
    reference: LaserReference | None = None,
) -> StepResult | None:
    """RANSAC over pairs of correspondences scored by the metric the scene selects, then
    a least-squares polish (Eq. (4)) on the winner's inliers (Section III-C).

    ``reference``: what the joint polish aligns scan t+1 with (a keyframe's scan); scan
    t's own by default.
    """
    if len(m.a) < params.min_correspondences:
        return None
    hyp = hypotheses_from_pairs(m.a, m.b, rng, params.hypotheses)
    if len(hyp) == 0:
        return None
    # Each hypothesis is first evaluated on all the correspondences (its inliers); those
    # with too little support are dropped, and the metric the scene selects decides among
    # the rest (the laser metric together with the support, see below).
    res = np.linalg.norm(_apply(hyp, m.b) - m.a[None], axis=2)
    n_in = (res < params.inlier_m).sum(axis=1)
    keep = (n_in >= params.min_inliers) & (n_in >= params.support_fraction * n_in.max())
    if not keep.any():
        return None
    support = n_in[keep] / n_in.max()
    hyp, res = hyp[keep], res[keep]
    use_laser = laser_metric_wanted(f1.lines, params)
    if use_laser:
        # Both in [0, 1]: the correspondences' support and the scans' alignment (1 when
        # every return lies on the other scan). A motion the correspondences like but the
        # walls contradict (a repeating pattern's period) loses, and so does one the walls
        # cannot tell apart from the truth (along a corridor) but the correspondences can.
        score = support + 1.0 + laser_scores(hyp, f1, f2, params, rng) / params.truncate_m
    else:
        score = image_scores(hyp, f1, f2, camera, T_cam_laser, params, rng)
    best = int(np.argmax(score))
    inl = res[best] < params.inlier_m
    pose = hyp[best]
    for _ in range(2):
        pose = point_to_point(m.b[inl], m.a[inl])
        inl = np.linalg.norm(_apply(pose[None], m.b)[0] - m.a, axis=1) < params.inlier_m
        if inl.sum() < params.min_inliers:
            return None
    if params.joint_polish:
        ref = LaserReference(f1.points, f1.normals) if reference is None else reference
        pose = joint_polish(pose, m.a[inl], m.b[inl], ref.points, f2.points, params, ref.normals)
    # Where the walls can judge (laser metric), a result they contradict fails: wrong
    # correspondences all agreeing, as a window centred one pattern period off yields.
    if (
        use_laser
        and 1.0 + laser_scores(pose[None], f1, f2, params, rng)[0] / params.truncate_m < params.min_alignment
    ):
        return None
    # Inliers bunched in one small patch of the scene (the only textured spot in view)
    # leave the rotation undetermined: the step fails and falls back.
    spread = float(np.sqrt(np.linalg.eigvalsh(np.cov(m.a[inl].T))[-1]))
    if spread < params.min_spread_m:
        return None
    return StepResult(pose, "laser" if use_laser else "image", len(m.a), int(inl.sum()), inl)


def iasm_step(
    f1: Frame,
    f2: Frame,
    camera: Camera,
    T_cam_laser: FloatArray,
    params: IasmParams,
    rng: np.random.Generator,
    reference: LaserReference | None = None,
) -> tuple[StepResult | None, Matches]:
    """One IASM step (Section III): search around each return's own pixel."""
    m = match_returns(f1, f2, f1.pixels, params.search_u_px, params.search_v_px)
    return robust_motion(m, f1, f2, camera, T_cam_laser, params, rng, reference), m
