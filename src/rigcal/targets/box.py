"""The box calibration target: a thin rectangular box at the height of the scan plane.

Paper Section II, Fig. 2: the laser's scan plane cuts the box's wide face (a straight
segment in the scan) and the user picks that face's two ends in the scan and in the image.

Box frame (``box``): origin at the box's centre, x along its depth pointing *away* from the
face the laser sees, y along its width, z up. The seen ("front") face is therefore the
plane x = -depth/2, facing -x. A placement in the laser frame is ``(x_m, y_m, yaw_rad)``:
the box centre in the laser's scan plane and the angle of the box's x axis from the laser's
+x (counter-clockwise). The box is centred on the scan plane, so its z extent is
``+/- height_m / 2`` in both frames.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rigcal.arrays import FloatArray

# Face names, in the order of BoxTarget.faces().
FACE_NAMES = ("front", "back", "right", "left", "bottom", "top")
# Index of the front face among BoxTarget.footprint_segments().
FRONT_FACE_SEGMENT = 3


@dataclass(frozen=True)
class BoxTarget:
    """A thin rectangular box target.

    Attributes:
        width_m: length of the face the laser sees (the distance between the two box ends).
        depth_m: extent perpendicular to that face.
        height_m: vertical extent, centred on the laser's scan plane z = 0.
    """

    width_m: float = 0.6
    depth_m: float = 0.15
    height_m: float = 0.08

    def __post_init__(self) -> None:
        for name in ("width_m", "depth_m", "height_m"):
            if not getattr(self, name) > 0:
                raise ValueError(f"BoxTarget.{name} must be > 0, got {getattr(self, name)!r}")

    def footprint(self, x_m: float, y_m: float, yaw_rad: float) -> FloatArray:
        """The box's outline in the scan plane.

        Returns:
            (4, 2) corners in the laser frame, metres, counter-clockwise seen from above,
            starting with the front face's right-hand end (box y = -width/2): front-right,
            back-right, back-left, front-left. Corners 3 and 0 bound the front face.
        """
        hd, hw = 0.5 * self.depth_m, 0.5 * self.width_m
        local = np.array([[-hd, -hw], [hd, -hw], [hd, hw], [-hd, hw]])
        return _to_laser_2d(local, x_m, y_m, yaw_rad)

    def footprint_segments(self, x_m: float, y_m: float, yaw_rad: float) -> FloatArray:
        """The four sides of :meth:`footprint` as segments for 2D ray casting.

        Returns:
            (4, 2, 2) segments ``[start, end]`` in the laser frame, metres; the last one,
            from front-left to front-right, is the front face.
        """
        c = self.footprint(x_m, y_m, yaw_rad)
        return np.stack([c, np.roll(c, -1, axis=0)], axis=1)

    def faces(self, x_m: float, y_m: float, yaw_rad: float) -> FloatArray:
        """The six faces as rectangles, for rendering.

        Returns:
            (6, 4, 3) corners in the laser frame, metres, faces in the order of
            :data:`FACE_NAMES`. Each face's corners go around the rectangle, so that corner 0
            and the edges ``c1 - c0`` and ``c3 - c0`` parameterise it.
        """
        hd, hw, hh = 0.5 * self.depth_m, 0.5 * self.width_m, 0.5 * self.height_m
        v = np.array(
            [
                [[-hd, -hw, -hh], [-hd, hw, -hh], [-hd, hw, hh], [-hd, -hw, hh]],  # front (x = -d/2)
                [[hd, -hw, -hh], [hd, hw, -hh], [hd, hw, hh], [hd, -hw, hh]],  # back
                [[-hd, -hw, -hh], [hd, -hw, -hh], [hd, -hw, hh], [-hd, -hw, hh]],  # right (y = -w/2)
                [[-hd, hw, -hh], [hd, hw, -hh], [hd, hw, hh], [-hd, hw, hh]],  # left
                [[-hd, -hw, -hh], [hd, -hw, -hh], [hd, hw, -hh], [-hd, hw, -hh]],  # bottom
                [[-hd, -hw, hh], [hd, -hw, hh], [hd, hw, hh], [-hd, hw, hh]],  # top
            ]
        )
        xy = _to_laser_2d(v[..., :2].reshape(-1, 2), x_m, y_m, yaw_rad).reshape(6, 4, 2)
        return np.concatenate([xy, v[..., 2:]], axis=-1)

    def front_ends(self, x_m: float, y_m: float, yaw_rad: float) -> FloatArray:
        """The two ends of the face towards the scanner, at laser height (the picked box ends).

        Returns:
            (2, 2) points in the laser frame's plane z = 0, metres: the end at box
            y = -width/2, then the end at y = +width/2. Seen from the front, the first is
            the right-hand end; a picking file orders the ends by beam angle, which for a
            face seen from the front is the same order.
        """
        c = self.footprint(x_m, y_m, yaw_rad)
        return np.array([c[0], c[3]])

    def placement_for_face(self, face_centre_xy: FloatArray, yaw_rad: float) -> tuple[float, float, float]:
        """The placement ``(x_m, y_m, yaw_rad)`` that puts the front face's centre at a point.

        Args:
            face_centre_xy: (2,) laser frame, metres.
            yaw_rad: the box's yaw; its front face's outward normal is -(cos yaw, sin yaw).
        """
        centre = np.asarray(face_centre_xy, dtype=float) + 0.5 * self.depth_m * np.array(
            [np.cos(yaw_rad), np.sin(yaw_rad)]
        )
        return float(centre[0]), float(centre[1]), float(yaw_rad)


def _to_laser_2d(local_xy: FloatArray, x_m: float, y_m: float, yaw_rad: float) -> FloatArray:
    """Box-frame (N, 2) points to the laser frame, for a placement (x, y, yaw)."""
    c, s = np.cos(yaw_rad), np.sin(yaw_rad)
    R = np.array([[c, -s], [s, c]])
    out: FloatArray = local_xy @ R.T + np.array([x_m, y_m])
    return out
