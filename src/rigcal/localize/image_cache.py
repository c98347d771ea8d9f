"""Decoded images kept in memory up to a byte budget, the least recently used going first;
safe to use from the prefetch thread (:mod:`rigcal.localize.prefetch`) and the caller's at
once.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

Gray = NDArray[np.uint8]

# Decoded images kept (least recently used out first): a whole 10 Hz VGA lap of several
# minutes fits, so methods that pass over the images twice (H-IASM: tracking, then
# matching) decode each PNG once.
_IMAGE_CACHE_BYTES = 768 * 2**20


@dataclass
class ImageCache:
    """Frames by index, up to ``_IMAGE_CACHE_BYTES`` in all."""

    _images: OrderedDict[int, Gray] = field(default_factory=OrderedDict, repr=False)
    _cached_bytes: int = field(default=0, repr=False)
    _lock: threading.Lock = field(default_factory=threading.Lock, repr=False)

    def get(self, i: int) -> Gray | None:
        """Frame i if kept, else None."""
        with self._lock:
            return self._images.get(i)

    def keep(self, i: int, g: Gray) -> Gray:
        """Keep frame i (the least recently used frames go when over the budget)."""
        with self._lock:
            if i in self._images:
                self._images.move_to_end(i)
            else:
                self._images[i] = g
                self._cached_bytes += g.nbytes
                while self._cached_bytes > _IMAGE_CACHE_BYTES and len(self._images) > 1:
                    self._cached_bytes -= self._images.popitem(last=False)[1].nbytes
        return g

    def indices(self) -> list[int]:
        """The frames kept, least recently used first."""
        with self._lock:
            return list(self._images)
