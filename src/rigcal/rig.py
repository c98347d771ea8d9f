"""The in-memory rig: the calibrated laser-camera pair that every later command reads."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, NamedTuple

import numpy as np

from rigcal.arrays import FloatArray
from rigcal.camera import Camera

# Order and meaning of the covariance's parameters, written into every rig file.
COVARIANCE_PARAMETERS = (
    "[dtheta_x, dtheta_y, dtheta_z] rad, [dt_x, dt_y, dt_z] m, in the camera frame: "
    "R_true = Exp(dtheta) R, t_true = t + dt"
)


class Sigmas(NamedTuple):
    """The 1-sigma uncertainty of T_cam_laser, from its covariance's diagonal.

    Attributes:
        rotation_deg: (3,) degrees, about the camera's x, y and z axes.
        translation_mm: (3,) millimetres, along the camera's x, y and z axes.
    """

    rotation_deg: FloatArray
    translation_mm: FloatArray


@dataclass(frozen=True)
class Rig:
    """A calibrated rig.

    Attributes:
        T_cam_laser: (4, 4) maps laser-frame points into the camera frame (paper Eq. (3)).
        camera: the camera model.
        covariance: (6, 6) covariance of T_cam_laser (see COVARIANCE_PARAMETERS), or None.
        laser: description of the scanner (name, field of view, step, max range).
        residuals: residual summary of the solve that made it (rms_px, ...), or empty.
        provenance: how it was made (version, time, command, input hashes, settings).
        uncertainty: the covariance's checks (docs/formats/rig.md): the noise model
            (assumed, estimated, used), the model's own covariance, the spread over
            captures and the sensitivity to the noise settings; empty when not made.
    """

    T_cam_laser: FloatArray
    camera: Camera
    covariance: FloatArray | None = None
    laser: dict[str, Any] = field(default_factory=dict)
    residuals: dict[str, Any] = field(default_factory=dict)
    provenance: dict[str, Any] = field(default_factory=dict)
    uncertainty: dict[str, Any] = field(default_factory=dict)

    @property
    def T_laser_cam(self) -> FloatArray:
        """(4, 4) the inverse direction: camera-frame points into the laser frame."""
        from rigcal.geometry import inv_T

        return inv_T(self.T_cam_laser)

    def sigmas(self) -> Sigmas | None:
        """1-sigma rotation (deg, per camera axis) and translation (mm), or None without
        a covariance: ``rig.sigmas().rotation_deg``, ``rig.sigmas().translation_mm``."""
        if self.covariance is None:
            return None
        d = np.sqrt(np.clip(np.diag(self.covariance), 0.0, None))
        return Sigmas(np.degrees(d[:3]), 1000.0 * d[3:])

    def to_json(self) -> dict[str, Any]:
        """The calibration for ``--json`` output and scripts: T_cam_laser as a 4x4 matrix
        and as rotation vector (rad) plus translation (m), and its covariance (or None)
        with the parameters' order and the 1-sigma values."""
        from rigcal.geometry import rt_from_T

        rt = rt_from_T(self.T_cam_laser)
        sig = self.sigmas()
        return {
            "T_cam_laser": [[float(x) for x in row] for row in self.T_cam_laser],
            "rotation_vector_rad": [float(x) for x in rt[:3]],
            "translation_m": [float(x) for x in rt[3:]],
            "covariance": None
            if self.covariance is None
            else [[float(x) for x in r] for r in self.covariance],
            "covariance_parameters": COVARIANCE_PARAMETERS,
            "sigma_rotation_deg": None if sig is None else [float(x) for x in sig.rotation_deg],
            "sigma_translation_mm": None if sig is None else [float(x) for x in sig.translation_mm],
        }
