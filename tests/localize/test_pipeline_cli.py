"""`rigcal localize` and `rigcal evaluate` on a simulated sequence."""

from __future__ import annotations

import itertools
import json

import pytest
import yaml

from rigcal.cli.main import main
from rigcal.io.trajectory import read_tum


@pytest.fixture(scope="module")
def sequence(tmp_path_factory):
    out = tmp_path_factory.mktemp("seq") / "cubicle"
    assert (
        main(
            [
                "simulate",
                "world",
                "--world",
                "cubicle-loop",
                "-o",
                str(out),
                "--laser-rate-hz",
                "10",
                "--no-images",
            ]
        )
        == 0
    )
    return out


def test_localize_writes_trajectory_summary_and_table(sequence, tmp_path, capsys):
    out = tmp_path / "icp"
    assert main(["localize", str(sequence), "--method", "icp", "-o", str(out), "--kitti"]) == 0
    cap = capsys.readouterr()
    table = cap.out
    assert "| icp |" in table
    traj = read_tum(out / "icp" / "trajectory.tum")
    summary = yaml.safe_load((out / "summary.yaml").read_text())
    # icp's time is the shared laser odometry's, which the stage line shows too.
    icp = summary["methods"]["icp"]
    icp_s = summary["stage_timings_s"]["icp_s"]
    assert icp["shared_stages_s"] == {"icp_s": icp_s}
    assert icp["total_s"] == pytest.approx(icp["seconds"] + icp_s, abs=2e-3)
    line = next(x for x in cap.err.splitlines() if x.startswith("icp: "))
    assert line == (
        f"icp: {len(traj)} poses in {icp['seconds'] + icp_s:.1f} s "
        f"(shared stages icp {icp_s:.1f} s; its own {icp['seconds']:.1f} s)"
    )
    assert len(traj) == summary["methods"]["icp"]["poses"]
    assert (out / "icp" / "trajectory.kitti").read_text().count("\n") == len(traj)
    assert summary["config"]["methods"] == ["icp"]
    assert (out / "paths.png").stat().st_size > 1000
    assert (out / "errors.svg").read_bytes()[:5] == b"<?xml"
    m = summary["methods"]["icp"]["metrics"]
    # A clean simulated office: point-to-line ICP closes the 35 m loop within a metre.
    assert m["loop_closure_error_m"] < 1.0
    assert m["path_length_m"] == pytest.approx(35.0, rel=0.05)
    assert json.loads((out / "summary.json").read_text())["methods"]["icp"]["metrics"] == m


def test_evaluate_agrees_with_the_summary(sequence, tmp_path, capsys):
    out = tmp_path / "p2p"
    assert main(["localize", str(sequence), "--method", "icp-p2p", "-o", str(out)]) == 0
    capsys.readouterr()
    assert (
        main(
            [
                "evaluate",
                str(out / "icp-p2p" / "trajectory.tum"),
                "--gt",
                str(sequence / "groundtruth.tum"),
                "--json",
            ]
        )
        == 0
    )
    m = json.loads(capsys.readouterr().out)
    summary = yaml.safe_load((out / "summary.yaml").read_text())["methods"]["icp-p2p"]["metrics"]
    assert m["loop_closure_error_m"] == pytest.approx(summary["loop_closure_error_m"], abs=1e-3)
    assert m["ate_rmse_m"] == pytest.approx(summary["ate_rmse_m"], abs=1e-3)


def test_bad_method_and_existing_output(sequence, tmp_path, capsys):
    assert main(["localize", str(sequence), "--method", "sift", "-o", str(tmp_path / "x")]) == 2
    assert "--method: got 'sift'" in capsys.readouterr().err
    assert main(["localize", str(sequence), "--method", "icp,icp", "-o", str(tmp_path / "x")]) == 2
    assert not (tmp_path / "x").exists()
    (tmp_path / "y").mkdir()
    assert main(["localize", str(sequence), "-o", str(tmp_path / "y")]) == 5
    assert main(["localize", str(tmp_path / "nope"), "-o", str(tmp_path / "z")]) == 3


