"""The field checks of Kalibr's camchain reader, ported to plain Python for the tests.

Kalibr reads a ``camchain-imucam.yaml`` with ``CameraChainParameters`` and, per camera,
``CameraParameters`` (aslam_offline_calibration/kalibr/python/kalibr_common/ConfigReader.py);
``kalibr_calibrate_imu_camera`` and the other tools call, per camera ``camN``:

- ``getRosTopic``: ``rostopic`` present ("rostopic field not found in yaml").
- ``getIntrinsics`` / ``checkIntrinsics``: ``camera_model`` and ``intrinsics`` present;
  the model one of pinhole, omni, eucm, ds; pinhole has exactly 4 intrinsics
  ``[fu, fv, pu, pv]``; focal lengths and principal point not negative.
- ``getDistortion`` / ``checkDistortion``: ``distortion_model`` and ``distortion_coeffs``
  present; the model one of radtan (4 coefficients), equidistant (4), fov (1), none (0).
- ``getResolution`` / ``checkResolution``: ``resolution`` present, two positive numbers.
- ``getExtrinsicsImuToCam``: ``T_cam_imu`` builds an ``sm.Transformation`` (a 4x4 matrix;
  here also checked to be a rigid transform: a rotation and last row 0 0 0 1, which
  sm.Transformation assumes).
- ``getCamOverlaps``: ``cam_overlaps`` present.
- ``numCameras`` counts the top-level entries, which are looked up as ``cam0``, ``cam1``, ...

Errors are raised as Kalibr raises them: ``RuntimeError("[CameraChainConfig Reader]: ...")``.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import yaml


class KalibrCamera:
    """One camera of the chain, as Kalibr's CameraParameters sees it."""

    def __init__(self, data: dict[str, Any]) -> None:
        self.data = data

    def _error(self, message: str) -> None:
        raise RuntimeError(f"[CameraConfig Reader]: {message}")

    def rostopic(self) -> str:
        if "rostopic" not in self.data:
            self._error("rostopic field not found in yaml")
        return str(self.data["rostopic"])

    def intrinsics(self) -> tuple[str, list[float]]:
        if "camera_model" not in self.data or "intrinsics" not in self.data:
            self._error("camera_model or intrinsics field not found in yaml")
        model, intr = self.data["camera_model"], self.data["intrinsics"]
        sizes = {"pinhole": 4, "omni": 5, "eucm": 6, "ds": 6}
        if model not in sizes:
            self._error(f"Invalid camera model; supported models are [{', '.join(sizes)}]")
        if len(intr) != sizes[model]:
            self._error(f"invalid intrinsics for {model}")
        fu, fv, pu, pv = intr[-4:]
        if fu < 0 or fv < 0:
            self._error("invalid focal length")
        if pu < 0 or pv < 0:
            self._error("invalid principal point")
        return model, [float(x) for x in intr]

    def distortion(self) -> tuple[str, list[float]]:
        if "distortion_model" not in self.data or "distortion_coeffs" not in self.data:
            self._error("distortion_model or distortion_coeffs field not found in yaml")
        model, coeffs = self.data["distortion_model"], self.data["distortion_coeffs"]
        sizes = {"radtan": 4, "equidistant": 4, "fov": 1, "none": 0}
        if model not in sizes:
            self._error(f"Invalid distortion model; supported models are [{', '.join(sizes)}]")
        if len(coeffs) != sizes[model]:
            self._error(f"distortion model {model} requires {sizes[model]} coefficients")
        return model, [float(x) for x in coeffs]

    def resolution(self) -> list[int]:
        if "resolution" not in self.data:
            self._error("resolution field not found in yaml")
        res = self.data["resolution"]
        if len(res) != 2 or res[0] <= 0 or res[1] <= 0:
            self._error("Invalid resolution")
        return [int(x) for x in res]


class KalibrCameraChain:
    """A camchain as Kalibr's CameraChainParameters reads it."""

    def __init__(self, text: str) -> None:
        self.data = yaml.safe_load(text)
        if not isinstance(self.data, dict):
            self._error("could not parse the yaml file")

    def _error(self, message: str) -> None:
        raise RuntimeError(f"[CameraChainConfig Reader]: {message}")

    def num_cameras(self) -> int:
        return len(self.data)

    def _cam(self, nr: int) -> dict[str, Any]:
        if nr >= self.num_cameras() or f"cam{nr}" not in self.data:
            self._error("out-of-range: camera index not in camera chain!")
        return dict(self.data[f"cam{nr}"])

    def camera(self, nr: int) -> KalibrCamera:
        return KalibrCamera(self._cam(nr))

    def T_cam_imu(self, nr: int) -> np.ndarray:
        try:
            T = np.array(self._cam(nr)["T_cam_imu"], dtype=float)
        except (KeyError, ValueError, TypeError):
            T = np.zeros(0)
        if T.shape != (4, 4):
            self._error(f"invalid camera baseline (cam{nr})")
        R = T[:3, :3]
        if not np.allclose(R @ R.T, np.eye(3), atol=1e-9) or np.linalg.det(R) < 0:
            self._error(f"invalid camera baseline (cam{nr}): not a rotation")
        if not np.array_equal(T[3], [0.0, 0.0, 0.0, 1.0]):
            self._error(f"invalid camera baseline (cam{nr}): last row")
        return T

    def cam_overlaps(self, nr: int) -> list[int]:
        cam = self._cam(nr)
        if "cam_overlaps" not in cam:
            self._error(f"cam_overlaps not found (cam{nr})")
        return list(cam["cam_overlaps"])

    def load_all(self) -> list[dict[str, Any]]:
        """Every getter the IMU-camera calibration calls, for every camera."""
        out = []
        for nr in range(self.num_cameras()):
            cam = self.camera(nr)
            out.append(
                {
                    "rostopic": cam.rostopic(),
                    "intrinsics": cam.intrinsics(),
                    "distortion": cam.distortion(),
                    "resolution": cam.resolution(),
                    "T_cam_imu": self.T_cam_imu(nr),
                    "cam_overlaps": self.cam_overlaps(nr),
                }
            )
        return out
