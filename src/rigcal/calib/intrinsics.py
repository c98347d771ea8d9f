"""Camera intrinsics from chessboard images: OpenCV detection, mrcal solve.

1. **Corners.** Each image's inner chessboard corners are found with OpenCV
   (``findChessboardCornersSB``, falling back to ``findChessboardCorners`` refined with
   ``cornerSubPix``), or the corners of a ChArUco board with ``cv2.aruco.CharucoDetector``
   (partly visible boards count: unseen corners get weight -1), or they are read from a
   corners file in mrcal's ``corners.vnl`` form (``# filename x y level``, as mrgingham
   writes it).
2. **Seed.** mrcal's ``seed_stereographic`` estimates a stereographic core and the board
   poses from a focal-length guess, which two short mrcal solves refine (geometry only,
   then the core), as ``mrcal-calibrate-cameras`` does.
3. **Solve.** The full lens model (e.g. ``LENSMODEL_OPENCV8`` or a splined model) is
   optimised by ``mrcal.optimize`` with outlier rejection and regularisation; the result is
   a mrcal camera model that keeps its optimisation inputs, so mrcal's projection
   uncertainty is available from it.
4. **Report.** RMS and worst reprojection errors over the inliers and over every detected
   corner (outliers included), per image, outliers, and mrcal's projection uncertainty
   (1-sigma, worst direction) at the image centre and corners; warnings for a degenerate
   set (:func:`degeneracy_warnings`). When a board is not found, other common board sizes
   are tried (:func:`other_board_sizes`).
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from rigcal.arrays import FloatArray
from rigcal.errors import CalibrationError, InputError
from rigcal.io.files import read_text, text_lines

MIN_IMAGES = 3
# An image whose board has fewer non-outlier corners than this is reported as unusable.
MIN_CORNERS_PER_BOARD = 10
# Degenerate sets: every board normal within this of the mean (deg); two views this close
# in rotation (deg) and position (fraction of the distance) count as the same view;
# fx / fy this far from 1; uncertainty at the image centre above this (px).
MIN_TILT_SPREAD_DEG = 10.0
SAME_VIEW_DEG, SAME_VIEW_FRACTION = 1.0, 0.01
MAX_ASPECT_DEVIATION = 0.05
MAX_CENTRE_UNCERTAINTY_PX = 1.0
# Weak geometry: boards turned about one camera axis only (the normals' spread about the
# other below MIN_TILT_SPREAD_DEG); a focal length whose 1-sigma (mrcal's, from the solve)
# is over this fraction; fewer views than this (the noise and the sigmas are then
# estimated from few views and may understate the error).
MAX_FOCAL_REL_SIGMA = 0.005
MIN_VIEWS = 10
# Inner-corner grids of common chessboards (OpenCV's samples, calib.io, printed A4/A3 ones),
# tried when the given board is not found.
COMMON_BOARDS = ((9, 6), (8, 6), (7, 5), (7, 6), (8, 5), (6, 4), (5, 4), (10, 7), (11, 8), (9, 7),
                 (11, 7), (12, 9), (13, 9), (7, 7), (8, 8), (6, 5), (5, 3), (4, 3))  # fmt: skip


@dataclass(frozen=True)
class Board:
    """A chessboard: its inner-corner grid and square size.

    Attributes:
        width_n, height_n: inner corners per row and per column (OpenCV's patternSize).
        spacing_m: square size, metres.
    """

    width_n: int
    height_n: int
    spacing_m: float

    def __post_init__(self) -> None:
        if self.width_n < 2 or self.height_n < 2 or not self.spacing_m > 0:
            raise ValueError("Board: need at least 2x2 inner corners and a positive spacing")


@dataclass(frozen=True)
class CharucoBoard:
    """A ChArUco board (OpenCV's ``cv2.aruco.CharucoBoard``).

    Attributes:
        squares_x, squares_y: squares per row and per column.
        square_m, marker_m: square and marker sizes, metres.
        dictionary: the ArUco dictionary's name in ``cv2.aruco``, e.g. ``DICT_5X5_100``.
    """

    squares_x: int
    squares_y: int
    square_m: float
    marker_m: float
    dictionary: str = "DICT_5X5_100"

    def __post_init__(self) -> None:
        if self.squares_x < 3 or self.squares_y < 3 or not 0 < self.marker_m < self.square_m:
            raise ValueError("CharucoBoard: need at least 3x3 squares and 0 < marker_m < square_m")

    @property
    def grid(self) -> Board:
        """Its inner-corner grid, as mrcal sees it."""
        return Board(self.squares_x - 1, self.squares_y - 1, self.square_m)

    def opencv(self) -> Any:
        import cv2

        name = self.dictionary
        if not name.startswith("DICT_") or not hasattr(cv2.aruco, name):
            raise InputError.at(None, "dictionary", name, "an ArUco dictionary such as DICT_5X5_100")
        d = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, name))
        return cv2.aruco.CharucoBoard((self.squares_x, self.squares_y), self.square_m, self.marker_m, d)


@dataclass(frozen=True)
class Detections:
    """Corners of the images a board was found in.

    Attributes:
        paths: the images (or names from a corners file) with a board, in input order.
        corners: (N, height_n, width_n, 3) x, y (px) and weight per corner (mrcal's
            ``observations_board``; weight < 0 marks a corner to ignore).
        missing: images in which no board was found.
        imagersize: (width, height) of the images.
    """

    paths: tuple[str, ...]
    corners: FloatArray
    missing: tuple[str, ...]
    imagersize: tuple[int, int]


@dataclass(frozen=True)
class IntrinsicsResult:
    """A solved camera and how well it fits."""

    model: Any  # mrcal.cameramodel, with its optimization_inputs
    rms_px: float
    worst_px: float
    per_image_rms_px: dict[str, float]
    outliers: int
    corners: int
    uncertainty_px: dict[str, float]
    images_used: int
    rms_all_px: float = float("nan")
    worst_all_px: float = float("nan")
    warnings: tuple[str, ...] = ()


def detect_corners(images: list[Path], board: Board) -> Detections:
    """Find the chessboard in every image.

    Raises:
        InputError: an image is missing or unreadable, or the images differ in size.
    """
    import cv2

    def find(img: NDArray[Any]) -> FloatArray | None:
        xy = _find_board(cv2, img, board)
        if xy is None:
            return None
        ones = np.ones((board.height_n, board.width_n, 1))
        out: FloatArray = np.concatenate([xy.reshape(board.height_n, board.width_n, 2), ones], axis=2)
        return out

    return _detect_all(images, board, find)


def detect_charuco(images: list[Path], board: CharucoBoard) -> Detections:
    """Find a ChArUco board in every image. Corners it does not see get weight -1 (mrcal
    ignores them); an image with fewer than MIN_CORNERS_PER_BOARD corners counts as
    missing.

    Raises:
        InputError: an image is missing or unreadable, or the images differ in size.
    """
    import cv2

    detector = cv2.aruco.CharucoDetector(board.opencv())
    grid = board.grid

    def find(img: NDArray[Any]) -> FloatArray | None:
        corners, ids, _, _ = detector.detectBoard(img)
        if ids is None or len(ids) < MIN_CORNERS_PER_BOARD:
            return None
        obs = np.zeros((grid.height_n * grid.width_n, 3))
        obs[:, 2] = -1.0
        obs[ids.ravel(), :2] = corners.reshape(-1, 2)
        obs[ids.ravel(), 2] = 1.0
        out: FloatArray = obs.reshape(grid.height_n, grid.width_n, 3)
        return out

    return _detect_all(images, grid, find)


def _detect_all(
    images: list[Path], grid: Board, find: Callable[[NDArray[Any]], FloatArray | None]
) -> Detections:
    """Read every image (grey), check they share one size, and run ``find`` on each: it
    returns the (height_n, width_n, 3) observations of the board, or None."""
    import cv2

    from rigcal.io.images import read_image_file

    paths: list[str] = []
    found: list[FloatArray] = []
    missing: list[str] = []
    size: tuple[int, int] | None = None
    first: Path | None = None
    for path in images:
        img = read_image_file(path, cv2.IMREAD_GRAYSCALE)
        if img is None:
            raise InputError(f"{path}: image not found or not readable (expected PNG, JPEG, ...)")
        h, w = img.shape
        if size is None:
            size, first = (w, h), path
        elif (w, h) != size:
            raise InputError(f"{path}: image is {w}x{h}; expected {size[0]}x{size[1]} like {first}")
        obs = find(img)
        if obs is None:
            missing.append(str(path))
            continue
        paths.append(str(path))
        found.append(obs)
    if size is None:
        raise InputError("no images given")
    corners = np.array(found) if found else np.zeros((0, grid.height_n, grid.width_n, 3))
    return Detections(tuple(paths), corners, tuple(missing), size)


def _find_board(cv2: Any, img: NDArray[Any], board: Board) -> FloatArray | None:
    pattern = (board.width_n, board.height_n)
    ok, xy = cv2.findChessboardCornersSB(img, pattern, flags=cv2.CALIB_CB_EXHAUSTIVE | cv2.CALIB_CB_ACCURACY)
    if not ok:
        ok, xy = cv2.findChessboardCorners(
            img, pattern, flags=cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE
        )
        if not ok:
            return None
        criteria = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 50, 0.01)
        xy = cv2.cornerSubPix(img, xy, (11, 11), (-1, -1), criteria)
    # Row-major, width_n per row. OpenCV may start the grid at either end; both orders are
    # the same planar grid (turned 180 deg about its centre), which mrcal's per-image board
    # poses absorb.
    out: FloatArray = np.asarray(xy, dtype=float).reshape(-1, 2)
    return out


def read_corners_vnl(path: Path, board: Board, imagersize: tuple[int, int]) -> Detections:
    """Read a corners file in mrcal's ``corners.vnl`` form.

    Each row is ``filename x y [level]``; an image whose board was not found has one row
    ``filename - - -``. ``level`` is a decimation level (weight 1/2^level; ``-`` or < 0:
    ignore the corner). Rows of one image are consecutive, width_n * height_n of them.

    Raises:
        InputError: unreadable file, or a row or image that does not fit the board.
    """
    text = read_text(path, "corners file")
    per_image: dict[str, list[tuple[float, float, float]]] = {}
    order: list[str] = []
    missing: list[str] = []
    for n, line in enumerate(text_lines(text), start=1):
        body = line.strip()
        if not body or body.startswith("#"):
            continue
        f = body.split()
        if len(f) not in (3, 4):
            raise InputError(f"{path}: line {n}: got {len(f)} fields; expected 'filename x y [level]'")
        name = f[0]
        if f[1] == "-":
            missing.append(name)
            continue
        try:
            x, y = float(f[1]), float(f[2])
            level = f[3] if len(f) == 4 else "0"
            lv = -1.0 if level == "-" else float(level)
            weight = -1.0 if lv < 0 else 0.5**lv
            if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(lv)):
                raise ValueError("not finite")
        except ValueError:
            raise InputError(
                f"{path}: line {n}: got {body[:60]!r}; expected 'filename x y [level]' numbers"
            ) from None
        if name not in per_image:
            per_image[name] = []
            order.append(name)
        per_image[name].append((x, y, weight))
    need = board.width_n * board.height_n
    grids = []
    for name in order:
        rows = per_image[name]
        if len(rows) != need:
            raise InputError(
                f"{path}: {name}: got {len(rows)} corners; "
                f"expected {need} for a {board.width_n}x{board.height_n} board"
            )
        grids.append(np.array(rows).reshape(board.height_n, board.width_n, 3))
    corners = np.array(grids) if grids else np.zeros((0, board.height_n, board.width_n, 3))
    return Detections(tuple(order), corners, tuple(missing), imagersize)


def write_corners_vnl(detections: Detections) -> str:
    """The detections as a ``corners.vnl`` text (weights written back as levels)."""
    rows = ["# filename x y level"]
    for name, grid in zip(detections.paths, detections.corners, strict=True):
        for x, y, w in grid.reshape(-1, 3):
            level = "-" if w <= 0 else f"{abs(float(np.log2(w))):g}"
            rows.append(f"{name} {x:.4f} {y:.4f} {level}")
    rows += [f"{name} - - -" for name in detections.missing]
    return "\n".join(rows) + "\n"


def check_lensmodel(lensmodel: str, key: str = "lensmodel") -> str:
    """``lensmodel`` if mrcal knows it (its parameter count can be computed).

    Raises:
        InputError: ``KEY: got NAME; expected a mrcal lens model ...``.
    """
    import mrcal

    try:
        mrcal.lensmodel_num_params(lensmodel)
    except Exception:  # mrcal raises bare Exceptions for unknown names
        raise InputError.at(None, key, lensmodel, "a mrcal lens model, e.g. LENSMODEL_OPENCV8") from None
    return lensmodel


def solve_intrinsics(
    detections: Detections,
    board: Board,
    lensmodel: str = "LENSMODEL_OPENCV8",
    focal_estimate_px: float | None = None,
) -> IntrinsicsResult:
    """Solve the camera's intrinsics with mrcal.

    Args:
        detections: the board corners.
        board: the board.
        lensmodel: the mrcal lens model to fit.
        focal_estimate_px: a rough focal length for the seed (default: the image width,
            about a 53 deg field of view; mrcal's seed is tolerant of a factor of 2).

    Raises:
        CalibrationError: too few images with a board, or the solve failed.
        InputError: an unknown lens model.
    """
    import mrcal

    check_lensmodel(lensmodel)
    n = len(detections.paths)
    if n < MIN_IMAGES:
        raise CalibrationError(
            f"the board was found in {n} image(s); at least {MIN_IMAGES} are needed (20 or more, "
            "tilted and covering the whole image, are recommended)"
            + (
                f"; not found in: {', '.join(Path(p).name for p in detections.missing)}"
                if detections.missing
                else ""
            )
        )
    W, H = detections.imagersize
    imagersizes = np.array([[W, H]], dtype=np.int32)
    # mrcal marks outliers in place: work on a copy, the detections stay as found.
    observations = np.array(detections.corners, dtype=float, order="C", copy=True)
    indices_frame_camera = np.column_stack([np.arange(n), np.zeros(n)]).astype(np.int32)
    indices = np.column_stack([indices_frame_camera, -np.ones(n)]).astype(np.int32)
    focal = float(focal_estimate_px or W)
    try:
        intr, rt_cam_ref, rt_ref_frame = mrcal.seed_stereographic(
            imagersizes=imagersizes,
            focal_estimate=focal,
            indices_frame_camera=indices_frame_camera,
            observations=observations,
            object_spacing=board.spacing_m,
        )
        common: dict[str, Any] = {
            "rt_cam_ref": rt_cam_ref,
            "rt_ref_frame": rt_ref_frame,
            "points": None,
            "observations_point": None,
            "indices_point_camintrinsics_camextrinsics": None,
            "calobject_warp": None,
            "observations_board": observations,
            "indices_frame_camintrinsics_camextrinsics": indices,
            "imagersizes": imagersizes,
            "calibration_object_spacing": board.spacing_m,
            "do_optimize_calobject_warp": False,
            "verbose": False,
        }
        # Seed refinement: board poses only, then the stereographic core too.
        for core in (False, True):
            mrcal.optimize(
                intrinsics=intr,
                lensmodel="LENSMODEL_STEREOGRAPHIC",
                do_optimize_intrinsics_core=core,
                do_optimize_intrinsics_distortions=False,
                do_apply_outlier_rejection=False,
                do_apply_regularization=False,
                **common,
            )
        n_extra = mrcal.lensmodel_num_params(lensmodel) - intr.shape[-1]
        rng = np.random.default_rng(0)
        extra = (rng.random((1, n_extra)) - 0.5) * 2e-6
        if re.search("OPENCV([0-9]+)", lensmodel) and int(re.search("OPENCV([0-9]+)", lensmodel)[1]) >= 8:  # type: ignore[index]
            extra[:, 5:8] *= 1e-3  # keep the rational terms near 0 (mrcal-calibrate-cameras)
        intrinsics = np.ascontiguousarray(np.concatenate([intr, extra], axis=1))
        inputs: dict[str, Any] = {
            "intrinsics": intrinsics,
            "lensmodel": lensmodel,
            "do_optimize_intrinsics_core": not lensmodel.startswith("LENSMODEL_SPLINED"),
            "do_optimize_intrinsics_distortions": True,
            "do_optimize_extrinsics": False,
            "do_optimize_frames": True,
            "do_apply_outlier_rejection": True,
            "do_apply_regularization": True,
            **common,
        }
        stats = mrcal.optimize(**inputs)
    except CalibrationError:
        raise
    except Exception as exc:  # mrcal raises plain exceptions for failed solves
        raise CalibrationError(f"the mrcal solve failed: {str(exc).strip().splitlines()[0][:120]}") from None
    model = mrcal.cameramodel(optimization_inputs=inputs, icam_intrinsics=0)
    return _result(model, inputs, stats, detections)


def _result(model: Any, inputs: dict[str, Any], stats: dict[str, Any], det: Detections) -> IntrinsicsResult:
    import mrcal

    obs = inputs["observations_board"]  # mrcal marks outliers with weight -1 in place
    H, W = obs.shape[1:3]
    ref = mrcal.ref_calibration_object(W, H, inputs["calibration_object_spacing"])  # (H, W, 3)
    p_cam = mrcal.transform_point_rt(inputs["rt_ref_frame"][:, None, None, :], ref[None])
    q = mrcal.project(p_cam, *model.intrinsics())
    err = np.linalg.norm(q - obs[..., :2], axis=-1).reshape(obs.shape[0], -1)  # pixels, unweighted
    inlier = obs[..., 2].reshape(obs.shape[0], -1) > 0
    per_image = {
        Path(p).name: round(
            float(np.sqrt(np.mean(err[i][inlier[i]] ** 2))) if inlier[i].any() else float("nan"), 4
        )
        for i, p in enumerate(det.paths)
    }
    W, H = det.imagersize
    where = {
        "centre": (0.5 * (W - 1), 0.5 * (H - 1)),
        "top_left_corner": (0.05 * W, 0.05 * H),
        "bottom_right_corner": (0.95 * W, 0.95 * H),
    }
    unc: dict[str, float] = {}
    for name, q in where.items():
        v = mrcal.unproject(np.array(q, dtype=float), *model.intrinsics())
        s = mrcal.projection_uncertainty(v * 10.0, model, what="worstdirection-stdev")
        unc[name] = round(float(s), 4)
    # "All": every corner the detector reported (outliers mrcal rejected included).
    detected = np.asarray(det.corners)[..., 2].reshape(obs.shape[0], -1) > 0
    result = IntrinsicsResult(
        model=model,
        rms_px=round(float(np.sqrt(np.mean(err[inlier] ** 2))), 4),
        worst_px=round(float(err[inlier].max()), 4),
        per_image_rms_px=per_image,
        outliers=int(stats.get("Noutliers_board", (~inlier).sum())),
        corners=int(inlier.size),
        uncertainty_px=unc,
        images_used=len(det.paths),
        rms_all_px=round(float(np.sqrt(np.mean(err[detected] ** 2))), 4),
        worst_all_px=round(float(err[detected].max()), 4),
    )
    return replace(result, warnings=degeneracy_warnings(result, inputs["rt_ref_frame"], det))


def degeneracy_warnings(
    result: IntrinsicsResult, rt_ref_frame: FloatArray, det: Detections
) -> tuple[str, ...]:
    """Why a solve may be weaker than its residuals say: boards all at one tilt, repeated
    views, fx / fy far from 1, a large uncertainty at the image centre.

    Args:
        result: the solve's figures.
        rt_ref_frame: (N, 6) the boards' poses in the camera (mrcal rt: rotation vector,
            translation).
        det: the detections (image names).
    """
    from scipy.spatial.transform import Rotation

    out = []
    R = Rotation.from_rotvec(np.asarray(rt_ref_frame)[:, :3])
    t = np.asarray(rt_ref_frame)[:, 3:]
    normals = R.apply(np.array([0.0, 0.0, 1.0]))
    mean = normals.mean(axis=0)
    mean /= np.linalg.norm(mean)
    spread = float(np.degrees(np.arccos(np.clip(np.abs(normals @ mean), -1.0, 1.0))).max())
    if spread < MIN_TILT_SPREAD_DEG:
        out.append(
            f"every board is seen within {spread:.1f} deg of one tilt: focal length and distortion are "
            "poorly separated; tilt the board (up to 45 deg) in some images"
        )
    out += weak_geometry_warnings(result.model, normals, len(t))
    same = []
    for i in range(len(t)):
        for j in range(i + 1, len(t)):
            dR = float(np.degrees((R[i].inv() * R[j]).magnitude()))
            dt = float(np.linalg.norm(t[i] - t[j]) / max(np.linalg.norm(t[i]), 1e-9))
            if dR < SAME_VIEW_DEG and dt < SAME_VIEW_FRACTION:
                same.append((Path(det.paths[i]).name, Path(det.paths[j]).name))
    if same:
        pairs = ", ".join(f"{a} = {b}" for a, b in same[:3]) + (" ..." if len(same) > 3 else "")
        out.append(f"{len(same)} pairs of images show nearly the same view ({pairs}): they add little")
    fx, fy = (float(x) for x in result.model.intrinsics()[1][:2])
    if abs(fx / fy - 1.0) > MAX_ASPECT_DEVIATION:
        out.append(f"fx / fy = {fx / fy:.3f}, far from 1 (square pixels): check the board size and the set")
    centre = result.uncertainty_px.get("centre", 0.0)
    if centre > MAX_CENTRE_UNCERTAINTY_PX:
        out.append(
            f"projection uncertainty at the image centre {centre:.2f} px "
            f"(over {MAX_CENTRE_UNCERTAINTY_PX:g}): take more images, nearer and covering the whole image"
        )
    return tuple(out)


def weak_geometry_warnings(model: Any, normals_cam: FloatArray, n_views: int) -> list[str]:
    """Which direction of the intrinsics a set of views leaves weak, and what views to add.

    - Boards turned about one camera axis only (e.g. upright against a wall, only swung
      left and right): the normals' spread about the other axis is under
      MIN_TILT_SPREAD_DEG while the whole spread is not (that case is "one tilt");
      the focal length is then fixed by one direction of foreshortening only.
    - The focal length's 1-sigma from mrcal's own uncertainty of the solve
      (:func:`rigcal.camera.intrinsics_covariance`) over MAX_FOCAL_REL_SIGMA, and the
      principal point's over 1 % of the image.
    - Fewer than MIN_VIEWS views: every sigma above is then estimated from few views.

    Args:
        model: the solved mrcal model (with its optimization_inputs).
        normals_cam: (N, 3) the boards' unit normals in the camera frame.
        n_views: the views used.
    """
    from rigcal.camera import intrinsics_covariance

    out = []
    n = np.asarray(normals_cam, dtype=float)
    n = n * np.sign(n[:, 2:3] + 1e-300)
    # Left-right turn (about the camera's y axis) and up-down tilt (about its x axis).
    turn = np.degrees(np.arctan2(n[:, 0], n[:, 2]))
    tilt = np.degrees(np.arctan2(n[:, 1], n[:, 2]))
    spans = {"left-right": float(np.ptp(turn)), "up-down": float(np.ptp(tilt))}
    weak = [k for k, v in spans.items() if v < MIN_TILT_SPREAD_DEG]
    if len(weak) == 1:
        other = (
            "tilted forward and back (about its horizontal axis)"
            if weak[0] == "up-down"
            else ("turned left and right (about its vertical axis)")
        )
        out.append(
            f"the boards are turned one way only: their normals span {spans[weak[0]]:.1f} deg {weak[0]} "
            f"(and {spans['left-right' if weak[0] == 'up-down' else 'up-down']:.1f} deg the other way), so "
            f"the focal length and principal point are fixed by one direction of foreshortening; add "
            f"views with the board {other} by 20-45 deg"
        )
    _, intr = model.intrinsics()
    cov = intrinsics_covariance(model)
    if cov is not None:
        s = np.sqrt(np.clip(np.diag(cov), 0.0, None))
        rel = s[:2] / np.asarray(intr[:2], dtype=float)
        W, H = model.imagersize()
        if rel.max() > MAX_FOCAL_REL_SIGMA or s[2] > 0.01 * W or s[3] > 0.01 * H:
            out.append(
                f"weak geometry: the focal length is known to {100 * rel.max():.1f} % (fx {s[0]:.1f} px, "
                f"fy {s[1]:.1f} px, 1-sigma) and the principal point to {s[2]:.1f}, {s[3]:.1f} px: the views "
                "are too alike; add views with the board tilted 20-45 deg about both of its axes, near the "
                "image's corners and edges, and nearer and farther"
            )
    if n_views < MIN_VIEWS:
        out.append(
            f"only {n_views} views: the corner noise and every uncertainty above are estimated from few "
            f"views and may understate the error; take {MIN_VIEWS} or more (20 recommended), the board "
            "tilted differently in each"
        )
    return out


def other_board_sizes(images: list[Path], board: Board, max_images: int = 3) -> dict[str, tuple[int, int]]:
    """For up to ``max_images`` images in which ``board`` was not found: the first common
    chessboard size (COMMON_BOARDS, either orientation) found in it instead.

    Returns:
        image name -> (width_n, height_n) of the board found, for the images where one was.
    """
    import cv2

    from rigcal.io.images import read_image_file

    # Larger grids first: a detector may take part of a large board for a smaller one.
    given = {(board.width_n, board.height_n), (board.height_n, board.width_n)}
    sizes = sorted((s for s in COMMON_BOARDS if s not in given), key=lambda s: -s[0] * s[1])
    flags = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE | cv2.CALIB_CB_FAST_CHECK
    out: dict[str, tuple[int, int]] = {}
    for path in images[:max_images]:
        img = read_image_file(path, cv2.IMREAD_GRAYSCALE)
        if img is None:
            continue
        for w, h in sizes:
            ok, _ = cv2.findChessboardCorners(img, (w, h), flags=flags)
            if ok:
                out[Path(path).name] = (w, h)
                break
    return out
