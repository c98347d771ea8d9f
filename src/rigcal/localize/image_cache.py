"""Decoded images kept in memory up to a byte budget, the least recently used going first;
safe to use from the prefetch thread (:mod:`rigcal.localize.prefetch`) and the caller's at
once. Frames can be decoded into it early (:class:`EarlyFrames`), before the modules
that otherwise decode them are imported.
"""

from __future__ import annotations

import sys
import threading
from collections import OrderedDict
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

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


class EarlyFrames:
    """Frames decoded into an :class:`ImageCache` on a thread of their own from the moment
    they are known: a command that knows which frames it will read starts decoding them
    while it still imports OpenCV, numba and the rest (the decoding, imagecodecs' libpng,
    runs outside the interpreter's lock, on the other core).

    Plain 8-bit PNGs only (:mod:`rigcal.io.png`: the levels ``read_grey`` returns, bit for
    bit), of the given size (height, width). The first frame it cannot take (another kind
    of file, another size, unreadable) ends it: the reader's own decoding then reads that
    frame and reports what is wrong with it. For readers that keep frames as decoded (no
    equalisation). :meth:`stop` before the reader decodes these frames itself, so that
    no frame is decoded twice.
    """

    def __init__(self, paths: Sequence[tuple[int, Path]], shape: tuple[int, int], cache: ImageCache) -> None:
        self.cache = cache
        self.decoded = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(
            target=self._run, args=(list(paths), shape), name="rigcal-early-frames", daemon=True
        )
        self._thread.start()

    def _run(self, paths: list[tuple[int, Path]], shape: tuple[int, int]) -> None:
        from rigcal.io.png import plain_png_grey

        for i, path in paths:
            if self._stop.is_set():
                return
            try:
                data = path.read_bytes()
            except OSError:
                return
            g = plain_png_grey(data, _to_grey())
            if g is None or g.shape != shape:
                return
            self.cache.keep(i, g)
            self.decoded += 1

    def stop(self) -> None:
        """Stop after the frame under way (kept) and wait for the thread."""
        self._stop.set()
        self._thread.join()


def _to_grey() -> Callable[[NDArray[np.uint8]], Gray]:
    """The colour conversion for :class:`EarlyFrames`: the compiled one once another thread
    has loaded it, numpy's before (the same levels). Never the first call of a compiled
    kernel here: that sets numba up (about half a CPU second of the interpreter's time,
    holding numba's compile lock), which another thread makes (the command's main thread
    at its first kernel, or a decoding thread) while this one goes on decoding."""
    from rigcal.jit import loaded

    images = sys.modules.get("rigcal.io.images")
    # The kernel is the module's last definition: present, the module is complete.
    kernel = getattr(images, "_rgb_to_grey", None)
    if images is not None and kernel is not None and loaded(kernel):
        to_grey: Callable[[NDArray[np.uint8]], Gray] = images.rgb_to_grey
        return to_grey
    from rigcal.io.png import rgb_to_grey_reference

    return rgb_to_grey_reference
