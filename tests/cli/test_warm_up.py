"""`rigcal warm-up`: every kernel compiled or loaded, nothing written but numba's cache."""

from __future__ import annotations

import os

from rigcal.cli.main import main
from rigcal.jit import COMPILED


def test_warm_up_runs_the_tour_and_reports_only_compiles(tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("TMPDIR", str(tmp_path))
    import tempfile

    monkeypatch.setattr(tempfile, "tempdir", None)
    before = len(COMPILED)
    assert main(["warm-up"]) == 0
    cap = capsys.readouterr()
    assert cap.out == ""
    compiled = len(COMPILED) - before
    if compiled:
        assert cap.err.startswith(f"compiled {compiled} kernels in ")
    else:
        assert cap.err == ""  # everything was cached: nothing to say
    assert os.listdir(tmp_path) == []  # its simulated data are gone
