"""Visual odometry pieces: the essential-matrix pose (Eq. 5), the laser scale (Eq. 6), the chain."""

from __future__ import annotations

import numpy as np
import pytest

from rigcal.geometry import rotation_angle_rad, rotvec_to_R
from rigcal.localize.tracks import FrameTracks
from rigcal.localize.vo import (
    VoParams,
    carried_back_scale,
    carried_scale,
    laser_scale,
    refine_essential,
    relative_pose,
)
from rigcal.sim.box_session import default_camera

CAM = default_camera()
FOCAL = 520.0


def _bearings(P):
    return P / np.linalg.norm(P, axis=1, keepdims=True)


def _scene(rng, n=300):
    return np.column_stack([rng.uniform(-3, 3, n), rng.uniform(-1.5, 1.5, n), rng.uniform(2.0, 8.0, n)])


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_relative_pose_recovers_rotation_and_direction(seed):
    rng = np.random.default_rng(seed)
    P1 = _scene(rng)
    R = rotvec_to_R(rng.normal(0, 0.05, 3))
    t = np.array([0.1, -0.02, 0.3]) + rng.normal(0, 0.02, 3)
    P2 = P1 @ R.T + t
    # 0.5 px of noise on each bearing, and 10 % of matches wrong.
    b1 = _bearings(P1 + rng.normal(0, 0.5 / FOCAL, P1.shape) * P1[:, 2:3])
    b2 = _bearings(P2 + rng.normal(0, 0.5 / FOCAL, P2.shape) * P2[:, 2:3])
    bad = rng.choice(len(b2), 30, replace=False)
    b2[bad] = b2[rng.permutation(bad)]
    rel = relative_pose(b1, b2, FOCAL, VoParams())
    assert rel is not None
    assert not rel.still
    assert np.degrees(rotation_angle_rad(rel.R @ R.T)) < 0.25
    assert np.degrees(np.arccos(np.clip(rel.t_unit @ t / np.linalg.norm(t), -1, 1))) < 3.0


def test_refinement_lowers_the_error_of_a_perturbed_pose():
    rng = np.random.default_rng(5)
    P1 = _scene(rng)
    R = rotvec_to_R([0.01, 0.03, -0.02])
    t = np.array([0.2, 0.0, 0.5])
    b1, b2 = _bearings(P1), _bearings(P1 @ R.T + t)
    R0 = rotvec_to_R([0.004, -0.003, 0.002]) @ R
    t0 = t / np.linalg.norm(t) + np.array([0.03, -0.02, 0.0])
    R1, t1 = refine_essential(R0, t0 / np.linalg.norm(t0), b1, b2, iterations=10)
    assert rotation_angle_rad(R1 @ R.T) < 0.1 * rotation_angle_rad(R0 @ R.T)
    assert np.linalg.norm(t1 - t / np.linalg.norm(t)) < 1e-3


def test_a_rig_standing_still_has_no_translation():
    rng = np.random.default_rng(3)
    P1 = _scene(rng)
    R = rotvec_to_R([0.0, 0.02, 0.0])
    rel = relative_pose(_bearings(P1), _bearings(P1 @ R.T), FOCAL, VoParams())
    assert rel is not None
    assert rel.still
    assert np.allclose(rel.t_unit, 0.0)
    assert rotation_angle_rad(rel.R @ R.T) < 1e-6


