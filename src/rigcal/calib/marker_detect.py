"""Reading the marker target's faces in an image: ChArUco corners, then each face's pose.

The markers are found (OpenCV's ``ArucoDetector`` with the target's dictionary); those
whose ids belong to no face are counted and ignored (another target in view, a marker of
another project on the wall). Each face's ChArUco detector (``CharucoDetector``) then
finds its markers, looks again for those it missed where the found ones predict them,
and gives the face's ChArUco corners: the saddle points between the chessboard squares,
interpolated from the markers and refined to sub-pixel on the image. A saddle point is
where two dark and two light squares meet, so blur and exposure move its edges outwards
and inwards alike and it stays put, unlike a marker's outer corner, which a detector
finds where the black border's edge crosses a threshold: blur, exposure and the edge's
sampling move that edge towards the brighter side, i.e. the marker shrinks or grows by a
fraction of a pixel in every image the same way, a bias that does not average out over
captures. The benchmark (benchmarks/marker_benchmark.py) measures both.

Each face's pose comes from its corners by PnP through the full lens model, with its
covariance from the corners' reprojection Jacobian
(:func:`rigcal.calib.board_session.points_pose`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from rigcal.calib.board_session import points_pose
from rigcal.camera import Camera
from rigcal.targets.marker import MarkerTarget, charuco_board

FloatArray = NDArray[np.float64]

# A face is read when this many of its ChArUco corners are found (PnP on fewer is
# fragile), spread over at least two rows and two columns.
MIN_FACE_CORNERS = 6
OUTLIER_SIGMAS = 4.0
OUTLIER_FLOOR_PX = 1.0


@dataclass(frozen=True)
class FaceView:
    """One face as the camera reads it.

    Attributes:
        face: the face's index on the target.
        corner_ids: (K,) the ChArUco corners found (OpenCV's corner ids).
        corners_px: (K, 2) where, pixel-centre convention.
        T_cam_face: (4, 4) the face's frame (:mod:`rigcal.targets.marker`) in the camera frame.
        pose_cov: (6, 6) its covariance over [w, dt] for ``corner_sigma_px``.
        rms_px: RMS reprojection error of the corners under the pose.
    """

    face: int
    corner_ids: NDArray[np.int64]
    corners_px: FloatArray
    T_cam_face: FloatArray
    pose_cov: FloatArray
    rms_px: float


@dataclass(frozen=True)
class TargetView:
    """What an image shows of the target.

    Attributes:
        faces: per face, its view, or None when too few of its corners were found.
        markers_seen: per face, how many of its markers were found.
        foreign_ids: ids of markers found that belong to no face of the target.
    """

    faces: tuple[FaceView | None, FaceView | None]
    markers_seen: tuple[int, int]
    foreign_ids: tuple[int, ...]

    def missing(self, target: MarkerTarget) -> str:
        """Why a face is missing, for a capture's verdict ("" when both are read)."""
        out = []
        for k, f in enumerate(self.faces):
            if f is None:
                out.append(
                    f"face {target.faces[k].name}: {self.markers_seen[k]} of its {target.faces[k].n_markers} "
                    f"markers seen, fewer than {MIN_FACE_CORNERS} ChArUco corners"
                )
        return "; ".join(out)


def detect_target(
    image: NDArray[np.uint8], camera: Camera, target: MarkerTarget, corner_sigma_px: float = 0.3
) -> TargetView:
    """Find the target's markers and corners in ``image`` and each face's pose.

    Args:
        image: (H, W) or (H, W, 3) uint8 image (BGR).
        camera: the camera (for the poses).
        target: the target.
        corner_sigma_px: the corners' noise the poses' covariances are computed with.
    """
    import cv2

    grey = np.asarray(image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_BGR2GRAY), dtype=np.uint8)
    params = detector_parameters()
    dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, target.dictionary))
    _, ids, _ = cv2.aruco.ArucoDetector(dictionary, params).detectMarkers(grey)
    ids = np.zeros(0, dtype=np.int64) if ids is None else np.asarray(ids, dtype=np.int64).ravel()
    foreign = tuple(sorted(int(i) for i in ids if int(i) not in target.all_ids))
    faces: list[FaceView | None] = []
    seen = []
    for k in range(2):
        view, n_markers = _face_view(grey, camera, target, k, params, corner_sigma_px)
        faces.append(view)
        seen.append(n_markers)
    return TargetView((faces[0], faces[1]), (seen[0], seen[1]), foreign)


def detector_parameters() -> Any:
    """OpenCV's marker detector settings: sub-pixel marker corners, 8 px per marker cell
    when reading the bits (a small or oblique marker's bits are read from more samples),
    a looser polygon fit and larger threshold windows (blurred edges), markers down to 1 %
    of the image's size in perimeter."""
    import cv2

    params = cv2.aruco.DetectorParameters()
    params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    params.perspectiveRemovePixelPerCell = 8
    params.polygonalApproxAccuracyRate = 0.05
    params.adaptiveThreshWinSizeMax = 53
    params.minMarkerPerimeterRate = 0.01
    return params


def _face_view(
    grey: NDArray[np.uint8], camera: Camera, target: MarkerTarget, k: int, params: Any, corner_sigma_px: float
) -> tuple[FaceView | None, int]:
    """Face k's view (None when too few corners are read) and how many of its markers
    were found. The ChArUco detector finds the face's markers, looks again for missed ones
    where the found ones predict them (``tryRefineMarkers``), interpolates the corners
    from as few as one marker and refines them on the image."""
    import cv2

    cparams = cv2.aruco.CharucoParameters()
    cparams.minMarkers = 1
    cparams.tryRefineMarkers = True
    detector = cv2.aruco.CharucoDetector(charuco_board(target, k), cparams, params)
    ch_corners, ch_ids, _, marker_ids = detector.detectBoard(grey)
    mine = (
        0 if marker_ids is None else int(np.isin(np.asarray(marker_ids).ravel(), target.faces[k].ids).sum())
    )
    if ch_ids is None or len(ch_ids) < MIN_FACE_CORNERS:
        return None, mine
    cid = ch_ids.ravel().astype(np.int64)
    px = ch_corners.reshape(-1, 2).astype(float)
    P = target.faces[k].corner_points[cid]
    # Corners on one row or one column (collinear) do not fix a pose.
    if len(np.unique(P[:, 0])) < 2 or len(np.unique(P[:, 1])) < 2:
        return None, mine
    T, cov, rms = points_pose(camera, P, px, corner_sigma_px)
    # A corner refined onto the wrong saddle (blur, a marker misread) is dropped when it
    # lies farther off the pose than OUTLIER_SIGMAS robust sigmas (at least
    # OUTLIER_FLOOR_PX), and the pose is solved again without it.
    err = np.linalg.norm(camera.project(P @ T[:3, :3].T + T[:3, 3]) - px, axis=1)
    keep = err <= max(OUTLIER_FLOOR_PX, OUTLIER_SIGMAS * 1.4826 * float(np.median(err)))
    if not keep.all():
        cid, px, P = cid[keep], px[keep], P[keep]
        if len(cid) < MIN_FACE_CORNERS or len(np.unique(P[:, 0])) < 2 or len(np.unique(P[:, 1])) < 2:
            return None, mine
        T, cov, rms = points_pose(camera, P, px, corner_sigma_px)
    return FaceView(k, cid, px, T, cov, rms), mine
