"""Ray-cast camera images of a simulated world (surfaces, floor, ceiling), with depth and labels.

World frame: z up, z = 0 the floor; the ceiling is a plane at
:attr:`WorldTextures.ceiling_height_m` (by default the tallest surface's top). Surfaces are
vertical rectangles from the floor to their height over their 2D segment a-b.

Every pixel's ray is the camera model's own bearing (:func:`rigcal.sim.render.pixel_bearings`,
lens distortion included), so a rendered point appears exactly where
:meth:`rigcal.camera.Camera.project` puts it. The nearest hit wins (a ray passing above a
1.5 m partition goes on to the wall behind it).

Speed: all surfaces are vertical, so whether a ray can meet a surface depends on its
azimuth only. The rays are kept sorted by azimuth in a *level frame* (the camera's centre,
z up, x along the camera's heading); for a rig moving on the floor that frame's rays never
change, so the sort is cached and each surface is tested only against the contiguous slice
of rays inside its azimuth interval. Surfaces out of range cost nothing.
"""

from __future__ import annotations

import math
from collections import OrderedDict
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from rigcal.arrays import FloatArray
from rigcal.camera import Camera
from rigcal.sim.render import pixel_bearings
from rigcal.sim.textures import WorldTextures, sample, world_textures
from rigcal.sim.world import World

F32 = NDArray[np.float32]
Image = NDArray[np.uint8]

SURFACE_FLOOR = -1
SURFACE_CEILING = -2
SURFACE_NONE = -3  # a ray that meets nothing (exactly horizontal in an open world)
RANGE_MAX_M = 100.0
_N_BINS = 2048  # azimuth bins of the ray sort
_LIGHT = np.array([0.6, 0.8], dtype=np.float32)  # horizontal direction walls are lit from


@dataclass(frozen=True)
class RenderedFrame:
    """One rendered camera frame.

    Attributes:
        image: (H, W, 3) uint8 BGR.
        depth_m: (H, W) float32 z-depth in the camera frame (along its optical axis), metres;
            inf where nothing was hit.
        surface: (H, W) int16 index into ``world.surfaces``; SURFACE_FLOOR (-1),
            SURFACE_CEILING (-2) or SURFACE_NONE (-3).
    """

    image: Image
    depth_m: F32
    surface: NDArray[np.int16]


@dataclass(frozen=True)
class CameraEffects:
    """Sensor effects applied to a rendered image.

    Attributes:
        noise_sigma: additive Gaussian noise, grey levels (1 sigma).
        blur_sigma_px: Gaussian blur (defocus, motion), pixels; 0 for none.
        exposure_walk: standard deviation of the log-gain's random walk per frame; 0 keeps
            the gain at 1.
    """

    noise_sigma: float = 2.0
    blur_sigma_px: float = 0.0
    exposure_walk: float = 0.0


class _RayFan:
    """A camera's rays in a level frame, sorted by azimuth."""

    def __init__(self, camera: Camera, R_level_cam: FloatArray) -> None:
        bear = pixel_bearings(camera)
        D = bear @ R_level_cam.T.astype(np.float32)
        az = np.arctan2(D[:, 1], D[:, 0])
        b = np.clip(
            ((az + np.float32(math.pi)) * np.float32(_N_BINS / (2 * math.pi))).astype(np.int16),
            0,
            _N_BINS - 1,
        )
        order = np.argsort(b, kind="stable")
        self.order = order
        self.inverse = np.empty_like(order)
        self.inverse[order] = np.arange(len(order))
        self.dx = np.ascontiguousarray(D[order, 0])
        self.dy = np.ascontiguousarray(D[order, 1])
        self.dz = np.ascontiguousarray(D[order, 2])
        self.bz = np.ascontiguousarray(bear[order, 2])
        with np.errstate(divide="ignore"):
            self.inv_dz = np.float32(1.0) / self.dz
        self.starts = np.searchsorted(b[order], np.arange(_N_BINS + 1)).astype(np.int64)


_FANS: OrderedDict[tuple[int, bytes], _RayFan] = OrderedDict()
_FANS_MAX = 4


def _fan(camera: Camera, R_level_cam: FloatArray) -> _RayFan:
    key = (hash(camera), R_level_cam.tobytes())
    hit = _FANS.get(key)
    if hit is None:
        hit = _FANS[key] = _RayFan(camera, R_level_cam)
        if len(_FANS) > _FANS_MAX:
            _FANS.popitem(last=False)
    _FANS.move_to_end(key)
    return hit


