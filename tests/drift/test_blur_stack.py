"""Blurred images made only over boxes (rigcal.drift.blur_stack): every value made is
the whole image's blur there, bit for bit, and reads beyond a box widen it first."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from rigcal.camera import Camera
from rigcal.drift.blur_stack import BlurStack
from rigcal.drift.edges import EdgeImages
from rigcal.drift.sampling import project_sample
from rigcal.sim.box_session import default_T_cam_laser


def images(rng: np.random.Generator, n: int, h: int = 120, w: int = 160) -> list[np.ndarray]:
    return [(rng.integers(0, 256, (h, w)) * 64).astype(np.uint16) for _ in range(n)]


def rows_of(src: list[np.ndarray]) -> tuple[object, int]:
    """A BlurStack's source (rows a:b of image i) and the images' height."""
    return (lambda i, a, b: src[i][a:b]), src[0].shape[0]


def whole(g: np.ndarray, sigma: float, row0: int, height: int) -> np.ndarray:
    out: np.ndarray = cv2.GaussianBlur(g, (0, 0), sigma)[row0 : row0 + height]
    return out


@pytest.mark.parametrize("sigma", [0.3, 1.4422205101855956, 3.104834939252005, 4.7])
def test_a_box_holds_the_whole_images_blur(sigma):
    rng = np.random.default_rng(1)
    src = images(rng, 3)
    row0, height = 17, 70
    keys = np.array([0, 0, 1, 2, 2])
    sig = np.array([sigma, 1.1 * sigma, sigma, sigma, 2.0 * sigma])
    stack = BlurStack(keys, sig, row0, height, 160, *rows_of(src))
    need = np.array([[0, 70, 0, 160], [5, 30, 40, 41], [60, 70, 150, 160], [0, 1, 0, 1], [20, 50, 3, 90]])
    stack.fill(need)
    np.testing.assert_array_equal(stack.box, need)
    for k, (r0, r1, c0, c1) in enumerate(need):
        ref = whole(src[keys[k]], sig[k], row0, height)
        np.testing.assert_array_equal(stack.stack[k, r0:r1, c0:c1], ref[r0:r1, c0:c1])


def test_widening_makes_the_reads_and_keeps_what_was_made():
    rng = np.random.default_rng(2)
    src = images(rng, 2)
    stack = BlurStack(np.array([0, 1]), np.array([1.5, 2.5]), 10, 100, 160, *rows_of(src))
    stack.fill(np.array([[40, 50, 60, 70], [0, 0, 0, 0]]))  # key 1: nothing made yet
    need = np.array([[45, 47, 100, 102], [90, 92, 158, 160], [3, 5, 0, 2]])
    keys = np.array([0, 1, 1])
    assert not stack.covers(keys, need).any()
    stack.widen(keys, need, 4)
    assert stack.covers(keys, need).all()
    np.testing.assert_array_equal(stack.box, [[40, 51, 60, 106], [0, 96, 0, 160]])  # unions, clipped
    for k in (0, 1):
        r0, r1, c0, c1 = stack.box[k]
        ref = whole(src[k], stack.sigma_px[k], 10, 100)
        np.testing.assert_array_equal(stack.stack[k, r0:r1, c0:c1], ref[r0:r1, c0:c1])


def test_the_kernel_reads_beyond_a_box_only_once_it_is_made():
    """project_sample with boxes too small (widened as it reads) gives what it gives on
    the whole stack; without a way to widen them, it refuses."""
    K = np.array([[260.0, 0.0, 159.5], [0.0, 260.0, 119.5], [0.0, 0.0, 1.0]])
    cam = Camera.from_opencv(K, [-0.15, 0.05, 0.0005, -0.0003, 0.0], 320, 240)
    T = default_T_cam_laser()
    rng = np.random.default_rng(3)
    src = images(rng, 3, 240, 320)
    n = 3000
    pts = np.column_stack([rng.uniform(0.5, 5.0, n), rng.uniform(-3.0, 3.0, n), rng.uniform(-1.0, 1.0, n)])
    which = rng.integers(0, 3, n)
    row0, height = 30, 180
    full = np.stack([whole(g, 1.7, row0, height) for g in src])
    ref = project_sample(pts, T[:3, :3], T[:3, 3], cam, full, which, 1, row0)
    stack = BlurStack(np.arange(3), np.full(3, 1.7), row0, height, 320, *rows_of(src))
    stack.fill(np.array([[50, 60, 100, 140], [0, 0, 0, 0], [0, 180, 0, 320]]))
    with pytest.raises(ValueError, match="outside the images' boxes"):
        project_sample(pts, T[:3, :3], T[:3, 3], cam, stack.stack, which, 1, row0, stack.box)
    calls = []

    def widen(keys: np.ndarray, need: np.ndarray) -> None:
        calls.append(len(keys))
        stack.widen(keys, need, 0)

    got = project_sample(pts, T[:3, :3], T[:3, 3], cam, stack.stack, which, 1, row0, stack.box, widen)
    assert calls
    assert np.isfinite(ref[0]).sum() > 1000
    for a, b in zip(got, ref, strict=True):
        np.testing.assert_array_equal(a, b)


def test_edge_images_over_boxes_read_as_whole_frames():
    rng = np.random.default_rng(4)
    gray_of = {i: rng.integers(0, 256, (240, 320)).astype(np.uint8) for i in (3, 7)}
    frames = np.array([3, 7, 7])
    rows = (20.0, 200.0)
    whole_frames = EdgeImages(gray_of, frames, 1.44, rows)
    boxed = EdgeImages(
        gray_of, frames, 1.44, rows, np.array([[40, 80, 10, 30], [0, 0, 0, 0], [150, 200, 300, 320]])
    )
    q = np.column_stack([rng.uniform(-5, 325, 2000), rng.uniform(0, 240, 2000)])
    which = rng.integers(0, 3, 2000)
    np.testing.assert_array_equal(boxed.sample(which, q), whole_frames.sample(which, q))


def test_many_boxes_blurred_side_by_side_hold_the_whole_images_blur():
    """Boxes of every size, touching the images' borders or not, several blurs, many
    to a row of crops (rigcal.drift.blur_stack._side_by_side)."""
    rng = np.random.default_rng(5)
    src = images(rng, 6, 90, 130)
    n = 400
    keys = rng.integers(0, 6, n)
    sig = rng.choice([0.7, 1.44, 3.1], n)
    row0, height = 5, 80
    r = np.sort(rng.integers(0, height + 1, (n, 2)), axis=1)
    c = np.sort(rng.integers(0, 131, (n, 2)), axis=1)
    need = np.column_stack([r[:, 0], r[:, 1] + 1, c[:, 0], c[:, 1] + 1])
    stack = BlurStack(keys, sig, row0, height, 130, *rows_of(src))
    stack.fill(need)
    for k in range(n):
        r0, r1, c0, c1 = stack.box[k]
        assert (r1 - r0) * (c1 - c0) > 0
        ref = whole(src[keys[k]], sig[k], row0, height)
        np.testing.assert_array_equal(stack.stack[k, r0:r1, c0:c1], ref[r0:r1, c0:c1])


def test_half_size_rows_are_their_own_full_size_rows_averaged():
    """The coarse stage's source rows (rigcal.drift.targetless._stack) resize only the
    full-size rows they average: for an image of even size, OpenCV's area resize at a
    scale of exactly 2 gives those rows of the whole image's resize."""
    rng = np.random.default_rng(6)
    g = (rng.integers(0, 256, (480, 640)) * 64).astype(np.uint16)
    whole_half = cv2.resize(g, (320, 240), interpolation=cv2.INTER_AREA)
    for a, b in ((0, 240), (0, 1), (17, 90), (239, 240), (100, 101)):
        part = cv2.resize(g[2 * a : 2 * b], (320, b - a), interpolation=cv2.INTER_AREA)
        np.testing.assert_array_equal(part, whole_half[a:b])


