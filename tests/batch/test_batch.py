"""Batch runs on the local process pool and on a local Ray cluster: outputs as the single
command writes them, failures per item, resume, the summary and the fleet plot."""

from __future__ import annotations

import csv
import json
import os
import shlex
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

from rigcal.batch.manifest import Item, read_manifest
from rigcal.batch.runner import BatchSettings, run_batch, run_item
from rigcal.calib.box.session import calibrate
from rigcal.cli.main import main
from rigcal.rigfile import write_rig
from rigcal.sim.box_session import (
    SessionSpec,
    default_T_cam_laser,
    generate_session,
    moved_T_cam_laser,
    write_session,
)


def session(folder: Path, n: int, seed: int, rotation_deg: float = 0.0) -> Path:
    T = moved_T_cam_laser(default_T_cam_laser(), rotation_deg, 0.0, seed=seed)
    write_session(
        generate_session(SessionSpec(n_captures=n, seed=seed), T_cam_laser=T), folder, render_images=False
    )
    return folder / "picks.yaml"


def tum(path: Path, xs: np.ndarray) -> Path:
    lines = [f"{0.1 * i:.3f} {x:.6f} {0.1 * x:.6f} 0 0 0 0 1" for i, x in enumerate(xs)]
    path.write_text("\n".join(lines) + "\n")
    return path


@pytest.fixture(scope="module")
def fleet(tmp_path_factory) -> Path:
    """A manifest of four drift checks against one stored rig: unmoved, turned, unmoved,
    and one whose picking file is missing."""
    base = tmp_path_factory.mktemp("fleet")
    rig = base / "rig.yaml"
    write_rig(rig, calibrate(session(base / "calib", 20, seed=1)).rig)
    session(base / "r1", 6, seed=11)
    session(base / "r2", 6, seed=12, rotation_deg=0.5)
    session(base / "r3", 6, seed=13)
    doc = {
        "schema_version": 1,
        "command": "check",
        "defaults": {"rig": "rig.yaml", "no_log": True},
        "items": [
            {"name": "r1", "picks": "r1/picks.yaml"},
            {"name": "r2", "picks": "r2/picks.yaml"},
            {"name": "gone", "picks": "r9/picks.yaml"},
            {"name": "r3", "picks": "r3/picks.yaml"},
        ],
    }
    (base / "fleet.yaml").write_text(yaml.safe_dump(doc))
    return base / "fleet.yaml"


@pytest.fixture(scope="module")
def ray_cluster():
    ray = pytest.importorskip("ray")
    ray.init(num_cpus=2, include_dashboard=False)
    yield ray
    ray.shutdown()


def records(out: Path) -> dict[str, dict]:
    return {p.parent.name: json.loads(p.read_text()) for p in out.glob("*/item.json")}


