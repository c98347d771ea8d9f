"""The file boundary's promises: modes that follow the umask, outputs apart from inputs,
--force only over rigcal's own folders, nothing half-written even under kill -9."""

from __future__ import annotations

import os
import signal
import stat
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from rigcal.errors import OutputError
from rigcal.io.files import (
    MARKER,
    atomic_folder,
    atomic_write_text,
    check_apart,
    check_folder_writable,
    check_writable,
    current_umask,
    remove_stale_temporaries,
)


def mode(p: Path) -> int:
    return stat.S_IMODE(p.stat().st_mode)


@pytest.fixture
def umask():
    old = os.umask(0o022)
    yield lambda m: os.umask(m)
    os.umask(old)


def test_current_umask_reads_without_changing(umask):
    umask(0o027)
    assert current_umask() == 0o027
    assert current_umask() == 0o027


@pytest.mark.parametrize(("mask", "expected"), [(0o022, 0o644), (0o077, 0o600), (0o002, 0o664)])
def test_files_follow_the_umask(tmp_path, umask, mask, expected):
    umask(mask)
    p = atomic_write_text(tmp_path / "a.yaml", "x\n")
    assert mode(p) == expected
    with atomic_folder(tmp_path / "f") as tmp:
        (tmp / "b.txt").write_text("y")
    assert mode(tmp_path / "f" / "b.txt") == expected
    assert mode(tmp_path / "f") == expected | 0o111 & ~mask


def test_force_over_a_0644_file_keeps_the_umask_mode(tmp_path, umask):
    p = tmp_path / "rig.yaml"
    p.write_text("old")
    p.chmod(0o644)
    atomic_write_text(p, "new", force=True)
    assert mode(p) == 0o644
    assert p.read_text() == "new"


def test_a_dangling_symlink_needs_force(tmp_path):
    link = tmp_path / "link"
    link.symlink_to(tmp_path / "nowhere")
    with pytest.raises(OutputError, match="exists"):
        atomic_write_text(link, "x")
    assert link.is_symlink()
    with pytest.raises(OutputError, match="not a folder"):
        check_folder_writable(link, force=True)


@pytest.mark.parametrize(
    ("out", "message"),
    [
        ("in/seq", "is the input"),
        ("in", "contains the input"),
        ("in/seq/sub", "is inside the input"),
        ("in/seq/../seq", "is the input"),
        ("in/alias", "is the input"),
    ],
)
def test_outputs_stay_apart_from_inputs(tmp_path, out, message):
    (tmp_path / "in" / "seq").mkdir(parents=True)
    (tmp_path / "in" / "alias").symlink_to(tmp_path / "in" / "seq")
    with pytest.raises(OutputError, match=message):
        check_apart(tmp_path / out, [tmp_path / "in" / "seq"])
    check_apart(tmp_path / "elsewhere", [tmp_path / "in" / "seq"])
    check_apart(tmp_path / "in" / "seq2", [tmp_path / "in" / "seq"])  # a sibling, not inside


def test_a_file_output_may_sit_beside_an_input_file(tmp_path):
    (tmp_path / "rig.yaml").write_text("x")
    check_writable(tmp_path / "rig.ros", False, [tmp_path / "rig.yaml"])
    with pytest.raises(OutputError, match="is the input"):
        check_writable(tmp_path / "rig.yaml", True, [tmp_path / "rig.yaml"])


