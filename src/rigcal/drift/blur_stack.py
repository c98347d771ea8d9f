"""Blurred images made only where they are read: one Gaussian blur per key (an image at a
blur level), over a box of it, widened on demand.

The targetless check (:mod:`rigcal.drift.targetless`) reads its blurred frames only
around the laser's returns projected into them (the photometric patches) and around
the scans' depth discontinuities (the edge bands, :mod:`rigcal.drift.edges`): a small
part of each frame. Blurring whole frames was most of the check's image work. Here
each key's blur is made over the box its reads fall in under the stored T_cam_laser
(with a margin for the correction), and a read that falls outside its key's box (the
estimate moved a point farther) widens the box first. A Gaussian blur of a crop that
reaches a kernel radius beyond the box equals the blur of the whole image there, bit
for bit (OpenCV's separable filter; ``tests/drift/test_blur_stack.py``), so every value
read is the value the whole blurred image holds: the results are those of blurring
every frame whole.

Coordinates are the stack's: rows from the first row of the band the stack holds
(``row0`` of the key's source image), columns as in the source image.
"""

from __future__ import annotations

import math
import mmap
import threading
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from rigcal.arrays import FloatArray, IntArray

Source = Callable[[int, int, int], NDArray[np.uint16]]
"""Rows a:b of a source image (uint16, the stack's grey scale, possibly downsampled,
every column) by its id, a and b."""


