"""Synthetic images of a flat calibration board seen through a camera model.

Every pixel's ray (through the full lens model, distortion included) is cut with the
board's plane and the board's texture is sampled there, so the corners in the image are
exactly where the camera model projects them: a test of an intrinsics solve with a known
answer.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from rigcal.camera import Camera
from rigcal.geometry import inv_T

FloatArray = NDArray[np.float64]


def render_board(
    camera: Camera, texture: NDArray[np.uint8], board_size_m: tuple[float, float], T_cam_board: FloatArray
) -> NDArray[np.uint8]:
    """The camera's grey image of a board lying in its frame's z = 0 plane.

    Args:
        camera: the camera model.
        texture: the board's picture (grey), its top-left at the board frame's origin, x
            to the right and y down, covering ``board_size_m``.
        board_size_m: (width, height) of the picture on the board, metres.
        T_cam_board: (4, 4) the board's pose in the camera frame.

    Returns:
        (height_px, width_px) uint8; pixels that miss the board are white.
    """
    import cv2

    W, H = camera.width_px, camera.height_px
    u, v = np.meshgrid(np.arange(W, dtype=float), np.arange(H, dtype=float))
    rays = camera.bearings(np.column_stack([u.ravel(), v.ravel()]))
    T_board_cam = inv_T(T_cam_board)
    d = rays @ T_board_cam[:3, :3].T
    o = T_board_cam[:3, 3]
    with np.errstate(divide="ignore", invalid="ignore"):
        s = -o[2] / d[:, 2]
    p = o[None, :2] + s[:, None] * d[:, :2]
    p[~(s > 0)] = -1e6
    th, tw = texture.shape[:2]
    map_x = (p[:, 0] / board_size_m[0] * tw - 0.5).reshape(H, W).astype(np.float32)
    map_y = (p[:, 1] / board_size_m[1] * th - 0.5).reshape(H, W).astype(np.float32)
    out = cv2.remap(texture, map_x, map_y, cv2.INTER_LINEAR, borderValue=255)
    return np.asarray(out, dtype=np.uint8)
