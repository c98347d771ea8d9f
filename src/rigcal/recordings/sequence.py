"""Sequence folders: time-stamped scans and images of a drive (docs/formats/sequence.md).

The input of the localization pipeline and the output of ``rigcal import-bag``::

    SEQUENCE/
      sequence.yaml     schema_version, name, where it came from, the streams
      scans.npz         every scan: stamps_s (N,), ranges_m (N, B) (NaN-padded),
                        n_beams, angle_min_rad, angle_increment_rad, range_min_m, range_max_m (N,)
      images/           one image file per frame
      images.csv        stamp_s,file per line, in time order
      camera.yaml       the camera, when the source had it (rigcal camera file)
      rig.yaml          the rig, when known (rig file)
      groundtruth.tum   the laser's true poses in the world, when known (simulations)
      odometry.tum      the robot base's wheel odometry, when the log has it (schema 3)
      gyro.csv          the gyroscope's yaw rate, when the log has it (schema 4)

Stamps are seconds, increasing within each stream. :func:`write_sequence` writes a whole
folder atomically; :func:`read_sequence` validates it.
"""

from __future__ import annotations

import contextlib
import posixpath
import zipfile
import zlib
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from functools import cached_property, partial
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from rigcal.arrays import FloatArray
from rigcal.errors import InputError
from rigcal.io.files import atomic_folder, check_keys, csv_fields, load_yaml, read_text, text_lines
from rigcal.io.gyro import Gyro, gyro_csv, read_gyro_csv
from rigcal.io.kinds import kind_of_bytes
from rigcal.io.stamps import check_seconds
from rigcal.io.validate import finite_array, parse_real, real, relative_inside, whole
from rigcal.io.wheel_odometry import WheelOdometry, odometry_tum, read_odometry_tum
from rigcal.scan import Scan, ScanArrayError, laser_clockwise, uniform_scans

ImagesKnown = Callable[[Path, FloatArray, list[str]], None]
"""A :func:`read_sequence` callback: the images' folder, stamps (s) and file names."""

SEQUENCE_SCHEMA_VERSION = 1
# Written when the folder keeps wheel odometry (its ``odometry`` mapping).
SEQUENCE_SCHEMA_VERSION_ODOMETRY = 3
# Written when the folder keeps a gyroscope (its ``gyro`` mapping).
SEQUENCE_SCHEMA_VERSION_GYRO = 4
# Versions read: 2 adds the optional ``laser: {clockwise: BOOL}`` mapping, 3 the optional
# ``odometry: {file, T_base_laser}`` (rigcal.io.wheel_odometry), 4 the optional
# ``gyro: {file}`` (rigcal.io.gyro).
SEQUENCE_SCHEMA_VERSIONS = (1, 2, 3, 4)
SCAN_KEYS = (
    "stamps_s",
    "ranges_m",
    "n_beams",
    "angle_min_rad",
    "angle_increment_rad",
    "range_min_m",
    "range_max_m",
)


@dataclass(frozen=True)
class ImageFrame:
    """One image: its stamp (s), its file name inside images/, and its encoded bytes."""

    stamp_s: float
    name: str
    data: bytes = field(repr=False)


@dataclass(frozen=True)
class Sequence:
    """A sequence in memory (as read: image bytes are not loaded).

    The wheel odometry's file (odometry.tum) is read when :attr:`odometry` is first asked
    for, not by :func:`read_sequence`: a run that does not use it (``rigcal localize
    --wheel-odometry ignore``) goes on whatever that file holds.
    """

    folder: Path | None
    name: str
    scans: tuple[Scan, ...]
    image_stamps_s: FloatArray
    image_files: tuple[str, ...]
    camera_file: str | None
    source: dict[str, Any]
    rig_file: str | None = None
    groundtruth_file: str | None = None
    odometry_reader: Callable[[], WheelOdometry] | None = field(default=None, repr=False, compare=False)
    image_folder: str = "images"  # the folder and index named in sequence.yaml's ``images``
    image_index: str = "images.csv"
    gyro_reader: Callable[[], Gyro] | None = field(default=None, repr=False, compare=False)

    @property
    def has_odometry(self) -> bool:
        """Whether sequence.yaml names wheel odometry (without reading its file)."""
        return self.odometry_reader is not None

    @cached_property
    def odometry(self) -> WheelOdometry | None:
        """The wheel odometry, read and checked against the scans on first use.

        Raises:
            InputError: its file is missing or malformed, naming the file, line and value.
        """
        return None if self.odometry_reader is None else self.odometry_reader()

    @property
    def has_gyro(self) -> bool:
        """Whether sequence.yaml names a gyroscope (without reading its file)."""
        return self.gyro_reader is not None

    @cached_property
    def gyro(self) -> Gyro | None:
        """The gyroscope, read and checked against the scans on first use (as :attr:`odometry`).

        Raises:
            InputError: its file is missing or malformed, naming the file, line and value.
        """
        return None if self.gyro_reader is None else self.gyro_reader()