def test_a_creeping_rig_is_not_turned_half_a_circle():
    # 7 mm between frames with the nearest points 0.6 m away: enough parallax to measure a
    # translation, too little for cheirality to tell R from its twisted pair reliably
    # (without the turn-only fit's check, 3 of these 24 noise draws came out 180 deg off).
    R = rotvec_to_R([0.0, 0.003, 0.0])
    t = np.array([0.006, 0.0, 0.003])
    for seed in range(24):
        rng = np.random.default_rng(seed)
        P1 = np.column_stack([rng.uniform(-2, 2, 400), rng.uniform(-1, 1, 400), rng.uniform(0.6, 2.0, 400)])
        P2 = P1 @ R.T + t
        b1 = _bearings(P1 + rng.normal(0, 0.3 / FOCAL, P1.shape) * P1[:, 2:3])
        b2 = _bearings(P2 + rng.normal(0, 0.3 / FOCAL, P2.shape) * P2[:, 2:3])
        rel = relative_pose(b1, b2, FOCAL, VoParams(), forward=np.array([0.0, 0.0, 1.0]))
        assert rel is not None
        assert not rel.still
        assert np.degrees(rotation_angle_rad(rel.R @ R.T)) < 0.5, seed
        assert rel.t_unit @ t / np.linalg.norm(t) > 0.5, seed  # not reversed (direction is loose here)


def _frames(P0, poses, rng, noise_px=0.3, ids=None):
    """FrameTracks of the points P0 (first camera) seen from cameras whose poses map the
    first camera's coordinates into theirs, with pixel noise."""
    ids = np.arange(len(P0)) if ids is None else ids
    out = []
    for R, t in poses:
        P = P0 @ R.T + t
        seen = P + rng.normal(0, noise_px / FOCAL, P.shape) * P[:, 2:3]
        # Pixels of a camera of unit focal length at the image centre: normalised coordinates.
        out.append(FrameTracks(ids, seen[:, :2] / seen[:, 2:3], _unproject))
    return out


def _unproject(xy):
    return _bearings(np.column_stack([xy, np.ones(len(xy))]))


def _carry_case(rng, ids=None, step=0.25):
    """Three frames: 0.3 m sideways and forward, then ``step`` m on while turning."""
    P0 = np.column_stack([rng.uniform(-2, 2, 300), rng.uniform(-1, 1, 300), rng.uniform(1.0, 4.0, 300)])
    R1, t1 = rotvec_to_R([0.0, 0.05, 0.0]), np.array([0.2, 0.0, 0.22])
    R2 = rotvec_to_R([0.0, 0.12, 0.0])
    t2 = step * np.array([0.6, 0.0, 0.8])
    # Frame 2's pose in frame 0's coordinates: x2 = R2 (R1 x0 + t1) + t2.
    frames = _frames(P0, [(np.eye(3), np.zeros(3)), (R1, t1), (R2 @ R1, R2 @ t1 + t2)], rng, ids=ids)
    return frames, (R1, t1), (R2, t2)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_tracks_carry_the_scale_of_the_run_before(seed):
    rng = np.random.default_rng(seed)
    (f0, f1, f2), before, (R2, t2) = _carry_case(rng)
    unit = t2 / np.linalg.norm(t2)
    est = carried_scale(f0, f1, f2, before, (R2, unit), FOCAL, VoParams())
    assert est.used >= 0.8 * 300
    assert est.scale == pytest.approx(0.25, rel=0.01)
    # The run before's scale is what it carries: twice the length before, twice this one.
    R1, t1 = before
    twice = carried_scale(f0, f1, f2, (R1, 2.0 * t1), (R2, unit), FOCAL, VoParams())
    assert twice.scale == pytest.approx(2 * est.scale, rel=0.01)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_tracks_carry_the_scale_back_from_the_run_after(seed):
    rng = np.random.default_rng(seed)
    (f0, f1, f2), (R1, t1), (R2, t2) = _carry_case(rng)
    est = carried_back_scale(f0, f1, f2, (R1, t1 / np.linalg.norm(t1)), (R2, t2), FOCAL, VoParams())
    assert est.used >= 0.8 * 300
    assert est.scale == pytest.approx(np.linalg.norm(t1), rel=0.01)
    # Carried forward from that scale, the run after's comes back.
    forward = carried_scale(
        f0, f1, f2, (R1, est.scale * t1 / np.linalg.norm(t1)), (R2, t2 / 0.25), FOCAL, VoParams()
    )
    assert forward.scale == pytest.approx(0.25, rel=0.01)


