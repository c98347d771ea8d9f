"""Indoor worlds made of vertical planes, for simulated drives (docs/formats/world.md).

A world is seen from above: walls are 2D segments standing on the floor, obstacles
(pillars, boxes, cubicle partitions) are closed polygons, each with a height and a texture
name for the camera; a closed path through the free space is where the rig drives. The
laser's scan plane is horizontal at ``laser_height_m``, so the laser sees every wall and
every obstacle taller than that height as 2D segments.

Built-in worlds (:data:`BUILTIN`): ``corridor-loop``, a 60 m loop through a building's
interior corridor (the paper's Section VI), with long texture-poor stretches;
``cubicle-loop``, a 35 m loop through narrow corridors between cubicle partitions
(Section III-D); ``calibration-room``, a room with the box target (Section II).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from rigcal.arrays import FloatArray
from rigcal.errors import InputError
from rigcal.io.files import check_keys, check_schema_version, get_float, load_yaml
from rigcal.io.validate import is_real

WORLD_SCHEMA_VERSION = 1
TEXTURES = ("plain", "posters", "bricks", "doors", "noise", "repeating", "signs")


@dataclass(frozen=True)
class Surface:
    """A vertical plane of the world: a 2D segment from the floor up to a height.

    Attributes:
        a, b: (2,) its ends, world frame, metres.
        height_m: its top above the floor.
        texture: one of TEXTURES.
    """

    a: FloatArray
    b: FloatArray
    height_m: float
    texture: str


@dataclass(frozen=True)
class World:
    """A world: its surfaces, the rig's path and the laser's height."""

    name: str
    surfaces: tuple[Surface, ...]
    path: FloatArray
    laser_height_m: float

    def scan_segments(self) -> FloatArray:
        """(S, 2, 2) the surfaces the scan plane cuts (those taller than the laser)."""
        segs = [np.array([s.a, s.b]) for s in self.surfaces if s.height_m > self.laser_height_m]
        return np.array(segs) if segs else np.zeros((0, 2, 2))

    @property
    def path_length_m(self) -> float:
        closed = np.vstack([self.path, self.path[:1]])
        return float(np.linalg.norm(np.diff(closed, axis=0), axis=1).sum())


def read_world(path: str | Path) -> World:
    """Read and validate a world file.

    Raises:
        InputError: a malformed file, naming the key and value.
    """
    path = Path(path)
    d = check_keys(
        load_yaml(path, "world file"),
        path,
        "",
        ["schema_version", "name", "path", "walls"],
        ["obstacles", "laser_height_m"],
        [WORLD_SCHEMA_VERSION],
    )
    check_schema_version(d, path, WORLD_SCHEMA_VERSION)
    laser_h = get_float(d, "laser_height_m", path, positive=True) if "laser_height_m" in d else 0.4
    surfaces: list[Surface] = []
    walls = d["walls"]
    if not isinstance(walls, list) or not walls:
        raise InputError.at(path, "walls", walls, "a non-empty list of walls")
    for i, w in enumerate(walls):
        kp = f"walls[{i}]"
        w = check_keys(w, path, kp, ["from", "to"], ["height_m", "texture"])
        a = _point(w["from"], path, f"{kp}.from")
        b = _point(w["to"], path, f"{kp}.to")
        if np.linalg.norm(b - a) < 1e-6:
            raise InputError.at(path, kp, w, "a wall of non-zero length")
        surfaces.append(Surface(a, b, _height(w, path, kp, 2.5), _texture(w, path, kp)))
    obstacles = d.get("obstacles", [])
    if not isinstance(obstacles, list):
        raise InputError.at(path, "obstacles", obstacles, "a list of obstacles")
    for i, o in enumerate(obstacles):
        kp = f"obstacles[{i}]"
        o = check_keys(o, path, kp, ["polygon"], ["height_m", "texture"])
        poly = o["polygon"]
        if not isinstance(poly, list) or len(poly) < 3:
            raise InputError.at(path, f"{kp}.polygon", poly, "at least 3 corners [[x, y], ...]")
        pts = [_point(p, path, f"{kp}.polygon[{j}]") for j, p in enumerate(poly)]
        h, tex = _height(o, path, kp, 1.0), _texture(o, path, kp)
        surfaces += [Surface(pts[j], pts[(j + 1) % len(pts)], h, tex) for j in range(len(pts))]
    route = d["path"]
    if not isinstance(route, list) or len(route) < 3:
        raise InputError.at(path, "path", route, "a closed path of at least 3 points [[x, y], ...]")
    waypoints = np.array([_point(p, path, f"path[{j}]") for j, p in enumerate(route)])
    _check_path(waypoints, route, path)
    _check_path_clear(waypoints, route, surfaces, path)
    if not isinstance(d["name"], str) or not d["name"]:
        raise InputError.at(path, "name", d["name"], "a non-empty string")
    return World(d["name"], tuple(surfaces), waypoints, laser_h)


MAX_CORNER_DEG = 150.0  # the rig drives a corner as an arc; a U-turn would spin it on the spot


def _check_path(P: FloatArray, route: list[Any], path: Path) -> None:
    """Each waypoint at least 0.1 m from the one before, each corner turning less than
    MAX_CORNER_DEG (the drive rounds corners into arcs; a sharper one spins the rig on
    the spot)."""
    n = len(P)
    for j in range(n):
        d_in = P[j] - P[j - 1]
        if np.hypot(*d_in) < 0.1:
            raise InputError.at(path, f"path[{j}]", route[j], "a point at least 0.1 m from the one before")
    for j in range(n):
        d_in, d_out = P[j] - P[j - 1], P[(j + 1) % n] - P[j]
        cross = float(d_in[0] * d_out[1] - d_in[1] * d_out[0])
        turn = abs(np.degrees(np.arctan2(cross, float(d_in @ d_out))))
        if turn >= MAX_CORNER_DEG:
            expected = f"a corner turning less than {MAX_CORNER_DEG:g} deg (it turns {turn:.0f} deg)"
            raise InputError.at(path, f"path[{j}]", route[j], expected)


def _check_path_clear(P: FloatArray, route: list[Any], surfaces: list[Surface], path: Path) -> None:
    """No leg of the closed path (waypoint to waypoint) crosses a wall or an obstacle's edge."""
    if not surfaces:
        return
    a = np.array([s.a for s in surfaces])
    b = np.array([s.b for s in surfaces])

    def side(o: Any, u: Any, v: Any) -> Any:
        d, e = np.asarray(u) - o, np.asarray(v) - o
        return np.sign(d[..., 0] * e[..., 1] - d[..., 1] * e[..., 0])

    for j in range(len(P)):
        p, q = P[j - 1], P[j]
        crosses = (side(p, q, a) * side(p, q, b) <= 0) & (side(a, b, p) * side(a, b, q) <= 0)
        if crosses.any():
            k = int(np.flatnonzero(crosses)[0])
            what = f"a leg from path[{(j - 1) % len(P)}] clear of walls and obstacles (it meets the surface "
            raise InputError.at(path, f"path[{j}]", route[j], what + f"{a[k].tolist()}-{b[k].tolist()})")


