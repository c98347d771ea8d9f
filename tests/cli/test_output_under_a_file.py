"""An output path under a file (``-o run.log/out``) is refused before any work, naming the
file, for every kind of output: a folder, a single file, the drift log, a chart."""

from __future__ import annotations

import pytest

from rigcal.errors import OutputError
from rigcal.io.files import atomic_write_text, check_folder_writable, check_writable


@pytest.mark.parametrize("depth", [1, 3])
def test_every_output_check_names_the_file_in_the_way(tmp_path, depth):
    blocker = tmp_path / "run.log"
    blocker.write_text("a log\n")
    out = blocker.joinpath(*(["sub"] * (depth - 1)), "out")
    match = rf"{out}: {blocker} is a file; expected a folder to write into"
    with pytest.raises(OutputError, match=match):
        check_folder_writable(out, force=True)
    with pytest.raises(OutputError, match=match):
        check_writable(out, force=True)
    assert blocker.read_text() == "a log\n"


def test_an_output_beside_a_file_is_fine(tmp_path):
    (tmp_path / "run.log").write_text("x")
    assert check_folder_writable(tmp_path / "new" / "out", force=False) == tmp_path / "new" / "out"
    atomic_write_text(tmp_path / "new.txt", "y")


def test_commands_refuse_it_with_exit_5(tmp_path, fails):
    blocker = tmp_path / "run.log"
    blocker.write_text("FLASER 1 1.0 0 0 0 0 0 0 100.0 h 1\n")
    line = fails(["import-carmen", blocker, "-o", blocker / "seq"], 5)
    assert line == f"Error: {blocker / 'seq'}: {blocker} is a file; expected a folder to write into"
    fails(["simulate", "box-session", "-o", blocker / "session"], 5)