def test_all_methods_on_one_sequence(drive, tmp_path, capsys):
    out = tmp_path / "all"
    assert main(["localize", str(drive), "--method", "icp,vo,kf,iasm,hiasm", "-o", str(out)]) == 0
    table = capsys.readouterr().out
    for m in ("icp", "vo", "kf", "iasm", "hiasm"):
        assert f"| {m} |" in table
        assert (out / m / "trajectory.tum").is_file()
    s = yaml.safe_load((out / "summary.yaml").read_text())
    methods = s["methods"]
    n_images = len((drive / "images.csv").read_text().splitlines()) - 1
    assert methods["iasm"]["poses"] == methods["hiasm"]["poses"] == n_images
    steps = methods["hiasm"]["steps_by"]
    assert sum(steps.values()) == n_images - 1
    assert steps["hiasm"] > 0.5 * (n_images - 1)
    assert methods["hiasm"]["fallbacks"] == steps["iasm"] + steps["vo"] + steps["icp"]
    rows = (out / "hiasm" / "steps.csv").read_text().splitlines()
    assert rows[0] == "image,stamp_s,used,metric,correspondences,inliers,fallback"
    assert len(rows) == n_images
    assert sum(r.split(",")[2] == "hiasm" for r in rows[1:]) == steps["hiasm"]
    # The laser odometry gives the first pair's scale too.
    assert rows[1].split(",")[2] == "hiasm"
    # A keyframe every 2 m (or 20 deg) over the first 6 m.
    assert 3 <= methods["iasm"]["keyframes"] <= n_images // 4
    assert methods["kf"]["vo_measurements"] > 0
    for m in ("vo", "iasm", "hiasm"):
        # Centimetres over the first 6 m: the images are used, and used right.
        assert methods[m]["metrics"]["average_position_error_m"] < 0.1
    assert {"read_s", "icp_s", "tracks_s", "vo_s", "hiasm_matching_s"} <= set(s["stage_timings_s"])
    # vo runs before kf: kf's own time leaves out the visual odometry it shares.
    stages = s["stage_timings_s"]
    assert methods["kf"]["shared_stages_s"] == {k: stages[k] for k in ("tracks_s", "icp_s", "vo_s")}
    assert methods["kf"]["seconds"] < s["stage_timings_s"]["vo_s"] + 0.5
    assert s["wall_s"] > 0
    assert (out / "paths.png").stat().st_size > 1000
    assert (out / "errors.svg").read_bytes()[:5] == b"<?xml"


