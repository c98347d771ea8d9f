"""From a recording to a box-target session: one scan + image pair per still moment.

A lab records the rig while the box (or the rig) is moved between placements. The moments
to calibrate from are those where nothing moves: there the scan and the image see the
same scene even though their stamps differ. :func:`find_still_periods`:

1. scan-to-scan change: the fraction of beams (valid in both scans) whose range changed by
   more than ``scan_threshold_m`` together with their neighbours, in runs of at least
   MIN_CHANGED_RUN beams; a pair of scans is still when it is under
   ``max_changed_fraction``. Something that moves changes neighbouring beams together;
   range noise and mixed pixels change beams one by one (a scanner with heavy-tailed
   noise of 1.4 cm scale moves 8 % of its beams by more than 5 cm from scan to scan, and
   almost none in runs of three);
2. image-to-image change: the fraction of pixels (grey, downscaled to at most 160 px wide)
   whose level changed by more than ``image_threshold``; still under the same fraction;
3. a still run is a maximal run of consecutive still pairs spanning at least
   ``min_frames`` frames; a still period is where a scan run and an image run overlap in
   time;
4. per period, the image nearest the overlap's middle and the scan nearest that image's
   stamp make the capture; their stamp difference is reported. A period whose pair looks
   like the previous capture's (the same still test between them) is the same placement
   and is skipped.

:func:`write_capture_session` writes the session folder (docs/formats/session.md) with a
picking file skeleton (schema 2) for ``rigcal pick`` / ``rigcal solve``.
"""

from __future__ import annotations

import shutil
from collections.abc import Sequence as Seq
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from rigcal.arrays import FloatArray
from rigcal.camera import Camera
from rigcal.errors import InputError
from rigcal.recordings.sequence import Sequence
from rigcal.scan import Scan

THUMB_WIDTH_PX = 160


@dataclass(frozen=True)
class CaptureSettings:
    """Thresholds of the still-moment search.

    Attributes:
        scan_threshold_m: a beam changed when its range moved more than this.
        image_threshold: a pixel changed when its grey level moved more than this (0-255).
        max_changed_fraction: two frames are still when under this fraction changed.
        min_frames: least number of consecutive still frames (each stream) of a period.
        max_offset_s: a pair whose stamps differ by more is not made.
    """

    scan_threshold_m: float = 0.05
    image_threshold: float = 15.0
    max_changed_fraction: float = 0.01
    min_frames: int = 5
    max_offset_s: float = 0.5

    def __post_init__(self) -> None:
        if not (self.scan_threshold_m > 0 and self.image_threshold > 0 and 0 < self.max_changed_fraction < 1):
            raise ValueError("CaptureSettings: thresholds must be > 0 and the fraction in (0, 1)")
        if self.min_frames < 2 or not self.max_offset_s > 0:
            raise ValueError("CaptureSettings: min_frames must be >= 2 and max_offset_s > 0")


@dataclass(frozen=True)
class StillCapture:
    """One still period and the pair taken from it.

    Attributes:
        start_s, end_s: the period (overlap of a still scan run and a still image run).
        scan_index, image_index: the pair, indices into the sequence.
        offset_s: image stamp minus scan stamp.
        still_scans, still_images: frames of each stream in the period.
    """

    start_s: float
    end_s: float
    scan_index: int
    image_index: int
    offset_s: float
    still_scans: int
    still_images: int


def scan_change(a: Scan, b: Scan, threshold_m: float) -> float:
    """Fraction of beams valid in both scans whose range moved by more than ``threshold_m``,
    counting only runs of at least MIN_CHANGED_RUN neighbouring such beams (1.0 when the
    scans have different beams)."""
    if len(a.ranges_m) != len(b.ranges_m) or not np.allclose(a.angles_rad, b.angles_rad):
        return 1.0
    both = a.valid & b.valid
    if not both.any():
        return 1.0
    moved = both & (np.abs(np.where(both, a.ranges_m - b.ranges_m, 0.0)) > threshold_m)
    # A beam is in a run when MIN_CHANGED_RUN consecutive moved beams cover it.
    k = MIN_CHANGED_RUN
    full = np.convolve(moved.astype(np.int64), np.ones(k, dtype=np.int64), mode="valid") == k
    in_run = np.convolve(full.astype(np.int64), np.ones(k, dtype=np.int64), mode="full") > 0
    return float(np.sum(in_run) / np.sum(both))


# Beams that change together (a run at least this long) are a change of the scene.
MIN_CHANGED_RUN = 3


def image_change(a: NDArray[np.float32], b: NDArray[np.float32], threshold: float) -> float:
    """Fraction of pixels of two thumbnails whose level moved by more than ``threshold``."""
    if a.shape != b.shape:
        return 1.0
    return float(np.mean(np.abs(a - b) > threshold))


