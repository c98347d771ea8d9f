"""Laser logs written as text by other tools, and their image lists, into sequence folders.

- **RADLOCC** ``laser.txt`` (the laser-camera calibration toolbox's log): one scan per line,
  ``stamp angle_min angle_increment angle_max range_unit_type N r_0 ... r_{N-1}`` as
  ``radlocc_collect`` writes it (unit type 3: metres, the only one read), or without the
  unit type and count, ``stamp angle_min angle_increment angle_max r_0 ...`` (seconds,
  radians, metres; whitespace or commas). The header's N is trusted (angle_max may be
  written one step off the last beam); without it ``N = round((angle_max - angle_min) /
  angle_increment) + 1``, within one step. ``nan`` / ``inf`` ranges (and those outside the
  valid interval, or equal to the scanner's no-return value when given) are no return.
- **Generic CSV**: a header naming ``stamp_s``, ``angle_rad`` (or ``angle_deg``) and
  ``range_m`` (other columns are ignored), then one row per beam; consecutive rows with the
  same stamp form a scan, their angles increasing, on one grid of beams (a gap of several
  steps: the beams between gave no return).
- **Image list**: one image per line, its stamp (seconds) and its file (relative to the
  list's folder), in either order; or RADLOCC's ``image_stamps.txt``: stamps only (one or
  two equal numbers per line), the k-th line for ``image_00k.png`` (k from 1, 3 digits or
  more, any image extension) beside it. Lines starting with ``#`` are comments.

- **Points on the board**, as MATLAB laser-camera toolboxes save a capture's selection:
  one laser return per line, ``x y`` or ``x y z`` (metres, laser frame; z, when given, is
  0: the scan plane), whitespace, comma or semicolon separated, ``%`` and ``#`` comments
  (:func:`read_board_points`; a board session's ``laser_side: {returns_file: FILE}``).

Every malformed line stops the import with the file, the line number and what was
expected (docs/formats/sequence.md), but for a log's incomplete last line (a log copied
while it was recorded), which is left out by the rule of :mod:`rigcal.io.log_lines`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from rigcal.arrays import FloatArray
from rigcal.errors import InputError
from rigcal.io.files import compressed, csv_fields, read_log_text, read_text, text_lines
from rigcal.io.images import eight_bit_pngs
from rigcal.io.log_lines import CutLine, ShortLineError, cut_last_line
from rigcal.io.stamps import StampRepair, repair_stamps
from rigcal.io.trajectory import read_tum_cut
from rigcal.io.validate import file_inside
from rigcal.io.wheel_odometry import odometry_of_tum
from rigcal.recordings.sequence import ImageFrame, write_sequence
from rigcal.scan import Scan

# RADLOCC's range unit type for metres (what radlocc_collect writes for ROS scans).
RADLOCC_METRES = 3.0


@dataclass(frozen=True)
class LaserTextSummary:
    """What an import did: the log's format, scans and images written, and whether a
    camera was written."""

    format: str
    scans: int
    images: int
    camera: bool
    stamps: StampRepair | None = None
    odometry: bool = False
    cut: CutLine | None = None
    images_cut: CutLine | None = None
    odometry_cut: CutLine | None = None
    image_stamps: StampRepair | None = None


def _fields(line: str) -> list[str]:
    return line.replace(",", " ").replace(";", " ").split()


def _log_text(path: Path, what: str) -> str:
    return read_log_text(path, what) if compressed(path) else read_text(path, what)


def _content_lines(path: Path, what: str, text: str | None = None) -> list[tuple[int, str]]:
    out = []
    text = _log_text(path, what) if text is None else text
    for n, line in enumerate(text_lines(text), start=1):
        s = line.strip()
        if s and not s.startswith(("#", "%")):
            out.append((n, s))
    if not out:
        raise InputError(f"{path}: got an empty file; expected a {what}")
    return out


# A listed point's z (the scan plane is z = 0) may be off by this much (rounding).
BOARD_POINTS_MAX_Z_M = 1e-3


def read_board_points(path: str | Path) -> FloatArray:
    """(M, 2) the laser returns on a board, one ``x y [z]`` per line (metres, laser frame).

    Raises:
        InputError: missing or unreadable, a line that is not 2 or 3 finite numbers, a z off
            the scan plane, or fewer than 2 distinct points, naming the file and line.
    """
    path = Path(path)
    what = "list of laser points on the board (x y [z] per line, metres)"
    pts = []
    for n, line in _content_lines(path, what):
        f = _fields(line)
        try:
            v = [float(x) for x in f]
        except ValueError:
            v = []
        if len(v) not in (2, 3) or not all(math.isfinite(x) for x in v):
            raise InputError(
                f"{path}: line {n}: got {line!r}; expected x y [z]: 2 or 3 finite numbers (metres)"
            )
        if len(v) == 3 and abs(v[2]) > BOARD_POINTS_MAX_Z_M:
            raise InputError(
                f"{path}: line {n}: got z = {v[2]:g}; expected 0 "
                "(a 2D scanner's returns lie in its z = 0 plane)"
            )
        pts.append(v[:2])
    if len(pts) < 2:
        raise InputError(f"{path}: got {len(pts)} point(s); expected at least 2 laser points on the board")
    out = np.array(pts, dtype=float)
    if len(np.unique(out, axis=0)) < 2:
        raise InputError(
            f"{path}: got {len(pts)} points all at ({out[0, 0]:g}, {out[0, 1]:g}); "
            "expected at least 2 distinct laser points on the board"
        )
    return out


def detect_format(path: Path) -> str:
    """``"csv"`` when the first content line is a header naming ``stamp_s``, else ``"radlocc"``."""
    first = _content_lines(path, "laser log")[0][1]
    return "csv" if "stamp_s" in [f.lower() for f in csv_fields(first)] else "radlocc"


def read_radlocc_laser(
    path: str | Path,
    range_min_m: float = 0.0,
    range_max_m: float = 80.0,
    no_return_m: float | None = None,
    stamps: str = "repair",
) -> list[Scan]:
    """Scans of a RADLOCC ``laser.txt`` (see the module docstring); ``stamps`` as
    :func:`restamped`.

    A line in radlocc_collect's form (range unit type and beam count N after the angles) is
    read by its N: the header's count is the scanner's own, while angle_max is written by
    some drivers one step short of the last beam (or one past it), so a count from the
    angles may differ from N by one step; the beams are at angle_min + i increment either
    way. The first line's form holds for the whole log.

    Args:
        no_return_m: the range the scanner writes for no return (a Hokuyo driver writes its
            maximum, e.g. 5.0); such ranges become no return. None: only nan, inf and
            ranges outside [range_min_m, range_max_m] are.

    Raises:
        InputError: a line with too few or non-numeric fields, a non-positive increment, a
            range count more than one step off the angles, a later line in the other form
            than the first, a stamp not after the previous (strict) or beyond repair.
    """
    path = Path(path)
    scans, lines, _ = _radlocc_scans(path, range_min_m, range_max_m, no_return_m, stamps == "strict")
    return restamped(scans, lines, path, stamps)[0]


def restamped(scans: list[Scan], lines: list[int], path: Path, stamps: str) -> tuple[list[Scan], StampRepair]:
    """The scans with their stamps repaired (``stamps="repair"``) or checked as they are
    (``"strict"``) by :func:`rigcal.io.stamps.repair_stamps`; ``lines`` their lines."""
    fixed = repair_stamps([s.stamp_s for s in scans], f"{path}: stamp", stamps, lines)
    return [replace(s, stamp_s=float(t)) for s, t in zip(scans, fixed.stamps_s, strict=True)], fixed


def _radlocc_scans(
    path: Path, range_min_m: float, range_max_m: float, no_return_m: float | None = None, strict: bool = False
) -> tuple[list[Scan], list[int], CutLine | None]:
    """The scans, their lines, and the incomplete last line left out (None: the log is whole)."""
    scans: list[Scan] = []
    numbers: list[int] = []
    form: list[bool] = []  # the first line's: radlocc_collect's header (unit type, count) or not
    text = _log_text(path, "RADLOCC laser log")
    lines = _content_lines(path, "RADLOCC laser log", text)
    cut = None
    for n, line in lines:
        where = f"{path}: line {n}"
        try:
            scans.append(_radlocc_line(path, where, line, form, range_min_m, range_max_m, no_return_m))
        except InputError as exc:  # a log cut short ends mid-line (rigcal.io.log_lines)
            if not scans:  # nothing whole before it: not a log cut short
                raise
            cut = cut_last_line(exc, text, n, lines[-1][0], line, where, strict)
            continue
        numbers.append(n)
    return scans, numbers, cut


def _radlocc_line(
    path: Path,
    where: str,
    line: str,
    form: list[bool],
    range_min_m: float,
    range_max_m: float,
    no_return_m: float | None,
) -> Scan:
    """One line's scan; ``form`` holds the first line's form once it is known."""
    f = _fields(line)
    try:
        values = [float(x) for x in f]
    except ValueError:
        raise InputError(
            f"{where}: got {line[:60]!r}; expected numbers: stamp angle_min increment angle_max ranges..."
        ) from None
    if len(values) < 6:
        raise ShortLineError(
            f"{where}: got {len(values)} fields; expected stamp, angle_min, increment, max, ranges"
        )
    stamp, a0, step, a1 = values[:4]
    if not all(math.isfinite(x) for x in (stamp, a0, step, a1)) or not step > 0:
        raise InputError(f"{where}: got stamp {stamp!r}, increment {step!r}; expected finite, increment > 0")
    if max(abs(a0), abs(a1)) > 2 * math.pi + 1e-6:
        raise InputError(f"{where}: got angles {a0!r} to {a1!r}; expected radians (within +/- 2 pi)")
    count = round((a1 - a0) / step) + 1
    declared = values[5]
    # radlocc_collect's form: range unit type and beam count N, then exactly N ranges.
    has_header = declared.is_integer() and declared >= 1 and len(values) == int(declared) + 6
    if not form:
        form.append(has_header)
    header_form = form[0]
    if has_header != header_form:
        short = header_form and len(values) < declared + 6  # fewer ranges than its count
        expected = (
            "stamp angle_min increment angle_max 3 N r_1 ... r_N (unit type 3: metres, N ranges), "
            f"as line {_first_line(path)} has"
            if header_form
            else "stamp angle_min increment angle_max r_1 ..., without unit type and count, as the first line"
        )
        raise (ShortLineError if short else InputError)(
            f"{where}: got {len(values) - 4} values after the angles; expected {expected}"
        )
    ranges = np.array(values[4:])
    if has_header:
        if values[4] != RADLOCC_METRES:
            raise InputError(f"{where}: range unit type {values[4]!r}; expected {RADLOCC_METRES:g} (metres)")
        ranges = ranges[2:]
    if abs(len(ranges) - count) > 1:
        said = f"the header's N = {int(declared)}" if has_header else f"{len(ranges)} ranges"
        raise (ShortLineError if len(ranges) < count else InputError)(
            f"{where}: got {said}; expected {count} (within one step) for angles {a0!r} to {a1!r} by {step!r}"
        )
    ranges = np.where(np.isfinite(ranges) & (ranges >= 0), ranges, np.nan)
    if no_return_m is not None:
        ranges = np.where(np.abs(ranges - no_return_m) <= 1e-9 * max(1.0, no_return_m), np.nan, ranges)
    return Scan.from_uniform(a0, step, ranges, range_min_m, range_max_m, stamp)


def _first_line(path: Path) -> int:
    return _content_lines(path, "RADLOCC laser log")[0][0]


def read_csv_laser(
    path: str | Path, range_min_m: float = 0.0, range_max_m: float = 80.0, stamps: str = "repair"
) -> list[Scan]:
    """Scans of a generic CSV log (see the module docstring); rows with one stamp are a
    scan, so only steps back are repaired (``stamps`` as :func:`restamped`).

    Raises:
        InputError: a missing column, a non-numeric value, angles not increasing within a
            scan, a stamp not after the previous scan's (strict) or beyond repair.
    """
    scans, lines, _ = _csv_scans(Path(path), range_min_m, range_max_m, stamps == "strict")
    return restamped(scans, lines, Path(path), stamps)[0]


def _csv_scans(
    path: Path, range_min_m: float, range_max_m: float, strict: bool = False
) -> tuple[list[Scan], list[int], CutLine | None]:
    """The scans, their first rows' lines, and the incomplete last row left out with the
    scan it ended (None: the log is whole)."""
    text = _log_text(path, "CSV laser log")
    lines = _content_lines(path, "CSV laser log", text)
    header = [h.lower() for h in csv_fields(lines[0][1])]
    angle_key = "angle_rad" if "angle_rad" in header else "angle_deg"
    for key in ("stamp_s", angle_key, "range_m"):
        if key not in header:
            raise InputError(
                f"{path}: line {lines[0][0]}: header {header}; expected columns stamp_s, angle_rad, range_m"
            )
    cols = [header.index(k) for k in ("stamp_s", angle_key, "range_m")]
    scale = math.pi / 180.0 if angle_key == "angle_deg" else 1.0
    groups: list[tuple[float, list[float], list[float]]] = []
    first_rows: list[int] = []
    cut = None
    for n, line in lines[1:]:
        parts = csv_fields(line)
        try:
            stamp, angle, rng = _csv_row(path, n, line, parts, cols, header)
        except InputError as exc:  # a log cut short ends mid-row (rigcal.io.log_lines)
            if not groups:  # nothing whole before it: not a log cut short
                raise
            cut = cut_last_line(exc, text, n, lines[-1][0], line, f"{path}: line {n}", strict)
            if groups and _same_stamp(parts, cols[0], groups[-1][0]):  # the scan it ended is cut too
                cut = replace(cut, records=len(groups[-1][1]))
                groups.pop()
                first_rows.pop()
            continue
        if not (math.isfinite(stamp) and math.isfinite(angle)):
            raise InputError(
                f"{path}: line {n}: got stamp {stamp!r}, angle {angle!r}; expected finite numbers"
            )
        if not groups or stamp != groups[-1][0]:
            groups.append((stamp, [], []))
            first_rows.append(n)
        if abs(angle * scale) > 2 * math.pi + 1e-6:
            raise InputError(f"{path}: line {n}: got angle {angle!r}; expected within +/- 2 pi radians")
        g = groups[-1]
        if g[1] and not angle * scale > g[1][-1]:
            raise InputError(
                f"{path}: line {n}: angle {angle!r} not after the previous beam's (angles increase)"
            )
        g[1].append(angle * scale)
        g[2].append(rng if math.isfinite(rng) and rng >= 0 else math.nan)
    if not groups:
        raise InputError(f"{path}: got a header only; expected rows stamp_s, angle, range_m")
    scans = [_on_a_grid(path, stamp, a, r, range_min_m, range_max_m) for stamp, a, r in groups]
    return scans, first_rows, cut


def _csv_row(
    path: Path, n: int, line: str, parts: list[str], cols: list[int], header: list[str]
) -> tuple[float, float, float]:
    """A CSV row's stamp, angle and range; a row short of a column (or ending in an empty
    field) is a :class:`ShortLineError`."""
    try:
        stamp, angle, rng = (float(parts[c]) for c in cols)
    except (ValueError, IndexError):
        short = len(parts) < len(header) or not parts[-1].strip()
        raise (ShortLineError if short else InputError)(
            f"{path}: line {n}: got {line[:60]!r}; expected numbers in the columns {header}"
        ) from None
    return stamp, angle, rng


def _same_stamp(parts: list[str], col: int, stamp: float) -> bool:
    """Whether a cut row belongs to the scan at ``stamp`` (or its stamp is itself cut)."""
    try:
        return float(parts[col]) == stamp
    except (ValueError, IndexError):
        return True


MAX_GRID_BEAMS = 100_000


def _on_a_grid(
    path: Path, stamp: float, angles: list[float], ranges: list[float], range_min_m: float, range_max_m: float
) -> Scan:
    """A CSV scan on its uniform beam grid (what sequence folders store: angle_min and
    increment): the step is the smallest angle gap and beams missing from the rows (rows
    left out for no return) get no return.

    Raises:
        InputError: angles that are not on one grid (a gap not a whole number of steps).
    """
    a = np.asarray(angles, dtype=np.float64)
    if len(a) == 1:
        return Scan.from_uniform(a[0], 0.0, np.asarray(ranges), range_min_m, range_max_m, stamp)
    step = float(np.diff(a).min())
    k = (a - a[0]) / step
    n = round(float(k[-1])) + 1
    if np.abs(k - np.round(k)).max() > 1e-3 or n > MAX_GRID_BEAMS:
        raise InputError.at(
            path,
            f"scan at stamp {stamp!r}: angles",
            f"gaps from {step!r} to {float(np.diff(a).max())!r} rad",
            "angles on one grid: every gap a whole number of the smallest (missing beams are no return)",
        )
    r = np.full(n, np.nan)
    r[np.round(k).astype(int)] = ranges
    return Scan.from_uniform(a[0], step, r, range_min_m, range_max_m, stamp)


def read_image_list(path: str | Path) -> tuple[FloatArray, list[Path]]:
    """Stamps (N,) and files of an image list, in time order.

    Raises:
        InputError: a line without one stamp and one existing file (or, for a stamps-only
            RADLOCC list, a missing ``image_00k`` file), or stamps not increasing.
    """
    stamps, files, _, _ = _image_list(Path(path), strict=True)
    return stamps, files


def _image_list(path: Path, strict: bool) -> tuple[FloatArray, list[Path], CutLine | None, StampRepair]:
    """:func:`read_image_list`, and its incomplete last line left out (a list copied while
    it was written, rigcal.io.log_lines; ``strict`` refuses it); its stamps repaired as a
    log's (:func:`rigcal.io.stamps.repair_stamps`: equal stamps of low-precision printing
    spread, small steps back placed; ``strict`` refuses them)."""
    text = _log_text(path, "image list")
    lines = _content_lines(path, "image list", text)
    stamps_only = all(_numbers_only(_fields(line)) for _, line in lines)
    stamps: list[float] = []
    files: list[Path] = []
    numbers: list[int] = []
    seen: dict[Path, int] = {}
    cut = None
    for k, (n, line) in enumerate(lines, start=1):
        try:
            stamp, file = _image_entry(path, k, n, line, stamps_only)
        except InputError as exc:
            if not stamps:  # nothing whole before it: not a list cut short
                raise
            cut = cut_last_line(exc, text, n, lines[-1][0], line, f"{path}: line {n}", strict)
            continue
        # One frame at two stamps would be a camera that stood still between them.
        first = seen.setdefault(file.resolve(), n)
        if first != n:
            raise InputError.at(
                path,
                f"line {n}: file",
                str(file.relative_to(path.parent)),
                f"an image no other line names (line {first} does)",
            )
        stamps.append(stamp)
        files.append(file)
        numbers.append(n)
    fixed = repair_stamps(stamps, str(path), "strict" if strict else "repair", numbers)
    return fixed.stamps_s, files, cut, fixed


def _image_entry(path: Path, k: int, n: int, line: str, stamps_only: bool) -> tuple[float, Path]:
    """Line n (the k-th entry) of an image list: its stamp and existing file."""
    f = _fields(line)
    if stamps_only:  # RADLOCC image_stamps.txt: image_00k.* beside it
        stamp = float(f[0])
        file = _radlocc_image(path.parent, k)
        if file is None:
            raise InputError(f"{path}: line {n}: image_{k:03d}.png (or .jpg, ...) not found in {path.parent}")
    else:
        numbers: list[str] = []
        names: list[str] = []
        for x in f:
            (numbers if _numbers_only([x]) else names).append(x)
        if len(f) != 2 or len(numbers) != 1 or not math.isfinite(float(numbers[0])):
            raise (ShortLineError if len(f) < 2 else InputError)(
                f"{path}: line {n}: got {line[:60]!r}; expected a stamp (s) and an image file"
            )
        stamp = float(numbers[0])
        file = file_inside(path.parent, names[0], path, f"line {n}")
        if not file.is_file():
            raise InputError(f"{path}: line {n}: image {names[0]} not found in {path.parent}")
    return stamp, file


def _numbers_only(fields: list[str]) -> bool:
    try:
        [float(x) for x in fields]
    except ValueError:
        return False
    return bool(fields)


def _radlocc_image(folder: Path, k: int) -> Path | None:
    """RADLOCC's k-th image (from 1): image_001.png, image_0001.jpg, ..."""
    for digits in (3, 4, 5, 6, 1):
        for ext in (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".pgm", ".ppm"):
            p = folder / f"image_{k:0{digits}d}{ext}"
            if p.is_file():
                return p
    return None