def write_sequence(
    folder: str | Path,
    name: str,
    scans: list[Scan],
    images: Iterable[ImageFrame],
    camera_yaml: str | None,
    source: dict[str, Any],
    force: bool = False,
    groundtruth_tum: str | None = None,
    rig_yaml: str | None = None,
    odometry: WheelOdometry | None = None,
    gyro: Gyro | None = None,
) -> Path:
    """Write a sequence folder atomically (refuses an existing folder unless ``force``).

    ``groundtruth_tum`` (the laser's poses in the world, TUM text) and ``rig_yaml`` (a rig
    file's text) are written when given, and so is ``odometry`` (odometry.tum and its
    mounting; schema 3) and ``gyro`` (gyro.csv; schema 4). ``images`` may be a
    generator: each frame is written as it comes.
    """
    B = max((len(s.ranges_m) for s in scans), default=0)
    ranges = np.full((len(scans), B), np.nan)
    for i, s in enumerate(scans):
        ranges[i, : len(s.ranges_m)] = s.ranges_m
    arrays = {
        "stamps_s": np.array([s.stamp_s if s.stamp_s is not None else np.nan for s in scans]),
        "ranges_m": ranges,
        "n_beams": np.array([len(s.ranges_m) for s in scans], dtype=np.int64),
        "angle_min_rad": np.array([s.angles_rad[0] for s in scans]),
        "angle_increment_rad": np.array([s.angle_increment_rad or 0.0 for s in scans]),
        "range_min_m": np.array([s.range_min_m for s in scans]),
        "range_max_m": np.array([s.range_max_m for s in scans]),
    }
    doc: dict[str, Any] = {
        "schema_version": SEQUENCE_SCHEMA_VERSION,
        "name": name,
        "source": source,
        "scans": {"file": "scans.npz", "count": len(scans)},
        "images": {"folder": "images", "index": "images.csv", "count": 0},
    }
    if camera_yaml is not None:
        doc["camera"] = "camera.yaml"
    if rig_yaml is not None:
        doc["rig"] = "rig.yaml"
    if groundtruth_tum is not None:
        doc["groundtruth"] = "groundtruth.tum"
    if odometry is not None:
        doc["schema_version"] = SEQUENCE_SCHEMA_VERSION_ODOMETRY
        doc["odometry"] = {"file": "odometry.tum", "T_base_laser": [float(v) for v in odometry.T_base_laser]}
    if gyro is not None:
        doc["schema_version"] = SEQUENCE_SCHEMA_VERSION_GYRO
        doc["gyro"] = {"file": "gyro.csv"}
    with atomic_folder(folder, force) as tmp:
        np.savez_compressed(tmp / "scans.npz", **arrays)  # type: ignore[arg-type]
        (tmp / "images").mkdir()
        rows = []
        for im in images:
            (tmp / "images" / im.name).write_bytes(im.data)
            rows.append(f"{im.stamp_s!r},{im.name}")
        doc["images"]["count"] = len(rows)
        (tmp / "images.csv").write_text("stamp_s,file\n" + "".join(r + "\n" for r in rows), encoding="utf-8")
        if camera_yaml is not None:
            (tmp / "camera.yaml").write_text(camera_yaml, encoding="utf-8")
        if rig_yaml is not None:
            (tmp / "rig.yaml").write_text(rig_yaml, encoding="utf-8")
        if groundtruth_tum is not None:
            (tmp / "groundtruth.tum").write_text(groundtruth_tum, encoding="utf-8")
        if odometry is not None:
            (tmp / "odometry.tum").write_text(odometry_tum(odometry), encoding="utf-8")
        if gyro is not None:
            (tmp / "gyro.csv").write_text(gyro_csv(gyro), encoding="utf-8")
        (tmp / "sequence.yaml").write_text(
            "# rigcal sequence (docs/formats/sequence.md)\n" + yaml.safe_dump(doc, sort_keys=False),
            encoding="utf-8",
        )
    return Path(folder)


