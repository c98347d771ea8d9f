"""Images read as grey, the way OpenCV's ``cv2.imread(path, cv2.IMREAD_GRAYSCALE)`` reads
them, faster for the PNGs sequences are made of.

Decoding is one of the largest costs of localizing a sequence from its images.
:func:`read_grey` decodes plain 8-bit grey and colour PNGs with imagecodecs (the image
data inflated by libdeflate, then unfiltered by libpng: faster than OpenCV's libpng,
``benchmarks/bench_decode.py``, figures in docs/benchmarks.md) and converts colour to
grey with the integer weights libpng applies for OpenCV, ``(9797 R + 19234 G + 3737 B) >>
15`` (ITU-R BT.601's 0.299, 0.587 and 0.114 in 1/32768, truncated), so the grey levels
are bit for bit OpenCV's and so are the tracks and trajectories computed from them. Any
other image (JPEG, a palette, transparency, or a PNG that states its gamma or colour
space, which libpng may honour) is read by OpenCV itself. A drive's 16-bit frames (PNG,
TIFF, PGM, PPM) are made 8-bit by one rule wherever they are read (:func:`eight_bit_pngs`
when a recording is imported, :func:`sixteen_bit_grey` when a sequence folder holds them):
every frame shifted right by the same bits, those of the drive's brightest level beyond 8
(:func:`depth_shift`). The plain PNGs' decoding is :mod:`rigcal.io.png`'s (importable
without OpenCV or numba, for decoding that starts
while a command still imports them).
"""

from __future__ import annotations

import contextlib
import logging
import os
import struct
import tempfile
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from rigcal.errors import InputError
from rigcal.io.png import PNG_SIGNATURE, WEIGHTS_RGB, plain_png_grey
from rigcal.io.png import plain_png_kind as plain_png_kind
from rigcal.io.png import rgb_to_grey_reference as rgb_to_grey_reference
from rigcal.jit import loaded, njit

Gray = NDArray[np.uint8]
log = logging.getLogger(__name__)

_WR, _WG, _WB = WEIGHTS_RGB


def read_grey(path: str | Path) -> Gray | None:
    """The image at ``path`` as 8-bit grey, or None when it cannot be read (as
    ``cv2.imread(path, cv2.IMREAD_GRAYSCALE)``, whose levels it returns)."""
    try:
        data = Path(path).read_bytes()
    except OSError:
        return None
    return grey_of(data)


def grey_of(data: bytes) -> Gray | None:
    """Encoded image bytes as 8-bit grey, as :func:`read_grey` reads a file."""
    import cv2

    if not data:
        return None
    grey = plain_png_grey(data, rgb_to_grey)
    if grey is not None:
        return grey
    out = decode(data, cv2.IMREAD_GRAYSCALE)
    return None if out is None else np.asarray(out, dtype=np.uint8)


# TIFF's two byte orders and binary PGM/PPM: formats that may hold 16-bit frames (besides
# PNG, whose IHDR says its depth). A JPEG is 8-bit.
_WIDE_SIGNATURES = (b"II*\x00", b"MM\x00*", b"P5", b"P6")


def sixteen_bit(data: bytes) -> NDArray[np.uint16] | None:
    """An encoded frame's levels when it is a 16-bit image (PNG, TIFF, binary PGM or PPM),
    as OpenCV decodes it unchanged ((H, W) grey, (H, W, 3) BGR or (H, W, 4) BGRA); None for
    any other frame (8-bit ones; JPEGs and 8-bit PNGs are not decoded)."""
    import cv2

    # IHDR's bit depth is byte 24 of a PNG (signature, chunk length and type, width, height).
    if data.startswith(PNG_SIGNATURE):
        if data[24:25] != b"\x10":
            return None
    elif not data.startswith(_WIDE_SIGNATURES):
        return None
    img = decode(data, cv2.IMREAD_UNCHANGED)
    return img if img is not None and img.dtype == np.uint16 else None


