"""Outputs that cannot be written: a read-only folder (or another user's) is refused
before any work with exit code 5 and one line naming it, whether the command writes a
folder (`localize`, the importers) or a file (`evaluate --plot`); an output folder that
exists or is a file as before. Nothing is written."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

import rigcal.io.files
from room_scans import room_drive


@pytest.fixture(scope="module")
def drive(tmp_path_factory) -> Path:
    return room_drive(tmp_path_factory.mktemp("drive"))


@pytest.fixture
def read_only(tmp_path, monkeypatch) -> Path:
    """A folder that cannot be written: really (chmod 555) for a user, and as the system
    would answer for root on a read-only mount (root passes permission bits)."""
    folder = tmp_path / "ro"
    folder.mkdir()
    folder.chmod(0o555)
    real = os.access

    def access(path, mode, **kw):
        if Path(path) == folder and mode & os.W_OK:
            return False
        return real(path, mode, **kw)

    monkeypatch.setattr(rigcal.io.files.os, "access", access)
    yield folder
    folder.chmod(0o755)


@pytest.mark.parametrize("out", ["out", "a/b/out"])
def test_localize_into_a_read_only_folder_stops_before_any_work(drive, read_only, fails, capsys, out):
    line = fails(["localize", drive, "--method", "icp", "-o", read_only / out], 5)
    assert line == f"Error: {read_only / out}: cannot write into {read_only} (read-only or not yours)"
    assert "laser odometry" not in capsys.readouterr().err  # refused before the work
    assert list(read_only.iterdir()) == []


def test_evaluate_plot_into_a_read_only_folder(drive, read_only, fails):
    gt = drive / "groundtruth.tum"
    gt.write_text("".join(f"{0.1 * k!r} {0.05 * k!r} 0 0 0 0 0 1\n" for k in range(40)))
    line = fails(["evaluate", gt, "--gt", gt, "--plot", read_only / "e.png"], 5)
    assert "cannot write into" in line
    gt.unlink()


def test_an_import_into_a_read_only_folder(tmp_path, read_only, fails):
    (tmp_path / "laser.txt").write_text("1.0 -0.5 0.25 0.5 3 5 2.0 2.0 2.0 2.0 2.0\n")
    line = fails(["import-laser", tmp_path / "laser.txt", "-o", read_only / "seq"], 5)
    assert line.endswith(f"cannot write into {read_only} (read-only or not yours)")


@pytest.mark.parametrize("what", ["folder", "file"])
def test_localize_over_a_folder_or_file_that_exists(drive, tmp_path, fails, what):
    out = tmp_path / "out"
    if what == "folder":
        out.mkdir()
        (out / "notes.txt").write_text("mine")
        assert fails(["localize", drive, "--method", "icp", "-o", out], 5).endswith(
            "pass --force to replace it"
        )
        line = fails(["localize", drive, "--method", "icp", "-o", out, "--force"], 5)
        assert "was not written by rigcal" in line
        assert (out / "notes.txt").read_text() == "mine"
    else:
        out.write_text("mine")
        line = fails(["localize", drive, "--method", "icp", "-o", out, "--force"], 5)
        assert line.endswith("exists and is not a folder; refusing to replace it")
        assert out.read_text() == "mine"
