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

The target is rigid, so its pose is read from every corner of every face at once: one PnP
through the full lens model over all the corners found, each placed in the target frame
by the targets file's geometry (:meth:`rigcal.targets.marker.MarkerTarget.T_target_face`),
with its covariance from the corners' reprojection Jacobian
(:func:`rigcal.calib.board.session.points_pose`). Both faces' planes follow from that one
pose, so a capture in which one face shows only a few corners (or none) still gives both,
and the corners of the two faces, far apart and on two planes, fix the pose better than
either face alone. A face with corners enough for its own pose is checked against the
target's: a face whose own pose disagrees (beyond FACE_GATE_CHI2 under the two poses'
covariances; a folded angle other than the file's, a face that slipped, a misread
marker) is named in :attr:`TargetView.disagreement`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from rigcal.arrays import MAD_TO_SIGMA, FloatArray
from rigcal.calib.board.session import points_pose
from rigcal.camera import Camera
from rigcal.geometry import inv_T
from rigcal.targets.marker import MarkerTarget, charuco_board

# The target's pose is read when this many ChArUco corners are found over its faces (PnP
# on fewer is fragile), not all on one row or one column of one face; a face gets a pose
# of its own (for the consistency check) from as many of its own.
MIN_FACE_CORNERS = 6
# A face's own pose disagrees with the target's beyond this chi-square (6 dof, 99.9 %).
FACE_GATE_CHI2 = 22.46
OUTLIER_SIGMAS = 4.0
OUTLIER_FLOOR_PX = 1.0


@dataclass(frozen=True)
class FaceView:
    """One face's corners as the camera reads them.

    Attributes:
        face: the face's index on the target.
        corner_ids: (K,) the ChArUco corners found (OpenCV's corner ids) and kept.
        corners_px: (K, 2) where, pixel-centre convention.
        T_cam_face: (4, 4) the face's own pose (its frame, :mod:`rigcal.targets.marker`, in
            the camera frame) from its corners alone, None with too few for one.
        pose_cov: (6, 6) its covariance over [w, dt] for ``corner_sigma_px``, or None.
        rms_px: RMS reprojection error of the corners under the target's pose.
        own_rms_px: RMS reprojection error of the corners kept by the face's own pose.
        own_corners: how many corners the face's own pose kept (0 without one).
    """

    face: int
    corner_ids: NDArray[np.int64]
    corners_px: FloatArray
    T_cam_face: FloatArray | None
    pose_cov: FloatArray | None
    rms_px: float
    own_rms_px: float = float("nan")
    own_corners: int = 0


@dataclass(frozen=True)
class TargetView:
    """What an image shows of the target.

    Attributes:
        faces: per face, its corners, or None when none of them was found.
        markers_seen: per face, how many of its markers were found.
        foreign_ids: ids of markers found that belong to no face of the target.
        T_cam_target: (4, 4) the target's pose from every corner of every face, None when
            too few were found.
        pose_cov: (6, 6) its covariance over [w, dt] (left perturbation, the rotation about
            the target's origin) for ``corner_sigma_px``, or None.
        rms_px: RMS reprojection error of all the corners under that pose.
        disagreement: why a face's own pose disagrees with the target's ("" when none does).
    """

    faces: tuple[FaceView | None, FaceView | None]
    markers_seen: tuple[int, int]
    foreign_ids: tuple[int, ...]
    T_cam_target: FloatArray | None = None
    pose_cov: FloatArray | None = None
    rms_px: float = float("nan")
    disagreement: str = ""

    @property
    def n_corners(self) -> int:
        """ChArUco corners the target's pose was read from."""
        return sum(len(f.corner_ids) for f in self.faces if f is not None)

    def T_cam_face(self, target: MarkerTarget, k: int) -> FloatArray:
        """(4, 4) face k's frame in the camera frame, from the target's pose."""
        assert self.T_cam_target is not None
        out: FloatArray = self.T_cam_target @ target.T_target_face(k)
        return out

    def missing(self, target: MarkerTarget) -> str:
        """Why the target's pose was not read, for a capture's verdict ("" when it was)."""
        if self.T_cam_target is not None:
            return ""
        seen = ", ".join(
            f"face {f.name}: {n} of its {f.n_markers} markers"
            for f, n in zip(target.faces, self.markers_seen, strict=True)
        )
        return (
            f"{self.n_corners} ChArUco corners over both faces, fewer than {MIN_FACE_CORNERS} "
            f"or all on one row or column ({seen} seen)"
        )


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
        view, n_markers = _face_corners(grey, camera, target, k, params, corner_sigma_px)
        faces.append(view)
        seen.append(n_markers)
    pair = (faces[0], faces[1])
    out = TargetView(pair, (seen[0], seen[1]), foreign)
    pose = target_pose(camera, target, pair, corner_sigma_px)
    if pose is None:
        return out
    T, cov, rms, kept = pose
    return replace(
        out,
        faces=kept,
        T_cam_target=T,
        pose_cov=cov,
        rms_px=rms,
        disagreement=face_disagreement(target, kept, T, cov),
    )


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


