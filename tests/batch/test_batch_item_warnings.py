"""What the single command says as a warning, a batch item says too: an evaluation of a
trajectory copied while it was written (its last line cut) is scored to its last whole
line, and the batch's log, the item's record and the summary name the cut line."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np

from rigcal.cli.main import main


def _tum(path: Path, xs: np.ndarray, cut: bool = False) -> Path:
    text = "".join(f"{0.1 * i:.3f} {x:.6f} 0 0 0 0 0 1\n" for i, x in enumerate(xs))
    path.write_text(text + ("4.000 3.2" if cut else ""))  # a last line without its newline
    return path


def test_a_cut_trajectory_is_scored_and_its_warning_kept(tmp_path, capsys):
    gt = _tum(tmp_path / "gt.tum", np.linspace(0, 5, 40))
    whole = _tum(tmp_path / "whole.tum", np.linspace(0, 5, 40))
    cut = _tum(tmp_path / "cut.tum", np.linspace(0, 5, 40), cut=True)
    manifest = tmp_path / "m.yaml"
    manifest.write_text(
        "schema_version: 1\ncommand: evaluate\n"
        f"defaults: {{gt: {gt}}}\nitems:\n"
        f"- {{name: whole, trajectory: {whole}}}\n- {{name: cut, trajectory: {cut}}}\n"
    )
    # the single command's warning, for reference
    assert main(["evaluate", str(cut), "--gt", str(gt)]) == 0
    single = [ln for ln in capsys.readouterr().err.splitlines() if ln.startswith("warning:")]
    assert len(single) == 1
    assert "cut.tum:41:" in single[0]
    assert "left out as incomplete" in single[0]

    assert main(["batch", str(manifest), "-o", str(tmp_path / "out"), "-j", "1"]) == 0
    err = capsys.readouterr().err
    assert f"warning: cut: {single[0].removeprefix('warning: ')}" in err.splitlines()
    assert "warning: whole" not in err
    rec = json.loads((tmp_path / "out" / "cut" / "item.json").read_text())
    assert rec["status"] == "ok"
    assert single[0] in rec["stderr"]
    doc = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert doc["schema_version"] == 3
    by_name = {r["name"]: r for r in doc["items"]}
    assert by_name["cut"]["warnings"] == single[0].removeprefix("warning: ")
    assert by_name["whole"]["warnings"] is None
    with open(tmp_path / "out" / "summary.csv", newline="") as f:
        rows = {r["name"]: r for r in csv.DictReader(f)}
    assert rows["cut"]["warnings"] == by_name["cut"]["warnings"]
    assert rows["whole"]["warnings"] == ""
