"""P3P (Lambda Twist) depths: ground truth, OpenCV agreement, degenerate and planar triples."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from rigcal.calib.box.horn import horn_batch
from rigcal.calib.box.p3p import P3PSolutions, p3p, p3p_poses
from rigcal.geometry import make_T, random_rotation, rotvec_to_R

PAIRS = ((0, 1), (0, 2), (1, 2))

# Camera looking along laser +x (the laser plane z = 0), pitched 5 deg down, as in test_ransac.
R_BASE = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])


def unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def random_triples(rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(bearings, world points, true depths), each (n, 3, 3) / (n, 3): points 2-6 m in front of the camera
    inside a 90 deg field of view, world frame at a random pose."""
    z = rng.uniform(2.0, 6.0, (n, 3))
    cam = np.stack([rng.uniform(-1.0, 1.0, (n, 3)) * z, rng.uniform(-1.0, 1.0, (n, 3)) * z, z], axis=2)
    R = np.stack([random_rotation(rng) for _ in range(n)])
    t = rng.uniform(-1.0, 1.0, (n, 3))
    world = np.einsum("kji,knj->kni", R, cam - t[:, None])  # cam = R world + t
    return unit(cam), world, np.linalg.norm(cam, axis=2)


def relative_residuals(bearings: np.ndarray, points: np.ndarray, sol: P3PSolutions) -> np.ndarray:
    """(K, 3) |lambda_i^2 + lambda_j^2 - 2 b_ij lambda_i lambda_j - |x_i - x_j|^2| per solution and pair,
    relative to the triple's largest squared distance."""
    y = unit(np.asarray(bearings, dtype=float).reshape(-1, 3, 3))[sol.triple]
    x = np.asarray(points, dtype=float).reshape(-1, 3, 3)[sol.triple]
    lam = sol.depths
    out = np.empty((len(lam), 3))
    for c, (i, j) in enumerate(PAIRS):
        b = np.einsum("ki,ki->k", y[:, i], y[:, j])
        lhs = lam[:, i] ** 2 + lam[:, j] ** 2 - 2.0 * b * lam[:, i] * lam[:, j]
        out[:, c] = np.abs(lhs - np.sum((x[:, i] - x[:, j]) ** 2, axis=1))
    scale = np.max([np.sum((x[:, i] - x[:, j]) ** 2, axis=1) for i, j in PAIRS], axis=0)
    return out / np.maximum(scale, np.finfo(float).tiny)[:, None]


def best_relative_depth_error(sol: P3PSolutions, true_depths: np.ndarray) -> np.ndarray:
    """(n,) per triple, the smallest max-relative depth error over its solutions (inf: no solution)."""
    err = np.full(len(true_depths), np.inf)
    rel = (np.abs(sol.depths - true_depths[sol.triple]) / true_depths[sol.triple]).max(axis=1)
    np.minimum.at(err, sol.triple, rel)
    return err


def assert_well_formed(sol: P3PSolutions, n: int) -> None:
    assert sol.triple.dtype == np.int64
    assert sol.depths.shape == (len(sol.triple), 3)
    assert np.isfinite(sol.depths).all()
    assert (sol.depths > 0).all()
    assert ((sol.triple >= 0) & (sol.triple < n)).all()
    assert np.bincount(sol.triple, minlength=n).max(initial=0) <= 4


def test_true_depths_are_among_the_solutions():
    rng = np.random.default_rng(0)
    y, x, true = random_triples(rng, 1000)
    sol = p3p(y, x)
    # Generic triples are well conditioned and the depths are polished by Gauss-Newton, so the true root is
    # found to ~1e-11; 1e-9 leaves margin while any other root of the quartic is off by O(1).
    assert best_relative_depth_error(sol, true).max() < 1e-9


def test_every_solution_satisfies_the_distance_equations():
    rng = np.random.default_rng(1)
    y, x, _ = random_triples(rng, 1000)
    sol = p3p(y, x)
    assert len(sol.triple) > 1000  # some triples have more than the true solution
    # Polished roots hold to rounding (~1e-15); a spurious root would miss by O(1).
    assert relative_residuals(y, x, sol).max() < 1e-10


def test_solutions_are_well_formed():
    rng = np.random.default_rng(2)
    y, x, _ = random_triples(rng, 1000)
    sol = p3p(y, x)
    assert_well_formed(sol, 1000)
    counts = np.bincount(sol.triple, minlength=1000)
    assert counts.min() >= 1  # the true solution always exists
    assert (counts >= 2).any()
    assert (counts == 4).any()
    assert (np.diff(sol.triple) >= 0).all()


