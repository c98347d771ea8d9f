"""The rig file: a versioned YAML file holding a calibrated rig (docs/formats/rig.md).

Schema version 2 (version 1 files, without the covariance's checks, are read as well)::

    schema_version: 2
    T_cam_laser: {maps: laser -> cam, rotation_vector_rad: [...], translation_m: [...]}
    uncertainty:                       # optional
      parameters: <text: order and meaning of the covariance's parameters>
      covariance: 6 rows of 6          # the honest one: the model's, scaled to the spread
      sigma_rotation_deg: [x, y, z]
      sigma_translation_mm: [x, y, z]
      noise: {name: {assumed, estimated, used}}          # version 2, optional
      model_covariance: 6 rows of 6                      # version 2, optional
      spread: {method, captures, scale, ..., covariance}  # version 2, optional
      sensitivity: [{setting, factor, value, rotation_deg, translation_mm, sigmas}]
    camera: {lensmodel: ..., intrinsics: [...], imagersize: [w, h]}   # mrcal's names
    laser: {...}                       # free-form description of the scanner
    residuals: {...}                   # summary of the solve
    provenance: {...}                  # rigcal version, UTC time, command, inputs, settings

Reading validates every field and rejects unknown keys.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from rigcal import __version__
from rigcal.camera import camera_from_dict
from rigcal.errors import InputError, OutputError
from rigcal.io.files import atomic_write_text, check_keys, load_yaml
from rigcal.io.transform import (
    float_matrix,
    float_vector,
    rigid_transform,
    transform_from_dict,
    transform_to_dict,
)
from rigcal.io.validate import finite_array, real
from rigcal.rig import COVARIANCE_PARAMETERS, Rig

RIG_SCHEMA_VERSION = 2
# Versions read: 3 adds uncertainty.reduced (a reduced solve's fixed and prior-bound
# parameters); a rig is written as 3 only when it has that section, else as 2.
RIG_SCHEMA_VERSIONS = (1, 2, 3)

_HEADER = (
    "# rigcal rig file, schema {version} (docs/formats/rig.md).\n"
    "# T_cam_laser maps laser-frame points into the camera frame: p_cam = R p_laser + t,\n"
    "# R given as a rotation vector (axis * angle, rad), t in metres.\n"
)


# A rig's sensors are metres apart; a translation beyond this is a broken file.
MAX_OFFSET_M = 1000.0


def rig_to_dict(rig: Rig) -> dict[str, Any]:
    """The YAML document of a rig (plain Python types only)."""
    doc: dict[str, Any] = {
        "schema_version": _version(rig),
        "T_cam_laser": transform_to_dict(rig.T_cam_laser, "cam", "laser"),
    }
    sig = rig.sigmas()
    if rig.covariance is not None and sig is not None:
        doc["uncertainty"] = {
            "parameters": COVARIANCE_PARAMETERS,
            "covariance": [[float(f"{x:.6e}") for x in row] for row in rig.covariance],
            "sigma_rotation_deg": [round(float(x), 6) for x in sig.rotation_deg],
            "sigma_translation_mm": [round(float(x), 4) for x in sig.translation_mm],
        } | _plain(rig.uncertainty)
    doc["camera"] = rig.camera.to_dict()
    doc["laser"] = _plain(rig.laser)
    doc["residuals"] = _plain(rig.residuals)
    doc["provenance"] = _plain(rig.provenance)
    return doc


def _version(rig: Rig) -> int:
    """The schema a rig is written in: 3 for a reduced solve's, else RIG_SCHEMA_VERSION."""
    return 3 if "reduced" in rig.uncertainty else RIG_SCHEMA_VERSION


def rig_to_text(rig: Rig) -> str:
    """Text of a rig file."""
    return _HEADER.format(version=_version(rig)) + yaml.safe_dump(
        rig_to_dict(rig), sort_keys=False, default_flow_style=None, width=100
    )


def write_rig(path: str | Path, rig: Rig, force: bool = False) -> Path:
    """Write a rig file atomically; refuses to overwrite unless ``force``, and refuses a
    rig that :func:`read_rig` would refuse (nothing is written then).

    Raises:
        OutputError: the file exists, cannot be written, or the rig is invalid.
    """
    try:
        text = checked_rig_text(rig, None, "rig")
    except InputError as e:
        raise OutputError(f"{path}: not written: the rig is invalid: {e}") from None
    return atomic_write_text(path, text, force=force)


