"""From a recording to a board session: the still moments where a chessboard is seen.

``rigcal capture SOURCE --target BOARD.yaml`` (a targets file with ``kind: board``,
:mod:`rigcal.targets.board`): the still moments come from
:func:`rigcal.calib.capture.find_still_periods`; then, per moment,

1. the board in the image: its corners (:func:`rigcal.calib.intrinsics.detect_corners`,
   as the board session's ``image:`` is read) and its pose by PnP
   (:func:`rigcal.calib.board.session.board_pose`);
2. the board in the scan: the moment's scans reduced to their per-beam robust mean
   (:func:`rigcal.scan.mean_scan`), the static background dropped across the captures
   and the board's returns found as ``laser_side: auto`` finds them
   (:func:`rigcal.calib.board.detect.detect_board_returns`); a capture with no candidate
   line is set aside and the search repeated over the others (the background is the
   same room seen in the captures kept).

A moment whose board is not seen in the image, or not found in the scan, is set aside
with the reason; the others are written as a board session (docs/formats/board-session.md,
schema 4: each capture's ``image``, the ``scans`` of its moment and ``laser_side: auto``)
that ``rigcal solve`` reads as it is, finding what was found here.
"""

from __future__ import annotations

from collections.abc import Sequence as Seq
from dataclasses import dataclass
from pathlib import Path

from rigcal.arrays import FloatArray
from rigcal.calib.board.detect import BoardNotFoundError, board_shape, detect_board_returns
from rigcal.calib.board.plane import MIN_CAPTURES
from rigcal.calib.board.session import BOARD_SESSION_SCANS_VERSION, board_pose, plane_observation
from rigcal.calib.capture import (
    StillCapture,
    check_capture_inputs,
    image_path,
    still_scan_indices,
    write_capture_files,
)
from rigcal.calib.intrinsics import Board, detect_corners
from rigcal.camera import Camera, read_camera
from rigcal.errors import CalibrationError, InputError
from rigcal.lines import LineParams
from rigcal.recordings.sequence import Sequence
from rigcal.scan import Scan, mean_scan
from rigcal.targets.board import BoardTarget, board_mapping

# The board poses' corner noise when the targets file gives none (the board session's default).
DEFAULT_CORNER_SIGMA_PX = 0.5


@dataclass(frozen=True)
class BoardCaptures:
    """What the board route found in the still moments.

    Attributes:
        names: every capture's name (capNN), in time order.
        corners: per capture, the board's inner corners seen in its image (0: not seen).
        scans: per capture, how many scans of its still moment it keeps.
        dropped: (name, reason) of the captures set aside.
    """

    names: tuple[str, ...]
    corners: tuple[int, ...]
    scans: tuple[int, ...]
    dropped: tuple[tuple[str, str], ...]

    @property
    def found(self) -> tuple[str, ...]:
        """The captures kept: the board seen in the image and found in the scan."""
        out = dict(self.dropped)
        return tuple(n for n in self.names if n not in out)


def target_board(target: BoardTarget) -> Board:
    """The chessboard of a board target."""
    return Board(target.corners_x, target.corners_y, target.spacing_m)


