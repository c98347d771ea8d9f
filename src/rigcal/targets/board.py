"""The board target: a flat chessboard, described in a targets file for ``rigcal capture``.

A targets file of schema version 2 (docs/formats/targets.md) says what kind of target it
describes (``kind: marker``, the V of :mod:`rigcal.targets.marker`, or ``kind: board``).
A board's file gives what a board session's ``board:`` mapping gives
(docs/formats/board-session.md): the inner corners per row and column, the square size,
optionally the sheet's size and the corners' noise. :func:`read_target` reads either
kind; :func:`board_mapping` is the board session's ``board:`` of a board target.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from rigcal.errors import InputError
from rigcal.io.files import check_keys, load_yaml
from rigcal.io.validate import is_real, real, whole
from rigcal.targets.marker import TARGETS_SCHEMA_VERSIONS, MarkerTarget, parse_targets

KINDS = ("marker", "board")


@dataclass(frozen=True)
class BoardTarget:
    """A chessboard target.

    Attributes:
        name: the target's name.
        corners_x, corners_y: inner corners per row and per column (OpenCV's patternSize).
        spacing_m: a square's side.
        size_m: (width, height) of the sheet, width along the rows, the pattern centred on
            it; None: the printed pattern's (inner corners plus one square all round).
        corner_sigma_px: the corners' noise in the image, None for the board method's default.
        path: the targets file it was read from, if any.
    """

    name: str
    corners_x: int
    corners_y: int
    spacing_m: float
    size_m: tuple[float, float] | None = None
    corner_sigma_px: float | None = None
    path: Path | None = None


def read_target(path: str | Path) -> MarkerTarget | BoardTarget:
    """Read and validate a targets file of either kind (docs/formats/targets.md).

    Raises:
        InputError: unreadable or invalid, one line naming the file, key and value.
    """
    path = Path(path)
    data = load_yaml(path, "targets file")
    kind = data.get("kind", "marker") if isinstance(data, dict) else "marker"
    if kind not in KINDS:
        raise InputError.at(path, "kind", kind, "marker (the V of two ChArUco faces) or board (a chessboard)")
    if kind == "board":
        return parse_board_target(data, path)
    return parse_targets(data, path)


def parse_board_target(data: Any, path: Path | None) -> BoardTarget:
    """Validate a parsed targets file with ``kind: board`` (see :func:`read_target`)."""
    d = check_keys(data, path, "", ["schema_version", "kind", "board"], ["name"], TARGETS_SCHEMA_VERSIONS)
    version = d["schema_version"]
    if type(version) is not int or version not in TARGETS_SCHEMA_VERSIONS or version < 2:
        raise InputError.at(path, "schema_version", version, "2 (kind: board needs schema version 2)")
    b = check_keys(
        d["board"], path, "board", ["corners_x", "corners_y", "spacing_m"], ["size_m", "corner_sigma_px"]
    )
    nx = whole(b["corners_x"], path, "board.corners_x", lo=2, hi=1000)
    ny = whole(b["corners_y"], path, "board.corners_y", lo=2, hi=1000)
    spacing = real(b["spacing_m"], path, "board.spacing_m", positive=True)
    size = sheet_size_m(b["size_m"], path, nx, ny, spacing) if "size_m" in b else None
    sigma = (
        real(b["corner_sigma_px"], path, "board.corner_sigma_px", positive=True)
        if "corner_sigma_px" in b
        else None
    )
    name = d.get("name", "board")
    if not isinstance(name, str):
        raise InputError.at(path, "name", name, "a string")
    return BoardTarget(name, nx, ny, spacing, size, sigma, path)


def sheet_size_m(
    v: Any, path: Path | None, corners_x: int, corners_y: int, spacing_m: float
) -> tuple[float, float]:
    """A board's ``size_m``: [width, height] of the sheet in metres, at least the printed
    pattern's (inner corners plus one square all round).

    Raises:
        InputError: not two finite numbers, or smaller than the pattern.
    """
    pattern = ((corners_x + 1) * spacing_m, (corners_y + 1) * spacing_m)
    ok = isinstance(v, list) and len(v) == 2
    ok = ok and all(is_real(x) for x in v)
    if not ok or not all(x >= p - 1e-9 for x, p in zip(v, pattern, strict=True)):
        raise InputError.at(
            path,
            "board.size_m",
            v,
            f"[width, height] of the board's sheet in metres, at least the printed pattern's "
            f"[{pattern[0]:g}, {pattern[1]:g}] (width along the rows of corners_x)",
        )
    return float(v[0]), float(v[1])


def board_mapping(target: BoardTarget) -> dict[str, Any]:
    """The board session's ``board:`` mapping of a board target."""
    out: dict[str, Any] = {
        "corners_x": target.corners_x,
        "corners_y": target.corners_y,
        "spacing_m": target.spacing_m,
    }
    if target.size_m is not None:
        out["size_m"] = [target.size_m[0], target.size_m[1]]
    if target.corner_sigma_px is not None:
        out["corner_sigma_px"] = target.corner_sigma_px
    return out


def board_target_text(target: BoardTarget) -> str:
    """The targets file of a board target (docs/formats/targets.md, schema version 2)."""
    b = board_mapping(target)
    lines = [
        "# rigcal targets file (docs/formats/targets.md)",
        "schema_version: 2",
        "kind: board",
        f"name: {target.name}",
        "board:",
        f"  corners_x: {b['corners_x']}          # inner corners per row",
        f"  corners_y: {b['corners_y']}          # inner corners per column",
        f"  spacing_m: {b['spacing_m']:g}       # a square's side",
    ]
    if "size_m" in b:
        lines.append(
            f"  size_m: [{b['size_m'][0]:g}, {b['size_m'][1]:g}]   # the sheet, width along the rows"
        )
    if "corner_sigma_px" in b:
        lines.append(f"  corner_sigma_px: {b['corner_sigma_px']:g}")
    return "\n".join(lines) + "\n"
