"""H-IASM: homography-based image-augmented scan matching (paper Section V, Fig. 7).

IASM (:mod:`rigcal.localize.iasm`) with each return's search window centred on where the
homography of its plane puts it in the next image, H = R_c + (s_{t-1} / d) t_c n^T
(Eq. (10)), with R_c and the unit t_c from visual odometry between the two images, the
scale from the laser odometry between them (the paper carries the previous step's,
s_{t-1}, over: ``IasmParams.odometry_scale`` False), and the plane's normal n and
distance d from the scan's lines in camera coordinates (Eq. (7)). The window is small
(``IasmParams.window_px``), which rejects the wrong matches of repeating patterns
(Fig. 5). Within it, the search runs among scan t+1's returns (as IASM's) or, with
``IasmParams.dense_window``, densely along the wall (:func:`window_search`). RANSAC and
the polish are IASM's (:func:`rigcal.localize.iasm.robust_motion`). A pair without
visual odometry, or without a scale (the first, with the carried scale), falls back to
IASM (:mod:`rigcal.localize.image_matching`).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from rigcal.arrays import FloatArray
from rigcal.camera import Camera
from rigcal.geometry import make_T, rotvec_to_R, transform_points
from rigcal.localize.iasm import (
    Frame,
    IasmParams,
    Matches,
    StepResult,
    match_returns,
    parabola_offset,
    robust_motion,
)
from rigcal.localize.patches import sample_patches
from rigcal.localize.polish import LaserReference, joint_polish


def homography_predictions(
    f1: Frame, R: FloatArray, t_unit: FloatArray, scale: float, camera: Camera, R_cam_laser: FloatArray
) -> FloatArray:
    """Where each return of f1 lands in the next image (N, 2; NaN where unknown).

    For the returns of each line: the line's plane normal n (horizontal, in the camera
    frame) and distance d = n^T P (Eq. (7)), the homography H = R + (s / d) t n^T
    (Eq. (10)) and the projection of H P. Returns on no line use their own plane through
    the point facing the camera (d = |P|), which predicts the same for that point.
    """
    out = np.full((len(f1.points), 2), np.nan)
    P = f1.cam
    pred3 = np.full((len(P), 3), np.nan)
    for k, seg in enumerate(f1.lines):
        idx = np.flatnonzero(f1.line_of == k)
        n = R_cam_laser @ np.array([seg.normal[0], seg.normal[1], 0.0])
        d = float(np.mean(P[idx] @ n))  # Eq. (7)
        if abs(d) < 1e-3:
            continue
        H = R + (scale / d) * np.outer(t_unit, n)  # Eq. (10)
        pred3[idx] = P[idx] @ H.T
    rest = (f1.line_of < 0) & np.isfinite(P[:, 2])
    pred3[rest] = P[rest] @ R.T + scale * t_unit
    ok = f1.visible & np.isfinite(pred3[:, 2]) & (pred3[:, 2] > 0.1)
    if ok.any():
        out[ok] = camera.project(pred3[ok])
    return out


def hiasm_step(
    f1: Frame,
    f2: Frame,
    R: FloatArray,
    t_unit: FloatArray,
    scale: float,
    camera: Camera,
    T_cam_laser: FloatArray,
    params: IasmParams,
    rng: np.random.Generator,
    reference: LaserReference | None = None,
) -> tuple[StepResult | None, Matches]:
    """One H-IASM step (Section V): search in a small window around each homography prediction."""
    pred = homography_predictions(f1, R, t_unit, scale, camera, T_cam_laser[:3, :3])
    if params.dense_window:
        m = window_search(f1, f2, pred, camera, T_cam_laser, params)
    else:
        m = match_returns(f1, f2, pred, params.window_px, params.window_px)
    return robust_motion(m, f1, f2, camera, T_cam_laser, params, rng, reference), m


def camera_motion(motion: FloatArray, T_cam_laser: FloatArray) -> tuple[FloatArray, FloatArray]:
    """The camera's (R, t) with x2 = R x1 + t for a laser motion T_t_t1 (x, y, yaw)."""
    T_l1_l2 = make_T(rotvec_to_R([0.0, 0.0, motion[2]]), [motion[0], motion[1], 0.0])
    T_c2_c1 = T_cam_laser @ np.linalg.inv(T_l1_l2) @ np.linalg.inv(T_cam_laser)
    return T_c2_c1[:3, :3], T_c2_c1[:3, 3]


def laser_motion(R: FloatArray, t: FloatArray, T_cam_laser: FloatArray) -> FloatArray:
    """The laser motion T_t_t1 (x, y, yaw) of a camera motion (R, t), x2 = R x1 + t: the
    inverse of :func:`camera_motion`, on the ground plane."""
    T_c2_c1 = make_T(R, t)
    T_l1_l2 = np.linalg.inv(T_cam_laser) @ np.linalg.inv(T_c2_c1) @ T_cam_laser
    return np.array([T_l1_l2[0, 3], T_l1_l2[1, 3], np.arctan2(T_l1_l2[1, 0], T_l1_l2[0, 0])])


