"""Localization: laser odometry, visual odometry, the Kalman filter, IASM and H-IASM.

``rigcal.localize`` is both this package and the API function
:func:`rigcal.api.localize`: importing a submodule makes Python bind the package to the
name ``rigcal.localize``, so the package is made callable and a call runs the function.
"""

from __future__ import annotations

import sys
import types
from typing import Any


class _CallablePackage(types.ModuleType):
    def __call__(self, *args: Any, **kwargs: Any) -> Any:
        from rigcal.api import localize

        return localize(*args, **kwargs)


sys.modules[__name__].__class__ = _CallablePackage
