"""Run a batch's items, each in a worker process, on a local process pool or a Ray cluster.

Every item calls the library function of its command (:mod:`rigcal.jobs`, the one the
single command calls), so its outputs are written exactly as ``rigcal
check|solve|localize|evaluate`` writes them; the command's JSON is the item's result. The
command line a rig file's provenance records is passed in: the batch's own, naming the
item and its single command's equivalent. A rigcal error, a bad option value or a bug in
one item is recorded for that item and the others go on. When an item ends,
``OUT/NAME/item.json`` records it (docs/formats/batch.md); a re-run skips items whose
record says they finished with the same command line and whose outputs are all there.

The local pool and Ray share one code path: both hand out
:class:`concurrent.futures.Future` objects for :func:`run_item` (Ray through
``ObjectRef.future()``), and one loop keeps a bounded number of them submitted and
collects them. Connecting to Ray (the ``--ray`` address forms, the connect timeout, a
loopback-only local instance) is :mod:`rigcal.batch.raycluster`.
"""

from __future__ import annotations

import concurrent.futures as cf
import contextlib
import datetime
import io
import itertools
import json
import multiprocessing
import os
import shlex
import sys
import time
import traceback
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from rigcal.batch.manifest import COMMANDS, Item
from rigcal.batch.raycluster import RayAddress, connect, differ, parse_address, versions
from rigcal.errors import OutputError
from rigcal.io.files import MARKER, atomic_write_text, check_apart

ITEM_SCHEMA_VERSION = 2  # 2: node
READABLE_ITEM_VERSIONS = (1, 2)
ITEM_FILE = "item.json"

# Exit codes of the single commands that mean "ran to the end" (check: 1 = drifted,
# 6 = a drive that cannot tell).
FINISHED = {"check": (0, 1, 6), "solve": (0,), "localize": (0,), "evaluate": (0,)}


@dataclass(frozen=True)
class BatchSettings:
    """How to run: ``workers`` local processes, or Ray at ``ray_address`` when given
    (``local`` starts a Ray instance on this machine's loopback interface; ``auto`` joins
    the running cluster; ``HOST:PORT`` a cluster's head from one of its nodes;
    ``ray://HOST:PORT`` a remote one through Ray Client: :mod:`rigcal.batch.raycluster`).
    ``rerun`` re-runs finished items too. ``connect_timeout_s`` bounds reaching a named
    cluster; ``ray_retries``: how often Ray runs an item again elsewhere when its worker
    or node dies (not when the command fails)."""

    workers: int = 0  # 0: one per CPU
    ray_address: str | None = None
    rerun: bool = False
    connect_timeout_s: float = 10.0
    ray_retries: int = 1


def run_item(item: Item, folder: Path, command: str, expect: dict[str, str] | None = None) -> dict[str, Any]:
    """Run one item in this process; never raises.

    Args:
        item: the item, its command and options.
        folder: the item's output folder.
        command: the command line its rig file's provenance records.
        expect: the driver's :func:`versions`; a worker with others does not run the item
            (a node of a cluster installed differently) and says which differ.

    Returns:
        ``exit_code`` as the single command's (2 for a bad option value); ``stdout``: the
        command's JSON; ``stderr``: its log lines and errors; ``error``: the one-line
        message of a rigcal error, or the traceback's last line of a bug; ``seconds`` of
        wall time; ``host`` and ``pid`` that ran it; ``node``: the Ray node's address when
        run as a Ray task, else None.
    """
    where = {"host": os.uname().nodename, "pid": os.getpid(), "node": _ray_node()}
    other = None if expect is None else differ(versions(), expect)
    if other is not None:
        return {
            "exit_code": 70,
            "stdout": "",
            "stderr": "",
            "error": f"worker on {where['node'] or where['host']} runs {other}; not run",
            "seconds": 0.0,
            **where,
        }
    from rigcal.errors import ArgumentError, RigcalError

    out, err = "", io.StringIO()
    t0 = time.perf_counter()
    error: str | None = None
    try:
        with contextlib.redirect_stderr(err):
            code, doc = _run_job(item, folder, command)
        out = json.dumps(doc, indent=1) + "\n"
    except RigcalError as exc:
        # A bad option value is the command's usage error (exit code 2), as on its command line.
        code = 2 if isinstance(exc, ArgumentError) else exc.exit_code
        error = str(exc)
        err.write(f"Error: {error}\n")
    except Exception as exc:  # a bug in the command: keep its traceback in the record
        code = 70
        err.write(traceback.format_exc())
        error = f"internal error: {type(exc).__name__}: {exc}"
    return {
        "exit_code": code,
        "stdout": out,
        "stderr": err.getvalue(),
        "error": error,
        "seconds": round(time.perf_counter() - t0, 3),
        **where,
    }


