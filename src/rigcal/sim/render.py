"""Ray-cast rendering of a box-target scene: a rectangular room and the box on a stand.

Every pixel's ray comes from :meth:`rigcal.camera.Camera.bearings` (so lens distortion is
rendered exactly as the camera model projects) and is intersected with the room (floor,
ceiling, four walls) and the bounded rectangles of the box's and its stand's faces; the
nearest hit wins. Surfaces get simple procedural textures (floor tiles, ceiling panels,
wall shading, posters, skirting) and the box a strong orange with dark outlines, so that a
person can pick the box's ends. Everything is deterministic: no random numbers.

Frames: the scene is given in the laser frame (docs/conventions.md). The room frame
(``room``) has its origin at the room's centre at laser height, x and y along its walls and
z up; the room's pose in the laser frame is ``(x_m, y_m, yaw_rad)``.
"""

from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from rigcal.arrays import FloatArray
from rigcal.camera import Camera
from rigcal.geometry import inv_T
from rigcal.targets.box import BoxTarget

Image = NDArray[np.uint8]

# Surface labels of render_scene's label image.
LABEL_NONE = -1
LABEL_FLOOR = 0
LABEL_CEILING = 1
LABEL_WALLS = (2, 3, 4, 5)  # walls at room x = +L/2, x = -L/2, y = +W/2, y = -W/2
LABEL_BOX = 6  # box faces are LABEL_BOX + index in rigcal.targets.box.FACE_NAMES (front = 6)
LABEL_STAND = 12

BOX_BGR = (20, 100, 235)  # strong orange; outlines are the same hue, darker
STAND_BGR = (70, 70, 75)
STAND_SIZE_M = 0.04

_WALL_BGR = ((205, 215, 220), (190, 205, 185), (215, 200, 190), (200, 200, 212))
_FLOOR_BGR = ((150, 165, 180), (130, 145, 160))
_CEILING_BGR = (232, 232, 228)
_POSTER_HUES = (1.8, 4.8)  # on hue_bgr's circle: 0 red, 1 yellow, 2 green, 3 cyan, 4 blue, 5 magenta


@dataclass(frozen=True)
class Room:
    """A closed rectangular room around the rig.

    Attributes:
        size_m: (length along room x, width along room y).
        height_m: floor to ceiling.
        laser_height_m: height of the laser's scan plane above the floor.
    """

    size_m: tuple[float, float] = (12.0, 9.0)
    height_m: float = 2.6
    laser_height_m: float = 0.4

    def wall_segments(self, room_pose: ArrayLike) -> FloatArray:
        """The walls cut by the scan plane, for 2D ray casting.

        Args:
            room_pose: (3,) the room's (x_m, y_m, yaw_rad) in the laser frame.

        Returns:
            (4, 2, 2) segments in the laser frame, metres.
        """
        hx, hy = 0.5 * self.size_m[0], 0.5 * self.size_m[1]
        c = np.array([[hx, -hy], [hx, hy], [-hx, hy], [-hx, -hy]])
        x, y, yaw = np.asarray(room_pose, dtype=float)
        R = _rot2(yaw)
        c = c @ R.T + np.array([x, y])
        return np.stack([c, np.roll(c, -1, axis=0)], axis=1)

    def pose_holding(
        self, rng: np.random.Generator, region: FloatArray, clearance_m: float, tries: int = 20
    ) -> tuple[float, float, float] | None:
        """A room pose (laser frame: x, y, yaw) that holds the laser and the laser-frame
        points ``region`` (K, 2) at least ``clearance_m`` from the walls, or None.

        As if the rig stood at a random place and heading in the room: the room's yaw is
        uniform, and the laser's position in the room is uniform over where everything fits.
        """
        hx, hy = 0.5 * self.size_m[0], 0.5 * self.size_m[1]
        half = np.array([hx, hy])
        for _ in range(tries):
            yaw = rng.uniform(-np.pi, np.pi)
            q = region @ _rot2(yaw)  # the region relative to the laser, in room axes
            lo = np.maximum(-half + clearance_m - q.min(axis=0), -half + clearance_m)
            hi = np.minimum(half - clearance_m - q.max(axis=0), half - clearance_m)
            if np.all(hi > lo):
                p = lo + rng.uniform(size=2) * (hi - lo)  # laser position in the room frame
                xy = -_rot2(yaw) @ p
                return float(xy[0]), float(xy[1]), float(yaw)
        return None

    def contains(self, room_pose: ArrayLike, points_xy: ArrayLike, margin_m: float = 0.0) -> bool:
        """Whether laser-frame points (N, 2) lie inside the room, at least margin_m from its walls."""
        x, y, yaw = np.asarray(room_pose, dtype=float)
        p = (np.atleast_2d(np.asarray(points_xy, dtype=float)) - np.array([x, y])) @ _rot2(yaw)
        hx, hy = 0.5 * self.size_m[0] - margin_m, 0.5 * self.size_m[1] - margin_m
        return bool(np.all((np.abs(p[:, 0]) < hx) & (np.abs(p[:, 1]) < hy)))