def test_no_duplicate_solutions_within_a_triple():
    rng = np.random.default_rng(3)
    y, x, _ = random_triples(rng, 500)
    sol = p3p(y, x)
    for k in np.unique(sol.triple):
        d = sol.depths[sol.triple == k]
        gaps = np.abs(d[:, None] - d[None]).max(axis=2) + np.eye(len(d))
        assert gaps.min() > 1e-6


def test_single_triple_as_two_dimensional_arrays():
    rng = np.random.default_rng(4)
    y, x, true = random_triples(rng, 5)
    batch = p3p(y, x)
    for k in range(5):
        one = p3p(y[k], x[k])
        assert (one.triple == 0).all()
        np.testing.assert_allclose(one.depths, batch.depths[batch.triple == k], rtol=1e-12)
        assert best_relative_depth_error(one, true[k : k + 1])[0] < 1e-9


def test_empty_batch():
    sol = p3p(np.zeros((0, 3, 3)), np.zeros((0, 3, 3)))
    assert sol.triple.shape == (0,)
    assert sol.depths.shape == (0, 3)


def test_bearings_need_not_be_unit_length():
    rng = np.random.default_rng(5)
    y, x, _ = random_triples(rng, 50)
    scaled = y * rng.uniform(0.1, 10.0, (50, 3, 1))
    a, b = p3p(y, x), p3p(scaled, x)
    np.testing.assert_array_equal(a.triple, b.triple)
    np.testing.assert_allclose(a.depths, b.depths, rtol=1e-10)


def opencv_poses(world: np.ndarray, bearings: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
    """OpenCV's P3P poses (R, t) with cam = R world + t; OpenCV 5 returns (count, rvecs, tvecs)."""
    image = bearings[:, :2] / bearings[:, 2:]
    count, rvecs, tvecs = cv2.solveP3P(world, image, np.eye(3), None, cv2.SOLVEPNP_P3P)
    assert count == len(rvecs) == len(tvecs)
    return [(cv2.Rodrigues(r)[0], t.ravel()) for r, t in zip(rvecs, tvecs, strict=True)]


def test_agrees_with_opencv():
    rng = np.random.default_rng(6)
    n = 500
    y, x, _ = random_triples(rng, n)
    sol = p3p(y, x)
    R, t, ok = horn_batch(sol.depths[:, :, None] * y[sol.triple], x[sol.triple])
    assert ok.all()
    counts = np.bincount(sol.triple, minlength=n)
    disagree = 0
    for k in range(n):
        theirs = opencv_poses(x[k], y[k])
        disagree += len(theirs) != counts[k]
        ours = np.flatnonzero(sol.triple == k)
        for R_cv, t_cv in theirs:
            # Both solvers are exact up to rounding; 1e-6 is far below the O(1) gap to another solution.
            err = [max(np.abs(R[i] - R_cv).max(), np.abs(t[i] - t_cv).max()) for i in ours]
            assert min(err, default=np.inf) < 1e-6, f"triple {k}: OpenCV pose not among ours"
    # Near a double root of the quartic (two solutions merging as the triple crosses the "danger
    # cylinder") the pair is numerically borderline real/complex, and the two solvers' different
    # tolerances can decide it differently; allow 0.5% of triples to differ in count.
    assert disagree <= 0.005 * n


@pytest.mark.parametrize("eps", [1e-3, 1e-6, 1e-9])
def test_nearly_collinear_points_give_no_wrong_solution(eps):
    rng = np.random.default_rng(7)
    n = 500
    direction = unit(rng.normal(size=(n, 3)))
    s = np.stack([np.zeros(n), rng.uniform(0.3, 1.0, n), rng.uniform(1.2, 2.0, n)], axis=1)
    world = rng.normal(size=(n, 1, 3)) + s[:, :, None] * direction[:, None]
    world[:, 1] += eps * rng.normal(size=(n, 3))  # lift the middle point off the line by ~eps
    R = np.stack([random_rotation(rng) for _ in range(n)])
    cam = np.einsum("kij,knj->kni", R, world - world.mean(axis=1, keepdims=True)) + np.array([0.0, 0.0, 6.0])
    y = unit(cam)
    sol = p3p(y, world)
    assert_well_formed(sol, n)
    # Returned solutions must be roots; the solver's own acceptance is 1e-6 relative to the sum of the
    # squared distances, which is at most 3x the largest one.
    assert relative_residuals(y, world, sol).max() < 3e-6


def test_far_points_with_small_bearing_angles():
    rng = np.random.default_rng(8)
    n = 500
    R = np.stack([random_rotation(rng) for _ in range(n)])
    # ~0.3 m spacing at 50 m: bearings ~0.5 deg apart.
    cam = rng.normal(scale=0.3, size=(n, 3, 3)) + np.array([0.0, 0.0, 50.0])
    world = np.einsum("kji,knj->kni", R, cam)
    y = unit(cam)
    sol = p3p(y, world)
    assert_well_formed(sol, n)
    # Depth differences are constrained through 1 - cos(angle) ~ 1e-5, so rounding is amplified ~1e5; the
    # other solutions differ by ~spacing / depth ~ 1e-2, so 1e-6 still singles out the true one.
    assert best_relative_depth_error(sol, np.linalg.norm(cam, axis=2)).max() < 1e-6
    assert relative_residuals(y, world, sol).max() < 1e-6


def test_exactly_collinear_evenly_spaced_points():
    rng = np.random.default_rng(9)
    world = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0]])
    cam = world @ random_rotation(rng).T + [0.0, 0.0, 5.0]
    sol = p3p(unit(cam), world)
    assert_well_formed(sol, 1)
    assert relative_residuals(unit(cam), world, sol).max() < 1e-6


