"""Synthetic recordings of a calibration: still moments of a target, with moves between.

A lab records the rig while a target is placed, held still and moved on. A recording
here is a sequence folder (docs/formats/sequence.md, :func:`rigcal.recordings.sequence.write_sequence`)
made of *still moments*, each the scans a simulator gives for one placement (independent
range noise each) and its image, the image recorded again every frame with fresh sensor
noise; between moments the target moves (scans and images change). The scanner and the
camera run unsynchronised (10 Hz and about 7.7 Hz), as in a real bag. ``rigcal capture``
finds the moments again; ``rig.yaml`` holds the true rig.

:func:`board_moments` makes the moments of a simulated board session
(:mod:`rigcal.sim.board_session`, its ``repeats`` the scans of a moment) with rendered
images of the board's sheet; :func:`marker_moments` those of a marker session
(:mod:`rigcal.sim.marker_session`, its ``scans_per_capture``).
"""

from __future__ import annotations

from collections.abc import Sequence as Seq
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from rigcal.camera import Camera
from rigcal.scan import Scan
from rigcal.sim.board_session import SimBoardSession, T_cam_board
from rigcal.sim.marker_session import SimMarkerSession
from rigcal.sim.world_render import CameraEffects, apply_effects

SCAN_PERIOD_S = 0.1
IMAGE_PERIOD_S = 0.13
MOVE_S = 0.6
# Sensor noise of each frame of a still moment's image (grey levels).
FRAME_NOISE = 1.0
# Texels per metre of a board sheet's picture.
SHEET_PX_PER_M = 500.0


@dataclass(frozen=True, eq=False)
class StillMoment:
    """One placement: its scans (one still moment's) and its image (BGR uint8)."""

    scans: tuple[Scan, ...]
    image: NDArray[np.uint8]


def board_moments(session: SimBoardSession, seed: int = 0) -> list[StillMoment]:
    """The still moments of a simulated board session: each pose's ``repeats`` captures'
    scans, and the board's sheet rendered at the pose over a still background (the rig
    does not move), shaded by incidence, with the realistic camera's blur and noise when
    the session's noise is realistic."""
    from rigcal.sim.boards import chessboard_sheet, render_board
    from rigcal.sim.render import pixel_bearings

    spec = session.spec
    rng = np.random.default_rng(seed)
    b = spec.board
    texture, origin = chessboard_sheet(b.width_n, b.height_n, b.spacing_m, spec.size_m, SHEET_PX_PER_M)
    background = _background(session.camera, rng)
    effects = CameraEffects(3.0, 0.8) if spec.noise is not None else CameraEffects(1.0, 0.0)
    rays = pixel_bearings(session.camera).astype(float)
    out = []
    k = spec.repeats
    for p in range(len(session.captures) // k):
        group = session.captures[p * k : (p + 1) * k]
        T = T_cam_board(session, group[0])
        # Matte paper lit from near the rig: brighter head-on (as the marker target's faces).
        lit = (texture.astype(np.float32) * (0.55 + 0.4 * abs(float(T[2, 2])))).astype(np.uint8)
        grey = render_board(session.camera, lit, spec.size_m, T, origin, background, rays)
        image = apply_effects(np.repeat(grey[:, :, None], 3, axis=2), effects, rng)
        out.append(StillMoment(tuple(c.scan for c in group), image))
    return out


def marker_moments(session: SimMarkerSession) -> list[StillMoment]:
    """The still moments of a simulated marker session (each capture's scans and image)."""
    return [StillMoment(c.scans or (c.scan,), c.image) for c in session.captures]


def _background(camera: Camera, rng: np.random.Generator) -> NDArray[np.uint8]:
    """A still room's grey picture: smooth shading and a few darker blocks (furniture)."""
    import cv2

    H, W = camera.height_px, camera.width_px
    coarse = rng.uniform(90, 170, (6, 8)).astype(np.float32)
    img: NDArray[np.float32] = np.asarray(
        cv2.resize(coarse, (W, H), interpolation=cv2.INTER_CUBIC), np.float32
    )
    for _ in range(6):
        x, y = int(rng.integers(0, W - 60)), int(rng.integers(0, H - 60))
        w, h = int(rng.integers(30, 120)), int(rng.integers(30, 120))
        img[y : y + h, x : x + w] *= np.float32(rng.uniform(0.5, 0.8))
    return np.clip(img, 0, 255).astype(np.uint8)


def write_still_recording(
    folder: str | Path,
    name: str,
    moments: Seq[StillMoment],
    camera: Camera,
    T_cam_laser: NDArray[np.float64],
    seed: int = 0,
    force: bool = False,
) -> list[float]:
    """Write a sequence folder of the moments (see the module), with the camera and the
    true rig. Returns each still moment's start stamp (s).

    Each moment lasts its scans' count times SCAN_PERIOD_S (scans at 10 Hz, images every
    IMAGE_PERIOD_S from 30 ms in, each with FRAME_NOISE of fresh noise); then MOVE_S of
    motion: scans of the next moment's first with every range moved, images shifted.
    """
    import cv2

    from rigcal.camera import camera_to_opencv_yaml
    from rigcal.recordings.sequence import ImageFrame, write_sequence
    from rigcal.rig import Rig
    from rigcal.rigfile import rig_to_text

    rng = np.random.default_rng(seed)
    scans: list[Scan] = []
    frames: list[ImageFrame] = []
    starts = []
    t = 100.0

    def image(stamp: float, img: NDArray[np.uint8]) -> None:
        ok, buf = cv2.imencode(".png", img, [cv2.IMWRITE_PNG_COMPRESSION, 1])
        assert ok
        frames.append(ImageFrame(stamp, f"{len(frames):06d}.png", buf.tobytes()))

    for m in moments:
        starts.append(t)
        for j, sc in enumerate(m.scans):
            scans.append(_stamped(sc, t + j * SCAN_PERIOD_S))
        end = t + len(m.scans) * SCAN_PERIOD_S
        for ts in np.arange(t + 0.03, end, IMAGE_PERIOD_S):
            noisy = m.image + rng.normal(0.0, FRAME_NOISE, m.image.shape)
            image(float(ts), np.clip(noisy + 0.5, 0, 255).astype(np.uint8))
        t = end
        for ts in np.arange(t, t + MOVE_S, SCAN_PERIOD_S):  # moving: everything shifts
            shift = 0.3 + rng.uniform(0, 0.5)
            sc = m.scans[0]
            scans.append(
                _stamped(
                    Scan(
                        sc.angles_rad,
                        sc.ranges_m + shift,
                        sc.range_min_m,
                        sc.range_max_m,
                        None,
                        sc.angle_increment_rad,
                    ),
                    float(ts),
                )
            )
            image(float(ts) + 0.05, np.roll(m.image, int(20 + 40 * shift), axis=1))
        t += MOVE_S
    order = np.argsort([f.stamp_s for f in frames], kind="stable")
    write_sequence(
        folder,
        name,
        scans,
        [frames[i] for i in order],
        camera_to_opencv_yaml(camera),
        {"tool": "rigcal.sim.recording", "seed": seed, "still_moments": len(moments)},
        force=force,
        rig_yaml=rig_to_text(Rig(T_cam_laser=np.asarray(T_cam_laser, dtype=float), camera=camera)),
    )
    return starts


def _stamped(scan: Scan, stamp_s: float) -> Scan:
    from dataclasses import replace

    return replace(scan, stamp_s=stamp_s)
