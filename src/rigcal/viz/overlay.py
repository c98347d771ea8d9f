"""A scan projected onto its image with the rig's calibration (the paper's Fig. 2a).

Laser points are mapped into the camera frame with T_cam_laser (Eq. (3)) and projected
through the camera model (Eq. (1) with distortion). Picked box ends are marked as green
circles, the projected laser box ends as crosses (red when rejected); a legend in the
top-left corner names what is drawn.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from rigcal.arrays import FloatArray
from rigcal.camera import Camera
from rigcal.geometry import transform_points
from rigcal.io.files import atomic_write_bytes
from rigcal.scan import Scan

SCAN_BGR = (255, 120, 0)  # blue, as in Fig. 2a
PICK_BGR = (0, 200, 0)
END_BGR = (0, 255, 255)
REJECTED_BGR = (0, 0, 255)


def project_scan(camera: Camera, T_cam_laser: FloatArray, scan: Scan) -> tuple[FloatArray, NDArray[np.bool_]]:
    """Pixels of every beam (N, 2) and the mask of those that land in the image (N,)."""
    pts = scan.points
    q = np.full((len(pts), 2), np.nan)
    valid = scan.valid
    if valid.any():
        q[valid] = camera.project(transform_points(T_cam_laser, pts[valid]))
    inside = valid & camera.in_image(q)
    return q, inside


def draw_overlay(
    image: NDArray[np.uint8],
    camera: Camera,
    T_cam_laser: FloatArray,
    scan: Scan,
    picked_px: FloatArray | None = None,
    projected_ends_px: FloatArray | None = None,
    end_inlier: NDArray[np.bool_] | None = None,
) -> NDArray[np.uint8]:
    """Draw the projected scan and the picks on a copy of ``image`` (BGR)."""
    import cv2

    out = image.copy()
    q, inside = project_scan(camera, T_cam_laser, scan)
    for u, v in q[inside]:
        cv2.circle(out, (round(u), round(v)), 2, SCAN_BGR, -1, cv2.LINE_AA)
    if picked_px is not None:
        for u, v in picked_px:
            cv2.circle(out, (round(u), round(v)), 7, PICK_BGR, 2, cv2.LINE_AA)
    entries: list[tuple[str, tuple[int, int, int], str]] = [("laser returns", SCAN_BGR, "dot")]
    if picked_px is not None:
        entries.append(("picked box end", PICK_BGR, "circle"))
    if projected_ends_px is not None:
        ok = np.ones(len(projected_ends_px), bool) if end_inlier is None else end_inlier
        for (u, v), good in zip(projected_ends_px, ok, strict=True):
            if np.isfinite(u) and np.isfinite(v):
                colour = END_BGR if good else REJECTED_BGR
                cv2.drawMarker(out, (round(u), round(v)), colour, cv2.MARKER_CROSS, 14, 2, cv2.LINE_AA)
        entries.append(("laser box end, projected", END_BGR, "cross"))
        if not ok.all():
            entries.append(("rejected end", REJECTED_BGR, "cross"))
    draw_legend(out, entries)
    return out


def draw_legend(image: NDArray[np.uint8], entries: list[tuple[str, tuple[int, int, int], str]]) -> None:
    """A legend box in the top-left corner: one (label, BGR colour, "dot"|"circle"|"cross")
    per row, on a dimmed background so that it reads on any image."""
    import cv2

    font, size = cv2.FONT_HERSHEY_SIMPLEX, 0.45
    width = max(cv2.getTextSize(label, font, size, 1)[0][0] for label, _, _ in entries) + 40
    height = 20 * len(entries) + 8
    box = image[4 : 4 + height, 4 : 4 + width]
    box[:] = (box * 0.35).astype(np.uint8)
    for k, (label, colour, mark) in enumerate(entries):
        cx, cy = 16, 16 + 20 * k
        if mark == "dot":
            cv2.circle(image, (cx, cy), 2, colour, -1, cv2.LINE_AA)
        elif mark == "circle":
            cv2.circle(image, (cx, cy), 6, colour, 2, cv2.LINE_AA)
        else:
            cv2.drawMarker(image, (cx, cy), colour, cv2.MARKER_CROSS, 12, 2, cv2.LINE_AA)
        cv2.putText(image, label, (cx + 16, cy + 5), font, size, (255, 255, 255), 1, cv2.LINE_AA)


def write_png(path: str | Path, image: NDArray[np.uint8], force: bool = False) -> Path:
    """Encode as PNG and write atomically."""
    import cv2

    ok, buf = cv2.imencode(".png", image)
    if not ok:  # pragma: no cover - cv2 encodes any 8-bit image
        raise RuntimeError("PNG encoding failed")
    return atomic_write_bytes(path, buf.tobytes(), force=force)
