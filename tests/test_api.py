"""The Python API (docs/api.md): `import rigcal` alone, the same answers as the CLI to the
last digit (one solve path per method), its argument checks and errors, the streaming
laser odometry, trajectories, and the documented example run as a script."""

from __future__ import annotations

import json
import re
import runpy
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

import rigcal
from rigcal.camera import read_camera
from rigcal.cli.main import main
from rigcal.errors import ArgumentError, InputError, OutputError
from rigcal.lines import LineParams, extract_lines
from rigcal.scan import read_scan
from rigcal.sim.board_session import BoardSpec, generate_board_session, write_board_session
from rigcal.sim.box_session import SessionSpec, generate_session, write_session

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def sim():
    return generate_session(SessionSpec(n_captures=8, seed=21))


def captures(sim):
    return [rigcal.BoxCapture(c.scan, c.segment_id, c.picked_pixels, c.name) for c in sim.captures]


def plain(doc):
    """A report as JSON carries it (tuples as lists; floats exact)."""
    return json.loads(json.dumps(doc))


def test_import_rigcal_exports_the_api_and_loads_it_lazily():
    code = "import sys, rigcal; print('rigcal.api' in sys.modules, callable(rigcal.solve_box))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.split() == ["False", "True"]
    assert set(rigcal.__all__) <= set(dir(rigcal))
    for name in rigcal.__all__:
        assert getattr(rigcal, name) is not None
    with pytest.raises(AttributeError, match="no attribute 'nope'"):
        rigcal.nope  # noqa: B018


