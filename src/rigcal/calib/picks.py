"""Picking files: the captures of a box-target session and what the user picked in each.

A picking file (docs/formats/picks.md) lists, per capture, a scan file, an image file, the
laser side of the box (a segment id as printed by ``rigcal lines``, or two laser points)
and the pixels of the two box ends in the image (paper Algorithm 1, step 2). Paths are
relative to the picking file. :func:`read_picks` validates everything and resolves each
capture into a :class:`BoxObservation`, the solver's input.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from rigcal.calib.lines import LineParams, Segment, extract_lines, fit_line
from rigcal.camera import Camera, read_camera
from rigcal.errors import InputError
from rigcal.io.files import check_keys, load_yaml
from rigcal.scan import Scan, read_scan

FloatArray = NDArray[np.float64]

PICKS_SCHEMA_VERSION = 1

# Laser points within this distance of the line through two given laser points count as
# points of the box side (for the `points:` form of laser_side).
SIDE_POINT_TOLERANCE_M = 0.03


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

    Raises:
        InputError: anything missing, unreadable or invalid, naming the file, key and value.
    """
    path = Path(path)
    data = load_yaml(path, "picking file")
    d = check_keys(data, path, "", ["schema_version", "camera", "captures"], ["laser", "name"])
    if d["schema_version"] != PICKS_SCHEMA_VERSION:
        raise InputError.at(path, "schema_version", d["schema_version"], f"{PICKS_SCHEMA_VERSION}")
    camera_path = _file(path, "camera", d["camera"])
    camera = read_camera(camera_path)
    laser = d.get("laser", {})
    if not isinstance(laser, dict) or not all(isinstance(k, str) for k in laser):
        raise InputError.at(path, "laser", laser, "a mapping describing the scanner (e.g. name: ...)")
    captures = d["captures"]
    if not isinstance(captures, list) or not captures:
        raise InputError.at(path, "captures", captures, "a non-empty list of captures")
    obs = tuple(
        _read_capture(path, i, c, camera, line_params or LineParams()) for i, c in enumerate(captures)
    )
    names = [o.name for o in obs]
    for i, n in enumerate(names):
        if names.index(n) != i:
            raise InputError.at(path, f"captures[{i}].name", n, "a name not used by another capture")
    return PickSession(path, camera, camera_path, dict(laser), obs)


def _file(base: Path, key: str, value: Any) -> Path:
    if not isinstance(value, str) or not value:
        raise InputError.at(base, key, value, "a file path (relative to the picking file)")
    p = (base.parent / value).resolve()
    if not p.is_file():
        raise InputError.at(base, key, value, f"an existing file (looked for {p})")
    return p


def _read_capture(path: Path, i: int, c: Any, camera: Camera, line_params: LineParams) -> BoxObservation:
    kp = f"captures[{i}]"
    c = check_keys(c, path, kp, ["scan", "image", "laser_side", "image_endpoints_px"], ["name"])
    name = c.get("name", f"capture{i:02d}")
    if not isinstance(name, str) or not name:
        raise InputError.at(path, f"{kp}.name", name, "a non-empty string")
    scan_path = _file(path, f"{kp}.scan", c["scan"])
    image_path = _file(path, f"{kp}.image", c["image"])
    scan = read_scan(scan_path)
    px = _pairs(c["image_endpoints_px"], path, f"{kp}.image_endpoints_px", "pixel")
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
    ends, side, beams = _laser_side(path, kp, c["laser_side"], scan, scan_path, line_params)
    step = float(np.median(np.diff(scan.angles_rad))) if len(scan.angles_rad) > 1 else 0.0
    return BoxObservation(i, name, scan_path, image_path, ends, side, beams, step, px)


def _pairs(value: Any, path: Path, key: str, what: str) -> FloatArray:
    ok = (
        isinstance(value, list)
        and len(value) == 2
        and all(
            isinstance(v, list)
            and len(v) == 2
            and all(isinstance(x, (int, float)) and not isinstance(x, bool) and np.isfinite(x) for x in v)
            for v in value
        )
    )
    if not ok:
        raise InputError.at(path, key, value, f"two {what} pairs [[a, b], [c, d]] of finite numbers")
    return np.array(value, dtype=float)


def _laser_side(
    path: Path, kp: str, side: Any, scan: Scan, scan_path: Path, line_params: LineParams
) -> tuple[FloatArray, FloatArray, NDArray[np.int64]]:
    """Resolve `laser_side` into (ends (2,2), side points (M,2), beam indices (M,))."""
    key = f"{kp}.laser_side"
    if not isinstance(side, dict) or len(side) != 1 or next(iter(side)) not in ("segment", "points"):
        raise InputError.at(path, key, side, "either {segment: ID} or {points: [[x1, y1], [x2, y2]]}")
    if "segment" in side:
        sid = side["segment"]
        segments = extract_lines(scan, line_params)
        if not (isinstance(sid, int) and not isinstance(sid, bool) and 0 <= sid < len(segments)):
            raise InputError.at(
                path,
                f"{key}.segment",
                sid,
                f"a segment id from 0 to {len(segments) - 1} (see `rigcal lines {scan_path}`)"
                if segments
                else "a segment id, but the scan has no line segments",
            )
        seg: Segment = segments[sid]
        return _extended_ends(seg.points, seg.indices, scan), np.array(seg.points), np.array(seg.indices)
    ends = _pairs(side["points"], path, f"{key}.points", "laser point")
    if np.linalg.norm(ends[0] - ends[1]) < 0.05:
        raise InputError.at(path, f"{key}.points", ends.tolist(), "two distinct ends at least 5 cm apart")
    beams = _beams_near(scan, ends)
    pts = scan.points[beams]
    if len(beams) < 2:
        return ends, ends.copy(), np.zeros(0, dtype=np.int64)
    return ends, pts, beams


def _beams_near(scan: Scan, ends: FloatArray) -> NDArray[np.int64]:
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


def _extended_ends(points: FloatArray, beams: NDArray[np.int64], scan: Scan) -> FloatArray:
    """Box-side ends from a segment: the fitted line cut by the rays half a beam step outside
    the first and last returns.

    The first and last returns on the box lie up to one beam step inside its true ends;
    half a step outward removes that bias on average (the residual is uniform within
    +/- half a step, the noise model the refinement uses).
    """
    centroid, direction, _ = fit_line(points)
    a_first = scan.angles_rad[beams[0]]
    a_last = scan.angles_rad[beams[-1]]
    step = float(np.median(np.diff(scan.angles_rad)))
    return np.array(
        [
            _ray_line(a_first - 0.5 * step, centroid, direction),
            _ray_line(a_last + 0.5 * step, centroid, direction),
        ]
    )


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
