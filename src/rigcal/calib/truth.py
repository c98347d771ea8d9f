"""Truth files: the known T_cam_laser of a simulated session, to check a solve against.

Format (docs/formats/truth.md)::

    schema_version: 1
    T_cam_laser: {maps: laser -> cam, rotation_vector_rad: [...], translation_m: [...]}
    generator: {...}     # optional, free-form: how the session was made (seed, noise)
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import yaml
from numpy.typing import NDArray

from rigcal.io.files import check_keys, check_schema_version, load_yaml
from rigcal.io.transform import transform_from_dict, transform_to_dict

TRUTH_SCHEMA_VERSION = 1


def truth_to_text(T_cam_laser: NDArray[np.float64], generator: dict[str, Any] | None = None) -> str:
    """Text of a truth file."""
    doc: dict[str, Any] = {
        "schema_version": TRUTH_SCHEMA_VERSION,
        "T_cam_laser": transform_to_dict(T_cam_laser, "cam", "laser"),
    }
    if generator:
        doc["generator"] = generator
    header = "# rigcal truth file: the T_cam_laser a session was generated with (docs/formats/truth.md)\n"
    return header + yaml.safe_dump(doc, sort_keys=False, default_flow_style=None)


def read_truth(path: str | Path) -> NDArray[np.float64]:
    """Read a truth file; returns T_cam_laser (4, 4)."""
    path = Path(path)
    d = check_keys(
        load_yaml(path, "truth file"),
        path,
        "",
        ["schema_version", "T_cam_laser"],
        ["generator"],
        [TRUTH_SCHEMA_VERSION],
    )
    check_schema_version(d, path, TRUTH_SCHEMA_VERSION)
    return transform_from_dict(d["T_cam_laser"], path, "T_cam_laser", "cam", "laser")
