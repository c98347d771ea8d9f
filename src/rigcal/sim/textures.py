"""Procedural textures of a simulated world's surfaces, floor and ceiling (docs/formats/world.md).

Every surface of a :class:`rigcal.sim.world.World` gets a texture image in metres
(:data:`TEXELS_PER_M` texels per metre, row 0 at the surface's top), generated from its
texture name (:data:`rigcal.sim.world.TEXTURES`) with a random generator seeded by the
seed and the surface's index, so one seed always gives the same world. The textures are
packed into one atlas with a mip pyramid (each level half the previous one, 2x2 averages);
the floor (tiles with speckle) and the ceiling (panels, grid bars and lights) are images
over the world's bounding box. :func:`sample` reads them with bilinear interpolation at the
mip level a pixel's footprint asks for, so that distant walls do not alias.

The names reproduce the paper's conditions (Section VI): ``plain`` is deliberately
texture-poor (faint low-frequency shading and a skirting board: the long texture-poor
corridor stretches), ``repeating`` is exactly periodic along the wall with period
:data:`REPEAT_PERIOD_M` (the repeating patterns that defeat IASM, Fig. 5); ``posters``,
``bricks``, ``doors``, ``noise`` and ``signs`` carry texture at many scales for SIFT and
for patch matching.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from rigcal.sim.render import hash01, hue_bgr
from rigcal.sim.world import World

F32 = NDArray[np.float32]
Image = NDArray[np.uint8]

TEXELS_PER_M = 200.0  # walls and floor; the ceiling has half as many
MIP_LEVELS = 6
PAD_TEXELS = 32  # around each surface in the atlas: one texel at the coarsest level
ATLAS_MAX_PX = 16384  # cv2.remap needs images under 32767 texels a side
REPEAT_PERIOD_M = 0.5
SKIRTING_M = 0.1
DADO_TOP_M = 0.85  # top of the lower-wall panel of posters and signs walls
_FONT = cv2.FONT_HERSHEY_SIMPLEX
_LETTERS = np.array(list("ABCDEFGHJKLMNPRSTUVWXYZ0123456789"))


@dataclass(frozen=True)
class MipImage:
    """An image and its mip pyramid, stacked in one image (so one cv2.remap reads them all).

    Attributes:
        packed: uint8 BGR; level k (of size (H / 2^k, W / 2^k)) at ``offsets[k]``.
        offsets: (MIP_LEVELS, 2) float32 column and row of each level's top-left texel.
        sizes: (MIP_LEVELS, 2) float32 width and height of each level.
        texels_per_m: texels per metre at level 0.
    """

    packed: Image
    offsets: F32
    sizes: F32
    texels_per_m: float

    @property
    def levels(self) -> tuple[Image, ...]:
        """Each level as a view into ``packed``."""
        out = []
        for (x, y), (w, h) in zip(self.offsets.astype(int), self.sizes.astype(int), strict=True):
            out.append(self.packed[y : y + h, x : x + w])
        return tuple(out)


@dataclass(frozen=True)
class WorldTextures:
    """The textures of a world, ready for :func:`sample`.

    Attributes:
        walls: the atlas of every surface's texture.
        origin_px: (S, 2) float32 atlas column and row of each surface's top-left corner
            (its ``a`` end at its top), level-0 texels.
        floor, ceiling: images over the world's bounding box; texel column and row are
            world x and y from ``floor_origin_m`` / ``ceiling_origin_m``.
        ceiling_height_m: the ceiling's height above the floor.
    """

    walls: MipImage
    origin_px: F32
    floor: MipImage
    floor_origin_m: tuple[float, float]
    ceiling: MipImage
    ceiling_origin_m: tuple[float, float]
    ceiling_height_m: float


def ceiling_height(world: World) -> float:
    """The ceiling's height: the tallest surface's top (2.5 m for a world without walls)."""
    return max((s.height_m for s in world.surfaces), default=2.5)


def world_textures(world: World, seed: int = 0, ceiling_height_m: float | None = None) -> WorldTextures:
    """Generate every texture of a world (about a second for the 60 m corridor loop).

    Args:
        world: the world.
        seed: textures are seeded by (seed, surface index); the floor and ceiling by seed.
        ceiling_height_m: defaults to :func:`ceiling_height`.
    """
    hc = ceiling_height(world) if ceiling_height_m is None else float(ceiling_height_m)
    longest = max((float(np.linalg.norm(s.b - s.a)) for s in world.surfaces), default=1.0)
    ppm = min(TEXELS_PER_M, (ATLAS_MAX_PX - 2 * PAD_TEXELS - 32) / longest)
    images = []
    for i, s in enumerate(world.surfaces):
        rng = np.random.default_rng([seed, i])
        w = max(math.ceil(float(np.linalg.norm(s.b - s.a)) * ppm), 1)
        h = max(math.ceil(s.height_m * ppm), 1)
        images.append(_GENERATORS[s.texture](rng, h, w, ppm))
    atlas, origin = _pack(images)

    pts = [p for s in world.surfaces for p in (s.a, s.b)] + list(world.path)
    lo = np.min(pts, axis=0) - 2.0
    hi = np.max(pts, axis=0) + 2.0
    extent = float(np.max(hi - lo))
    fppm = min(TEXELS_PER_M, (ATLAS_MAX_PX - 64) / extent)
    cppm = 0.5 * fppm
    fw, fh = (_ceil32(float(v) * fppm) for v in hi - lo)
    cw, ch = (_ceil32(float(v) * cppm) for v in hi - lo)
    origin_m = (float(lo[0]), float(lo[1]))
    return WorldTextures(
        walls=mips(atlas, ppm),
        origin_px=origin,
        floor=mips(_floor(np.random.default_rng([seed, 1_000_001]), fh, fw, fppm), fppm),
        floor_origin_m=origin_m,
        ceiling=mips(_ceiling(np.random.default_rng([seed, 1_000_002]), ch, cw, cppm), cppm),
        ceiling_origin_m=origin_m,
        ceiling_height_m=hc,
    )


def sample(tex: MipImage, u: F32, v: F32, footprint_m: F32, clamp: bool = False) -> F32:
    """Bilinear samples of a mip-mapped texture.

    Args:
        tex: the texture.
        u, v: (N,) float32 level-0 texel coordinates (column, row; texel centres at integers).
        footprint_m: (N,) the pixel's size on the surface, metres; the level whose texel is
            closest to it (in log scale) is read.
        clamp: keep the samples inside each level (edges repeated); the wall atlas needs
            no clamping (its entries are padded), the floor and ceiling do.

    Returns:
        (N, 3) float32 BGR.
    """
    with np.errstate(divide="ignore", invalid="ignore"):
        lvl = np.log2(np.maximum(footprint_m * np.float32(tex.texels_per_m), np.float32(1e-6)))
    k = np.clip(np.rint(lvl), 0, MIP_LEVELS - 1).astype(np.intp)
    scale = _SCALES[k]
    half = np.float32(0.5)
    uk = (u + half) * scale - half
    vk = (v + half) * scale - half
    if clamp:
        wk, hk = tex.sizes[k, 0], tex.sizes[k, 1]
        uk = np.clip(uk, 0, wk - 1)
        vk = np.clip(vk, 0, hk - 1)
    uk += tex.offsets[k, 0]
    vk += tex.offsets[k, 1]
    return _remap(tex.packed, uk, vk, cv2.BORDER_REPLICATE)


_SCALES = (0.5 ** np.arange(MIP_LEVELS)).astype(np.float32)


def _remap(img: Image, u: F32, v: F32, border: int) -> F32:
    """cv2.remap of scattered points: maps folded into rows of 1024 (remap's size limit)."""
    n = len(u)
    cols = 1024
    rows = -(-n // cols)
    mu = np.zeros(rows * cols, dtype=np.float32)
    mv = np.zeros(rows * cols, dtype=np.float32)
    mu[:n] = u
    mv[:n] = v
    r = cv2.remap(img, mu.reshape(rows, cols), mv.reshape(rows, cols), cv2.INTER_LINEAR, borderMode=border)
    out: F32 = r.reshape(-1, 3)[:n].astype(np.float32)
    return out


# --- atlas and mip levels ---------------------------------------------------------------------
def _ceil32(x: float) -> int:
    return max(32, math.ceil(x / 32.0) * 32)


def _pack(images: list[Image]) -> tuple[Image, F32]:
    """Shelf-pack surface textures (edges replicated into a padding) into one atlas whose
    sides and every entry's position are multiples of 2^(MIP_LEVELS - 1)."""
    origin = np.zeros((len(images), 2), dtype=np.float32)
    places = []
    x = y = shelf = 0
    for i, im in enumerate(images):
        w, h = _ceil32(im.shape[1] + 2 * PAD_TEXELS), _ceil32(im.shape[0] + 2 * PAD_TEXELS)
        if x + w > ATLAS_MAX_PX:
            x, y, shelf = 0, y + shelf, 0
        places.append((x, y))
        origin[i] = (x + PAD_TEXELS, y + PAD_TEXELS)
        x += w
        shelf = max(shelf, h)
    width = _ceil32(
        max(
            (p[0] + _ceil32(im.shape[1] + 2 * PAD_TEXELS) for p, im in zip(places, images, strict=True)),
            default=32,
        )
    )
    height = _ceil32(y + shelf)
    atlas = np.zeros((height, width, 3), dtype=np.uint8)
    for (x, y), im in zip(places, images, strict=True):
        p = PAD_TEXELS
        padded = cv2.copyMakeBorder(im, p, p, p, p, cv2.BORDER_REPLICATE)
        atlas[y : y + padded.shape[0], x : x + padded.shape[1]] = padded
    return atlas, origin


def mips(img: Image, texels_per_m: float) -> MipImage:
    """The mip pyramid (2x2 averages), level 0 on top and the others side by side below it."""
    levels = [np.ascontiguousarray(img)]
    for _ in range(1, MIP_LEVELS):
        prev = levels[-1]
        h, w = prev.shape[:2]
        if h % 2:
            prev = np.vstack([prev, prev[-1:]])
        if w % 2:
            prev = np.hstack([prev, prev[:, -1:]])
        half = cv2.resize(prev, (prev.shape[1] // 2, prev.shape[0] // 2), interpolation=cv2.INTER_AREA)
        levels.append(np.asarray(half, dtype=np.uint8))
    gap = 4
    H0, W0 = levels[0].shape[:2]
    H = H0 + gap + levels[1].shape[0]
    W = max(W0, sum(lv.shape[1] + gap for lv in levels[1:]))
    packed = np.zeros((H, W, 3), dtype=np.uint8)
    offsets = np.zeros((MIP_LEVELS, 2), dtype=np.float32)
    sizes = np.zeros((MIP_LEVELS, 2), dtype=np.float32)
    x, y = 0, 0
    for k, lv in enumerate(levels):
        if k == 1:
            x, y = 0, H0 + gap
        h, w = lv.shape[:2]
        packed[y : y + h, x : x + w] = lv
        offsets[k] = (x, y)
        sizes[k] = (w, h)
        if k:
            x += w + gap
    return MipImage(packed, offsets, sizes, float(texels_per_m))


# --- building blocks --------------------------------------------------------------------------
def _fbm(rng: np.random.Generator, h: int, w: int, cells_px: tuple[float, ...]) -> F32:
    """Multi-scale value noise, about unit standard deviation: Gaussian grids of the given
    cell sizes (texels) upsampled bicubically and summed with weights growing with the cell."""
    out = np.zeros((h, w), dtype=np.float32)
    total = 0.0
    for c in cells_px:
        gh, gw = int(h / c) + 3, int(w / c) + 3
        grid = rng.standard_normal((gh, gw)).astype(np.float32)
        up = cv2.resize(grid, (int(gw * c), int(gh * c)), interpolation=cv2.INTER_CUBIC)
        wgt = math.sqrt(c)
        out += wgt * up[:h, :w]
        total += wgt * wgt
    out *= np.float32(1.0 / math.sqrt(total))
    return out


def _colour(rng: np.random.Generator, lo: float, hi: float) -> NDArray[np.float32]:
    """A random light paint colour, BGR 0..255."""
    base = rng.uniform(lo, hi)
    out: NDArray[np.float32] = (base + rng.uniform(-18, 18, 3)).clip(0, 255).astype(np.float32)
    return out


def _saturated(rng: np.random.Generator) -> tuple[int, int, int]:
    c = hue_bgr(np.array([rng.uniform(0.0, 6.0)], dtype=np.float32))[0] * rng.uniform(150, 235) + rng.uniform(
        0, 40
    )
    return (int(c[0]), int(c[1]), int(c[2]))


def _paint(rng: np.random.Generator, h: int, w: int, ppm: float, amp: float, fine: float) -> F32:
    """A painted wall: a paint colour with shading of relative amplitude ``amp`` (cells of
    0.5-2 m) and fine grain of ``fine`` grey levels; (h, w, 3) float32."""
    col = _colour(rng, 175, 225)
    shade = 1.0 + amp * _fbm(rng, h, w, (0.5 * ppm, 1.0 * ppm, 2.0 * ppm))
    img = shade[:, :, None] * col
    if fine > 0:
        img += fine * _fbm(rng, h, w, (2.0, 6.0))[:, :, None]
    return img


def _skirting(img: F32, ppm: float, rng: np.random.Generator) -> None:
    """A dark skirting board at the foot of the wall, with a lit top edge."""
    h = img.shape[0]
    k = max(round(SKIRTING_M * ppm), 1)
    tone = rng.uniform(45, 85)
    img[h - k :] = np.array([tone, tone * 1.1, tone * 1.25], dtype=np.float32)
    img[h - k : h - k + max(k // 12, 1)] = 30.0


def _dado(img: F32, ppm: float, rng: np.random.Generator) -> None:
    """A protective lower-wall panel from the skirting up to ``DADO_TOP_M``: wood-like
    grain and knots at several scales, panel seams every 0.6-1.4 m and a chair rail on top.
    It puts texture where the laser's scan plane meets the wall (the paper's scan points
    project onto textured surfaces, Fig. 5)."""
    h, w = img.shape[:2]
    top = h - round(DADO_TOP_M * ppm)
    bottom = h - round(SKIRTING_M * ppm)
    if top >= bottom:
        return
    bh = bottom - top
    col = _colour(rng, 90, 150) * np.array([0.75, 0.95, 1.2], dtype=np.float32)
    grain = _fbm(rng, bh, w, (1.5, 4.0, 10.0, 0.08 * ppm, 0.25 * ppm))
    # Streaks along the wall: noise stretched six times horizontally.
    raw = _fbm(rng, bh, w, (2.0, 0.1 * ppm))[:, : max(w // 6, 1)]
    streaks = np.asarray(cv2.resize(raw, (w, bh), interpolation=cv2.INTER_LINEAR), dtype=np.float32)
    panel = col * (1.0 + 0.28 * grain + 0.18 * streaks)[:, :, None]
    x = 0.0
    while x < w:
        x += rng.uniform(0.6, 1.4) * ppm
        xi = int(x)
        panel[:, max(xi - 2, 0) : xi + 2] *= 0.45
    img[top:bottom] = panel
    rail = max(round(0.03 * ppm), 2)
    img[max(top - rail, 0) : top] = np.array([205, 210, 215], dtype=np.float32)
    img[top : top + 1] = 40.0


def _text(
    img: Image, rng: np.random.Generator, x: int, y: int, height_px: int, colour: tuple[int, int, int], n: int
) -> None:
    """``n`` random capital letters and digits whose cap height is about ``height_px``."""
    word = "".join(rng.choice(_LETTERS, n))
    scale = height_px / 22.0
    cv2.putText(img, word, (x, y), _FONT, scale, colour, max(round(scale * 2), 1), cv2.LINE_AA)


def _to_u8(img: F32) -> Image:
    """Round and saturate to uint8 (img is overwritten)."""
    np.clip(img, 0.0, 254.5, out=img)
    img += np.float32(0.5)
    out: Image = img.astype(np.uint8)
    return out


# --- the textures -----------------------------------------------------------------------------
def _plain(rng: np.random.Generator, h: int, w: int, ppm: float) -> Image:
    """Texture-poor: faint low-frequency shading, a skirting board; nothing else."""
    img = _paint(rng, h, w, ppm, 0.025, 0.0)
    _skirting(img, ppm, rng)
    return _to_u8(img)


def _noise(rng: np.random.Generator, h: int, w: int, ppm: float) -> Image:
    """Cubicle fabric: coloured multi-scale noise from 1 cm to 1 m, an aluminium top rail."""
    col = _colour(rng, 110, 170)
    n = _fbm(rng, h, w, (2.0, 5.0, 12.0, 0.1 * ppm, 0.3 * ppm, 1.0 * ppm))
    tint = _fbm(rng, h, w, (0.2 * ppm, 0.6 * ppm))
    img = col * (1.0 + 0.22 * n)[:, :, None]
    img[:, :, 0] += 12 * tint
    img[:, :, 2] -= 12 * tint
    rail = max(int(0.04 * ppm), 1)
    img[:rail] = 200.0
    img[rail : rail + max(rail // 4, 1)] = 90.0
    return _to_u8(img)


def _bricks(rng: np.random.Generator, h: int, w: int, ppm: float) -> Image:
    """Running-bond bricks 215 x 65 mm, 10 mm mortar, each brick its own shade, grain."""
    bw, bh, m = 0.225 * ppm, 0.075 * ppm, 0.010 * ppm
    rows, cols = np.mgrid[0:h, 0:w].astype(np.float32)
    course = np.floor(rows / bh)
    shift = (course % 2) * 0.5 * bw
    idx = np.floor((cols + shift) / bw)
    fx = (cols + shift) - idx * bw
    fy = rows - course * bh
    seed = float(rng.integers(1, 1000))
    tone = hash01(idx + seed, course)
    tone2 = hash01(course + 0.5 * seed, idx)
    base = np.array([60, 75, 150], dtype=np.float32)
    img = base * (0.7 + 0.5 * tone)[:, :, None]
    img[:, :, 1] += 25 * (tone2 - 0.5)
    img *= (1.0 + 0.12 * _fbm(rng, h, w, (1.5, 4.0, 10.0)))[:, :, None]
    mortar = (fx < m) | (fy < m)
    img[mortar] = np.array([170, 175, 180], dtype=np.float32) * (0.9 + 0.1 * tone[mortar])[:, None]
    return _to_u8(img)


def _posters(rng: np.random.Generator, h: int, w: int, ppm: float) -> Image:
    """Painted wall with posters every 0.6-2 m: frames, shapes, colour fields and text."""
    img = _to_u8(_paint(rng, h, w, ppm, 0.03, 1.5))
    x = rng.uniform(0.2, 1.2) * ppm
    while x < w - 0.4 * ppm:
        pw = rng.uniform(0.45, 1.0) * ppm
        ph = min(rng.uniform(0.6, 1.1) * ppm, h - 0.95 * ppm - 0.05 * ppm)
        if ph < 0.25 * ppm:
            break
        pw = min(pw, w - x)
        x0, x1 = int(x), int(x + pw)
        y1 = int(h - rng.uniform(0.9, 1.2) * ppm)
        y0 = max(int(y1 - ph), 0)
        _poster(img, rng, x0, y0, x1, y1, ppm)
        x += pw + rng.uniform(0.6, 2.0) * ppm
    out = img.astype(np.float32)
    _dado(out, ppm, rng)
    _skirting(out, ppm, rng)
    return _to_u8(out)


def _poster(img: Image, rng: np.random.Generator, x0: int, y0: int, x1: int, y1: int, ppm: float) -> None:
    w, h = x1 - x0, y1 - y0
    bg = (240, 240, 238) if rng.random() < 0.5 else _saturated(rng)
    cv2.rectangle(img, (x0, y0), (x1, y1), bg, -1)
    sub = img[y0:y1, x0:x1]
    for _ in range(int(rng.integers(3, 9))):
        kind = rng.integers(0, 4)
        cx, cy = int(rng.uniform(0.1, 0.9) * w), int(rng.uniform(0.1, 0.7) * h)
        r = int(rng.uniform(0.05, 0.25) * min(w, h)) + 2
        col = _saturated(rng)
        if kind == 0:
            cv2.circle(sub, (cx, cy), r, col, -1, cv2.LINE_AA)
        elif kind == 1:
            cv2.rectangle(sub, (cx - r, cy - r // 2), (cx + r, cy + r), col, -1)
        elif kind == 2:
            tri = np.array([[cx, cy - r], [cx - r, cy + r], [cx + r, cy + r]], dtype=np.int32)
            cv2.fillPoly(sub, [tri], col, cv2.LINE_AA)
        else:
            cv2.line(sub, (cx - r, cy), (cx + r, cy + r // 2), col, max(r // 6, 2), cv2.LINE_AA)
    ink = (25, 25, 30) if sum(bg) > 450 else (245, 245, 245)
    th = max(int(0.045 * ppm), 6)
    y = int(0.78 * h)
    for _ in range(int(rng.integers(2, 4))):
        if y + th > h - 4:
            break
        _text(sub, rng, int(0.08 * w), y, th, ink, int(rng.integers(4, 10)))
        y += int(1.7 * th)
    f = max(int(0.02 * ppm), 2)
    cv2.rectangle(img, (x0, y0), (x1, y1), (245, 245, 245), f)
    cv2.rectangle(img, (x0 - 1, y0 - 1), (x1 + 1, y1 + 1), (40, 40, 40), 1)


def _doors(rng: np.random.Generator, h: int, w: int, ppm: float) -> Image:
    """Painted wall with doors every 2.5-5 m: frame, wooden leaf with grain, kick plate,
    handle, a window in some, and a room sign beside each."""
    img = _to_u8(_paint(rng, h, w, ppm, 0.03, 1.5))
    wood = np.array([45, 85, 130], dtype=np.float32) * rng.uniform(0.8, 1.2)
    x = rng.uniform(0.5, 2.0) * ppm
    dw, fr = 0.9 * ppm, max(int(0.06 * ppm), 2)
    dh = min(2.1, h / ppm - 0.15) * ppm
    while x + dw + 2 * fr < w:
        x0, x1 = int(x), int(x + dw)
        y0, y1 = int(h - dh), h
        grain = _fbm(rng, y1 - y0, x1 - x0, (3.0, 8.0))
        streak = cv2.resize(
            rng.standard_normal((1, max((x1 - x0) // 4, 2))).astype(np.float32),
            (x1 - x0, y1 - y0),
            interpolation=cv2.INTER_LINEAR,
        )
        leaf = wood * (1.0 + 0.10 * grain + 0.10 * streak)[:, :, None]
        img[y0:y1, x0:x1] = _to_u8(leaf)
        kick = int(0.2 * ppm)
        img[y1 - kick : y1, x0:x1] = (165, 165, 160)
        if rng.random() < 0.5:
            wx0, wx1 = x0 + int(0.3 * dw), x1 - int(0.3 * dw)
            cv2.rectangle(img, (wx0, y0 + int(0.2 * ppm)), (wx1, y0 + int(0.9 * ppm)), (95, 90, 80), -1)
            cv2.rectangle(
                img, (wx0, y0 + int(0.2 * ppm)), (wx1, y0 + int(0.9 * ppm)), (20, 20, 20), max(fr // 4, 1)
            )
        side = x1 - int(0.1 * ppm) if rng.random() < 0.5 else x0 + int(0.1 * ppm)
        hy = h - int(1.0 * ppm)
        cv2.rectangle(
            img,
            (side - int(0.06 * ppm), hy - int(0.015 * ppm)),
            (side + int(0.06 * ppm), hy + int(0.015 * ppm)),
            (200, 200, 205),
            -1,
        )
        cv2.circle(img, (side, hy), int(0.03 * ppm), (150, 150, 155), -1, cv2.LINE_AA)
        cv2.rectangle(img, (x0 - fr, y0 - fr), (x1 + fr, y1), (235, 235, 230), fr)
        cv2.rectangle(img, (x0 - fr - 1, y0 - fr - 1), (x1 + fr + 1, y1), (60, 60, 60), 1)
        # Room sign beside the door.
        sx = x1 + fr + int(0.15 * ppm)
        sy = h - int(1.65 * ppm)
        if sx + int(0.3 * ppm) < w and sy > 0:
            cv2.rectangle(img, (sx, sy), (sx + int(0.3 * ppm), sy + int(0.15 * ppm)), _saturated(rng), -1)
            _text(img, rng, sx + int(0.03 * ppm), sy + int(0.11 * ppm), int(0.07 * ppm), (250, 250, 250), 3)
        x = x1 + rng.uniform(1.6, 4.0) * ppm
    out = img.astype(np.float32)
    _skirting(out, ppm, rng)
    return _to_u8(out)


def _signs(rng: np.random.Generator, h: int, w: int, ppm: float) -> Image:
    """Painted wall with signs, notice boards and extinguisher cabinets every 0.8-2.5 m."""
    base = _paint(rng, h, w, ppm, 0.03, 1.5)
    _dado(base, ppm, rng)
    img = _to_u8(base)
    x = rng.uniform(0.2, 1.0) * ppm
    while x < w - 0.5 * ppm:
        kind = rng.integers(0, 3)
        if kind == 0:  # a sign: plate, text, arrow
            sw, sh = rng.uniform(0.25, 0.5) * ppm, rng.uniform(0.12, 0.25) * ppm
            y0 = int(h - rng.uniform(1.4, min(2.0, h / ppm - 0.05)) * ppm)
            col = _saturated(rng)
            cv2.rectangle(img, (int(x), y0), (int(x + sw), int(y0 + sh)), col, -1)
            _text(
                img,
                rng,
                int(x + 0.1 * sh),
                int(y0 + 0.7 * sh),
                int(0.4 * sh),
                (250, 250, 250),
                int(rng.integers(3, 7)),
            )
            ax = int(x + sw - 0.45 * sh)
            cv2.arrowedLine(
                img,
                (ax - int(0.3 * sh), int(y0 + 0.5 * sh)),
                (ax + int(0.3 * sh), int(y0 + 0.5 * sh)),
                (250, 250, 250),
                max(int(0.06 * sh), 1),
                cv2.LINE_AA,
                tipLength=0.5,
            )
            x += sw
        elif kind == 1:  # a cork notice board with pinned sheets
            bw, bh = rng.uniform(0.6, 1.2) * ppm, min(rng.uniform(0.5, 0.8) * ppm, h - 1.0 * ppm)
            if bh < 0.2 * ppm:
                x += 0.5 * ppm
                continue
            y1 = int(h - 0.95 * ppm)
            y0 = int(y1 - bh)
            cork = _fbm(rng, y1 - y0, int(bw), (1.5, 4.0))
            # A board near the wall's end is cut at the end (the texture is drawn whole, so
            # the random stream, and every other wall, is as for a board that fits).
            x0, x1 = int(x), min(int(x) + int(bw), w)
            img[y0:y1, x0:x1] = _to_u8(
                np.array([70, 120, 165], dtype=np.float32) * (1 + 0.15 * cork[:, : x1 - x0])[:, :, None]
            )
            for _ in range(int(rng.integers(3, 8))):
                px, py = int(x + rng.uniform(0, 0.75) * bw), int(y0 + rng.uniform(0, 0.6) * bh)
                pw, ph = int(0.21 * ppm * rng.uniform(0.8, 1.2)), int(0.297 * ppm * rng.uniform(0.6, 1.0))
                cv2.rectangle(img, (px, py), (px + pw, py + ph), (235, 240, 240), -1)
                for k in range(3):
                    _text(
                        img,
                        rng,
                        px + 3,
                        py + int((0.25 + 0.22 * k) * ph),
                        max(int(0.03 * ppm), 5),
                        (40, 40, 40),
                        5,
                    )
            x += bw
        else:  # an extinguisher cabinet
            cw, ch = 0.3 * ppm, 0.6 * ppm
            y1 = int(h - rng.uniform(0.6, 0.9) * ppm)
            cv2.rectangle(img, (int(x), int(y1 - ch)), (int(x + cw), y1), (30, 30, 190), -1)
            cv2.rectangle(
                img,
                (int(x + 0.05 * ppm), int(y1 - ch + 0.1 * ppm)),
                (int(x + cw - 0.05 * ppm), y1 - int(0.2 * ppm)),
                (200, 210, 215),
                -1,
            )
            _text(img, rng, int(x + 0.04 * ppm), y1 - int(0.06 * ppm), int(0.06 * ppm), (250, 250, 250), 4)
            x += cw
        x += rng.uniform(0.8, 2.5) * ppm
    out = img.astype(np.float32)
    _skirting(out, ppm, rng)
    return _to_u8(out)


def _repeating(rng: np.random.Generator, h: int, w: int, ppm: float) -> Image:
    """Exactly periodic along the wall (period REPEAT_PERIOD_M): one tile with panels,
    a disc and stripes, repeated; the paper's Fig. 5 case."""
    pw = max(round(REPEAT_PERIOD_M * ppm), 4)
    tile = _to_u8(_paint(rng, h, pw, ppm, 0.0, 3.0))
    m = max(pw // 10, 1)
    cv2.rectangle(tile, (m, int(0.3 * h)), (pw - m, int(0.75 * h)), _saturated(rng), -1)
    cv2.circle(tile, (pw // 2, int(0.45 * h)), max(pw // 4, 1), _saturated(rng), -1, cv2.LINE_AA)
    cv2.line(tile, (0, int(0.6 * h)), (pw, int(0.68 * h)), (30, 30, 30), max(pw // 25, 1), cv2.LINE_AA)
    cv2.rectangle(tile, (pw // 3, int(0.15 * h)), (2 * pw // 3, int(0.22 * h)), (40, 40, 40), -1)
    # The same motif low on the wall, where the laser's scan plane meets it.
    lo_top, lo_bottom = h - round(0.75 * ppm), h - round(0.15 * ppm)
    cv2.rectangle(tile, (m, lo_top), (pw - m, lo_bottom), _saturated(rng), -1)
    mid = (lo_top + lo_bottom) // 2
    cv2.circle(tile, (pw // 2, mid), max(pw // 5, 1), _saturated(rng), -1, cv2.LINE_AA)
    cv2.line(
        tile,
        (m, lo_top + (lo_bottom - lo_top) // 5),
        (pw - m, mid + pw // 8),
        (30, 30, 30),
        max(pw // 25, 1),
        cv2.LINE_AA,
    )
    out = np.tile(tile, (1, -(-w // pw), 1))[:, :w].astype(np.float32)
    _skirting(out, ppm, np.random.default_rng(0))  # the same skirting in every period
    return _to_u8(out)


def _floor(rng: np.random.Generator, h: int, w: int, ppm: float) -> Image:
    """Floor tiles 0.4 m with grout, each tile its own shade, terrazzo speckle."""
    tile = 0.4 * ppm
    ny, nx = int(h / tile) + 2, int(w / tile) + 2
    iy, ix = np.mgrid[0:ny, 0:nx].astype(np.float32)
    tone = 0.85 + 0.3 * hash01(ix + float(rng.integers(0, 1000)), iy)
    big = cv2.resize(tone, (int(nx * tile), int(ny * tile)), interpolation=cv2.INTER_NEAREST)
    g: F32 = np.asarray(big, dtype=np.float32)[:h, :w]
    g *= 1.0 + 0.08 * _fbm(rng, h, w, (1.5, 4.0, 0.5 * ppm))
    dots = rng.random((h, w), dtype=np.float32)
    g = np.where(dots < 0.02, g * np.float32(0.55), g)
    g = np.where(dots > 0.985, g * np.float32(1.35), g)
    gr = max(int(0.008 * ppm), 1)
    for k in range(int(h / tile) + 1):
        g[int(k * tile) : int(k * tile) + gr] = 0.57
    for k in range(int(w / tile) + 1):
        g[:, int(k * tile) : int(k * tile) + gr] = 0.57
    out: Image = np.asarray(cv2.merge([cv2.convertScaleAbs(g, alpha=c) for c in (150.0, 160.0, 170.0)]))
    return out


def _ceiling(rng: np.random.Generator, h: int, w: int, ppm: float) -> Image:
    """Suspended ceiling: 0.6 m acoustic panels with pitted speckle, a metal grid, and
    0.6 x 1.2 m light panels with louvres on some."""
    panel = 0.6 * ppm
    img = np.full((h, w, 3), 228.0, dtype=np.float32)
    img *= (1.0 + 0.04 * _fbm(rng, h, w, (1.5, 3.0)))[:, :, None]
    pits = rng.random((h, w), dtype=np.float32) < 0.03
    img[pits] *= 0.8
    ny, nx = int(h / panel) + 1, int(w / panel) + 1
    off = float(rng.integers(0, 1000))
    for j in range(0, ny - 1, 2):
        for i in range(nx):
            if hash01(np.array([i + off]), np.array([j + 0.0]))[0] < 0.18:
                x0, y0 = int(i * panel), int(j * panel)
                x1, y1 = int(x0 + panel), int(y0 + 2 * panel)
                img[y0:y1, x0:x1] = 252.0
                for k in range(1, 6):
                    yy = int(y0 + k * (y1 - y0) / 6)
                    img[yy : yy + 2, x0:x1] = 205.0
                img[y0:y1, (x0 + x1) // 2 : (x0 + x1) // 2 + 2] = 205.0
    g = max(int(0.015 * ppm), 1)
    for k in range(ny + 1):
        img[int(k * panel) : int(k * panel) + g] = (175, 175, 172)
    for k in range(nx + 1):
        img[:, int(k * panel) : int(k * panel) + g] = (175, 175, 172)
    return _to_u8(img)


_GENERATORS: dict[str, Callable[[np.random.Generator, int, int, float], Image]] = {
    "plain": _plain,
    "posters": _posters,
    "bricks": _bricks,
    "doors": _doors,
    "noise": _noise,
    "repeating": _repeating,
    "signs": _signs,
}