def thumbnail(path: Path) -> NDArray[np.float32]:
    """An image as grey float32, area-downscaled to at most THUMB_WIDTH_PX wide."""
    import cv2

    from rigcal.io.images import read_image_file

    img = read_image_file(path, cv2.IMREAD_GRAYSCALE)
    if img is None:
        raise InputError(f"{path}: cannot decode image (expected PNG, JPEG or another format OpenCV reads)")
    if img.dtype != np.uint8:  # mono16: to 8 bits, as the threshold is in 8-bit levels
        img = (img.astype(np.float32) / 257.0).astype(np.uint8)
    h, w = img.shape
    if w > THUMB_WIDTH_PX:
        img = cv2.resize(
            img, (THUMB_WIDTH_PX, max(1, round(h * THUMB_WIDTH_PX / w))), interpolation=cv2.INTER_AREA
        )
    return np.asarray(img, dtype=np.float32)


def still_runs(changes: FloatArray, max_fraction: float, min_frames: int) -> list[tuple[int, int]]:
    """Maximal runs [a, b] of frames where every consecutive pair changed under
    ``max_fraction`` (changes[k] compares frame k with frame k+1), at least ``min_frames``
    frames long."""
    runs = []
    start = 0
    n = len(changes) + 1
    for k in range(n):
        end_of_run = k == n - 1 or changes[k] >= max_fraction
        if end_of_run:
            if k - start + 1 >= min_frames:
                runs.append((start, k))
            start = k + 1
    return runs


def find_still_periods(
    seq: Sequence, settings: CaptureSettings | None = None, origin: str | Path | None = None
) -> list[StillCapture]:
    """The still periods of a sequence and one scan + image pair from each. ``origin``
    is what messages name (the bag a temporary sequence folder was read from; default the
    sequence's folder).

    Raises:
        InputError: the sequence has no images or an image cannot be decoded.
    """
    settings = settings or CaptureSettings()
    if seq.folder is None or not seq.image_files:
        raise InputError(f"{origin or seq.folder}: images: got none; expected a recording with camera images")
    scans = seq.scans
    scan_t = np.array([s.stamp_s for s in scans], dtype=float)
    scan_d = np.array(
        [scan_change(scans[k], scans[k + 1], settings.scan_threshold_m) for k in range(len(scans) - 1)]
    )
    images_dir = _images_dir(seq)
    thumbs = [thumbnail(images_dir / f) for f in seq.image_files]
    image_d = np.array(
        [image_change(thumbs[k], thumbs[k + 1], settings.image_threshold) for k in range(len(thumbs) - 1)]
    )
    image_t = np.asarray(seq.image_stamps_s, dtype=float)
    scan_runs = still_runs(scan_d, settings.max_changed_fraction, settings.min_frames)
    image_runs = still_runs(image_d, settings.max_changed_fraction, settings.min_frames)
    out: list[StillCapture] = []
    for sa, sb in scan_runs:
        for ia, ib in image_runs:
            lo = max(scan_t[sa], image_t[ia])
            hi = min(scan_t[sb], image_t[ib])
            if hi < lo:
                continue
            in_overlap = np.flatnonzero((image_t >= lo) & (image_t <= hi))
            if not len(in_overlap):
                continue
            i = int(in_overlap[np.argmin(np.abs(image_t[in_overlap] - 0.5 * (lo + hi)))])
            cand = np.arange(sa, sb + 1)
            s = int(cand[np.argmin(np.abs(scan_t[cand] - image_t[i]))])
            offset = float(image_t[i] - scan_t[s])
            if abs(offset) > settings.max_offset_s:
                continue
            if out and _same_placement(seq, thumbs, out[-1], s, i, settings):
                continue
            out.append(
                StillCapture(
                    float(lo),
                    float(hi),
                    s,
                    i,
                    offset,
                    int(np.sum((scan_t >= lo) & (scan_t <= hi))),
                    len(in_overlap),
                )
            )
    return out


def _check_image_sizes(
    seq: Sequence, captures: Seq[StillCapture], camera: Camera, origin: str | Path | None
) -> None:
    """Every captured image must have the camera's size."""
    import cv2

    from rigcal.io.images import read_image_file

    for c in captures:
        path = image_path(seq, c)
        img = read_image_file(path, cv2.IMREAD_UNCHANGED)
        if img is None:
            raise InputError(
                f"{path}: cannot decode image (expected PNG, JPEG or another format OpenCV reads)"
            )
        h, w = img.shape[:2]
        if (w, h) != (camera.width_px, camera.height_px):
            stamp = float(seq.image_stamps_s[c.image_index])
            own = origin is None or Path(origin) == seq.folder
            where = path if own else f"{origin}: image at {stamp:.9f} s"
            raise InputError.at(
                where,
                "size",
                f"{w}x{h}",
                f"the camera's size {camera.width_px}x{camera.height_px} ({camera.source})",
            )


