"""Horn's quaternion absolute orientation: exact recovery, Kabsch agreement, degenerate sets."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from rigcal.calib.horn import horn, horn_batch, quaternion_to_R
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
    from rigcal.calib.horn import sym3_eigvalsh

    rng = np.random.default_rng(21)
    A = rng.normal(size=(500, 3, 3))
    S = A + np.transpose(A, (0, 2, 1))
    S[:5] = np.diag([2.0, 2.0, 2.0])  # a triple eigenvalue
    S[5:10] = np.diag([0.0, 1.0, 1.0])  # a double one
    np.testing.assert_allclose(sym3_eigvalsh(S), np.linalg.eigvalsh(S), atol=1e-9)