def checked_rig_text(rig: Rig, where: str | Path | None, keypath: str) -> str:
    """The text of a rig file, checked by the reader's own validation first (a NaN
    translation, a matrix that is no rotation, a bad camera would write a file that
    :func:`read_rig` refuses).

    Raises:
        InputError: ``WHERE: KEYPATH.KEY: got VALUE; expected ...``.
    """
    rigid_transform(rig.T_cam_laser, where, f"{keypath}.T_cam_laser")
    try:
        text = rig_to_text(rig)
        rig_from_dict(yaml.safe_load(text), where, prefix=f"{keypath}.")
    except (TypeError, ValueError, AttributeError, yaml.YAMLError) as e:
        raise InputError.at(where, keypath, type(rig).__name__, f"a rig that can be written ({e})") from None
    return text


def read_rig(path: str | Path) -> Rig:
    """Read and validate a rig file.

    Raises:
        InputError: missing, unreadable or invalid file, naming the key and value.
    """
    path = Path(path)
    return rig_from_dict(load_yaml(path, "rig file"), path)


def rig_from_dict(data: Any, path: str | Path | None, prefix: str = "") -> Rig:
    """A rig from its parsed YAML document, validated (:func:`read_rig`); ``prefix``
    goes before every key path in messages."""
    try:
        return _rig_from_dict(data, path)
    except InputError as e:
        if not prefix:
            raise
        where = f"{path}: " if path is not None else ""
        text = str(e)[len(where) :] if str(e).startswith(where) else str(e)
        raise InputError(f"{where}{prefix}{text}") from None


def _rig_from_dict(data: Any, path: str | Path | None) -> Rig:
    d = check_keys(
        data,
        path,
        "",
        ["schema_version", "T_cam_laser", "camera"],
        ["uncertainty", "laser", "residuals", "provenance"],
        RIG_SCHEMA_VERSIONS,
    )
    version = d["schema_version"]
    if type(version) is not int or version not in RIG_SCHEMA_VERSIONS:
        raise InputError.at(path, "schema_version", version, "1, 2 or 3 (the versions this rigcal reads)")
    T = transform_from_dict(d["T_cam_laser"], path, "T_cam_laser", "cam", "laser")
    finite_array(T[:3, 3], path, "T_cam_laser.translation_m", lo=-MAX_OFFSET_M, hi=MAX_OFFSET_M)
    camera = camera_from_dict(d["camera"], path, "camera")
    cov = None
    extra: dict[str, Any] = {}
    if "uncertainty" in d:
        checks = list(_UNCERTAINTY_CHECKS) if version >= 2 else []
        checks += ["reduced"] if version >= 3 else []
        u = check_keys(
            d["uncertainty"],
            path,
            "uncertainty",
            ["parameters", "covariance"],
            ["sigma_rotation_deg", "sigma_translation_mm", *checks],
        )
        if u["parameters"] != COVARIANCE_PARAMETERS:
            raise InputError.at(path, "uncertainty.parameters", u["parameters"], repr(COVARIANCE_PARAMETERS))
        cov = _covariance(u["covariance"], path, "uncertainty.covariance")
        # The sigmas repeat the covariance's diagonal (rounded): they must agree with it.
        d_sqrt = np.sqrt(np.clip(np.diag(cov), 0.0, None))
        implied = {"sigma_rotation_deg": np.degrees(d_sqrt[:3]), "sigma_translation_mm": 1000.0 * d_sqrt[3:]}
        for key in ("sigma_rotation_deg", "sigma_translation_mm"):
            if key in u:
                given = float_vector(u[key], path, f"uncertainty.{key}", 3)
                if not np.allclose(given, implied[key], rtol=1e-3, atol=1e-4):
                    shown = [round(float(x), 6) for x in implied[key]]
                    raise InputError.at(
                        path,
                        f"uncertainty.{key}",
                        u[key],
                        f"{shown}, the square roots of the covariance's diagonal",
                    )
        extra = _uncertainty_checks(u, path)
    sections = {}
    for key in ("laser", "residuals", "provenance"):
        value = d.get(key, {})
        if not isinstance(value, dict):
            raise InputError.at(path, key, value, "a mapping")
        sections[key] = value
    return Rig(T, camera, cov, sections["laser"], sections["residuals"], sections["provenance"], extra)


_UNCERTAINTY_CHECKS = ("noise", "model_covariance", "spread", "sensitivity")


