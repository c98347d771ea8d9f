"""Projection and bilinear sampling for the targetless check, in one compiled pass.

Each Gauss-Newton step of the check (:mod:`rigcal.drift.targetless`) projects every grid
point into its image with T_cam_laser (paper Eq. (1) plus the lens's distortion) and reads
the grey level and its gradient there. :func:`project_sample` does both per point in one
loop: the OpenCV distortion models (``LENSMODEL_PINHOLE``, ``LENSMODEL_OPENCV4/5/8/12``:
mrcal's, in OpenCV's coefficient order) with their derivatives in closed form, and the
grey level by bilinear interpolation with its derivatives by central differences half a
pixel either side (smooth across pixel borders, unlike the bilinear's own derivative).
Other lens models (mrcal's splined ones) are projected by mrcal and sampled by the same
kernel. :func:`project_sample_reference` is the numpy reference the kernel is tested
against.

The images are one stack (K, H, W) of blurred, possibly downsampled grey levels stored
as uint16 x 64, possibly a band of their rows only (the laser's returns fill a band of
the image); each point names its image in the stack. A stack downsampled by 2 (the
coarse stage, where the blur is wide) is read at q_half = (q - 0.5) / 2: its pixel (u, v)
is the mean of full-size pixels (2u, 2v) to (2u + 1, 2v + 1), centred at (2u + 0.5,
2v + 0.5).
"""

from __future__ import annotations

from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import numpy as np
from numpy.typing import NDArray

from rigcal.arrays import FloatArray
from rigcal.jit import njit

GRAD_STEP_PX = 0.5
"""Half the span of the central differences, in the stack's pixels."""
GREY_SCALE = 64.0
"""The stack holds grey levels times this (uint16: 1/64 grey level steps)."""
BORDER_PX = 1.0
"""A point nearer than this to the image's edge (full-size pixels) reads NaN."""

_OPENCV_CODES = {
    "LENSMODEL_PINHOLE": 0,
    "LENSMODEL_OPENCV4": 4,
    "LENSMODEL_OPENCV5": 5,
    "LENSMODEL_OPENCV8": 8,
    "LENSMODEL_OPENCV12": 12,
}


def compiled_model(lensmodel: str) -> bool:
    """Whether the kernel projects this lens model itself (else mrcal does)."""
    return lensmodel in _OPENCV_CODES


