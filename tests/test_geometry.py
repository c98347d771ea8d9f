"""Rotation helpers: Rodrigues' formula against scipy's rotations."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from rigcal.geometry import R_to_rotvec, rotvec_to_R


@pytest.mark.parametrize("size", [0.0, 1e-9, 1e-6, 1e-3, 0.3, 1.0, 3.0])
def test_rotvec_to_R_matches_scipy_from_tiny_to_large_angles(size):
    rng = np.random.default_rng(1)
    for _ in range(50):
        w = rng.normal(0.0, 1.0, 3)
        w *= size / max(np.linalg.norm(w), 1e-300)
        R = rotvec_to_R(w)
        assert np.abs(R - Rotation.from_rotvec(w).as_matrix()).max() < 1e-14
        assert np.abs(R @ R.T - np.eye(3)).max() < 1e-14
        if 1e-6 <= size < np.pi:
            assert np.allclose(R_to_rotvec(R), w, atol=1e-12)


def test_rotvec_to_R_takes_a_batch():
    w = np.array([[0.0, 0.0, 0.5], [0.1, -0.2, 0.3]])
    R = rotvec_to_R(w)
    assert R.shape == (2, 3, 3)
    assert np.allclose(R[1], rotvec_to_R(w[1]))