@dataclass(frozen=True)
class Scene:
    """What a capture sees, in the laser frame.

    Attributes:
        room: the room.
        room_pose: (x_m, y_m, yaw_rad) of the room frame in the laser frame.
        box: the box target (None: an empty room).
        box_pose: (x_m, y_m, yaw_rad) of the box (rigcal.targets.box) in the laser frame.
        stand: draw the post the box stands on (floor to the box's bottom).
    """

    room: Room
    room_pose: tuple[float, float, float]
    box: BoxTarget | None = field(default_factory=BoxTarget)
    box_pose: tuple[float, float, float] = (2.0, 0.0, 0.0)
    stand: bool = True


# --- bearing grid cache -----------------------------------------------------------------
_BEARINGS: OrderedDict[tuple[str, bytes, int, int], NDArray[np.float32]] = OrderedDict()
_BEARINGS_MAX = 4


def pixel_bearings(camera: Camera) -> NDArray[np.float32]:
    """Unit rays of every pixel centre, cached per camera model.

    Returns:
        (height_px * width_px, 3) float32 unit vectors in the camera frame, row-major
        (pixel (u, v) at index v * width + u). Read-only.
    """
    key = (camera.lensmodel, camera.intrinsics.tobytes(), camera.width_px, camera.height_px)
    hit = _BEARINGS.get(key)
    if hit is not None:
        _BEARINGS.move_to_end(key)
        return hit
    u, v = np.meshgrid(np.arange(camera.width_px, dtype=float), np.arange(camera.height_px, dtype=float))
    b = camera.bearings(np.column_stack([u.ravel(), v.ravel()])).astype(np.float32)
    b.setflags(write=False)
    _BEARINGS[key] = b
    if len(_BEARINGS) > _BEARINGS_MAX:
        _BEARINGS.popitem(last=False)
    return b


def render_image(camera: Camera, T_cam_laser: ArrayLike, scene: Scene) -> Image:
    """Render the scene as the camera sees it.

    Args:
        camera: the camera (its lens model and image size).
        T_cam_laser: (4, 4) laser frame to camera frame.
        scene: the room and box, in the laser frame.

    Returns:
        (height_px, width_px, 3) uint8 BGR image.
    """
    return render_scene(camera, T_cam_laser, scene)[0]


def render_scene(camera: Camera, T_cam_laser: ArrayLike, scene: Scene) -> tuple[Image, NDArray[np.int8]]:
    """Render the scene, also returning which surface each pixel shows.

    Returns:
        image: (H, W, 3) uint8 BGR.
        labels: (H, W) int8 surface labels (``LABEL_*``; box faces are ``LABEL_BOX`` plus
        their index in :data:`rigcal.targets.box.FACE_NAMES`).
    """
    H, W = camera.height_px, camera.width_px
    T_laser_cam = inv_T(np.asarray(T_cam_laser, dtype=float))
    bear = pixel_bearings(camera)
    # Rays in the laser frame: origin o (camera centre), directions D (N, 3).
    o = T_laser_cam[:3, 3].astype(np.float32)
    D = bear @ T_laser_cam[:3, :3].T.astype(np.float32)

    room = scene.room
    rx, ry, ryaw = (float(v) for v in scene.room_pose)
    R2 = _rot2(ryaw).astype(np.float32)
    o_room = np.array([*(R2.T @ (o[:2] - np.array([rx, ry], dtype=np.float32))), o[2]], dtype=np.float32)
    D_room = np.column_stack([D[:, :2] @ R2, D[:, 2]])
    half = np.array(
        [0.5 * room.size_m[0], 0.5 * room.size_m[1], 0.0], dtype=np.float32
    )  # z handled separately
    t_best = np.full(len(D), np.inf, dtype=np.float32)
    label = np.full(len(D), LABEL_NONE, dtype=np.int8)
    # Inside a box-shaped room every ray leaves through exactly one of the three exit planes.
    with np.errstate(divide="ignore", invalid="ignore"):
        for axis, (lab_pos, lab_neg) in enumerate(
            ((LABEL_WALLS[0], LABEL_WALLS[1]), (LABEL_WALLS[2], LABEL_WALLS[3]), (LABEL_CEILING, LABEL_FLOOR))
        ):
            d = D_room[:, axis]
            if axis < 2:
                hi, lo = half[axis], -half[axis]
            else:
                hi, lo = room.height_m - room.laser_height_m, -room.laser_height_m
            t = np.where(d > 0, (hi - o_room[axis]) / d, (lo - o_room[axis]) / d)
            t = np.where(np.isfinite(t) & (t > 0), t, np.inf).astype(np.float32)
            closer = t < t_best
            t_best[closer] = t[closer]
            label[closer] = np.where(d[closer] > 0, lab_pos, lab_neg)

    # Box faces and stand faces: bounded rectangles; keep the face coordinates for outlines.
    bx, by, byaw = (float(v) for v in scene.box_pose)
    box = scene.box
    rects = [] if box is None else [(f, LABEL_BOX + i) for i, f in enumerate(box.faces(bx, by, byaw))]
    if box is not None and scene.stand:
        stand_h = room.laser_height_m - 0.5 * box.height_m
        if stand_h > 0:
            post = BoxTarget(width_m=STAND_SIZE_M, depth_m=STAND_SIZE_M, height_m=stand_h)
            z_mid = -room.laser_height_m + 0.5 * stand_h
            for f in post.faces(bx, by, byaw)[:4]:  # the four sides; top and bottom are hidden
                rects.append((f + np.array([0.0, 0.0, z_mid]), LABEL_STAND))
    edge_m = np.full(len(D), np.inf, dtype=np.float32)
    for corners, lab in rects:
        t, e = ray_rectangle(o, D, corners)
        closer = t < t_best
        t_best[closer] = t[closer]
        label[closer] = lab
        edge_m[closer] = e[closer]

    img = _shade(o, D, o_room, D_room, t_best, label, edge_m, room, camera)
    return img.reshape(H, W, 3), label.reshape(H, W)