def test_a_turn_on_the_spot_carries_no_scale():
    # Without translation the rays of this run do not meet: no track votes.
    rng = np.random.default_rng(7)
    (f0, f1, f2), before, (R2, _) = _carry_case(rng, step=0.0)
    est = carried_scale(f0, f1, f2, before, (R2, np.array([0.6, 0.0, 0.8])), FOCAL, VoParams())
    assert est.used == 0
    assert np.isnan(est.scale)


def test_tracks_lost_between_the_runs_carry_no_scale():
    rng = np.random.default_rng(8)
    (f0, f1, f2), before, (R2, t2) = _carry_case(rng)
    # Only 5 of the first frame's tracks are still alive at the run's end.
    f2 = FrameTracks(f2.ids[:5], f2.pixels[:5], f2.unproject)
    est = carried_scale(f0, f1, f2, before, (R2, t2 / np.linalg.norm(t2)), FOCAL, VoParams())
    assert est.used == 0


def test_too_few_matches_fail():
    rng = np.random.default_rng(4)
    P1 = _scene(rng, n=10)
    assert relative_pose(_bearings(P1), _bearings(P1 + np.array([0.1, 0, 0.2])), FOCAL, VoParams()) is None


@pytest.mark.parametrize(("t", "depth"), [((0.05, 0.0, 0.3), 3.0), ((0.2, 0.0, 0.1), 2.5)])
def test_laser_scale_from_patches_on_a_textured_wall(texture, wall_image, t, depth):
    t = np.array(t)
    R = rotvec_to_R([0.0, 0.03, 0.0])
    img1 = wall_image(np.eye(3), np.zeros(3), depth, texture)
    img2 = wall_image(R, t, depth, texture)
    # The laser's line across the wall, 10 cm below the optical axis.
    x = np.linspace(-2.0, 2.0, 200)
    P1 = np.column_stack([x, np.full_like(x, 0.1), np.full_like(x, depth)])
    est = laser_scale(img1, img2, CAM, R, t / np.linalg.norm(t), P1, 1.0, VoParams())
    assert est.used > 20
    assert est.scale == pytest.approx(np.linalg.norm(t), rel=0.03)


def test_laser_scale_on_a_blank_wall_has_no_votes(texture):
    blank = np.full((CAM.height_px, CAM.width_px), 128, dtype=np.uint8)
    x = np.linspace(-2.0, 2.0, 50)
    P1 = np.column_stack([x, np.full_like(x, 0.1), np.full_like(x, 3.0)])
    est = laser_scale(blank, blank, CAM, np.eye(3), np.array([0.0, 0.0, 1.0]), P1, 1.0, VoParams())
    assert est.used == 0
    assert np.isnan(est.scale)


@pytest.mark.parametrize("seed", range(6))
def test_a_turn_while_moving_forward_is_not_taken_for_a_sideways_move(seed):
    """A narrow view of walls at similar depth: a turn while moving forward and a larger
    turn while moving sideways explain the image motion almost equally (bas-relief); the
    rig's direction of travel as a start picks the right one."""
    rng = np.random.default_rng(seed)
    n = 250
    # Points on the walls ahead: 3-6 m away, within +-25 deg of the optical axis.
    az = rng.uniform(-0.45, 0.45, n)
    el = rng.uniform(-0.3, 0.3, n)
    depth = rng.uniform(3.0, 6.0, n)
    P1 = np.column_stack([np.tan(az), np.tan(el), np.ones(n)]) * depth[:, None]
    yaw = 0.35  # 20 deg about the camera's vertical (y) axis
    R = rotvec_to_R([0.0, yaw, 0.0])
    c = np.array([0.05, 0.0, 0.45])  # forward travel, camera frame
    t = -R @ c
    P2 = P1 @ R.T + t
    b1 = _bearings(P1 + rng.normal(0, 0.3 / FOCAL, P1.shape) * P1[:, 2:3])
    b2 = _bearings(P2 + rng.normal(0, 0.3 / FOCAL, P2.shape) * P2[:, 2:3])
    rel = relative_pose(b1, b2, FOCAL, VoParams(), forward=np.array([0.0, 0.0, 1.0]))
    assert rel is not None
    assert np.degrees(rotation_angle_rad(rel.R @ R.T)) < 0.5
    # Direction and sign: the points triangulate in front.
    assert np.degrees(np.arccos(np.clip(rel.t_unit @ t / np.linalg.norm(t), -1, 1))) < 5.0


