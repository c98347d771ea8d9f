"""PCD point-cloud files (PCL's format) holding one sweep of a 2D scanner.

Some scanner drivers and recording tools save each sweep as a ``.pcd`` file: a text
header (``VERSION``, ``FIELDS``, ``SIZE``, ``TYPE``, ``COUNT``, ``WIDTH``, ``HEIGHT``,
``VIEWPOINT``, ``POINTS``, ``DATA``), then the points as text (``DATA ascii``), packed
records (``DATA binary``) or LZF-compressed columns (``DATA binary_compressed``). Only
the fields ``x``, ``y`` and ``z`` are read (metres, laser frame); other fields are
skipped. A point stored as ``0 0 0`` (or NaN) is no return.

Each return keeps its own angle, ``atan2(y, x)``: such sweeps are often stored clockwise
and with unevenly spaced beams (a spinning scanner's beams drift up to about 2 deg off an
even grid), so they are never converted to an ``angle_min`` / ``angle_increment`` grid.
No-return points have no angle of their own: each gets one between its valid neighbours
in the file's order, so that it stays in its place in the sweep (a gap that line
extraction does not bridge). The result is ordered by angle, counter-clockwise
(docs/formats/scan.md, "PCD scans").
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from rigcal.arrays import FloatArray
from rigcal.errors import InputError
from rigcal.io.files import read_bytes, text_lines

# The x, y, z of a 2D scan lie in its plane: |z| above this is a 3D cloud or a scan
# moved into another frame.
MAX_ABS_Z_M = 0.01
# No header is longer than this (a PCD header is about a dozen short lines).
_MAX_HEADER_LINES = 64
_HEADER_KEYS = (
    "VERSION",
    "FIELDS",
    "SIZE",
    "TYPE",
    "COUNT",
    "WIDTH",
    "HEIGHT",
    "VIEWPOINT",
    "POINTS",
    "DATA",
)
_DATA_FORMS = ("ascii", "binary", "binary_compressed")
# numpy dtypes for PCD's TYPE (F, I, U) and SIZE (bytes), little-endian as PCL writes.
_DTYPES = {
    ("F", 4): "<f4",
    ("F", 8): "<f8",
    ("I", 1): "i1",
    ("I", 2): "<i2",
    ("I", 4): "<i4",
    ("I", 8): "<i8",
    ("U", 1): "u1",
    ("U", 2): "<u2",
    ("U", 4): "<u4",
    ("U", 8): "<u8",
}


@dataclass(frozen=True)
class PcdScan:
    """A PCD sweep as a 2D scan's beams, ordered by angle.

    Attributes:
        angles_rad: (N,) each return's own angle atan2(y, x), strictly increasing
            (no-return points: an angle between their valid neighbours').
        ranges_m: (N,) hypot(x, y), 0 for no return.
        file_index: (N,) each beam's point index in the file.
    """

    angles_rad: FloatArray
    ranges_m: FloatArray
    file_index: NDArray[np.int64]


def read_pcd_scan(path: str | Path) -> PcdScan:
    """Read a PCD file of one 2D sweep (module docstring).

    Raises:
        InputError: unreadable file; a header line missing, out of order or malformed
            (naming the line and value); no x, y or z field, or one whose type, size or
            count rigcal does not read; data shorter than the header says; a point with
            |z| > MAX_ABS_Z_M; two returns at one angle; fewer than 2 valid returns.
    """
    path = Path(path)
    raw = read_bytes(path, "PCD scan")
    header, body, data_line = _header(path, raw)
    fields = header["FIELDS"]
    n = len(fields)
    sizes = _ints(path, header, "SIZE", n)
    types = header["TYPE"]
    if len(types) != n:
        raise InputError(
            f"{path}: line {header['_line']['TYPE']}: TYPE: got {len(types)} types; expected {n}"
        )
    counts = _ints(path, header, "COUNT", n) if "COUNT" in header else [1] * n
    width, height = _ints(path, header, "WIDTH", 1)[0], _ints(path, header, "HEIGHT", 1)[0]
    points = _ints(path, header, "POINTS", 1)[0]
    if points != width * height:
        raise InputError(
            f"{path}: line {header['_line']['POINTS']}: POINTS: got {points}; expected WIDTH x HEIGHT "
            f"= {width * height}"
        )
    columns: list[str] = []
    for name, ty, size, count in zip(fields, types, sizes, counts, strict=True):
        if (ty, size) not in _DTYPES:
            raise InputError(
                f"{path}: line {header['_line']['TYPE']}: field {name}: got TYPE {ty} SIZE {size}; "
                "expected F with SIZE 4 or 8, or I/U with SIZE 1, 2, 4 or 8"
            )
        if count < 1:
            raise InputError(
                f"{path}: line {header['_line']['COUNT']}: field {name}: got COUNT {count}; expected >= 1"
            )
        columns += [name] * count
    for axis in ("x", "y", "z"):
        if axis not in fields:
            raise InputError(
                f"{path}: line {header['_line']['FIELDS']}: FIELDS: got {' '.join(fields)!r}; "
                "expected the fields x, y and z"
            )
        k = fields.index(axis)
        if counts[k] != 1:
            raise InputError(
                f"{path}: line {header['_line']['COUNT']}: field {axis}: got COUNT {counts[k]}; expected 1"
            )
    form = header["DATA"][0]
    dtypes = [
        (f"f{j}", _DTYPES[(ty, size)])
        for j, (ty, size, count) in enumerate(zip(types, sizes, counts, strict=True))
        for _ in range(count)
    ]
    if form == "ascii":
        xyz = _ascii(path, body, data_line, columns, points, fields)
    elif form == "binary":
        xyz = _binary(path, body, dtypes, columns, points)
    else:
        xyz = _compressed(path, body, dtypes, columns, points)
    return _sweep(path, xyz)


def _header(path: Path, raw: bytes) -> tuple[dict[str, Any], bytes, int]:
    """The header's entries (each a list of words; ``_line`` maps each key to its line
    number), the bytes after the DATA line, and the DATA line's number."""
    header: dict[str, Any] = {"_line": {}}
    pos = 0
    expected = list(_HEADER_KEYS)
    for line_no in range(1, _MAX_HEADER_LINES + 1):
        end = raw.find(b"\n", pos)
        if end < 0:
            end = len(raw)
        try:
            line = raw[pos:end].decode("ascii").strip()
        except UnicodeDecodeError:
            raise InputError(
                f"{path}: line {line_no}: got bytes that are not text; expected a PCD header line "
                f"({expected[0] if expected else 'DATA'} ...); is this a PCD file?"
            ) from None
        pos = end + 1
        if not line or line.startswith("#"):
            if end >= len(raw):
                break
            continue
        key, *words = line.split()
        if key not in _HEADER_KEYS:
            raise InputError(
                f"{path}: line {line_no}: got {line[:40]!r}; expected a PCD header line "
                f"({', '.join(_HEADER_KEYS)})"
            )
        if key in header:
            raise InputError(f"{path}: line {line_no}: {key}: given twice")
        if not words:
            raise InputError(f"{path}: line {line_no}: {key}: got no value")
        header[key] = words
        header["_line"][key] = line_no
        if key == "DATA":
            if words[0] not in _DATA_FORMS:
                raise InputError(
                    f"{path}: line {line_no}: DATA: got {words[0]!r}; expected ascii, binary or "
                    "binary_compressed"
                )
            for need in ("FIELDS", "SIZE", "TYPE", "WIDTH", "HEIGHT", "POINTS"):
                if need not in header:
                    raise InputError(
                        f"{path}: {need}: missing from the PCD header (before DATA, line {line_no})"
                    )
            return header, raw[pos:], line_no
        if end >= len(raw):
            break
    raise InputError(
        f"{path}: DATA: missing; expected a PCD header ending in 'DATA ascii|binary|binary_compressed'"
    )


