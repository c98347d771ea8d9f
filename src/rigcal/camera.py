"""Camera model: project, unproject and bearings, on top of mrcal's lens models.

A :class:`Camera` is a mrcal lens model (``LENSMODEL_PINHOLE``, ``LENSMODEL_OPENCV4/5/8/12``,
``LENSMODEL_SPLINED_STEREOGRAPHIC_...``, ...) with its intrinsics and image size. It is read
from a mrcal ``.cameramodel`` file or from a rigcal camera file holding OpenCV's K and
distortion coefficients (docs/formats/camera.md); OpenCV's coefficient order
(k1, k2, p1, p2[, k3[, k4, k5, k6[, s1..s4]]]) is exactly mrcal's ``LENSMODEL_OPENCVn``.

Camera frame: x right, y down, z forward (optical axis). Pixel coordinates: (0, 0) is the
centre of the top-left pixel (mrcal's and OpenCV's convention). See docs/conventions.md.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from rigcal.arrays import FloatArray
from rigcal.errors import InputError
from rigcal.io.files import check_keys, check_schema_version, load_yaml
from rigcal.io.validate import is_real

CAMERA_SCHEMA_VERSION = 1

# Number of OpenCV distortion coefficients -> mrcal lens model.
_OPENCV_MODELS = {
    0: "LENSMODEL_PINHOLE",
    4: "LENSMODEL_OPENCV4",
    5: "LENSMODEL_OPENCV5",
    8: "LENSMODEL_OPENCV8",
    12: "LENSMODEL_OPENCV12",
}


@dataclass(frozen=True, eq=False)
class Camera:
    """A calibrated camera.

    Attributes:
        lensmodel: mrcal lens model name, e.g. ``LENSMODEL_OPENCV5``.
        intrinsics: (n,) float64: fx, fy, cx, cy, then the model's distortion parameters.
        width_px, height_px: image size.
        source: where the model was read from (informative).
    """

    lensmodel: str
    intrinsics: FloatArray
    width_px: int
    height_px: int
    source: str | None = field(default=None, compare=False)

    def __post_init__(self) -> None:
        intr = np.array(self.intrinsics, dtype=float)
        intr.setflags(write=False)
        object.__setattr__(self, "intrinsics", intr)

    def __eq__(self, other: object) -> bool:
        """Same lens model, intrinsics and image size (the source is not compared)."""
        if not isinstance(other, Camera):
            return NotImplemented
        return (
            self.lensmodel == other.lensmodel
            and (self.width_px, self.height_px) == (other.width_px, other.height_px)
            and np.array_equal(self.intrinsics, other.intrinsics)
        )

    def __hash__(self) -> int:
        return hash((self.lensmodel, self.width_px, self.height_px, self.intrinsics.tobytes()))

    # --- constructors -------------------------------------------------------------------
    @classmethod
    def from_opencv(
        cls,
        K: ArrayLike,
        distortion: ArrayLike,
        width_px: int,
        height_px: int,
        source: str | None = None,
    ) -> Camera:
        """From OpenCV's 3x3 K (no skew) and 0/4/5/8/12 distortion coefficients."""
        K = np.asarray(K, dtype=float)
        dist = np.asarray(distortion, dtype=float).ravel()
        if len(dist) not in _OPENCV_MODELS:
            raise InputError.at(source, "distortion", dist.tolist(), "0, 4, 5, 8 or 12 coefficients")
        intr = np.concatenate([[K[0, 0], K[1, 1], K[0, 2], K[1, 2]], dist])
        return cls(_OPENCV_MODELS[len(dist)], intr, int(width_px), int(height_px), source)

    @classmethod
    def from_mrcal(cls, model: Any, source: str | None = None) -> Camera:
        """From a ``mrcal.cameramodel``."""
        lensmodel, intr = model.intrinsics()
        w, h = model.imagersize()
        return cls(str(lensmodel), np.asarray(intr, dtype=float), int(w), int(h), source)

    # --- geometry -----------------------------------------------------------------------
    @property
    def K(self) -> FloatArray:
        """(3, 3) pinhole part of the model (Eq. (1) of the paper)."""
        fx, fy, cx, cy = self.intrinsics[:4]
        return np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])

    @property
    def distortion(self) -> FloatArray:
        """Distortion parameters (OpenCV order for the OPENCVn models)."""
        return np.array(self.intrinsics[4:])

    def project(self, points_cam: ArrayLike) -> FloatArray:
        """Project camera-frame points to pixels (paper Eq. (1) plus lens distortion).

        Args:
            points_cam: (N, 3) points in the camera frame, metres.

        Returns:
            (N, 2) pixel coordinates; NaN for points at or behind the camera plane (z <= 0).
        """
        import mrcal

        p = np.atleast_2d(np.asarray(points_cam, dtype=float))
        q = np.array(mrcal.project(p, self.lensmodel, self.intrinsics), dtype=float).reshape(-1, 2)
        q[~(p[:, 2] > 0)] = np.nan
        return q

    def project_with_gradient(self, points_cam: ArrayLike) -> tuple[FloatArray, FloatArray]:
        """Project, and also return dq/dp.

        Returns:
            q: (N, 2) pixels (NaN where z <= 0); dq_dp: (N, 2, 3) Jacobian of q with respect
            to the camera-frame point.
        """
        import mrcal

        p = np.atleast_2d(np.asarray(points_cam, dtype=float))
        q, dq_dp, _ = mrcal.project(p, self.lensmodel, self.intrinsics, get_gradients=True)
        q = np.array(q, dtype=float).reshape(-1, 2)
        dq_dp = np.array(dq_dp, dtype=float).reshape(-1, 2, 3)
        behind = ~(p[:, 2] > 0)
        q[behind] = np.nan
        dq_dp[behind] = np.nan
        return q, dq_dp

    def bearings(self, pixels: ArrayLike) -> FloatArray:
        """Unit rays in the camera frame through pixels (paper Eq. (2), with distortion undone).

        Args:
            pixels: (N, 2) pixel coordinates.

        Returns:
            (N, 3) unit vectors in the camera frame.
        """
        import mrcal

        q = np.atleast_2d(np.asarray(pixels, dtype=float))
        v = np.asarray(mrcal.unproject(q, self.lensmodel, self.intrinsics, normalize=True), dtype=float)
        return v.reshape(-1, 3)

    def in_image(self, pixels: ArrayLike, margin_px: float = 0.0) -> NDArray[np.bool_]:
        """(N,) mask of pixels inside the image (pixel centres at integers, edges at -0.5)."""
        q = np.atleast_2d(np.asarray(pixels, dtype=float))
        lo = -0.5 + margin_px
        with np.errstate(invalid="ignore"):
            return (
                (q[:, 0] >= lo)
                & (q[:, 1] >= lo)
                & (q[:, 0] <= self.width_px - 0.5 - margin_px)
                & (q[:, 1] <= self.height_px - 0.5 - margin_px)
            )

    # --- serialisation ------------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        """The embedded form used in rig files (mrcal's key names)."""
        return {
            "lensmodel": self.lensmodel,
            "intrinsics": [float(x) for x in self.intrinsics],
            "imagersize": [self.width_px, self.height_px],
        }

    def to_cameramodel(self, rt_cam_ref: ArrayLike | None = None) -> Any:
        """A ``mrcal.cameramodel`` with these intrinsics (and optional extrinsics)."""
        import mrcal

        rt = np.zeros(6) if rt_cam_ref is None else np.asarray(rt_cam_ref, dtype=float)
        return mrcal.cameramodel(
            intrinsics=(self.lensmodel, np.array(self.intrinsics)),
            imagersize=np.array([self.width_px, self.height_px]),
            rt_cam_ref=rt,
        )