def _run_job(item: Item, folder: Path, command: str) -> tuple[int, Any]:
    """The item's command as its library function (:mod:`rigcal.jobs`) with the outputs
    :meth:`Item.argv` gives the single command; the exit code and the JSON document."""
    from rigcal import jobs

    o = item.options

    def path(key: str) -> Path | None:
        return Path(o[key]) if key in o else None

    if item.command == "solve":
        given = {
            k: o[k]
            for k in ("truth", "seed", "threshold_px", "pick_sigma_px", "range_sigma_m", "loss")
            if k in o
        }
        if "truth" in given:
            given["truth"] = Path(given["truth"])
        solved = jobs.solve_files(
            Path(o["picks"]),
            folder / "rig.yaml",
            command=command,
            report_dir=folder / "report",
            paper_endpoints=bool(o.get("paper_endpoints", False)),
            force=True,
            **given,
        )
        return 0, solved.doc
    if item.command == "check":
        checked = jobs.check_rig(
            Path(o["rig"]),
            picks=path("picks"),
            session=path("session"),
            sequence=path("sequence"),
            trajectory=path("trajectory"),
            wheel_odometry=o.get("wheel_odometry", "use") == "use",
            log=path("log"),
            no_log=bool(o.get("no_log", False)),
            **{k: o[k] for k in ("level", "min_captures") if k in o},
        )
        return checked.exit_code, checked.record
    if item.command == "localize":
        done = jobs.localize_sequence(
            Path(o["sequence"]),
            folder / "localize",
            methods=o.get("method", "icp"),
            rig=path("rig"),
            kitti=bool(o.get("kitti", False)),
            iasm=[str(v) for v in o.get("iasm", ())],
            tracks=[str(v) for v in o.get("tracks", ())],
            force=True,
        )
        return 0, done.doc
    assert item.command == "evaluate", item.command
    scored = jobs.evaluate_files([Path(o["trajectory"])], Path(o["gt"]))
    for cut_path, cut in scored.cut:  # the single command's warning, in the item's stderr
        print(f"warning: {cut.warning(cut_path)}", file=sys.stderr)
    return 0, scored.doc


def warning_lines(stderr: str) -> list[str]:
    """The ``warning:`` lines an item's command printed (its stderr), without the prefix:
    what the single command would have said on the terminal (a file read to its last whole
    line, stamps repaired), kept in the batch's summary."""
    return [
        line.split(":", 1)[1].strip() for line in stderr.splitlines() if line.lower().startswith("warning:")
    ]


def item_command(batch_command: str, item: Item, argv: list[str]) -> str:
    """The command line an item's results record (a rig file's ``provenance.command``):
    the batch's, then the item and the single command that writes the same."""
    return f"{batch_command} [item {item.name}: rigcal {shlex.join(argv)}]"


def _ray_node() -> str | None:
    """The address of the Ray node this process is a worker of, or None."""
    ray = sys.modules.get("ray")
    if ray is None or not ray.is_initialized():
        return None
    try:
        return str(ray.util.get_node_ip_address())
    except Exception:  # Ray's errors have no common base class
        return None


def item_record(item: Item, argv: list[str], ran: dict[str, Any]) -> dict[str, Any]:
    """The ``item.json`` record of a finished or failed item."""
    code = ran["exit_code"]
    ok = code in FINISHED[item.command] and ran["error"] is None
    result: Any = None
    if ok:
        try:
            result = json.loads(ran["stdout"])
        except json.JSONDecodeError:
            ok, ran["error"] = False, "the command's output is not JSON"
    status = "failed"
    if ok:
        status = {1: "drifted", 6: "cannot_tell"}.get(code, "ok") if item.command == "check" else "ok"
    return {
        "schema_version": ITEM_SCHEMA_VERSION,
        "name": item.name,
        "command": item.command,
        "argv": argv,
        "status": status,
        "exit_code": code,
        "error": ran["error"],
        "seconds": ran["seconds"],
        "host": ran["host"],
        "node": ran.get("node"),
        "finished_utc": datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%dT%H:%M:%SZ"),
        "result": result,
        "stderr": ran["stderr"][-4000:],
    }


