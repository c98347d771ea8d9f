"""The marker target: a two-faced V whose faces carry ChArUco patterns.

Beyond the paper's box target (Section II), whose pose a person reads off the image: each
face of this target carries a printed ChArUco pattern (OpenCV's aruco module), so the
camera reads the pose of each face by itself, and the laser's scan plane cuts both faces
(a V in the scan). A targets file (docs/formats/targets.md) describes it; :func:`read_targets`
validates one; :func:`face_image` draws a face as it is printed (and as the simulator
textures it).

Frames (docs/conventions.md):

- **face frame** (``face``, one per face): the face seen from the front (the sensors'
  side), origin at its top-left corner, x to the right along the face, y down, z into
  the face (away from the viewer). The face spans x in [0, width_m], y in [0, edge_m].
- **pattern frame** (``pattern``): OpenCV's ChArUco board frame, the face frame shifted
  by the pattern's ``offset_m`` (its top-left outer corner on the face).
- **target frame** (``target``): origin at the top of the faces' common edge, y down
  along the edge, z along the V's bisector away from the viewer, x to the right. The left
  face ends on the edge at its right side (x = width_m), the right face starts there.
  For a ``concave`` corner (the inside of a box's corner, opening towards the sensors) the
  edge is the V's farthest line, for ``convex`` (a box's outside corner) its nearest.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from rigcal.arrays import FloatArray
from rigcal.errors import InputError
from rigcal.geometry import make_T
from rigcal.io.files import check_keys, load_yaml
from rigcal.io.validate import real, whole

TARGETS_SCHEMA_VERSION = 1
# Versions read: 2 adds ``kind`` (``marker``, or ``board``: rigcal.targets.board). A marker
# target is written as version 1, which holds all of it.
TARGETS_SCHEMA_VERSIONS = (1, 2)
CORNERS = ("concave", "convex")
# A V narrower or wider than this is too close to one plane (or folded flat) for the
# laser to tell its faces apart.
MIN_ANGLE_DEG = 20.0
MAX_ANGLE_DEG = 160.0
# OpenCV's predefined dictionaries and their sizes (ids 0 .. size - 1).
DICTIONARIES = {
    **{f"DICT_{n}X{n}_{k}": k for n in (4, 5, 6, 7) for k in (50, 100, 250, 1000)},
    "DICT_ARUCO_ORIGINAL": 1024,
    "DICT_APRILTAG_16h5": 30,
    "DICT_APRILTAG_25h9": 35,
    "DICT_APRILTAG_36h10": 2320,
    "DICT_APRILTAG_36h11": 587,
    "DICT_ARUCO_MIP_36h12": 250,
}


@dataclass(frozen=True)
class MarkerFace:
    """One face of the target and its ChArUco pattern.

    Attributes:
        name: the face's name.
        width_m: the face's width, across the edge.
        squares: (columns, rows) of the ChArUco pattern's squares.
        square_m: a square's side.
        marker_m: a marker's side (inside its white square).
        ids: the markers' ids, in OpenCV's order (row-major over the white squares).
        offset_m: (x, y) the pattern's top-left outer corner on the face, face frame.
    """

    name: str
    width_m: float
    squares: tuple[int, int]
    square_m: float
    marker_m: float
    ids: tuple[int, ...]
    offset_m: tuple[float, float]

    @property
    def n_markers(self) -> int:
        """Markers on a ChArUco pattern of these squares (the white ones)."""
        return self.squares[0] * self.squares[1] // 2

    @property
    def corner_points(self) -> FloatArray:
        """(K, 3) the pattern's inner (chessboard) corners in the face frame, OpenCV's order
        (the ChArUco corner ids)."""
        sx, sy = self.squares
        j, i = np.meshgrid(np.arange(1, sy), np.arange(1, sx), indexing="ij")
        p = np.column_stack([i.ravel() * self.square_m, j.ravel() * self.square_m, np.zeros(i.size)])
        return p + np.array([self.offset_m[0], self.offset_m[1], 0.0])


@dataclass(frozen=True)
class MarkerTarget:
    """A V of two faces with ChArUco patterns.

    Attributes:
        name: the target's name.
        dictionary: OpenCV dictionary name (``DICT_4X4_50``, ...).
        angle_deg: the angle between the faces, inside the V.
        edge_m: length of the faces' common edge (both faces' height).
        corner: ``concave`` (the V opens towards the sensors) or ``convex``.
        faces: (left, right) as seen from the front.
        path: the targets file it was read from, if any.
    """

    name: str
    dictionary: str
    angle_deg: float
    edge_m: float
    corner: str
    faces: tuple[MarkerFace, MarkerFace]
    path: Path | None = None

    def T_target_face(self, k: int) -> FloatArray:
        """(4, 4) face k's frame in the target frame."""
        beta = np.radians(0.5 * (180.0 - self.angle_deg))  # each face's turn from the frontal plane
        # Concave: the left face runs away from the viewer towards the edge, the right one
        # back towards the viewer; convex the other way round.
        sign = (1.0 if k == 0 else -1.0) * (1.0 if self.corner == "concave" else -1.0)
        x = np.array([np.cos(beta), 0.0, sign * np.sin(beta)])
        y = np.array([0.0, 1.0, 0.0])
        R = np.column_stack([x, y, np.cross(x, y)])
        origin = -self.faces[0].width_m * x if k == 0 else np.zeros(3)
        return make_T(R, origin)

    def outline(self, k: int) -> FloatArray:
        """(4, 2) face k's corners in its face frame (x, y), clockwise as seen from the front."""
        w, h = self.faces[k].width_m, self.edge_m
        return np.array([[0.0, 0.0], [w, 0.0], [w, h], [0.0, h]])

    @property
    def all_ids(self) -> set[int]:
        """Every marker id on the target."""
        return set(self.faces[0].ids) | set(self.faces[1].ids)