def test_every_run_through_the_first_corner_turns_by_the_true_angle(tmp_path):
    """The corridor loop's first corner (simulated, seed 1): over 20 deg of turn within a
    run, and each run's turn within half a degree of the truth."""
    from rigcal.io.trajectory import read_tum
    from rigcal.localize.pipeline import _vo_result, planar_at
    from rigcal.localize.streams import open_streams
    from rigcal.localize.vo import visual_odometry
    from rigcal.sim.drive import DriveSpec, write_drive
    from rigcal.sim.world import corridor_loop

    write_drive(corridor_loop(), DriveSpec(seed=1, duration_s=2.4), str(tmp_path / "seq"))
    streams = open_streams(tmp_path / "seq")
    res = _vo_result(streams)
    truth = planar_at(read_tum(tmp_path / "seq" / "groundtruth.tum"), streams.image_stamps_s[res.frames])
    turned = np.diff(res.poses[:, 2])
    true_turn = np.diff(truth[:, 2])
    assert np.abs(true_turn).max() > np.radians(15)  # the corner is in there
    assert np.degrees(np.abs(turned - true_turn)).max() < 0.5
    # The runs measured on one thread give the same odometry as on two (the default).
    rig = streams.rig
    assert rig is not None
    one = visual_odometry(
        streams.feature_tracks(),
        streams.image,
        streams.image_stamps_s,
        rig.camera,
        rig.T_cam_laser,
        streams.laser_points_at_image,
        workers=1,
    )
    assert one.steps == res.steps
    assert np.array_equal(one.poses, res.poses)


@pytest.mark.parametrize(
    ("detector", "laser_again", "carried_at_least"),
    [("sift", None, 4), ("shi-tomasi", None, 2), ("shi-tomasi", 19, 3)],
)
def test_the_tracks_carry_the_scale_where_the_laser_gives_none(
    tmp_path, detector, laser_again, carried_at_least
):
    """The corridor loop's first seconds (simulated, seed 1) with the laser's points taken
    away after the first frames (and given back from frame ``laser_again`` on): the runs
    between take their scale from the tracks, each to a few percent of its true length,
    while tracks live across three frames. A run whose first and last frames share no
    track with the run before's first frame takes it back from the run after, if that
    one has a scale; else it moves at the last measured speed ("no-scale")."""
    from rigcal.io.trajectory import read_tum
    from rigcal.localize.pipeline import planar_at
    from rigcal.localize.streams import open_streams
    from rigcal.localize.tracks import TrackParams
    from rigcal.localize.vo import visual_odometry
    from rigcal.sim.drive import DriveSpec, write_drive
    from rigcal.sim.world import corridor_loop

    write_drive(corridor_loop(), DriveSpec(seed=1, duration_s=2.4), str(tmp_path / "seq"))
    streams = open_streams(tmp_path / "seq")
    streams.track_params = TrackParams(detector=detector)
    streams.laser_odometry()
    rig = streams.rig
    assert rig is not None

    def first_frames_only(i: int):
        given = i < 3 or (laser_again is not None and i >= laser_again)
        return streams.laser_points_at_image(i) if given else np.zeros((0, 2))

    tracks = streams.feature_tracks()
    res = visual_odometry(
        tracks, streams.image, streams.image_stamps_s, rig.camera, rig.T_cam_laser, first_frames_only
    )
    status = [s.status for s in res.steps]
    assert status[0] == "ok"
    assert status[1 : 1 + carried_at_least] == ["carried"] * carried_at_least
    if laser_again is None:
        assert set(status[1:]) <= {"carried", "no-scale"}
    else:
        assert status == ["ok", "carried", "carried", "carried", "ok"]
        assert res.steps[-1].first == laser_again  # the run that carries the scale back
    truth = planar_at(read_tum(tmp_path / "seq" / "groundtruth.tum"), streams.image_stamps_s[res.frames])
    step = np.linalg.norm(np.diff(res.poses[:, :2], axis=0), axis=1)
    true_step = np.linalg.norm(np.diff(truth[:, :2], axis=0), axis=1)
    for k, s in enumerate(res.steps):
        if s.status == "carried":
            assert step[k] == pytest.approx(true_step[k], rel=0.05), k
        elif s.status == "no-scale":  # nothing to carry: the run before had no scale either,
            before = res.steps[k - 1]  # or no track is alive in the three frames
            alive = np.intersect1d(tracks[before.first].ids, tracks[s.first].ids)
            tracked = len(np.intersect1d(alive, tracks[s.last].ids))
            assert before.status == "no-scale" or tracked < VoParams().min_scale_votes
            assert k == len(res.steps) - 1 or res.steps[k + 1].status == "no-scale"  # nor after


