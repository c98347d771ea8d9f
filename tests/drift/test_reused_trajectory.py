"""`rigcal check RIG --sequence SEQ --trajectory FILE`: the targetless check on the laser
poses of a trajectory computed before (a `rigcal localize` run's TUM file) instead of its
own laser odometry."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from test_targetless import REALISTIC, moved, run, small_camera

from rigcal.cli.main import main
from rigcal.drift.log import read_log
from rigcal.drift.trajectory import trajectory_odometry
from rigcal.errors import InputError
from rigcal.geometry import se2
from rigcal.io.trajectory import Trajectory, planar_trajectory, read_tum, write_tum
from rigcal.jobs import check_rig
from rigcal.localize.streams import open_streams
from rigcal.rig import Rig
from rigcal.rigfile import read_rig, write_rig
from rigcal.sim.box_session import default_T_cam_laser


@pytest.fixture(scope="module")
def drive(tmp_path_factory) -> dict[str, Path]:
    """A 34 s cubicle drive (5 physical corners: enough for them to judge one edge
    direction), its rig, and its laser's poses as `rigcal localize` writes them (here the
    simulator's truth: the laser's poses at the scans' stamps)."""
    base = tmp_path_factory.mktemp("trajectory")
    rig = Rig(default_T_cam_laser(), small_camera(), laser={"name": "simulated 2D scanner"})
    write_rig(base / "rig.yaml", rig)
    folder = base / "drive"
    extra = ["--world", "cubicle-loop", "--duration-s", "34", "--camera-rate-hz", "5"]
    rig_file = str(base / "rig.yaml")
    code = main(
        ["simulate", "world", "-o", str(folder), "--seed", "3", "--rig", rig_file, *REALISTIC, *extra]
    )
    assert code == 0
    return {"rig": base / "rig.yaml", "drive": folder, "truth": folder / "groundtruth.tum"}


def written(path: Path, traj: Trajectory) -> Path:
    write_tum(path, traj)
    return path