def read_sequence(folder: str | Path, on_images: ImagesKnown | None = None) -> Sequence:
    """Read and validate a sequence folder.

    Args:
        on_images: called with the images' folder, stamps and file names as soon as the
            image index is read, before the scans (a caller may start decoding frames
            while the scans are read); not called when the index is unreadable (its error
            is raised where it always is, after the scans').

    Raises:
        InputError: a missing or malformed file, naming it and the key or line.
    """
    folder = Path(folder)
    path = folder / "sequence.yaml"
    if folder.is_file():  # sequence.yaml or scans.npz given for its folder, or another file
        hint = f" ({folder.parent}?)" if (folder.parent / "sequence.yaml").is_file() else ""
        raise InputError(f"{folder}: got a file; expected a sequence folder{hint}, holding sequence.yaml")
    if not folder.exists():
        raise InputError(f"{folder}: not found; expected a sequence folder holding sequence.yaml")
    d = check_keys(
        load_yaml(path, "sequence file"),
        path,
        "",
        ["schema_version", "name", "scans", "images"],
        ["source", "camera", "rig", "groundtruth", "laser", "odometry", "gyro"],
        SEQUENCE_SCHEMA_VERSIONS,
    )
    clockwise = laser_clockwise(d, path, SEQUENCE_SCHEMA_VERSIONS, since=2)
    if not isinstance(d["name"], str):
        raise InputError.at(path, "name", d["name"], "a string (the recording's name)")
    if not isinstance(d.get("source") or {}, dict):
        raise InputError.at(path, "source", d["source"], "a mapping (where the sequence came from)")
    if on_images is not None:
        with contextlib.suppress(InputError):  # raised below, in its usual order
            im = check_keys(d["images"], path, "images", ["folder", "index", "count"])
            index = folder / relative_inside(im["index"], path, "images.index")
            on_images(folder / relative_inside(im["folder"], path, "images.folder"), *_read_index(index))
    sc = check_keys(d["scans"], path, "scans", ["file", "count"])
    npz = folder / relative_inside(sc["file"], path, "scans.file")
    count = whole(sc["count"], path, "scans.count")
    arrays = _load_scan_arrays(npz)
    n = _check_scan_arrays(arrays, npz)
    if n != count:
        raise InputError.at(path, "scans.count", sc["count"], f"{n}, the number of scans in {npz.name}")
    st = arrays["stamps_s"]
    bad = np.flatnonzero(~np.isfinite(st) | np.r_[False, np.diff(st) <= 0])
    if len(bad):
        k = int(bad[0])
        raise InputError(
            f"{npz}: stamps_s[{k}]: got {float(st[k])!r}; expected a finite stamp after "
            f"{float(st[k - 1]) if k else '-inf'!r} (scan stamps increase)"
        )
    check_seconds(st, str(npz), "stamps_s", step="scan")
    try:
        scans = uniform_scans(
            arrays["angle_min_rad"],
            arrays["angle_increment_rad"],
            arrays["ranges_m"],
            arrays["n_beams"],
            arrays["range_min_m"],
            arrays["range_max_m"],
            arrays["stamps_s"],
            clockwise=clockwise,
        )
    except ScanArrayError as exc:  # e.g. a step so small against the first angle that the angles stall
        raise InputError.at(
            npz, f"{exc.key}[{exc.index}]", float(arrays[exc.key][exc.index]), exc.expected
        ) from None
    im = check_keys(d["images"], path, "images", ["folder", "index", "count"])
    index = folder / relative_inside(im["index"], path, "images.index")
    images = folder / relative_inside(im["folder"], path, "images.folder")
    stamps, files = _read_index(index)
    check_seconds(stamps, str(index), "stamp_s")
    if len(files) != whole(im["count"], path, "images.count"):
        raise InputError.at(path, "images.count", im["count"], f"{len(files)}, the rows of {index.name}")
    for f in files:
        if not (images / f).is_file():
            raise InputError(f"{index}: image {f} not found in {images}")
    named = {key: relative_inside(d[key], path, key) for key in ("camera", "rig", "groundtruth") if key in d}
    for key, rel in named.items():
        if not (folder / rel).is_file():
            raise InputError.at(path, key, d[key], f"a file in {folder}")
    odometry = None
    if "odometry" in d:
        odometry = _odometry_reader(folder, path, d, np.array([s.stamp_s for s in scans], dtype=float))
    gyro = None
    if "gyro" in d:
        gyro = _gyro_reader(folder, path, d, np.array([s.stamp_s for s in scans], dtype=float))
    return Sequence(
        folder,
        str(d["name"]),
        tuple(scans),
        stamps,
        tuple(files),
        named.get("camera"),
        d.get("source", {}),
        named.get("rig"),
        named.get("groundtruth"),
        odometry,
        relative_inside(im["folder"], path, "images.folder"),
        relative_inside(im["index"], path, "images.index"),
        gyro,
    )