def test_the_shared_option_rules_keep_the_command_line_light():
    """rigcal solve declares its options with calib/options' types: importing the command
    line must not import the solver (``rigcal --help`` stays instant)."""
    code = (
        "import sys, rigcal.cli.main; "
        "print(sorted(m for m in ('rigcal.calib.box.solve', 'rigcal.calib.box.refine', 'numpy', 'scipy') "
        "if m in sys.modules))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"


def test_the_package_ships_py_typed_and_the_wheel_takes_the_whole_package():
    assert (ROOT / "src" / "rigcal" / "py.typed").is_file()
    import tomllib

    wheel = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["hatch"]["build"]["targets"]["wheel"]
    assert wheel["packages"] == ["src/rigcal"]
    assert "exclude" not in wheel
    assert "only-include" not in wheel


# --- one solve path: in memory equals the file solve to the last digit ---------------------


def _box_from_files(folder: Path):
    """The picking file's captures rebuilt in memory, as a user holding the same data would."""
    doc = yaml.safe_load((folder / "picks.yaml").read_text())
    sigma = doc["laser"]["range_sigma_m"]
    caps = [
        rigcal.BoxCapture(
            read_scan(folder / c["scan"]), c["laser_side"]["segment"], c["image_endpoints_px"], c["name"]
        )
        for c in doc["captures"]
    ]
    return caps, read_camera(folder / doc["camera"]), sigma


def test_solve_box_in_memory_equals_the_file_solve_and_the_command_line(sim, tmp_path, capsys):
    write_session(sim, tmp_path / "s", render_images=False)
    picks = tmp_path / "s" / "picks.yaml"
    caps, camera, sigma = _box_from_files(tmp_path / "s")
    mem = rigcal.solve_box(caps, camera, range_sigma_m=sigma)
    from_file = rigcal.solve_box(picks)
    np.testing.assert_array_equal(mem.rig.T_cam_laser, from_file.rig.T_cam_laser)
    np.testing.assert_array_equal(mem.rig.covariance, from_file.rig.covariance)
    assert plain(mem.report) == plain(from_file.report)
    assert mem.rig.uncertainty == from_file.rig.uncertainty
    assert main(["solve", str(picks), "-o", str(tmp_path / "rig.yaml"), "--json"]) == 0
    cli = json.loads(capsys.readouterr().out)
    assert cli["rig"]["T_cam_laser"] == mem.rig.T_cam_laser.tolist()
    assert cli["rig"]["covariance"] == mem.rig.covariance.tolist()
    for key in ("summary", "noise", "uncertainty", "rejected", "warnings"):
        assert cli[key] == plain(mem.report[key]), key
    # The options reach the same solver: the paper's endpoints and another loss change it.
    other = rigcal.solve_box(caps, camera, range_sigma_m=sigma, loss="linear", paper_endpoints=True)
    assert not np.array_equal(other.rig.T_cam_laser, mem.rig.T_cam_laser)
    assert other.rig.provenance["refine"] == {"use_side_points": False, "loss": "linear", "loss_scale": 3.0}


def _board_from_files(folder: Path):
    doc = yaml.safe_load((folder / "board_session.yaml").read_text())
    sigma = doc["laser"]["range_sigma_m"]
    params = LineParams.for_range_noise(sigma)
    caps = []
    for c in doc["captures"]:
        segments = extract_lines(read_scan(folder / c["scan"]), params)
        ids = c["laser_side"].get("segments", [c["laser_side"].get("segment")])
        pieces = sorted((segments[i] for i in ids), key=lambda g: int(g.indices[0]))
        points = np.concatenate([np.array(g.points) for g in pieces])
        caps.append(rigcal.BoardCapture(c["corners_px"], points, c["name"]))
    b = doc["board"]
    board = rigcal.Board(b["corners_x"], b["corners_y"], b["spacing_m"])
    return caps, read_camera(folder / doc["camera"]), board, sigma, b.get("corner_sigma_px", 0.5)


def test_solve_board_in_memory_equals_the_file_solve_and_the_command_line(tmp_path, capsys):
    spec = BoardSpec(n_captures=8, seed=4)
    sim = generate_board_session(spec)
    write_board_session(sim, tmp_path / "b")
    session = tmp_path / "b" / "board_session.yaml"
    caps, camera, board, sigma, corner_sigma = _board_from_files(tmp_path / "b")
    mem = rigcal.solve_board(caps, camera, board, corner_sigma_px=corner_sigma, T_truth=sim.T_cam_laser)
    from_file = rigcal.solve_board(session, T_truth=sim.T_cam_laser)
    np.testing.assert_array_equal(mem.rig.T_cam_laser, from_file.rig.T_cam_laser)
    np.testing.assert_array_equal(mem.rig.covariance, from_file.rig.covariance)
    # The same report, but for the note on the camera's uncertainty, which names the camera
    # file where there is one (the in-memory camera has none), and each capture's count of
    # scans, which only a capture read from scan files has (one scan each here).
    mem_doc, file_doc = plain(mem.report), plain(from_file.report)
    mem_cam, file_cam = mem_doc["uncertainty"].pop("camera"), file_doc["uncertainty"].pop("camera")
    assert [c.pop("scans") for c in file_doc["per_capture"]] == [1] * len(caps)
    assert not any("scans" in c for c in mem_doc["per_capture"])
    assert mem_doc == file_doc
    assert mem_cam["included"] is file_cam["included"] is False
    assert "camera.yaml" in file_cam["note"]
    assert "--intrinsics-sigma" in mem_cam["note"]
    # The data's own noise estimates and the uncertainty block, as the command line's.
    assert mem.report["noise"]["range_sigma_m"]["estimated"] is not None
    assert "spread" in mem.report["uncertainty"] or mem.report["uncertainty"]
    assert mem.report["truth"]["rotation_error_deg"] < 1.0
    assert main(["solve", str(session), "-o", str(tmp_path / "rig.yaml"), "--json"]) == 0
    cli = json.loads(capsys.readouterr().out)
    assert cli["rig"]["T_cam_laser"] == mem.rig.T_cam_laser.tolist()
    assert cli["rig"]["covariance"] == mem.rig.covariance.tolist()
    assert cli["uncertainty"]["camera"] == file_cam
    assert cli["uncertainty"] == mem_doc["uncertainty"] | {"camera": file_cam}
    for key in ("summary", "noise", "warnings"):
        assert cli[key] == plain(mem.report[key]), key
    assert [c.pop("scans") for c in cli["per_capture"]] == [1] * len(caps)
    assert cli["per_capture"] == mem_doc["per_capture"]
    # --noise assumed and --no-range-bias, from the API.
    fixed = rigcal.solve_board(caps, camera, board, range_sigma_m=sigma, noise="assumed", range_bias=False)
    assert fixed.rig.provenance["noise"]["mode"] == "assumed"
    assert fixed.report["summary"]["range_bias_sigma_mm"] is None


# --- argument checks: ArgumentError naming the function, argument and value ------------------


def test_solve_box_refuses_what_the_command_line_refuses(sim):
    caps = captures(sim)
    cases = [
        ({"range_sigma_m": float("nan")}, r"rigcal\.solve_box: range_sigma_m: got nan; expected a finite"),
        ({"range_sigma_m": 0.0}, r"range_sigma_m: got 0\.0; expected a finite number x>=1e-05"),
        ({"pick_sigma_px": -1}, r"pick_sigma_px: got -1; expected a finite number x>=0\.001"),
        ({"threshold_px": "6"}, r"threshold_px: got '6'"),
        ({"seed": -1}, r"seed: got -1; expected an integer x>=0"),
        ({"seed": 1.5}, r"seed: got 1\.5"),
        ({"noise": "estimated"}, r"noise: got 'estimated'; expected one of auto, assumed"),
        ({"loss": "l2"}, r"loss: got 'l2'; expected one of linear, huber, soft_l1, cauchy"),
        ({"paper_endpoints": "yes"}, r"paper_endpoints: got 'yes'; expected True or False"),
        ({"T_truth": np.eye(3)}, r"T_truth: got 'an array of shape \(3, 3\)'; expected shape \(4x4\)"),
        ({"T_truth": np.full((4, 4), np.nan)}, r"T_truth\[0\]\[0\]: got nan"),
        ({"T_truth": 2 * np.eye(4)}, r"T_truth\[3\]: got \[0\.0, 0\.0, 0\.0, 2\.0\]"),
        ({"T_truth": np.diag([2.0, 1, 1, 1])}, r"T_truth\[:3, :3\]: .*expected a rotation matrix"),
        ({"T_truth": "eye"}, r"T_truth: got 'eye'"),
    ]
    for kwargs, message in cases:
        with pytest.raises(ArgumentError, match=message):
            rigcal.solve_box(caps, sim.camera, **kwargs)


def test_the_command_line_refuses_the_same_values_as_a_usage_error(tmp_path, capsys):
    out = str(tmp_path / "rig.yaml")
    for option, value in (("--seed", "-1"), ("--range-sigma-m", "nan"), ("--loss", "l2"), ("--noise", "x")):
        assert main(["solve", str(tmp_path / "picks.yaml"), "-o", out, option, value]) == 2
        assert value in capsys.readouterr().err


def test_solve_box_bad_captures_name_the_capture_and_value(sim, tmp_path):
    caps = captures(sim)
    cases = [
        ((caps,), r"camera: got None; expected a rigcal\.Camera"),
        ((caps, "camera.yaml"), r"camera: got 'camera\.yaml'; expected a rigcal\.Camera"),
        ((42, sim.camera), r"captures: got 42; expected a session file path or a non-empty list"),
        (([], sim.camera), r"captures: got \[\]"),
        (([*caps[:2], "cap"], sim.camera), r"captures\[2\]: got 'cap'; expected a rigcal\.BoxCapture"),
        ((tmp_path / "picks.yaml", sim.camera), r"camera: got 'Camera'; expected None with a picking file"),
    ]
    for args, message in cases:
        with pytest.raises(ArgumentError, match=message):
            rigcal.solve_box(*args)
    bad_camera = rigcal.Camera("LENSMODEL_OPENCV5", [np.nan, 500, 320, 240, 0, 0, 0, 0, 0], 640, 480)
    with pytest.raises(ArgumentError, match=r"camera\.intrinsics\[0\]: got nan"):
        rigcal.solve_box(caps, bad_camera)

    def one_bad(i, **change):
        c = caps[i]
        fields = {"scan": c.scan, "side": c.side, "image_endpoints_px": c.image_endpoints_px, "name": c.name}
        return [*caps[:i], rigcal.BoxCapture(**(fields | change)), *caps[i + 1 :]]

    cases2 = [
        (one_bad(2, side=999), r"captures\[2\]\.side: got 999; expected a segment id from 0 to"),
        (one_bad(0, side=[3]), r"captures\[0\]\.side: got \[3\]; expected a segment id, or 2 or more"),
        (one_bad(0, side=[5, 3]), r"captures\[0\]\.side: got \[5, 3\]; .*increasing"),
        (one_bad(0, side=[0.5, 3.5]), r"captures\[0\]\.side: got \[0\.5, 3\.5\]"),
        (one_bad(0, side=True), r"captures\[0\]\.side: got True"),
        (one_bad(0, image_endpoints_px=[[-5.0, 1.0], [10.0, 10.0]]), r"image_endpoints_px: got \[\[-5\.0"),
        (one_bad(1, image_endpoints_px=[[np.nan, 1], [1, 1]]), r"image_endpoints_px\[0\]\[0\]: got nan"),
        (one_bad(1, image_endpoints_px=[1, 2, 3]), r"\[1\]\.image_endpoints_px: got 'an array of shape"),
        (one_bad(1, scan="scan.yaml"), r"captures\[1\]\.scan: got 'scan\.yaml'; expected a rigcal\.Scan"),
        (one_bad(1, name="../x"), r"captures\[1\]\.name: got '\.\./x'"),
        (one_bad(1, name=caps[0].name), r"captures\[1\]\.name: got '.*'; expected a name not used"),
    ]
    for bad, message in cases2:
        with pytest.raises(ArgumentError, match=message):
            rigcal.solve_box(bad, sim.camera)


def test_solve_board_bad_arguments_name_the_argument():
    spec = BoardSpec(n_captures=3, seed=1)
    sim = generate_board_session(spec)
    board = rigcal.Board(spec.board.width_n, spec.board.height_n, spec.board.spacing_m)
    good = [
        rigcal.BoardCapture(c.corners_px, c.scan.points[extract_lines(c.scan)[c.segment_id].indices], c.name)
        for c in sim.captures
    ]
    n = board.width_n * board.height_n
    cases = [
        ((good, sim.camera), {}, r"rigcal\.solve_board: board: got None; expected a rigcal\.Board"),
        ((good, sim.camera, (8, 6, 0.1)), {}, r"board: got \(8, 6, 0\.1\)"),
        ((good, sim.camera, board), {"range_sigma_m": float("nan")}, r"range_sigma_m: got nan"),
        ((good, sim.camera, board), {"corner_sigma_px": 0}, r"corner_sigma_px: got 0; expected a finite"),
        ((good, sim.camera, board), {"noise": "auto "}, r"noise: got 'auto '"),
        ((good, sim.camera, board), {"range_bias": 1}, r"range_bias: got 1; expected True or False"),
        ((good, sim.camera, board), {"T_truth": np.eye(3)}, r"T_truth: got 'an array of shape \(3, 3\)'"),
        (
            ([rigcal.BoardCapture(np.eye(4), good[0].points_laser)], sim.camera, board),
            {},
            rf"corners_px: .*\({n}x2\)",
        ),
        (
            ([rigcal.BoardCapture(np.full((n, 2), np.nan), good[0].points_laser)], sim.camera, board),
            {},
            r"captures\[0\]\.corners_px\[0\]\[0\]: got nan",
        ),
        (
            ([rigcal.BoardCapture(good[0].corners_px, np.zeros((1, 2)))], sim.camera, board),
            {},
            r"captures\[0\]\.points_laser: got \[\[0\.0, 0\.0\]\]; expected 2 or more",
        ),
        (([good[0], object()], sim.camera, board), {}, r"captures\[1\]: got <object"),
        (("session.yaml", sim.camera), {}, r"camera: got 'Camera'; expected None with a session file"),
    ]
    for args, kwargs, message in cases:
        with pytest.raises(ArgumentError, match=message):
            rigcal.solve_board(*args, **kwargs)


def test_write_rig_refuses_a_rig_read_rig_would_refuse_and_writes_nothing(sim, tmp_path):
    sol = rigcal.solve_box(captures(sim), sim.camera)
    from dataclasses import replace

    T = sol.rig.T_cam_laser.copy()
    T[0, 3] = np.nan
    out = tmp_path / "rig.yaml"
    with pytest.raises(ArgumentError, match=r"rigcal\.write_rig: rig\.T_cam_laser\[0\]\[3\]: got nan"):
        rigcal.write_rig(out, replace(sol.rig, T_cam_laser=T))
    T = sol.rig.T_cam_laser.copy()
    T[0, 3] = 5000.0
    with pytest.raises(ArgumentError, match=r"rig\.T_cam_laser\.translation_m\[0\]: got 5000\.0"):
        rigcal.write_rig(out, replace(sol.rig, T_cam_laser=T))
    cov = sol.rig.covariance.copy()
    cov[0, 0] = -1.0
    with pytest.raises(ArgumentError, match=r"rig\.uncertainty\.covariance"):
        rigcal.write_rig(out, replace(sol.rig, covariance=cov))
    with pytest.raises(ArgumentError, match=r"rig\.camera: got 'cam'; expected a rigcal\.Camera"):
        rigcal.write_rig(out, replace(sol.rig, camera="cam"))
    with pytest.raises(ArgumentError, match=r"rigcal\.write_rig: rig\.laser: got \[1\]; expected a mapping"):
        rigcal.write_rig(out, replace(sol.rig, laser=[1]))
    bad_camera = rigcal.Camera("LENSMODEL_OPENCV5", [500, -1, 320, 240, 0, 0, 0, 0, 0], 640, 480)
    with pytest.raises(ArgumentError, match=r"rig\.camera\.intrinsics: got \[500\.0, -1\.0"):
        rigcal.write_rig(out, replace(sol.rig, camera=bad_camera))
    with pytest.raises(ArgumentError, match=r"rig: got 'rig'; expected a rigcal\.Rig"):
        rigcal.write_rig(out, "rig")
    with pytest.raises(ArgumentError, match=r"path: got 3"):
        rigcal.write_rig(3, sol.rig)
    with pytest.raises(ArgumentError, match=r"force: got 'no'"):
        rigcal.write_rig(out, sol.rig, force="no")
    assert not out.exists()
    rigcal.write_rig(out, sol.rig)
    again = rigcal.read_rig(out)
    sig = again.sigmas()
    assert sig is not None
    np.testing.assert_allclose(sig.rotation_deg, sol.rig.sigmas().rotation_deg, rtol=1e-5)
    assert sig[1] is sig.translation_mm  # still a pair
    with pytest.raises(OutputError, match="exists"):
        rigcal.write_rig(out, sol.rig)
    with pytest.raises(ArgumentError, match=r"rigcal\.read_rig: path: got None"):
        rigcal.read_rig(None)


def test_the_library_writer_refuses_an_invalid_rig_too(sim, tmp_path):
    from dataclasses import replace

    from rigcal.rigfile import write_rig

    sol = rigcal.solve_box(captures(sim), sim.camera)
    T = sol.rig.T_cam_laser.copy()
    T[1, 3] = np.inf
    with pytest.raises(OutputError, match=r"rig\.yaml: not written: the rig is invalid: .*_laser\[1\]\[3\]"):
        write_rig(tmp_path / "rig.yaml", replace(sol.rig, T_cam_laser=T))
    assert not (tmp_path / "rig.yaml").exists()


def test_localize_checks_its_arguments_before_working(tmp_path):
    seq = tmp_path / "nope"
    cases = [
        (([],), r"rigcal\.localize: methods: got \[\]; expected a method name or a non-empty list"),
        (("icpx",), r"rigcal\.localize: methods: got 'icpx'; expected one of \["),
        (("icp,icp",), r"methods: got 'icp,icp'; expected one or more distinct methods"),
        ((["icp", 3],), r"methods: got \['icp', 3\]"),
        ((None,), r"methods: got None"),
    ]
    for args, message in cases:
        with pytest.raises(ArgumentError, match=message):
            rigcal.localize(seq, *args)
    with pytest.raises(ArgumentError, match=r"rigcal\.localize: tracks: got 'clahe'; expected a mapping"):
        rigcal.localize(seq, "vo", tracks="clahe")
    with pytest.raises(ArgumentError, match=r"rigcal\.localize: sequence: got 7"):
        rigcal.localize(7)
    with pytest.raises(ArgumentError, match=r"force: got 1"):
        rigcal.localize(seq, force=1)
    with pytest.raises(ArgumentError, match=r"localize: wheel_odometry: got 'use'; expected True or False"):
        rigcal.localize(seq, wheel_odometry="use")
    (tmp_path / "out").mkdir()
    with pytest.raises(OutputError, match="exists"):
        rigcal.localize(seq, "icp", output=tmp_path / "out")
    with pytest.raises(InputError):
        rigcal.localize(seq, "icp")  # a method as a plain name is one method


def test_localize_takes_the_tracks_and_iasm_settings(tmp_path):
    seq, out = tmp_path / "drive", tmp_path / "out"
    assert main(["simulate", "world", "-o", str(seq), "--duration-s", "3", "--seed", "1"]) == 0
    runs = rigcal.localize(seq, ["vo"], output=out, tracks={"equalize": "clahe", "n_features": 600})
    assert len(runs["vo"].stamps_s) > 2
    settings = yaml.safe_load((out / "summary.yaml").read_text())["config"]["settings"]
    assert settings["tracks"]["equalize"] == "clahe"
    assert settings["tracks"]["n_features"] == 600
    with pytest.raises(ArgumentError, match=r"tracks equalize: got 'hist'; expected one of none, gain"):
        rigcal.localize(seq, ["vo"], tracks={"equalize": "hist"})
    with pytest.raises(ArgumentError, match=r"iasm: got 'snap=1'; expected KEY=VALUE with KEY one of"):
        rigcal.localize(seq, ["iasm"], iasm={"snap": 1})


# --- streaming odometry and trajectories --------------------------------------------------------


def test_laser_odometry_scan_by_scan_equals_the_batch_icp(tmp_path):
    from rigcal.localize.metrics import anchored
    from rigcal.localize.pipeline import planar_at
    from rigcal.localize.streams import open_streams

    seq = tmp_path / "drive"
    assert main(["simulate", "world", "-o", str(seq), "--duration-s", "4", "--seed", "3", "--no-images"]) == 0
    batch = rigcal.localize(seq, "icp,icp-p2p")
    scans = rigcal.read_scans(seq)
    assert [s.stamp_s for s in scans] == [s.stamp_s for s in open_streams(seq).scans]
    for method in ("icp", "icp-p2p"):
        odom = rigcal.LaserOdometry(method)
        poses = [odom.register_scan(scan) for scan in scans]
        assert len(odom) == len(scans)
        np.testing.assert_array_equal(np.array(poses), odom.poses)
        np.testing.assert_array_equal(odom.stamps_s, batch[method].stamps_s)
        truth = yaml.safe_load((seq / "sequence.yaml").read_text())["groundtruth"]
        gt = planar_at(rigcal.read_trajectory(seq / truth), odom.stamps_s)
        # The batch run's poses are anchored at the truth's first pose: so are these.
        np.testing.assert_array_equal(anchored(odom.poses, gt), batch[method].poses)
    assert odom.poses[0].tolist() == [0.0, 0.0, 0.0]
    assert odom.degeneracy.shape == (len(scans),)
    with pytest.raises(ArgumentError, match=r"rigcal\.read_scans: sequence: got 1"):
        rigcal.read_scans(1)
    with pytest.raises(InputError):
        rigcal.read_scans(tmp_path / "none")


def test_laser_odometry_starts_each_step_from_a_given_motion(tmp_path):
    """Scans far apart at irregular gaps (as a robot's loop that falls behind): the
    constant-velocity start fails, a motion from elsewhere (wheel odometry; here the
    truth) keeps the track."""
    from rigcal.geometry import pose_of, se2
    from rigcal.localize.metrics import anchored
    from rigcal.localize.pipeline import planar_at

    seq = tmp_path / "drive"
    args = ["simulate", "world", "-o", str(seq), "--duration-s", "12", "--seed", "2", "--no-images"]
    assert main(args) == 0
    scans = rigcal.read_scans(seq)
    keep = np.cumsum([0] + [1, 40] * len(scans))
    sub = [scans[k] for k in keep[keep < len(scans)]]
    gt = planar_at(rigcal.read_trajectory(seq / "groundtruth.tum"), np.array([s.stamp_s for s in sub]))
    errors = []
    for guided in (False, True):
        odom = rigcal.LaserOdometry()
        for n, scan in enumerate(sub):
            step = pose_of(np.linalg.inv(se2(gt[n - 1])) @ se2(gt[n])) if guided and n else None
            odom.register_scan(scan, guess=step)
        errors.append(np.linalg.norm(anchored(odom.poses, gt)[:, :2] - gt[:, :2], axis=1).max())
    assert errors[1] < 0.05
    assert errors[1] < errors[0]


def test_laser_odometry_checks_its_scans_and_takes_a_motion_guess():
    rng = np.random.default_rng(0)
    angles = np.radians(np.arange(-135, 135.01, 0.5))
    with pytest.raises(ArgumentError, match=r"rigcal\.LaserOdometry: method: got 'ndt'; expected one of icp"):
        rigcal.LaserOdometry("ndt")
    odom = rigcal.LaserOdometry()
    scan = rigcal.Scan(angles, 5.0 + 0.001 * rng.standard_normal(len(angles)), 0.1, 30.0, stamp_s=1.0)
    odom.register_scan(scan)
    with pytest.raises(ArgumentError, match=r"register_scan: scan: got 'scan'; expected a rigcal\.Scan"):
        odom.register_scan("scan")
    same_time = rigcal.Scan(angles, scan.ranges_m, 0.1, 30.0, stamp_s=1.0)
    with pytest.raises(ArgumentError, match=r"scan\.stamp_s: got 1\.0; expected a stamp after the previous"):
        odom.register_scan(same_time)
    later = rigcal.Scan(angles, scan.ranges_m, 0.1, 30.0, stamp_s=2.0)
    with pytest.raises(ArgumentError, match=r"guess: got 'an array of shape \(2,\)'"):
        odom.register_scan(later, guess=[0.0, 0.0])
    with pytest.raises(ArgumentError, match=r"guess\[2\]: got nan"):
        odom.register_scan(later, guess=[0.0, 0.0, np.nan])
    assert len(odom) == 1  # refused scans are not registered
    pose = odom.register_scan(later, guess=[0.0, 0.0, 0.0])
    assert np.abs(pose).max() < 0.05  # the scanner stood still in a round room


def test_trajectories_read_and_write_under_stable_names(tmp_path):
    stamps = np.array([0.0, 0.1, 0.2])
    poses = np.array([[0.0, 0, 0], [0.1, 0.0, 0.05], [0.2, 0.01, 0.1]])
    loc = rigcal.Localization("icp", stamps, poses, None)
    tum = rigcal.write_trajectory(tmp_path / "a.tum", loc)
    back = rigcal.read_trajectory(tum)
    np.testing.assert_array_equal(back.stamps_s, stamps)
    np.testing.assert_allclose(back.poses, loc.trajectory().poses, atol=1e-12)
    kitti = rigcal.write_trajectory(tmp_path / "a.kitti", back)
    assert rigcal.read_trajectory(kitti).stamps_s is None
    np.testing.assert_allclose(rigcal.read_trajectory(kitti, "kitti").poses, back.poses, atol=1e-12)
    with pytest.raises(OutputError, match="exists"):
        rigcal.write_trajectory(tum, loc)
    cases = [
        ((tmp_path / "b.tum", rigcal.Trajectory(back.poses)), r"\.stamps_s: got None; expected stamps"),
        ((tmp_path / "b.tum", rigcal.Trajectory(back.poses, stamps[::-1])), r"expected increasing stamps"),
        ((tmp_path / "b.tum", rigcal.Trajectory(2 * back.poses, stamps)), r"trajectory\.poses\[0\]\[3\]"),
        ((tmp_path / "b.tum", back.poses), r"trajectory: got 'an array|trajectory: got array"),
        ((tmp_path / "b.tum", loc, "g2o"), r"format: got 'g2o'; expected one of tum, kitti"),
    ]
    for args, message in cases:
        with pytest.raises(ArgumentError, match=message):
            rigcal.write_trajectory(*args)
    assert not (tmp_path / "b.tum").exists()
    with pytest.raises(ArgumentError, match=r"rigcal\.Localization\.trajectory: z_m: got nan"):
        loc.trajectory(float("nan"))
    with pytest.raises(ArgumentError, match=r"rigcal\.write_trajectory: trajectory\.poses: got 'an array"):
        rigcal.write_trajectory(tmp_path / "c.tum", rigcal.Localization("icp", stamps, stamps, None))
    assert loc.trajectory(0.4).poses[0, 2, 3] == 0.4
    with pytest.raises(ArgumentError, match=r"rigcal\.read_trajectory: format: got 'TUM'"):
        rigcal.read_trajectory(tum, "TUM")


# --- docs and example ----------------------------------------------------------------------------


def test_the_documented_example_runs(capsys):
    runpy.run_path(str(ROOT / "examples" / "api_example.py"), run_name="__main__")
    out = capsys.readouterr().out
    box = re.search(r"box target: \d+/\d+ captures, .* error ([\d.]+) deg, ([\d.]+) mm", out)
    board = re.search(r"checkerboard: \d+/\d+ captures, .* error ([\d.]+) deg, ([\d.]+) mm", out)
    drive = re.search(r"localize: icp, \d+ poses over [\d.]+ m; ATE ([\d.]+) m", out)
    stream = re.search(r"streaming: (\d+) scans, last pose equal to the batch run's: True", out)
    assert box, out
    assert board, out
    assert drive, out
    assert stream, out
    assert float(box[1]) < 0.5
    assert float(box[2]) < 30
    assert float(board[1]) < 1.5
    assert float(board[2]) < 40
    assert float(drive[1]) < 0.2


def test_the_api_page_names_every_exported_name():
    page = (ROOT / "docs" / "api.md").read_text()
    for name in rigcal.__all__:
        if name != "__version__":
            assert f"rigcal.{name}" in page, name
    assert "examples/api_example.py" in page
    assert "ArgumentError" in (ROOT / "docs" / "cli.md").read_text() or "ArgumentError" in page


@pytest.mark.slow
def test_a_users_script_is_type_checked_against_the_api(tmp_path):
    """py.typed and the report's types: mypy reads a script's mistakes as it would in a
    user's project (a report key of the other method, a float taken for text)."""
    script = tmp_path / "user.py"
    script.write_text(
        "import rigcal\n"
        "sol = rigcal.solve_box('picks.yaml')\n"
        "rms: float = sol.report['summary']['rms_px']\n"
        "sig = sol.rig.sigmas()\n"
        "deg = None if sig is None else sig.rotation_deg\n"
        "wrong: str = sol.report['summary']['rms_px']\n"
        "board_key = sol.report['summary']['rms_mm']\n"
        "board = rigcal.solve_board('board_session.yaml')\n"
        "mm: float = board.report['summary']['rms_mm']\n"
        "odom = rigcal.LaserOdometry()\n"
        "n: int = len(odom)\n"
    )
    run = subprocess.run(
        [sys.executable, "-m", "mypy", "--no-incremental", "--follow-imports=silent", str(script)],
        capture_output=True,
        text=True,
        cwd=tmp_path,
    )
    errors = [line for line in run.stdout.splitlines() if ": error:" in line]
    assert len(errors) == 2, run.stdout
    assert "user.py:6: error: Incompatible types in assignment" in errors[0]
    assert 'user.py:7: error: TypedDict "BoxSummary" has no key "rms_mm"' in errors[1]