def test_force_replaces_only_folders_rigcal_wrote(tmp_path):
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "notes.txt").write_text("keep")
    with pytest.raises(OutputError, match="not written by rigcal"), atomic_folder(mine, force=True):
        pass
    assert (mine / "notes.txt").read_text() == "keep"
    (tmp_path / "empty").mkdir()
    with atomic_folder(tmp_path / "empty", force=True) as tmp:
        (tmp / "a").write_text("1")
    assert (tmp_path / "empty" / MARKER).is_file()
    with atomic_folder(tmp_path / "empty", force=True) as tmp:
        (tmp / "b").write_text("2")
    assert sorted(p.name for p in (tmp_path / "empty").iterdir()) == [MARKER, "b"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["empty", "mine"]


def test_a_failed_folder_write_leaves_nothing(tmp_path):
    def fill(tmp: Path) -> None:
        (tmp / "half").write_text("x")
        raise RuntimeError("boom")

    with pytest.raises(RuntimeError), atomic_folder(tmp_path / "out") as tmp:
        fill(tmp)
    assert list(tmp_path.iterdir()) == []


def dead_pid() -> int:
    p = subprocess.Popen([sys.executable, "-c", "pass"])
    p.wait()
    return p.pid


def test_stale_temporaries_of_dead_processes_are_removed(tmp_path):
    pid = dead_pid()
    (tmp_path / f".out.{pid}.abcd.tmp").mkdir()
    (tmp_path / f".rig.yaml.{pid}.xyz.tmp").write_text("half")
    (tmp_path / f".out.{os.getpid()}.live.tmp").mkdir()  # a running process's: kept
    (tmp_path / ".out.notapid.tmp").mkdir()  # not rigcal's pattern: kept
    remove_stale_temporaries(tmp_path / "out")
    remove_stale_temporaries(tmp_path / "rig.yaml")
    assert sorted(p.name for p in tmp_path.iterdir()) == [f".out.{os.getpid()}.live.tmp", ".out.notapid.tmp"]


def test_an_old_folder_of_a_dead_swap_is_put_back(tmp_path):
    old = tmp_path / f".out.{dead_pid()}.abcd.old"
    old.mkdir()
    (old / "summary.yaml").write_text("previous")
    remove_stale_temporaries(tmp_path / "out")
    assert (tmp_path / "out" / "summary.yaml").read_text() == "previous"


# --- kill -9 mid-write -----------------------------------------------------------------------
# The child blocks at the moment of publication (the rename) after writing everything to
# its temporary; the test kills it there with SIGKILL, the worst moment for a writer.
WRITE = textwrap.dedent(
    """
    from pathlib import Path
    import numpy as np

    def write(writer, target):
        from rigcal.scan import Scan
        scan = Scan.from_uniform(-1.0, 0.01, np.full(200, 2.0), 0.05, 30.0, 1.0)
        if writer == "scan":
            from rigcal.scan import write_scan
            write_scan(target, scan, force=True)
        elif writer == "text":
            from rigcal.io.files import atomic_write_text
            atomic_write_text(target, "new export\\n" * 10000, force=True)
        elif writer == "png":
            from rigcal.viz.scan_plot import render_scan_segments
            render_scan_segments(scan, [], target, force=True)
        elif writer == "tum":
            from rigcal.io.trajectory import Trajectory, write_tum
            write_tum(target, Trajectory(np.tile(np.eye(4), (5, 1, 1)), np.arange(5.0)), force=True)
        elif writer == "sequence":
            from rigcal.recordings.sequence import write_sequence
            write_sequence(target, "s", [scan] * 3, [], None, {}, force=True)
        elif writer == "session":
            from rigcal.sim.box_session import SessionSpec, generate_session, write_session
            session = generate_session(SessionSpec(n_captures=3, seed=1))
            write_session(session, target, force=True, render_images=False)
    """
)
CHILD = WRITE + textwrap.dedent(
    """
    import os, sys, time

    calls = {"n": 0}

    def blocking(real):
        def f(*a, **k):
            calls["n"] += 1
            if calls["n"] == int(sys.argv[3]):
                print("ready", flush=True)
                time.sleep(60)
            return real(*a, **k)
        return f

    # Files are published by os.replace, folders by os.rename (folder aside, then new in).
    if sys.argv[1] in ("sequence", "session"):
        os.rename = blocking(os.rename)
    else:
        os.replace = blocking(os.replace)
    write(sys.argv[1], Path(sys.argv[2]))
    """
)

FILE_WRITERS = ["scan", "text", "png", "tum"]
FOLDER_WRITERS = ["sequence", "session"]


def kill_mid_write(writer: str, target: Path, block_at: int = 1) -> None:
    child = subprocess.Popen(
        [sys.executable, "-c", CHILD, writer, str(target), str(block_at)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    assert child.stdout is not None
    line = child.stdout.readline()
    assert line == "ready\n", child.stderr.read() if child.stderr else ""
    child.send_signal(signal.SIGKILL)
    child.wait()


def run_writer(writer: str, target: Path) -> None:
    """The same writer, in this process."""
    namespace: dict[str, object] = {}
    exec(WRITE, namespace)
    namespace["write"](writer, target)  # type: ignore[operator]


def previous(target: Path, folder: bool) -> dict[str, bytes]:
    if not target.exists():
        return {}
    if not folder:
        return {target.name: target.read_bytes()}
    return {p.relative_to(target).as_posix(): p.read_bytes() for p in target.rglob("*") if p.is_file()}


@pytest.mark.parametrize(
    ("writer", "over_existing"),
    [(w, False) for w in FILE_WRITERS] + [(w, e) for w in FOLDER_WRITERS for e in (False, True)],
)
def test_kill_9_mid_write_leaves_no_partial_output(tmp_path, writer, over_existing):
    folder = writer in FOLDER_WRITERS
    target = tmp_path / ("out" if folder else f"out.{writer}")
    if over_existing:
        run_writer(writer, target)
    before = previous(target, folder)
    # For a folder over an existing one the second rename (the new folder into place, after
    # the old one was moved aside) is the worst moment.
    kill_mid_write(writer, target, 2 if over_existing else 1)
    if not over_existing:
        assert previous(target, folder) == before  # still absent
    assert any(p.name.startswith(f".{target.name}.") for p in tmp_path.iterdir())  # its temporary
    remove_stale_temporaries(target)  # what the next write does first
    assert previous(target, folder) == before  # absent, or the old output back in place
    assert [p.name for p in tmp_path.iterdir()] == ([target.name] if before else [])
    run_writer(writer, target)  # and the next write succeeds
    assert sorted(p.name for p in tmp_path.iterdir()) == [target.name]