def depth_shift(top_level: int) -> int:
    """The bits a drive's 16-bit frames are shifted right by to make them 8-bit: those of
    its brightest level beyond 8 (a 12-bit camera's levels up to 4095: 4; a camera filling
    16 bits: 8, its top byte), the same for every frame, so that a level means the same
    brightness in every frame and a camera that fills only 12 of its 16 bits is not read
    as nearly black (OpenCV keeps a 16-bit image's top byte)."""
    return max(0, int(top_level).bit_length() - 8)


def eight_bits(img: NDArray[np.uint16], shift: int) -> NDArray[np.uint8]:
    """A 16-bit frame's levels shifted right by ``shift`` bits (:func:`depth_shift`), as
    8 bits (levels above the drive's brightest cannot occur: it sets the shift)."""
    return np.minimum(img >> shift, 255).astype(np.uint8)


def sixteen_bit_grey(img: NDArray[np.uint16], shift: int) -> Gray:
    """A 16-bit frame as the 8-bit grey its 8-bit PNG (:func:`eight_bit_pngs`) reads as
    (:func:`read_grey`: colour by libpng's weights, alpha ignored)."""
    eight = eight_bits(img, shift)
    if eight.ndim == 2:
        return eight
    return rgb_to_grey(np.ascontiguousarray(eight[..., 2::-1]))  # BGR(A) -> RGB


def eight_bit_pngs(images: list[bytes]) -> tuple[list[bytes], dict[str, int]]:
    """A drive's encoded frames with its 16-bit frames (PNG, TIFF, PGM, PPM:
    :func:`sixteen_bit`) as 8-bit PNGs, every one shifted right by the same bits
    (:func:`depth_shift`). Other frames are returned as they are (the same objects: a
    frame that is not is a PNG now); the dict says what was done (``frames``,
    ``max_level``, ``shift_bits``; empty: nothing)."""
    import cv2

    # Two passes, each decoding one frame at a time: a drive's 16-bit frames need not fit
    # in memory together.
    levels = {k: int(img.max()) for k, data in enumerate(images) if (img := sixteen_bit(data)) is not None}
    if not levels:
        return images, {}
    top = max(levels.values())
    shift = depth_shift(top)
    out = list(images)
    for k in levels:
        img = sixteen_bit(images[k])
        assert img is not None  # it decoded in the first pass
        ok, buf = cv2.imencode(".png", eight_bits(img, shift))
        assert ok  # cv2 encodes any 8-bit image
        out[k] = bytes(buf.tobytes())
    return out, {"frames": len(levels), "max_level": top, "shift_bits": shift}


def sixteen_bit_levels(paths: list[Path]) -> dict[str, int]:
    """The 16-bit frames among ``paths`` (:func:`sixteen_bit`), as :func:`eight_bit_pngs`
    records them: ``frames``, ``max_level``, ``shift_bits`` (empty: none). Each file is read
    once, one at a time."""
    levels = []
    for path in paths:
        try:
            data = path.read_bytes()
        except OSError:  # the frame's own reading names it
            continue
        img = sixteen_bit(data)
        if img is not None:
            levels.append(int(img.max()))
    if not levels:
        return {}
    top = max(levels)
    return {"frames": len(levels), "max_level": top, "shift_bits": depth_shift(top)}


def read_grey_at_depth(path: str | Path, depth: dict[str, int]) -> Gray | None:
    """The image at ``path`` as 8-bit grey (:func:`read_grey`); a 16-bit frame of a drive
    whose 16-bit frames ``depth`` describes (:func:`sixteen_bit_levels`) shifted right by
    its ``shift_bits``, as its 8-bit PNG would read (:func:`sixteen_bit_grey`)."""
    if depth:
        try:
            img = sixteen_bit(Path(path).read_bytes())
        except OSError:
            return None
        if img is not None:
            return sixteen_bit_grey(img, depth["shift_bits"])
    return read_grey(path)