def finished_record(item: Item, folder: Path) -> dict[str, Any] | None:
    """The earlier record of ``item`` if it finished with the same command line and its
    outputs are all there (then a re-run skips it), else None."""
    path = folder / ITEM_FILE
    try:
        rec = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError, RecursionError):
        return None
    if not isinstance(rec, dict) or rec.get("schema_version") not in READABLE_ITEM_VERSIONS:
        return None
    if rec.get("status") not in ("ok", "drifted", "cannot_tell") or rec.get("argv") != item.argv(folder):
        return None
    if not all((folder / o).exists() for o in COMMANDS[item.command].outputs):
        return None
    return rec


@dataclass(frozen=True)
class Task:
    """One item to run: its output folder, the command line its results record, and the
    single command's equivalent (``item.json``'s ``argv``)."""

    item: Item
    folder: Path
    command: str
    argv: list[str]


@dataclass
class Outcome:
    """One item's record and whether it was taken from an earlier run."""

    item: Item
    record: dict[str, Any]
    resumed: bool


def run_batch(
    items: list[Item],
    output: str | Path,
    settings: BatchSettings | None = None,
    progress: Callable[[Outcome, int, int], None] | None = None,
    log: Callable[[str], None] | None = None,
    command: str = "rigcal batch",
) -> list[Outcome]:
    """Run every item not finished yet, writing ``OUT/NAME/`` per item.

    Items are handed out a few at a time (twice the workers or the cluster's CPUs), so
    that a manifest of any length holds only that many tasks in the pool or the cluster.

    Args:
        items: from :func:`~rigcal.batch.manifest.read_manifest` or ``glob_items``.
        output: the batch's output folder (created; kept between runs for resuming).
        settings: workers, Ray address, re-run.
        progress: called after each item with its outcome, the count done and the total.
        log: called with a line about the run (where Ray runs, its session files).
        command: the batch's command line, which the items' rig files record
            (:func:`item_command`).

    Returns:
        The outcomes in the items' order.

    Raises:
        InputError: Ray was asked for and cannot be imported or reached.
        OutputError: an item's record cannot be written.
    """
    settings = settings or BatchSettings()
    address = None if settings.ray_address is None else parse_address(settings.ray_address)
    out = Path(output)
    if out.exists() and not out.is_dir():
        raise OutputError(f"{out}: exists and is not a folder; expected the batch's output folder")
    # The items' inputs stay apart from the output (a drift log is one of the check's outputs).
    check_apart(out, [Path(v) for i in items for k, v in i.options.items() if k != "log" and _is_path(v)])
    try:
        foreign = out.is_dir() and not (out / MARKER).is_file() and any(out.iterdir())
    except OSError as exc:
        raise OutputError(f"{out}: cannot read: {exc.strerror or exc}") from None
    if foreign:
        raise OutputError(
            f"{out}: exists and was not written by rigcal (no {MARKER} file); "
            "expected a new, empty or earlier batch output folder"
        )
    outcomes: dict[str, Outcome] = {}
    todo: list[Task] = []
    for item in items:
        folder = (out / item.name).resolve()
        rec = None if settings.rerun else finished_record(item, folder)
        if rec is not None:
            outcomes[item.name] = Outcome(item, rec, resumed=True)
        else:
            argv = item.argv(folder)
            todo.append(Task(item, folder, item_command(command, item, argv), argv))
    done = len(outcomes)
    if progress is not None:
        for o in outcomes.values():
            progress(o, done, len(items))
    if todo and not (out / MARKER).is_file():
        atomic_write_text(out / MARKER, "This folder was written by rigcal batch.\n")
    if todo:
        with _executor(settings, address, len(todo), log or (lambda line: None)) as (submit, window):
            waiting = iter(todo)
            futures: dict[cf.Future[dict[str, Any]], Task] = {}
            for task in itertools.islice(waiting, window):
                futures[_submitted(submit, task)] = task
            while futures:
                finished, _ = cf.wait(futures, return_when=cf.FIRST_COMPLETED)
                for fut in finished:
                    task = futures.pop(fut)
                    item = task.item
                    for nxt in itertools.islice(waiting, 1):
                        futures[_submitted(submit, nxt)] = nxt
                    rec = item_record(item, task.argv, _result(fut))
                    atomic_write_text(
                        out / item.name / ITEM_FILE, json.dumps(rec, indent=1) + "\n", force=True
                    )
                    outcomes[item.name] = Outcome(item, rec, resumed=False)
                    done += 1
                    if progress is not None:
                        progress(outcomes[item.name], done, len(items))
    return [outcomes[i.name] for i in items]