def read_targets(path: str | Path) -> MarkerTarget:
    """Read and validate a targets file (docs/formats/targets.md).

    Raises:
        InputError: unreadable, unknown keys, missing or non-positive sizes, an unknown
            dictionary, duplicate or out-of-range ids, a pattern larger than its face, or
            faces that cannot make a V; one line naming the file, key and value.
    """
    path = Path(path)
    return parse_targets(load_yaml(path, "targets file"), path)


def parse_targets(data: Any, path: Path | None) -> MarkerTarget:
    """Validate a parsed targets file (see :func:`read_targets`)."""
    if isinstance(data, dict) and data.get("kind", "marker") != "marker":
        raise InputError.at(
            path,
            "kind",
            data["kind"],
            "marker (a V of two ChArUco faces; kind: board describes a chessboard, for rigcal capture)",
        )
    d = check_keys(
        data,
        path,
        "",
        ["schema_version", "dictionary", "angle_deg", "edge_m", "faces"],
        ["name", "corner", "kind"],
        TARGETS_SCHEMA_VERSIONS,
    )
    version = d["schema_version"]
    if type(version) is not int or version not in TARGETS_SCHEMA_VERSIONS:
        raise InputError.at(path, "schema_version", version, "1 or 2 (the versions this rigcal reads)")
    if "kind" in d and version < 2:
        raise InputError.at(path, "kind", d["kind"], "no kind in schema_version 1 (kind needs 2)")
    dictionary = d["dictionary"]
    if dictionary not in DICTIONARIES:
        raise InputError.at(
            path, "dictionary", dictionary, "one of OpenCV's dictionaries: " + ", ".join(DICTIONARIES)
        )
    corner = d.get("corner", "concave")
    if corner not in CORNERS:
        raise InputError.at(path, "corner", corner, "concave (the V opens towards the sensors) or convex")
    angle = real(d["angle_deg"], path, "angle_deg", positive=True)
    if not MIN_ANGLE_DEG <= angle <= MAX_ANGLE_DEG:
        raise InputError.at(
            path,
            "angle_deg",
            d["angle_deg"],
            f"the angle between the faces in [{MIN_ANGLE_DEG:g}, {MAX_ANGLE_DEG:g}] degrees "
            "(faces nearer flat or folded shut cannot be told apart in a scan)",
        )
    edge = real(d["edge_m"], path, "edge_m", positive=True)
    faces = d["faces"]
    if not isinstance(faces, list) or len(faces) != 2:
        shown = f"{len(faces)} faces" if isinstance(faces, list) else faces
        raise InputError.at(path, "faces", shown, "a list of two faces (left, right as seen from the front)")
    out = [_face(path, f"faces[{k}]", f, edge, DICTIONARIES[dictionary], k) for k, f in enumerate(faces)]
    if out[0].name == out[1].name:
        raise InputError.at(path, "faces[1].name", out[1].name, "a name other than the first face's")
    shared = sorted(set(out[0].ids) & set(out[1].ids))
    if shared:
        raise InputError.at(path, "faces[1].ids", shared[:5], "ids not used on faces[0] (duplicate ids)")
    name = d.get("name", "marker target")
    if not isinstance(name, str):
        raise InputError.at(path, "name", name, "a string")
    return MarkerTarget(name, dictionary, angle, edge, corner, (out[0], out[1]), path)


