"""The marker method end to end: a simulated V session read with no hand input and solved;
markers of another target, a print at the wrong scale, a capture without the target, weak
views, the session file's errors, and the route from a bag (rigcal capture --target)."""

from __future__ import annotations

import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

from rigcal.calib.marker.calibrate import calibrate_marker, weak_views
from rigcal.calib.marker.session import read_marker_session
from rigcal.calib.report import truth_comparison
from rigcal.cli.main import main
from rigcal.errors import CalibrationError, InputError
from rigcal.sim.marker_session import MarkerSpec, generate_marker_session, write_marker_session

N = 8


@pytest.fixture(scope="module")
def sim():
    return generate_marker_session(MarkerSpec(n_captures=N, seed=5))


@pytest.fixture(scope="module")
def folder(tmp_path_factory, sim) -> Path:
    return write_marker_session(sim, tmp_path_factory.mktemp("marker") / "s")


@pytest.fixture(scope="module")
def solved(folder):
    return calibrate_marker(folder / "marker_session.yaml", truth_path=folder / "truth.yaml")


def _copy(folder: Path, tmp_path: Path) -> Path:
    out = tmp_path / "s"
    shutil.copytree(folder, out)
    return out


def test_recovers_the_truth_with_an_honest_covariance(solved, sim):
    r = solved.report
    assert r["summary"]["method"] == "marker"
    assert r["summary"]["captures"] == N
    assert r["summary"]["captures_found"] >= N - 1
    t = truth_comparison(solved.result.T_cam_laser, solved.result.covariance, sim.T_cam_laser)
    # Bounds from the noise: 1 cm range noise on ~16 faces gives a few tenths of a degree.
    assert t["rotation_error_deg"] < 1.0
    assert t["translation_error_mm"] < 20.0
    assert t["nees"] < 25.0  # chi-square 6 dof: 99.97 %
    assert r["marker"]["scale"]["ratio"] == pytest.approx(1.0, abs=0.01)
    assert not [w for w in r["warnings"] if "scale disagreement" in w]
    assert np.median([a for a in r["marker"]["apex_mm"].values() if a is not None]) < 15.0
    # The rig file looks like the board method's: covariance, uncertainty checks.
    assert solved.rig.covariance.shape == (6, 6)
    assert "spread" in solved.rig.uncertainty


def test_markers_of_another_target_are_ignored_and_counted(folder, tmp_path):
    s = _copy(folder, tmp_path)
    img = cv2.imread(str(s / "images" / "cap00.png"))
    d = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_4X4_50)
    for k, marker_id in enumerate((40, 41)):
        m = cv2.aruco.generateImageMarker(d, marker_id, 48, borderBits=1)
        pad = cv2.copyMakeBorder(m, 8, 8, 8, 8, cv2.BORDER_CONSTANT, value=255)
        img[10 : 10 + 64, 10 + 80 * k : 74 + 80 * k] = pad[:, :, None]
    cv2.imwrite(str(s / "images" / "cap00.png"), img)
    session = read_marker_session(s / "marker_session.yaml")
    assert session.foreign_ids == {"cap00": (40, 41)}
    cal = calibrate_marker(s / "marker_session.yaml")
    assert cal.report["marker"]["foreign_markers"] == {"captures": 1, "ids": [40, 41]}
    assert any("2 markers of another target (ids [40, 41])" in w for w in cal.report["warnings"])


def test_a_print_at_the_wrong_scale_shows_as_a_scale_disagreement(folder, tmp_path):
    s = _copy(folder, tmp_path)
    t = yaml.safe_load((s / "targets.yaml").read_text())
    # The file says 5 % smaller than printed: the camera puts every face 5 % too near.
    for f in t["faces"]:
        f["square_m"] *= 0.95
        f["marker_m"] *= 0.95
    (s / "targets.yaml").write_text(yaml.safe_dump(t))
    cal = calibrate_marker(s / "marker_session.yaml")
    ratio = cal.report["marker"]["scale"]["ratio"]
    assert ratio == pytest.approx(1 / 0.95, abs=0.01)
    assert any(
        w.startswith(f"scale disagreement: the laser puts the faces {ratio:.4f}")
        for w in cal.report["warnings"]
    )
    # And each face's own pose disagrees with the target's.
    assert any("own pose is" in w and "off the target's" in w for w in cal.report["warnings"])