def test_matches_picture(drive, tmp_path, capsys):
    png = tmp_path / "m.png"
    assert main(["matches", str(drive), "--image", "10", "--method", "hiasm", "-o", str(png)]) == 0
    assert "correspondences" in capsys.readouterr().out
    assert png.stat().st_size > 1000
    assert main(["matches", str(drive), "--image", "10", "-o", str(png)]) == 5  # exists
    assert main(["matches", str(drive), "--image", "9999", "-o", str(tmp_path / "n.png")]) == 3
    assert "--image: got 9999" in capsys.readouterr().err
    svg = tmp_path / "m2.svg"
    assert main(["matches", str(drive), "--image", "10", "-o", str(svg), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["output"] == str(svg)
    assert doc["method"] == "iasm"  # the default, the simplest as localize's
    assert b"<svg" in svg.read_bytes()[:400]
    assert main(["matches", str(drive), "--image", "10", "-o", str(tmp_path / "m.gif")]) == 3
    assert "a name ending in .png, .svg, .pdf" in capsys.readouterr().err
    assert doc["correspondences"] >= doc["inliers"] > 0
    assert set(doc["motion"]) == {"x_m", "y_m", "yaw_rad"}


def test_image_methods_need_images_and_a_matching_camera(sequence, drive, tmp_path, capsys):
    # The cubicle sequence has no images.
    assert main(["localize", str(sequence), "--method", "vo", "-o", str(tmp_path / "a")]) == 3
    assert "images.count: got 0" in capsys.readouterr().err
    assert not (tmp_path / "a").exists()
    # A rig whose camera is not the images' size.
    rig = (drive / "rig.yaml").read_text().replace("imagersize: [640, 480]", "imagersize: [800, 480]")
    (tmp_path / "rig.yaml").write_text(rig)
    code = main(
        [
            "localize",
            str(drive),
            "--method",
            "iasm",
            "--rig",
            str(tmp_path / "rig.yaml"),
            "-o",
            str(tmp_path / "b"),
        ]
    )
    assert code == 3
    assert "expected 800x480" in capsys.readouterr().err


def test_progress_reaches_every_stages_end(sequence, tmp_path):
    from rigcal.localize.pipeline import run

    calls: list[tuple[str, int, int]] = []
    run(sequence, ["icp"], progress=lambda *a: calls.append(a))
    stages = {c[0] for c in calls}
    assert stages == {"laser odometry"}
    last = calls[-1]
    assert last[1] == last[2] > 100
    assert all(b[1] >= a[1] for a, b in itertools.pairwise(calls))


def test_summary_holds_the_effective_settings(sequence, tmp_path):
    out = tmp_path / "cfg"
    assert main(["localize", str(sequence), "-o", str(out)]) == 0
    cfg = yaml.safe_load((out / "summary.yaml").read_text())["config"]["settings"]
    assert cfg["icp"]["method"] == "point-to-line"
    assert cfg["iasm"]["patch_radius_px"] == 5
    assert cfg["kf"]["vo_sigmas_forward_cross_yawrate"][1] > cfg["kf"]["icp_sigmas_forward_cross_yawrate"][1]
    assert json.loads((out / "summary.json").read_text())["config"]["settings"] == cfg


def test_progress_lines_for_stages_side_by_side(capsys):
    # stderr is not a terminal here: no bars, one line per stage as it ends.
    from rigcal.cli.progress import Progress

    with Progress("scan", disable=False) as bars:
        for k in range(1, 5):
            bars("laser odometry", k, 4)
            if k <= 2:
                bars("feature tracks", k, 2)
        bars("laser odometry", 4, 4)  # reported again after it ended: ignored
    err = capsys.readouterr().err.splitlines()
    assert [line.split(":")[0] for line in err] == ["feature tracks", "laser odometry"]
    assert err[1].startswith("laser odometry: 4/4 in ")


def test_quiet_progress_prints_nothing(capsys):
    from rigcal.cli.progress import Progress

    with Progress(disable=True) as bars:
        count = bars.counter("reading")
        for k in range(1, 4):
            count(k)
    assert capsys.readouterr().err == ""


def test_icp_steps_flag_a_featureless_corridor(tmp_path):
    """Half the drive in a featureless corridor (walls only), half in a room: the
    corridor's steps are flagged degenerate in icp/steps.csv and counted in the summary."""
    import numpy as np

    from rigcal.recordings.sequence import write_sequence
    from rigcal.scan import Scan
    from rigcal.sim.raycast import beam_angles, cast_scan

    _, _, ang = beam_angles(270.0, 0.5)
    corridor = np.array([[[-100, -1], [100, -1]], [[-100, 1], [100, 1]]], float)
    room = np.array([[[-3, -2], [5, -2]], [[5, -2], [5, 3]], [[5, 3], [-3, 3]], [[-3, 3], [-3, -2]]], float)
    scans = []
    for k in range(40):
        x = 0.05 * k
        walls = corridor if k < 20 else room
        r = cast_scan(walls - [x, 0.0], ang, 30.0)
        scans.append(Scan.from_uniform(float(ang[0]), float(ang[1] - ang[0]), r, 0.1, 30.0, 0.1 * k))
    seq = write_sequence(tmp_path / "seq", "t", scans, [], None, {})
    out = tmp_path / "out"
    assert main(["localize", str(seq), "--method", "icp", "-o", str(out)]) == 0
    rows = (out / "icp" / "steps.csv").read_text().splitlines()
    assert rows[0] == "scan,stamp_s,degeneracy,degenerate,rms_m,skipped"
    flags = [int(r.split(",")[3]) for r in rows[1:]]
    assert len(flags) == 39
    assert all(flags[:18])
    assert not any(flags[21:])
    summary = yaml.safe_load((out / "summary.yaml").read_text())
    assert summary["methods"]["icp"]["degenerate_steps"] == sum(flags)


def test_iasm_settings_from_the_command_line_reach_the_run_and_the_summary(drive, tmp_path):
    out = tmp_path / "raw"
    args = ["localize", str(drive), "--method", "iasm", "-o", str(out)]
    assert main([*args, "--iasm", "snap_max_m=0", "--iasm", "hypotheses = 80", "--iasm", "keyframe_m=0"]) == 0
    s = yaml.safe_load((out / "summary.yaml").read_text())
    cfg = s["config"]["settings"]["iasm"]
    assert cfg["snap_max_m"] == 0.0
    assert cfg["hypotheses"] == 80
    assert cfg["dense_window"] is False
    # Without keyframes every step aligns with the scan before it.
    assert s["methods"]["iasm"]["keyframes"] == s["methods"]["iasm"]["poses"]
    assert s["methods"]["iasm"]["metrics"]["average_position_error_m"] < 0.1


def test_hiasm_with_the_papers_carried_scale_starts_with_iasm(drive, tmp_path):
    out = tmp_path / "carried"
    args = ["localize", str(drive), "--method", "hiasm", "-o", str(out), "--iasm", "odometry_scale=false"]
    assert main(args) == 0
    rows = (out / "hiasm" / "steps.csv").read_text().splitlines()
    # No scale before the first step: it falls back to IASM; later steps carry the last one.
    assert rows[1].split(",")[2] == "iasm"
    assert "no scale yet" in rows[1]
    assert sum(r.split(",")[2] == "hiasm" for r in rows[2:]) > 0.5 * (len(rows) - 2)
    s = yaml.safe_load((out / "summary.yaml").read_text())
    assert s["config"]["settings"]["iasm"]["odometry_scale"] is False
    assert s["methods"]["hiasm"]["metrics"]["average_position_error_m"] < 0.1


def test_steps_far_from_the_laser_odometry_fall_back(drive, tmp_path):
    def rows(gate: str) -> list[list[str]]:
        out = tmp_path / f"gate{gate}"
        args = [
            "localize",
            str(drive),
            "--method",
            "iasm,hiasm",
            "-o",
            str(out),
            "--iasm",
            f"odometry_gate_m={gate}",
        ]
        assert main(args) == 0
        return [
            r.split(",")
            for m in ("iasm", "hiasm")
            for r in (out / m / "steps.csv").read_text().splitlines()[1:]
        ]

    # The drive's image steps agree with the laser odometry to well under 0.1 m ...
    assert not any("off the laser odometry" in r[6] for r in rows("0.1"))
    # ... but not to 0.1 mm: then every step falls back to ICP and says why.
    strict = rows("0.0001")
    assert all(r[2] == "icp" for r in strict)
    assert sum("m off the laser odometry" in r[6] for r in strict) > 0.5 * len(strict)


def test_iasm_settings_parse_each_field_by_its_type():
    from rigcal.localize.pipeline import parse_iasm_settings

    p = parse_iasm_settings(["dense_window=TRUE", "window_px=6", "hypotheses=40", "joint_polish=0"])
    assert p.dense_window is True
    assert p.joint_polish is False
    assert p.window_px == 6.0
    assert isinstance(p.window_px, float)
    assert p.hypotheses == 40
    assert isinstance(p.hypotheses, int)
    assert parse_iasm_settings([]) == parse_iasm_settings(()) == type(p)()


@pytest.mark.parametrize(
    ("option", "item", "message"),
    [
        ("--iasm", "snap=0.03", "--iasm: got 'snap=0.03'; expected KEY=VALUE with KEY one of"),
        ("--iasm", "snap_max_m", "--iasm: got 'snap_max_m'; expected KEY=VALUE"),
        ("--iasm", "snap_max_m=abc", "--iasm snap_max_m: got 'abc'; expected a number, 0 or more"),
        ("--iasm", "snap_max_m=-1", "--iasm snap_max_m: got '-1'; expected a number, 0 or more"),
        ("--iasm", "window_px=nan", "--iasm window_px: got 'nan'; expected a number, 0 or more"),
        ("--iasm", "hypotheses=1.5", "--iasm hypotheses: got '1.5'; expected a whole number, 0 or more"),
        ("--iasm", "dense_window=yes", "--iasm dense_window: got 'yes'; expected true or false"),
        ("--tracks", "detector=orb", "--tracks detector: got 'orb'; expected one of sift, shi-tomasi"),
        ("--tracks", "detectors=sift", "--tracks: got 'detectors=sift'; expected KEY=VALUE with KEY one of"),
        ("--tracks", "levels=2.5", "--tracks levels: got '2.5'; expected a whole number, 0 or more"),
        ("--tracks", "predict=maybe", "--tracks predict: got 'maybe'; expected true or false"),
        ("--tracks", "equalize=hist", "--tracks equalize: got 'hist'; expected one of none, gain, clahe"),
        (
            "--tracks",
            "clahe_clip=0",
            "--tracks: got 'clahe_clip=0'; expected clahe_clip in (0, 100], not 0.0",
        ),
    ],
)
def test_bad_settings_are_refused_before_any_work(sequence, tmp_path, capsys, option, item, message):
    out = tmp_path / "bad"
    assert main(["localize", str(sequence), "--method", "vo", option, item, "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert message in err
    assert len(err.strip().splitlines()) == 1
    assert not out.exists()


def test_a_laser_that_cannot_see_the_corridors_end(tmp_path):
    """Eight seconds of the corridor loop with a 4 m laser: the laser odometry is degenerate
    along the straight, the image methods choose the image metric there (Section III-C)
    and carry the motion along it, and the KF leaves ICP's degenerate steps to VO."""
    seq, out = tmp_path / "short", tmp_path / "out"
    args = ["simulate", "world", "-o", str(seq), "--duration-s", "8", "--seed", "1", "--range-max-m", "4"]
    assert main(args) == 0
    assert main(["localize", str(seq), "--method", "icp,kf,iasm,hiasm", "-o", str(out)]) == 0
    methods = json.loads((out / "summary.json").read_text())["methods"]
    assert methods["icp"]["degenerate_steps"] > 50
    icp_error = methods["icp"]["metrics"]["average_position_error_m"]
    assert icp_error > 0.3
    for m in ("iasm", "hiasm"):
        assert methods[m]["metric"]["image"] > 10
        assert methods[m]["metrics"]["average_position_error_m"] < 0.05 * icp_error
    assert methods["kf"]["metrics"]["average_position_error_m"] < 0.1 * icp_error


@pytest.mark.parametrize("detector", ["shi-tomasi", "sift"])
def test_the_tracks_detector_reaches_the_run_and_the_summary(drive, tmp_path, detector):
    out = tmp_path / detector
    args = ["localize", str(drive), "--method", "vo", "-o", str(out), "--json"]
    assert main([*args, "--tracks", f"detector={detector}", "--tracks", "n_features = 800"]) == 0
    s = yaml.safe_load((out / "summary.yaml").read_text())
    assert s["config"]["settings"]["tracks"]["detector"] == detector
    assert s["config"]["settings"]["tracks"]["n_features"] == 800
    assert s["config"]["settings"]["tracks"]["equalize"] == "gain"  # the default, recorded
    assert s["methods"]["vo"]["metrics"]["average_position_error_m"] < 0.5


def test_track_settings_parse_each_field_by_its_type():
    from rigcal.localize.pipeline import parse_track_settings
    from rigcal.localize.tracks import TrackParams

    p = parse_track_settings(["detector=sift", "predict=false", "max_fb_px=0.5", "levels=2"])
    assert p == TrackParams(detector="sift", predict=False, max_fb_px=0.5, levels=2)
    assert isinstance(p.levels, int)
    assert parse_track_settings([]) == TrackParams()