def find_boards(
    seq: Sequence,
    captures: Seq[StillCapture],
    camera: Camera,
    target: BoardTarget,
    max_scans: int | None = None,
    params: LineParams | None = None,
) -> BoardCaptures:
    """The board in each still moment's image and scans (see the module's steps).

    Args:
        seq: the recording.
        captures: its still moments.
        camera: the camera the images were taken with.
        target: the board.
        max_scans: scans of a moment kept (:func:`rigcal.calib.capture.still_scan_indices`).
        params: line extraction's settings (default: the board session's with no ``laser``).
    """
    board = target_board(target)
    sigma = target.corner_sigma_px or DEFAULT_CORNER_SIGMA_PX
    names = [f"cap{k:02d}" for k in range(len(captures))]
    corners = [0] * len(captures)
    n_scans = []
    dropped: dict[str, str] = {}
    alive: list[int] = []
    scans: list[Scan] = []
    poses: list[FloatArray] = []
    planes: list[tuple[FloatArray, float]] = []
    for k, c in enumerate(captures):
        idx = still_scan_indices(seq, c, max_scans)
        n_scans.append(len(idx))
        det = detect_corners([image_path(seq, c)], board)
        if not det.paths:
            dropped[names[k]] = f"board: no {board.width_n}x{board.height_n} chessboard found in the image"
            continue
        xy = det.corners[0, :, :, :2].reshape(-1, 2)
        corners[k] = len(xy)
        T, cov, _ = board_pose(camera, board, xy, sigma)
        o = plane_observation(k, names[k], T, cov, xy[:0])
        alive.append(k)
        scans.append(mean_scan([seq.scans[s] for s in idx]))
        poses.append(T)
        planes.append((o.normal_cam, o.distance_m))
    shape = board_shape(board, target.size_m)
    while len(alive) >= MIN_CAPTURES:
        try:
            detect_board_returns(scans, poses, planes, shape, {}, params or LineParams())
        except BoardNotFoundError as exc:
            dropped[names[alive[exc.capture]]] = f"the board in the scan: {exc.detail}"
            for lst in (alive, scans, poses, planes):
                del lst[exc.capture]
            continue
        except CalibrationError:
            pass  # no consensus: the solve says so, with the captures it has
        break
    return BoardCaptures(
        tuple(names), tuple(corners), tuple(n_scans), tuple((n, dropped[n]) for n in names if n in dropped)
    )


def write_board_capture_session(
    seq: Sequence,
    captures: Seq[StillCapture],
    output: str | Path,
    camera_file: Path,
    target: BoardTarget,
    force: bool = False,
    origin: str | Path | None = None,
    max_scans: int | None = None,
) -> BoardCaptures:
    """Find the board in every still moment (:func:`find_boards`) and write the session
    folder atomically: ``camera.*``, ``targets.yaml`` (the board's targets file),
    ``images/capNN.*`` and ``scans/capNN_JJ.yaml`` of every capture (those set aside too,
    to look at) and ``board_session.yaml`` with the captures kept.

    Raises:
        InputError: no still period, a negative range, an image not of the camera's size
            (:func:`rigcal.calib.capture.check_capture_inputs`), or no image shows the board.
        CalibrationError: the board found in fewer than MIN_CAPTURES still moments.
        OutputError: the folder exists and ``force`` is false, or a write failed.
    """
    import shutil

    import yaml

    from rigcal.io.files import atomic_folder

    origin = origin or seq.folder
    check_capture_inputs(seq, captures, camera_file, origin, max_scans)
    found = find_boards(seq, captures, read_camera(camera_file), target, max_scans)
    board = f"{target.corners_x}x{target.corners_y}"
    if not any(found.corners):
        raise InputError.at(
            target.path or origin,
            "board",
            f"{board} inner corners",
            f"the chessboard the recording shows: none of the {len(captures)} still moments of {origin} "
            "shows it (check corners_x and corners_y: inner corners, not squares)",
        )
    if len(found.found) < MIN_CAPTURES:
        why = "; ".join(f"{n}: {r}" for n, r in found.dropped)
        raise CalibrationError(
            f"{origin}: the board was found in {len(found.found)} of {len(captures)} still moments; "
            f"the board method needs {MIN_CAPTURES} ({why})"
        )
    with atomic_folder(output, force) as tmp:
        camera_name, entries = write_capture_files(tmp, seq, captures, camera_file, max_scans)
        if target.path is not None:
            shutil.copyfile(target.path, tmp / "targets.yaml")
        kept = set(found.found)
        doc = {
            "schema_version": BOARD_SESSION_SCANS_VERSION,
            "method": "board",
            "name": f"captured from {seq.name}",
            "camera": camera_name,
            "board": board_mapping(target),
            "captures": [e | {"laser_side": "auto"} for e in entries if e["name"] in kept],
        }
        head = [
            "# rigcal board session (docs/formats/board-session.md), written by rigcal capture.",
            f"# {len(captures)} still moments of {seq.name}, the {board} board found in {len(kept)}; "
            "solve it as it is: rigcal solve board_session.yaml",
        ]
        head += [f"# set aside: {n} ({r})" for n, r in found.dropped]
        (tmp / "board_session.yaml").write_text(
            "\n".join(head) + "\n" + yaml.safe_dump(doc, sort_keys=False, default_flow_style=None, width=110),
            encoding="utf-8",
        )
    return found