def test_exactly_collinear_points_batch_does_not_crash():
    rng = np.random.default_rng(2)
    n = 300
    direction = unit(rng.normal(size=(n, 3)))
    s = np.sort(rng.uniform(-1.0, 1.0, (n, 3)), axis=1)
    world = rng.normal(size=(n, 1, 3)) + s[:, :, None] * direction[:, None]
    R = np.stack([random_rotation(rng) for _ in range(n)])
    cam = np.einsum("kij,knj->kni", R, world) + rng.uniform(-1.0, 1.0, (n, 1, 3)) + [0.0, 0.0, 5.0]
    sol = p3p(unit(cam), world)
    assert_well_formed(sol, n)
    assert relative_residuals(unit(cam), world, sol).max() < 3e-6


@pytest.mark.parametrize("same", [(0, 1), (0, 2), (1, 2), (0, 1, 2)], ids=["01", "02", "12", "all"])
@pytest.mark.parametrize("consistent", [True, False], ids=["consistent", "generic-bearings"])
def test_coincident_points_do_not_crash(same, consistent):
    rng = np.random.default_rng(10)
    world = rng.normal(size=(3, 3))
    world[list(same)] = world[same[0]]
    if consistent:  # the coincident points share a bearing too
        bearings = unit(world @ random_rotation(rng).T + [0.0, 0.0, 5.0])
    else:
        bearings = unit(rng.normal(scale=0.3, size=(3, 3)) + np.array([0.0, 0.0, 1.0]))
    sol = p3p(bearings, world)
    assert_well_formed(sol, 1)
    assert relative_residuals(bearings, world, sol).max(initial=0.0) < 3e-6


def test_degenerate_triple_does_not_spoil_the_batch():
    rng = np.random.default_rng(11)
    y, x, true = random_triples(rng, 20)
    x[7] = x[7, 0]  # three coincident points
    sol = p3p(y, x)
    assert_well_formed(sol, 20)
    err = best_relative_depth_error(sol, true)
    assert err[np.arange(20) != 7].max() < 1e-9


@pytest.mark.parametrize("height_m", [0.12, 0.0])
def test_planar_points_with_camera_looking_along_the_plane(height_m):
    rng = np.random.default_rng(12)
    n = 1000
    T = make_T(rotvec_to_R([0.087, 0.02, -0.01]) @ R_BASE, [0.02, height_m, -0.05])
    ahead = rng.uniform(1.2, 4.0, (n, 3))
    world = np.stack([ahead, rng.uniform(-0.4, 0.4, (n, 3)) * ahead, np.zeros((n, 3))], axis=2)
    cam = world @ T[:3, :3].T + T[:3, 3]
    y = unit(cam)
    sol = p3p(y, world)
    assert_well_formed(sol, n)
    # Random triples from a scan are sometimes thin triangles seen at grazing angles, a little worse
    # conditioned than the generic case: observed ~1e-9, allowed 1e-8.
    assert best_relative_depth_error(sol, np.linalg.norm(cam, axis=2)).max() < 1e-8
    assert relative_residuals(y, world, sol).max() < 1e-8
    R, t, ok = horn_batch(sol.depths[:, :, None] * y[sol.triple], world[sol.triple])
    pose_err = np.maximum(np.abs(R - T[:3, :3]).max(axis=(1, 2)), np.abs(t - T[:3, 3]).max(axis=1))
    best = np.full(n, np.inf)
    np.minimum.at(best, sol.triple[ok], pose_err[ok])
    usable = np.isin(np.arange(n), sol.triple[ok])  # horn rejects near-collinear triples
    assert usable.mean() > 0.95
    assert best[usable].max() < 1e-6


