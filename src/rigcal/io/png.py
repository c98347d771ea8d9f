"""Plain 8-bit PNGs decoded to grey with imagecodecs and numpy alone (no OpenCV, no
compiled kernel), so that a command can start decoding a drive's frames on a second
thread while it is still importing the libraries its other steps use.

The levels are OpenCV's (``cv2.imread(path, cv2.IMREAD_GRAYSCALE)``) as
:func:`rigcal.io.images.read_grey` reads them: colour is converted with libpng's integer
weights (:data:`WEIGHTS_RGB`). :func:`rigcal.io.images.read_grey` decodes plain PNGs here,
with its compiled conversion (the same levels, four times faster).

The image data of a plain PNG is inflated by libdeflate (imagecodecs' ``deflate_decode``:
about half the time of the zlib inflation libpng does, which is most of a noisy frame's
decoding) and handed to libpng stored (uncompressed deflate blocks, which libpng copies),
so that libpng unfilters the rows as it always does: the same pixels, by the same code
(:func:`stored_png`). A file this cannot rewrite exactly is decoded by libpng as it is.
"""

from __future__ import annotations

import struct
import threading
import zlib
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
# A stored deflate block holds at most this many bytes.
_STORED_BLOCK = 65535
# The IEND chunk, whole (length 0, type, CRC).
_IEND = b"\x00\x00\x00\x00IEND\xaeB`\x82"
# Image data inflated here at most (bytes; 64 MiB: a 20-megapixel colour frame), so that a
# header naming an absurd size allocates nothing: libpng reads such files as they are.
_STORED_MAX_BYTES = 64 * 2**20
# Each decoding thread's buffers (the inflated rows, the rewritten PNG, the colour image),
# reused frame after frame: a fresh megabyte per frame costs the kernel's zeroing of its
# pages at first touch, about as much as libpng's unfiltering.
_buffers = threading.local()


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


def stored_png(data: bytes) -> tuple[bytearray, int, int] | None:
    """(the PNG, its height, its width): ``data`` with its image data inflated (by
    libdeflate) and stored uncompressed, for libpng to decode to the same pixels faster;
    None for a file this does not rewrite (libpng then decodes ``data`` itself, and
    reports what is wrong with it).

    Taken: a plain PNG (:func:`plain_png_kind`) of compression, filter and interlace method
    0, whose IDAT chunks follow one another with their CRCs right (libpng's own checks,
    made here since their bytes are not handed on) and end with IEND and the file; whose
    data inflates (the zlib stream's Adler-32 checked) to exactly the rows the header
    states. The IHDR chunk is copied (libpng checks its CRC) and the chunks between it and
    the data (text, time, resolution, background: no effect on the levels) left out. The
    PNG is a buffer this thread reuses for its next file.
    """
    if plain_png_kind(data) is None:
        return None
    ihdr = data[8:33]
    if ihdr[4:8] != b"IHDR":  # not the first chunk: libpng refuses the file
        return None
    width, height, _, colour, compression, filtering, interlace = struct.unpack(">IIBBBBB", ihdr[8:21])
    if compression or filtering or interlace or width == 0 or height == 0:
        return None
    n = height * (1 + width * (3 if colour == _RGB else 1))
    if n > _STORED_MAX_BYTES:
        return None
    idat = _idat_spans(data)
    if idat is None:
        return None
    import imagecodecs

    raw, png = _stored_buffers(n)
    whole = memoryview(data)
    stream = b"".join(whole[a:b] for a, b in idat)
    try:
        inflated = imagecodecs.deflate_decode(stream, out=raw)
    except Exception:  # a damaged stream: libpng decides
        return None
    if len(inflated) != n:
        return None
    view, rows = memoryview(png), memoryview(raw)
    view[:8] = PNG_SIGNATURE
    view[8:33] = ihdr
    struct.pack_into(">I4s2s", png, 33, len(png) - 8 - 25 - 12 - 12, b"IDAT", b"\x78\x01")
    pos = 43
    for start in range(0, n, _STORED_BLOCK):
        size = min(_STORED_BLOCK, n - start)
        struct.pack_into("<BHH", png, pos, start + size == n, size, 0xFFFF ^ size)
        view[pos + 5 : pos + 5 + size] = rows[start : start + size]
        pos += 5 + size
    view[pos : pos + 4] = stream[-4:]  # the Adler-32 of the same rows
    struct.pack_into(">I", png, pos + 4, zlib.crc32(view[37 : pos + 4]))
    view[pos + 8 :] = _IEND
    return png, height, width


def _idat_spans(data: bytes) -> list[tuple[int, int]] | None:
    """The (start, end) of each IDAT chunk's data in a plain PNG, when they follow one
    another with right CRCs up to IEND, the file's end; else None."""
    pos, spans = 8, list[tuple[int, int]]()
    whole = memoryview(data)  # chunks read in place, not copied
    while pos + 12 <= len(data):
        length, ctype = struct.unpack(">I4s", data[pos : pos + 8])
        end = pos + 12 + length
        if end > len(data):
            return None
        if ctype == b"IDAT":
            if spans and spans[-1][1] + 4 != pos:
                return None
            if zlib.crc32(whole[pos + 4 : end - 4]) != struct.unpack_from(">I", data, end - 4)[0]:
                return None
            spans.append((pos + 8, end - 4))
        elif spans:
            return spans if data[pos:] == _IEND else None
        pos = end
    return None


def _stored_buffers(n: int) -> tuple[bytearray, bytearray]:
    """This thread's buffers for n bytes of rows: the rows, the PNG storing them."""
    have = getattr(_buffers, "stored", None)
    if have is None or len(have[0]) != n:
        blocks = -(-n // _STORED_BLOCK)
        # signature, IHDR, IDAT's length and type, zlib header, blocks, Adler-32, CRC, IEND
        have = (bytearray(n), bytearray(8 + 25 + 8 + 2 + 5 * blocks + n + 4 + 4 + 12))
        _buffers.stored = have
    return have


def _colour_buffer(height: int, width: int) -> NDArray[np.uint8]:
    """This thread's (H, W, 3) colour image, reused."""
    have: NDArray[np.uint8] | None = getattr(_buffers, "colour", None)
    if have is None or have.shape != (height, width, 3):
        have = np.empty((height, width, 3), np.uint8)
        _buffers.colour = have
    return have


def plain_png_grey(
    data: bytes, to_grey: Callable[[NDArray[np.uint8]], Gray] = rgb_to_grey_reference
) -> Gray | None:
    """The grey levels of a plain 8-bit grey or colour PNG (:func:`plain_png_kind`; colour
    converted by ``to_grey``, which returns a new array: the colour image is a buffer this
    thread reuses), or None for any other file, or one that does not decode here (OpenCV
    then decides)."""
    kind = plain_png_kind(data)
    if kind is None:
        return None
    import imagecodecs

    stored = stored_png(data)
    source: bytes | bytearray = data if stored is None else stored[0]
    try:
        if kind == _RGB and stored is not None:
            img = np.asarray(imagecodecs.png_decode(source, out=_colour_buffer(stored[1], stored[2])))
        else:
            img = np.asarray(imagecodecs.png_decode(source))
    except Exception:  # a damaged file: OpenCV decides (and reports None)
        return None
    if img.dtype == np.uint8:
        if kind == _GREY and img.ndim == 2:
            return img
        if kind == _RGB and img.ndim == 3 and img.shape[2] == 3:
            return to_grey(img)
    return None