def _odometry_reader(
    folder: Path, path: Path, d: Mapping[str, Any], scan_stamps_s: FloatArray
) -> Callable[[], WheelOdometry]:
    """The ``odometry`` mapping (schema 3), checked now, and the reader of its TUM file
    (checked against the scans when called)."""
    if whole(d["schema_version"], path, "schema_version") < SEQUENCE_SCHEMA_VERSION_ODOMETRY:
        need = f"{SEQUENCE_SCHEMA_VERSION_ODOMETRY} for key 'odometry'"
        raise InputError.at(path, "schema_version", d["schema_version"], need)
    od = check_keys(d["odometry"], path, "odometry", ["file", "T_base_laser"])
    mount = od["T_base_laser"]
    if not isinstance(mount, list) or len(mount) != 3:
        raise InputError.at(path, "odometry.T_base_laser", mount, "[x, y, yaw] (m, m, rad)")
    xyz = [real(v, path, f"odometry.T_base_laser[{i}]") for i, v in enumerate(mount)]
    file = folder / relative_inside(od["file"], path, "odometry.file")
    return partial(_read_odometry, file, np.array(xyz), scan_stamps_s)


def _gyro_reader(
    folder: Path, path: Path, d: Mapping[str, Any], scan_stamps_s: FloatArray
) -> Callable[[], Gyro]:
    """The ``gyro`` mapping (schema 4), checked now, and the reader of its file (checked
    against the scans when called)."""
    if whole(d["schema_version"], path, "schema_version") < SEQUENCE_SCHEMA_VERSION_GYRO:
        need = f"{SEQUENCE_SCHEMA_VERSION_GYRO} for key 'gyro'"
        raise InputError.at(path, "schema_version", d["schema_version"], need)
    g = check_keys(d["gyro"], path, "gyro", ["file"])
    file = folder / relative_inside(g["file"], path, "gyro.file")
    return partial(_read_gyro, file, scan_stamps_s)


def _read_gyro(file: Path, scan_stamps_s: FloatArray) -> Gyro:
    """The sequence's gyro.csv; its error says how to go on without it."""
    try:
        return read_gyro_csv(file, scan_stamps_s)
    except InputError as exc:
        raise InputError(f"{exc} (--gyro ignore runs without it)") from None


def _read_odometry(file: Path, T_base_laser: FloatArray, scan_stamps_s: FloatArray) -> WheelOdometry:
    """The sequence's odometry.tum; its error says how to go on without it."""
    try:
        return read_odometry_tum(file, T_base_laser, scan_stamps_s)
    except InputError as exc:
        raise InputError(f"{exc} (--wheel-odometry ignore runs without it)") from None


def _load_scan_arrays(npz: Path) -> dict[str, Any]:
    """The arrays of scans.npz, or one line naming what the file or a missing or broken
    array is (a file copied while written, another tool's archive, a folder)."""
    keys = ", ".join(SCAN_KEYS)
    expected = f"a NumPy .npz archive of the scans (arrays {keys}; docs/formats/sequence.md)"
    try:
        with npz.open("rb") as f:
            head = f.read(32)
        if not zipfile.is_zipfile(npz):
            what = "an empty file" if not head else kind_of_bytes(head) or f"a file starting {head[:8]!r}"
            if head.startswith(b"PK"):
                what = "a zip archive cut short or broken (no table of contents at its end)"
            raise InputError(f"{npz}: got {what}; expected {expected}")
        with np.load(npz, allow_pickle=False) as z:
            arrays = {}
            for k in SCAN_KEYS:
                if k not in z.files:
                    has = ", ".join(sorted(z.files)[:10]) or "none"
                    why = f"got no such array (it has {has})"
                    raise InputError(f"{npz}: {k}: {why}; expected the arrays {keys}")
                try:
                    arrays[k] = np.array(z[k])
                except (ValueError, OSError, EOFError, zipfile.BadZipFile, zlib.error) as exc:
                    why = f"got an unreadable array ({exc})"
                    raise InputError(f"{npz}: {k}: {why}; expected numbers as numpy.savez writes") from None
    except FileNotFoundError:
        raise InputError(f"{npz}: scans file not found") from None
    except IsADirectoryError:
        raise InputError(f"{npz}: got a folder; expected {expected}") from None
    except (OSError, zipfile.BadZipFile) as exc:
        raise InputError(f"{npz}: cannot read the scans file: {exc}") from None
    st = arrays["stamps_s"]
    if st.dtype.kind in "iu":  # ROS and other loggers keep integer nanoseconds
        raise InputError.at(
            npz, "stamps_s", f"{st.dtype} array", "seconds as floating-point numbers (integers: nanoseconds?)"
        )
    return arrays


