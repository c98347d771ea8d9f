"""Picking files: the captures of a box-target session and what the user picked in each.

A picking file (docs/formats/session.md) lists, per capture, a scan file, an image file, the
laser side of the box (a segment id as printed by ``rigcal lines``, or two laser points)
and the pixels of the two box ends in the image (paper Algorithm 1, step 2). Paths are
relative to the picking file. :func:`read_picks` validates everything and resolves each
capture into a :class:`BoxObservation`, the solver's input.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
from numpy.typing import NDArray

from rigcal.arrays import FloatArray
from rigcal.camera import Camera, read_camera
from rigcal.errors import InputError
from rigcal.io.files import check_keys, get_float, load_yaml
from rigcal.io.validate import is_real, path_component, slashed
from rigcal.lines import LineParams, Segment, extract_lines, fit_line
from rigcal.scan import Scan, mean_scan, read_scan

PICKS_SCHEMA_VERSION = 2
# The forms of a capture's laser_side (segments: a side line extraction split, schema 2).
LASER_SIDE_FORMS = ("segment", "segments", "points")
LASER_SIDE_EXPECTED = "{segment: ID}, {segments: [ID, ...]} or {points: [[x1, y1], [x2, y2]]}"
# Schema 1 files are read as they are (docs/formats/session.md).
READABLE_PICKS_VERSIONS = (1, 2)

# Laser points within this distance of the line through two given laser points count as
# points of the box side (for the `points:` form of laser_side).
SIDE_POINT_TOLERANCE_M = 0.03
# At most this many missing returns next to a box end widen its interval (beyond that the
# scanner sees nothing there at all, e.g. open space, and more steps only add noise).
MAX_DROPOUT_STEPS = 4
# A return this close beyond a box end means the scan goes on around the box's corner (its
# side is visible); the end is then known to about CORNER_STEPS beam steps.
CORNER_GAP_M = 0.1
CORNER_STEPS = 3


@dataclass(frozen=True)
class BoxObservation:
    """One capture, resolved: what the laser and the camera saw of the box side.

    Attributes:
        capture: index of the capture in the picking file.
        name: the capture's name.
        scan_path, image_path: absolute paths of its files.
        laser_endpoints: (2, 2) metres, laser frame: the two ends of the box side, in the
            same order as ``image_endpoints_px``.
        side_points: (M, 2) metres, laser frame: the laser returns on the box side (M >= 2).
        side_beams: (M,) beam indices of those returns in the scan.
        beam_step_rad: angular step of the scanner, for the endpoint noise model.
        image_endpoints_px: (2, 2) picked pixels of the two box ends.
        end_gap_steps: (2,) for each end, in beam steps, the width of the interval in which
            the true box end lies (see :func:`extended_ends`): 1 at a clean depth jump, more
            at a corner or next to missing returns.
        review: the picking file marks the pick for review (``pick.review: true``).
    """

    capture: int
    name: str
    scan_path: Path
    image_path: Path
    laser_endpoints: FloatArray
    side_points: FloatArray
    side_beams: NDArray[np.int64]
    beam_step_rad: float
    image_endpoints_px: FloatArray
    end_gap_steps: tuple[int, int] = (1, 1)
    review: bool = False


@dataclass(frozen=True)
class PickSession:
    """A whole picking file, resolved."""

    path: Path
    camera: Camera
    camera_path: Path
    laser: dict[str, Any]
    observations: tuple[BoxObservation, ...]

    def input_files(self) -> list[Path]:
        """Every file the session was read from (for provenance hashes)."""
        files = [self.path, self.camera_path]
        for obs in self.observations:
            files += [obs.scan_path, obs.image_path]
        return files


def read_picks(path: str | Path, line_params: LineParams | None = None) -> PickSession:
    """Read and validate a picking file and every file it names.

    Every capture must be picked (``laser_side`` and ``image_endpoints_px``).

    Raises:
        InputError: anything missing, unreadable or invalid, naming the file, key and value.
    """
    draft = read_pick_draft(path, line_params)
    obs = tuple(resolve_capture(draft, c) for c in draft.captures)
    return PickSession(draft.path, draft.camera, draft.camera_path, dict(draft.laser), obs)


@dataclass(frozen=True)
class PickMeta:
    """How a capture's image ends were picked (schema 2's ``pick`` mapping).

    Attributes:
        source: ``"manual"`` (a person) or ``"auto"`` (``rigcal pick``).
        confidence: 0-1, for automatic picks.
        review: the pick should be checked by eye before it is trusted.
    """

    source: str = "manual"
    confidence: float = 1.0
    review: bool = False


@dataclass(frozen=True)
class CaptureDraft:
    """One capture as written, validated but possibly not picked yet.

    Attributes:
        index, name: position in the file and name.
        scan_path, image_path: absolute paths (both files exist; the image has the
            camera's size).
        scan: the scan.
        laser_side: the raw ``laser_side`` mapping, or None when missing.
        image_endpoints_px: (2, 2) pixels, or None when missing.
        pick: how the ends were picked (schema 2), None when unknown.
    """

    index: int
    name: str
    scan_path: Path
    image_path: Path
    scan: Scan
    laser_side: dict[str, Any] | None
    image_endpoints_px: FloatArray | None
    pick: PickMeta | None


@dataclass(frozen=True)
class PickDraft:
    """A picking file, validated, whose captures may not all be picked yet (the input and
    output of ``rigcal pick``)."""

    path: Path
    schema_version: int
    name: str | None
    camera: Camera
    camera_path: Path
    camera_ref: str
    laser: dict[str, Any]
    box: dict[str, float]
    captures: tuple[CaptureDraft, ...]
    line_params: LineParams


def read_pick_draft(path: str | Path, line_params: LineParams | None = None) -> PickDraft:
    """Read a picking file whose captures need not all be picked (schema 2 allows a capture
    without ``laser_side`` or ``image_endpoints_px``; schema 1 requires both).

    Raises:
        InputError: anything missing, unreadable or invalid, naming the file, key and value.
    """
    path = Path(path)
    data = load_yaml(path, "picking file")
    d = check_keys(
        data,
        path,
        "",
        ["schema_version", "camera", "captures"],
        ["laser", "name", "box"],
        READABLE_PICKS_VERSIONS,
    )
    version = d["schema_version"]
    if type(version) is not int or version not in READABLE_PICKS_VERSIONS:
        raise InputError.at(
            path,
            "schema_version",
            version,
            f"one of {list(READABLE_PICKS_VERSIONS)} (the versions this rigcal reads)",
        )
    if version == 1 and "box" in d:
        raise InputError.at(path, "box", d["box"], "no such key in schema 1 (schema_version: 2 has it)")
    name = d.get("name")
    if name is not None and not isinstance(name, str):
        raise InputError.at(path, "name", name, "a string")
    camera_path = session_file(path, "camera", d["camera"])
    camera = read_camera(camera_path)
    laser = d.get("laser", {})
    if not isinstance(laser, dict) or not all(isinstance(k, str) for k in laser):
        raise InputError.at(path, "laser", laser, "a mapping describing the scanner (e.g. name: ...)")
    box = _box(path, d.get("box", {}))
    captures = d["captures"]
    if not isinstance(captures, list) or not captures:
        raise InputError.at(path, "captures", captures, "a non-empty list of captures")
    params = line_params or line_params_for(path, laser)
    # Each capture's entry first (its own errors win), then the files named once across
    # the captures as read, then the files themselves.
    entries = [_draft_entry(path, version, i, c, camera) for i, c in enumerate(captures)]
    check_files_once(path, [f for e in entries for f in e.files])
    drafts = tuple(_read_draft(path, i, e, camera) for i, e in enumerate(entries))
    check_unique_names(path, [c.name for c in drafts])
    return PickDraft(
        path, version, name, camera, camera_path, str(d["camera"]), dict(laser), box, drafts, params
    )


def resolve_capture(draft: PickDraft, c: CaptureDraft) -> BoxObservation:
    """A picked capture's :class:`BoxObservation` (paper Algorithm 1, step 2).

    Raises:
        InputError: the capture is not picked yet, or its laser side is invalid.
    """
    kp = f"captures[{c.index}]"
    for key, value in (("laser_side", c.laser_side), ("image_endpoints_px", c.image_endpoints_px)):
        if value is None:
            raise InputError(
                f"{draft.path}: {kp}.{key}: missing; this key is required to solve "
                f"(`rigcal pick {draft.path.name}` proposes it)"
            )
    assert c.laser_side is not None
    assert c.image_endpoints_px is not None
    side = _laser_side(
        draft.path, kp, c.laser_side, c.scan, c.scan_path, draft.line_params, draft.schema_version
    )
    review = c.pick is not None and c.pick.review
    if isinstance(side, tuple):  # two laser points given: no returns to fit
        ends, pts, beams = side
        obs = BoxObservation(
            c.index,
            c.name,
            c.scan_path,
            c.image_path,
            ends,
            pts,
            beams,
            c.scan.step_rad,
            c.image_endpoints_px,
        )
    else:
        obs = side_observation(c.index, c.name, c.scan_path, c.image_path, c.scan, side, c.image_endpoints_px)
    return replace(obs, review=review) if review else obs


def side_ends(draft: PickDraft, c: CaptureDraft, laser_side: dict[str, Any]) -> FloatArray:
    """The box ends (2, 2), metres, laser frame, end 0 at the smaller beam angle, of a
    capture's ``laser_side`` mapping (as :func:`resolve_capture` takes them).

    Raises:
        InputError: an invalid segment id or points.
    """
    side = _laser_side(
        draft.path,
        f"captures[{c.index}]",
        laser_side,
        c.scan,
        c.scan_path,
        draft.line_params,
        draft.schema_version,
    )
    if isinstance(side, tuple):
        return side[0]
    return extended_ends(np.array(c.scan.points[side]), side, c.scan)[0]


def _box(path: Path, value: Any) -> dict[str, float]:
    b = check_keys(value, path, "box", [], ["width_m", "height_m"])
    out = {}
    for key in b:
        out[key] = get_float(b, key, path, "box", positive=True)
    return out


class _DraftEntry(NamedTuple):
    """A box capture's entry, validated before any file it names is looked at."""

    c: Mapping[str, Any]
    name: str
    px: FloatArray | None
    side: Any
    meta: PickMeta | None
    files: list[tuple[str, Any]]


def _draft_entry(path: Path, version: int, i: int, c: Any, camera: Camera) -> _DraftEntry:
    kp = f"captures[{i}]"
    if version == 1:
        c = check_keys(c, path, kp, ["scan", "image", "laser_side", "image_endpoints_px"], ["name"])
    else:
        c = check_keys(c, path, kp, ["scan", "image"], ["name", "laser_side", "image_endpoints_px", "pick"])
    name = capture_name(path, kp, c, i)
    files = [file_entry(path, f"{kp}.image", c["image"]), *scan_entries(path, kp, c, many=False)]
    px = None
    if "image_endpoints_px" in c:
        px = point_pairs(c["image_endpoints_px"], path, f"{kp}.image_endpoints_px", "pixel")
        inside = camera.in_image(px)
        for j in range(2):
            if not inside[j]:
                raise InputError.at(
                    path,
                    f"{kp}.image_endpoints_px[{j}]",
                    px[j].tolist(),
                    f"a pixel inside the {camera.width_px}x{camera.height_px} image",
                )
        if np.linalg.norm(px[0] - px[1]) < 2.0:
            raise InputError.at(path, f"{kp}.image_endpoints_px", px.tolist(), "two distinct box ends")
    side = c.get("laser_side")
    if "laser_side" in c and not (
        isinstance(side, dict) and len(side) == 1 and next(iter(side)) in LASER_SIDE_FORMS
    ):
        raise InputError.at(path, f"{kp}.laser_side", side, LASER_SIDE_EXPECTED)
    meta = _pick_meta(path, f"{kp}.pick", c["pick"]) if "pick" in c else None
    return _DraftEntry(c, name, px, side, meta, files)


def _read_draft(path: Path, i: int, e: _DraftEntry, camera: Camera) -> CaptureDraft:
    kp = f"captures[{i}]"
    scan, (scan_path,) = read_capture_scans(path, kp, e.c, many=False)
    image_path = session_file(path, f"{kp}.image", e.c["image"])
    check_image(path, f"{kp}.image", e.c["image"], image_path, camera)
    return CaptureDraft(i, e.name, scan_path, image_path, scan, e.side, e.px, e.meta)


def _pick_meta(path: Path, kp: str, value: Any) -> PickMeta:
    m = check_keys(value, path, kp, ["source"], ["confidence", "review"])
    if m["source"] not in ("manual", "auto"):
        raise InputError.at(path, f"{kp}.source", m["source"], "'manual' or 'auto'")
    conf = get_float(m, "confidence", path, kp) if "confidence" in m else 1.0
    if not 0.0 <= conf <= 1.0:
        raise InputError.at(path, f"{kp}.confidence", m["confidence"], "a number from 0 to 1")
    review = m.get("review", False)
    if not isinstance(review, bool):
        raise InputError.at(path, f"{kp}.review", review, "true or false")
    return PickMeta(str(m["source"]), conf, review)


def line_params_for(path: Path | None, laser: dict[str, Any]) -> LineParams:
    """Line-extraction thresholds for the picking file's scanner: scaled to its
    ``laser.range_sigma_m`` when given (``rigcal lines --range-sigma-m`` must then be
    given the same value to print the same segment ids), else the defaults."""
    if "range_sigma_m" not in laser:
        return LineParams()
    sigma = laser["range_sigma_m"]
    if not is_real(sigma) or not 0 <= sigma < 1:
        raise InputError.at(path, "laser.range_sigma_m", sigma, "a range noise in metres, 0 <= sigma < 1")
    return LineParams.for_range_noise(float(sigma))


def capture_name(path: Path, kp: str, capture: Any, i: int) -> str:
    """A capture's ``name`` (default capture00, capture01, ...), a non-empty string."""
    # Reports name files after captures: a name must stay one file-name component.
    return path_component(capture.get("name", f"capture{i:02d}"), path, f"{kp}.name")


def check_unique_names(path: Path, names: list[str]) -> None:
    """No two captures share a name (reports and overlays are named after them)."""
    for i, n in enumerate(names):
        if names.index(n) != i:
            raise InputError.at(path, f"captures[{i}].name", n, "a name not used by another capture")


def check_files_once(path: Path, named: list[tuple[str, Any]]) -> None:
    """No file is named by two of the captures' file entries (``image``, ``scan``, each of
    ``scans``; key path and value, as :func:`scan_entries` and :func:`file_entry` return
    them after each capture's entry is validated), however the paths are spelled: a
    capture listed twice, or a scan or image pasted into the wrong capture, would be
    weighed twice in the solve and shrink its covariance, with nothing wrong to see in its
    answer. The files need not exist yet (reading them comes after)."""
    seen: dict[Path, str] = {}
    for key, value in named:
        try:
            file = (path.parent / slashed(value)).resolve()
        except (OSError, RuntimeError):  # a symlink loop: session_file names it
            continue
        first = seen.setdefault(file, key)
        if first != key:
            raise InputError.at(
                path,
                key,
                value,
                f"a file no other entry names ({first} names it too: a capture listed twice?)",
            )


def file_entry(base: Path, key: str, value: Any) -> tuple[str, Any]:
    """A capture's file entry ``key: value`` as (key, value), checked to be a file path
    (relative to the session file; the file is looked for by :func:`session_file`)."""
    if not isinstance(value, str) or not value or "\0" in value:
        raise InputError.at(base, key, value, "a file path (relative to the picking file)")
    return key, value


def session_file(base: Path, key: str, value: Any) -> Path:
    file_entry(base, key, value)
    p = (base.parent / slashed(value)).resolve()  # a session written on Windows: '\' as '/'
    if not p.is_file():
        raise InputError.at(base, key, value, f"an existing file (looked for {p})")
    return p


def side_observation(
    capture: int,
    name: str,
    scan_path: Path,
    image_path: Path,
    scan: Scan,
    beams: NDArray[np.int64],
    image_endpoints_px: FloatArray,
) -> BoxObservation:
    """A capture whose box side is the scan's returns ``beams`` (a line segment's).

    The box ends are :func:`extended_ends` of those returns.
    """
    beams = np.asarray(beams, dtype=np.int64)
    points = np.array(scan.points[beams])
    ends, gaps = extended_ends(points, beams, scan)
    return BoxObservation(
        capture,
        name,
        scan_path,
        image_path,
        ends,
        points,
        beams,
        scan.step_rad,
        np.array(image_endpoints_px, dtype=float),
        gaps,
    )


def check_image(path: Path, key: str, value: str, image_path: Path, camera: Camera) -> None:
    """The image must decode and have the camera's size (a wrong camera file or a resized
    image would silently bias every pick)."""
    import cv2

    from rigcal.io.images import read_image_file

    img = read_image_file(image_path, cv2.IMREAD_UNCHANGED)
    if img is None:
        raise InputError.at(path, key, value, "an image file OpenCV can read (PNG, JPEG, ...)")
    h, w = img.shape[:2]
    if (w, h) != (camera.width_px, camera.height_px):
        raise InputError.at(
            path,
            key,
            value,
            f"an image of the camera's size {camera.width_px}x{camera.height_px}, not {w}x{h}",
        )


def point_pairs(value: Any, path: Path, key: str, what: str) -> FloatArray:
    ok = (
        isinstance(value, list)
        and len(value) == 2
        and all(isinstance(v, list) and len(v) == 2 and all(is_real(x) for x in v) for v in value)
    )
    if not ok:
        raise InputError.at(path, key, value, f"two {what} pairs [[a, b], [c, d]] of finite numbers")
    return np.array(value, dtype=float)


def _laser_side(
    path: Path,
    kp: str,
    side: Any,
    scan: Scan,
    scan_path: Path,
    line_params: LineParams,
    version: int = PICKS_SCHEMA_VERSION,
) -> NDArray[np.int64] | tuple[FloatArray, FloatArray, NDArray[np.int64]]:
    """Resolve `laser_side`: the beam indices of a segment (or of several: a side that
    line extraction split), or for two given laser points (ends (2,2), side points (M,2),
    beam indices (M,))."""
    key = f"{kp}.laser_side"
    if not isinstance(side, dict) or len(side) != 1 or next(iter(side)) not in LASER_SIDE_FORMS:
        raise InputError.at(path, key, side, LASER_SIDE_EXPECTED)
    if "segment" in side:
        seg = segment_by_id(path, f"{key}.segment", side["segment"], scan, scan_path, line_params)
        return np.array(seg.indices, dtype=np.int64)
    if "segments" in side:
        pieces = segments_by_ids(
            path, f"{key}.segments", side["segments"], scan, scan_path, line_params, version
        )
        return np.concatenate([np.asarray(g.indices, dtype=np.int64) for g in pieces])
    ends = point_pairs(side["points"], path, f"{key}.points", "laser point")
    if np.linalg.norm(ends[0] - ends[1]) < 0.05:
        raise InputError.at(path, f"{key}.points", ends.tolist(), "two distinct ends at least 5 cm apart")
    # End 0 is the end at the smaller beam angle (docs/conventions.md), as for a segment,
    # whatever order the file lists the points in; angles measured from the scan's first beam.
    a = np.mod(np.arctan2(ends[:, 1], ends[:, 0]) - scan.angles_rad[0], 2.0 * np.pi)
    if a[1] < a[0]:
        ends = ends[::-1].copy()
    beams = beams_near(scan, ends)
    pts = scan.points[beams]
    if len(beams) < 2:
        raise InputError.at(
            path,
            f"{key}.points",
            ends.tolist(),
            f"two points on the box side in the scan: fewer than 2 valid returns lie within "
            f"{100 * SIDE_POINT_TOLERANCE_M:g} cm of the line between them",
        )
    return ends, pts, beams


def segments_by_ids(
    path: Path, key: str, ids: Any, scan: Scan, scan_path: Path, line_params: LineParams, version: int
) -> list[Segment]:
    """The scan's segments ``ids`` (a target that line extraction split into pieces), in
    beam order; a picking or board session file needs schema_version 2 for them.

    Raises:
        InputError: an old file, not a non-empty list of distinct ids, or an id that is not
            a segment of this scan, naming the file, key and value.
    """
    if version < 2:
        raise InputError.at(path, key, ids, "no segments in schema_version 1 (needs 2)")
    if not isinstance(ids, list) or not ids or len(set(map(repr, ids))) != len(ids):
        raise InputError.at(path, key, ids, "a non-empty list of distinct segment ids")
    pieces = [
        segment_by_id(path, f"{key}[{j}]", sid, scan, scan_path, line_params) for j, sid in enumerate(ids)
    ]
    return sorted(pieces, key=lambda g: int(g.indices[0]))


def segment_by_id(
    path: Path, key: str, sid: Any, scan: Scan, scan_path: Path, line_params: LineParams
) -> Segment:
    """The scan's line segment ``sid``, numbered as ``rigcal lines`` prints them.

    Raises:
        InputError: not a segment id of this scan, naming the file, key and value.
    """
    segments = extract_lines(scan, line_params)
    if not (isinstance(sid, int) and not isinstance(sid, bool) and 0 <= sid < len(segments)):
        raise InputError.at(
            path,
            key,
            sid,
            f"a segment id from 0 to {len(segments) - 1} (see `rigcal lines {scan_path}`)"
            if segments
            else "a segment id, but the scan has no line segments",
        )
    return segments[sid]


def beams_near(scan: Scan, ends: FloatArray) -> NDArray[np.int64]:
    """Valid beams whose points lie on the segment between two laser points."""
    pts = scan.points
    valid = scan.valid
    d = ends[1] - ends[0]
    L = float(np.linalg.norm(d))
    u = d / L
    n = np.array([-u[1], u[0]])
    rel = np.where(valid[:, None], pts - ends[0], np.nan)
    with np.errstate(invalid="ignore"):
        along = rel @ u
        across = np.abs(rel @ n)
        keep = valid & (across < SIDE_POINT_TOLERANCE_M) & (along > -0.02) & (along < L + 0.02)
    return np.flatnonzero(keep).astype(np.int64)


def extended_ends(
    points: FloatArray, beams: NDArray[np.int64], scan: Scan
) -> tuple[FloatArray, tuple[int, int]]:
    """Box-side ends from its returns: the fitted line cut by rays just outside the first
    and last returns.

    Where the next beam jumps to something farther (the wall behind the box), the
    outermost return on the box lies up to one beam step inside the true end, so the true
    end is uniform over the next step: the ray half a step outward removes that bias on
    average. When neighbouring beams returned nothing (dropouts: 0, NaN, out of range) the
    true end may lie under any of them too: with k such beams the interval is k + 1 steps
    wide and the ray goes (k + 1) / 2 steps outward.

    Where the scan instead continues around the box's corner onto its side (the next
    return within CORNER_GAP_M), the first side returns lie within range noise of the
    side's line and the segment may hold one or two of them, or stop a return short: the
    end is taken at the outermost return (plus half of any dropouts) with an interval of
    CORNER_STEPS steps.

    Returns:
        (ends (2, 2) metres, end 0 at the smaller beam angle; interval widths in steps,
        which the refinement's noise model uses).
    """
    centroid, direction, _ = fit_line(points)
    step = scan.step_rad
    valid = scan.valid
    offsets = []
    widths = []
    for beam, outward in ((int(beams[0]), -1), (int(beams[-1]), 1)):
        k = 0
        b = beam + outward
        while 0 <= b < len(valid) and not valid[b] and k < MAX_DROPOUT_STEPS:
            k += 1
            b += outward
        corner = (
            0 <= b < len(valid)
            and bool(valid[b])
            and float(np.linalg.norm(scan.points[b] - scan.points[beam])) < CORNER_GAP_M
        )
        offsets.append(0.5 * k if corner else 0.5 * (k + 1))
        widths.append(CORNER_STEPS + k if corner else k + 1)
    a_first = scan.angles_rad[beams[0]] - offsets[0] * step
    a_last = scan.angles_rad[beams[-1]] + offsets[1] * step
    ends = np.array([_ray_line(a_first, centroid, direction), _ray_line(a_last, centroid, direction)])
    return ends, (widths[0], widths[1])


def _ray_line(angle: float, c: FloatArray, u: FloatArray) -> FloatArray:
    """Where the beam at `angle` from the origin meets the line c + s u."""
    r = np.array([np.cos(angle), np.sin(angle)])
    # lambda r = c + s u  ->  [r, -u] [lambda, s]^T = c
    A = np.column_stack([r, -u])
    if abs(np.linalg.det(A)) < 1e-9:  # beam parallel to the line: keep the nearest point
        return c
    lam, _ = np.linalg.solve(A, c)
    out: FloatArray = lam * r
    return out


def scan_entries(
    path: Path, kp: str, capture: Mapping[str, Any], many: bool, required: bool = True
) -> list[tuple[str, Any]]:
    """A capture's scan entries as (key path, value), the files not yet looked at: its
    ``scan``, or with ``many`` (a session version that has them) each of its ``scans``,
    the scans of one still moment; exactly one of the two keys (or neither, when not
    ``required``).

    Raises:
        InputError: both keys (or neither, when ``required``), an empty or non-list
            ``scans``, an entry that is not a file path.
    """
    both = many and "scan" in capture and "scans" in capture
    if both or (required and "scan" not in capture and "scans" not in capture):
        raise InputError.at(path, kp, sorted(capture), "one of scan (a file) or scans (a list of files)")
    if "scan" in capture:
        return [file_entry(path, f"{kp}.scan", capture["scan"])]
    if "scans" not in capture:
        return []
    value = capture["scans"]
    if not isinstance(value, list) or not value:
        raise InputError.at(path, f"{kp}.scans", value, "a non-empty list of scan files (one still moment)")
    return [file_entry(path, f"{kp}.scans[{j}]", v) for j, v in enumerate(value)]


def read_capture_scans(
    path: Path, kp: str, capture: Mapping[str, Any], many: bool
) -> tuple[Scan, list[Path]]:
    """A capture's scan: its ``scan`` file, or with ``many`` (a session version that has
    them) the per-beam robust mean (:func:`rigcal.scan.mean_scan`) of its ``scans``, the
    scans of one still moment; exactly one of the two keys (:func:`scan_entries`).
    Returns the scan and the files read.

    Raises:
        InputError: both keys or neither, an empty or non-list ``scans``, a missing or bad
            scan file, or scans whose beams differ from the first one's.
    """
    entries = scan_entries(path, kp, capture, many)
    files = [session_file(path, key, v) for key, v in entries]
    scans = [read_scan(p) for p in files]
    if "scan" in capture:
        return scans[0], files
    value = capture["scans"]
    for j, s in enumerate(scans[1:], 1):
        if s.angles_rad.shape != scans[0].angles_rad.shape or not np.allclose(
            s.angles_rad, scans[0].angles_rad, atol=1e-9
        ):
            raise InputError.at(
                path, f"{kp}.scans[{j}]", value[j], f"a scan with the beams of {value[0]} (one scanner)"
            )
        if (s.range_min_m, s.range_max_m) != (scans[0].range_min_m, scans[0].range_max_m):
            raise InputError.at(
                path, f"{kp}.scans[{j}]", value[j], f"a scan with the range limits of {value[0]}"
            )
    return mean_scan(scans), files


# A session reader's check of one capture's entry: (session file, schema version, index,
# entry) -> the entry as checked and its file entries (key path, value), no file looked at.
CaptureEntry = Callable[[Path, int, int, Any], tuple[Any, list[tuple[str, Any]]]]


@dataclass(frozen=True)
class SessionHeader:
    """What every plane-method session file (board, marker) starts with, validated.

    Attributes:
        data: the file's top-level mapping.
        version: its ``schema_version``.
        camera, camera_path: the camera and its file.
        laser: the scanner's description (``laser``, default empty).
        params: the line extraction's settings for that scanner.
        captures: each capture's entry as the reader's ``entry`` returned it.
    """

    data: Mapping[str, Any]
    version: int
    camera: Camera
    camera_path: Path
    laser: dict[str, Any]
    params: LineParams
    captures: list[Any]


def read_session_header(
    path: Path,
    kind: str,
    method: str,
    versions: tuple[int, ...],
    required: list[str],
    optional: list[str],
    entry: CaptureEntry,
    method_hint: str = "",
) -> SessionHeader:
    """Read a session file's top level: its keys (``schema_version``, ``method``, ``camera``,
    ``captures`` and ``required`` must be there; ``laser``, ``name`` and ``optional`` may),
    the version among ``versions``, ``method``, the camera, ``laser`` and ``captures``:
    each capture's entry checked by ``entry(path, version, index, capture)`` (its keys, name
    and file entries, no file looked at), then :func:`check_files_once` over the file
    entries of all of them, so that a capture's own error comes before the one across
    captures.

    Raises:
        InputError: anything missing, unknown or invalid, naming the file, key and value.
    """
    d = check_keys(
        load_yaml(path, kind),
        path,
        "",
        ["schema_version", "method", "camera", "captures", *required],
        ["laser", "name", *optional],
        versions,
    )
    version = d["schema_version"]
    if type(version) is not int or version not in versions:
        shown = ", ".join(map(str, versions[:-1])) + " or " * (len(versions) > 1) + str(versions[-1])
        raise InputError.at(path, "schema_version", version, f"{shown} (the versions this rigcal reads)")
    if d["method"] != method:
        raise InputError.at(path, "method", d["method"], f"'{method}'{method_hint}")
    camera_path = session_file(path, "camera", d["camera"])
    camera = read_camera(camera_path)
    laser = d.get("laser", {})
    if not isinstance(laser, dict):
        raise InputError.at(path, "laser", laser, "a mapping describing the scanner")
    params = line_params_for(path, laser)
    captures = d["captures"]
    if not isinstance(captures, list) or not captures:
        raise InputError.at(path, "captures", captures, "a non-empty list of captures")
    checked = [entry(path, version, i, c) for i, c in enumerate(captures)]
    check_files_once(path, [f for _, files in checked for f in files])
    return SessionHeader(d, version, camera, camera_path, laser, params, [c for c, _ in checked])