class BlurStack:
    """(K, H, W) uint16 blurred images, key k holding source ``image_of[k]`` blurred by
    ``sigma_px[k]``, rows ``row0`` to ``row0 + H`` of it, made only inside ``box[k]``
    (rows r0:r1, columns c0:c1; empty at first). Pixels outside a key's box hold
    nothing meaningful: readers check the box (:meth:`covers`) and widen it
    (:meth:`widen`) before reading.

    With ``narrow``, each key keeps only a window of columns around its box (its columns
    from ``col0[k]`` on, as many as the widest box and a margin): key k's column c is
    ``stack[k, :, c - col0[k]]``. For boxes far narrower than the images (an edge's
    search); a box widened beyond its window gives every key the whole width."""

    def __init__(
        self,
        image_of: IntArray,
        sigma_px: FloatArray,
        row0: int,
        height: int,
        width: int,
        source: Source,
        source_height: int,
        narrow: bool = False,
    ) -> None:
        self.image_of = np.asarray(image_of, dtype=np.int64)
        self.sigma_px = np.asarray(sigma_px, dtype=np.float64)
        self.row0 = row0
        self.height, self.width = height, width
        self.stack = _untouched((0 if narrow else len(self.image_of), height, width))
        self.col0 = np.zeros(len(self.image_of), dtype=np.int64)
        self._narrow = narrow
        self.box = np.zeros((len(self.image_of), 4), dtype=np.int64)
        self._source = source
        self._height = source_height  # the source images' rows
        self._lock = threading.Lock()

    def fill(self, need: IntArray, threads: int = 2) -> None:
        """Make each key's blur over ``need[k]`` (rows r0:r1, columns c0:c1, stack
        coordinates; clipped to the stack), on ``threads`` threads (OpenCV releases the
        interpreter). Each source image is read once for all its keys; the keys' crops
        (:meth:`_padded`) of one blur are then laid side by side and blurred at once:
        OpenCV filters a wide image several times faster per pixel than a narrow one,
        and each crop's pad keeps its neighbours out of its box."""
        need = self._clipped(need)
        made = np.flatnonzero((need[:, 1] > need[:, 0]) & (need[:, 3] > need[:, 2]))
        images = np.unique(self.image_of[made])
        if self._narrow:
            wide = int((need[made, 3] - need[made, 2]).max(initial=0)) + 2 * NARROW_MARGIN_PX
            window = min(wide, self.width)
            self.col0 = np.clip(need[:, 2] - NARROW_MARGIN_PX, 0, self.width - window)
            self.stack = _untouched((len(self.image_of), self.height, window))
        of_image = [made[self.image_of[made] == i] for i in images]
        crops: list[list[tuple[int, NDArray[np.uint16]]]] = [[] for _ in images]

        def cut(n: int) -> None:
            keys = of_image[n]
            pads = np.array([_pad(float(x)) for x in self.sigma_px[keys]])
            a = max(int((self.row0 + need[keys, 0] - pads).min()), 0)
            b = min(int((self.row0 + need[keys, 1] + pads).max()), self._height)
            g = self._source(int(images[n]), a, b)  # the rows its keys' crops read
            crops[n] = [(int(k), self._padded(int(k), need[k], g, a)) for k in keys]

        def blur(rows: list[tuple[int, NDArray[np.uint16]]]) -> None:
            sigma = float(self.sigma_px[rows[0][0]])
            buf = np.zeros((max(c.shape[0] for _, c in rows), sum(c.shape[1] for _, c in rows)), np.uint16)
            x = 0
            for _, c in rows:
                buf[: c.shape[0], x : x + c.shape[1]] = c
                x += c.shape[1]
            out = cv2.GaussianBlur(buf, (0, 0), sigma)
            x = 0
            for k, c in rows:
                self._place(k, need[k], out, x)
                self.box[k] = need[k]
                x += c.shape[1]

        with ThreadPoolExecutor(max_workers=max(threads, 1), thread_name_prefix="blur-stack") as pool:
            list(pool.map(cut, range(len(images))))
            list(pool.map(blur, _side_by_side([kc for n in crops for kc in n], self.sigma_px)))

    def covers(self, keys: IntArray, need: IntArray) -> NDArray[np.bool_]:
        """(N,) whether each key's box holds the (N, 4) region ``need``."""
        b = self.box[keys]
        rows = (b[:, 0] <= need[:, 0]) & (need[:, 1] <= b[:, 1])
        out: NDArray[np.bool_] = rows & (b[:, 2] <= need[:, 2]) & (need[:, 3] <= b[:, 3])
        return out

    def widen(self, keys: IntArray, need: IntArray, margin_px: int) -> None:
        """Widen each key's box to hold the regions ``need`` of its reads (N, 4), with
        ``margin_px`` more on every side, and make the blur there; safe from several
        threads at once (a box grows only after its pixels are made)."""
        with self._lock:
            for k in np.unique(keys):
                r = need[keys == k]
                if self.covers(np.full(len(r), k), r).all():  # another thread made it meanwhile
                    continue
                lo = r[:, 0::2].min(axis=0) - margin_px  # first row, first column
                hi = r[:, 1::2].max(axis=0) + margin_px  # past the last
                b = self.box[k]
                if b[1] > b[0] and b[3] > b[2]:  # the union with what is made
                    lo, hi = np.minimum(lo, b[0::2]), np.maximum(hi, b[1::2])
                want = self._clipped(np.array([[lo[0], hi[0], lo[1], hi[1]]]))[0]
                if want[2] < self.col0[k] or want[3] > self.col0[k] + self.stack.shape[2]:
                    self._whole_width()
                pad = _pad(float(self.sigma_px[k]))
                a = max(self.row0 + int(want[0]) - pad, 0)
                b = min(self.row0 + int(want[1]) + pad, self._height)
                crop = self._padded(int(k), want, self._source(int(self.image_of[k]), a, b), a)
                self._place(int(k), want, cv2.GaussianBlur(crop, (0, 0), float(self.sigma_px[k])), 0)
                self.box[k] = want

    def _whole_width(self) -> None:
        """Every key's window the images' whole width (what is made kept)."""
        wide = _untouched((len(self.image_of), self.height, self.width))
        for k, (r0, r1, c0, c1) in enumerate(self.box):
            if r1 > r0 and c1 > c0:
                wide[k, r0:r1, c0:c1] = self.stack[k, r0:r1, c0 - self.col0[k] : c1 - self.col0[k]]
        self.stack, self.col0 = wide, np.zeros_like(self.col0)

    def _clipped(self, need: IntArray) -> IntArray:
        H, W = self.height, self.width
        out = np.array(need, dtype=np.int64, copy=True)
        out[:, 0:2] = np.clip(out[:, 0:2], 0, H)
        out[:, 2:4] = np.clip(out[:, 2:4], 0, W)
        return out

    def _padded(self, k: int, box: IntArray, g: NDArray[np.uint16], g_row0: int) -> NDArray[np.uint16]:
        """Key k's source over box, a kernel radius wider on every side, from ``g`` (the
        source's rows from ``g_row0`` on, those the crop reads): the image's pixels, or
        OpenCV's default border (reflected, the edge pixel once) beyond the image, so
        that blurring the crop alone gives the whole image's blur in the box."""
        pad = _pad(float(self.sigma_px[k]))
        r0, r1, c0, c1 = (int(x) for x in box)
        top, bottom, left, right = self.row0 + r0 - pad, self.row0 + r1 + pad, c0 - pad, c1 + pad
        a, b = max(top, 0), min(bottom, self._height)
        ca, cb = max(left, 0), min(right, g.shape[1])
        crop: NDArray[np.uint16] = g[a - g_row0 : b - g_row0, ca:cb]
        if (a - top, bottom - b, ca - left, right - cb) == (0, 0, 0, 0):
            return crop
        border = cv2.BORDER_REFLECT_101
        out = cv2.copyMakeBorder(crop, a - top, bottom - b, ca - left, right - cb, borderType=border)
        return np.asarray(out, dtype=np.uint16)

    def _place(self, k: int, box: IntArray, blurred: NDArray[Any], x: int) -> None:
        """Key k's box from its blurred crop, the crop's columns from x on."""
        pad = _pad(float(self.sigma_px[k]))
        r0, r1, c0, c1 = (int(v) for v in box)
        at = c0 - int(self.col0[k])
        self.stack[k, r0:r1, at : at + c1 - c0] = blurred[pad : pad + r1 - r0, x + pad : x + pad + c1 - c0]


