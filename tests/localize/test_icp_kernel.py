"""ICP's compiled kernel and the grid nearest neighbours against their numpy/scipy references."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

from rigcal.lines import extract_lines, return_labels
from rigcal.localize.icp import IcpParams, icp
from rigcal.localize.line_normals import line_normals
from rigcal.localize.nearest import Grid
from rigcal.scan import Scan
from rigcal.sim.raycast import cast_scan

ANGLES = np.radians(np.arange(-135, 135.001, 0.25))
ROOM = np.array(
    [[[-3, -2], [5, -2]], [[5, -2], [5, 3]], [[5, 3], [-3, 3]], [[-3, 3], [-3, -2]], [[1, 0.5], [1.6, 1.2]]]
)


def room_scan(pose: np.ndarray, rng: np.random.Generator) -> Scan:
    x, y, yaw = pose
    c, s = np.cos(yaw), np.sin(yaw)
    r = cast_scan((ROOM - [x, y]) @ np.array([[c, s], [-s, c]]).T, ANGLES, 30.0)
    r = r + rng.normal(0, 0.01, len(r))
    return Scan(ANGLES, np.where(np.isfinite(r), r, 0.0), 0.05, 30.0)


@pytest.mark.parametrize("k", [1, 4, 5])
@pytest.mark.parametrize("seed", range(3))
def test_grid_neighbours_are_the_k_d_trees(k, seed):
    rng = np.random.default_rng(seed)
    # clustered points (returns along walls) and far-away and outside queries
    pts = np.concatenate([rng.normal(size=(300, 2)) * [5.0, 0.02] + [0, 1], rng.uniform(-8, 8, (200, 2))])
    q = np.concatenate([pts + rng.normal(scale=0.05, size=pts.shape), rng.uniform(-40, 40, (300, 2))])
    d_ref, i_ref = cKDTree(pts).query(q, k=k)
    d, i = Grid(pts).query(q, k)
    np.testing.assert_array_equal(i, i_ref)
    np.testing.assert_allclose(d, d_ref, rtol=1e-12, atol=0)


@pytest.mark.parametrize("angle_deg", [0.0, 90.0, 30.0, 135.0])
def test_grid_neighbours_along_walls_at_any_angle(angle_deg):
    """Returns along walls (a room scan's, turned): each cell's points sorted along its
    longer side, x or y, and the walk outwards from the query's coordinate stays exact."""
    rng = np.random.default_rng(int(angle_deg))
    s = room_scan(np.array([0.3, -0.2, np.radians(angle_deg)]), rng)
    pts = s.points[s.valid]
    q = np.concatenate([pts + rng.normal(scale=0.02, size=pts.shape), rng.uniform(-6, 6, (200, 2))])
    for k in (1, 4):
        d_ref, i_ref = cKDTree(pts).query(q, k=k)
        d, i = Grid(pts).query(q, k)
        np.testing.assert_array_equal(i, i_ref)
        np.testing.assert_allclose(d, d_ref, rtol=1e-12, atol=0)


def test_grid_needs_a_point():
    with pytest.raises(ValueError, match="at least one point"):
        Grid(np.zeros((0, 2)))


@pytest.mark.parametrize("seed", range(5))
def test_kernel_median_is_numpys_partition(seed):
    from rigcal.localize.icp_compiled import _median

    rng = np.random.default_rng(seed)
    for n in (1, 2, 3, 10, 101, 1064):
        v = rng.exponential(size=n)
        v[rng.integers(0, n, n // 3)] = v[0]  # repeated values
        work = np.empty(n + 5)
        assert _median(v, n, work) == np.partition(v, n // 2)[n // 2]


def test_grid_with_fewer_points_than_k_and_coincident_points():
    pts = np.array([[0.0, 0.0], [0.0, 0.0], [1.0, 0.0]])
    d, i = Grid(pts).query(np.array([[0.9, 0.0]]), 5)
    assert d.shape == (1, 3)
    np.testing.assert_allclose(d[0], [0.1, 0.9, 0.9])
    assert i[0, 0] == 2


@pytest.mark.parametrize(
    "params",
    [
        IcpParams(),
        IcpParams(normals="neighbours"),
        IcpParams(method="point-to-point"),
        IcpParams(reject_m=0.005),
        IcpParams(method="point-to-point", reject_m=0.005, subsample=1),
    ],
    ids=["point-to-line", "neighbour-normals", "point-to-point", "median-threshold", "point-to-point-median"],
)
@pytest.mark.parametrize("seed", range(4))
def test_compiled_icp_matches_the_numpy_iterations(params, seed):
    """Same pose, figures and pairs as the numpy reference, on random room scans and
    motions (with and without the scans' line normals)."""
    rng = np.random.default_rng(seed)
    a = rng.uniform([-1, -0.5, -0.3], [1, 0.5, 0.3])
    b = a + rng.uniform([-0.3, -0.3, -0.2], [0.3, 0.3, 0.2])
    s1, s2 = room_scan(a, rng), room_scan(b, rng)
    m, d = s1.points[s1.valid], s2.points[s2.valid]
    normals = None
    if params.normals == "lines":
        normals = line_normals(m, return_labels(s1, extract_lines(s1))[s1.valid])
    guess = rng.normal(scale=0.02, size=3) if seed % 2 else None
    got = icp(m, d, guess, params, normals)
    ref = icp(m, d, guess, params, normals, kernel=False)
    np.testing.assert_allclose(got.pose, ref.pose, rtol=0, atol=1e-10)
    assert got.iterations == ref.iterations
    assert got.rms_m == pytest.approx(ref.rms_m, rel=1e-9)
    assert got.inlier_fraction == ref.inlier_fraction
    assert got.degeneracy == pytest.approx(ref.degeneracy, rel=1e-9)
    np.testing.assert_array_equal(got.nearest, ref.nearest)


def test_compiled_icp_rejects_normals_of_another_shape():
    rng = np.random.default_rng(0)
    s = room_scan(np.zeros(3), rng)
    m = s.points[s.valid]
    with pytest.raises(ValueError, match="model_normals"):
        icp(m, m, None, IcpParams(), np.zeros((len(m) - 1, 2)))


def test_compiled_icp_in_a_degenerate_corridor_matches():
    """Two long parallel walls: the point-to-line step goes through the eigenvector
    solve (the degenerate branch) in both."""
    rng = np.random.default_rng(5)
    u = np.linspace(-10, 10, 800)
    m = np.concatenate([np.column_stack([u, np.full(800, 1.0)]), np.column_stack([u, np.full(800, -1.0)])])
    m += rng.normal(scale=0.005, size=m.shape)
    d = m[::2] + np.array([0.05, 0.02])
    normals = np.tile([0.0, 1.0], (len(m), 1))
    got = icp(m, d, None, IcpParams(), normals)
    ref = icp(m, d, None, IcpParams(), normals, kernel=False)
    np.testing.assert_allclose(got.pose, ref.pose, rtol=0, atol=1e-10)
    assert got.degeneracy < 1e-3


@pytest.mark.parametrize("seed", range(3))
def test_iasm_laser_scores_from_the_grid_match_the_k_d_trees(seed):
    from types import SimpleNamespace

    from rigcal.localize.iasm import IasmParams, laser_scores

    rng = np.random.default_rng(seed)
    s1, s2 = room_scan(np.zeros(3), rng), room_scan(np.array([0.1, 0.05, 0.03]), rng)
    f1 = SimpleNamespace(points=s1.points[s1.valid])
    f2 = SimpleNamespace(points=s2.points[s2.valid])
    hyp = np.concatenate([[[0.1, 0.05, 0.03]], rng.normal(scale=[0.3, 0.3, 0.2], size=(60, 3))])
    params = IasmParams()
    got = laser_scores(hyp, f1, f2, params, np.random.default_rng(7))
    ref = laser_scores(hyp, f1, f2, params, np.random.default_rng(7), kernel=False)
    np.testing.assert_allclose(got, ref, rtol=1e-12, atol=0)
    assert got.argmax() == 0


def test_sad_kernel_matches_numpy_and_carries_nan():
    from rigcal.localize.iasm import sad_rows

    rng = np.random.default_rng(3)
    a = rng.uniform(0, 255, (50, 121)).astype(np.float32)
    b = rng.uniform(0, 255, (60, 121)).astype(np.float32)
    b[7, 5] = np.nan
    ia, ib = rng.integers(0, 50, 400), rng.integers(0, 60, 400)
    got, ref = sad_rows(a, ia, b, ib), sad_rows(a, ia, b, ib, kernel=False)
    np.testing.assert_allclose(got, ref, rtol=1e-12)
    assert np.array_equal(np.isnan(got), ib == 7)
    assert np.isnan(got).any()


@pytest.mark.parametrize("seed", range(3))
def test_iasm_matching_with_compiled_sad_matches_numpy(seed):
    """Bidirectional SAD matching of two frames whose patches are shifted copies with
    noise: the same correspondences and refined points with the kernel as with numpy."""
    from types import SimpleNamespace

    from rigcal.localize.iasm import match_returns

    rng = np.random.default_rng(seed)
    n = 300
    base = rng.uniform(0, 255, (n + 5, 121)).astype(np.float32)
    u = np.linspace(20, 620, n)

    def frame(shift: int) -> SimpleNamespace:
        patches = base[shift : shift + n] + rng.normal(0, 2, (n, 121)).astype(np.float32)
        return SimpleNamespace(
            patches=patches,
            pixels=np.column_stack([u, np.full(n, 240.0)]),
            visible=rng.uniform(size=n) > 0.1,
            points=np.column_stack([np.linspace(1, 4, n), np.linspace(-2, 2, n)]),
            line_of=np.repeat(np.arange(n // 50), 50),
        )

    f1, f2 = frame(0), frame(2)
    got = match_returns(f1, f2, f1.pixels, 20.0, 5.0)
    ref = match_returns(f1, f2, f1.pixels, 20.0, 5.0, kernel=False)
    assert len(ref.i1) > n // 2
    np.testing.assert_array_equal(got.i1, ref.i1)
    np.testing.assert_array_equal(got.i2, ref.i2)
    np.testing.assert_allclose(got.b, ref.b, rtol=1e-9)
    np.testing.assert_allclose(got.sad, ref.sad, rtol=1e-12)
