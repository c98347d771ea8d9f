"""PCD sweeps as scans: each return at its own angle, clockwise uneven sweeps, no-return
points, the three DATA forms, and every error path."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from rigcal.errors import InputError
from rigcal.io.pcd import lzf_decompress, read_pcd_scan
from rigcal.scan import read_scan


def sweep(rng: np.random.Generator, n: int = 400) -> np.ndarray:
    """(n, 3) a 360 deg sweep stored clockwise, beams up to 1.9 deg off an even grid, every
    tenth point no return (0 0 0)."""
    step = 2 * np.pi / n
    angles = np.pi - step * np.arange(n) - rng.uniform(-0.45, 0.45, n) * step  # clockwise
    angles[::37] += np.radians(1.9) * np.sign(rng.normal(size=len(angles[::37])))
    ranges = rng.uniform(0.5, 6.0, n)
    xyz = np.column_stack([ranges * np.cos(angles), ranges * np.sin(angles), np.zeros(n)])
    xyz[::10] = 0.0
    return xyz


def header(
    n: int, data: str, fields: str = "x y z intensity", size: str = "4 4 4 4", type_: str = "F F F F"
) -> str:
    count = " ".join("1" for _ in fields.split())
    return (
        "# .PCD v0.7 - Point Cloud Data file format\nVERSION 0.7\n"
        f"FIELDS {fields}\nSIZE {size}\nTYPE {type_}\nCOUNT {count}\nWIDTH {n}\nHEIGHT 1\n"
        f"VIEWPOINT 0 0 0 1 0 0 0\nPOINTS {n}\nDATA {data}\n"
    )


def write_ascii(path: Path, xyz: np.ndarray) -> Path:
    rows = "".join(f"{float(x)!r} {float(y)!r} {float(z)!r} 100\n" for x, y, z in xyz)
    path.write_text(header(len(xyz), "ascii") + rows)
    return path


def records(xyz: np.ndarray) -> np.ndarray:
    dt = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("i", "<f4")])
    rec = np.zeros(len(xyz), dtype=dt)
    rec["x"], rec["y"], rec["z"], rec["i"] = xyz[:, 0], xyz[:, 1], xyz[:, 2], 7.0
    return rec


def write_binary(path: Path, xyz: np.ndarray) -> Path:
    path.write_bytes(header(len(xyz), "binary").encode() + records(xyz).tobytes())
    return path


def lzf_literals(raw: bytes) -> bytes:
    """LZF data of literal runs only (a valid stream that any decoder reads)."""
    out = bytearray()
    for k in range(0, len(raw), 32):
        chunk = raw[k : k + 32]
        out.append(len(chunk) - 1)
        out += chunk
    return bytes(out)


def write_compressed(path: Path, xyz: np.ndarray) -> Path:
    rec = records(xyz)
    raw = b"".join(np.ascontiguousarray(rec[f]).tobytes() for f in ("x", "y", "z", "i"))
    packed = lzf_literals(raw)
    sizes = np.array([len(packed), len(raw)], dtype="<u4").tobytes()
    path.write_bytes(header(len(xyz), "binary_compressed").encode() + sizes + packed)
    return path


@pytest.mark.parametrize("writer", [write_ascii, write_binary, write_compressed])
def test_each_return_keeps_its_own_angle(tmp_path: Path, writer) -> None:
    rng = np.random.default_rng(3)
    xyz = sweep(rng)
    scan = read_scan(writer(tmp_path / "s.pcd", xyz))
    tol = 1e-12 if writer is write_ascii else 1e-6
    ok = np.abs(xyz[:, :2]).sum(axis=1) > 0
    # Every valid return comes back at its own point (no resampling to a grid), counter-clockwise.
    assert scan.valid.sum() == ok.sum()
    assert np.all(np.diff(scan.angles_rad) > 0)
    want = xyz[ok, :2][np.argsort(np.arctan2(xyz[ok, 1], xyz[ok, 0]))]
    assert np.allclose(scan.points[scan.valid], want, atol=tol * 10)
    # The no-return points stay as invalid beams between their neighbours.
    assert (~scan.valid).sum() == (~ok).sum()
    assert scan.angle_increment_rad is None
    steps = np.degrees(np.diff(scan.angles_rad[scan.valid]))
    assert steps.max() - steps.min() > 1.9  # the uneven spacing survives


def test_lzf_back_reference() -> None:
    assert lzf_decompress(b"\x02abc" + bytes([0x20, 2]), 6) == b"abcabc"
    assert lzf_decompress(b"\x02abc" + bytes([0xE0, 1, 2]), 3 + 10) == b"abc" + b"abcabcabca"
    assert lzf_decompress(b"\x02abc" + bytes([0x20, 9]), 6) is None  # before the start
    assert lzf_decompress(b"\x05ab", 6) is None  # a literal run past the end


def test_points_off_the_plane_are_refused(tmp_path: Path) -> None:
    xyz = sweep(np.random.default_rng(1), 50)
    xyz[3, 2] = 0.4
    with pytest.raises(InputError, match=r"s.pcd: point 3: z: got 0.4; expected \|z\| <= 0.01 m"):
        read_scan(write_ascii(tmp_path / "s.pcd", xyz))


def test_two_returns_at_one_angle_are_refused(tmp_path: Path) -> None:
    xyz = sweep(np.random.default_rng(1), 50)
    xyz[5] = 2.0 * xyz[4]
    with pytest.raises(
        InputError, match=r"points 4 and 5: got 'angle .* deg'; expected one return per angle"
    ):
        read_scan(write_ascii(tmp_path / "s.pcd", xyz))


def _broken(tmp_path: Path, text: str | bytes) -> Path:
    p = tmp_path / "b.pcd"
    if isinstance(text, str):
        p.write_text(text)
    else:
        p.write_bytes(text)
    return p


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("VERSION 0.7\nFOO 1\n", r"line 2: got 'FOO 1'; expected a PCD header line"),
        (
            header(2, "ascii", "x y intensity", "4 4 4", "F F F") + "1 2 3\n4 5 6\n",
            r"FIELDS: got 'x y intensity'; expected the fields x, y and z",
        ),
        (
            header(2, "ascii", size="4 4 2 4") + "1 2 0 1\n4 5 0 1\n",
            r"line 5: field z: got TYPE F SIZE 2; expected F with SIZE 4 or 8",
        ),
        (header(2, "ascii", type_="F F X F") + "1 2 0 1\n4 5 0 1\n", r"field z: got TYPE X SIZE 4"),
        (
            header(2, "lzma") + "1 2 0 1\n",
            r"line 11: DATA: got 'lzma'; expected ascii, binary or binary_compressed",
        ),
        (
            header(2, "ascii").replace("POINTS 2", "POINTS 3"),
            r"line 10: POINTS: got 3; expected WIDTH x HEIGHT = 2",
        ),
        (
            header(2, "ascii").replace("WIDTH 2", "WIDTH two"),
            r"line 7: WIDTH: got 'two'; expected a whole number",
        ),
        (header(2, "ascii") + "1 2 0 1\n", r"got 1 point lines after DATA ascii; expected POINTS = 2"),
        (header(2, "ascii") + "1 2 0 1\n4 oops 0 1\n", r"line 13: y: got 'oops'; expected a number"),
        (header(2, "ascii") + "1 2 0 1\n4 5 0\n", r"line 13: got 3 values; expected 4 \(x y z intensity\)"),
        (
            header(2, "ascii") + "0 0 0 1\n4 5 0 1\n",
            r"got 1 valid points of 2; expected a sweep with returns",
        ),
        ("VERSION 0.7\nFIELDS x y z\n", r"DATA: missing"),
        ("VERSION 0.7\nDATA ascii\n", r"FIELDS: missing from the PCD header"),
        ("VERSION 0.7\nVERSION 0.7\n", r"line 2: VERSION: given twice"),
        (
            header(2, "binary").encode() + b"\0" * 20,
            r"DATA binary: got 20 bytes of points; expected POINTS x record size = 2 x 16 = 32",
        ),
        (header(2, "binary_compressed").encode() + b"\0" * 4, r"DATA binary_compressed: got 4 bytes"),
        (
            header(2, "binary_compressed").encode() + np.array([4, 99], dtype="<u4").tobytes() + b"\3abcd",
            r"got sizes 4 \(compressed, 5 present\) and 99 \(raw\); expected a raw size of 32",
        ),
        (
            header(1, "binary_compressed").encode() + np.array([2, 16], dtype="<u4").tobytes() + b"\x20\x05",
            r"the LZF data is corrupt",
        ),
        (b"\xff\xfe\x00binary junk", r"line 1: got bytes that are not text; expected a PCD header line"),
    ],
)
def test_broken_files_name_line_field_and_value(tmp_path: Path, text: str | bytes, message: str) -> None:
    with pytest.raises(InputError, match=message):
        read_pcd_scan(_broken(tmp_path, text))


def test_missing_file(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="PCD scan not found"):
        read_scan(tmp_path / "none.pcd")
    (tmp_path / "d.pcd").mkdir()
    with pytest.raises(InputError, match="got a folder"):
        read_scan(tmp_path / "d.pcd")