NARROW_MARGIN_PX = 16
"""A narrow stack's windows reach this much beyond the widest box on either side."""


def _untouched(shape: tuple[int, int, int]) -> NDArray[np.uint16]:
    """An uninitialised uint16 array whose memory is taken a small page at a time as it
    is written: the boxes are a small part of it. (numpy asks the kernel for huge pages
    for large arrays, and a huge page is zeroed whole, 2 MiB, at its first write: the
    boxes' scattered rows would take and zero most of the array.)"""
    size = int(np.prod(shape)) * 2
    if size == 0:
        return np.empty(shape, dtype=np.uint16)
    buf = mmap.mmap(-1, size)  # anonymous memory, zero pages mapped at first write
    if hasattr(mmap, "MADV_NOHUGEPAGE"):
        buf.madvise(mmap.MADV_NOHUGEPAGE)
    return np.frombuffer(buf, dtype=np.uint16).reshape(shape)


def _pad(sigma_px: float) -> int:
    """Pixels beyond a box that its blur reads: OpenCV's 16-bit Gaussian kernel has
    round(8 sigma + 1) | 1 taps, at most 4 sigma + 0.75 either side."""
    return math.ceil(4.0 * sigma_px) + 1


SIDE_BY_SIDE_PX = 4096
"""Crops laid side by side in one blur, at most this wide in all (a few MiB)."""


def _side_by_side(
    crops: list[tuple[int, NDArray[np.uint16]]], sigma_px: FloatArray
) -> list[list[tuple[int, NDArray[np.uint16]]]]:
    """The crops in rows to blur at once: of one blur each, of about one height (the
    tallest first: a row is as tall as its tallest crop), at most
    :data:`SIDE_BY_SIDE_PX` wide."""
    crops = sorted(crops, key=lambda kc: (float(sigma_px[kc[0]]), -kc[1].shape[0]))
    out: list[list[tuple[int, NDArray[np.uint16]]]] = []
    width = 0
    for k, c in crops:
        if not out or sigma_px[out[-1][0][0]] != sigma_px[k] or width + c.shape[1] > SIDE_BY_SIDE_PX:
            out.append([])
            width = 0
        out[-1].append((k, c))
        width += c.shape[1]
    return out
