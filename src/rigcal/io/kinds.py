"""What kind of file is this? So that a file given in the wrong place is named as what it is.

Readers say what they expect (``load_yaml(path, "scan file")``); when the file is clearly
another kind rigcal knows (a picking file given as a rig, a sequence's ``scans.npz`` given
as a scan, a bag, an image), :mod:`rigcal.io.files` says so in one line instead of failing
on a key or a decode error. Detection is by content and conservative: a file that matches
no signature is left to the reader's own checks.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

# Kind (as readers name it) -> its documentation.
DOCS = {
    "picking file": "docs/formats/session.md",
    "board session file": "docs/formats/board-session.md",
    "rig file": "docs/formats/rig.md",
    "truth file": "docs/formats/truth.md",
    "scan file": "docs/formats/scan.md",
    "sequence file": "docs/formats/sequence.md",
    "camera file": "docs/formats/camera.md",
    "world file": "docs/formats/world.md",
}
# Readers that also accept another kind (``rigcal solve`` takes either session).
ACCEPTS = {"picking file": {"board session file"}}
# Keys only files of that kind have: a file with any of the expected kind's is a broken
# file of that kind (its reader says what is wrong), never "another kind".
DISTINCT = {
    "picking file": {"captures"},
    "board session file": {"method", "board", "corners_vnl"},
    "rig file": {"T_cam_laser", "uncertainty", "residuals", "provenance"},
    "truth file": {"T_cam_laser", "generator"},
    "scan file": {"ranges_m", "range_min_m", "range_max_m", "angles_rad", "angle_min_rad"},
    "sequence file": {"scans", "images", "groundtruth"},
    "camera file": {
        "K",
        "image_width_px",
        "image_height_px",
        "camera_matrix",
        "distortion_model",
        "lensmodel",
    },
    "world file": {"walls", "obstacles", "laser_height_m"},
}

_MAGIC = (
    (b"PK\x03\x04", "a zip archive such as NumPy's .npz (a sequence folder's scans.npz?)"),
    (b"\x93NUMPY", "a NumPy .npy array"),
    (b"\x89PNG", "a PNG image"),
    (b"\xff\xd8\xff", "a JPEG image"),
    (b"#ROSBAG", "a ROS 1 bag"),
    (b"SQLite format 3", "an SQLite database (a ROS 2 bag's .db3?)"),
    (b"%PDF", "a PDF document"),
)


def kind_of_bytes(head: bytes) -> str | None:
    """A description of a binary file from its first bytes, or None."""
    for magic, what in _MAGIC:
        if head.startswith(magic):
            return what
    return None


def kind_of_mapping(data: Any) -> str | None:
    """The rigcal file kind a parsed YAML mapping is, by its signature keys, or None."""
    if not isinstance(data, Mapping):
        return None
    keys = set(data)
    if data.get("method") == "board" and "captures" in keys:
        return "board session file"
    if {"captures", "camera"} <= keys:
        return "picking file"
    if {"T_cam_laser", "camera"} <= keys:
        return "rig file"
    if "T_cam_laser" in keys:
        return "truth file"
    if "ranges_m" in keys:
        return "scan file"
    if {"scans", "images"} <= keys:
        return "sequence file"
    if {"K", "image_width_px"} <= keys or {"camera_matrix", "distortion_coefficients"} <= keys:
        return "camera file"
    if {"walls", "path"} <= keys:
        return "world file"
    return None


def wrong_kind(path: Path, data: Any, expected: str) -> str | None:
    """The one-line message when ``data`` (read from ``path``) is another known kind than
    ``expected``; None when it is not (or unknown)."""
    if expected not in DOCS or not isinstance(data, Mapping) or DISTINCT[expected] & set(data):
        return None
    found = kind_of_mapping(data)
    if found is None or found == expected or found in ACCEPTS.get(expected, set()):
        return None
    return f"{path}: got a {found} ({DOCS[found]}); expected a {expected} ({DOCS[expected]})"


def binary_message(path: Path, expected: str) -> str | None:
    """The one-line message when a text file was expected and ``path`` is a known binary
    kind; None when it is not recognised."""
    try:
        with open(path, "rb") as f:
            head = f.read(32)
    except OSError:
        return None
    found = kind_of_bytes(head)
    if found is None:
        return None
    doc = f" ({DOCS[expected]})" if expected in DOCS else ""
    return f"{path}: got {found}; expected a {expected}{doc}, which is text"