def ray_rectangle(
    o: NDArray[np.float32], D: NDArray[np.float32], corners: FloatArray
) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
    """Ray parameters of hits with a rectangle (inf where missed) and each hit's distance to
    the rectangle's nearest edge, metres."""
    c = corners.astype(np.float32)
    p0, e1, e2 = c[0], c[1] - c[0], c[3] - c[0]
    n = np.cross(e1, e2)
    den = D @ n
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.float32(n @ (p0 - o)) / den
    P = o + t[:, None] * D - p0
    L1, L2 = float(np.linalg.norm(e1)), float(np.linalg.norm(e2))
    a = P @ (e1 / L1)
    b = P @ (e2 / L2)
    hit = np.isfinite(t) & (t > 0) & (a >= 0) & (a <= L1) & (b >= 0) & (b <= L2)
    edge = np.minimum(np.minimum(a, L1 - a), np.minimum(b, L2 - b))
    return np.where(hit, t, np.inf).astype(np.float32), edge.astype(np.float32)


def _shade(
    o: NDArray[np.float32],
    D: NDArray[np.float32],
    o_room: NDArray[np.float32],
    D_room: NDArray[np.float32],
    t: NDArray[np.float32],
    label: NDArray[np.int8],
    edge_m: NDArray[np.float32],
    room: Room,
    camera: Camera,
) -> Image:
    """Colour every pixel from its surface label and hit point."""
    out = np.zeros((len(t), 3), dtype=np.float32)
    P = o_room + t[:, None] * D_room  # hit points in the room frame
    # Size of one pixel on a surface facing the camera at distance t: keeps lines ~1 px wide.
    px_m = t / np.float32(0.5 * (camera.intrinsics[0] + camera.intrinsics[1]))
    z_floor = -room.laser_height_m

    m = label == LABEL_FLOOR
    if m.any():
        out[m] = _tiles(P[m, 0], P[m, 1], px_m[m], 0.5, _FLOOR_BGR, (95, 100, 105))
    m = label == LABEL_CEILING
    if m.any():
        out[m] = _tiles(P[m, 0], P[m, 1], px_m[m], 0.6, (_CEILING_BGR, _CEILING_BGR), (180, 180, 178))
    for k, lab in enumerate(LABEL_WALLS):
        m = label == lab
        if m.any():
            along = P[m, 1] if k < 2 else P[m, 0]
            out[m] = _wall(along, P[m, 2] - z_floor, px_m[m], k)
    m = (label >= LABEL_BOX) & (label < LABEL_BOX + 6)
    if m.any():
        # Per-face brightness (front, back, right, left, bottom, top) as under a ceiling light.
        face_gain = np.array([1.0, 0.7, 0.8, 0.8, 0.55, 0.92], dtype=np.float32)
        g = face_gain[label[m] - LABEL_BOX]
        outline = edge_m[m] < 1.2 * px_m[m]
        g = np.where(outline, 0.4 * g, g)
        out[m] = g[:, None] * np.array(BOX_BGR, dtype=np.float32)
    m = label == LABEL_STAND
    if m.any():
        out[m] = np.array(STAND_BGR, dtype=np.float32)
    # Gentle fall-off with distance, as from lights near the rig.
    fall = np.clip(1.08 - 0.025 * t, 0.75, 1.05)[:, None]
    return np.clip(out * fall + 0.5, 0, 255).astype(np.uint8)