def _face_corners(
    grey: NDArray[np.uint8], camera: Camera, target: MarkerTarget, k: int, params: Any, corner_sigma_px: float
) -> tuple[FaceView | None, int]:
    """Face k's corners (None when none is read), with its own pose when they are enough
    (:func:`_own_pose`), and how many of its markers were found. The ChArUco detector
    finds the face's markers, looks again for missed ones where the found ones predict
    them (``tryRefineMarkers``), interpolates the corners from as few as one marker and
    refines them on the image."""
    import cv2

    cparams = cv2.aruco.CharucoParameters()
    cparams.minMarkers = 1
    cparams.tryRefineMarkers = True
    detector = cv2.aruco.CharucoDetector(charuco_board(target, k), cparams, params)
    ch_corners, ch_ids, _, marker_ids = detector.detectBoard(grey)
    mine = (
        0 if marker_ids is None else int(np.isin(np.asarray(marker_ids).ravel(), target.faces[k].ids).sum())
    )
    if ch_ids is None or len(ch_ids) == 0:
        return None, mine
    cid = ch_ids.ravel().astype(np.int64)
    px = ch_corners.reshape(-1, 2).astype(float)
    own = _own_pose(camera, target.faces[k].corner_points[cid], px, corner_sigma_px)
    if own is None:
        return FaceView(k, cid, px, None, None, float("nan")), mine
    return FaceView(k, cid, px, own[0], own[1], float("nan"), own[2], int(own[3].sum())), mine


def _spans(P: FloatArray) -> bool:
    """Whether points of one face (its frame) are not all on one row or one column."""
    return len(np.unique(P[:, 0])) >= 2 and len(np.unique(P[:, 1])) >= 2


def _own_pose(
    camera: Camera, P: FloatArray, px: FloatArray, corner_sigma_px: float
) -> tuple[FloatArray, FloatArray, float, NDArray[np.bool_]] | None:
    """A face's own pose from its corners (:func:`robust_pose`), when there are
    MIN_FACE_CORNERS of them spanning two rows and two columns (else None)."""

    def enough(keep: NDArray[np.bool_]) -> bool:
        return bool(keep.sum() >= MIN_FACE_CORNERS) and _spans(P[keep])

    return robust_pose(camera, P, px, corner_sigma_px, enough)


def robust_pose(
    camera: Camera,
    P: FloatArray,
    px: FloatArray,
    corner_sigma_px: float,
    enough: Callable[[NDArray[np.bool_]], bool],
    T_init: FloatArray | None = None,
) -> tuple[FloatArray, FloatArray, float, NDArray[np.bool_]] | None:
    """The pose of points ``P`` seen at ``px`` by PnP (:func:`points_pose`), its
    covariance, the RMS reprojection error of the corners kept and which were kept; None
    when the corners (all, or those kept) are not ``enough``.

    A corner refined onto the wrong saddle (blur, a marker misread) is dropped when it
    lies farther off the pose than OUTLIER_SIGMAS robust sigmas (at least
    OUTLIER_FLOOR_PX), and the pose is solved again without it.
    """
    keep = np.ones(len(P), dtype=bool)
    if not enough(keep):
        return None
    T, cov, rms = points_pose(camera, P, px, corner_sigma_px, T_init)
    err = np.linalg.norm(camera.project(P @ T[:3, :3].T + T[:3, 3]) - px, axis=1)
    keep = err <= max(OUTLIER_FLOOR_PX, OUTLIER_SIGMAS * MAD_TO_SIGMA * float(np.median(err)))
    if not keep.all():
        if not enough(keep):
            return None
        T, cov, rms = points_pose(camera, P[keep], px[keep], corner_sigma_px, T)
    return T, cov, rms, keep