def project_sample(
    points: FloatArray,
    R: FloatArray,
    t: FloatArray,
    camera: Any,
    stack: NDArray[np.uint16],
    which: NDArray[np.int64],
    down: int,
    row0: int = 0,
    box: NDArray[np.int64] | None = None,
    widen: Callable[[NDArray[np.int64], NDArray[np.int64]], None] | None = None,
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Grey levels at the projections of points, and their derivatives.

    Args:
        points: (N, 3) points in the laser frame, metres.
        R, t: (3, 3), (3,) T_cam_laser's rotation and translation.
        camera: the :class:`rigcal.camera.Camera`.
        stack: (K, H, W) uint16 images, grey levels x :data:`GREY_SCALE`.
        which: (N,) the image of each point in the stack.
        down: the stack's downsampling (1 or 2).
        row0: the stack's first row, in its own (downsampled) pixels: a stack may hold a
            band of the images' rows only; points outside it read NaN.
        box: (K, 4) where each image of the stack is made (rows r0:r1, columns c0:c1 of
            the stack, :class:`rigcal.drift.blur_stack.BlurStack`); None: everywhere.
        widen: with ``box``, called with the images and the (N, 4) regions of the reads
            that fall outside their boxes; it makes them (widening ``box``), and those
            points are read again.

    Returns:
        value: (N,) grey levels (NaN outside the image, behind the camera).
        d_point: (N, 3) d value / d point, laser frame.
        d_rot: (N, 3) d value / d w for a right update x' = Exp(w) x (point cross d_point).
    """
    n = len(points)
    value = np.empty(n)
    d_point = np.empty((n, 3))
    d_rot = np.empty((n, 3))
    need = np.empty((n, 4), dtype=np.int64)
    R = np.ascontiguousarray(R, dtype=np.float64)
    t = np.ascontiguousarray(t, dtype=np.float64)
    pts = np.ascontiguousarray(points, dtype=np.float64)
    if box is None:
        box = np.tile(np.array([0, stack.shape[1], 0, stack.shape[2]], dtype=np.int64), (len(stack), 1))
    intr = np.zeros(16)
    if compiled_model(camera.lensmodel):
        code = _OPENCV_CODES[camera.lensmodel]
        intr[: len(camera.intrinsics)] = camera.intrinsics
        q, dq = np.zeros((0, 2)), np.zeros((0, 2, 3))
    else:
        code = -1
        q, dq = camera.project_with_gradient(pts @ R.T + t)
    size = (camera.width_px, camera.height_px)
    q, dq = np.ascontiguousarray(q), np.ascontiguousarray(dq)
    which = np.ascontiguousarray(which)

    def part(a: int, b: int) -> None:
        """Points a to b (the kernel releases the interpreter: parts run side by side)."""
        qa, dqa = (q[a:b], dq[a:b]) if code < 0 else (q, dq)
        _project_sample_kernel(
            pts[a:b], R, t, intr, code, qa, dqa, stack, box, which[a:b], down, row0, *size,
            value[a:b], d_point[a:b], d_rot[a:b], need[a:b],
        )  # fmt: skip

    if n < SPLIT_ABOVE:
        part(0, n)
    else:
        with ThreadPoolExecutor(max_workers=2, thread_name_prefix="sample") as pool:
            list(pool.map(lambda ab: part(*ab), ((0, n // 2), (n // 2, n))))
    missed = np.flatnonzero(need[:, 0] >= 0)
    for _ in range(3):  # once is enough: widen makes what the reads need
        if not len(missed):
            break
        if widen is None:
            raise ValueError("project_sample: reads outside the images' boxes, and nothing to widen them")
        widen(which[missed], need[missed])
        m = missed
        qm, dqm = (q[m], dq[m]) if code < 0 else (q, dq)
        v, dp, dr = np.empty(len(m)), np.empty((len(m), 3)), np.empty((len(m), 3))
        nd = np.empty((len(m), 4), dtype=np.int64)
        _project_sample_kernel(
            pts[m], R, t, intr, code, qm, dqm, stack, box, which[m], down, row0, *size, v, dp, dr, nd
        )
        value[m], d_point[m], d_rot[m], need[m] = v, dp, dr, nd
        missed = m[nd[:, 0] >= 0]
    if len(missed):
        raise RuntimeError("project_sample: widen did not make the regions the reads need")
    return value, d_point, d_rot


SPLIT_ABOVE = 20000
"""More points than this are projected and sampled in two halves on two threads."""


@njit
def _distort(
    x: float, y: float, intr: FloatArray, code: int
) -> tuple[float, float, float, float, float, float]:
    """OpenCV's distortion of normalised (x, y): (xd, yd) and d(xd, yd)/d(x, y)."""
    if code == 0:
        return x, y, 1.0, 0.0, 0.0, 1.0
    k1, k2, p1, p2 = intr[4], intr[5], intr[6], intr[7]
    k3 = intr[8] if code >= 5 else 0.0
    k4 = intr[9] if code >= 8 else 0.0
    k5 = intr[10] if code >= 8 else 0.0
    k6 = intr[11] if code >= 8 else 0.0
    s1 = intr[12] if code >= 12 else 0.0
    s2 = intr[13] if code >= 12 else 0.0
    s3 = intr[14] if code >= 12 else 0.0
    s4 = intr[15] if code >= 12 else 0.0
    r2 = x * x + y * y
    num = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    den = 1.0 + r2 * (k4 + r2 * (k5 + r2 * k6))
    dnum = k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2)
    dden = k4 + r2 * (2.0 * k5 + 3.0 * k6 * r2)
    rad = num / den
    drad = (dnum * den - num * dden) / (den * den)  # d rad / d r2
    sx = s1 + 2.0 * s2 * r2  # d (s1 r2 + s2 r2^2) / d r2
    sy = s3 + 2.0 * s4 * r2
    xd = x * rad + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x) + r2 * (s1 + s2 * r2)
    yd = y * rad + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y + r2 * (s3 + s4 * r2)
    a = rad + 2.0 * x * x * drad + 2.0 * p1 * y + 6.0 * p2 * x + 2.0 * x * sx
    b = 2.0 * x * y * drad + 2.0 * p1 * x + 2.0 * p2 * y + 2.0 * y * sx
    c = 2.0 * x * y * drad + 2.0 * p1 * x + 2.0 * p2 * y + 2.0 * x * sy
    d = rad + 2.0 * y * y * drad + 6.0 * p1 * y + 2.0 * p2 * x + 2.0 * y * sy
    return xd, yd, a, b, c, d