def _tiles(
    x: NDArray[np.float32],
    y: NDArray[np.float32],
    px_m: NDArray[np.float32],
    size_m: float,
    colours: tuple[tuple[int, int, int], tuple[int, int, int]],
    grout: tuple[int, int, int],
) -> NDArray[np.float32]:
    """A checker of square tiles with grout lines and a little per-tile variation."""
    ix = np.floor(x / size_m)
    iy = np.floor(y / size_m)
    parity = ((ix + iy) % 2).astype(np.int64)
    base = np.array(colours, dtype=np.float32)[parity]
    base *= (0.94 + 0.12 * hash01(ix, iy))[:, None]
    fx = np.abs(x / size_m - np.round(x / size_m)) * size_m
    fy = np.abs(y / size_m - np.round(y / size_m)) * size_m
    line = np.minimum(fx, fy) < np.maximum(0.006, 0.6 * px_m)
    base[line] = np.array(grout, dtype=np.float32)
    return base


def _wall(
    along: NDArray[np.float32], z: NDArray[np.float32], px_m: NDArray[np.float32], k: int
) -> NDArray[np.float32]:
    """Wall k: soft paint shading, posters every few metres, a dark skirting board.

    Args:
        along: coordinate along the wall, metres (room frame).
        z: height above the floor, metres.
    """
    base = np.array(_WALL_BGR[k], dtype=np.float32)
    shade = 1.0 + 0.05 * np.sin(0.9 * along + 1.7 * k) * np.cos(1.3 * z - 0.6 * along)
    col: NDArray[Any] = shade[:, None] * base
    # Posters: 0.7 m x 0.9 m, one every 2.3 m, bottom edge 1.0 m above the floor.
    pitch, pw, ph, z0 = 2.3, 0.7, 0.9, 1.0
    slot = np.floor((along + 0.37 * k) / pitch)
    a = (along + 0.37 * k) - slot * pitch - 0.5 * (pitch - pw)
    zz = z - z0
    on = (a >= 0) & (a <= pw) & (zz >= 0) & (zz <= ph)
    if on.any():
        h = hash01(slot[on], np.full(int(on.sum()), k, dtype=np.float32))
        frame = (a[on] < 0.04) | (a[on] > pw - 0.04) | (zz[on] < 0.04) | (zz[on] > ph - 0.04)
        # Three horizontal colour bands and a disc whose hues depend on the poster. Hues
        # stay within green-cyan-blue-violet, so that nothing but the box is orange.
        band = np.clip((zz[on] / ph * 3).astype(np.int64), 0, 2)
        hue = _POSTER_HUES[0] + (h * 3.0 + band * 1.1) % (_POSTER_HUES[1] - _POSTER_HUES[0])
        pc: NDArray[Any] = hue_bgr(hue) * np.float32(200) + np.float32(30)
        circle = (a[on] - 0.5 * pw) ** 2 + (zz[on] - 0.62 * ph) ** 2 < (0.18 + 0.08 * h) ** 2
        disc = _POSTER_HUES[0] + (hue[circle] - _POSTER_HUES[0] + 1.5) % (_POSTER_HUES[1] - _POSTER_HUES[0])
        pc[circle] = np.array([40, 40, 40], dtype=np.float32) + 180 * hue_bgr(disc)
        pc[frame] = np.array([245, 245, 245], dtype=np.float32)
        col[on] = pc
    skirt = z < 0.1
    col[skirt] = np.array([55, 70, 90], dtype=np.float32)
    edge = np.abs(z - 0.1) < 0.5 * px_m
    col[edge] = np.array([35, 45, 60], dtype=np.float32)
    return col


def hue_bgr(hue: NDArray[Any]) -> NDArray[np.float32]:
    """Saturated colours on the hue circle (hue in [0, 6)), as BGR in [0, 1]."""
    h = hue[:, None] + np.array([4.0, 2.0, 0.0], dtype=np.float32)  # B, G, R phase
    out: NDArray[np.float32] = np.clip(np.abs((h % 6.0) - 3.0) - 1.0, 0.0, 1.0).astype(np.float32)
    return out


def hash01(a: NDArray[np.floating], b: NDArray[np.floating]) -> NDArray[np.float32]:
    """A deterministic pseudo-random value in [0, 1) per integer pair (texture variation)."""
    v = np.sin(a.astype(np.float64) * 12.9898 + b.astype(np.float64) * 78.233) * 43758.5453
    out: NDArray[np.float32] = (v - np.floor(v)).astype(np.float32)
    return out


def _rot2(yaw: float) -> FloatArray:
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([[c, -s], [s, c]])