def _ints(path: Path, header: dict[str, Any], key: str, n: int) -> list[int]:
    words = header[key]
    line = header["_line"][key]
    if len(words) != n:
        raise InputError(f"{path}: line {line}: {key}: got {len(words)} values; expected {n}")
    out = []
    for w in words:
        try:
            v = int(w)
        except ValueError:
            raise InputError(f"{path}: line {line}: {key}: got {w!r}; expected a whole number") from None
        if v < 0:
            raise InputError(f"{path}: line {line}: {key}: got {v}; expected a number >= 0")
        out.append(v)
    return out


def _ascii(
    path: Path, body: bytes, data_line: int, columns: list[str], points: int, fields: list[str]
) -> FloatArray:
    text = text_lines(body.decode("ascii", errors="replace"))
    rows = [(k, ln) for k, ln in enumerate(text) if ln.strip()]
    if len(rows) != points:
        raise InputError(f"{path}: got {len(rows)} point lines after DATA ascii; expected POINTS = {points}")
    idx = [columns.index(a) for a in ("x", "y", "z")]
    out = np.empty((points, 3))
    for j, (k, ln) in enumerate(rows):
        words = ln.split()
        where = f"{path}: line {data_line + 1 + k}"
        if len(words) != len(columns):
            raise InputError(
                f"{where}: got {len(words)} values; expected {len(columns)} ({' '.join(fields)})"
            )
        for c, i in enumerate(idx):
            try:
                out[j, c] = float(words[i])
            except ValueError:
                raise InputError(f"{where}: {'xyz'[c]}: got {words[i]!r}; expected a number") from None
    return out


def _binary(
    path: Path, body: bytes, dtypes: list[tuple[str, str]], columns: list[str], points: int
) -> FloatArray:
    dt = np.dtype(dtypes)
    need = dt.itemsize * points
    if len(body) < need:
        raise InputError(
            f"{path}: DATA binary: got {len(body)} bytes of points; expected POINTS x record size = "
            f"{points} x {dt.itemsize} = {need}"
        )
    rec = np.frombuffer(body[:need], dtype=dt, count=points)
    return np.column_stack([rec[f"f{columns.index(a)}"].astype(np.float64) for a in ("x", "y", "z")])