def import_laser_text(
    log: str | Path,
    output: str | Path,
    images: str | Path | None = None,
    camera: str | Path | None = None,
    fmt: str | None = None,
    range_min_m: float = 0.0,
    range_max_m: float = 80.0,
    force: bool = False,
    no_return_m: float | None = None,
    stamps: str = "repair",
    odometry: str | Path | None = None,
    laser_offset: FloatArray | None = None,
) -> LaserTextSummary:
    """Write a sequence folder from a RADLOCC or CSV laser log, its image list and camera,
    and (``odometry``: a TUM file of the base's poses, the laser at ``laser_offset`` on
    it) its wheel odometry. ``stamps``: "repair" or "strict" (:func:`restamped`).

    Raises:
        InputError: a malformed log, image list, camera or odometry file.
        OutputError: the folder exists and ``force`` is false.
    """
    from rigcal.camera import camera_to_opencv_yaml, read_camera

    log = Path(log)
    fmt = fmt or detect_format(log)
    if fmt not in ("csv", "radlocc"):
        raise InputError.at(log, "--format", fmt, "one of ['csv', 'radlocc']")
    if no_return_m is not None and fmt != "radlocc":
        raise InputError.at(
            log, "--no-return-m", no_return_m, "a RADLOCC log (a CSV writes no return as nan)"
        )
    strict = stamps == "strict"
    if fmt == "radlocc":
        scans, lines, cut = _radlocc_scans(log, range_min_m, range_max_m, no_return_m, strict)
    else:
        scans, lines, cut = _csv_scans(log, range_min_m, range_max_m, strict)
    scans, fixed = restamped(scans, lines, log, stamps)
    wheel, odometry_cut = None, None
    if odometry is not None:
        mount = np.zeros(3) if laser_offset is None else laser_offset
        traj, odometry_cut = read_tum_cut(odometry, strict)  # a TUM file cut short: the logs' rule
        wheel = odometry_of_tum(traj, odometry, mount, fixed.stamps_s)
    frames: list[ImageFrame] = []
    list_cut, image_fix = None, None
    if images is not None:
        image_stamps, files, list_cut, image_fix = _image_list(Path(images), strict)
        frames = [
            ImageFrame(float(t), f"{i:06d}{f.suffix.lower()}", f.read_bytes())
            for i, (t, f) in enumerate(zip(image_stamps, files, strict=True))
        ]
    datas, depth = eight_bit_pngs([f.data for f in frames])  # 16-bit frames as import-bag's
    frames = [  # a 16-bit frame (a TIFF, say) is an 8-bit PNG now
        ImageFrame(f.stamp_s, f.name if data is f.data else f"{Path(f.name).stem}.png", data)
        for f, data in zip(frames, datas, strict=True)
    ]
    camera_yaml = camera_to_opencv_yaml(read_camera(camera)) if camera is not None else None
    source: dict[str, Any] = {
        "log": str(log.resolve()),
        "format": fmt,
        "images": str(Path(images).resolve()) if images else None,
    }
    source["stamps"] = fixed.record(stamps)
    if image_fix is not None and image_fix.repaired:
        source["image_stamps"] = image_fix.record(stamps)
    if depth:
        source["images_16_bit"] = depth
    if cut is not None:
        source["incomplete_last_line"] = cut.line
    if list_cut is not None:
        source["images_incomplete_last_line"] = list_cut.line
    if odometry is not None:
        source["odometry"] = str(Path(odometry).resolve())
    if odometry_cut is not None:
        source["odometry_incomplete_last_line"] = odometry_cut.line
    write_sequence(output, log.name, scans, frames, camera_yaml, source, force=force, odometry=wheel)
    return LaserTextSummary(
        fmt,
        len(scans),
        len(frames),
        camera_yaml is not None,
        fixed,
        wheel is not None,
        cut,
        list_cut,
        odometry_cut,
        image_fix,
    )
