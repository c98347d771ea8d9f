"""Settings shared by the whole suite.

Hypothesis property tests run a fixed set of 40 examples each (derandomized: the same in
every CI run). Set RIGCAL_HYPOTHESIS_EXAMPLES=N to explore N random examples instead.
"""

from __future__ import annotations

import os

from hypothesis import HealthCheck, settings

_EXPLORE = os.environ.get("RIGCAL_HYPOTHESIS_EXAMPLES")
settings.register_profile(
    "rigcal",
    max_examples=int(_EXPLORE) if _EXPLORE else 40,
    derandomize=not _EXPLORE,
    deadline=None,
    suppress_health_check=list(HealthCheck),
)
settings.load_profile("rigcal")
