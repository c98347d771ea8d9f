"""`rigcal evaluate`: unrounded JSON, --precision for the table, --plot as evo_ape's."""

from __future__ import annotations

import json

import numpy as np
import pytest

from rigcal.cli.main import main
from rigcal.geometry import make_T, rotvec_to_R
from rigcal.io.trajectory import Trajectory, write_tum
from rigcal.localize.metrics import ate_rmse


def _write(path, xy_yaw, stamps):
    poses = np.array([make_T(rotvec_to_R([0.0, 0.0, p[2]]), [p[0], p[1], 0.0]) for p in xy_yaw])
    write_tum(path, Trajectory(poses, stamps))


@pytest.fixture
def runs(tmp_path):
    """A 20 m loop as truth and two estimates (out/iasm, out/hiasm) off it by a few mm."""
    rng = np.random.default_rng(7)
    t = np.linspace(0.0, 2 * np.pi, 400)
    truth = np.column_stack([10 / np.pi * np.cos(t), 10 / np.pi * np.sin(t), t + np.pi / 2])
    stamps = 100.0 + 0.05 * np.arange(len(t))
    _write(tmp_path / "gt.tum", truth, stamps)
    paths = []
    for name in ("iasm", "hiasm"):
        (tmp_path / "out" / name).mkdir(parents=True)
        est = truth + rng.normal(0.0, [0.004, 0.004, 0.0005], truth.shape).cumsum(axis=0)
        _write(tmp_path / "out" / name / "trajectory.tum", est, stamps)
        paths.append(tmp_path / "out" / name / "trajectory.tum")
    return tmp_path, paths, truth, stamps


def test_json_is_unrounded_and_the_table_takes_a_precision(runs, capsys):
    tmp, paths, _, _ = runs
    assert main(["evaluate", str(paths[0]), "--gt", str(tmp / "gt.tum"), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    # TUM files keep the poses to their written digits; the figure is not rounded further.
    from rigcal.io.trajectory import read_tum
    from rigcal.localize.pipeline import planar_at

    est, gt = read_tum(paths[0]), read_tum(tmp / "gt.tum")
    exact = ate_rmse(planar_at(est, est.stamps_s), planar_at(gt, gt.stamps_s))
    assert doc["ate_rmse_m"] == pytest.approx(exact, rel=1e-12)
    assert doc["ate_rmse_m"] != round(doc["ate_rmse_m"], 4)
    assert main(["evaluate", *map(str, paths), "--gt", str(tmp / "gt.tum"), "--precision", "6"]) == 0
    rows = capsys.readouterr().out.splitlines()
    assert rows[2].startswith("| iasm | ")
    assert rows[3].startswith("| hiasm | ")
    cells = rows[2].strip("| ").split(" | ")[1:]
    assert all(len(c.split(".")[1]) == 6 for c in cells if c != "-")
    assert f"{doc['ate_rmse_m']:.6f}" in cells


def test_plot_draws_both_paths_and_their_errors(runs, capsys):
    tmp, paths, _, _ = runs
    png = tmp / "compare.png"
    args = ["evaluate", *map(str, paths), "--gt", str(tmp / "gt.tum"), "--plot", str(png)]
    assert main(args) == 0
    assert png.read_bytes()[:4] == b"\x89PNG"
    assert f"wrote {png}" in capsys.readouterr().err
    assert main(args) == 5  # exists: --force to replace
    assert main([*args, "--force"]) == 0
    assert main([*args[:-1], str(tmp / "compare.gif")]) == 3
    assert "a name ending in .png, .svg, .pdf" in capsys.readouterr().err
    assert not (tmp / "compare.gif").exists()
    from rigcal.viz.paths_plot import evaluation_figure

    fig = evaluation_figure(
        np.zeros((2, 3)), {"a": np.zeros((2, 3))}, {"a": np.zeros((2, 3))}, {"a": np.zeros(2)}
    )
    paths_ax, errors_ax = fig.axes[:2]
    assert paths_ax.get_xlabel() == "x (m)"
    assert errors_ax.get_ylabel() == "error (m)"


def test_precision_out_of_range_is_a_usage_error(runs):
    tmp, paths, _, _ = runs
    assert main(["evaluate", str(paths[0]), "--gt", str(tmp / "gt.tum"), "--precision", "13"]) == 2