def test_check_fleet_on_the_local_pool(fleet, tmp_path, capsys):
    out = tmp_path / "nightly"
    code = main(["batch", str(fleet), "-o", str(out), "-j", "2"])
    stdout, err = capsys.readouterr()
    assert code == 1  # one drifted, one failed
    rec = records(out)
    assert {k: v["status"] for k, v in rec.items()} == {
        "r1": "ok",
        "r2": "drifted",
        "gone": "failed",
        "r3": "ok",
    }
    assert rec["gone"]["exit_code"] == 3
    assert rec["gone"]["error"] == f"{fleet.parent / 'r9' / 'picks.yaml'}: picking file not found"
    assert "[4/4]" in err
    assert "gone: failed" in err
    assert "1 failed" in err
    assert stdout.splitlines()[2].startswith("gone\tfailed\t")
    # each item ran in a worker process, not here
    assert all(
        r["exit_code"] == 3 or r["result"]["input"].startswith(str(fleet.parent)) for r in rec.values()
    )
    # the item's result is what the single command prints with --json
    code1 = main(
        [
            "check",
            str(fleet.parent / "rig.yaml"),
            "--picks",
            str(fleet.parent / "r2/picks.yaml"),
            "--no-log",
            "--json",
        ]
    )
    single = json.loads(capsys.readouterr().out)
    assert code1 == 1
    assert {k: v for k, v in single.items() if k != "checked_utc"} == {
        k: v for k, v in rec["r2"]["result"].items() if k != "checked_utc"
    }
    # summary: CSV and JSON agree, one row per item in the manifest's order
    doc = json.loads((out / "summary.json").read_text())
    assert doc["schema_version"] == 3
    assert doc["counts"] == {"ok": 2, "drifted": 1, "cannot_tell": 0, "failed": 1}
    with open(out / "summary.csv", newline="") as f:
        table = list(csv.DictReader(f))
    assert [r["name"] for r in table] == ["r1", "r2", "gone", "r3"]
    assert [r["status"] for r in table] == [r["status"] for r in doc["items"]]
    assert table[1]["verdict"] == "drifted"
    assert float(table[1]["rotation_deg"]) > 0.3
    assert table[2]["verdict"] == ""
    assert "not found" in table[2]["error"]
    img = cv2.imread(str(out / "fleet_drift.png"))
    assert img is not None
    assert img.shape[0] > 300

    # resume: nothing finished runs again; the failed item does
    code = main(["batch", str(fleet), "-o", str(out), "-j", "2"])
    err = capsys.readouterr().err
    assert code == 1
    assert err.count("skipped, finished before") == 3
    again = records(out)
    assert again["r1"] == rec["r1"]
    assert again["gone"]["finished_utc"] >= rec["gone"]["finished_utc"]
    doc2 = json.loads((out / "summary.json").read_text())
    assert [r["resumed"] for r in doc2["items"]] == [True, True, False, True]


def test_resume_reruns_items_whose_outputs_or_options_changed(tmp_path):
    a = tum(tmp_path / "a.tum", np.linspace(0, 5, 40))
    b = tum(tmp_path / "b.tum", np.linspace(0, 5, 40) * 1.02)
    gt = tum(tmp_path / "gt.tum", np.linspace(0, 5, 40))
    items = [
        Item("a", "evaluate", {"trajectory": a, "gt": gt}),
        Item("b", "evaluate", {"trajectory": b, "gt": gt}),
    ]
    out = tmp_path / "out"
    first = run_batch(items, out, BatchSettings(workers=1))
    assert [o.record["status"] for o in first] == ["ok", "ok"]
    assert first[0].record["result"]["ate_rmse_m"] == 0.0
    assert first[1].record["result"]["ate_rmse_m"] > 0
    assert first[0].record["host"] == os.uname().nodename
    # a changed command line (other ground truth) runs again; an unchanged one is skipped
    items[1] = Item("b", "evaluate", {"trajectory": b, "gt": a})
    second = run_batch(items, out, BatchSettings(workers=1))
    assert [o.resumed for o in second] == [True, False]
    # a broken record is not trusted: the item runs again; --rerun runs everything
    (out / "a" / "item.json").write_text("{")
    assert [o.resumed for o in run_batch(items, out, BatchSettings(workers=1))] == [False, True]
    assert [o.resumed for o in run_batch(items, out, BatchSettings(workers=1, rerun=True))] == [False, False]


def test_a_solve_item_with_missing_outputs_runs_again(tmp_path):
    picks = session(tmp_path / "s", 8, seed=4)
    out = tmp_path / "out"
    items = [Item("s", "solve", {"picks": picks, "seed": 2})]
    (o,) = run_batch(items, out, BatchSettings(workers=1))
    assert o.record["status"] == "ok"
    assert (out / "s" / "rig.yaml").exists()
    assert (out / "s" / "report" / "report.json").exists()
    rig = yaml.safe_load((out / "s" / "rig.yaml").read_text())
    # provenance names the batch, the item and the single command that writes the same
    assert rig["provenance"]["command"].startswith(f"rigcal batch [item s: rigcal solve {picks} --seed 2 -o ")
    (out / "s" / "rig.yaml").unlink()
    (o,) = run_batch(items, out, BatchSettings(workers=1))
    assert not o.resumed
    assert (out / "s" / "rig.yaml").exists()