def decode(data: bytes, flags: int) -> NDArray[Any] | None:
    """``cv2.imdecode(data, flags)``, None for a file that does not decode, with what
    OpenCV's PNG codec prints about a damaged file (libpng's "libpng error: IDAT: CRC
    error", OpenCV's own warnings) kept off the terminal: it goes to the debug log, so that
    the one line a command prints on bad input is rigcal's. (PNG decodes hold a lock while
    stderr is redirected; plain 8-bit PNGs of sequences are read by :func:`read_grey`'s
    own decoder, JPEGs without the lock.)

    The pixels are the image's as stored, whatever its EXIF or TIFF orientation tag says
    (a phone's or a tilted camera's "rotate 180 for display"): a camera file describes the
    sensor's pixels, and OpenCV would turn a JPEG read as grey or colour but not one read
    unchanged, and a TIFF always (:func:`as_stored`)."""
    import cv2

    if not data:
        return None
    if flags != cv2.IMREAD_UNCHANGED:  # (-1: OpenCV applies no orientation to it but a TIFF's)
        flags |= cv2.IMREAD_IGNORE_ORIENTATION
    if data.startswith(PNG_SIGNATURE):  # libpng writes its own "libpng error: ..." lines
        with _codec_messages_to_log():
            out = cv2.imdecode(np.frombuffer(data, np.uint8), flags)
    else:  # JPEG and the rest say nothing of their own, and decode in parallel threads
        out = cv2.imdecode(np.frombuffer(data, np.uint8), flags)
    if out is None:
        return None
    if data.startswith(_TIFF_SIGNATURES):
        return as_stored(np.asarray(out), tiff_orientation(data))
    return np.asarray(out)


_TIFF_SIGNATURES = (b"II*\x00", b"MM\x00*", b"II+\x00", b"MM\x00+")  # TIFF, BigTIFF


def tiff_orientation(data: bytes) -> int:
    """A TIFF's (or BigTIFF's) Orientation tag (274) in its first image directory, 1 (as
    stored) when it has none or the directory cannot be read."""
    order = "<" if data[:2] == b"II" else ">"
    big = data[2:4] in (b"+\x00", b"\x00+")
    # An entry: tag, type, count, then the value (a SHORT's in its first 2 bytes).
    entry, value_at, count_fmt, offset_fmt = (20, 12, "Q", "Q") if big else (12, 8, "H", "I")
    try:
        (ifd,) = struct.unpack_from(order + offset_fmt, data, 8 if big else 4)
        (n,) = struct.unpack_from(order + count_fmt, data, ifd)
        first = ifd + (8 if big else 2)
        for k in range(min(int(n), 4096)):
            tag, kind = struct.unpack_from(order + "HH", data, first + k * entry)
            if tag == 274 and kind == 3:  # SHORT, its value in the entry's value field
                (value,) = struct.unpack_from(order + "H", data, first + k * entry + value_at)
                return int(value) if 1 <= value <= 8 else 1
    except struct.error:
        return 1
    return 1


def as_stored(img: NDArray[Any], orientation: int) -> NDArray[Any]:
    """``img`` decoded turned for display by a TIFF orientation tag (1 to 8, EXIF's
    meanings), turned back to its pixels as stored."""
    undo = {
        2: lambda a: a[:, ::-1],
        3: lambda a: a[::-1, ::-1],
        4: lambda a: a[::-1],
        5: lambda a: a.swapaxes(0, 1),
        6: lambda a: np.rot90(a, 1),
        7: lambda a: a[::-1, ::-1].swapaxes(0, 1),
        8: lambda a: np.rot90(a, -1),
    }
    return np.ascontiguousarray(undo[orientation](img)) if orientation in undo else img


def read_image(path: str | Path) -> NDArray[np.uint8]:
    """Read an image as 8-bit BGR; InputError if missing or unreadable."""
    import cv2

    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: image not found")
    img = read_image_file(path, cv2.IMREAD_COLOR)
    if img is None:
        raise InputError(f"{path}: cannot decode image (expected PNG, JPEG or another format OpenCV reads)")
    out: NDArray[np.uint8] = np.asarray(img, dtype=np.uint8)
    return out


def image_size(path: str | Path) -> tuple[int, int]:
    """(width, height) in pixels of an image file.

    Raises:
        InputError: the file is missing or not a readable image.
    """
    import cv2

    img = read_image_file(path, cv2.IMREAD_GRAYSCALE)
    if img is None:
        raise InputError(f"{path}: image not found or not readable")
    return (int(img.shape[1]), int(img.shape[0]))


