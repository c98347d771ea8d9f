"""The command line's error paths: each ends in its documented exit code (docs/cli.md)
with one ``Error:`` line on stderr and nothing written."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import pytest

from rigcal.cli.main import main


@pytest.fixture
def fails(capsys, tmp_path) -> Callable[[list[str], int], str]:
    """Run ``rigcal ARGV`` and check that it fails with ``code``, one ``Error:`` line and no
    new file under ``tmp_path``; return the error line."""

    def run(argv: list[str], code: int) -> str:
        before = set(Path(tmp_path).rglob("*"))
        assert main([str(a) for a in argv]) == code
        err = capsys.readouterr().err
        lines = err.strip().splitlines()
        assert lines, "no error line"
        assert lines[-1].startswith("Error: "), err
        assert "Traceback" not in err
        assert set(Path(tmp_path).rglob("*")) == before
        return lines[-1]

    return run
