"""The on-disk form of a rigid transform, shared by every rigcal YAML file.

One rotation representation on disk: the rotation vector (axis times angle, radians; the
``r`` of mrcal's ``rt``). The direction is written into the block itself::

    T_cam_laser:
      maps: laser -> cam          # p_cam = R p_laser + t
      rotation_vector_rad: [rx, ry, rz]
      translation_m: [tx, ty, tz]
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from rigcal.errors import InputError
from rigcal.geometry import R_to_rotvec, make_T, rotvec_to_R
from rigcal.io.files import check_keys
from rigcal.io.validate import is_real


def transform_to_dict(T: NDArray[np.float64], to_frame: str, from_frame: str) -> dict[str, Any]:
    """YAML-ready block for T_{to}_{from}."""
    T = np.asarray(T, dtype=float)
    return {
        "maps": f"{from_frame} -> {to_frame}",
        "rotation_vector_rad": [round(float(x), 12) for x in R_to_rotvec(T[:3, :3])],
        "translation_m": [round(float(x), 12) for x in T[:3, 3]],
    }


def transform_from_dict(
    d: Any, path: str | Path | None, keypath: str, to_frame: str, from_frame: str
) -> NDArray[np.float64]:
    """Parse and validate a block written by :func:`transform_to_dict`; returns T_{to}_{from}."""
    d = check_keys(d, path, keypath, ["maps", "rotation_vector_rad", "translation_m"])
    want = f"{from_frame} -> {to_frame}"
    if d["maps"] != want:
        raise InputError.at(path, f"{keypath}.maps", d["maps"], f"'{want}'")
    r = float_vector(d["rotation_vector_rad"], path, f"{keypath}.rotation_vector_rad", 3)
    if np.linalg.norm(r) > np.pi + 1e-9:
        raise InputError.at(
            path, f"{keypath}.rotation_vector_rad", r.tolist(), "a rotation of at most pi rad"
        )
    t = float_vector(d["translation_m"], path, f"{keypath}.translation_m", 3)
    return make_T(rotvec_to_R(r), t)


def float_vector(value: Any, path: str | Path | None, keypath: str, n: int) -> NDArray[np.float64]:
    """A list of exactly n finite numbers (booleans rejected)."""
    if not isinstance(value, list) or len(value) != n:
        raise InputError.at(path, keypath, value, f"a list of {n} numbers")
    for i, x in enumerate(value):
        if not is_real(x):
            raise InputError.at(path, f"{keypath}[{i}]", x, "a finite number")
    return np.array(value, dtype=float)


def float_matrix(value: Any, path: str | Path | None, keypath: str, n: int, m: int) -> NDArray[np.float64]:
    """An n x m nested list of finite numbers."""
    if not isinstance(value, list) or len(value) != n:
        raise InputError.at(path, keypath, value, f"{n} rows of {m} numbers")
    return np.array([float_vector(row, path, f"{keypath}[{i}]", m) for i, row in enumerate(value)])


def rigid_transform(value: Any, path: str | Path | None, keypath: str) -> NDArray[np.float64]:
    """``value`` as a (4, 4) rigid transform: finite, the last row [0, 0, 0, 1], and a
    rotation (orthonormal to 1e-6, determinant +1) in the top-left 3x3 block; the check
    of a transform given in memory (the Python API's ``T_truth``, a rig to write).

    Raises:
        InputError: naming the key and what was expected.
    """
    from rigcal.io.validate import finite_array

    T = finite_array(value, path, keypath, shape=(4, 4))
    R = T[:3, :3]
    if not np.array_equal(T[3], [0.0, 0.0, 0.0, 1.0]):
        raise InputError.at(path, f"{keypath}[3]", T[3].tolist(), "[0, 0, 0, 1] (a rigid transform)")
    if np.abs(R @ R.T - np.eye(3)).max() > 1e-6 or np.linalg.det(R) < 0:
        raise InputError.at(
            path, f"{keypath}[:3, :3]", R.tolist(), "a rotation matrix (orthonormal, determinant +1)"
        )
    return T
