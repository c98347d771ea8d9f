"""Array aliases and robust-statistics constants shared by every layer."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

# sigma of a normal distribution over its median absolute deviation: 1 / Phi^-1(3/4)
MAD_TO_SIGMA = 1.482602218505602
