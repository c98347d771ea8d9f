"""H-IASM steps on rendered views of a simulated corridor (paper Section V, Fig. 5)."""

from __future__ import annotations

import numpy as np
from corridor_views import CAM, T_CAM_LASER, correct, corridor, posters_pair, view

from rigcal.localize.hiasm import (
    camera_motion,
    hiasm_step,
    homography_predictions,
    laser_motion,
    visual_fallback,
    window_search,
)
from rigcal.localize.iasm import IasmParams, iasm_step, match_returns
from rigcal.sim.textures import world_textures


def test_repeating_pattern_fools_iasm_but_not_hiasm(repeating):
    """Fig. 5: a 0.3 m step along a wall with a 0.5 m period. IASM's search around each
    return's own pixel holds the wrong period's copy, not the true match; H-IASM's window
    around the homography's prediction holds only the true match."""
    world, tex = repeating
    params = IasmParams()
    motion = np.array([0.3, 0.0, 0.0])
    f1 = view(world, tex, (0.0, 0.0, 0.0), params)
    f2 = view(world, tex, tuple(motion), params)
    rng = np.random.default_rng(0)
    _, m_iasm = iasm_step(f1, f2, CAM, T_CAM_LASER, params, rng)
    R, t = camera_motion(motion, T_CAM_LASER)
    res, m_h = hiasm_step(
        f1, f2, R, t / np.linalg.norm(t), float(np.linalg.norm(t)), CAM, T_CAM_LASER, params, rng
    )
    assert len(m_iasm.a) > 20
    assert correct(m_iasm, motion).mean() < 0.3
    assert len(m_h.a) > 20
    assert correct(m_h, motion).mean() > 0.9
    assert res is not None
    assert np.linalg.norm(res.motion[:2] - motion[:2]) < 0.01
    assert abs(res.motion[2]) < np.radians(0.1)


def test_a_scale_carried_from_a_faster_step_misplaces_hiasms_windows():
    """The rig slows from 0.4 m to 0.1 m between images: with the previous step's scale
    (the paper's, carried over) the windows sit 0.3 m ahead of the true matches; with the
    step's own (the laser odometry's, ``IasmParams.odometry_scale``) they hold them."""
    params = IasmParams()
    motion = np.array([0.1, 0.0, 0.0])
    f1, f2 = posters_pair(motion, params)
    R, t = camera_motion(motion, T_CAM_LASER)
    t_unit = t / np.linalg.norm(t)
    carried = float(np.linalg.norm(camera_motion(np.array([0.4, 0.0, 0.0]), T_CAM_LASER)[1]))
    found = {}
    for name, scale in (("carried", carried), ("own", float(np.linalg.norm(t)))):
        res, m = hiasm_step(f1, f2, R, t_unit, scale, CAM, T_CAM_LASER, params, np.random.default_rng(0))
        right = res is not None and np.linalg.norm(res.motion[:2] - motion[:2]) < 0.01
        found[name] = (correct(m, motion).mean() if len(m.a) else 0.0, right)
    assert found["carried"][0] < 0.2
    assert not found["carried"][1]
    assert found["own"][0] > 0.9
    assert found["own"][1]


def test_homography_prediction_is_the_returns_next_pixel(repeating):
    """Eq. (10): each return of a line lands where the true motion projects it."""
    world, tex = repeating
    params = IasmParams()
    motion = np.array([0.2, 0.05, np.radians(3.0)])
    f1 = view(world, tex, (0.0, 0.0, 0.0), params)
    R, t = camera_motion(motion, T_CAM_LASER)
    pred = homography_predictions(
        f1, R, t / np.linalg.norm(t), float(np.linalg.norm(t)), CAM, T_CAM_LASER[:3, :3]
    )
    ok = np.isfinite(pred[:, 0])
    assert ok.sum() > 50
    P2 = f1.cam[ok] @ R.T + t
    assert np.allclose(pred[ok], CAM.project(P2), atol=0.3)


def test_dense_window_search_also_takes_the_right_period(repeating):
    """Fig. 5 with H-IASM's dense window search: the matches are the true ones."""
    world, tex = repeating
    params = IasmParams(dense_window=True)
    motion = np.array([0.3, 0.0, 0.0])
    f1 = view(world, tex, (0.0, 0.0, 0.0), params)
    f2 = view(world, tex, tuple(motion), params)
    R, t = camera_motion(motion, T_CAM_LASER)
    res, m = hiasm_step(
        f1, f2, R, t / np.linalg.norm(t), float(np.linalg.norm(t)), CAM, T_CAM_LASER, params,
        np.random.default_rng(0),
    )  # fmt: skip
    assert len(m.a) > 20
    assert correct(m, motion).mean() > 0.9
    assert res is not None
    assert np.linalg.norm(res.motion[:2] - motion[:2]) < 0.01