def read_image_file(path: str | Path, flags: int) -> NDArray[Any] | None:
    """The image at ``path`` decoded with :func:`decode`; None when it is missing,
    unreadable or does not decode (as ``cv2.imread(path, flags)``).

    A still image read as 8-bit grey or colour (``cv2.IMREAD_GRAYSCALE``,
    ``cv2.IMREAD_COLOR``: the captures of a calibration, a box picking file's images)
    that is 16-bit (:func:`sixteen_bit`) is shifted right by its own brightest level's
    bits beyond 8 (:func:`depth_shift`), not cut to its top byte as OpenCV does: a 12-bit
    camera's frame would read nearly black and its board go unfound. Each still is its own
    exposure, so each has its own shift (a drive's frames share one:
    :func:`eight_bit_pngs`)."""
    import cv2

    try:
        data = Path(path).read_bytes()
    except OSError:
        return None
    if flags in (cv2.IMREAD_GRAYSCALE, cv2.IMREAD_COLOR):
        wide = sixteen_bit(data)
        if wide is not None:
            return still_eight_bit(wide, grey=flags == cv2.IMREAD_GRAYSCALE)
    return decode(data, flags)


def still_eight_bit(img: NDArray[np.uint16], grey: bool) -> NDArray[np.uint8]:
    """A 16-bit still (grey, BGR or BGRA) as 8-bit grey or BGR, shifted by its own
    brightest level's bits beyond 8 (:func:`depth_shift`)."""
    shift = depth_shift(int(img.max()))
    if grey:
        return sixteen_bit_grey(img, shift)
    eight = eight_bits(img, shift)
    if eight.ndim == 2:
        return np.ascontiguousarray(np.repeat(eight[..., None], 3, axis=2))
    return np.ascontiguousarray(eight[..., :3])


_STDERR_LOCK = threading.Lock()


@contextlib.contextmanager
def _codec_messages_to_log() -> Iterator[None]:
    """Redirect file descriptor 2 (where libpng and OpenCV's logger write) to a temporary
    file for the duration; lines from the codecs go to the debug log, any other text
    (another thread's) is written back to stderr afterwards."""
    import cv2

    with _STDERR_LOCK, tempfile.TemporaryFile() as sink:
        level = cv2.utils.logging.getLogLevel()
        try:
            saved = os.dup(2)
        except OSError:  # no stderr to redirect
            yield
            return
        try:
            cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_SILENT)
            os.dup2(sink.fileno(), 2)
            yield
        finally:
            os.dup2(saved, 2)
            os.close(saved)
            cv2.utils.logging.setLogLevel(level)
            sink.seek(0)
            other = []
            for line in sink.read().decode("utf-8", "replace").splitlines(keepends=True):
                if line.startswith(("libpng", "libjpeg", "Corrupt JPEG", "Premature end of JPEG")):
                    log.debug("image codec: %s", line.strip())
                else:
                    other.append(line)
            if other:
                os.write(2, "".join(other).encode())


_loading = threading.Lock()


def rgb_to_grey(rgb: NDArray[np.uint8]) -> Gray:
    """(H, W, 3) RGB to (H, W) grey with libpng's integer weights (:data:`WEIGHTS_RGB`).

    Until its kernel is loaded, one thread loads it (at a process's first kernel, numba's
    set-up: about half a CPU second, under numba's compile lock) while the others convert
    with numpy (:func:`rgb_to_grey_reference`, the same levels) rather than wait."""
    out = np.empty(rgb.shape[:2], dtype=np.uint8)
    if not loaded(_rgb_to_grey):
        if not _loading.acquire(blocking=False):
            return rgb_to_grey_reference(rgb)
        try:
            _rgb_to_grey(np.ascontiguousarray(rgb), out)
        finally:
            _loading.release()
        return out
    _rgb_to_grey(np.ascontiguousarray(rgb), out)
    return out


@njit
def _rgb_to_grey(rgb: NDArray[np.uint8], out: Gray) -> None:
    h, w = out.shape
    for i in range(h):
        for j in range(w):
            v = _WR * np.uint32(rgb[i, j, 0]) + _WG * np.uint32(rgb[i, j, 1]) + _WB * np.uint32(rgb[i, j, 2])
            out[i, j] = np.uint8(v >> 15)