def test_a_capture_without_the_target_is_set_aside_with_the_reason(folder, tmp_path):
    s = _copy(folder, tmp_path)
    cv2.imwrite(str(s / "images" / "cap03.png"), np.full((480, 640, 3), 128, np.uint8))
    session = read_marker_session(s / "marker_session.yaml")
    assert "cap03" not in session.found
    reason = dict(session.dropped)["cap03"]
    assert reason.startswith("markers: 0 ChArUco corners over both faces")
    assert "face left: 0 of its 10 markers" in reason
    assert len(session.observations) == 2 * len(session.found)


def test_a_capture_with_one_face_hidden_still_gives_both_planes(sim, folder, tmp_path):
    """The target's pose comes from every face's corners at once, so a capture whose right
    face is covered still gives both faces' planes."""
    from rigcal.geometry import transform_points
    from rigcal.sim.marker_session import T_laser_face

    s = _copy(folder, tmp_path)
    c = sim.captures[2]
    t = sim.spec.target
    T = sim.T_cam_laser @ T_laser_face(t, c.T_laser_target, 1)
    outline = np.column_stack([t.outline(1), np.zeros(4)])
    px = sim.camera.project(transform_points(T, outline))
    img = cv2.imread(str(s / "images" / "cap02.png"))
    cv2.fillConvexPoly(img, np.round(px).astype(np.int32), (128, 128, 128))
    cv2.imwrite(str(s / "images" / "cap02.png"), img)
    session = read_marker_session(s / "marker_session.yaml")
    assert "cap02" in session.found
    view = session.views[session.found.index("cap02")]
    assert view.faces[1] is None
    assert view.n_corners >= 6
    j = session.found.index("cap02")
    a, b = session.observations[2 * j : 2 * j + 2]
    assert a.pose_key == b.pose_key == "cap02"
    # Both planes where the truth puts them.
    for o, k in ((a, 0), (b, 1)):
        T_true = sim.T_cam_laser @ T_laser_face(t, c.T_laser_target, k)
        n_true = T_true[:3, 2] * np.sign(T_true[:3, 2] @ T_true[:3, 3])
        assert np.degrees(np.arccos(min(1.0, float(o.normal_cam @ n_true)))) < 1.0
        assert abs(o.distance_m - float(n_true @ T_true[:3, 3])) < 0.01


def test_one_pose_per_face_when_asked(folder, sim):
    """joint=False poses each face from its own corners (the joint pose's comparison): no
    warning that the faces disagree with the targets file, a pose fit per face."""
    cal = calibrate_marker(folder / "marker_session.yaml", joint=False)
    s = cal.session
    assert not s.rigid
    assert not s.joint
    assert len(s.pose_fits) == 2 * len(s.found)
    assert all(o.pose_key is None for o in s.observations)
    assert not [w for w in cal.report["warnings"] if "disagree with the targets file" in w]
    t = truth_comparison(cal.result.T_cam_laser, cal.result.covariance, sim.T_cam_laser)
    assert t["rotation_error_deg"] < 1.0


def test_a_capture_carries_the_scans_of_its_still_moment(sim, folder):
    doc = yaml.safe_load((folder / "marker_session.yaml").read_text())
    assert doc["schema_version"] == 2
    assert len(doc["captures"][0]["scans"]) == sim.spec.scans_per_capture == 10
    session = read_marker_session(folder / "marker_session.yaml")
    assert set(session.scans_per_capture.values()) == {10}


def test_too_few_captures_found(folder, tmp_path):
    s = _copy(folder, tmp_path)
    for k in range(N - 4):
        cv2.imwrite(str(s / "images" / f"cap{k:02d}.png"), np.full((480, 640, 3), 128, np.uint8))
    with pytest.raises(
        CalibrationError, match=r"the target was found in \d of 8 captures; the marker method needs 5"
    ):
        read_marker_session(s / "marker_session.yaml")


@pytest.mark.parametrize("swallowed", [(3,), (0, 1, 2, 3, 4, 5)])
def test_a_v_taken_for_background_is_found_where_its_pose_predicts(sim, folder, monkeypatch, swallowed):
    """With few captures the static background is not told apart reliably: a target
    standing where others stood can be dropped with it. The V is then picked where the
    image pose and the rough pose from the other captures predict its cut; when too few
    captures show a V among the moving returns for a rough pose (here 2 of 8), the
    candidates are sought among all returns."""
    from rigcal.calib.board import detect as bd

    static_returns = bd.static_returns

    def swallowing(scans, *a, **k):
        out = static_returns(scans, *a, **k)
        for i in swallowed:
            for beams in sim.captures[i].face_beams:
                out[i][beams] = True
        return out

    monkeypatch.setattr(bd, "static_returns", swallowing)
    session = read_marker_session(folder / "marker_session.yaml")
    assert set(session.found) >= {f"cap{i:02d}" for i in swallowed}
    for i in swallowed:
        j = session.found.index(f"cap{i:02d}")
        for k in range(2):
            beams = set(sim.captures[i].face_beams[k].tolist())
            pts = session.observations[2 * j + k].points_laser
            # The face's own returns: the true hits, with at most a few at the apex taken by the other.
            assert len(pts) >= len(beams) - 3


