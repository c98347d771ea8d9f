"""Synthetic images of a flat calibration board seen through a camera model.

Every pixel's ray (through the full lens model, distortion included) is cut with the
board's plane and the board's texture is sampled there, so the corners in the image are
exactly where the camera model projects them: a test of an intrinsics solve with a known
answer.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from rigcal.arrays import FloatArray
from rigcal.camera import Camera
from rigcal.geometry import inv_T


def render_board(
    camera: Camera,
    texture: NDArray[np.uint8],
    board_size_m: tuple[float, float],
    T_cam_board: FloatArray,
    origin_m: tuple[float, float] = (0.0, 0.0),
    background: NDArray[np.uint8] | None = None,
    rays: FloatArray | None = None,
) -> NDArray[np.uint8]:
    """The camera's image of a board lying in its frame's z = 0 plane.

    Args:
        camera: the camera model.
        texture: the board's picture (grey or BGR), its top-left at ``origin_m`` in the
            board frame, x to the right and y down, covering ``board_size_m``.
        board_size_m: (width, height) of the picture on the board, metres.
        T_cam_board: (4, 4) the board's pose in the camera frame.
        origin_m: (x, y) the picture's top-left corner in the board frame.
        background: (height_px, width_px[, 3]) what pixels that miss the board show
            (the texture's channels); None: white.
        rays: (height_px * width_px, 3) every pixel's bearing, row-major, when the caller
            has them (:func:`rigcal.sim.render.pixel_bearings`); None: computed here.

    Returns:
        (height_px, width_px[, 3]) uint8.
    """
    import cv2

    W, H = camera.width_px, camera.height_px
    if rays is None:
        u, v = np.meshgrid(np.arange(W, dtype=float), np.arange(H, dtype=float))
        rays = camera.bearings(np.column_stack([u.ravel(), v.ravel()]))
    T_board_cam = inv_T(T_cam_board)
    d = rays @ T_board_cam[:3, :3].T
    o = T_board_cam[:3, 3]
    with np.errstate(divide="ignore", invalid="ignore"):
        s = -o[2] / d[:, 2]
    p = o[None, :2] + s[:, None] * d[:, :2] - np.asarray(origin_m)
    p[~(s > 0)] = -1e6
    th, tw = texture.shape[:2]
    map_x = (p[:, 0] / board_size_m[0] * tw - 0.5).reshape(H, W).astype(np.float32)
    map_y = (p[:, 1] / board_size_m[1] * th - 0.5).reshape(H, W).astype(np.float32)
    if background is None:
        out = cv2.remap(texture, map_x, map_y, cv2.INTER_LINEAR, borderValue=255)
    else:
        out = cv2.remap(
            texture, map_x, map_y, cv2.INTER_LINEAR, dst=background.copy(), borderMode=cv2.BORDER_TRANSPARENT
        )
    return np.asarray(out, dtype=np.uint8)


def chessboard_sheet(
    corners_x: int, corners_y: int, spacing_m: float, size_m: tuple[float, float], px_per_m: float
) -> tuple[NDArray[np.uint8], tuple[float, float]]:
    """A chessboard's sheet as printed: (H, W) uint8, white, the pattern (inner corners
    plus one square all round) centred on it; and the sheet's top-left corner in the
    board frame (origin at the first inner corner, x along the rows, y down)."""
    w0, h0 = (corners_x - 1) * spacing_m, (corners_y - 1) * spacing_m
    x0, y0 = -0.5 * (size_m[0] - w0), -0.5 * (size_m[1] - h0)
    W, H = round(size_m[0] * px_per_m), round(size_m[1] * px_per_m)
    x = x0 + (np.arange(W) + 0.5) / px_per_m
    y = y0 + (np.arange(H) + 0.5) / px_per_m
    i = np.floor(x / spacing_m).astype(int)
    j = np.floor(y / spacing_m).astype(int)
    inside = (i[None, :] >= -1) & (i[None, :] < corners_x) & (j[:, None] >= -1) & (j[:, None] < corners_y)
    black = inside & ((i[None, :] + j[:, None]) % 2 == 0)
    return np.where(black, 0, 255).astype(np.uint8), (x0, y0)


def board_views(
    camera: Camera,
    board: Any,
    n_views: int,
    rng: np.random.Generator,
    corner_sigma_px: float = 0.3,
    max_tilt_deg: float | tuple[float, float] = 40.0,
    distance_m: tuple[float, float] = (0.8, 2.0),
    jitter: tuple[float, float] | None = None,
) -> Any:
    """Chessboard corners as a detector reports them (:class:`rigcal.calib.intrinsics.Detections`),
    for an intrinsics solve with a known answer: each view's board is placed in front of the
    camera (tilted about both of its axes by up to ``max_tilt_deg``, at ``distance_m``, anywhere
    its corners stay inside the image) and its corners are projected through the full lens
    model with Gaussian noise of ``corner_sigma_px``. ``max_tilt_deg`` may be a pair: the
    largest tilts about the board's x (horizontal) and y (vertical) axes.

    Args:
        jitter: (deg, m) when given, every view is the first one moved by up to these (a
            board left in place and a camera barely touched: near-identical views).
    """
    from rigcal.calib.intrinsics import Detections
    from rigcal.geometry import make_T, rotvec_to_R

    W, H = camera.width_px, camera.height_px
    gx, gy = np.meshgrid(np.arange(board.width_n), np.arange(board.height_n))
    P = np.column_stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)]) * board.spacing_m
    centre = P.mean(axis=0)

    def pose() -> FloatArray:
        tilt = np.radians(rng.uniform(-1.0, 1.0, size=2) * np.broadcast_to(max_tilt_deg, (2,)))
        R = rotvec_to_R(np.array([tilt[0], tilt[1], rng.uniform(-0.3, 0.3)]))
        d = rng.uniform(*distance_m)
        ray = camera.bearings(np.array([[rng.uniform(0.25, 0.75) * W, rng.uniform(0.25, 0.75) * H]]))[0]
        return make_T(R, ray / ray[2] * d - R @ centre)

    views: list[FloatArray] = []
    first: FloatArray | None = None
    while len(views) < n_views:
        if jitter is not None and first is not None:
            turn = np.radians(jitter[0]) * rng.uniform(-1, 1, size=3) / np.sqrt(3)
            T = make_T(
                rotvec_to_R(turn) @ first[:3, :3], first[:3, 3] + jitter[1] * rng.uniform(-1, 1, size=3)
            )
        else:
            T = pose()
        q = camera.project(P @ T[:3, :3].T + T[:3, 3])
        if not camera.in_image(q, margin_px=10.0).all():
            continue
        first = T if first is None else first
        views.append(q + rng.normal(scale=corner_sigma_px, size=q.shape))
    corners = np.concatenate(
        [
            np.stack(views).reshape(n_views, board.height_n, board.width_n, 2),
            np.ones((n_views, board.height_n, board.width_n, 1)),
        ],
        axis=-1,
    )
    names = tuple(f"view{i:02d}.png" for i in range(n_views))
    return Detections(names, corners, (), (W, H))


def solved_camera_model(
    camera: Camera, n_views: int = 15, seed: int = 0, corner_sigma_px: float = 0.3, board: Any = None
) -> Any:
    """A mrcal camera model of ``camera`` as an intrinsics calibration leaves it: solved by
    :func:`rigcal.calib.intrinsics.solve_intrinsics` (``mrcal.optimize``) from ``n_views``
    simulated chessboard views (:func:`board_views`), so its intrinsics carry the solve's
    error and it keeps the ``optimization_inputs`` its uncertainty comes from."""
    from rigcal.calib.intrinsics import Board, solve_intrinsics

    board = board or Board(9, 6, 0.04)
    rng = np.random.default_rng(seed)
    det = board_views(camera, board, n_views, rng, corner_sigma_px, distance_m=(0.4, 0.9))
    return solve_intrinsics(det, board, camera.lensmodel, focal_estimate_px=float(camera.intrinsics[0])).model
