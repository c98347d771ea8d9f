"""rigcal: laser-camera calibration and image-augmented laser scan matching.

The Python API (docs/api.md)::

    import rigcal

    sol = rigcal.solve_box("session/picks.yaml")        # or captures in memory
    rigcal.write_rig("rig.yaml", sol.rig)
    rig = rigcal.read_rig("rig.yaml")
    runs = rigcal.localize("corridor/", ["icp", "hiasm"])

The names are loaded on first use, so ``import rigcal`` (and the ``rigcal`` command's
``--help``) stays fast.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

__version__ = "0.1.0"

__all__ = [
    "BoardCapture",
    "BoxCapture",
    "Camera",
    "Localization",
    "Rig",
    "Scan",
    "Solution",
    "__version__",
    "localize",
    "read_rig",
    "solve_board",
    "solve_box",
    "write_rig",
]

if TYPE_CHECKING:
    from rigcal.api import (
        BoardCapture,
        BoxCapture,
        Localization,
        Solution,
        localize,
        read_rig,
        solve_board,
        solve_box,
        write_rig,
    )
    from rigcal.camera import Camera
    from rigcal.rig import Rig
    from rigcal.scan import Scan

_HOMES = {"Camera": "rigcal.camera", "Rig": "rigcal.rig", "Scan": "rigcal.scan"}


def __getattr__(name: str) -> Any:
    if name not in __all__ or name == "__version__":
        raise AttributeError(f"module 'rigcal' has no attribute {name!r}")
    import importlib

    return getattr(importlib.import_module(_HOMES.get(name, "rigcal.api")), name)


def __dir__() -> list[str]:
    return sorted(__all__)