def _face(path: Path | None, kp: str, f: Any, edge_m: float, dict_size: int, k: int) -> MarkerFace:
    f = check_keys(
        f, path, kp, ["width_m", "squares", "square_m", "marker_m"], ["name", "ids", "first_id", "offset_m"]
    )
    width = real(f["width_m"], path, f"{kp}.width_m", positive=True)
    sq = f["squares"]
    if not isinstance(sq, list) or len(sq) != 2:
        raise InputError.at(path, f"{kp}.squares", sq, "[columns, rows] of the ChArUco pattern's squares")
    squares = (
        whole(sq[0], path, f"{kp}.squares[0]", lo=3, hi=100),
        whole(sq[1], path, f"{kp}.squares[1]", lo=3, hi=100),
    )
    square = real(f["square_m"], path, f"{kp}.square_m", positive=True)
    marker = real(f["marker_m"], path, f"{kp}.marker_m", positive=True)
    if marker >= square:
        raise InputError.at(path, f"{kp}.marker_m", f["marker_m"], f"a marker side < square_m ({square:g})")
    n = squares[0] * squares[1] // 2
    if "ids" in f and "first_id" in f:
        raise InputError.at(path, kp, sorted(f), "one of ids (listed) or first_id (consecutive), not both")
    if "ids" in f:
        v = f["ids"]
        if not isinstance(v, list) or len(v) != n:
            shown = f"{len(v)} ids" if isinstance(v, list) else v
            raise InputError.at(path, f"{kp}.ids", shown, f"{n} marker ids (one per white square)")
        ids = tuple(whole(x, path, f"{kp}.ids[{j}]", lo=0, hi=dict_size - 1) for j, x in enumerate(v))
        dup = sorted({x for x in ids if ids.count(x) > 1})
        if dup:
            raise InputError.at(path, f"{kp}.ids", dup[:5], "distinct ids (duplicate ids)")
    else:
        first = whole(f.get("first_id", k * n), path, f"{kp}.first_id", lo=0, hi=dict_size - 1)
        if first + n > dict_size:
            raise InputError.at(
                path,
                f"{kp}.first_id",
                first,
                f"at most {dict_size - n} ({n} markers in a dictionary of {dict_size})",
            )
        ids = tuple(range(first, first + n))
    pw, ph = squares[0] * square, squares[1] * square
    if "offset_m" in f:
        v = f["offset_m"]
        if not isinstance(v, list) or len(v) != 2:
            raise InputError.at(
                path, f"{kp}.offset_m", v, "[x, y] of the pattern's top-left corner on the face, metres"
            )
        offset = (
            real(v[0], path, f"{kp}.offset_m[0]", nonneg=True),
            real(v[1], path, f"{kp}.offset_m[1]", nonneg=True),
        )
    else:
        offset = (0.5 * (width - pw), 0.5 * (edge_m - ph))
    if offset[0] + pw > width + 1e-9 or offset[1] + ph > edge_m + 1e-9 or min(offset) < -1e-9:
        raise InputError.at(
            path,
            kp,
            f"pattern {pw:g} x {ph:g} m at {offset[0]:g}, {offset[1]:g}",
            f"a pattern inside its face of {width:g} x {edge_m:g} m (width_m x edge_m)",
        )
    name = f.get("name", ("left", "right")[k])
    if not isinstance(name, str) or not name:
        raise InputError.at(path, f"{kp}.name", name, "a non-empty string")
    return MarkerFace(name, width, squares, square, marker, ids, offset)