def test_a_narrow_stack_keeps_a_window_of_columns_per_image():
    """Each key's columns from col0 on only; a box widened within its window stays
    there, one widened beyond it gives every key the whole width, what was made kept."""
    rng = np.random.default_rng(7)
    src = images(rng, 2)
    stack = BlurStack(np.array([0, 1]), np.array([1.5, 3.1]), 10, 100, 160, *rows_of(src), narrow=True)
    stack.fill(np.array([[10, 60, 40, 50], [20, 90, 120, 130]]))
    assert stack.stack.shape == (2, 100, 10 + 32)
    np.testing.assert_array_equal(stack.col0, [24, 104])  # 16 px before each box

    def check() -> None:
        for k in (0, 1):
            r0, r1, c0, c1 = stack.box[k]
            ref = whole(src[k], stack.sigma_px[k], 10, 100)
            got = stack.stack[k, r0:r1, c0 - stack.col0[k] : c1 - stack.col0[k]]
            np.testing.assert_array_equal(got, ref[r0:r1, c0:c1])

    check()
    stack.widen(np.array([0]), np.array([[55, 70, 48, 52]]), 2)  # inside its window
    assert stack.stack.shape[2] == 42
    check()
    stack.widen(np.array([1]), np.array([[5, 7, 3, 5]]), 2)  # far beyond it
    assert stack.stack.shape[2] == 160
    np.testing.assert_array_equal(stack.col0, [0, 0])
    check()
