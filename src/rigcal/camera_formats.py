"""Camera intrinsics from other tools: ROS ``camera_info`` YAML and OpenCV FileStorage.

:func:`rigcal.camera.read_camera` dispatches here by content (docs/formats/camera.md):

- a ROS ``camera_info`` YAML file, as ``camera_calibration`` writes it
  (``image_width``, ``image_height``, ``camera_matrix``, ``distortion_model``,
  ``distortion_coefficients``; ``plumb_bob`` or ``rational_polynomial``);
- an OpenCV FileStorage file (``.xml``, or YAML with ``!!opencv-matrix`` nodes), as OpenCV's
  calibration sample writes it (``camera_matrix`` / ``distortion_coefficients`` /
  ``image_width`` / ``image_height``, or the aliases in :data:`OPENCV_KEYS`, in any case:
  older programs write ``image_Width`` / ``image_Height``).

Both become OpenCV K plus distortion, i.e. mrcal's ``LENSMODEL_OPENCVn``.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from rigcal.camera import Camera
from rigcal.errors import InputError
from rigcal.io.files import check_keys
from rigcal.io.validate import is_real

ROS_REQUIRED = ("image_width", "image_height", "camera_matrix", "distortion_model", "distortion_coefficients")
ROS_OPTIONAL = ("camera_name", "rectification_matrix", "projection_matrix")
ROS_DISTORTION_MODELS = {"plumb_bob": (5,), "rational_polynomial": (8,)}

# Names OpenCV programs use for the same things, first match wins.
OPENCV_KEYS = {
    "K": ("camera_matrix", "cameraMatrix", "Camera_Matrix", "K", "M"),
    "D": ("distortion_coefficients", "distCoeffs", "Distortion_Coefficients", "D", "dist_coeffs"),
    "width": ("image_width", "imageWidth", "width"),
    "height": ("image_height", "imageHeight", "height"),
}


def is_ros_camera_info(data: Any) -> bool:
    """Whether parsed YAML looks like a ROS camera_info file."""
    return isinstance(data, Mapping) and "camera_matrix" in data and "distortion_model" in data


def is_opencv_storage(path: Path) -> bool:
    """An OpenCV FileStorage file: ``.xml``, YAML with OpenCV's ``%YAML:1.0`` header, or
    YAML holding ``!!opencv-matrix`` / ``!!opencv-nd-matrix`` nodes (what OpenCV 4.x/5.x writes)."""
    if path.suffix.lower() == ".xml":
        return True
    try:
        with open(path, "rb") as f:
            head = f.read(1 << 14)
    except OSError:
        return False
    # 2-D arrays are written as ``!!opencv-matrix``, 1-D ones as ``!!opencv-nd-matrix``.
    return head.startswith(b"%YAML:1.0") or (
        head.startswith(b"%YAML") and (b"opencv-matrix" in head or b"opencv-nd-matrix" in head)
    )


def camera_from_ros_camera_info(data: Mapping[str, Any], path: Path) -> Camera:
    """A camera from a parsed ROS camera_info YAML file."""
    d = check_keys(data, path, "", ROS_REQUIRED, ROS_OPTIONAL)
    for key in ("image_width", "image_height"):
        v = d[key]
        if isinstance(v, bool) or not isinstance(v, int) or v <= 0:
            raise InputError.at(path, key, v, "a positive integer")
    K = _ros_matrix(d["camera_matrix"], path, "camera_matrix", 3, 3)
    model = d["distortion_model"]
    if model not in ROS_DISTORTION_MODELS:
        raise InputError.at(
            path,
            "distortion_model",
            model,
            f"one of {sorted(ROS_DISTORTION_MODELS)} (mrcal has no equivalent of the others)",
        )
    dist = _ros_matrix(d["distortion_coefficients"], path, "distortion_coefficients", 1, None).ravel()
    if len(dist) not in ROS_DISTORTION_MODELS[model]:
        raise InputError.at(
            path,
            "distortion_coefficients.data",
            dist.tolist(),
            f"{ROS_DISTORTION_MODELS[model][0]} coefficients",
        )
    check_pinhole_K(K, path, "camera_matrix")
    return Camera.from_opencv(K, dist, d["image_width"], d["image_height"], source=str(path))


def _ros_matrix(value: Any, path: Path, key: str, rows: int, cols: int | None) -> np.ndarray:
    m = check_keys(value, path, key, ["rows", "cols", "data"])
    r, c, data = m["rows"], m["cols"], m["data"]
    ok = (
        r == rows
        and isinstance(c, int)
        and (cols is None or c == cols)
        and isinstance(data, list)
        and len(data) == r * c
        and all(is_real(x) for x in data)
    )
    if not ok:
        shape = f"{rows}x{cols}" if cols is not None else f"{rows}xN"
        raise InputError.at(path, key, value, f"{{rows, cols, data}} of a {shape} matrix of finite numbers")
    return np.array(data, dtype=float).reshape(r, c)


def camera_from_opencv_storage(path: Path) -> Camera:
    """A camera from an OpenCV FileStorage file (XML or ``%YAML:1.0``)."""
    import cv2

    from rigcal.io.files import check_markup_depth

    check_markup_depth(path, "camera file")
    try:
        fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    except (cv2.error, SystemError) as exc:
        # opencv-python 5 wraps the constructor's cv2.error in a SystemError.
        cause = exc.__cause__ if isinstance(exc.__cause__, cv2.error) else exc
        raise InputError(
            f"{path}: not a readable OpenCV FileStorage file: {str(cause).strip()[:100]}"
        ) from None
    if not fs.isOpened():
        raise InputError(f"{path}: not a readable OpenCV FileStorage file")
    try:
        K = _node_matrix(fs, path, "K")
        D = _node_matrix(fs, path, "D").ravel()
        size = [_node_int(fs, path, k) for k in ("width", "height")]
    finally:
        fs.release()
    if K.shape != (3, 3):
        raise InputError.at(path, _found_key(OPENCV_KEYS["K"]), K.tolist(), "a 3x3 matrix")
    check_pinhole_K(K, path, "camera_matrix")
    if len(D) not in (0, 4, 5, 8, 12):
        raise InputError.at(path, "distortion_coefficients", D.tolist(), "0, 4, 5, 8 or 12 coefficients")
    return Camera.from_opencv(K, D, size[0], size[1], source=str(path))


def _found_key(names: tuple[str, ...]) -> str:
    return " or ".join(names[:2])


def _node(fs: Any, path: Path, what: str) -> Any:
    """The first of the top-level nodes named as OPENCV_KEYS[what] lists them, the names
    matched without regard to case (programs write ``image_width``, ``image_Width``,
    ``Image_Width``...)."""
    root = fs.root()
    keys = {str(k).lower(): str(k) for k in reversed(root.keys())} if root is not None else {}
    for name in OPENCV_KEYS[what]:
        node = fs.getNode(keys.get(name.lower(), name))
        if not node.empty():
            return node
    raise InputError(
        f"{path}: {OPENCV_KEYS[what][0]}: missing; expected one of the keys {list(OPENCV_KEYS[what])}"
    )


def _node_matrix(fs: Any, path: Path, what: str) -> np.ndarray:
    import cv2

    node = _node(fs, path, what)
    try:  # a scalar, string or list is no opencv-matrix; .nan in its data cannot be read
        m = node.mat() if node.isMap() else None
    except cv2.error:
        m = None
    if m is None or not np.all(np.isfinite(m)):
        raise InputError(f"{path}: {OPENCV_KEYS[what][0]}: expected an opencv-matrix of finite numbers")
    return np.asarray(m, dtype=float)


def _node_int(fs: Any, path: Path, what: str) -> int:
    v = _node(fs, path, what).real()
    if not (v > 0 and float(v).is_integer()):
        raise InputError.at(path, OPENCV_KEYS[what][0], v, "a positive integer")
    return int(v)


def check_pinhole_K(K: np.ndarray, path: str | Path | None, key: str) -> None:
    """Refuse a K with skew or non-positive focal lengths (every reader of K uses this)."""
    if K[0, 1] != 0 or K[1, 0] != 0 or K[2, 0] != 0 or K[2, 1] != 0 or K[2, 2] != 1:
        raise InputError.at(path, key, K.tolist(), "[[fx, 0, cx], [0, fy, cy], [0, 0, 1]] (no skew)")
    if not (K[0, 0] > 0 and K[1, 1] > 0):
        raise InputError.at(path, key, K.tolist(), "positive focal lengths fx, fy")


def camera_to_ros_camera_info(camera: Camera, name: str = "camera") -> str:
    """A ROS camera_info YAML text for a pinhole / plumb_bob / rational_polynomial camera."""
    n = {"LENSMODEL_PINHOLE": 0, "LENSMODEL_OPENCV5": 5, "LENSMODEL_OPENCV8": 8, "LENSMODEL_OPENCV4": 4}.get(
        camera.lensmodel
    )
    if n is None:
        raise InputError.at(None, "lensmodel", camera.lensmodel, "PINHOLE or OPENCV4/5/8 for ROS camera_info")
    dist = list(camera.distortion) + [0.0] * ((5 if n <= 5 else 8) - n)
    model = "plumb_bob" if len(dist) == 5 else "rational_polynomial"
    K = camera.K
    P = np.column_stack([K, np.zeros(3)])

    def block(rows: int, cols: int, data: list[float]) -> str:
        return f"\n  rows: {rows}\n  cols: {cols}\n  data: [{', '.join(repr(float(x)) for x in data)}]"

    return (
        f"image_width: {camera.width_px}\nimage_height: {camera.height_px}\ncamera_name: {name}\n"
        f"camera_matrix:{block(3, 3, list(K.ravel()))}\n"
        f"distortion_model: {model}\n"
        f"distortion_coefficients:{block(1, len(dist), dist)}\n"
        f"rectification_matrix:{block(3, 3, list(np.eye(3).ravel()))}\n"
        f"projection_matrix:{block(3, 4, list(P.ravel()))}\n"
    )
