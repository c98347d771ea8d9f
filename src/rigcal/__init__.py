"""rigcal: laser-camera calibration and image-augmented laser scan matching.

The Python API (docs/api.md)::

    import rigcal

    sol = rigcal.solve_box("session/picks.yaml")        # or captures in memory
    rigcal.write_rig("rig.yaml", sol.rig)
    rig = rigcal.read_rig("rig.yaml")
    runs = rigcal.localize("corridor/", ["icp", "hiasm"])
    odom = rigcal.LaserOdometry()                        # scan by scan, in a robot's loop

The names are loaded on first use, so ``import rigcal`` (and the ``rigcal`` command's
``--help``) stays fast.

``rigcal.localize`` is both the subpackage and :func:`rigcal.api.localize`: importing a
submodule makes Python bind the subpackage to the name, so this package makes the
subpackage callable as it is bound, and a call runs the function (the subpackage itself
knows nothing of the API above it).
"""

from __future__ import annotations

import sys
import types
from typing import TYPE_CHECKING, Any

__version__ = "0.1.0"

__all__ = [
    "ArgumentError",
    "Board",
    "BoardCapture",
    "BoardReport",
    "BoxCapture",
    "BoxReport",
    "CalibrationError",
    "Camera",
    "InputError",
    "LaserOdometry",
    "Localization",
    "OutputError",
    "Rig",
    "RigcalError",
    "Scan",
    "Sigmas",
    "Solution",
    "Trajectory",
    "__version__",
    "localize",
    "read_rig",
    "read_scans",
    "read_trajectory",
    "solve_board",
    "solve_box",
    "write_rig",
    "write_trajectory",
]

if TYPE_CHECKING:
    from rigcal.api import (
        Board,
        BoardCapture,
        BoardReport,
        BoxCapture,
        BoxReport,
        LaserOdometry,
        Localization,
        Solution,
        Trajectory,
        localize,
        read_rig,
        read_scans,
        read_trajectory,
        solve_board,
        solve_box,
        write_rig,
        write_trajectory,
    )
    from rigcal.camera import Camera
    from rigcal.errors import ArgumentError, CalibrationError, InputError, OutputError, RigcalError
    from rigcal.rig import Rig, Sigmas
    from rigcal.scan import Scan

_HOMES = {
    "Camera": "rigcal.camera",
    "Rig": "rigcal.rig",
    "Sigmas": "rigcal.rig",
    "Scan": "rigcal.scan",
    **dict.fromkeys(
        ("ArgumentError", "CalibrationError", "InputError", "OutputError", "RigcalError"), "rigcal.errors"
    ),
}


def __getattr__(name: str) -> Any:
    if name not in __all__ or name == "__version__":
        raise AttributeError(f"module 'rigcal' has no attribute {name!r}")
    import importlib

    return getattr(importlib.import_module(_HOMES.get(name, "rigcal.api")), name)


def __dir__() -> list[str]:
    return sorted(__all__)


class _CallableLocalize(types.ModuleType):
    """``rigcal.localize``, the subpackage, as the API's function."""

    def __call__(self, *args: Any, **kwargs: Any) -> Any:
        return __getattr__("localize")(*args, **kwargs)


class _Package(types.ModuleType):
    """This package: the subpackage ``rigcal.localize`` is made callable as Python binds it."""

    def __setattr__(self, name: str, value: Any) -> None:
        if name == "localize" and isinstance(value, types.ModuleType):
            value.__class__ = _CallableLocalize
        super().__setattr__(name, value)


sys.modules[__name__].__class__ = _Package
