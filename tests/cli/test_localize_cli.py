"""`rigcal localize`: its error paths and exit codes (the runs: tests/localize)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from rigcal.cli.main import main
from rigcal.errors import ArgumentError
from rigcal.io.trajectory import read_tum
from rigcal.jobs import localize_sequence
from rigcal.localize import kalman


def test_a_missing_sequence_is_bad_input(fails, tmp_path):
    fails(["localize", tmp_path / "seq", "-o", tmp_path / "out"], 3)


def test_an_unknown_method_is_a_usage_error(fails, tmp_path):
    assert "--method" in fails(
        ["localize", tmp_path / "seq", "--method", "icp,slam", "-o", tmp_path / "out"], 2
    )


def test_an_unknown_setting_is_a_usage_error(fails, tmp_path):
    assert "--iasm" in fails(["localize", tmp_path / "seq", "--iasm", "nope=1", "-o", tmp_path / "out"], 2)


def test_an_unknown_kalman_filter_is_a_usage_error(fails, tmp_path):
    assert "--kf" in fails(["localize", tmp_path / "seq", "--kf", "paper", "-o", tmp_path / "out"], 2)


def test_an_unknown_kalman_filter_is_refused_by_the_library_call_too(tmp_path):
    with pytest.raises(ArgumentError, match=r"--kf.*'paper'.*weighted, fixed"):
        localize_sequence(tmp_path / "seq", tmp_path / "out", methods="kf", kf="paper")


@pytest.fixture(scope="module")
def short_drive(tmp_path_factory) -> Path:
    """Four seconds of the cubicle loop, with images."""
    out = tmp_path_factory.mktemp("drive") / "cubicles"
    args = ["simulate", "world", "--world", "cubicle-loop", "-o", str(out)]
    args += ["--duration-s", "4", "--seed", "1"]
    assert main(args) == 0
    return out


@pytest.mark.parametrize(
    ("options", "named"),
    [
        (["--smooth"], "--smooth ignored: it acts only on method kf, which is not"),
        (["--kf", "fixed"], "--kf ignored: it acts only on method kf, which is not"),
        (
            ["--kf", "driven", "--smooth"],
            "--kf and --smooth ignored: they act only on method kf, which is not",
        ),
        (
            ["--iasm", "snap_max_m=0"],
            "--iasm ignored: it acts only on method iasm or hiasm, none of which is",
        ),
        (
            ["--tracks", "n_features=500"],
            "--tracks ignored: it acts only on method vo or kf or hiasm, none of which is",
        ),
    ],
)
def test_options_of_methods_not_run_are_named_as_ignored(short_drive, tmp_path, capsys, options, named):
    args = ["localize", str(short_drive), "--method", "icp", *options, "-o", str(tmp_path / "out")]
    assert main(args) == 0
    assert f"warning: {named} among the methods given (icp)" in capsys.readouterr().err


def test_loop_closure_options_without_loop_closure_are_named_as_ignored(short_drive, tmp_path, capsys):
    args = [
        "localize",
        str(short_drive),
        "--method",
        "icp",
        "--pose-graph",
        "scipy",
        "-o",
        str(tmp_path / "o"),
    ]
    assert main(args) == 0
    err = capsys.readouterr().err
    assert "warning: --pose-graph ignored: it acts only with --loop-closure, which is not given" in err


def test_options_of_methods_run_or_left_at_their_defaults_warn_nothing(short_drive, tmp_path, capsys):
    assert main(["localize", str(short_drive), "--method", "icp", "-o", str(tmp_path / "a")]) == 0
    args = ["localize", str(short_drive), "--method", "icp,kf", "--smooth", "--tracks", "n_features=500"]
    assert main([*args, "-o", str(tmp_path / "b")]) == 0
    assert "ignored" not in capsys.readouterr().err


def test_the_kf_option_picks_the_papers_the_weighted_or_the_driven_filter(short_drive, tmp_path, capsys):
    docs = {}
    for mode in ("weighted", "fixed", "driven", "icp-first"):
        out = tmp_path / mode
        args = ["localize", str(short_drive), "--method", "kf", "--kf", mode, "-o", str(out), "--json"]
        assert main(args) == 0
        docs[mode] = json.loads(capsys.readouterr().out)
        traj = read_tum(out / "kf" / "trajectory.tum")
        assert len(traj.poses) > 10
    weighted, fixed = docs["weighted"], docs["fixed"]
    assert weighted["config"]["settings"]["kf"]["weights"] == "covariance"
    assert weighted["config"]["settings"]["kf"]["adapt"] is True
    assert fixed["config"]["settings"]["kf"]["weights"] == "fixed"
    assert fixed["config"]["settings"]["kf"]["adapt"] is False
    assert weighted["methods"]["kf"]["weights"] == "covariance"
    assert fixed["methods"]["kf"]["weights"] == "fixed"
    # The same inputs, weighed otherwise: different paths; the weighted filter follows a
    # well-constrained ICP more closely than the paper's fixed covariances let it.
    ate = {m: d["methods"]["kf"]["metrics"]["ate_rmse_m"] for m, d in docs.items()}
    assert ate["weighted"] != ate["fixed"]
    assert ate["weighted"] < ate["fixed"]
    # --kf driven: the weighted filter with ICP's steps driving the prediction.
    driven = docs["driven"]
    assert driven["config"]["settings"]["kf"]["drive"] == "icp"
    assert driven["config"]["settings"]["kf"]["weights"] == "covariance"
    assert driven["methods"]["kf"]["prediction"] == "icp steps"
    assert weighted["methods"]["kf"]["prediction"] == "constant velocity"
    # --kf icp-first: driven, VO only along ICP's open directions.
    first = docs["icp-first"]["config"]["settings"]["kf"]
    assert (first["drive"], first["vo_pays"]) == ("icp", kalman.VO_OPEN_ONLY)
    assert docs["weighted"]["config"]["settings"]["kf"]["vo_pays"] == 0.0


def test_icp_first_scores_icps_ate_and_smooth_reaches_the_filter(short_drive, tmp_path, capsys):
    """`--kf icp-first` on a drive whose ICP constrains every direction: the filter's path
    is ICP's, scored at the scans as ICP is, so its ATE is ICP's exactly (the filter's
    image-stamp poses are not scored); `--smooth` is recorded in the settings and leaves
    that path as it is (no update to spread back)."""
    docs = {}
    for smooth in (False, True):
        out = tmp_path / f"smooth-{smooth}"
        args = ["localize", str(short_drive), "--method", "icp,kf", "--kf", "icp-first", "-o", str(out)]
        args.append("--json")
        assert main([*args, "--smooth"] if smooth else args) == 0
        docs[smooth] = json.loads(capsys.readouterr().out)
        kf, icp = (read_tum(out / m / "trajectory.tum") for m in ("kf", "icp"))
        assert kf.stamps_s is not None
        assert icp.stamps_s is not None
        assert set(kf.stamps_s) <= set(icp.stamps_s)
    for smooth, doc in docs.items():
        assert doc["config"]["settings"]["kf"]["smooth"] is smooth
        m = doc["methods"]
        assert m["kf"]["metrics"]["ate_rmse_m"] == m["icp"]["metrics"]["ate_rmse_m"]


def test_kf_with_wheel_odometry_fuses_the_calibrated_wheels(tmp_path, capsys):
    """Eight seconds of the corridor loop with wheel odometry (2 % scale error): method kf
    with the default filter runs with the wheels as witness and calibrated input (the
    summary says so) and ends within its inputs' reach: below the wheels' own ATE."""
    drive = tmp_path / "drive"
    args = ["simulate", "world", "--world", "corridor-loop", "--duration-s", "8", "--seed", "2"]
    assert main([*args, "--wheel-odometry", "-o", str(drive)]) == 0
    out = tmp_path / "out"
    assert main(["localize", str(drive), "--method", "icp,kf,odom", "-o", str(out), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    kf = doc["config"]["settings"]["kf"]
    assert (kf["wheel_witness"], kf["wheel_calibrated"], kf["wheel_input"]) == (True, True, True)
    assert doc["methods"]["kf"]["wheel_measurements"] > 0
    ate = {m: doc["methods"][m]["metrics"]["ate_rmse_m"] for m in ("icp", "kf", "odom")}
    assert ate["kf"] < ate["odom"]