def test_a_solve_item_writes_the_rig_and_report_the_command_writes(tmp_path, monkeypatch):
    """Same inputs, same files: the batch item's rig file equals `rigcal solve`'s but for
    the provenance's command line (which names the batch) and its time."""
    picks = session(tmp_path / "s", 6, seed=5)
    out = tmp_path / "out"
    (o,) = run_batch([Item("s", "solve", {"picks": picks, "seed": 3})], out, BatchSettings(workers=1))
    assert o.record["status"] == "ok"
    single = tmp_path / "single"
    argv = [
        "solve",
        str(picks),
        "--seed",
        "3",
        "-o",
        str(single / "rig.yaml"),
        "--report",
        str(single / "report"),
    ]
    monkeypatch.setattr("sys.argv", ["rigcal", *argv])
    assert main(argv) == 0

    def without_made(path: Path) -> tuple[dict, str]:
        doc = yaml.safe_load(path.read_text())
        del doc["provenance"]["created_utc"]
        return doc, doc["provenance"].pop("command")

    batch_rig, batch_cmd = without_made(out / "s" / "rig.yaml")
    single_rig, single_cmd = without_made(single / "rig.yaml")
    assert batch_rig == single_rig
    assert single_cmd == "rigcal " + shlex.join(argv)
    assert batch_cmd == f"rigcal batch [item s: rigcal {shlex.join(o.record['argv'])}]"
    for name in ("report.json", "report.txt", "residuals.svg"):
        assert (out / "s" / "report" / name).read_bytes() == (single / "report" / name).read_bytes(), name
    assert sorted(p.name for p in (out / "s" / "report").iterdir()) == sorted(
        p.name for p in (single / "report").iterdir()
    )
    # the item's result is what `rigcal solve --json` prints, but for the rig's command line
    assert (
        o.record["result"]["summary"]
        == json.loads((single / "report" / "report.json").read_text())["summary"]
    )


def test_run_item_reports_bugs_and_usage_errors_without_raising(tmp_path, monkeypatch):
    t = tum(tmp_path / "a.tum", np.linspace(0, 1, 5))
    bad_solve = Item("s", "solve", {"picks": t, "threshold_px": -1.0})
    usage = run_item(bad_solve, tmp_path / "s", "rigcal batch")
    assert usage["exit_code"] == 2  # as `rigcal solve --threshold-px -1`
    assert usage["error"].startswith("--threshold-px: got -1.0; expected a finite number")
    assert not (tmp_path / "s").exists()
    missing = run_item(Item("e", "evaluate", {"trajectory": tmp_path / "none.tum", "gt": t}), tmp_path, "b")
    assert missing["exit_code"] == 3
    assert "none.tum" in missing["error"]
    assert missing["stderr"].startswith("Error: ")
    import rigcal.localize.metrics as metrics
    import rigcal.localize.pipeline  # noqa: F401  (imported first, so it keeps the real evaluate)

    def broken(*args, **kwargs):
        raise ZeroDivisionError("boom")

    monkeypatch.setattr(metrics, "evaluate", broken)
    bug = run_item(Item("e", "evaluate", {"trajectory": t, "gt": t}), tmp_path / "e", "rigcal batch")
    assert bug["exit_code"] == 70
    assert bug["error"] == "internal error: ZeroDivisionError: boom"
    assert "Traceback" in bug["stderr"]


def test_check_fleet_on_ray(ray_cluster, fleet, tmp_path):
    out = tmp_path / "ray"
    outcomes = run_batch(read_manifest(fleet), out, BatchSettings(ray_address="auto"))
    assert [o.record["status"] for o in outcomes] == ["ok", "drifted", "failed", "ok"]
    assert outcomes[2].record["exit_code"] == 3
    assert "not found" in outcomes[2].record["error"]
    # the same records as the local pool would write, from Ray's worker processes
    assert {o.record["result"]["verdict"] for o in outcomes if o.record["result"]} == {"ok", "drifted"}
    assert (out / "r2" / "item.json").exists()
    again = run_batch(read_manifest(fleet), out, BatchSettings(ray_address="auto"))
    assert [o.resumed for o in again] == [True, True, False, True]