def visual_fallback(
    f1: Frame,
    f2: Frame,
    R: FloatArray,
    t_unit: FloatArray,
    scale: float,
    T_cam_laser: FloatArray,
    params: IasmParams,
    reference: LaserReference | None = None,
) -> FloatArray:
    """H-IASM's step where the image correspondences fail and the laser odometry is
    degenerate (along a corridor whose ends are out of the laser's range, its step is
    short): visual odometry's motion (R, t_unit) with the carried scale, aligned with the
    walls (scan t's, or the keyframe's ``reference``), which fix the heading and the
    motion across the corridor, held to visual odometry's within ``fallback_sigma_m`` and
    ``fallback_sigma_deg`` where they do not (beyond the paper)."""
    vo = laser_motion(R, scale * t_unit, T_cam_laser)
    ref = reference or LaserReference(f1.points, f1.normals)
    none = np.zeros((0, 2))
    return joint_polish(vo, none, none, ref.points, f2.points, params, ref.normals, vo)


def window_search(
    f1: Frame,
    f2: Frame,
    predicted: FloatArray,
    camera: Camera,
    T_cam_laser: FloatArray,
    params: IasmParams,
) -> Matches:
    """H-IASM's correspondences: each return of f1 searched for along the wall of scan
    t+1 it is predicted to land on, within ``window_px`` of the prediction (Section V).

    The search is dense: candidates every ``window_step_px`` along the wall line of scan
    t+1 (the line of the return of f2 whose pixel is nearest the prediction), each
    projected into image t+1 and compared by SAD; a parabola through the SADs around the
    minimum places the match between candidates. A match is therefore a point on the wall
    anywhere, not one of scan t+1's returns (IASM's, which a beam's spacing quantises,
    1-3 cm on the walls here). A minimum at the window's edge is no match.

    Args:
        predicted: (N1, 2) where each return of f1 is expected in image 2 (NaN: unknown).
    """
    i1 = np.flatnonzero(f1.visible & np.isfinite(predicted[:, 0]))
    i2 = np.flatnonzero(f2.visible & (f2.line_of >= 0))
    if len(i1) == 0 or len(i2) == 0:
        return Matches.none()
    # The return of scan t+1 nearest each prediction, in pixels, within the window.
    dist, near = cKDTree(f2.pixels[i2]).query(predicted[i1], distance_upper_bound=params.window_px)
    ok = np.isfinite(dist)
    i1, j = i1[ok], i2[near[ok]]
    if len(i1) == 0:
        return Matches.none()
    n = f2.normals[j]
    u = np.column_stack([-n[:, 1], n[:, 0]])  # along the wall

    def pixels(q: FloatArray) -> FloatArray:
        return camera.project(transform_points(T_cam_laser, q))

    # Pixels per metre along the wall at each return, and the offset along the wall
    # whose pixel is nearest the prediction: the window's centre.
    q0 = f2.points[j] - np.einsum("ij,ij->i", f2.points[j] - f2.centres[j], n)[:, None] * n  # on the line
    g = (pixels(q0 + 0.005 * u) - pixels(q0 - 0.005 * u)) / 0.01
    gg = np.einsum("ij,ij->i", g, g)
    keep = gg > 1.0
    i1, j, q0, u, g, gg = i1[keep], j[keep], q0[keep], u[keep], g[keep], gg[keep]
    s0 = np.einsum("ij,ij->i", predicted[i1] - f2.pixels[j], g) / gg
    steps = np.arange(-params.window_px, params.window_px + 1e-9, params.window_step_px)
    ds = steps[None, :] / np.sqrt(gg)[:, None]  # (M, S) metres along the wall
    cand = q0[:, None, :] + (s0[:, None] + ds)[:, :, None] * u[:, None, :]
    M, S = ds.shape
    px = pixels(cand.reshape(-1, 2))
    r = params.patch_radius_px
    inside = camera.in_image(np.nan_to_num(px, nan=-1e6), margin_px=r + 1)
    patches = np.full((M * S, (2 * r + 1) ** 2), np.nan, dtype=np.float32)
    patches[inside] = sample_patches(f2.gray, px[inside], r)
    sad = np.abs(patches.reshape(M, S, -1) - f1.patches[i1][:, None, :]).mean(axis=2)
    sad = np.where(np.isfinite(sad), sad, np.inf)
    k = np.argmin(sad, axis=1)
    rows = np.arange(M)
    good = (k > 0) & (k < S - 1) & np.isfinite(sad[rows, k])
    rows, k = rows[good], k[good]
    s_lo, s_mid, s_hi = sad[rows, k - 1], sad[rows, k], sad[rows, k + 1]
    x = np.nan_to_num(parabola_offset(s_lo, s_mid, s_hi))  # none where a neighbour is off the image
    off = s0[rows] + ds[rows, k] + x * (ds[rows, 1] - ds[rows, 0])
    b = q0[rows] + off[:, None] * u[rows]
    return Matches(i1[rows], j[rows], f1.points[i1[rows]], b, s_mid)
