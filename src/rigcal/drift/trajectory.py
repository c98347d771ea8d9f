"""A trajectory already computed (``rigcal localize``'s ``METHOD/trajectory.tum``) as the
targetless check's laser motion, instead of the check's own laser odometry.

The check needs the laser's planar pose at every image it uses and at the scan nearest
each (:mod:`rigcal.drift.targetless`, step 1). A TUM file of the laser's poses (T_world_laser
with stamps, as ``localize`` writes for every method: ``icp`` at the scans' stamps, the
image methods at the images') is interpolated at the sequence's scan stamps (x, y and the
unwrapped yaw, linearly), which the check then reads as it reads its own odometry. The
file must cover the sequence's images: the first image's stamp to the last's, to within
:data:`MAX_EXTRAPOLATION_S` (``localize``'s ``icp`` trajectory ends at the last scan, which
may come a few milliseconds before the last image), with poses at most :data:`MAX_GAP_S`
apart; the stamps just outside the file's span take the end segment's velocity.

A TUM file says nothing of where the laser odometry was degenerate (a featureless
corridor), so no pair of frames is left out for it: reuse the trajectory of a method that
bridges such stretches (``kf``, ``iasm``, ``hiasm``), or let the check run its own odometry.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from rigcal.arrays import FloatArray
from rigcal.errors import InputError
from rigcal.geometry import pose_of, se2
from rigcal.io.trajectory import read_tum
from rigcal.localize.odometry import Odometry
from rigcal.localize.streams import Streams

MAX_GAP_S = 0.5
"""Poses further apart than this within the drive's images are a gap: the motion between
them is not known."""
MAX_EXTRAPOLATION_S = 0.05
"""The file may end this much before the last image (or start after the first): the pose
there is the end segment's, moved on at its velocity."""
MAX_TILT_DEG = 5.0
"""A pose whose z axis tilts more than this from the world's is not a planar laser's (a
camera's trajectory, whose z axis looks forward, is the usual mistake)."""


def trajectory_odometry(path: str | Path, streams: Streams) -> Odometry:
    """The laser's poses at the sequence's scan stamps from the TUM file ``path``, in the
    first scan's frame (:class:`rigcal.localize.odometry.Odometry`; every step counted as
    constrained, no fit RMS).

    Raises:
        InputError: the file is not a TUM trajectory (:func:`rigcal.io.trajectory.read_tum`:
            its stamps must increase), its poses are not planar, or it does not cover the
            sequence's images (one line naming the file, the value and what was expected).
    """
    path = Path(path)
    traj = read_tum(path)
    assert traj.stamps_s is not None
    t = traj.stamps_s
    tilt = np.degrees(np.arccos(np.clip(traj.poses[:, 2, 2], -1.0, 1.0)))
    if tilt.max() > MAX_TILT_DEG:
        n = int(np.argmax(tilt))
        raise InputError.at(
            path,
            f"pose at {float(t[n])!r} s",
            f"z axis tilted {tilt[n]:.1f} deg",
            f"the planar laser's poses (z up, within {MAX_TILT_DEG:g} deg), as `rigcal localize` writes them",
        )
    img = streams.image_stamps_s
    if len(t) < 2 or t[0] > img[0] + MAX_EXTRAPOLATION_S or t[-1] < img[-1] - MAX_EXTRAPOLATION_S:
        raise InputError.at(
            path,
            "stamps",
            f"{t[0]:.3f} to {t[-1]:.3f} s",
            f"a span covering the sequence's images, {img[0]:.3f} to {img[-1]:.3f} s, to within "
            f"{MAX_EXTRAPOLATION_S:g} s ({streams._yaml()})",
        )
    # The poses from the last at or before the first image to the first at or after the last.
    lo = max(int(np.searchsorted(t, img[0], side="right")) - 1, 0)
    hi = min(int(np.searchsorted(t, img[-1], side="left")), len(t) - 1)
    gaps = np.diff(t[lo : hi + 1])
    if len(gaps) and gaps.max() > MAX_GAP_S:
        n = lo + int(np.argmax(gaps))
        raise InputError.at(
            path,
            f"stamps after {float(t[n])!r} s",
            f"a gap of {gaps.max():.3f} s",
            f"poses at most {MAX_GAP_S:g} s apart over the sequence's images",
        )
    planar = np.column_stack([traj.poses[:, 0, 3], traj.poses[:, 1, 3], np.unwrap(_yaw(traj.poses))])
    at_scans = _planar_at(t, planar, streams.scan_stamps_s)
    T0_inv = np.linalg.inv(se2(at_scans[0]))
    poses = np.array([pose_of(T0_inv @ se2(p)) for p in at_scans])
    n_scans = len(poses)
    return Odometry(poses, np.ones(n_scans), np.full(n_scans, np.nan), 0)


def _yaw(T: FloatArray) -> FloatArray:
    """(N,) the heading of poses (N, 4, 4): their x axis's angle in the world's x-y plane."""
    out: FloatArray = np.arctan2(T[:, 1, 0], T[:, 0, 0])
    return out


def _planar_at(t: FloatArray, planar: FloatArray, at: FloatArray) -> FloatArray:
    """(M, 3) planar poses (x, y, unwrapped yaw) at the times ``at``: linear between the
    poses, the end segments' velocity for at most MAX_EXTRAPOLATION_S beyond either end
    (held further on, where the check never reads them)."""
    out = np.column_stack([np.interp(at, t, planar[:, a]) for a in range(3)])
    for end, nb, sign in ((0, 1, -1.0), (len(t) - 1, len(t) - 2, 1.0)):
        beyond = sign * (at - t[end]) > 0.0
        if beyond.any():
            v = (planar[end] - planar[nb]) / (t[end] - t[nb])
            dt = np.clip(at[beyond] - t[end], -MAX_EXTRAPOLATION_S, MAX_EXTRAPOLATION_S)
            out[beyond] = planar[end] + dt[:, None] * v
    result: FloatArray = out
    return result