def target_pose(
    camera: Camera,
    target: MarkerTarget,
    faces: tuple[FaceView | None, FaceView | None],
    corner_sigma_px: float,
) -> tuple[FloatArray, FloatArray, float, tuple[FaceView | None, FaceView | None]] | None:
    """T_cam_target by one PnP over every face's corners in the target frame
    (:func:`robust_pose`), its (6, 6) covariance, the RMS reprojection error and the faces
    with the corners it kept (a face keeps its own pose, from all its corners, even when
    the target's pose keeps none of them: the disagreement check needs it); None with
    fewer than MIN_FACE_CORNERS corners, or all of them on one row or column of one face.
    """
    parts = [f for f in faces if f is not None]
    if not parts:
        return None
    P_face = [target.faces[f.face].corner_points[f.corner_ids] for f in parts]
    which = np.concatenate([np.full(len(f.corner_ids), f.face) for f in parts])
    P = np.vstack(
        [
            p @ target.T_target_face(f.face)[:3, :3].T + target.T_target_face(f.face)[:3, 3]
            for f, p in zip(parts, P_face, strict=True)
        ]
    )
    Pf = np.vstack(P_face)
    px = np.vstack([f.corners_px for f in parts])

    def enough(keep: NDArray[np.bool_]) -> bool:
        if keep.sum() < MIN_FACE_CORNERS:
            return False
        on = [k for k in range(2) if (keep & (which == k)).any()]
        return len(on) == 2 or bool(_spans(Pf[keep & (which == on[0])]))

    # From the own pose of the face with most corners, when one has one (a non-planar DLT
    # start on few noisy corners can be poor).
    owned = [f for f in parts if f.T_cam_face is not None]
    T0 = None
    if owned:
        best = max(owned, key=lambda f: len(f.corner_ids))
        assert best.T_cam_face is not None
        T0 = best.T_cam_face @ inv_T(target.T_target_face(best.face))
    found = robust_pose(camera, P, px, corner_sigma_px, enough, T0)
    if found is None:
        return None
    T, cov, rms, keep = found
    err = np.linalg.norm(camera.project(P @ T[:3, :3].T + T[:3, 3]) - px, axis=1)
    out: list[FaceView | None] = [None, None]
    for f in parts:
        rows = which == f.face
        k_rows = keep[rows]
        mine = keep & rows
        face_rms = float(np.sqrt(np.mean(err[mine] ** 2))) if mine.any() else float("nan")
        out[f.face] = replace(
            f, corner_ids=f.corner_ids[k_rows], corners_px=f.corners_px[k_rows], rms_px=face_rms
        )
    return T, cov, rms, (out[0], out[1])


def face_disagreement(
    target: MarkerTarget,
    faces: tuple[FaceView | None, FaceView | None],
    T_cam_target: FloatArray,
    pose_cov: FloatArray,
) -> str:
    """Why a face's own pose disagrees with the target's ("" when none does): the
    difference [w, dt] between the face's own pose and the target's pose of that face,
    both about the face's origin, weighed by the sum of their covariances (the target's
    moved to the face's origin; the two share the face's corners, so the sum is a bound
    that errs towards agreement), beyond FACE_GATE_CHI2."""
    from rigcal.geometry import R_to_rotvec

    out = []
    for f in faces:
        if f is None or f.T_cam_face is None or f.pose_cov is None:
            continue
        T_pred = T_cam_target @ target.T_target_face(f.face)
        w = R_to_rotvec(f.T_cam_face[:3, :3] @ T_pred[:3, :3].T)
        dt = f.T_cam_face[:3, 3] - T_pred[:3, 3]
        # A rotation w about the target's origin o moves the face's origin b by w x (b - o).
        arm = T_pred[:3, 3] - T_cam_target[:3, 3]
        A = np.eye(6)
        A[3:, :3] = -_skew(arm)
        C = A @ pose_cov @ A.T + f.pose_cov
        d = np.concatenate([w, dt])
        chi2 = float(d @ np.linalg.solve(C, d))
        if chi2 > FACE_GATE_CHI2:
            out.append(
                f"face {target.faces[f.face].name}'s own pose is {np.degrees(np.linalg.norm(w)):.2f} deg / "
                f"{1000 * np.linalg.norm(dt):.1f} mm off the target's (chi-square {chi2:.0f} > "
                f"{FACE_GATE_CHI2:g}): check the targets file's angle and the face's mounting"
            )
    return "; ".join(out)


def _skew(v: FloatArray) -> FloatArray:
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])