def render_world(
    world: World,
    camera: Camera,
    T_world_cam: ArrayLike,
    textures: WorldTextures | None = None,
    range_max_m: float = RANGE_MAX_M,
) -> RenderedFrame:
    """Render what the camera sees of the world, without sensor effects.

    Args:
        world: the world.
        camera: the camera (lens model and image size).
        T_world_cam: (4, 4) the camera's pose in the world frame.
        textures: the world's textures (:func:`rigcal.sim.textures.world_textures`);
            generated with seed 0 when None (slow: pass them when rendering many frames).
        range_max_m: surfaces farther than this are not drawn.

    Returns:
        The image, z-depth and surface index of every pixel.
    """
    tex = world_textures(world) if textures is None else textures
    T = np.asarray(T_world_cam, dtype=float)
    R, o = T[:3, :3], T[:3, 3]
    # Level frame: rotate the world about z by the camera's heading, so that a rig moving
    # on the floor keeps one cached ray fan.
    fwd = R[:2, 2] if np.hypot(R[0, 2], R[1, 2]) > 1e-6 else R[:2, 0]
    psi = math.atan2(float(fwd[1]), float(fwd[0]))
    c, s = math.cos(psi), math.sin(psi)
    R_level_world = np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])
    fan = _fan(camera, np.round(R_level_world @ R, 9))
    oz = np.float32(o[2])
    hc = np.float32(tex.ceiling_height_m)

    # Floor and ceiling: every ray that is not horizontal meets one of them.
    t_best: F32 = (np.where(fan.dz < 0, -oz, hc - oz) * fan.inv_dz).astype(np.float32)
    t_best[~np.isfinite(t_best) | (t_best <= 0)] = np.inf
    label = np.where(fan.dz < 0, SURFACE_FLOOR, SURFACE_CEILING).astype(np.int16)
    label[~np.isfinite(t_best)] = SURFACE_NONE
    along: F32 = np.zeros_like(t_best)
    cos_in: F32 = np.abs(fan.dz)  # cosine of the incidence angle at the hit

    n_surf = len(world.surfaces)
    A = np.array([sf.a for sf in world.surfaces]).reshape(-1, 2) - o[:2]
    B = np.array([sf.b for sf in world.surfaces]).reshape(-1, 2) - o[:2]
    R2 = R_level_world[:2, :2]
    A, B = A @ R2.T, B @ R2.T
    for j in range(n_surf):
        sl = _azimuth_slices(A[j], B[j], range_max_m)
        if not sl:
            continue
        surf = world.surfaces[j]
        ab = B[j] - A[j]
        L = float(np.hypot(*ab))
        u = ab / L
        nx, ny = np.float32(-u[1]), np.float32(u[0])
        dist = np.float32(nx * A[j, 0] + ny * A[j, 1])  # signed distance of the plane from the camera
        a_u = np.float32(A[j] @ u)
        ux, uy = np.float32(u[0]), np.float32(u[1])
        for lo, hi in sl:
            i0, i1 = int(fan.starts[lo]), int(fan.starts[hi])
            if i1 <= i0:
                continue
            dx, dy, dz = fan.dx[i0:i1], fan.dy[i0:i1], fan.dz[i0:i1]
            den = dx * nx + dy * ny
            with np.errstate(divide="ignore", invalid="ignore"):
                t = dist / den
            sa = t * (dx * ux + dy * uy) - a_u
            z = oz + t * dz
            hit = (t > 0) & (t < t_best[i0:i1]) & (sa >= 0) & (sa <= L) & (z >= 0) & (z <= surf.height_m)
            k = np.flatnonzero(hit)
            if len(k):
                t_best[i0 + k] = t[k]
                label[i0 + k] = j
                # Texture coordinate: from the end on the viewer's left, so that text
                # reads the right way from both sides of a wall.
                dk = den[k]
                along[i0 + k] = np.where(dk > 0, sa[k], np.float32(L) - sa[k])
                cos_in[i0 + k] = np.abs(dk)

    colour = _shade(world, camera, tex, fan, o, R_level_world, t_best, label, along, cos_in)
    H, W = camera.height_px, camera.width_px
    np.clip(colour, 0.0, 254.5, out=colour)
    colour += np.float32(0.5)
    image = colour.astype(np.uint8)[fan.inverse].reshape(H, W, 3)
    depth = (t_best * fan.bz)[fan.inverse].reshape(H, W)
    return RenderedFrame(image, depth.astype(np.float32), label[fan.inverse].reshape(H, W))


def _azimuth_slices(A: FloatArray, B: FloatArray, range_max_m: float) -> list[tuple[int, int]]:
    """Bin ranges [lo, hi) of the level frame's azimuth bins that may see segment A-B
    (relative to the camera); empty when it is out of range or seen edge-on."""
    ab = B - A
    cross = A[0] * B[1] - A[1] * B[0]
    L2 = float(ab @ ab)
    if abs(cross) < 1e-9 * max(L2, 1e-12):
        return []
    s = float(np.clip(-(A @ ab) / L2, 0.0, 1.0))
    if np.hypot(*(A + s * ab)) > range_max_m:
        return []
    pa = math.atan2(A[1], A[0])
    pb = math.atan2(B[1], B[0])
    d = (pb - pa + math.pi) % (2 * math.pi) - math.pi
    lo = pa if d >= 0 else pb
    w = 2 * math.pi / _N_BINS
    b0 = math.floor((lo + math.pi) / w) - 1
    b1 = math.floor((lo + abs(d) + math.pi) / w) + 2  # exclusive
    if b0 < 0:
        return [(b0 + _N_BINS, _N_BINS), (0, b1)]
    if b1 > _N_BINS:
        return [(b0, _N_BINS), (0, b1 - _N_BINS)]
    return [(b0, b1)]


