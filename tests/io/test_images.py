"""rigcal.io.images: grey levels bit for bit OpenCV's IMREAD_GRAYSCALE, whichever decoder
reads the file."""

from __future__ import annotations

import struct
import zlib
from pathlib import Path

import cv2
import imagecodecs
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rigcal.io import images, png
from rigcal.io.images import plain_png_kind, read_grey, rgb_to_grey, rgb_to_grey_reference


def _png(img: np.ndarray, *params: int) -> bytes:
    ok, buf = cv2.imencode(".png", img, list(params))
    assert ok
    return buf.tobytes()


def _with_chunk_after_ihdr(png: bytes, ctype: bytes, data: bytes) -> bytes:
    """``png`` with a chunk inserted right after its IHDR."""
    end = 8 + 12 + 13
    crc = struct.pack(">I", zlib.crc32(ctype + data) & 0xFFFFFFFF)
    return png[:end] + struct.pack(">I", len(data)) + ctype + data + crc + png[end:]


def _decoded_by_imagecodecs(monkeypatch: pytest.MonkeyPatch) -> list[int]:
    calls: list[int] = []
    real = imagecodecs.png_decode

    def spy(data: bytes, **kw: object) -> np.ndarray:
        calls.append(len(data))
        return np.asarray(real(data, **kw))

    monkeypatch.setattr(imagecodecs, "png_decode", spy)
    return calls


def _textured(rng: np.random.Generator, h: int, w: int, channels: int) -> np.ndarray:
    shape = (h, w) if channels == 1 else (h, w, channels)
    return rng.integers(0, 256, shape, dtype=np.uint8)


@settings(max_examples=25, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    h=st.integers(1, 40),
    w=st.integers(1, 40),
    channels=st.sampled_from([1, 3]),
    compression=st.integers(0, 9),
)
def test_plain_pngs_read_as_opencv_reads_them(tmp_path_factory, seed, h, w, channels, compression):
    img = _textured(np.random.default_rng(seed), h, w, channels)
    path = tmp_path_factory.mktemp("png") / "frame.png"
    path.write_bytes(_png(img, cv2.IMWRITE_PNG_COMPRESSION, compression))
    assert plain_png_kind(path.read_bytes()) == (0 if channels == 1 else 2)
    assert png.stored_png(path.read_bytes()) is not None  # the rows inflated by libdeflate
    got = read_grey(path)
    assert got is not None
    assert got.dtype == np.uint8
    np.testing.assert_array_equal(got, cv2.imread(str(path), cv2.IMREAD_GRAYSCALE))


def test_a_colour_png_is_decoded_by_imagecodecs_and_matches_opencv(tmp_path, monkeypatch):
    # Smooth colour ramps and noise: every rounding case of the weighted sum turns up.
    rng = np.random.default_rng(3)
    img = _textured(rng, 120, 160, 3)
    img[:60] = np.stack(np.meshgrid(np.arange(160) % 256, np.arange(60)), -1)[..., [0, 1, 0]].astype(np.uint8)
    path = tmp_path / "a.png"
    path.write_bytes(_png(img, cv2.IMWRITE_PNG_STRATEGY, cv2.IMWRITE_PNG_STRATEGY_HUFFMAN_ONLY))
    calls = _decoded_by_imagecodecs(monkeypatch)
    np.testing.assert_array_equal(read_grey(path), cv2.imread(str(path), cv2.IMREAD_GRAYSCALE))
    stored = png.stored_png(path.read_bytes())
    assert stored is not None
    assert calls == [len(stored[0])]  # libpng given the rows stored, once


def test_the_compiled_conversion_follows_its_numpy_reference():
    rng = np.random.default_rng(0)
    rgb = rng.integers(0, 256, (33, 47, 3), dtype=np.uint8)
    rgb[0, :3] = [[0, 0, 0], [255, 255, 255], [255, 0, 0]]
    np.testing.assert_array_equal(rgb_to_grey(rgb), rgb_to_grey_reference(rgb))
    # A grey pixel keeps its level (the weights sum to 32768).
    flat = np.repeat(np.arange(256, dtype=np.uint8)[None, :, None], 3, axis=2)
    np.testing.assert_array_equal(rgb_to_grey(flat)[0], np.arange(256))


@pytest.mark.parametrize(
    ("name", "chunk"),
    [
        ("gamma", (b"gAMA", struct.pack(">I", 45455))),
        ("srgb", (b"sRGB", b"\x00")),
        ("transparency", (b"tRNS", struct.pack(">HHH", 1, 2, 3))),
    ],
)
def test_pngs_stating_a_colour_space_or_transparency_are_left_to_opencv(tmp_path, monkeypatch, name, chunk):
    img = _textured(np.random.default_rng(1), 20, 30, 3)
    data = _with_chunk_after_ihdr(_png(img), *chunk)
    assert plain_png_kind(data) is None
    path = tmp_path / f"{name}.png"
    path.write_bytes(data)
    calls = _decoded_by_imagecodecs(monkeypatch)
    np.testing.assert_array_equal(read_grey(path), cv2.imread(str(path), cv2.IMREAD_GRAYSCALE))
    assert calls == []