def camera_from_dict(d: Any, path: str | Path | None, keypath: str) -> Camera:
    """Parse the embedded form written by :meth:`Camera.to_dict` (rig files)."""
    import mrcal

    d = check_keys(d, path, keypath, ["lensmodel", "intrinsics", "imagersize"])
    lensmodel = d["lensmodel"]
    try:
        n = mrcal.lensmodel_num_params(lensmodel)
    except Exception:
        raise InputError.at(path, f"{keypath}.lensmodel", lensmodel, "a mrcal lens model name") from None
    intr = _float_list(d["intrinsics"], path, f"{keypath}.intrinsics", n)
    if not (intr[0] > 0 and intr[1] > 0):  # every mrcal lens model starts with fx, fy, cx, cy
        raise InputError.at(path, f"{keypath}.intrinsics", intr[:4], "fx, fy, cx, cy, ... with fx, fy > 0")
    size = d["imagersize"]
    if not (isinstance(size, list) and len(size) == 2 and all(_is_pos_int(x) for x in size)):
        raise InputError.at(path, f"{keypath}.imagersize", size, "[width, height], positive integers")
    return Camera(str(lensmodel), np.array(intr), int(size[0]), int(size[1]), str(path) if path else None)


def read_camera(path: str | Path) -> Camera:
    """Read a camera: a mrcal ``.cameramodel``, a rigcal camera YAML file (OpenCV K +
    distortion), a ROS ``camera_info`` YAML file, or an OpenCV FileStorage file (XML or
    ``%YAML:1.0``); see docs/formats/camera.md.

    Raises:
        InputError: missing, unreadable or invalid file.
    """
    from rigcal import camera_formats

    path = Path(path)
    if path.suffix == ".cameramodel":
        return _read_cameramodel(path)
    if not path.is_file():
        raise InputError(f"{path}: camera file not found")
    if camera_formats.is_opencv_storage(path):
        return camera_formats.camera_from_opencv_storage(path)
    data = load_yaml(path, "camera file")
    if camera_formats.is_ros_camera_info(data):
        return camera_formats.camera_from_ros_camera_info(data, path)
    return _read_opencv_yaml(path, data)