def _submitted(submit: Submit, task: Task) -> cf.Future[dict[str, Any]]:
    """``submit(task)``, or a future holding its error: a pool whose worker died refuses
    new items, which are then recorded as failed like the items it was running."""
    try:
        return submit(task)
    except Exception as exc:  # BrokenProcessPool, a lost Ray connection
        fut: cf.Future[dict[str, Any]] = cf.Future()
        fut.set_exception(exc)
        return fut


def _is_path(value: Any) -> bool:
    return isinstance(value, (str, Path)) and Path(value).is_absolute()


def _result(fut: cf.Future[dict[str, Any]]) -> dict[str, Any]:
    """A worker's answer, or a failed item's when the worker itself died."""
    try:
        return fut.result()
    except Exception as exc:  # a crashed worker process or a lost Ray node
        return {
            "exit_code": 70,
            "stdout": "",
            "stderr": "",
            "error": f"worker failed: {type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}",
            "seconds": 0.0,
            "host": "",
            "node": None,
        }


Submit = Callable[[Task], "cf.Future[dict[str, Any]]"]


@contextlib.contextmanager
def _executor(
    settings: BatchSettings, address: RayAddress | None, n_items: int, log: Callable[[str], None]
) -> Iterator[tuple[Submit, int]]:
    """A submit function for :func:`run_item` (a local process pool or Ray tasks) and how
    many items to keep submitted at once."""
    if address is None:
        workers = min(settings.workers or os.cpu_count() or 1, n_items)
        # spawn: fresh interpreters, no copied threads or locks (cv2, numba) from this one
        ctx = multiprocessing.get_context("spawn")
        threads = max(1, (os.cpu_count() or 1) // workers)
        with (
            _thread_limits(threads),
            cf.ProcessPoolExecutor(workers, ctx, _start_worker, (threads,)) as pool,
        ):
            yield (lambda t: pool.submit(run_item, t.item, t.folder, t.command)), 2 * workers
        return
    expect = versions()
    with connect(address, settings.workers, settings.connect_timeout_s, log) as (ray, session):
        remote = ray.remote(num_cpus=1, max_retries=settings.ray_retries)(run_item)
        remote = remote.options(**session.task_options) if session.task_options else remote
        # -j N on a cluster: at most N items at once (a share of a shared cluster)
        window = settings.workers or 2 * max(1, int(ray.cluster_resources().get("CPU", 1)))
        yield (lambda t: remote.remote(t.item, t.folder, t.command, expect).future()), window


# Thread pools of the libraries under a worker: BLAS (OpenMP, OpenBLAS, MKL) and numba.
THREAD_VARIABLES = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS")


@contextlib.contextmanager
def _thread_limits(threads: int) -> Iterator[None]:
    """While the pool runs, the environment its workers start with gives each library
    ``threads`` threads (the cores shared out among the workers, as Ray does for its
    tasks), unless the user set a variable already: workers that each start a thread per
    core would oversubscribe the machine."""
    unset = [v for v in THREAD_VARIABLES if v not in os.environ]
    for v in unset:
        os.environ[v] = str(threads)
    try:
        yield
    finally:
        for v in unset:
            os.environ.pop(v, None)


def _start_worker(threads: int) -> None:
    """A pool worker's start: OpenCV's own thread pool to ``threads`` threads."""
    import cv2

    cv2.setNumThreads(threads)