def test_the_poses_are_the_trajectory_at_the_scans_in_the_first_scans_frame(drive):
    streams = open_streams(drive["drive"], rig_file=drive["rig"])
    od = trajectory_odometry(drive["truth"], streams)
    assert od.poses.shape == (len(streams.scans), 3)
    np.testing.assert_allclose(od.poses[0], 0.0, atol=1e-12)
    # Every scan's pose against the truth, both seen from the first scan.
    truth = read_tum(drive["truth"])
    assert truth.stamps_s is not None
    T0 = truth.poses[0]
    for k in (1, len(streams.scans) // 2, len(streams.scans) - 1):
        n = int(np.argmin(np.abs(truth.stamps_s - streams.scan_stamps_s[k])))
        rel = np.linalg.inv(T0) @ truth.poses[n]
        np.testing.assert_allclose(se2(od.poses[k])[:2, 2], rel[:2, 3], atol=1e-9)
        assert math.isclose(od.poses[k][2], math.atan2(rel[1, 0], rel[0, 0]), abs_tol=1e-9)


def test_poses_between_the_trajectorys_stamps_are_interpolated(drive, tmp_path):
    """A trajectory of every 4th pose (0.1 s apart, as an image method's at the images'
    stamps) gives the scans in between their poses linearly: exact where the speed holds,
    off by at most a quarter of a speed change times the gap where it changes (the
    simulated robot starts and stops at once: 1 m/s in 0.1 s, 2.5 cm)."""
    streams = open_streams(drive["drive"], rig_file=drive["rig"])
    full = trajectory_odometry(drive["truth"], streams)
    truth = read_tum(drive["truth"])
    assert truth.stamps_s is not None
    sparse = written(tmp_path / "sparse.tum", Trajectory(truth.poses[::4], truth.stamps_s[::4]))
    od = trajectory_odometry(sparse, streams)
    err_m = np.linalg.norm(od.poses[:, :2] - full.poses[:, :2], axis=1)
    err_deg = np.degrees(np.abs(np.angle(np.exp(1j * (od.poses[:, 2] - full.poses[:, 2])))))
    assert err_m.max() < 0.025
    assert np.quantile(err_m, 0.9) < 0.001
    assert err_deg.max() < 2.0
    assert np.quantile(err_deg, 0.9) < 0.05


def test_a_reused_trajectory_checks_the_true_rig_ok_and_is_logged(drive, tmp_path, capsys):
    log = tmp_path / "log.jsonl"
    code, out, err = run(
        capsys, "check", drive["rig"], "--sequence", drive["drive"], "--trajectory", drive["truth"],
        "--log", log, "--json",
    )  # fmt: skip
    assert code == 0, err
    t = json.loads(out)["targetless"]
    assert t["trajectory"]["file"] == str(drive["truth"].resolve())
    assert len(t["trajectory"]["sha256"]) == 64
    assert {"rx", "ry"} <= set(t["observed_axes"])
    assert read_log(log)[-1]["targetless"]["trajectory"] == t["trajectory"]


def test_a_sideways_shift_of_2_cm_is_detected_on_a_reused_trajectory(drive, tmp_path, capsys):
    """The drive's 5 corners fix the yaw and both shifts and judge one direction, mostly
    the sideways shift (the rest is left to a drive with more corners)."""
    stored = moved(drive["rig"], tmp_path / "moved.yaml", 4, 0.02)
    code, out, err = run(
        capsys, "check", stored, "--sequence", drive["drive"], "--trajectory", drive["truth"], "--json"
    )
    assert code == 1, err
    t = json.loads(out)["targetless"]
    assert "ty" in t["observed_axes"]
    # The right correction is -2 cm along laser y, reported along the judged direction
    # (the yaw mixed in): a good part of it, the right sign.
    assert t["correction_translation_mm"][1] < -10.0


def _check_err(capsys, drive, traj: Path) -> str:
    code, out, err = run(
        capsys, "check", drive["rig"], "--sequence", drive["drive"], "--trajectory", traj, "--no-log"
    )
    assert code == 3, (out, err)
    assert err.count("\n") == 1
    assert err.startswith(f"Error: {traj}: ")
    return err


def test_a_trajectory_that_does_not_cover_the_images_is_bad_input(drive, tmp_path, capsys):
    truth = read_tum(drive["truth"])
    assert truth.stamps_s is not None
    half = len(truth) // 2
    cut = written(tmp_path / "cut.tum", Trajectory(truth.poses[:half], truth.stamps_s[:half]))
    err = _check_err(capsys, drive, cut)
    assert "stamps: got '0.000 to " in err
    assert "expected a span covering the sequence's images" in err


def test_a_trajectory_may_end_a_little_before_the_last_image(drive, tmp_path, capsys):
    """`localize`'s icp trajectory ends at the last scan, a few milliseconds before the
    last image at most: within 0.05 s the end segment's velocity carries it on."""
    streams = open_streams(drive["drive"], rig_file=drive["rig"])
    truth = read_tum(drive["truth"])
    assert truth.stamps_s is not None
    last = float(streams.image_stamps_s[-1])
    keep = truth.stamps_s <= last - 0.03
    near = written(tmp_path / "near.tum", Trajectory(truth.poses[keep], truth.stamps_s[keep]))
    od = trajectory_odometry(near, streams)
    full = trajectory_odometry(drive["truth"], streams)
    upto = streams.scan_stamps_s <= last  # the scans the check may read
    assert np.abs(od.poses[upto, :2] - full.poses[upto, :2]).max() < 0.005
    keep = truth.stamps_s <= last - 0.1
    far = written(tmp_path / "far.tum", Trajectory(truth.poses[keep], truth.stamps_s[keep]))
    err = _check_err(capsys, drive, far)
    assert "to within 0.05 s" in err


def test_stamps_out_of_order_are_bad_input(drive, tmp_path, capsys):
    lines = drive["truth"].read_text().splitlines()
    lines[10], lines[11] = lines[11], lines[10]
    bad = tmp_path / "swapped.tum"
    bad.write_text("\n".join(lines) + "\n")
    err = _check_err(capsys, drive, bad)
    assert "line 12: timestamp" in err
    assert "expected increasing" in err


def test_a_gap_in_the_trajectory_is_bad_input(drive, tmp_path, capsys):
    truth = read_tum(drive["truth"])
    assert truth.stamps_s is not None
    keep = (truth.stamps_s < 10.0) | (truth.stamps_s > 11.0)
    gap = written(tmp_path / "gap.tum", Trajectory(truth.poses[keep], truth.stamps_s[keep]))
    err = _check_err(capsys, drive, gap)
    assert "a gap of 1.0" in err
    assert "at most 0.5 s apart" in err


def test_a_cameras_trajectory_is_bad_input(drive, tmp_path, capsys):
    """The camera's poses (z looking forward) instead of the laser's."""
    truth = read_tum(drive["truth"])
    T_laser_cam = np.linalg.inv(read_rig(drive["rig"]).T_cam_laser)
    cam = written(tmp_path / "cam.tum", Trajectory(truth.poses @ T_laser_cam, truth.stamps_s))
    err = _check_err(capsys, drive, cam)
    assert "z axis tilted" in err
    assert "planar laser's poses" in err


def test_a_kitti_file_is_bad_input(drive, tmp_path, capsys):
    """KITTI files have no stamps: the check cannot match them to the scans."""
    truth = read_tum(drive["truth"])
    kitti = tmp_path / "poses.txt"
    kitti.write_text("".join(" ".join(repr(float(x)) for x in T[:3].ravel()) + "\n" for T in truth.poses))
    err = _check_err(capsys, drive, kitti)
    assert "got 12 fields; expected 8" in err


def test_a_missing_trajectory_is_bad_input(drive, tmp_path, capsys):
    _check_err(capsys, drive, tmp_path / "nothing.tum")


def test_trajectory_goes_with_a_sequence_only(drive, capsys):
    code, _, err = run(capsys, "check", drive["rig"], "--trajectory", drive["truth"], "--picks", drive["rig"])
    assert code == 2
    assert "--trajectory goes with --sequence" in err
    with pytest.raises(InputError, match=r"--trajectory: got .*; expected a drive's check"):
        check_rig(drive["rig"], picks=drive["rig"], trajectory=drive["truth"], no_log=True)


def test_a_planar_trajectory_as_localize_writes_it_reads_back(drive, tmp_path):
    """`rigcal localize` writes planar poses at the truth's height (planar_trajectory)."""
    streams = open_streams(drive["drive"], rig_file=drive["rig"])
    t = streams.scan_stamps_s
    yaw = np.linspace(0.0, 4.0 * math.pi, len(t))  # two full turns: the yaw is unwrapped
    xy = np.column_stack([np.cos(yaw), np.sin(yaw)])
    path = written(tmp_path / "icp.tum", planar_trajectory(t, np.column_stack([xy, yaw]), z_m=0.4))
    od = trajectory_odometry(path, streams)
    P0 = se2(np.r_[xy[0], yaw[0]])
    want = np.linalg.inv(P0) @ se2(np.r_[xy[-1], yaw[-1]])
    np.testing.assert_allclose(se2(od.poses[-1]), want, atol=1e-9)


def test_a_batch_check_item_takes_the_trajectory(drive, tmp_path):
    from rigcal.batch.manifest import Item
    from rigcal.batch.runner import run_item

    options = {"rig": drive["rig"], "sequence": drive["drive"], "trajectory": drive["truth"], "no_log": True}
    item = Item("d", "check", options)
    ran = run_item(item, tmp_path / "d", "check")
    assert ran["exit_code"] == 0, ran
    assert json.loads(ran["stdout"])["targetless"]["trajectory"]["file"] == str(drive["truth"].resolve())
