"""An image's orientation tag (EXIF's in a JPEG, PNG or WebP; TIFF's own) is not applied:
every reader gets the pixels as stored, the sensor's, which the camera file describes.
OpenCV alone would turn a JPEG read as grey or colour but not one read unchanged (the size
check), and a TIFF always."""

from __future__ import annotations

import struct
from pathlib import Path

import cv2
import numpy as np
import pytest
from PIL import Image

from rigcal.io.images import (
    as_stored,
    image_size,
    read_grey,
    read_grey_at_depth,
    read_image,
    read_image_file,
    sixteen_bit_levels,
    tiff_orientation,
)

PIXELS = np.random.default_rng(0).integers(0, 256, (6, 9), dtype=np.uint8)  # no symmetry


def _tagged(path: Path, fmt: str, orientation: int, pixels: np.ndarray = PIXELS) -> Path:
    exif = Image.Exif()
    exif[0x0112] = orientation
    extra = {"JPEG": {"quality": 100}, "WEBP": {"lossless": True}}.get(fmt, {})
    Image.fromarray(pixels).save(path, fmt, exif=exif.tobytes(), **extra)
    return path


def _grey(img: np.ndarray) -> np.ndarray:
    return img if img.ndim == 2 else img[..., 0]


@pytest.mark.parametrize("fmt", ["JPEG", "PNG", "TIFF", "WEBP"])
@pytest.mark.parametrize("orientation", range(1, 9))
def test_every_reader_gets_the_stored_pixels_whatever_the_tag(tmp_path, fmt, orientation):
    plain = _tagged(tmp_path / f"plain.{fmt.lower()}", fmt, 1)
    tagged = _tagged(tmp_path / f"tagged.{fmt.lower()}", fmt, orientation)
    want = read_grey(plain)
    assert want is not None
    assert want.shape == PIXELS.shape
    tol = 0 if fmt != "JPEG" else 8  # the same stored JPEG data decode alike; PIXELS vs JPEG do not
    got = [
        read_grey(tagged),
        read_image_file(tagged, cv2.IMREAD_GRAYSCALE),
        read_image_file(tagged, cv2.IMREAD_COLOR),
        read_image_file(tagged, cv2.IMREAD_UNCHANGED),
        read_image(tagged),
    ]
    for img in got:
        assert img is not None
        assert _grey(img).shape == want.shape
        assert np.abs(_grey(img).astype(int) - want).max() <= tol
    assert image_size(tagged) == (9, 6)


def _tiff(pixels: np.ndarray, orientation: int, order: str) -> bytes:
    """An uncompressed grey TIFF (8- or 16-bit) with an Orientation tag, in either byte order."""
    h, w = pixels.shape
    bits = pixels.dtype.itemsize * 8
    body = pixels.astype(pixels.dtype.newbyteorder(order)).tobytes()
    tags = [  # (tag, type SHORT=3 / LONG=4, value)
        (256, 4, w),
        (257, 4, h),
        (258, 3, bits),
        (259, 3, 1),
        (262, 3, 1),
        (273, 4, 8),
        (274, 3, orientation),
        (277, 3, 1),
        (278, 4, h),
        (279, 4, len(body)),
    ]
    ifd = struct.pack(order + "H", len(tags))
    for tag, kind, value in tags:
        packed = struct.pack(order + "H", value) + b"\0\0" if kind == 3 else struct.pack(order + "I", value)
        ifd += struct.pack(order + "HHI", tag, kind, 1) + packed
    head = (b"II*\0" if order == "<" else b"MM\0*") + struct.pack(order + "I", 8 + len(body))
    return head + body + ifd + b"\0\0\0\0"


@pytest.mark.parametrize("order", ["<", ">"])
@pytest.mark.parametrize("orientation", [3, 6, 8])
def test_a_tiff_of_either_byte_order_and_depth_is_read_as_stored(tmp_path, order, orientation):
    for pixels in (PIXELS, PIXELS.astype(np.uint16) * 16):  # 8 bits; a 12-bit camera's
        data = _tiff(pixels, orientation, order)
        assert tiff_orientation(data) == orientation
        path = tmp_path / "frame.tif"
        path.write_bytes(data)
        unchanged = read_image_file(path, cv2.IMREAD_UNCHANGED)
        assert unchanged is not None
        np.testing.assert_array_equal(unchanged, pixels)
        depth = sixteen_bit_levels([path])
        grey = read_grey_at_depth(path, depth)
        assert grey is not None
        np.testing.assert_array_equal(grey, PIXELS)  # 16-bit: shifted back by its 4 bits


def test_orientation_of_a_damaged_or_untagged_tiff_is_as_stored():
    data = _tiff(PIXELS, 6, "<")
    assert tiff_orientation(data[:20]) == 1  # cut inside the directory
    assert tiff_orientation(data.replace(struct.pack("<HH", 274, 3), struct.pack("<HH", 999, 3))) == 1
    assert tiff_orientation(_tiff(PIXELS, 9, "<")) == 1  # not an orientation
    assert as_stored(PIXELS, 1) is PIXELS