def test_a_scan_without_the_v_is_set_aside_with_the_reason(folder, tmp_path):
    s = _copy(folder, tmp_path)
    d = yaml.safe_load((s / "marker_session.yaml").read_text())
    # Capture 5's scans are copies of capture 4's: the target is not where cap05's image
    # puts it (copies: one file named by two captures is refused on its own).
    copies = []
    for name in d["captures"][4]["scans"]:
        copy = name.replace("cap04", "cap04_as_cap05")
        shutil.copyfile(s / name, s / copy)
        copies.append(copy)
    d["captures"][5]["scans"] = copies
    (s / "marker_session.yaml").write_text(yaml.safe_dump(d))
    session = read_marker_session(s / "marker_session.yaml")
    assert "cap05" not in session.found
    assert dict(session.dropped)["cap05"].startswith("the V in the scan: ")
    assert len(session.found) == N - 1


def test_check_v_against_the_targets_geometry(sim):
    """The V check under the true pose: the true arms pass; arms at the wrong angle, off
    the apex, or too short are refused with the reason."""
    from rigcal.calib.marker.session import check_v, face_shape
    from rigcal.geometry import make_T, rotvec_to_R
    from rigcal.sim.marker_session import T_laser_face

    t = sim.spec.target
    c = sim.captures[1]
    poses = tuple(sim.T_cam_laser @ T_laser_face(t, c.T_laser_target, k) for k in range(2))
    shapes = [face_shape(t, k) for k in range(2)]
    arms = tuple(c.scan.points[b[c.scan.valid[b]]] for b in c.face_beams)
    assert check_v(sim.T_cam_laser, poses, shapes, arms, 5, 0.01) is None
    # The left arm turned by 20 degrees about the apex's end of it.
    a = arms[0]
    end = a[np.argmin(np.linalg.norm(a - arms[1].mean(axis=0), axis=1))]
    turned = (a - end) @ rotvec_to_R([0, 0, np.radians(20)])[:2, :2].T + end
    assert "the arms meet at" in check_v(sim.T_cam_laser, poses, shapes, (turned, arms[1]), 5, 0.01)
    # Both arms 15 cm away along the laser's x.
    moved = tuple(x + np.array([0.15, 0.0]) for x in arms)
    why = check_v(sim.T_cam_laser, poses, shapes, moved, 5, 0.01)
    assert "from the apex the faces' pose predicts" in why
    # An arm of a few returns only, or none.
    assert "spans" in check_v(sim.T_cam_laser, poses, shapes, (a[:6], arms[1]), 5, 0.01)
    assert check_v(sim.T_cam_laser, poses, shapes, (None, arms[1]), 5, 0.01).startswith(
        "0 returns near the left"
    )
    # The faces' pose under a laser 2 m away: off the scan plane.
    far = sim.T_cam_laser @ make_T(np.eye(3), [0.0, 0.0, 2.0])
    assert "off the scan plane" in check_v(far, poses, shapes, arms, 5, 0.01)


def test_weak_views():
    rng = np.random.default_rng(0)
    yaw = rng.uniform(-1, 1, 20)
    upright = np.column_stack([-np.cos(yaw), np.sin(yaw), np.zeros(20)])
    w = weak_views(upright + rng.normal(0, 0.02, upright.shape), rng.uniform(1, 2, 20))
    assert len(w) == 1
    assert "hardly point up-down (laser z)" in w[0]
    assert "tilted" in w[0]
    tilt = rng.uniform(-0.5, 0.5, 20)
    tilted = upright * np.cos(tilt)[:, None] + np.outer(np.sin(tilt), [0, 0, 1])
    assert weak_views(tilted, rng.uniform(1, 2, 20)) == []
    near = weak_views(tilted, 1.5 + rng.uniform(0, 0.05, 20))
    assert len(near) == 1
    assert "add views nearer and farther" in near[0]


