"""16-bit stills (a calibration's captures) read as 8 bits by their own brightest level's
bits, not cut to their top byte (rigcal.io.images.read_image_file)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from rigcal.io.images import image_size, read_image, read_image_file


def _board_12_bit(h: int = 60, w: int = 80) -> np.ndarray:
    """A 12-bit camera's grey frame in a 16-bit container: levels 200..4000."""
    yy, xx = np.mgrid[:h, :w]
    return np.where(((yy // 10) + (xx // 10)) % 2 == 0, 200, 4000).astype(np.uint16)


@pytest.mark.parametrize("ext", [".png", ".tiff", ".pgm"])
def test_a_12_bit_grey_still_is_shifted_by_its_own_bits(tmp_path, ext):
    img = _board_12_bit()
    path = tmp_path / f"still{ext}"
    assert cv2.imwrite(str(path), img)
    grey = read_image_file(path, cv2.IMREAD_GRAYSCALE)
    assert grey is not None
    assert grey.dtype == np.uint8
    assert grey.shape == img.shape
    # 4000 < 4096: 12 bits, shifted by 4 (OpenCV's top byte would give 15)
    assert int(grey.max()) == 4000 >> 4
    assert int(grey.min()) == 200 >> 4
    assert int(cv2.imread(str(path), cv2.IMREAD_GRAYSCALE).max()) == 4000 >> 8
    bgr = read_image(path)
    assert bgr.shape == (*img.shape, 3)
    assert bgr.dtype == np.uint8
    assert (bgr == grey[..., None]).all()
    assert image_size(path) == (img.shape[1], img.shape[0])


def test_a_16_bit_colour_still_reads_as_its_8_bit_png_would(tmp_path):
    rng = np.random.default_rng(3)
    img = rng.integers(0, 1024, size=(40, 50, 3)).astype(np.uint16)  # 10 bits
    path = tmp_path / "colour.png"
    assert cv2.imwrite(str(path), img)
    shift = int(img.max()).bit_length() - 8
    eight = (img >> shift).astype(np.uint8)
    ref = tmp_path / "eight.png"
    assert cv2.imwrite(str(ref), eight)
    assert (read_image_file(path, cv2.IMREAD_COLOR) == eight).all()
    assert (read_image_file(path, cv2.IMREAD_GRAYSCALE) == cv2.imread(str(ref), cv2.IMREAD_GRAYSCALE)).all()


def test_8_bit_stills_and_unchanged_reads_are_opencvs(tmp_path):
    img = (_board_12_bit() >> 4).astype(np.uint8)
    path = tmp_path / "eight.png"
    assert cv2.imwrite(str(path), img)
    assert (read_image_file(path, cv2.IMREAD_GRAYSCALE) == cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)).all()
    wide = tmp_path / "wide.png"
    assert cv2.imwrite(str(wide), _board_12_bit())
    unchanged = read_image_file(wide, cv2.IMREAD_UNCHANGED)
    assert unchanged is not None
    assert unchanged.dtype == np.uint16  # sizes are read from it as it is


def test_a_12_bit_board_is_found_at_full_contrast(tmp_path):
    """A checkerboard in a 12-bit camera's frame reads with its levels spread over 8 bits
    (a top byte would hold them in 0..11) and is detected."""
    h, w, sq = 240, 320, 30
    yy, xx = np.mgrid[:h, :w]
    inside = (yy >= 30) & (yy < 30 + 6 * sq) & (xx >= 40) & (xx < 40 + 8 * sq)
    dark = (((yy - 30) // sq + (xx - 40) // sq) % 2 == 0) & inside
    img = np.where(dark, 100, 3000).astype(np.uint16)
    path = tmp_path / "board.png"
    assert cv2.imwrite(str(path), img)
    grey = read_image_file(path, cv2.IMREAD_GRAYSCALE)
    assert grey is not None
    assert int(grey.max()) - int(grey.min()) == (3000 >> 4) - (100 >> 4)
    ok, corners = cv2.findChessboardCorners(grey, (7, 5))
    assert ok
    assert len(corners) == 35