def _check_scan_arrays(a: dict[str, Any], npz: Path) -> int:
    """The arrays of scans.npz: shapes that agree, beam counts within the ranges' width,
    finite geometry (0 < range_min < range_max, angles within 2 pi), ranges >= 0 or NaN /
    inf (no return). Returns the number of scans."""
    r = a["ranges_m"]
    if r.ndim != 2 or r.dtype.kind not in "fiu":
        raise InputError.at(npz, "ranges_m", f"{r.dtype} array of shape {r.shape}", "numbers of shape (N, B)")
    n, width = r.shape
    for key in SCAN_KEYS[:1] + SCAN_KEYS[2:]:
        if a[key].shape != (n,) or a[key].dtype.kind not in "fiu":
            raise InputError.at(npz, key, f"{a[key].dtype} array of shape {a[key].shape}", f"{n} numbers")
    nb = a["n_beams"]
    if nb.dtype.kind not in "iu" or (len(nb) and not (nb.min() >= 1 and nb.max() <= width)):
        raise InputError.at(
            npz, "n_beams", nb[:5].tolist(), f"whole numbers from 1 to {width} (the ranges' width)"
        )
    finite_array(a["angle_min_rad"], npz, "angle_min_rad", lo=-2 * np.pi, hi=2 * np.pi)
    step = finite_array(a["angle_increment_rad"], npz, "angle_increment_rad", nonneg=True, hi=2 * np.pi)
    if ((step <= 0) & (nb > 1)).any():
        k = int(np.flatnonzero((step <= 0) & (nb > 1))[0])
        raise InputError.at(npz, f"angle_increment_rad[{k}]", float(step[k]), "a step > 0 (rad)")
    lo = finite_array(a["range_min_m"], npz, "range_min_m", nonneg=True)
    hi = finite_array(a["range_max_m"], npz, "range_max_m", positive=True)
    if (lo >= hi).any():
        k = int(np.flatnonzero(lo >= hi)[0])
        raise InputError.at(npz, f"range_min_m[{k}]", float(lo[k]), f"less than range_max_m = {hi[k]:g}")
    with np.errstate(invalid="ignore"):
        neg = r < 0
    if neg.any():
        i, j = (int(x) for x in np.argwhere(neg)[0])
        raise InputError.at(
            npz, f"ranges_m[{i}][{j}]", float(r[i, j]), "a range >= 0 (NaN or inf: no return)"
        )
    return int(n)


def _read_index(index: Path) -> tuple[FloatArray, list[str]]:
    # Blank lines (an editor's last newline) are no data; read_text drops a byte-order mark.
    lines = text_lines(read_text(index, "image index"))
    if not lines or csv_fields(lines[0]) != ["stamp_s", "file"]:
        got = lines[0][:60] if lines else ""
        raise InputError(f"{index}: line 1: got {got!r}; expected the header 'stamp_s,file'")
    stamps, files = [], []
    seen: dict[str, int] = {}
    for n, line in enumerate(lines[1:], start=2):
        if not line.strip():
            continue
        parts = csv_fields(line)  # a spreadsheet's quotes (a name holding a comma) read as CSV
        if len(parts) != 2:
            raise InputError(f"{index}: line {n}: got {line[:60]!r}; expected 'stamp_s,file'")
        stamps.append(parse_real(parts[0], index, f"line {n}: stamp_s"))
        files.append(relative_inside(parts[1], index, f"line {n}: file"))
        # One frame at two stamps would be a camera that stood still between them.
        first = seen.setdefault(posixpath.normpath(files[-1]), n)
        if first != n:
            raise InputError.at(
                index, f"line {n}: file", files[-1], f"an image no other line names (line {first} does)"
            )
        if len(stamps) > 1 and stamps[-1] <= stamps[-2]:
            raise InputError(f"{index}: line {n}: stamp {stamps[-1]!r} not after {stamps[-2]!r}")
    return np.array(stamps), files