def default_target() -> MarkerTarget:
    """The default V: two 0.5 x 0.6 m faces at 90 degrees, 4 x 5 squares of 110 mm with
    80 mm DICT_4X4_50 markers (ids 0-9 and 10-19); each face fits on an A1 sheet, and a
    640 x 480 camera with a 63 degree field of view reads its markers up to about 2.5 m."""
    faces = tuple(
        MarkerFace(name, 0.5, (4, 5), 0.11, 0.08, tuple(range(10 * k, 10 * k + 10)), (0.03, 0.025))
        for k, name in enumerate(("left", "right"))
    )
    return MarkerTarget("V target", "DICT_4X4_50", 90.0, 0.6, "concave", (faces[0], faces[1]))


def targets_text(target: MarkerTarget) -> str:
    """The targets file of a target (docs/formats/targets.md)."""
    lines = [
        "# rigcal targets file (docs/formats/targets.md)",
        f"schema_version: {TARGETS_SCHEMA_VERSION}",
        f"name: {target.name}",
        f"dictionary: {target.dictionary}",
        f"corner: {target.corner}          # concave: the V opens towards the sensors",
        f"angle_deg: {target.angle_deg:g}          # between the faces",
        f"edge_m: {target.edge_m:g}             # the common edge (both faces' height)",
        "faces:                  # left, right as seen from the front",
    ]
    for f in target.faces:
        ids = list(f.ids)
        id_text = f"first_id: {ids[0]}" if ids == list(range(ids[0], ids[0] + len(ids))) else f"ids: {ids}"
        lines += [
            f"  - name: {f.name}",
            f"    width_m: {f.width_m:g}",
            f"    squares: [{f.squares[0]}, {f.squares[1]}]",
            f"    square_m: {f.square_m:g}",
            f"    marker_m: {f.marker_m:g}",
            f"    {id_text}",
            f"    offset_m: [{f.offset_m[0]:g}, {f.offset_m[1]:g}]",
        ]
    return "\n".join(lines) + "\n"


def charuco_board(target: MarkerTarget, k: int) -> Any:
    """OpenCV's ChArUco board of face k (its pattern frame)."""
    import cv2

    f = target.faces[k]
    d = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, target.dictionary))
    return cv2.aruco.CharucoBoard(f.squares, f.square_m, f.marker_m, d, np.array(f.ids, dtype=np.int32))


def face_image(target: MarkerTarget, k: int, px_per_m: float) -> NDArray[np.uint8]:
    """(H, W) uint8 face k as printed: white, its pattern at its offset, ``px_per_m``
    pixels per metre (a pixel's edge at 0, its centre at 0.5 px)."""
    f = target.faces[k]
    W, H = round(f.width_m * px_per_m), round(target.edge_m * px_per_m)
    img = np.full((H, W), 255, dtype=np.uint8)
    pw, ph = round(f.squares[0] * f.square_m * px_per_m), round(f.squares[1] * f.square_m * px_per_m)
    x0, y0 = round(f.offset_m[0] * px_per_m), round(f.offset_m[1] * px_per_m)
    pattern = charuco_board(target, k).generateImage((pw, ph), marginSize=0, borderBits=1)
    img[y0 : y0 + ph, x0 : x0 + pw] = pattern
    return img