@njit
def _bilinear(img: NDArray[np.uint16], u: float, v: float) -> float:
    """Bilinear grey level at (u, v), the border replicated."""
    h, w = img.shape
    u = min(max(u, 0.0), w - 1.0)
    v = min(max(v, 0.0), h - 1.0)
    u0 = min(int(u), w - 2)
    v0 = min(int(v), h - 2)
    fu = u - u0
    fv = v - v0
    top = img[v0, u0] * (1.0 - fu) + img[v0, u0 + 1] * fu
    bottom = img[v0 + 1, u0] * (1.0 - fu) + img[v0 + 1, u0 + 1] * fu
    return (top * (1.0 - fv) + bottom * fv) / GREY_SCALE


@njit
def _read(
    stack: NDArray[np.uint16],
    box: NDArray[np.int64],
    k: int,
    qx: float,
    qy: float,
    down: int,
    row0: int,
    width: int,
    height: int,
    need: NDArray[np.int64],
) -> tuple[float, float, float]:
    """Grey level and its derivatives per full-size pixel at full-size pixel (qx, qy).
    A read whose pixels lie outside image k's box (``box[k]``: rows r0:r1, columns c0:c1
    of the stack, where its blur is made) reads NaN and puts the rows and columns it
    needs in ``need`` (else need[0] is -1)."""
    need[0] = -1
    b = BORDER_PX
    if not (qx >= b and qy >= b and qx <= width - 1.0 - b and qy <= height - 1.0 - b):
        return np.nan, 0.0, 0.0
    img = stack[k]
    if down == 1:
        u, v = qx, qy - row0
    else:
        u, v = (qx - 0.5) / down, (qy - 0.5) / down - row0
    if not (v >= 1.0 and v <= img.shape[0] - 2.0):  # outside the stack's band of rows
        return np.nan, 0.0, 0.0
    h = GRAD_STEP_PX
    # The pixels the bilinear reads at (u +- h, v +- h) (:func:`_bilinear`).
    r_lo = int(v - h)
    r_hi = int(v + h) + 2
    c_lo = min(max(int(np.floor(u - h)), 0), img.shape[1] - 2)
    c_hi = min(int(np.floor(u + h)) + 2, img.shape[1])
    if r_lo < box[k, 0] or r_hi > box[k, 1] or c_lo < box[k, 2] or c_hi > box[k, 3]:
        need[0], need[1], need[2], need[3] = r_lo, r_hi, c_lo, c_hi
        return np.nan, 0.0, 0.0
    val = _bilinear(img, u, v)
    gx = (_bilinear(img, u + h, v) - _bilinear(img, u - h, v)) / (2.0 * h * down)
    gy = (_bilinear(img, u, v + h) - _bilinear(img, u, v - h)) / (2.0 * h * down)
    return val, gx, gy


@njit
def _chain(
    x: FloatArray, R: FloatArray, gpx: float, gpy: float, gpz: float, d_point: FloatArray, d_rot: FloatArray
) -> None:
    """d value / d point (laser frame) = g_cam R, and its cross with the point."""
    for a in range(3):
        d_point[a] = gpx * R[0, a] + gpy * R[1, a] + gpz * R[2, a]
    d_rot[0] = x[1] * d_point[2] - x[2] * d_point[1]
    d_rot[1] = x[2] * d_point[0] - x[0] * d_point[2]
    d_rot[2] = x[0] * d_point[1] - x[1] * d_point[0]