def _shade(
    world: World,
    camera: Camera,
    tex: WorldTextures,
    fan: _RayFan,
    o: FloatArray,
    R_level_world: FloatArray,
    t: F32,
    label: NDArray[np.int16],
    along: F32,
    cos_in: F32,
) -> F32:
    """Colour of every ray (fan order): textures at the hit points, lit by ceiling lights."""
    out = np.zeros((len(t), 3), dtype=np.float32)
    f = np.float32(0.5 * (camera.intrinsics[0] + camera.intrinsics[1]))
    # Footprint of a pixel on the surface, metres: the geometric mean of its two axes.
    foot_all: F32 = (t / f / np.sqrt(np.maximum(cos_in, np.float32(0.05)))).astype(np.float32, copy=False)
    walls = np.flatnonzero(label >= 0)
    if len(walls):
        j = label[walls]
        surfs = world.surfaces
        ab = np.array([sf.b - sf.a for sf in surfs])
        u = ab / np.linalg.norm(ab, axis=1)[:, None]
        tw = t[walls]
        foot = foot_all[walls]
        ppm = np.float32(tex.walls.texels_per_m)
        top = np.array([sf.height_m for sf in surfs], dtype=np.float32)
        z = np.float32(o[2]) + tw * fan.dz[walls]
        uu = tex.origin_px[j, 0] + along[walls] * ppm - np.float32(0.5)
        vv = tex.origin_px[j, 1] + (top[j] - z) * ppm - np.float32(0.5)
        # Walls facing the light are a little brighter: corners and pillars stand out.
        n_world = np.column_stack([-u[:, 1], u[:, 0]]).astype(np.float32)
        lit = np.float32(0.82) + np.float32(0.18) * np.abs(n_world @ _LIGHT)
        out[walls] = sample(tex.walls, uu, vv, foot) * lit[j][:, None]
    R2t = R_level_world[:2, :2].T.astype(np.float32)  # level -> world (horizontal)
    for lab, img, org in (
        (SURFACE_FLOOR, tex.floor, tex.floor_origin_m),
        (SURFACE_CEILING, tex.ceiling, tex.ceiling_origin_m),
    ):
        k = np.flatnonzero(label == lab)
        if not len(k):
            continue
        tk = t[k]
        hx = tk * fan.dx[k]
        hy = tk * fan.dy[k]
        x = np.float32(o[0]) + hx * R2t[0, 0] + hy * R2t[0, 1]
        y = np.float32(o[1]) + hx * R2t[1, 0] + hy * R2t[1, 1]
        foot = foot_all[k]
        ppm = np.float32(img.texels_per_m)
        uu = (x - np.float32(org[0])) * ppm - np.float32(0.5)
        vv = (y - np.float32(org[1])) * ppm - np.float32(0.5)
        out[k] = sample(img, uu, vv, foot, clamp=True)
    # Gentle fall-off with distance, as from lights near the rig (as rigcal.sim.render).
    fall = np.clip(np.float32(1.08) - np.float32(0.02) * np.minimum(t, np.float32(1e3)), 0.7, 1.05)
    out *= fall[:, None]
    return out


def apply_effects(
    image: F32 | Image, effects: CameraEffects, rng: np.random.Generator, gain: float = 1.0
) -> Image:
    """A rendered image as the camera records it: exposure gain, blur, additive noise.

    Args:
        image: (H, W, 3) BGR, float32 or uint8.
        effects: the effects.
        rng: draws the noise.
        gain: exposure gain (1 for none).

    Returns:
        (H, W, 3) uint8 BGR.
    """
    img: F32 = np.asarray(image, dtype=np.float32)
    if gain != 1.0:
        img = np.multiply(img, np.float32(gain), dtype=np.float32)
    if effects.blur_sigma_px > 0:
        img = np.asarray(cv2.GaussianBlur(img, (0, 0), effects.blur_sigma_px), dtype=np.float32)
    if effects.noise_sigma > 0:
        img = img + np.float32(effects.noise_sigma) * _normal(rng, img.shape)
    out: Image = np.clip(img + np.float32(0.5), 0, 255).astype(np.uint8)
    return out


_NORMAL_TABLE: F32 | None = None


def _normal(rng: np.random.Generator, shape: tuple[int, ...]) -> F32:
    """Standard normal samples via a 65536-entry inverse-CDF table of 16-bit uniforms
    (a few times faster than Generator.standard_normal; tails cut at 4.3 sigma)."""
    global _NORMAL_TABLE
    if _NORMAL_TABLE is None:
        from scipy.special import ndtri

        _NORMAL_TABLE = ndtri((np.arange(65536) + 0.5) / 65536).astype(np.float32)
    idx = rng.integers(0, 65536, size=shape, dtype=np.uint16)
    out: F32 = _NORMAL_TABLE[idx]
    return out
