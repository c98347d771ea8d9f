"""The targetless check's compiled projection and sampling against its numpy reference."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from rigcal.camera import Camera
from rigcal.drift import sampling
from rigcal.drift.sampling import project_sample, project_sample_reference
from rigcal.sim.box_session import default_T_cam_laser

K = np.array([[520.0, 0.0, 319.5], [0.0, 515.0, 239.5], [0.0, 0.0, 1.0]])
CAMERAS = {
    "pinhole": Camera.from_opencv(K, [], 640, 480),
    "opencv5": Camera.from_opencv(K, [-0.15, 0.05, 0.0005, -0.0003, 0.01], 640, 480),
    "opencv8": Camera.from_opencv(K, [-0.2, 0.08, 0.001, -0.0005, 0.01, 0.02, -0.01, 0.005], 640, 480),
    "opencv12": Camera.from_opencv(
        K, [-0.2, 0.08, 0.001, -0.0005, 0.01, 0.02, -0.01, 0.005, 1e-3, -2e-3, 5e-4, 1e-3], 640, 480
    ),
}


def problem(down: int, n: int = 4000) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(7)
    raw = rng.uniform(0, 255, (3, 480 // down, 640 // down)).astype(np.float32)
    stack = np.stack([cv2.GaussianBlur(g, (0, 0), 1.5) * 64.0 for g in raw]).astype(np.uint16)
    # Points ahead of the laser and some behind the camera (x < 0) or outside the image.
    pts = np.column_stack([rng.uniform(-1.0, 5.0, n), rng.uniform(-4.0, 4.0, n), rng.uniform(-1.5, 1.5, n)])
    return pts, stack, rng.integers(0, 3, n)


@pytest.mark.parametrize("name", sorted(CAMERAS))
@pytest.mark.parametrize("down", [1, 2])
def test_kernel_matches_the_reference(name, down):
    cam = CAMERAS[name]
    T = default_T_cam_laser()
    pts, stack, which = problem(down)
    got = project_sample(pts, T[:3, :3], T[:3, 3], cam, stack, which, down)
    ref = project_sample_reference(pts, T[:3, :3], T[:3, 3], cam, stack, which, down)
    nan = np.isnan(ref[0])
    assert 0.1 < nan.mean() < 0.9  # both kinds of point are there
    np.testing.assert_array_equal(np.isnan(got[0]), nan)
    for a, b in zip(got, ref, strict=True):
        np.testing.assert_allclose(np.nan_to_num(a), np.nan_to_num(b), rtol=1e-7, atol=1e-7)


def test_the_derivatives_are_those_of_the_grey_level():
    """d value / d point and d value / d w against central differences of the value."""
    cam = CAMERAS["opencv5"]
    T = default_T_cam_laser()
    pts, _, which = problem(1, 300)
    v, u = np.mgrid[0:480, 0:640]
    smooth = 128.0 + 60.0 * np.sin(u / 9.0) * np.cos(v / 7.0)  # smooth on the scale of a pixel
    stack = np.stack([smooth * 64.0] * 3).astype(np.uint16)
    val, d_point, d_rot = project_sample(pts, T[:3, :3], T[:3, 3], cam, stack, which, 1)
    ok = np.isfinite(val)
    h = 1e-5
    for a in range(3):
        e = np.zeros(3)
        e[a] = h
        plus = project_sample(pts + e, T[:3, :3], T[:3, 3], cam, stack, which, 1)[0]
        minus = project_sample(pts - e, T[:3, :3], T[:3, 3], cam, stack, which, 1)[0]
        num = (plus - minus) / (2 * h)
        # The value is bilinear (its own derivative jumps at pixel borders) and the
        # derivative a central difference over one pixel: on a smooth image they agree.
        good = ok & np.isfinite(num)
        scale = np.abs(d_point[good, a]).max()
        assert np.abs(num[good] - d_point[good, a]).max() < 0.1 * scale
    np.testing.assert_allclose(d_rot[ok], np.cross(pts[ok], d_point[ok]), atol=1e-9)


def test_models_the_kernel_does_not_know_go_through_mrcal(monkeypatch):
    cam = CAMERAS["opencv5"]
    T = default_T_cam_laser()
    pts, stack, which = problem(2)
    compiled = project_sample(pts, T[:3, :3], T[:3, 3], cam, stack, which, 2)
    monkeypatch.setattr(sampling, "compiled_model", lambda lensmodel: False)
    by_mrcal = project_sample(pts, T[:3, :3], T[:3, 3], cam, stack, which, 2)
    for a, b in zip(compiled, by_mrcal, strict=True):
        np.testing.assert_allclose(a, b, rtol=1e-7, atol=1e-7)


@pytest.mark.parametrize("down", [1, 2])
def test_a_band_of_rows_reads_as_the_whole_image_inside_it_and_nan_outside(down):
    cam = CAMERAS["opencv5"]
    T = default_T_cam_laser()
    pts, stack, which = problem(down)
    row0, rows = 60 // down, 200 // down
    band = np.ascontiguousarray(stack[:, row0 : row0 + rows])
    whole = project_sample(pts, T[:3, :3], T[:3, 3], cam, stack, which, down)
    part = project_sample(pts, T[:3, :3], T[:3, 3], cam, band, which, down, row0)
    ref = project_sample_reference(pts, T[:3, :3], T[:3, 3], cam, band, which, down, row0)
    inside = np.isfinite(part[0])
    assert 0.1 < inside.sum() / np.isfinite(whole[0]).sum() < 0.9
    for a, b, c in zip(part, whole, ref, strict=True):
        np.testing.assert_allclose(a[inside], b[inside], rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(np.nan_to_num(a), np.nan_to_num(c), rtol=1e-7, atol=1e-7)
    # Outside the band (one pixel's margin for the differences), the whole image's rows.
    q = cam.project(pts @ T[:3, :3].T + T[:3, 3])
    v = (q[:, 1] if down == 1 else (q[:, 1] - 0.5) / down) - row0
    expect = np.isfinite(whole[0]) & (v >= 1.0) & (v <= rows - 2.0)
    np.testing.assert_array_equal(inside, expect)


def test_grey_levels_at_points_of_an_image_cut_to_them_are_the_whole_images():
    """The texture test's samples (targetless._sample_grey) read the image cut to the
    points: the same NaN outside the image and the same levels (to the float32 rounding of
    the coordinates) as reading it whole."""
    from rigcal.drift.targetless import _sample, _sample_grey

    rng = np.random.default_rng(3)
    gray = rng.integers(0, 256, (480, 640)).astype(np.uint8)
    for trial in range(200):
        q = rng.uniform([-5, -5], [645, 485]) + rng.normal(
            0.0, rng.uniform(0.5, 60.0), (rng.integers(1, 50), 2)
        )
        if trial % 7 == 0:
            q[0] = np.nan
        whole, cut = _sample(gray.astype(np.float32), q), _sample_grey(gray, q)
        np.testing.assert_array_equal(np.isnan(cut), np.isnan(whole))
        np.testing.assert_allclose(cut[~np.isnan(cut)], whole[~np.isnan(whole)], atol=0.01, rtol=0.0)


@pytest.mark.parametrize("compiled", [True, False])
def test_many_points_sampled_in_two_halves_side_by_side_read_as_in_one_pass(monkeypatch, compiled):
    cam = CAMERAS["opencv5"]
    T = default_T_cam_laser()
    pts, stack, which = problem(1, 5001)
    if not compiled:
        monkeypatch.setattr(sampling, "compiled_model", lambda lensmodel: False)
    monkeypatch.setattr(sampling, "SPLIT_ABOVE", 10**9)
    whole = project_sample(pts, T[:3, :3], T[:3, 3], cam, stack, which, 1)
    monkeypatch.setattr(sampling, "SPLIT_ABOVE", 1000)
    halves = project_sample(pts, T[:3, :3], T[:3, 3], cam, stack, which, 1)
    for a, b in zip(whole, halves, strict=True):
        np.testing.assert_array_equal(a, b)