@pytest.mark.parametrize(
    ("edit", "match"),
    [
        (lambda d: d.update(method="board"), r"method: got 'board'; expected 'marker'"),
        (lambda d: d.update(schema_version=3), r"schema_version: got 3"),
        (lambda d: d.update(targets="nope.yaml"), r"targets: got 'nope.yaml'; expected an existing file"),
        (lambda d: d["captures"][1].pop("image"), r"captures\[1\]\.image: missing"),
        (
            lambda d: d["captures"][1].update(image="truth.yaml"),
            r"captures\[1\]\.image: .*an image file",
        ),
        (lambda d: d["captures"][0].update(colour=1), r"captures\[0\]\.colour: got 1; expected no such key"),
        (lambda d: d.update(captures=[]), r"captures: got \[\]; expected a non-empty list"),
        (lambda d: d["captures"][2].update(name="cap01"), r"captures\[2\]\.name: got 'cap01'"),
        (
            lambda d: d["captures"][1].update(scan="truth.yaml"),
            r"captures\[1\]: got \['image', 'name', 'scan', 'scans'\]; expected one of scan .* or scans",
        ),
        (
            lambda d: d["captures"][1].update(scans=[]),
            r"captures\[1\]\.scans: got \[\]; expected a non-empty list",
        ),
        (
            lambda d: d["captures"][1]["scans"].append("nope.yaml"),
            r"captures\[1\]\.scans\[10\]: got 'nope.yaml'; expected an existing file",
        ),
        (lambda d: d.update(schema_version=1), r"captures\[0\]\.scans: got .*; expected no such key"),
    ],
)
def test_session_errors(folder, tmp_path, edit, match):
    s = _copy(folder, tmp_path)
    d = yaml.safe_load((s / "marker_session.yaml").read_text())
    edit(d)
    (s / "marker_session.yaml").write_text(yaml.safe_dump(d))
    with pytest.raises(InputError, match=match):
        read_marker_session(s / "marker_session.yaml")


def test_cli_solve_writes_rig_and_report(folder, tmp_path, capsys):
    rig, rep = tmp_path / "rig.yaml", tmp_path / "rep"
    args = ["solve", str(folder / "marker_session.yaml"), "-o", str(rig), "--report", str(rep)]
    assert main([*args, "--truth", str(folder / "truth.yaml")]) == 0
    out = capsys.readouterr().out
    assert out.startswith("marker target 'V target' (DICT_4X4_50): found in")
    assert "error against truth" in out
    report = yaml.safe_load((rep / "report.yaml").read_text())
    assert report["summary"]["method"] == "marker"
    assert (rep / "residuals.png").is_file()
    assert rig.is_file()


def test_from_a_bag_with_no_hand_input(sim, folder, tmp_path, capsys):
    from test_capture import write_still_bag

    bag = tmp_path / "lab"
    write_still_bag(bag, [c.scan for c in sim.captures], [c.image for c in sim.captures], sim.camera)
    out = tmp_path / "v"
    args = ["capture", str(bag), "--scan-topic", "/scan", "--image-topic", "/cam/image"]
    args += ["--camera-info-topic", "/cam/info", "-o", str(out)]
    bad = tmp_path / "bad.yaml"
    bad.write_text((folder / "targets.yaml").read_text().replace("edge_m: 0.6", "edge_m: -1"))
    assert main([*args, "--target", str(bad)]) == 3
    assert not out.exists()
    assert main([*args, "--target", str(folder / "targets.yaml")]) == 0
    table = capsys.readouterr().out
    assert table.count("markers left ") == N
    assert (out / "marker_session.yaml").is_file()
    assert (out / "targets.yaml").is_file()
    # Every scan of each still moment is kept (10 Hz for about a second, the overlap with
    # the still images' run), for the solve to average.
    doc = yaml.safe_load((out / "marker_session.yaml").read_text())
    assert doc["schema_version"] == 2
    assert all(4 <= len(c["scans"]) <= 11 for c in doc["captures"])
    assert main(["solve", str(out / "marker_session.yaml"), "-o", str(tmp_path / "rig.yaml")]) == 0
    from rigcal.rigfile import read_rig

    T = read_rig(tmp_path / "rig.yaml").T_cam_laser
    t = truth_comparison(T, np.eye(6), sim.T_cam_laser)
    assert t["rotation_error_deg"] < 1.5
    assert t["translation_error_mm"] < 30.0
