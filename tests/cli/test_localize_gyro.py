"""``rigcal localize --gyro``: method kf fuses a sequence's gyroscope, or runs as without it."""

from __future__ import annotations

import json

from rigcal.cli.main import main


def test_kf_fuses_the_gyro_and_ignoring_it_is_the_run_without_it(tmp_path, capsys):
    """Six seconds of the corridor loop simulated with and without the gyro (the same seed:
    the same scans and images): kf with ``--gyro ignore``, the default, writes the
    trajectory of the sequence without one, to the byte; with ``--gyro use`` the summary counts its steps and
    the trajectory differs. ``--gyro`` on a sequence without one, and without method kf,
    is named in a warning after the run."""
    args = ["simulate", "world", "--world", "corridor-loop", "--duration-s", "6", "--seed", "3"]
    assert main([*args, "-o", str(tmp_path / "plain")]) == 0
    assert main([*args, "--gyro", "-o", str(tmp_path / "gyro")]) == 0
    capsys.readouterr()
    runs = {
        "plain": (tmp_path / "plain", ["--gyro", "use"]),
        "ignored": (tmp_path / "gyro", ["--gyro", "ignore"]),
        "used": (tmp_path / "gyro", ["--gyro", "use"]),
        "default": (tmp_path / "gyro", []),
    }
    docs, errs = {}, {}
    for name, (seq, extra) in runs.items():
        out = tmp_path / f"out-{name}"
        assert main(["localize", str(seq), "--method", "icp,kf", "-o", str(out), "--json", *extra]) == 0
        captured = capsys.readouterr()
        docs[name], errs[name] = json.loads(captured.out), captured.err
    kf = {name: (tmp_path / f"out-{name}" / "kf" / "trajectory.tum").read_bytes() for name in runs}
    assert kf["ignored"] == kf["plain"]
    assert kf["default"] == kf["plain"]  # the gyro is fused only when asked for
    assert kf["used"] != kf["plain"]
    assert [docs[n]["config"]["gyro"] for n in runs] == ["none", "ignored", "used", "ignored"]
    assert docs["used"]["methods"]["kf"]["gyro_measurements"] >= 55
    assert "gyro_measurements" not in docs["ignored"]["methods"]["kf"]
    warned = [line for line in errs["plain"].splitlines() if line.startswith("warning: --gyro")]
    assert warned == [f"warning: --gyro ignored: {tmp_path / 'plain'} has no gyroscope (gyro.csv, schema 4)"]
    assert "warning: --gyro" not in errs["used"] + errs["ignored"] + errs["default"]
    out = tmp_path / "out-icp"
    assert main(["localize", str(tmp_path / "gyro"), "--method", "icp", "-o", str(out), "--gyro", "use"]) == 0
    err = capsys.readouterr().err
    assert (
        "warning: --gyro ignored: it acts only on method kf, which is not among the methods given (icp)"
        in err
    )


def test_a_broken_gyro_file_is_a_one_line_error(tmp_path, fails):
    """A gyro.csv with a NaN rate: one line naming the file, the sample and the way on."""
    args = [
        "simulate",
        "world",
        "--world",
        "corridor-loop",
        "--duration-s",
        "2",
        "--seed",
        "3",
        "--no-images",
    ]
    seq = tmp_path / "seq"
    assert main([*args, "--gyro", "-o", str(seq)]) == 0
    (seq / "gyro.csv").write_text("stamp_s,yaw_rate_rad_s\n0.0,0.1\n0.005,nan\n")
    # Read before any work where method kf uses it (the images' check comes after).
    line = fails(["localize", seq, "--method", "kf", "--gyro", "use", "-o", tmp_path / "out"], 3)
    assert line == (
        f"Error: {seq / 'gyro.csv'}: gyro sample 1: got [0.005, nan]; expected a finite stamp and a "
        "yaw rate within +-40 rad/s (--gyro ignore runs without it)"
    )


def test_a_drive_that_starts_standing_gives_the_gyros_bias_in_the_summary(tmp_path, capsys):
    """2 s standing, then 1 s of motion (seed 11: a simulated bias of -0.083 deg/s): the
    summary counts the seconds the rig stood still and gives the bias learned there, within
    3 of its sigmas of the simulated one; a drive without a gyro has no such figures."""
    import numpy as np

    from rigcal.sim.drive import DriveSpec, Motion, gyro_bias
    from rigcal.sim.world import BUILTIN

    seq = tmp_path / "seq"
    args = ["simulate", "world", "--world", "corridor-loop", "--duration-s", "1", "--seed", "11"]
    assert main([*args, "--start-still", "2", "--gyro", "-o", str(seq)]) == 0
    capsys.readouterr()
    out = tmp_path / "out"
    assert main(["localize", str(seq), "--method", "kf", "--gyro", "use", "-o", str(out), "--json"]) == 0
    kf = json.loads(capsys.readouterr().out)["methods"]["kf"]
    assert 1.8 <= kf["gyro_still_s"] <= 2.1
    spec = DriveSpec(seed=11, duration_s=1.0, start_still_s=2.0, gyro=True)
    t, bias = gyro_bias(Motion(BUILTIN["corridor-loop"](), spec), spec)
    simulated = float(np.degrees(np.interp(2.0, t, bias)))
    assert kf["gyro_bias_sigma_deg_s"] < 0.02
    assert abs(kf["gyro_bias_deg_s"] - simulated) < 3 * kf["gyro_bias_sigma_deg_s"]