def test_cli_errors(fleet, tmp_path, capsys):
    assert main(["batch", str(tmp_path / "none.yaml"), "-o", str(tmp_path / "o")]) == 3
    assert "batch manifest not found" in capsys.readouterr().err
    assert main(["batch", str(tmp_path / "*.tum"), "-o", str(tmp_path / "o")]) == 2
    assert "a glob needs --command" in capsys.readouterr().err
    assert main(["batch", str(fleet), "--command", "solve", "-o", str(tmp_path / "o")]) == 2
    assert main(["batch", str(tmp_path / "*.tum"), "--command", "evaluate", "--set", "gt", "-o", "o"]) == 3
    assert "--set: got 'gt'; expected KEY=VALUE" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


def test_an_output_that_is_a_file_is_refused_before_any_item_runs(tmp_path):
    from rigcal.errors import OutputError

    (tmp_path / "out").write_text("x")
    t = tum(tmp_path / "a.tum", np.linspace(0, 1, 5))
    with pytest.raises(OutputError, match=r"out: exists and is not a folder"):
        run_batch([Item("a", "evaluate", {"trajectory": t, "gt": t})], tmp_path / "out")


def test_ray_missing_is_one_line(tmp_path, monkeypatch):
    import sys

    from rigcal.errors import InputError

    monkeypatch.setitem(sys.modules, "ray", None)  # import ray raises ImportError
    t = tum(tmp_path / "a.tum", np.linspace(0, 1, 5))
    with pytest.raises(InputError, match=r"--ray: got 'ray'; expected Ray installed"):
        run_batch(
            [Item("a", "evaluate", {"trajectory": t, "gt": t})],
            tmp_path / "o",
            BatchSettings(ray_address="auto"),
        )


def test_a_glob_of_trajectories_on_the_cli(tmp_path, capsys):
    gt = tum(tmp_path / "gt.tum", np.linspace(0, 5, 40))
    (tmp_path / "runs").mkdir()
    for k in (1.0, 1.05):
        tum(tmp_path / "runs" / f"x{k}.tum", np.linspace(0, 5, 40) * k)
    out = tmp_path / "out"
    code = main(
        [
            "batch",
            str(tmp_path / "runs" / "*.tum"),
            "--command",
            "evaluate",
            "--set",
            f"gt={gt}",
            "-o",
            str(out),
            "--json",
            "-j",
            "1",
        ]
    )
    assert code == 0
    table = json.loads(capsys.readouterr().out)
    assert [r["name"] for r in table] == ["x1.0", "x1.05"]
    assert table[0]["ate_rmse_m"] == 0.0
    assert table[1]["ate_rmse_m"] > 0.0
    assert not (out / "fleet_drift.png").exists()


def test_pool_workers_share_the_cores_out_unless_the_user_set_the_threads(monkeypatch):
    """Workers start with each library's threads limited to their share of the cores
    (a variable the user set is kept), and the parent's environment is restored after."""
    from concurrent.futures import ProcessPoolExecutor
    from multiprocessing import get_context

    from rigcal.batch.runner import THREAD_VARIABLES, _start_worker, _thread_limits

    for v in THREAD_VARIABLES:
        monkeypatch.delenv(v, raising=False)
    monkeypatch.setenv("MKL_NUM_THREADS", "7")
    with _thread_limits(3), ProcessPoolExecutor(1, get_context("spawn"), _start_worker, (3,)) as pool:
        seen = pool.submit(_worker_threads, THREAD_VARIABLES).result()
    assert seen == {
        "OMP_NUM_THREADS": "3",
        "OPENBLAS_NUM_THREADS": "3",
        "MKL_NUM_THREADS": "7",
        "NUMBA_NUM_THREADS": "3",
        "cv2": 3,
    }
    assert os.environ["MKL_NUM_THREADS"] == "7"
    assert not any(v in os.environ for v in THREAD_VARIABLES if v != "MKL_NUM_THREADS")


def _worker_threads(names):
    """In a worker: the thread variables it started with and OpenCV's thread count."""
    return {**{v: os.environ.get(v) for v in names}, "cv2": cv2.getNumThreads()}