def _compressed(
    path: Path, body: bytes, dtypes: list[tuple[str, str]], columns: list[str], points: int
) -> FloatArray:
    """binary_compressed: two uint32 (compressed and raw sizes), then LZF data holding
    each field's values for all points, field after field."""
    if len(body) < 8:
        raise InputError(
            f"{path}: DATA binary_compressed: got {len(body)} bytes; expected the two sizes and data"
        )
    packed, size = (int(x) for x in np.frombuffer(body[:8], dtype="<u4"))
    need = sum(np.dtype(t).itemsize for _, t in dtypes) * points
    if size != need or len(body) < 8 + packed:
        raise InputError(
            f"{path}: DATA binary_compressed: got sizes {packed} (compressed, {len(body) - 8} present) and "
            f"{size} (raw); expected a raw size of {need} for {points} points"
        )
    raw = lzf_decompress(body[8 : 8 + packed], size)
    if raw is None:
        raise InputError(f"{path}: DATA binary_compressed: the LZF data is corrupt")
    cols = []
    offset = 0
    for _, t in dtypes:
        width = np.dtype(t).itemsize * points
        cols.append(np.frombuffer(raw[offset : offset + width], dtype=t, count=points))
        offset += width
    return np.column_stack([cols[columns.index(a)].astype(np.float64) for a in ("x", "y", "z")])


def lzf_decompress(data: bytes, size: int) -> bytes | None:
    """LZF (liblzf, as PCL uses it) decompressed to ``size`` bytes; None when the data is
    corrupt (a back reference before the start, or a length other than ``size``)."""
    out = bytearray()
    i = 0
    n = len(data)
    while i < n:
        ctrl = data[i]
        i += 1
        if ctrl < 32:  # a literal run of ctrl + 1 bytes
            run = ctrl + 1
            if i + run > n:
                return None
            out += data[i : i + run]
            i += run
            continue
        length = ctrl >> 5
        if length == 7:
            if i >= n:
                return None
            length += data[i]
            i += 1
        if i >= n:
            return None
        ref = len(out) - ((ctrl & 0x1F) << 8) - data[i] - 1
        i += 1
        if ref < 0:
            return None
        for _ in range(length + 2):  # back references may overlap what they write
            out.append(out[ref])
            ref += 1
        if len(out) > size:
            return None
    return bytes(out) if len(out) == size else None


def _sweep(path: Path, xyz: FloatArray) -> PcdScan:
    """The points as beams: own angles, ranges, no-return points placed between their
    neighbours, ordered by angle."""
    finite = np.isfinite(xyz).all(axis=1)
    valid = finite & (np.abs(xyz[:, :2]).sum(axis=1) > 0)
    bad_z = np.flatnonzero(valid & (np.abs(np.where(finite, xyz[:, 2], 0.0)) > MAX_ABS_Z_M))
    if len(bad_z):
        j = int(bad_z[0])
        raise InputError.at(
            path,
            f"point {j}: z",
            float(xyz[j, 2]),
            f"|z| <= {MAX_ABS_Z_M:g} m: a 2D scan's points in its own plane (is this a 3D cloud, "
            "or a scan moved into another frame?)",
        )
    good = np.flatnonzero(valid)
    if len(good) < 2:
        raise InputError(f"{path}: got {len(good)} valid points of {len(xyz)}; expected a sweep with returns")
    angles = np.full(len(xyz), np.nan)
    angles[good] = np.arctan2(xyz[good, 1], xyz[good, 0])
    ranges = np.zeros(len(xyz))
    ranges[good] = np.hypot(xyz[good, 0], xyz[good, 1])
    # A no-return point sits between its valid neighbours in the file: its angle is
    # interpolated along the file's order on the unwrapped angles of the valid ones.
    unwrapped = np.unwrap(angles[good])
    index = np.arange(len(xyz))
    filled = np.interp(index, good, unwrapped)
    # Before the first and after the last valid return: on at the sweep's median step.
    step = float(np.median(np.diff(unwrapped) / np.diff(good)))
    filled = np.where(index < good[0], unwrapped[0] + (index - good[0]) * step, filled)
    filled = np.where(index > good[-1], unwrapped[-1] + (index - good[-1]) * step, filled)
    angles = np.where(valid, angles, np.angle(np.exp(1j * filled)))
    order = np.lexsort((~valid, angles))  # by angle; at a tie the valid return first
    a, r, v = angles[order], ranges[order], valid[order]
    keep = np.ones(len(a), dtype=bool)
    same = np.flatnonzero(np.diff(a) <= 0) + 1
    for k in same:
        if v[k] and v[k - 1]:
            i, j = sorted((int(order[k - 1]), int(order[k])))
            raise InputError.at(
                path,
                f"points {i} and {j}",
                f"angle {math.degrees(float(a[k])):.6f} deg",
                "one return per angle (a sweep saved twice, or a 3D cloud?)",
            )
        keep[k] = False  # a no-return point at a taken angle adds nothing
    return PcdScan(a[keep], r[keep], order[keep].astype(np.int64))