def _point(v: Any, path: Path, key: str) -> FloatArray:
    ok = isinstance(v, list) and len(v) == 2 and all(is_real(x) and abs(x) <= 1e5 for x in v)
    if not ok:
        raise InputError.at(path, key, v, "a point [x, y] in metres, within 100 km of the origin")
    return np.array(v, dtype=float)


def _height(d: Any, path: Path, kp: str, default: float) -> float:
    return get_float(d, "height_m", path, kp, positive=True) if "height_m" in d else default


def _texture(d: Any, path: Path, kp: str) -> str:
    t = d.get("texture", "plain")
    if t not in TEXTURES:
        raise InputError.at(path, f"{kp}.texture", t, f"one of {list(TEXTURES)}")
    return str(t)


# --- built-in worlds -------------------------------------------------------------------------
def _rect(cx: float, cy: float, w: float, h: float) -> FloatArray:
    return np.array(
        [
            [cx - w / 2, cy - h / 2],
            [cx + w / 2, cy - h / 2],
            [cx + w / 2, cy + h / 2],
            [cx - w / 2, cy + h / 2],
        ]
    )


def _ring(outer: FloatArray, inner: FloatArray, textures: list[str], height: float) -> list[Surface]:
    """The walls of a corridor running around a block: the outer and inner rectangles."""
    out = []
    for poly in (outer, inner):
        for j in range(4):
            out.append(Surface(poly[j], poly[(j + 1) % 4], height, textures[j % len(textures)]))
    return out