def _true_pixels(f1, motion):
    """Where the true motion puts each return of f1 in the next image (NaN: not visible)."""
    c, s = np.cos(motion[2]), np.sin(motion[2])
    b = (f1.points - motion[:2]) @ np.array([[c, -s], [s, c]])
    P = np.column_stack([b, np.zeros(len(b))]) @ T_CAM_LASER[:3, :3].T + T_CAM_LASER[:3, 3]
    out = np.full((len(b), 2), np.nan)
    out[f1.visible] = CAM.project(P[f1.visible])
    return out, b


def test_dense_window_search_places_matches_between_the_returns():
    """On noise-free views of a textured wall, a step that puts no return of scan t+1 where
    a return of scan t was: the dense search finds each point on the wall to well under a
    millimetre; the best of scan t+1's returns (with the parabola) is a beam spacing's
    fraction off."""
    params = IasmParams()
    motion = np.array([0.1037, 0.0, 0.0])
    f1, f2 = posters_pair(motion, params)
    pred, true_b = _true_pixels(f1, motion)
    dense = window_search(f1, f2, pred, CAM, T_CAM_LASER, params)
    beams = match_returns(f1, f2, pred, params.window_px, params.window_px)
    err_dense = np.linalg.norm(dense.b - true_b[dense.i1], axis=1)
    err_beams = np.linalg.norm(beams.b - true_b[beams.i1], axis=1)
    assert len(dense.i1) > 100
    assert np.median(err_dense) < 0.5e-3
    assert np.median(err_dense) < 0.5 * np.median(err_beams)
    # each match lies on scan t+1's wall (y = 1.5 m in the frame after a step along x)
    left = np.abs(dense.b[:, 1] - 1.5) < 0.05
    assert left.mean() > 0.9
    assert np.abs(dense.b[left, 1] - 1.5).max() < 1e-6


def test_dense_window_search_without_predictions_or_lines_finds_nothing():
    world = corridor("posters")
    tex = world_textures(world, 0)
    params = IasmParams()
    f1 = view(world, tex, (0.0, 0.0, 0.0), params)
    f2 = view(world, tex, (0.1, 0.0, 0.0), params)
    none = np.full((len(f1.points), 2), np.nan)
    assert len(window_search(f1, f2, none, CAM, T_CAM_LASER, params).i1) == 0
    far = np.full((len(f1.points), 2), -500.0)  # every prediction far outside the image
    assert len(window_search(f1, f2, far, CAM, T_CAM_LASER, params).i1) == 0


def test_laser_motion_inverts_camera_motion():
    motion = np.array([0.3, -0.05, np.radians(7.0)])
    R, t = camera_motion(motion, T_CAM_LASER)
    assert np.allclose(laser_motion(R, t, T_CAM_LASER), motion)


def test_visual_fallback_takes_the_motion_along_the_corridor_from_vo_and_the_rest_from_the_walls():
    """A corridor whose ends are out of an 8 m laser's range: visual odometry with 1 deg
    of rotation error and its direction 3 deg off, scaled by the true step's length; the
    walls take out the heading and cross-corridor errors, the length along stays VO's."""
    world = corridor("plain")
    tex = world_textures(world, 0)
    params = IasmParams()
    motion = np.array([0.1, 0.004, np.radians(0.5)])
    f1 = view(world, tex, (0.0, 0.0, 0.0), params, range_max_m=8.0)
    f2 = view(world, tex, tuple(motion), params, range_max_m=8.0)
    wrong = motion + np.array([0.0, 0.1 * np.sin(np.radians(3.0)), np.radians(1.0)])
    R, t = camera_motion(wrong, T_CAM_LASER)
    scale = float(np.linalg.norm(camera_motion(motion, T_CAM_LASER)[1]))
    out = visual_fallback(f1, f2, R, t / np.linalg.norm(t), scale, T_CAM_LASER, params)
    assert abs(out[0] - motion[0]) < 0.002
    assert abs(out[1] - motion[1]) < 0.002
    assert abs(out[2] - motion[2]) < np.radians(0.05)