def _images_dir(seq: Sequence) -> Path:
    assert seq.folder is not None
    return seq.folder / seq.image_folder


def image_path(seq: Sequence, capture: StillCapture) -> Path:
    """The file of a still moment's image."""
    return _images_dir(seq) / seq.image_files[capture.image_index]


def _same_placement(
    seq: Sequence,
    thumbs: list[NDArray[np.float32]],
    prev: StillCapture,
    s: int,
    i: int,
    settings: CaptureSettings,
) -> bool:
    return (
        scan_change(seq.scans[prev.scan_index], seq.scans[s], settings.scan_threshold_m)
        < settings.max_changed_fraction
        and image_change(thumbs[prev.image_index], thumbs[i], settings.image_threshold)
        < settings.max_changed_fraction
    )


def write_capture_session(
    seq: Sequence,
    captures: Seq[StillCapture],
    output: str | Path,
    camera_file: Path,
    box_width_m: float | None = None,
    force: bool = False,
    origin: str | Path | None = None,
    targets_file: Path | None = None,
    max_scans: int | None = None,
) -> Path:
    """Write the session folder: ``camera.*``, ``scans/capNN.yaml``, ``images/capNN.*``
    and ``picks.yaml`` (schema 2, captures not picked yet), atomically; with a marker
    target's ``targets_file``, that file (as ``targets.yaml``) and ``marker_session.yaml``
    (docs/formats/marker-session.md, ready for ``rigcal solve``) instead of the picking
    file, each capture with the scans of its still moment (:func:`still_scan_indices`,
    at most ``max_scans``). ``origin`` is what messages name, as in
    :func:`find_still_periods`. (A board target's session: :mod:`rigcal.calib.board.capture`.)

    Raises:
        InputError: no still period was found, or a captured image's size is not the
            camera's (a wrong camera would bias every pick and the solve).
        OutputError: the folder exists and ``force`` is false, or a write failed.
    """
    import yaml

    from rigcal.io.files import atomic_folder

    origin = origin or seq.folder
    many = targets_file is not None
    check_capture_inputs(seq, captures, camera_file, origin, max_scans if many else 1)
    with atomic_folder(output, force) as tmp:
        camera_name, entries = write_capture_files(tmp, seq, captures, camera_file, max_scans if many else 1)
        if targets_file is not None:
            _write_marker_session(tmp, seq, captures, camera_name, targets_file, entries)
            return Path(output)
        doc: dict[str, object] = {
            "schema_version": 2,
            "name": f"captured from {seq.name}",
            "camera": camera_name,
        }
        if box_width_m is not None:
            doc["box"] = {"width_m": float(box_width_m)}
        doc["captures"] = entries
        head = [
            "# rigcal picking file (docs/formats/session.md), written by rigcal capture.",
            f"# {len(captures)} still moments of {seq.name}; each capture's scan and image stamps:",
        ]
        for k, c in enumerate(captures):
            head.append(
                f"#   cap{k:02d}: scan {seq.scans[c.scan_index].stamp_s:.3f} s, image "
                f"{float(seq.image_stamps_s[c.image_index]):.3f} s (offset {1000 * c.offset_s:+.1f} ms), "
                f"still {c.end_s - c.start_s:.2f} s"
            )
        head += [
            "# Not picked yet: pick the image ends of 3+ captures (image_endpoints_px, laser_side),",
            "# then `rigcal pick picks.yaml -o picks-auto.yaml --sheet sheet.png` proposes the rest.",
        ]
        (tmp / "picks.yaml").write_text(
            "\n".join(head) + "\n" + yaml.safe_dump(doc, sort_keys=False, default_flow_style=None, width=110),
            encoding="utf-8",
        )
    return Path(output)