def test_a_text_chunk_keeps_the_fast_path(tmp_path):
    img = _textured(np.random.default_rng(2), 10, 12, 3)
    data = _with_chunk_after_ihdr(_png(img), b"tEXt", b"Software\x00rigcal")
    assert plain_png_kind(data) == 2


@pytest.mark.parametrize(
    ("name", "img"),
    [
        ("rgba", np.full((8, 9, 4), 200, np.uint8)),
        ("mono16", (np.arange(72, dtype=np.uint16).reshape(8, 9) * 900)),
        ("rgb16", np.full((8, 9, 3), 40000, np.uint16)),
    ],
)
def test_other_pngs_are_read_by_opencv(tmp_path, name, img):
    data = _png(img)
    assert plain_png_kind(data) is None
    path = tmp_path / f"{name}.png"
    path.write_bytes(data)
    np.testing.assert_array_equal(read_grey(path), cv2.imread(str(path), cv2.IMREAD_GRAYSCALE))


def test_jpeg_is_read_by_opencv(tmp_path):
    img = _textured(np.random.default_rng(4), 32, 32, 3)
    path = tmp_path / "a.jpg"
    path.write_bytes(cv2.imencode(".jpg", img)[1].tobytes())
    assert plain_png_kind(path.read_bytes()) is None
    np.testing.assert_array_equal(read_grey(path), cv2.imread(str(path), cv2.IMREAD_GRAYSCALE))