def _read_cameramodel(path: Path) -> Camera:
    import mrcal

    if not path.is_file():
        raise InputError(f"{path}: camera model not found")
    try:
        model = mrcal.cameramodel(str(path))
    except Exception as exc:  # mrcal raises bare Exceptions for malformed files
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        if len(first) > 120:
            first = first[:117] + "..."
        raise InputError(f"{path}: not a valid mrcal cameramodel: {first}") from None
    lensmodel, intrinsics = model.intrinsics()
    # Every mrcal lens model starts its intrinsics with fx, fy, cx, cy.
    if not (np.all(np.isfinite(intrinsics)) and intrinsics[0] > 0 and intrinsics[1] > 0):
        raise InputError.at(
            path, "intrinsics", [float(x) for x in intrinsics[:4]], f"{lensmodel} with positive focal lengths"
        )
    return Camera.from_mrcal(model, source=str(path))


def _read_opencv_yaml(path: Path, data: Any) -> Camera:
    d = check_keys(
        data,
        path,
        "",
        ["schema_version", "image_width_px", "image_height_px", "K"],
        ["distortion", "name"],
        [CAMERA_SCHEMA_VERSION],
    )
    check_schema_version(d, path, CAMERA_SCHEMA_VERSION)
    for key in ("image_width_px", "image_height_px"):
        if not _is_pos_int(d[key]):
            raise InputError.at(path, key, d[key], "a positive integer")
    K_rows = d["K"]
    if not (isinstance(K_rows, list) and len(K_rows) == 3):
        raise InputError.at(path, "K", K_rows, "3 rows [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]")
    K = np.array([_float_list(row, path, f"K[{i}]", 3) for i, row in enumerate(K_rows)])
    if K[0, 1] != 0 or K[1, 0] != 0 or K[2, 0] != 0 or K[2, 1] != 0 or K[2, 2] != 1:
        raise InputError.at(path, "K", K_rows, "[[fx, 0, cx], [0, fy, cy], [0, 0, 1]] (no skew)")
    if not (K[0, 0] > 0 and K[1, 1] > 0):
        raise InputError.at(path, "K", K_rows, "positive focal lengths fx, fy")
    dist_raw = d.get("distortion", [])
    if not isinstance(dist_raw, list) or len(dist_raw) not in _OPENCV_MODELS:
        raise InputError.at(path, "distortion", dist_raw, "a list of 0, 4, 5, 8 or 12 coefficients")
    dist = _float_list(dist_raw, path, "distortion", len(dist_raw))
    return Camera.from_opencv(K, dist, d["image_width_px"], d["image_height_px"], source=str(path))


def camera_to_opencv_yaml(camera: Camera) -> str:
    """Text of a rigcal camera file for an OPENCVn or PINHOLE camera."""
    n_dist = {v: k for k, v in _OPENCV_MODELS.items()}.get(camera.lensmodel)
    if n_dist is None:
        raise InputError.at(None, "lensmodel", camera.lensmodel, f"one of {sorted(_OPENCV_MODELS.values())}")
    K = camera.K
    rows = ",\n".join(f"    [{', '.join(_fmt(x) for x in row)}]" for row in K)
    dist = ", ".join(_fmt(x) for x in camera.distortion)
    return (
        f"schema_version: {CAMERA_SCHEMA_VERSION}\n"
        f"image_width_px: {camera.width_px}\n"
        f"image_height_px: {camera.height_px}\n"
        f"K: [\n{rows}]\n"
        f"distortion: [{dist}]  # OpenCV order: k1, k2, p1, p2[, k3[, k4, k5, k6[, s1, s2, s3, s4]]]\n"
    )