def _degenerate_batch(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Generic, collinear, coincident and planar grazing triples, mixed in one batch."""
    y, x, _ = random_triples(rng, 400)
    x[:40] = x[:40, :1] + rng.uniform(-1, 1, (40, 3, 1)) * unit(rng.normal(size=(40, 1, 3)))  # collinear
    x[40:60, 1] = x[40:60, 0]  # two coincident points
    x[60:70] = x[60:70, :1]  # three
    y[70:80, 2] = y[70:80, 1]  # two coincident bearings
    x[80:120, :, 2] = 0.0  # planar
    x[120:140] += rng.normal(scale=1e-9, size=(20, 3, 3))
    return y, x


@pytest.mark.parametrize("seed", range(5))
def test_compiled_kernel_matches_the_numpy_reference(seed):
    """p3p (compiled, one triple at a time) finds the same solutions as p3p_numpy, in the
    same order, on generic and degenerate triples. Where two of the points coincide no
    true solution exists and the candidates sit at the acceptance threshold, so there the
    two may keep different ones, each satisfying the distance equations."""
    from rigcal.calib.box.p3p import p3p_numpy

    rng = np.random.default_rng(100 + seed)
    y, x = _degenerate_batch(rng) if seed % 2 else random_triples(rng, 2000)[:2]
    got, ref = p3p(y, x), p3p_numpy(y, x)
    assert_well_formed(got, len(y))
    assert relative_residuals(y, x, got).max(initial=0.0) < 1e-6
    same = (ref.triple < 40) | (ref.triple >= 60) if seed % 2 else np.ones(len(ref.triple), bool)
    mine = (got.triple < 40) | (got.triple >= 60) if seed % 2 else np.ones(len(got.triple), bool)
    assert same.sum() > 0.8 * len(np.unique(ref.triple))
    np.testing.assert_array_equal(got.triple[mine], ref.triple[same])
    np.testing.assert_allclose(got.depths[mine], ref.depths[same], rtol=1e-8, atol=0)


def test_kernel_refuses_mismatched_shapes():
    with pytest.raises(ValueError, match=r"expected \(n, 3, 3\) each"):
        p3p(np.ones((4, 3, 3)), np.ones((4, 2, 3)))


def _planar_grazing_batch(rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Laser-plane triples (z = 0) seen by a camera looking along the plane, as RANSAC draws them."""
    T = make_T(rotvec_to_R([0.087, 0.02, -0.01]) @ R_BASE, [0.02, 0.12, -0.05])
    ahead = rng.uniform(1.2, 4.0, (n, 3))
    world = np.stack([ahead, rng.uniform(-0.4, 0.4, (n, 3)) * ahead, np.zeros((n, 3))], axis=2)
    return unit(world @ T[:3, :3].T + T[:3, 3]), world


@pytest.mark.parametrize("batch", ["random", "degenerate", "planar"])
def test_poses_are_p3p_then_horn_batch(batch):
    """p3p_poses (P3P and Horn compiled) gives p3p's solutions and horn_batch's poses of them."""
    rng = np.random.default_rng(300)
    if batch == "random":
        y, x = random_triples(rng, 2000)[:2]
    elif batch == "degenerate":
        y, x = _degenerate_batch(rng)
    else:
        y, x = _planar_grazing_batch(rng, 2000)
    got = p3p_poses(y, x)
    sol = p3p(y, x)
    R, t, ok = horn_batch(sol.depths[:, :, None] * y[sol.triple], x[sol.triple])
    np.testing.assert_array_equal(got.triple, sol.triple)
    np.testing.assert_array_equal(got.depths, sol.depths)
    np.testing.assert_array_equal(got.ok, ok)
    assert ok.mean() > 0.8
    # Both eigenvectors are backward stable; they differ by rounding over N's eigengap
    # (test_horn bounds it per set), largest on the thinnest triangles the collinearity
    # flag lets through: observed 1.2e-10 on the planar ones.
    np.testing.assert_allclose(got.R, R, atol=5e-10, rtol=0)
    np.testing.assert_allclose(got.t, t, atol=5e-10, rtol=0)
    assert np.median(np.abs(got.R - R).max(axis=(1, 2))) < 1e-14


def test_poses_of_an_empty_batch():
    got = p3p_poses(np.zeros((0, 3, 3)), np.zeros((0, 3, 3)))
    assert got.R.shape == (0, 3, 3)
    assert got.t.shape == (0, 3)
    assert got.ok.shape == (0,)