def check_capture_inputs(
    seq: Sequence,
    captures: Seq[StillCapture],
    camera_file: Path,
    origin: str | Path | None,
    max_scans: int | None = 1,
) -> None:
    """What a captured session needs before anything is written: a still period, scans
    with no negative range (each capture's kept scans, :func:`still_scan_indices` with
    ``max_scans``; 1: the scan paired with the image), images of the camera's size.

    Raises:
        InputError: no still period, a negative range, an image of another size.
    """
    from rigcal.camera import read_camera

    if not captures:
        raise InputError(
            f"{origin}: still periods: got none; expected moments where the scans and images stay "
            "still for the given number of frames (see rigcal capture --help for the thresholds)"
        )
    for k, c in enumerate(captures):
        for s in still_scan_indices(seq, c, max_scans):
            r = seq.scans[s].ranges_m
            if np.any(r < 0):
                raise InputError.at(
                    origin,
                    f"scans[{s}].ranges_m",
                    float(r[r < 0][0]),
                    f"ranges >= 0 (0, NaN or inf for no return) in the scan of capture {k}",
                )
    _check_image_sizes(seq, captures, read_camera(camera_file), origin)


def write_capture_files(
    tmp: Path, seq: Sequence, captures: Seq[StillCapture], camera_file: Path, max_scans: int | None = 1
) -> tuple[str, list[dict[str, object]]]:
    """A captured session's files in the folder ``tmp``: the camera file, each capture's
    image (``images/capNN.*``) and scans: with ``max_scans`` 1 the scan paired with the
    image (``scans/capNN.yaml``), else those of its still moment (``scans/capNN_JJ.yaml``,
    :func:`still_scan_indices`). Returns the camera file's name and one session entry
    per capture (``name``, ``image``, and ``scan`` or ``scans``)."""
    from rigcal.scan import scan_to_text

    (tmp / "scans").mkdir()
    (tmp / "images").mkdir()
    camera_name = "camera" + "".join(camera_file.suffixes[-1:]) if camera_file.suffix else "camera.yaml"
    shutil.copyfile(camera_file, tmp / camera_name)
    entries: list[dict[str, object]] = []
    for k, c in enumerate(captures):
        name = f"cap{k:02d}"
        src = image_path(seq, c)
        image_rel = f"images/{name}{src.suffix.lower()}"
        shutil.copyfile(src, tmp / image_rel)
        if max_scans == 1:
            (tmp / "scans" / f"{name}.yaml").write_text(
                scan_to_text(seq.scans[c.scan_index]), encoding="utf-8"
            )
            entries.append({"name": name, "scan": f"scans/{name}.yaml", "image": image_rel})
            continue
        # A session of a plane method keeps every scan of the still moment (the solve averages them).
        files = []
        for j, s in enumerate(still_scan_indices(seq, c, max_scans)):
            files.append(f"scans/{name}_{j:02d}.yaml")
            (tmp / files[-1]).write_text(scan_to_text(seq.scans[s]), encoding="utf-8")
        entries.append({"name": name, "image": image_rel, "scans": files})
    return camera_name, entries


def still_scan_indices(seq: Sequence, capture: StillCapture, max_scans: int | None = None) -> list[int]:
    """The scans of a still moment: those stamped within its period (at least the one
    paired with its image), in time order, at most ``max_scans`` (default
    MAX_STILL_SCANS) spread evenly over it; with ``max_scans`` 1, the one paired with
    its image."""
    if max_scans == 1:
        return [capture.scan_index]
    max_scans = max_scans or MAX_STILL_SCANS
    t = np.array([s.stamp_s for s in seq.scans], dtype=float)
    idx = np.flatnonzero((t >= capture.start_s) & (t <= capture.end_s))
    if capture.scan_index not in idx:
        idx = np.sort(np.append(idx, capture.scan_index))
    if len(idx) > max_scans:
        idx = idx[np.round(np.linspace(0, len(idx) - 1, max_scans)).astype(int)]
    return [int(i) for i in idx]


# A still moment's scans kept for a marker or board session: independent noise averages down as
# 1/sqrt(K), so beyond this many more scans buy little (a 1.7x smaller sigma from 10 to
# 30) and cost files.
MAX_STILL_SCANS = 30


def _write_marker_session(
    tmp: Path,
    seq: Sequence,
    captures: Seq[StillCapture],
    camera_name: str,
    targets_file: Path,
    entries: list[dict[str, object]],
) -> None:
    """The marker session file of a captured folder, and its targets file beside it."""
    import yaml

    shutil.copyfile(targets_file, tmp / "targets.yaml")
    doc = {
        "schema_version": 2,
        "method": "marker",
        "name": f"captured from {seq.name}",
        "camera": camera_name,
        "targets": "targets.yaml",
        "captures": entries,
    }
    head = [
        "# rigcal marker session (docs/formats/marker-session.md), written by rigcal capture.",
        f"# {len(captures)} still moments of {seq.name}; solve it as it is: rigcal solve marker_session.yaml",
    ]
    (tmp / "marker_session.yaml").write_text(
        "\n".join(head) + "\n" + yaml.safe_dump(doc, sort_keys=False, default_flow_style=None, width=110),
        encoding="utf-8",
    )