def corridor_loop() -> World:
    """A 60 m loop through a corridor 2 m wide around an 18.5 x 8.5 m block (centre line
    20.5 x 9.5 m), with posters and doors on some stretches and long plain ones, and a
    repeating pattern on one wall."""
    outer = _rect(0.0, 0.0, 22.5, 11.5)
    inner = _rect(0.0, 0.0, 18.5, 7.5)
    surfaces = _ring(outer, inner, ["posters", "plain", "doors", "repeating"], 2.6)
    # Pillars along a long stretch, standing against the outer wall (the corridor's centre
    # line stays clear), give ICP something to hold on to.
    for x in (-6.0, 0.0, 6.0):
        pillar = _rect(x, 5.6, 0.3, 0.3)
        surfaces += [
            Surface(p, q, 2.6, "bricks") for p, q in zip(pillar, np.roll(pillar, -1, axis=0), strict=True)
        ]
    path = _rect(0.0, 0.0, 20.5, 9.5)
    return World("corridor-loop", tuple(surfaces), path, 0.4)


def cubicle_loop() -> World:
    """A 35 m loop (centre line 11 x 6.5 m) between an office's outer walls and a block
    of cubicle partitions 1.5 m tall, in corridors 1.4 m wide."""
    outer = _rect(0.0, 0.0, 12.4, 7.9)
    inner = _rect(0.0, 0.0, 9.6, 5.1)
    surfaces = _ring(outer, inner, ["posters", "signs", "plain", "noise"], 2.5)
    # The inner block is cubicles: partitions 1.5 m tall (above the laser, below the camera's view top).
    surfaces = surfaces[:4] + [Surface(s.a, s.b, 1.5, "noise") for s in surfaces[4:]]
    path = _rect(0.0, 0.0, 11.0, 6.5)
    return World("cubicle-loop", tuple(surfaces), path, 0.4)


def calibration_room() -> World:
    """A 10 x 8 m room with a 0.6 m box target at laser height in its middle."""
    room = _rect(0.0, 0.0, 10.0, 8.0)
    surfaces = [Surface(room[j], room[(j + 1) % 4], 2.8, "posters") for j in range(4)]
    box = _rect(0.0, 0.0, 0.15, 0.6)
    surfaces += [Surface(box[j], box[(j + 1) % 4], 0.44, "plain") for j in range(4)]
    path = _rect(0.0, 0.0, 5.0, 4.0)
    return World("calibration-room", tuple(surfaces), path, 0.4)


BUILTIN: dict[str, Callable[[], World]] = {
    "corridor-loop": corridor_loop,
    "cubicle-loop": cubicle_loop,
    "calibration-room": calibration_room,
}


def world_named(name: str) -> World:
    """A built-in world by name, or a world file by path."""
    if name in BUILTIN:
        return BUILTIN[name]()
    if Path(name).suffix in (".yaml", ".yml"):
        return read_world(name)
    raise InputError.at(None, "--world", name, f"one of {sorted(BUILTIN)} or a world file (.yaml)")
