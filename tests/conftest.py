"""Settings shared by the whole suite.

Hypothesis property tests run a fixed set of 40 examples each (derandomized: the same in
every CI run). Set RIGCAL_HYPOTHESIS_EXAMPLES=N to explore N random examples instead.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Iterator

import pytest
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


@pytest.fixture(autouse=True)
def _rigcal_logger_restored() -> Iterator[None]:
    """Each test leaves the ``rigcal`` logger as it found it: a command run with ``-v``
    installs a stderr handler at INFO/DEBUG (``rigcal.cli.progress.configure``) that would
    otherwise print later tests' log lines on their stderr."""
    log = logging.getLogger("rigcal")
    handlers, level, propagate = list(log.handlers), log.level, log.propagate
    yield
    log.handlers[:] = handlers
    log.setLevel(level)
    log.propagate = propagate