def test_laser_scale_divides_out_the_second_images_exposure_gain(texture, wall_image):
    """The second image 35 % brighter (automatic exposure): the SAD along the epipolar
    line loses most of its votes to the gain; with the gain measured on the tracks they
    are back."""
    from rigcal.localize.tracks import gain_between

    t, depth = np.array([0.05, 0.0, 0.3]), 3.0
    R = rotvec_to_R([0.0, 0.03, 0.0])
    img1 = (wall_image(np.eye(3), np.zeros(3), depth, texture).astype(float) * 0.6).astype(np.uint8)
    img2 = np.clip(np.round(wall_image(R, t, depth, texture) * 0.6 * 1.35), 0, 255).astype(np.uint8)
    x = np.linspace(-2.0, 2.0, 200)
    P1 = np.column_stack([x, np.full_like(x, 0.1), np.full_like(x, depth)])
    # Points seen in both images, as the tracks give them.
    grid = np.stack(np.meshgrid(np.linspace(-1.5, 1.5, 12), np.linspace(-1.0, 1.0, 8)), -1).reshape(-1, 2)
    Q = np.column_stack([grid, np.full(len(grid), depth)])
    gain = gain_between(img1, CAM.project(Q), img2, CAM.project(Q @ R.T + t))
    assert gain == pytest.approx(1.35, rel=0.01)
    unit = t / np.linalg.norm(t)
    raw = laser_scale(img1, img2, CAM, R, unit, P1, 1.0, VoParams())
    fixed = laser_scale(img1, img2, CAM, R, unit, P1, 1.0, VoParams(), gain)
    assert fixed.used > 20
    assert fixed.scale == pytest.approx(np.linalg.norm(t), rel=0.03)
    assert fixed.used > 2 * raw.used or not np.isfinite(raw.scale)


def test_a_still_runs_yaw_takes_the_rotation_its_still_test_lets_through():
    from rigcal.localize.vo import VoParams, still_rotation_covariance

    cov = np.diag([1e-6, 1e-6, 1e-10])
    out = still_rotation_covariance(cov, 520.0)
    assert out[2, 2] == pytest.approx(1e-10 + (VoParams().still_px / 520.0) ** 2 / 3.0)
    assert np.array_equal(out[:2], cov[:2])  # the rest kept
    assert cov[2, 2] == 1e-10  # the input untouched
    # A stricter still test lets less through.
    assert still_rotation_covariance(cov, 520.0, VoParams(still_px=0.3))[2, 2] < out[2, 2]
