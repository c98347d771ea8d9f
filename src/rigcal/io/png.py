"""Plain 8-bit PNGs decoded to grey with imagecodecs and numpy alone (no OpenCV, no
compiled kernel), so that a command can start decoding a drive's frames on a second
thread while it is still importing the libraries its other steps use.

The levels are OpenCV's (``cv2.imread(path, cv2.IMREAD_GRAYSCALE)``) as
:func:`rigcal.io.images.read_grey` reads them: colour is converted with libpng's integer
weights (:data:`WEIGHTS_RGB`). :func:`rigcal.io.images.read_grey` decodes plain PNGs here,
with its compiled conversion (the same levels, four times faster).
"""

from __future__ import annotations

import struct
from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray

Gray = NDArray[np.uint8]

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
# Chunks before the image data that leave the decoded levels as stored: text, time,
# resolution, background (which grey reading ignores without transparency).
_PLAIN_CHUNKS = frozenset({b"IHDR", b"pHYs", b"tEXt", b"zTXt", b"iTXt", b"tIME", b"bKGD", b"eXIf"})
# IHDR colour types read here: 0 grey, 2 RGB.
_GREY, _RGB = 0, 2
# libpng's rgb-to-grey weights for OpenCV's (0.299, 0.587) in 1/32768 (the blue weight is
# what is left), applied as (r R + g G + b B) >> 15.
WEIGHTS_RGB = (9797, 19234, 3737)


def plain_png_kind(data: bytes) -> int | None:
    """The IHDR colour type (0 grey, 2 RGB) of an 8-bit PNG whose chunks before the image
    data change nothing in how its levels read; None for anything else."""
    if not data.startswith(PNG_SIGNATURE):
        return None
    pos = len(PNG_SIGNATURE)
    kind: int | None = None
    while pos + 8 <= len(data):
        length, ctype = struct.unpack(">I4s", data[pos : pos + 8])
        if ctype == b"IDAT":
            return kind
        if ctype not in _PLAIN_CHUNKS:
            return None
        if ctype == b"IHDR":
            if length != 13 or pos + 21 > len(data):
                return None
            depth, colour = data[pos + 16], data[pos + 17]
            if depth != 8 or colour not in (_GREY, _RGB):
                return None
            kind = colour
        pos += 12 + length
    return None


def rgb_to_grey_reference(rgb: NDArray[np.uint8]) -> Gray:
    """(H, W, 3) RGB to (H, W) grey with libpng's integer weights, in numpy (the
    reference :func:`rigcal.io.images.rgb_to_grey`'s kernel is tested against)."""
    wr, wg, wb = WEIGHTS_RGB
    c = rgb.astype(np.uint32)
    out: Gray = ((wr * c[..., 0] + wg * c[..., 1] + wb * c[..., 2]) >> 15).astype(np.uint8)
    return out


def plain_png_grey(
    data: bytes, to_grey: Callable[[NDArray[np.uint8]], Gray] = rgb_to_grey_reference
) -> Gray | None:
    """The grey levels of a plain 8-bit grey or colour PNG (:func:`plain_png_kind`; colour
    converted by ``to_grey``), or None for any other file, or one that does not decode
    here (OpenCV then decides)."""
    kind = plain_png_kind(data)
    if kind is None:
        return None
    import imagecodecs

    try:
        img = np.asarray(imagecodecs.png_decode(data))
    except Exception:  # a damaged file: OpenCV decides (and reports None)
        return None
    if img.dtype == np.uint8:
        if kind == _GREY and img.ndim == 2:
            return img
        if kind == _RGB and img.ndim == 3 and img.shape[2] == 3:
            return to_grey(img)
    return None