def _fmt(x: float) -> str:
    text = f"{float(x):.10g}"
    # YAML 1.1 reads an exponent form without a '.' (1e-05, 1e+20) as a string.
    return text.replace("e", ".0e") if "e" in text and "." not in text else text


def _is_pos_int(x: Any) -> bool:
    """A positive integer that can be an image side (at most 10**6 pixels)."""
    return isinstance(x, int) and not isinstance(x, bool) and 0 < x <= 10**6


def _float_list(value: Any, path: str | Path | None, key: str, n: int) -> list[float]:
    if not isinstance(value, list) or len(value) != n:
        raise InputError.at(path, key, value, f"a list of {n} numbers")
    return [_one_float(v, path, f"{key}[{i}]") for i, v in enumerate(value)]


def _one_float(v: Any, path: str | Path | None, key: str) -> float:
    if not is_real(v):
        raise InputError.at(path, key, v, "a finite number")
    return float(v)


def intrinsics_covariance(model: Any) -> FloatArray | None:
    """(n, n) covariance of a mrcal model's intrinsics (its lens model's order: fx, fy, cx,
    cy, distortion), from the calibration that solved it: mrcal's own propagation of the
    calibration images' pixel noise (estimated from the solve's residuals) through the
    solve, Var(b) = sigma^2 D inv(J*^T J*) ... D, the intrinsics' block (the board poses and
    every other state marginalised out; mrcal's docs, "Projection uncertainty"). Intrinsics
    the solve held fixed get no variance.

    Returns:
        None when the model carries no ``optimization_inputs`` (so no uncertainty).
    """
    import mrcal
    from mrcal.model_analysis import _propagate_calibration_uncertainty

    inputs = model.optimization_inputs()
    if inputs is None:
        return None
    lensmodel, intr = model.intrinsics()
    n = len(intr)
    icam = int(model.icam_intrinsics())
    has_core = bool(mrcal.lensmodel_metadata_and_config(lensmodel)["has_core"])
    core = has_core and bool(inputs.get("do_optimize_intrinsics_core", True))
    rest = bool(inputs.get("do_optimize_intrinsics_distortions", True))
    # Which of the intrinsics the solve's state holds, in order (mrcal packs the core first).
    first = 4 if has_core else 0
    held = ([0, 1, 2, 3] if core else []) + (list(range(first, n)) if rest else [])
    cov = np.zeros((n, n))
    istate = mrcal.state_index_intrinsics(icam, **inputs)
    if istate is None or not held:
        return cov
    dF_db = np.zeros((len(held), int(mrcal.num_states(**inputs))))
    dF_db[np.arange(len(held)), istate + np.arange(len(held))] = 1.0
    sub = np.asarray(
        _propagate_calibration_uncertainty("covariance", dF_dbunpacked=dF_db, optimization_inputs=inputs),
        dtype=float,
    )
    cov[np.ix_(held, held)] = 0.5 * (sub + sub.T)
    return cov


def read_intrinsics_covariance(path: str | Path) -> tuple[FloatArray | None, str]:
    """The covariance of a camera file's intrinsics (:func:`intrinsics_covariance`), or
    None and why it is missing: only a mrcal ``.cameramodel`` that keeps its
    ``optimization_inputs`` carries it (OpenCV, ROS and rigcal camera files hold the
    intrinsics alone).

    Raises:
        InputError: a missing or invalid camera model.
    """
    import mrcal

    path = Path(path)
    if path.suffix != ".cameramodel":
        return (
            None,
            f"{path.name} (an OpenCV, ROS or rigcal camera file) carries no uncertainty of its intrinsics",
        )
    _read_cameramodel(path)  # validates, with the one-line errors
    cov = intrinsics_covariance(mrcal.cameramodel(str(path)))
    if cov is None:
        return None, f"{path.name} keeps no optimization_inputs, so no uncertainty of its intrinsics"
    return cov, f"{path.name}'s optimization_inputs (mrcal's uncertainty of the calibration that solved it)"