def _covariance(value: Any, path: str | Path | None, key: str) -> Any:
    cov = float_matrix(value, path, key, 6, 6)
    # Tolerances relative to the matrix's scale: the writer keeps 7 significant digits,
    # which can push a (near-)zero eigenvalue slightly below 0.
    scale = float(np.abs(cov).max())
    if (
        not np.allclose(cov, cov.T, rtol=1e-4, atol=1e-9 * scale)
        or np.linalg.eigvalsh(cov).min() < -1e-5 * scale
    ):
        raise InputError.at(path, key, "...", "a symmetric positive semi-definite matrix")
    return cov


def _uncertainty_checks(u: Mapping[str, Any], path: str | Path | None) -> dict[str, Any]:
    """The covariance's checks of a version 2 rig file, validated (docs/formats/rig.md)."""
    out: dict[str, Any] = {}
    if "noise" in u:
        noise = u["noise"]
        if not isinstance(noise, dict):
            raise InputError.at(
                path, "uncertainty.noise", noise, "a mapping of noise name to assumed/estimated/used"
            )
        for name, v in noise.items():
            key = f"uncertainty.noise.{name}"
            v = check_keys(v, path, key, ["assumed", "estimated", "used"], [])
            for k in ("assumed", "used", "estimated"):
                if k != "estimated" or v[k] is not None:
                    real(v[k], path, f"{key}.{k}", nonneg=True)
        out["noise"] = noise
    if "model_covariance" in u:
        _covariance(u["model_covariance"], path, "uncertainty.model_covariance")
        out["model_covariance"] = u["model_covariance"]
    if "spread" in u:
        sp = u["spread"]
        if not isinstance(sp, dict) or "scale" not in sp or "covariance" not in sp:
            raise InputError.at(path, "uncertainty.spread", sp, "a mapping with scale and covariance")
        real(sp["scale"], path, "uncertainty.spread.scale", nonneg=True)
        _covariance(sp["covariance"], path, "uncertainty.spread.covariance")
        out["spread"] = sp
    if "sensitivity" in u:
        sens = u["sensitivity"]
        if not isinstance(sens, list) or not all(isinstance(x, dict) for x in sens):
            raise InputError.at(path, "uncertainty.sensitivity", sens, "a list of mappings")
        out["sensitivity"] = sens
    if "reduced" in u:
        r = check_keys(
            u["reduced"],
            path,
            "uncertainty.reduced",
            ["model", "solved", "prior_bound"],
            ["level_frame", "noise_dof"],
        )
        for key in ("solved", "prior_bound"):
            if not isinstance(r[key], dict) or not all(
                isinstance(v, dict) and "value" in v and "sigma" in v for v in r[key].values()
            ):
                raise InputError.at(
                    path,
                    f"uncertainty.reduced.{key}",
                    r[key],
                    "a mapping of parameter to {value, sigma, ...}",
                )
        out["reduced"] = u["reduced"]
    return out


def provenance(
    command: str, inputs: list[Path], settings: dict[str, Any], base: Path | None = None
) -> dict[str, Any]:
    """How a result was made: version, UTC time, command line, input hashes, settings.

    Args:
        command: the command line.
        inputs: every file read.
        settings: solver settings to record.
        base: when given, recorded as ``inputs_base`` (absolute) and input paths are written
            relative to it where they lie below it.
    """
    import datetime

    from rigcal.io.files import sha256_file

    def shown(p: Path) -> str:
        if base is not None:
            try:
                return Path(p).resolve().relative_to(base.resolve()).as_posix()
            except ValueError:
                pass
        return str(Path(p).resolve())

    out: dict[str, Any] = {
        "rigcal_version": __version__,
        "created_utc": datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%dT%H:%M:%SZ"),
        "command": command,
    }
    if base is not None:
        out["inputs_base"] = str(base.resolve())
    out["inputs"] = [{"path": shown(p), "sha256": sha256_file(p)} for p in inputs]
    return out | settings


def _plain(x: Any) -> Any:
    """Convert numpy scalars/arrays and paths to plain YAML-safe types."""
    if isinstance(x, dict):
        return {str(k): _plain(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_plain(v) for v in x]
    if isinstance(x, np.ndarray):
        return _plain(x.tolist())
    if isinstance(x, np.bool_):
        return bool(x)
    if isinstance(x, np.integer):
        return int(x)
    if isinstance(x, (np.floating, float)):
        return float(x)
    if isinstance(x, Path):
        return str(x)
    return x
