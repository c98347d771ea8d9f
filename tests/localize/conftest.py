"""Shared pieces of the localization tests: a camera looking at a textured wall."""

from __future__ import annotations

import numpy as np
import pytest
from corridor_views import corridor
from scipy.ndimage import gaussian_filter, map_coordinates

from rigcal.cli.main import main
from rigcal.sim.box_session import default_camera
from rigcal.sim.textures import world_textures

CAM = default_camera()


def _wall_image(R, t, depth, texture):
    """A camera at x2 = R x1 + t looking at the textured plane z1 = depth (first camera's frame)."""
    u, v = np.meshgrid(np.arange(CAM.width_px, dtype=float), np.arange(CAM.height_px, dtype=float))
    b2 = CAM.bearings(np.column_stack([u.ravel(), v.ravel()]))
    c = -R.T @ t  # second camera centre in the first frame
    d = b2 @ R  # its rays in the first frame
    s = (depth - c[2]) / d[:, 2]
    X = c + s[:, None] * d
    # Texture: 200 texels per metre over [-4, 4] m.
    coords = np.vstack([(X[:, 1] + 4.0) * 200.0, (X[:, 0] + 4.0) * 200.0])
    img = map_coordinates(texture, coords, order=1, mode="nearest")
    return np.clip(img, 0, 255).astype(np.uint8).reshape(CAM.height_px, CAM.width_px)


@pytest.fixture(scope="module")
def texture():
    """A smooth random texture, 1600x1600 texels (200 per metre over [-4, 4] m)."""
    rng = np.random.default_rng(11)
    tex = gaussian_filter(rng.normal(0, 1, (1600, 1600)), 3.0)
    return 128 + 60 * tex / tex.std()


@pytest.fixture(scope="module")
def wall_image():
    """``wall_image(R, t, depth, texture)``: the second camera's view of a textured plane."""
    return _wall_image


@pytest.fixture(scope="module")
def repeating():
    """The corridor with a 0.5 m period pattern on its left wall, and its textures."""
    world = corridor("repeating")
    return world, world_textures(world, 0)


@pytest.fixture(scope="session")
def drive(tmp_path_factory):
    """Six seconds of the corridor loop, with images: a straight stretch, then a turn."""
    out = tmp_path_factory.mktemp("drive") / "corridor"
    args = ["simulate", "world", "--world", "corridor-loop", "-o", str(out)]
    args += ["--duration-s", "6", "--seed", "1"]
    assert main(args) == 0
    return out
