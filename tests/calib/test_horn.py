"""Horn's quaternion absolute orientation: exact recovery, Kabsch agreement, degenerate sets."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from rigcal.calib.box.horn import horn, horn_batch, horn_batch_compiled, horn_bearings, quaternion_to_R
from rigcal.geometry import random_rotation

REFLECT_Z = np.diag([1.0, 1.0, -1.0])


def random_poses(rng: np.random.Generator, k: int) -> tuple[np.ndarray, np.ndarray]:
    return np.stack([random_rotation(rng) for _ in range(k)]), rng.uniform(-2.0, 2.0, (k, 3))


def apply(R: np.ndarray, t: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a = R b + t for batches R (K,3,3), t (K,3), b (K,N,3)."""
    return np.einsum("kij,knj->kni", R, b) + t[:, None]


def kabsch(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares proper rotation with a ~ R b + t by SVD, reflection corrected."""
    ca, cb = a.mean(axis=0), b.mean(axis=0)
    U, _, Vt = np.linalg.svd((b - cb).T @ (a - ca))
    d = np.sign(np.linalg.det(Vt.T @ U.T))
    R = Vt.T @ np.diag([1.0, 1.0, d]) @ U.T
    return R, ca - R @ cb


def assert_proper_rotations(R: np.ndarray) -> None:
    np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-12)
    np.testing.assert_allclose(R @ np.swapaxes(R, -1, -2), np.broadcast_to(np.eye(3), R.shape), atol=1e-12)


@pytest.mark.parametrize("n_points", [3, 20])
def test_recovers_exact_poses(n_points):
    rng = np.random.default_rng(0)
    R_true, t_true = random_poses(rng, 200)
    b = rng.uniform(-1.0, 1.0, (200, n_points, 3))
    R, t, ok = horn_batch(apply(R_true, t_true, b), b)
    assert ok.all()
    # Noise-free data: the quaternion is an eigenvector of a well-separated eigenvalue, exact to rounding.
    np.testing.assert_allclose(R, R_true, atol=1e-12)
    np.testing.assert_allclose(t, t_true, atol=1e-12)


def test_batch_equals_per_item():
    rng = np.random.default_rng(1)
    R_true, t_true = random_poses(rng, 30)
    b = rng.uniform(-1.0, 1.0, (30, 8, 3))
    a = apply(R_true, t_true, b) + rng.normal(scale=0.01, size=b.shape)
    R, t, ok = horn_batch(a, b)
    assert ok.all()
    for k in range(30):
        Rk, tk = horn(a[k], b[k])
        np.testing.assert_allclose(Rk, R[k], atol=1e-14)
        np.testing.assert_allclose(tk, t[k], atol=1e-14)


def test_single_set_as_two_dimensional_arrays():
    rng = np.random.default_rng(2)
    R_true, t_true = random_poses(rng, 1)
    b = rng.uniform(-1.0, 1.0, (1, 5, 3))
    R, t, ok = horn_batch(apply(R_true, t_true, b)[0], b[0])
    assert R.shape == (1, 3, 3)
    assert t.shape == (1, 3)
    assert ok.tolist() == [True]
    np.testing.assert_allclose(R[0], R_true[0], atol=1e-12)


@pytest.mark.parametrize("sigma", [0.001, 0.05, 0.5])
def test_agrees_with_kabsch_on_noisy_data(sigma):
    rng = np.random.default_rng(3)
    R_true, t_true = random_poses(rng, 100)
    b = rng.uniform(-1.0, 1.0, (100, 10, 3))
    a = apply(R_true, t_true, b) + rng.normal(scale=sigma, size=b.shape)
    R, t, ok = horn_batch(a, b)
    assert ok.all()
    assert_proper_rotations(R)
    # Both are the exact least-squares minimiser; they differ only by eigen/SVD rounding.
    for k in range(100):
        R_k, t_k = kabsch(a[k], b[k])
        np.testing.assert_allclose(R[k], R_k, atol=1e-9)
        np.testing.assert_allclose(t[k], t_k, atol=1e-9)


@pytest.mark.parametrize("n_points", [4, 20])
def test_reflected_data_gives_a_proper_rotation(n_points):
    rng = np.random.default_rng(4)
    R_true, t_true = random_poses(rng, 100)
    b = rng.uniform(-1.0, 1.0, (100, n_points, 3))
    a = apply(R_true @ REFLECT_Z, t_true, b)  # a mirror image of b: no rotation fits exactly
    R, t, ok = horn_batch(a, b)
    assert ok.all()
    assert_proper_rotations(R)
    for k in range(100):
        R_k, t_k = kabsch(a[k], b[k])
        assert np.linalg.det(R_true[k] @ REFLECT_Z) < 0  # the data really is reflected
        np.testing.assert_allclose(R[k], R_k, atol=1e-9)
        np.testing.assert_allclose(t[k], t_k, atol=1e-9)


def test_rotation_is_proper_for_arbitrary_data():
    rng = np.random.default_rng(5)
    a = rng.normal(size=(500, 6, 3))
    b = rng.normal(size=(500, 6, 3))
    R, _, ok = horn_batch(a, b)
    assert ok.all()
    assert_proper_rotations(R)


def degenerate_sets(rng: np.random.Generator) -> dict[str, np.ndarray]:
    d = rng.normal(size=3)
    base = rng.normal(size=3)
    line = base + np.linspace(-1.0, 1.0, 6)[:, None] * d
    near = line.copy()
    near[2] += 1e-6 * rng.normal(size=3)  # second singular value ~1e-6 of the first: below 1e-3
    return {
        "collinear": line,
        "nearly-collinear": near,
        "coincident": np.tile(base, (6, 1)),
        "two-distinct": np.vstack([np.tile(base, (3, 1)), np.tile(base + d, (3, 1))]),
    }


@pytest.mark.parametrize("which", ["collinear", "nearly-collinear", "coincident", "two-distinct"])
@pytest.mark.parametrize("side", ["source", "target"])
def test_degenerate_sets_are_flagged(which, side):
    rng = np.random.default_rng(6)
    R_true, t_true = random_poses(rng, 4)
    b = rng.uniform(-1.0, 1.0, (4, 6, 3))
    a = apply(R_true, t_true, b)
    bad = degenerate_sets(rng)[which]
    if side == "source":
        b[2] = bad
        a[2] = apply(R_true[2:3], t_true[2:3], bad[None])[0]
    else:
        a[2] = bad
    R, t, ok = horn_batch(a, b)
    assert ok.tolist() == [True, True, False, True]
    assert_same_as_reference(a, b)  # the compiled kernel flags the same sets
    np.testing.assert_array_equal(R[2], np.eye(3))
    np.testing.assert_array_equal(t[2], np.zeros(3))
    np.testing.assert_allclose(R[ok], R_true[ok], atol=1e-12)
    with pytest.raises(ValueError, match="collinear"):
        horn(a[2], b[2])


def test_well_spread_set_is_not_flagged():
    # Second singular value ~1.5e-2 of the first: a thin zigzag, but well above the 1e-3 threshold.
    rng = np.random.default_rng(7)
    R_true, t_true = random_poses(rng, 1)
    b = np.column_stack([np.linspace(-1.0, 1.0, 7), 0.01 * (-1.0) ** np.arange(7), np.zeros(7)])
    R, t, ok = horn_batch(apply(R_true, t_true, b[None]), b[None])
    assert ok[0]
    np.testing.assert_allclose(R[0], R_true[0], atol=1e-10)
    np.testing.assert_allclose(t[0], t_true[0], atol=1e-10)


@pytest.mark.parametrize("bad_value", [np.nan, np.inf])
@pytest.mark.parametrize("side", ["a", "b"])
def test_non_finite_input_is_flagged(bad_value, side):
    rng = np.random.default_rng(8)
    R_true, t_true = random_poses(rng, 3)
    b = rng.uniform(-1.0, 1.0, (3, 5, 3))
    a = apply(R_true, t_true, b)
    (a if side == "a" else b)[1, 3, 0] = bad_value
    R, t, ok = horn_batch(a, b)
    assert ok.tolist() == [True, False, True]
    assert np.isfinite(R).all()
    assert np.isfinite(t).all()
    np.testing.assert_array_equal(R[1], np.eye(3))
    np.testing.assert_array_equal(t[1], np.zeros(3))
    np.testing.assert_allclose(R[[0, 2]], R_true[[0, 2]], atol=1e-12)
    np.testing.assert_allclose(t[[0, 2]], t_true[[0, 2]], atol=1e-12)
    with pytest.raises(ValueError, match="horn"):
        horn(a[1], b[1])


def test_empty_batch():
    R, t, ok = horn_batch(np.zeros((0, 5, 3)), np.zeros((0, 5, 3)))
    assert R.shape == (0, 3, 3)
    assert t.shape == (0, 3)
    assert ok.shape == (0,)
    assert ok.dtype == np.bool_


def test_quaternion_to_R_matches_scipy():
    rng = np.random.default_rng(9)
    q = rng.normal(size=(1000, 4))  # (w, x, y, z), deliberately not unit length
    expected = Rotation.from_quat(q[:, [1, 2, 3, 0]]).as_matrix()  # scipy is scalar-last
    np.testing.assert_allclose(quaternion_to_R(q), expected, atol=1e-14)
    np.testing.assert_allclose(quaternion_to_R(-q), expected, atol=1e-14)


def test_quaternion_to_R_conventions():
    # A quarter turn about z (w = cos 45 deg, z = sin 45 deg) maps x to y; a single quaternion gives (3, 3).
    s = np.sqrt(0.5)
    R = quaternion_to_R([s, 0.0, 0.0, s])
    assert R.shape == (3, 3)
    np.testing.assert_allclose(R @ [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], atol=1e-15)
    np.testing.assert_array_equal(quaternion_to_R([[1.0, 0.0, 0.0, 0.0]]), np.eye(3)[None])


def test_closed_form_symmetric_eigenvalues_match_numpy():
    from rigcal.calib.box.horn import sym3_eigvalsh

    rng = np.random.default_rng(21)
    A = rng.normal(size=(500, 3, 3))
    S = A + np.transpose(A, (0, 2, 1))
    S[:5] = np.diag([2.0, 2.0, 2.0])  # a triple eigenvalue
    S[5:10] = np.diag([0.0, 1.0, 1.0])  # a double one
    np.testing.assert_allclose(sym3_eigvalsh(S), np.linalg.eigvalsh(S), atol=1e-9)


# The compiled kernel (horn_batch_compiled, horn_bearings) against horn_batch, its reference.


def eigengap_ratio(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(K,) lambda_1 / (lambda_1 - lambda_2) of Horn's N: how much rounding its top
    eigenvector suffers. From the singular values s of S: N's eigenvalues are
    +-s1 +-s2 +-s3 with an even number of minus signs times sign(det S)."""
    A = a - a.mean(axis=1, keepdims=True)
    B = b - b.mean(axis=1, keepdims=True)
    S = np.einsum("kni,knj->kij", B, A)
    s = np.linalg.svd(S, compute_uv=False)
    d = np.sign(np.linalg.det(S))
    out: np.ndarray = (s[:, 0] + s[:, 1] + d * s[:, 2]) / np.maximum(2.0 * (s[:, 1] + d * s[:, 2]), 1e-300)
    return out


def assert_same_as_reference(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The compiled kernel gives horn_batch's flags, and its poses to rounding: both
    eigenvectors are backward stable, so they differ by ~1e-16 times N's eigengap ratio
    (observed up to 2.5e-15 times it; allowed 1e-14)."""
    R_ref, t_ref, ok_ref = horn_batch(a, b)
    R, t, ok = horn_batch_compiled(a, b)
    np.testing.assert_array_equal(ok, ok_ref)
    tol = 1e-14 * np.where(ok, eigengap_ratio(a, b), 1.0)
    size = np.maximum(1.0, np.abs(np.where(ok[:, None, None], a, 0.0)).max(axis=(1, 2)))
    assert (np.abs(R - R_ref).max(axis=(1, 2)) <= tol).all()
    assert (np.abs(t - t_ref).max(axis=1) <= tol * size).all()
    return ok


def cost(R: np.ndarray, t: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(K,) Horn's least-squares cost sum |a_i - (R b_i + t)|^2."""
    out: np.ndarray = ((a - apply(R, t, b)) ** 2).sum(axis=(1, 2))
    return out


@pytest.mark.parametrize("n_points", [3, 4, 20])
@pytest.mark.parametrize("sigma", [0.0, 1e-3, 0.05])
def test_compiled_matches_reference_on_random_sets(n_points, sigma):
    rng = np.random.default_rng(30 + n_points)
    R_true, t_true = random_poses(rng, 2000)
    b = rng.uniform(-1.0, 1.0, (2000, n_points, 3))
    a = apply(R_true, t_true, b) + rng.normal(scale=sigma, size=b.shape)
    ok = assert_same_as_reference(a, b)
    assert ok.all()


def test_compiled_matches_reference_on_arbitrary_and_reflected_data():
    rng = np.random.default_rng(31)
    a = rng.normal(size=(1000, 6, 3))
    b = rng.normal(size=(1000, 6, 3))
    assert_same_as_reference(a, b)
    R_true, t_true = random_poses(rng, 300)
    b = rng.uniform(-1.0, 1.0, (300, 5, 3))
    assert_same_as_reference(apply(R_true @ REFLECT_Z, t_true, b), b)


def test_compiled_matches_reference_on_half_turns():
    # Rotations by 180 deg: the quaternion's scalar part is zero.
    rng = np.random.default_rng(32)
    axis = rng.normal(size=(500, 3))
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    angle = np.pi - np.concatenate([np.zeros(250), rng.uniform(0.0, 1e-6, 250)])
    R_true = Rotation.from_rotvec(angle[:, None] * axis).as_matrix()
    t_true = rng.uniform(-2.0, 2.0, (500, 3))
    b = rng.uniform(-1.0, 1.0, (500, 3, 3))
    assert_same_as_reference(apply(R_true, t_true, b), b)
    R, _, ok = horn_batch_compiled(apply(R_true, t_true, b), b)
    assert ok.all()
    np.testing.assert_allclose(R, R_true, atol=1e-12)


@pytest.mark.parametrize("ratio", [3e-3, 1e-2, 0.1])
def test_compiled_matches_reference_on_thin_triangles(ratio):
    # Triangles whose third point is `ratio` (times 0.5-2) off the line of the others, so
    # that some are flagged (below 1e-3) and N's two largest eigenvalues come close.
    rng = np.random.default_rng(33)
    k = 2000
    R_true, t_true = random_poses(rng, k)
    u = rng.normal(size=(k, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    v = np.cross(u, rng.normal(size=(k, 3)))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    s = rng.uniform(-1.0, 1.0, (k, 3))
    s -= s.mean(axis=1, keepdims=True)
    w = np.stack([[-1.0, 0.5, 0.5]] * k) * rng.uniform(0.5, 2.0, (k, 1))
    b = rng.uniform(-1, 1, (k, 1, 3)) + s[:, :, None] * u[:, None] + ratio * w[:, :, None] * v[:, None]
    a = apply(R_true, t_true, b)
    ok = assert_same_as_reference(a, b)
    assert ok.mean() > 0.8


@pytest.mark.parametrize("size_m", [1e-6, 1e-3, 1e3])
def test_compiled_matches_reference_at_any_scale(size_m):
    rng = np.random.default_rng(34)
    R_true, t_true = random_poses(rng, 500)
    b = size_m * rng.uniform(-1.0, 1.0, (500, 3, 3))
    a = apply(R_true, size_m * t_true, b)
    assert_same_as_reference(a, b)


def test_compiled_flags_at_the_spread_threshold_as_the_reference():
    # Thin zigzags whose second singular value straddles MIN_SPREAD_RATIO of the first: the
    # kernel's quick bounds leave these to the closed-form eigenvalues, as the reference.
    rng = np.random.default_rng(35)
    R_true, t_true = random_poses(rng, 400)
    heights = np.geomspace(1e-4, 1e-2, 400)
    x = np.linspace(-1.0, 1.0, 7)
    b = np.stack([np.column_stack([x, h * (-1.0) ** np.arange(7), np.zeros(7)]) for h in heights])
    ok = assert_same_as_reference(apply(R_true, t_true, b), b)
    assert 0 < ok.sum() < len(ok)


@pytest.mark.parametrize("bad_value", [np.nan, np.inf, -np.inf])
def test_compiled_flags_non_finite_input(bad_value):
    rng = np.random.default_rng(8)
    R_true, t_true = random_poses(rng, 3)
    b = rng.uniform(-1.0, 1.0, (3, 5, 3))
    a = apply(R_true, t_true, b)
    a[1, 3, 0] = bad_value
    b[2, 0, 2] = bad_value
    R, t, ok = horn_batch_compiled(a, b)
    assert ok.tolist() == [True, False, False]
    np.testing.assert_array_equal(R[1:], np.stack([np.eye(3)] * 2))
    np.testing.assert_array_equal(t[1:], np.zeros((2, 3)))


def test_compiled_with_two_equal_largest_eigenvalues_is_optimal():
    # A mirror image whose scatter is diag(3, 1, 1): S has singular values (3, 1, 1) with
    # det S < 0, so N's two largest eigenvalues coincide and every rotation about x by any
    # angle fits equally well. The kernel falls back to Jacobi rotations; its rotation
    # must reach the reference's (optimal) cost, and near-coincident ones too.
    rng = np.random.default_rng(36)
    base = np.array([[1.0, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]])
    b = base * np.sqrt([1.5, 0.5, 0.5])  # scatter diag(3, 1, 1)
    sets_b = np.stack([b, b * [1.0, 1.0 + 1e-9, 1.0], b * [1.0, 1.0 + 1e-6, 1.0]])
    R_true, t_true = random_poses(rng, 3)
    sets_a = apply(R_true @ REFLECT_Z, t_true, sets_b)
    R_ref, t_ref, ok_ref = horn_batch(sets_a, sets_b)
    R, t, ok = horn_batch_compiled(sets_a, sets_b)
    assert ok.all()
    assert ok_ref.all()
    assert_proper_rotations(R)
    np.testing.assert_allclose(cost(R, t, sets_a, sets_b), cost(R_ref, t_ref, sets_a, sets_b), rtol=1e-12)


def test_jacobi_and_adjugate_eigenvectors():
    from rigcal.calib.box.horn import _k_adjugate_column, _k_sym4_det, _k_top_eigenvector_jacobi

    rng = np.random.default_rng(37)
    for _ in range(200):
        A = rng.normal(size=(4, 4))
        M = A + A.T
        w, V = np.linalg.eigh(M)
        upper = tuple(M[np.triu_indices(4)])
        assert _k_sym4_det(upper) == pytest.approx(np.linalg.det(M), abs=1e-12)
        q = np.array(_k_top_eigenvector_jacobi(M.copy(), np.empty((4, 4))))
        assert abs(q @ V[:, -1]) == pytest.approx(1.0, abs=1e-13)
        *q_adj, found = _k_adjugate_column(upper, w[-1])
        if w[-1] - w[-2] > 1e-2:
            assert found
            assert abs(np.array(q_adj) @ V[:, -1]) == pytest.approx(1.0, abs=1e-12)
    # A repeated largest eigenvalue: every column of the adjugate vanishes.
    *_, found = _k_adjugate_column(tuple(np.diag([2.0, 2.0, 1.0, -5.0])[np.triu_indices(4)]), 2.0)
    assert not found
    q = np.array(_k_top_eigenvector_jacobi(np.diag([2.0, 2.0, 1.0, -5.0]), np.empty((4, 4))))
    assert np.linalg.norm(q[:2]) == pytest.approx(1.0)


def test_horn_bearings_is_horn_batch_on_the_gathered_sets():
    rng = np.random.default_rng(38)
    n, K = 50, 120
    y = rng.normal(size=(n, 3, 3))
    y /= np.linalg.norm(y, axis=2, keepdims=True)
    x = rng.uniform(-1.0, 1.0, (n, 3, 3))
    triple = rng.integers(0, n, K)
    depths = rng.uniform(0.5, 5.0, (K, 3))
    R, t, ok = horn_bearings(y, triple, depths, x)
    R_ref, t_ref, ok_ref = horn_batch(depths[:, :, None] * y[triple], x[triple])
    np.testing.assert_array_equal(ok, ok_ref)
    np.testing.assert_allclose(R, R_ref, atol=1e-12)
    np.testing.assert_allclose(t, t_ref, atol=1e-12)


def test_compiled_shapes_and_errors():
    rng = np.random.default_rng(39)
    R_true, t_true = random_poses(rng, 1)
    b = rng.uniform(-1.0, 1.0, (1, 5, 3))
    R, t, ok = horn_batch_compiled(apply(R_true, t_true, b)[0], b[0])
    assert R.shape == (1, 3, 3)
    assert t.shape == (1, 3)
    assert ok.tolist() == [True]
    R, t, ok = horn_batch_compiled(np.zeros((0, 5, 3)), np.zeros((0, 5, 3)))
    assert R.shape == (0, 3, 3)
    assert t.shape == (0, 3)
    assert ok.shape == (0,)
    with pytest.raises(ValueError, match=r"expected \(K, N, 3\) each"):
        horn_batch_compiled(np.zeros((2, 5, 3)), np.zeros((2, 4, 3)))
    with pytest.raises(ValueError, match="indices below n"):
        horn_bearings(np.ones((2, 3, 3)), [0, 2], np.ones((2, 3)), np.ones((2, 3, 3)))
    with pytest.raises(ValueError, match=r"\(K, M\)"):
        horn_bearings(np.ones((2, 3, 3)), [0, 1], np.ones((2, 4)), np.ones((2, 3, 3)))
    R, t, ok = horn_bearings(np.ones((2, 3, 3)), np.zeros(0, dtype=int), np.zeros((0, 3)), np.ones((2, 3, 3)))
    assert R.shape == (0, 3, 3)
    assert ok.shape == (0,)
