"""The targetless check's edge term: the scans' depth discontinuities and their offsets
from the images' edges."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from rigcal.camera import Camera
from rigcal.drift.edges import (
    REPAIR_GATE_PX,
    EdgeImages,
    Edges,
    band_points,
    corner_clusters,
    edge_residuals,
    scan_discontinuities,
)
from rigcal.geometry import make_T, rotvec_to_R, se2
from rigcal.lines import extract_lines
from rigcal.scan import Scan
from rigcal.sim.box_session import default_T_cam_laser

STEP = math.radians(0.25)
K = np.array([[520.0, 0.0, 319.5], [0.0, 515.0, 239.5], [0.0, 0.0, 1.0]])
CAMERA = Camera.from_opencv(K, [], 640, 480)


def cast(segments: list[tuple[tuple[float, float], tuple[float, float]]], rng: np.random.Generator) -> Scan:
    """A scan of the segments from the origin, 0.25 deg steps over +-60 deg, 3 mm noise;
    no return (range 0) where no segment is hit."""
    angles = np.arange(-60.0, 60.0, 0.25)
    out = np.zeros(len(angles))
    for n, a in enumerate(np.radians(angles)):
        d = np.array([math.cos(a), math.sin(a)])
        best = np.inf
        for p, q in segments:
            p_, e = np.array(p), np.array(q) - np.array(p)
            den = d[0] * -e[1] - d[1] * -e[0]
            if abs(den) < 1e-12:
                continue
            t = (p_[0] * -e[1] - p_[1] * -e[0]) / den
            s = (d[0] * p_[1] - d[1] * p_[0]) / den
            if t > 0 and 0 <= s <= 1:
                best = min(best, t)
        out[n] = best + rng.normal(0, 0.003) if np.isfinite(best) else 0.0
    return Scan.from_uniform(math.radians(-60.0), STEP, out, 0.05, 30.0)


def test_corners_and_occluding_ends_are_found_where_the_world_has_edges():
    rng = np.random.default_rng(3)
    # A wall ahead (x = 4) meeting a wall on the left (y = 1) at a corner, and a square
    # pillar 0.3 m wide in front of the wall ahead.
    pillar = np.array([[2.35, -1.65], [2.65, -1.65], [2.65, -1.35], [2.35, -1.35]])
    walls = [((4.0, -3.0), (4.0, 1.0)), ((4.0, 1.0), (1.0, 1.0))]
    walls += [(tuple(pillar[k]), tuple(pillar[(k + 1) % 4])) for k in range(4)]
    scan = cast(walls, rng)  # type: ignore[arg-type]
    feet = scan_discontinuities(scan, extract_lines(scan))
    truth = np.array([[4.0, 1.0], *pillar])
    # Every foot is at one of the world's vertical edges (a wall's end into nothing is not).
    d = np.linalg.norm(feet[:, None, :] - truth[None], axis=2)
    assert d.min(axis=1).max() < 0.012
    # The corner of the walls (lines' intersection): to millimetres.
    assert d[:, 0].min() < 0.005
    # The pillar's near corner (two faces meet) and its two silhouette edges seen from
    # the laser (occluding line ends: within half a beam step, 6 mm at 2.7 m); its far
    # corner (2.65, -1.65) is hidden.
    assert d[:, 4].min() < 0.005
    assert d[:, 1].min() < 0.012
    assert d[:, 3].min() < 0.012


def render_edge(foot: np.ndarray, T: np.ndarray) -> np.ndarray:
    """(480, 640) uint8: a vertical edge through the foot (laser frame), dark to its left
    in the image, bright to its right (4 x 4 samples a pixel), with blur and noise."""
    X = np.array([[*foot, -1.0], [*foot, 1.0]]) @ T[:3, :3].T + T[:3, 3]
    n = np.cross(X[0], X[1])
    ss = 4
    v, u = np.mgrid[0 : 480 * ss, 0 : 640 * ss]
    rays = (
        np.stack([(u + 0.5) / ss - 0.5, (v + 0.5) / ss - 0.5, np.ones(u.shape)], axis=-1) @ np.linalg.inv(K).T
    )
    side = (rays @ n > 0).astype(np.float32)
    img = cv2.resize(90.0 + 70.0 * side, (640, 480), interpolation=cv2.INTER_AREA)
    img = cv2.GaussianBlur(img, (0, 0), 0.7) + np.random.default_rng(1).normal(0, 1.0, img.shape)
    return np.clip(img, 0, 255).astype(np.uint8)


@pytest.fixture(scope="module")
def scene():
    T = default_T_cam_laser()
    feet = np.array([[3.0, 0.2], [2.0, -0.5], [5.0, 1.1], [2.5, 0.6]])
    gray_of = {k: render_edge(f, T) for k, f in enumerate(feet)}
    n = len(feet)
    depth = np.linalg.norm(feet, axis=1)
    edges = Edges(band_points(feet), np.arange(n), np.zeros(n, np.int64), np.arange(n), depth)
    images = EdgeImages(gray_of, edges.img, 1.2, (0.0, 480.0))
    return T, edges, images


def test_the_right_T_puts_the_projections_on_the_edges(scene):
    T, edges, images = scene
    r, _, usable, _ = edge_residuals(CAMERA, T, edges, images, 6.0)
    assert usable.sum() >= 8
    # Bilinear sampling locks a peak a little towards pixel centres (up to about 0.2 px,
    # as many ways as the other: it averages out over edges at all sub-pixel phases).
    assert np.abs(r[usable]).max() < 0.25
    assert np.sqrt(np.mean(r[usable] ** 2)) < 0.1


@pytest.mark.parametrize("axis", range(6))
def test_the_offsets_move_as_their_derivatives_say(scene, axis):
    """r(T Exp(xi)) - r(T) against J xi, for a change of 0.2 deg or 2 cm along one axis;
    laser z (a shift along the edges) moves nothing."""
    T, edges, images = scene
    r0, J, u0, _ = edge_residuals(CAMERA, T, edges, images, 8.0)
    xi = np.zeros(6)
    xi[axis] = 0.004 if axis < 3 else 0.02
    r1, _, u1, _ = edge_residuals(CAMERA, T @ make_T(rotvec_to_R(xi[:3]), xi[3:]), edges, images, 8.0)
    ok = u0 & u1
    assert ok.sum() >= 6
    pred = J[ok] @ xi
    if axis == 5:
        assert np.abs(pred).max() < 0.2
    elif axis != 1:  # a pitch moves a vertical edge mostly along itself
        assert np.abs(pred).max() > 0.5
    np.testing.assert_allclose(r1[ok] - r0[ok], pred, atol=0.1 + 0.1 * np.abs(pred).max())


def test_no_edge_in_the_window_is_not_usable(scene):
    T, edges, images = scene
    far = T @ make_T(np.eye(3), [0.0, 0.15, 0.0])  # 15 cm: the edges 15-40 px away
    _, _, usable, _ = edge_residuals(CAMERA, far, edges, images, 6.0)
    assert not usable.any()


def test_paired_once_the_bands_keep_their_edges_as_the_estimate_moves(scene):
    """Paired at the start estimate, a band is re-measured only within the gate of its
    first edge: far from the start its residual is the offset from the projection to that
    same edge (not to another edge the window would find, nor none)."""
    T, edges, images = scene
    _, _, u0, found = edge_residuals(CAMERA, T, edges, images, 6.0)
    far = T @ make_T(np.eye(3), [0.0, 0.15, 0.0])
    r1, _, u1, found1 = edge_residuals(CAMERA, far, edges, images, 6.0, anchor=found)
    ok = u0 & u1
    assert ok.sum() >= 8
    # The offset from the far projection to the first pairing's edge, band by band.
    E, B, K, _ = edges.X.shape
    mid = edges.X[:, :, K // 2].reshape(-1, 3)
    q = CAMERA.project(mid @ far[:3, :3].T + far[:3, 3]).reshape(E, B, 2)
    top = CAMERA.project(edges.X[:, :, -1].reshape(-1, 3) @ far[:3, :3].T + far[:3, 3]).reshape(E, B, 2)
    bottom = CAMERA.project(edges.X[:, :, 0].reshape(-1, 3) @ far[:3, :3].T + far[:3, 3]).reshape(E, B, 2)
    d = top - bottom
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    nrm = np.stack([d[..., 1], -d[..., 0]], axis=-1)
    want = np.einsum("ebi,ebi->eb", found[:, :, K // 2] - q, nrm).ravel()
    assert np.abs(want[ok]).min() > 10.0  # far beyond the gate: no re-pairing could reach
    np.testing.assert_allclose(r1[ok], want[ok], atol=0.3)
    # Re-measured within the gate: the edge points stay where they were found.
    assert np.abs(found1 - found).max(axis=(2, 3)).reshape(-1)[ok].max() <= REPAIR_GATE_PX + 0.5


def test_a_band_off_its_edges_line_is_not_paired_nor_used_later():
    """Above 0.525 m the image's edge is 5 px aside of the true one (a texture edge
    beside the corner, a farther edge in the window): the top band finds it and
    disagrees with the two below, which agree with each other; it is left out at the
    first pairing and stays out when re-measured around its (absent) anchor. With only
    the top band and one other band usable, neither can be told right: both out."""
    T = default_T_cam_laser()
    foot = np.array([3.0, 0.2])
    aside = foot + np.array([0.0, 5.0 * np.linalg.norm(foot) / K[0, 0]])  # 5 px to one side
    v_cut = CAMERA.project(np.array([[*foot, 0.525]]) @ T[:3, :3].T + T[:3, 3])[0, 1]
    img = render_edge(foot, T)
    rows = np.arange(480) < v_cut  # image up is the laser's z up
    img[rows] = render_edge(aside, T)[rows]
    one = np.zeros(1, np.int64)
    edges = Edges(band_points(foot[None]), one, one, one, np.array([3.0]))
    images = EdgeImages({0: img}, edges.img, 1.2, (0.0, 480.0))
    r, _, usable, found = edge_residuals(CAMERA, T, edges, images, 8.0)
    assert usable.tolist() == [True, True, False]
    assert np.abs(r[:2]).max() < 0.3
    assert np.isnan(found[0, 2]).all()
    _, _, usable1, _ = edge_residuals(CAMERA, T, edges, images, 8.0, anchor=found)
    assert usable1.tolist() == [True, True, False]
    # The lowest band out of the image's rows: the two left disagree, and neither is used.
    images_top = EdgeImages({0: img}, edges.img, 1.2, (0.0, 200.0))  # bands 1 and 2 only
    _, _, usable2, found2 = edge_residuals(CAMERA, T, edges, images_top, 8.0)
    assert not usable2.any()
    assert np.isnan(found2).all()


def test_corner_observations_cluster_by_their_place_in_the_world():
    """Three corners seen from a moving, turning laser, each foot with 1 cm of noise and
    the odometry's pose slightly off: each corner's observations are one cluster."""
    rng = np.random.default_rng(5)
    corners = np.array([[3.0, 1.0], [3.3, 1.0], [6.0, -1.5]])
    feet_world, truth = [], []
    for k in range(30):
        pose = np.array([0.05 * k, 0.01 * k, 0.02 * k])
        P = se2(pose)
        seen = rng.permutation(3)[: rng.integers(1, 4)]
        local = (corners[seen] - P[:2, 2]) @ P[:2, :2]  # laser frame
        odo = se2(pose + rng.normal(0.0, [0.005, 0.005, 0.001]))
        feet_world.append((local + rng.normal(0.0, 0.01, local.shape)) @ odo[:2, :2].T + odo[:2, 2])
        truth.append(seen)
    labels = corner_clusters(np.concatenate(feet_world))
    truth_ = np.concatenate(truth)
    assert len(np.unique(labels)) == 3
    for c in range(3):
        assert len(np.unique(labels[truth_ == c])) == 1
    assert labels[0] == 0  # numbered by first appearance
    assert corner_clusters(np.zeros((0, 2))).shape == (0,)
