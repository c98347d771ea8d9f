"""rigcal capture: still moments of a bag (written here with rosbags) into a session; rigcal
pick on it; and the errors of both."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml
from rosbags.rosbag2 import Writer
from rosbags.typesys import Stores, get_typestore

from rigcal.calib.box.picks import read_pick_draft, read_picks
from rigcal.calib.capture import CaptureSettings, find_still_periods, still_runs
from rigcal.cli.main import main
from rigcal.errors import InputError
from rigcal.recordings.bag import import_bag
from rigcal.recordings.sequence import read_sequence
from rigcal.rig import Rig
from rigcal.rigfile import write_rig
from rigcal.sim.box_session import SessionSpec, generate_session

TS = get_typestore(Stores.ROS2_HUMBLE)
T = TS.types


def _hdr(t: float, frame: str):
    sec = int(t)
    return T["std_msgs/msg/Header"](
        stamp=T["builtin_interfaces/msg/Time"](sec=sec, nanosec=round((t - sec) * 1e9)), frame_id=frame
    )


def _scan_msg(t: float, scan):
    return T["sensor_msgs/msg/LaserScan"](
        header=_hdr(t, "laser"), angle_min=float(scan.angles_rad[0]), angle_max=float(scan.angles_rad[-1]),
        angle_increment=float(scan.angle_increment_rad), time_increment=0.0, scan_time=0.1,
        range_min=float(scan.range_min_m), range_max=float(scan.range_max_m),
        ranges=np.asarray(scan.ranges_m, np.float32), intensities=np.zeros(0, np.float32),
    )  # fmt: skip


def _image_msg(t: float, img):
    h, w = img.shape[:2]
    return T["sensor_msgs/msg/Image"](
        header=_hdr(t, "cam"), height=h, width=w, encoding="bgr8", is_bigendian=0, step=3 * w,
        data=np.ascontiguousarray(img).ravel(),
    )  # fmt: skip


def _info_msg(t: float, camera):
    K = camera.K
    roi = T["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0, do_rectify=False)
    return T["sensor_msgs/msg/CameraInfo"](
        header=_hdr(t, "cam"), height=camera.height_px, width=camera.width_px, distortion_model="plumb_bob",
        d=np.asarray(camera.distortion, float), k=K.ravel(), r=np.eye(3).ravel(),
        p=np.hstack([K, np.zeros((3, 1))]).ravel(), binning_x=0, binning_y=0, roi=roi,
    )  # fmt: skip


def write_still_bag(path: Path, scans, images, camera, still_s=1.0, move_s=0.6, rng=None) -> list[float]:
    """A bag where the rig holds still at each placement for ``still_s`` (scans at 10 Hz,
    images at 7.7 Hz, unsynchronised), then moves for ``move_s`` (scans and images
    change). Returns the start time of each still period."""
    rng = rng or np.random.default_rng(0)
    starts = []
    t0 = 100.0
    with Writer(path, version=8) as w:
        cs = w.add_connection("/scan", "sensor_msgs/msg/LaserScan", typestore=TS)
        ci = w.add_connection("/cam/image", "sensor_msgs/msg/Image", typestore=TS)
        cc = w.add_connection("/cam/info", "sensor_msgs/msg/CameraInfo", typestore=TS)
        w.write(cc, int(t0 * 1e9), TS.serialize_cdr(_info_msg(t0, camera), "sensor_msgs/msg/CameraInfo"))
        t = t0
        for scan, img in zip(scans, images, strict=True):
            starts.append(t)
            events = []
            for ts in np.arange(t, t + still_s, 0.1):
                noisy = scan.ranges_m + rng.normal(0, 0.005, len(scan.ranges_m)) * scan.valid
                events.append(
                    (
                        ts,
                        cs,
                        _scan_msg(
                            ts,
                            type(scan).from_uniform(
                                scan.angles_rad[0],
                                scan.angle_increment_rad,
                                noisy,
                                scan.range_min_m,
                                scan.range_max_m,
                            ),
                        ),
                    )
                )
            for ts in np.arange(t + 0.03, t + still_s, 0.13):
                noisy_img = np.clip(img + rng.normal(0, 1.5, img.shape), 0, 255).astype(np.uint8)
                events.append((ts, ci, _image_msg(ts, noisy_img)))
            t += still_s
            for ts in np.arange(t, t + move_s, 0.1):  # moving: everything shifts
                shift = 0.3 + rng.uniform(0, 0.5)
                moved = type(scan).from_uniform(
                    scan.angles_rad[0],
                    scan.angle_increment_rad,
                    scan.ranges_m + shift,
                    scan.range_min_m,
                    scan.range_max_m,
                )
                events.append((ts, cs, _scan_msg(ts, moved)))
                events.append(
                    (ts + 0.05, ci, _image_msg(ts + 0.05, np.roll(img, int(20 + 40 * shift), axis=1)))
                )
            t += move_s
            for ts, con, msg in sorted(events, key=lambda e: e[0]):
                w.write(con, int(ts * 1e9), TS.serialize_cdr(msg, con.msgtype))
    return starts


@pytest.fixture(scope="module")
def sim():
    return generate_session(SessionSpec(n_captures=5, seed=4, pick_sigma_px=0.0))


@pytest.fixture(scope="module")
def recorded(tmp_path_factory, sim):
    from rigcal.sim.render import render_image

    folder = tmp_path_factory.mktemp("rec")
    images = [render_image(sim.camera, sim.T_cam_laser, sim.scene(c)) for c in sim.captures]
    starts = write_still_bag(folder / "lab", [c.scan for c in sim.captures], images, sim.camera)
    return folder / "lab", starts


def test_still_runs():
    ch = np.array([0, 0, 0, 0.5, 0, 0, 0, 0, 0.9, 0])
    assert still_runs(ch, 0.01, 3) == [(0, 3), (4, 8)]
    assert still_runs(ch, 0.01, 5) == [(4, 8)]
    assert still_runs(np.array([]), 0.01, 2) == []


def test_capture_finds_one_pair_per_still_period(recorded, tmp_path):
    bag, starts = recorded
    import_bag(bag, tmp_path / "seq", "/scan", "/cam/image", "/cam/info")
    seq = read_sequence(tmp_path / "seq")
    found = find_still_periods(seq)
    assert len(found) == len(starts)
    for c, t0 in zip(found, starts, strict=True):
        assert t0 <= seq.scans[c.scan_index].stamp_s < t0 + 1.0
        assert abs(c.offset_s) <= 0.05 + 1e-9  # scans every 0.1 s: the nearest is within 50 ms
        assert c.still_scans >= 5
    # Stricter than the data allows: nothing is still long enough.
    assert find_still_periods(seq, CaptureSettings(min_frames=50)) == []


def test_capture_cli_then_pick_then_solve(recorded, sim, tmp_path, capsys):
    bag, starts = recorded
    out = tmp_path / "session"
    argv = ["capture", str(bag), "--scan-topic", "/scan", "--image-topic", "/cam/image",
            "--camera-info-topic", "/cam/info", "--box-width-m", "0.6", "-o", str(out)]  # fmt: skip
    assert main(argv) == 0
    text = capsys.readouterr().out
    assert f"{len(starts)} captures; largest stamp offset" in text
    draft = read_pick_draft(out / "picks.yaml")
    assert len(draft.captures) == len(starts)
    assert draft.box == {"width_m": 0.6}
    # The skeleton is not solvable yet, and says what to do.
    with pytest.raises(InputError, match=r"captures\[0\]\.laser_side: missing; .*rigcal pick"):
        read_picks(out / "picks.yaml")
    assert main(argv) == 5  # exists
    # Pick with a rough rig (the truth turned by 0.3 deg): every capture proposed, close to the truth.
    from rigcal.sim.box_session import moved_T_cam_laser

    rough = moved_T_cam_laser(sim.T_cam_laser, 0.3, 10.0, seed=1)
    write_rig(tmp_path / "rough.yaml", Rig(T_cam_laser=rough, camera=sim.camera))
    assert main(["pick", str(out / "picks.yaml"), "--rig", str(tmp_path / "rough.yaml"),
                 "-o", str(out / "auto.yaml"), "--sheet", str(tmp_path / "sheet.png")]) == 0  # fmt: skip
    doc = yaml.safe_load((out / "auto.yaml").read_text())
    assert doc["schema_version"] == 2
    assert all(c["pick"]["source"] == "auto" for c in doc["captures"])
    assert cv2.imread(str(tmp_path / "sheet.png")) is not None
    s = read_picks(out / "auto.yaml")
    for obs, truth in zip(s.observations, sim.captures, strict=True):
        # Along the edge the search finds the end; across it the rough pose's error remains.
        assert np.linalg.norm(obs.image_endpoints_px - truth.true_pixels, axis=1).max() < 6.0
    assert main(["solve", str(out / "auto.yaml"), "-o", str(tmp_path / "rig.yaml")]) == 0


def test_capture_errors(recorded, tmp_path, capsys):
    bag, _ = recorded
    assert main(["capture", str(bag), "-o", str(tmp_path / "s")]) == 3
    assert "both topics for a bag" in capsys.readouterr().err
    argv = [
        "capture",
        str(bag),
        "--scan-topic",
        "/scan",
        "--image-topic",
        "/cam/image",
        "-o",
        str(tmp_path / "s"),
    ]
    assert main(argv) == 3  # no camera
    assert "give --camera FILE" in capsys.readouterr().err
    assert main([*argv, "--camera-info-topic", "/cam/info", "--still-frames", "500"]) == 3
    err = capsys.readouterr().err
    # The error names the bag, not the temporary folder the bag was read into (gone by now).
    assert f"Error: {bag}: still periods: got none" in err
    assert "rigcal-capture-" not in err
    assert not (tmp_path / "s").exists()


def test_images_of_another_size_than_the_camera_are_refused(recorded, sim, tmp_path, capsys):
    from rigcal.camera import Camera, camera_to_opencv_yaml

    bag, _ = recorded
    c = sim.camera
    half = Camera.from_opencv(c.K / 2 * [[1], [1], [2]], c.distortion, c.width_px // 2, c.height_px // 2)
    (tmp_path / "half.yaml").write_text(camera_to_opencv_yaml(half))
    argv = ["capture", str(bag), "--scan-topic", "/scan", "--image-topic", "/cam/image",
            "--camera", str(tmp_path / "half.yaml"), "-o", str(tmp_path / "s")]  # fmt: skip
    assert main(argv) == 3
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert err.startswith(f"Error: {bag}: image at ")
    assert err.endswith(
        f"size: got '{c.width_px}x{c.height_px}'; expected the camera's size "
        f"{c.width_px // 2}x{c.height_px // 2} ({tmp_path / 'half.yaml'})"
    )
    assert not (tmp_path / "s").exists()
    # From a sequence folder the image file is named.
    import_bag(bag, tmp_path / "seq", "/scan", "/cam/image")
    assert main(["capture", str(tmp_path / "seq"), *argv[6:]]) == 3
    assert f"Error: {tmp_path / 'seq' / 'images'}/" in capsys.readouterr().err


def test_negative_range_stops_before_writing(recorded, tmp_path):
    import dataclasses

    from rigcal.calib.capture import write_capture_session

    bag, _ = recorded
    import_bag(bag, tmp_path / "seq", "/scan", "/cam/image", "/cam/info")
    seq = read_sequence(tmp_path / "seq")
    found = find_still_periods(seq)
    k = found[1].scan_index
    bad = seq.scans[k].ranges_m.copy()
    bad[5] = -1.0
    scans = list(seq.scans)
    scans[k] = dataclasses.replace(seq.scans[k], ranges_m=bad)
    seq = dataclasses.replace(seq, scans=tuple(scans))
    with pytest.raises(InputError, match=rf"scans\[{k}\]\.ranges_m: got -1\.0; expected ranges >= 0"):
        write_capture_session(seq, found, tmp_path / "session", tmp_path / "seq" / "camera.yaml")
    assert not (tmp_path / "session").exists()