def test_missing_empty_and_damaged_files_read_as_none(tmp_path):
    assert read_grey(tmp_path / "missing.png") is None
    (tmp_path / "empty.png").write_bytes(b"")
    assert read_grey(tmp_path / "empty.png") is None
    good = _png(_textured(np.random.default_rng(5), 16, 16, 3))
    (tmp_path / "cut.png").write_bytes(good[: len(good) // 2])
    cut = read_grey(tmp_path / "cut.png")
    # A cut file: whatever OpenCV makes of it (nothing, or what it could decode).
    expected = cv2.imread(str(tmp_path / "cut.png"), cv2.IMREAD_GRAYSCALE)
    if expected is None:
        assert cut is None
    else:
        np.testing.assert_array_equal(cut, expected)
    (tmp_path / "junk.png").write_bytes(images.PNG_SIGNATURE + b"\x00\x00\x00\x0dIHDR" + b"\x00" * 5)
    assert read_grey(tmp_path / "junk.png") is None


def test_a_truncated_header_is_not_plain():
    assert plain_png_kind(b"") is None
    assert plain_png_kind(images.PNG_SIGNATURE) is None
    assert plain_png_kind(images.PNG_SIGNATURE + struct.pack(">I4s", 13, b"IHDR") + b"\x00" * 4) is None


def test_a_path_given_as_text_reads_too(tmp_path: Path):
    path = tmp_path / "g.png"
    img = _textured(np.random.default_rng(6), 5, 7, 1)
    path.write_bytes(_png(img))
    np.testing.assert_array_equal(read_grey(str(path)), img)


def test_a_damaged_png_decodes_to_none_and_libpng_says_nothing(tmp_path, capfd, caplog, monkeypatch):
    import logging

    from rigcal.io.images import decode, read_image_file

    # A command run with -v by a module-scoped fixture elsewhere may have left a stderr
    # handler on the rigcal logger; this test is about libpng's own output, not rigcal's.
    monkeypatch.setattr(logging.getLogger("rigcal"), "handlers", [])
    monkeypatch.setattr(logging.getLogger("rigcal"), "propagate", True)

    png = bytearray(cv2.imencode(".png", np.arange(400, dtype=np.uint8).reshape(20, 20))[1].tobytes())
    png[60] ^= 0xFF  # damaged IDAT: libpng prints "libpng error: IDAT: ..." on fd 2
    (tmp_path / "bad.png").write_bytes(bytes(png))
    with caplog.at_level(logging.DEBUG, logger="rigcal.io.images"):
        assert decode(bytes(png), cv2.IMREAD_GRAYSCALE) is None
        assert read_image_file(tmp_path / "bad.png", cv2.IMREAD_COLOR) is None
        assert read_grey(tmp_path / "bad.png") is None
    assert capfd.readouterr().err == ""
    assert "image codec: libpng error: IDAT: " in caplog.text  # -v shows it
    assert read_image_file(tmp_path / "nope.png", cv2.IMREAD_COLOR) is None


def test_other_text_on_stderr_while_decoding_is_written_back(capfd):
    import os

    from rigcal.io.images import _codec_messages_to_log

    with _codec_messages_to_log():
        os.write(2, b"progress 3/4\n")
    assert capfd.readouterr().err == "progress 3/4\n"


def test_rgb_to_grey_converts_with_numpy_while_another_thread_loads_its_kernel(monkeypatch):
    """A decoding thread does not wait on the kernel's loading (numba's set-up at a
    process's first kernel) under way on another: numpy's conversion, the same levels."""
    import rigcal.io.images as images

    calls = []

    class Unloaded:
        def __init__(self) -> None:
            self.signatures: list[object] = []

        def __call__(self, rgb, out):  # type: ignore[no-untyped-def]
            calls.append(rgb.shape)
            out[:] = rgb_to_grey_reference(rgb)

    monkeypatch.setattr(images, "_rgb_to_grey", Unloaded())
    rgb = np.random.default_rng(5).integers(0, 256, (6, 7, 3), dtype=np.uint8)
    with images._loading:  # another thread is loading the kernel
        np.testing.assert_array_equal(rgb_to_grey(rgb), rgb_to_grey_reference(rgb))
    assert calls == []
    np.testing.assert_array_equal(rgb_to_grey(rgb), rgb_to_grey_reference(rgb))  # this thread loads it
    assert calls == [(6, 7, 3)]
    assert not images._loading.locked()


def _with_ihdr(data: bytes, **fields: int) -> bytes:
    """A PNG with IHDR fields (height, interlace) changed and its CRC made right again."""
    w, h, depth, colour, comp, filt, inter = struct.unpack(">IIBBBBB", data[16:29])
    h, inter = fields.get("height", h), fields.get("interlace", inter)
    body = b"IHDR" + struct.pack(">IIBBBBB", w, h, depth, colour, comp, filt, inter)
    return data[:12] + body + struct.pack(">I", zlib.crc32(body)) + data[33:]


def _grey_of(data: bytes) -> np.ndarray | None:
    return png.plain_png_grey(data, rgb_to_grey)


def _stored_pixels_equal(data: bytes) -> bool:
    stored = png.stored_png(data)
    assert stored is not None
    return bool(np.array_equal(imagecodecs.png_decode(bytes(stored[0])), imagecodecs.png_decode(data)))


@pytest.mark.parametrize("channels", [1, 3])
@pytest.mark.parametrize("compression", [0, 1, 9])
def test_the_rows_stored_uncompressed_decode_to_the_same_pixels(channels, compression):
    # Taller than one stored block (65535 bytes) and with every row filter libpng picks.
    img = _textured(np.random.default_rng(7), 150, 230, channels)
    img[:40] = 100
    data = _png(img, cv2.IMWRITE_PNG_COMPRESSION, compression)
    assert _stored_pixels_equal(data)
    assert _stored_pixels_equal(_with_chunk_after_ihdr(data, b"tEXt", b"Software\x00rigcal"))


def test_pngs_not_rewritten_are_decoded_as_they_are(tmp_path):
    img = _textured(np.random.default_rng(8), 30, 40, 3)
    good = _png(img)
    iend = good.rindex(b"IEND") - 4
    text = struct.pack(">I", 4) + b"tEXt" + b"a\x00bc" + struct.pack(">I", zlib.crc32(b"tEXta\x00bc"))
    damaged = bytearray(good)
    damaged[60] ^= 0xFF  # in the IDAT: its CRC is wrong
    cases = {
        "chunk after the data": good[:iend] + text + good[iend:],
        "bytes after IEND": good + b"\x00",
        "interlaced": _with_ihdr(good, interlace=1),
        "taller than its data": _with_ihdr(good, height=31),
        "shorter than its data": _with_ihdr(good, height=29),
        "damaged data": bytes(damaged),
        "IHDR not first": good[:8] + text + good[8:],
    }
    for name, data in cases.items():
        assert png.stored_png(data) is None, name
        path = tmp_path / "f.png"
        path.write_bytes(data)
        expected = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
        got = read_grey(path)
        assert (got is None and expected is None) or np.array_equal(got, expected), name
    np.testing.assert_array_equal(_grey_of(good[:iend] + text + good[iend:]), rgb_to_grey(img[..., ::-1]))


def test_frames_decoded_one_after_another_keep_their_own_levels():
    """The colour image and the stored PNG are buffers each thread reuses: a frame's grey
    levels are an array of its own."""
    rng = np.random.default_rng(9)
    a, b = _textured(rng, 20, 30, 3), _textured(rng, 20, 30, 3)
    ga = _grey_of(_png(a))
    gb = _grey_of(_png(b))
    assert ga is not None
    assert gb is not None
    np.testing.assert_array_equal(ga, rgb_to_grey(np.ascontiguousarray(a[..., ::-1])))
    np.testing.assert_array_equal(gb, rgb_to_grey(np.ascontiguousarray(b[..., ::-1])))
    assert png.stored_png(_png(a)) is not None