@njit
def _project_sample_kernel(
    pts: FloatArray,
    R: FloatArray,
    t: FloatArray,
    intr: FloatArray,
    code: int,
    q: FloatArray,
    dq: FloatArray,
    stack: NDArray[np.uint16],
    box: NDArray[np.int64],
    which: NDArray[np.int64],
    down: int,
    row0: int,
    width: int,
    height: int,
    value: FloatArray,
    d_point: FloatArray,
    d_rot: FloatArray,
    need: NDArray[np.int64],
) -> None:
    """Per point: project (``code`` >= 0: the OpenCV model with that many coefficients;
    -1: the projection ``q`` and its derivatives ``dq`` given), read (:func:`_read`: a
    read outside its image's box says what it needs), chain the gradient."""
    fx, fy, cx, cy = intr[0], intr[1], intr[2], intr[3]
    for n in range(pts.shape[0]):
        if code < 0:
            val, gx, gy = _read(stack, box, which[n], q[n, 0], q[n, 1], down, row0, width, height, need[n])
            g0 = gx * dq[n, 0, 0] + gy * dq[n, 1, 0]
            g1 = gx * dq[n, 0, 1] + gy * dq[n, 1, 1]
            g2 = gx * dq[n, 0, 2] + gy * dq[n, 1, 2]
        else:
            X = R[0, 0] * pts[n, 0] + R[0, 1] * pts[n, 1] + R[0, 2] * pts[n, 2] + t[0]
            Y = R[1, 0] * pts[n, 0] + R[1, 1] * pts[n, 1] + R[1, 2] * pts[n, 2] + t[1]
            Z = R[2, 0] * pts[n, 0] + R[2, 1] * pts[n, 1] + R[2, 2] * pts[n, 2] + t[2]
            val, gx, gy = np.nan, 0.0, 0.0
            g0 = g1 = g2 = 0.0
            need[n, 0] = -1
            if Z > 0.0:
                iz = 1.0 / Z
                x = X * iz
                y = Y * iz
                xd, yd, a11, a12, a21, a22 = _distort(x, y, intr, code)
                val, gx, gy = _read(
                    stack, box, which[n], fx * xd + cx, fy * yd + cy, down, row0, width, height, need[n]
                )
                # d value / d (x, y) through the distortion, then d (x, y) / d (X, Y, Z).
                gnx = gx * fx * a11 + gy * fy * a21
                gny = gx * fx * a12 + gy * fy * a22
                g0, g1, g2 = gnx * iz, gny * iz, -(gnx * x + gny * y) * iz
        value[n] = val
        if not np.isfinite(val):
            g0 = g1 = g2 = 0.0
        _chain(pts[n], R, g0, g1, g2, d_point[n], d_rot[n])


def compile_now() -> None:
    """Compile (or load from the cache) the kernel with the argument types the check uses,
    on one point (``rigcal warm-up``: a drive long enough to reach the check's estimate
    would take the warm-up minutes to simulate)."""
    from rigcal.camera import Camera

    cam = Camera.from_opencv(np.diag([100.0, 100.0, 1.0]) + np.eye(3, k=2) * 10.0, [], 20, 20)
    stack = np.zeros((1, 20, 20), dtype=np.uint16)
    project_sample(np.array([[0.0, 0.0, 1.0]]), np.eye(3), np.zeros(3), cam, stack, np.zeros(1, np.int64), 1)


def project_sample_reference(
    points: FloatArray,
    R: FloatArray,
    t: FloatArray,
    camera: Any,
    stack: NDArray[np.uint16],
    which: NDArray[np.int64],
    down: int,
    row0: int = 0,
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """:func:`project_sample` by mrcal's projection and numpy's bilinear interpolation."""
    q, dq = camera.project_with_gradient(points @ R.T + t)
    h = GRAD_STEP_PX

    def bilinear(u: FloatArray, v: FloatArray) -> FloatArray:
        H, W = stack.shape[1:]
        u = np.clip(u, 0.0, W - 1.0)
        v = np.clip(v, 0.0, H - 1.0)
        u0 = np.minimum(u.astype(np.int64), W - 2)
        v0 = np.minimum(v.astype(np.int64), H - 2)
        fu, fv = u - u0, v - v0
        img = stack.astype(np.float64)
        top = img[which, v0, u0] * (1 - fu) + img[which, v0, u0 + 1] * fu
        bottom = img[which, v0 + 1, u0] * (1 - fu) + img[which, v0 + 1, u0 + 1] * fu
        out: FloatArray = (top * (1 - fv) + bottom * fv) / GREY_SCALE
        return out

    qq = np.nan_to_num(q, nan=-10.0)
    u, v = (qq[:, 0], qq[:, 1]) if down == 1 else ((qq[:, 0] - 0.5) / down, (qq[:, 1] - 0.5) / down)
    v = v - row0
    val = bilinear(u, v)
    gx = (bilinear(u + h, v) - bilinear(u - h, v)) / (2 * h * down)
    gy = (bilinear(u, v + h) - bilinear(u, v - h)) / (2 * h * down)
    w, hh = camera.width_px, camera.height_px
    inside = (qq[:, 0] >= BORDER_PX) & (qq[:, 1] >= BORDER_PX)
    inside &= (qq[:, 0] <= w - 1.0 - BORDER_PX) & (qq[:, 1] <= hh - 1.0 - BORDER_PX)
    inside &= (v >= 1.0) & (v <= stack.shape[1] - 2.0)
    val = np.where(inside, val, np.nan)
    g_cam = gx[:, None] * dq[:, 0, :] + gy[:, None] * dq[:, 1, :]
    d_point = np.where(inside[:, None], g_cam @ R, 0.0)
    d_rot = np.cross(points, d_point)
    return val, d_point, d_rot
