"""The --ray address: its forms, a bounded connect, one-line errors before anything runs;
the per-item version check of a worker installed differently."""

from __future__ import annotations

import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from rigcal.batch.manifest import Item
from rigcal.batch.raycluster import RayAddress, parse_address, probe, resolve
from rigcal.batch.runner import BatchSettings, run_batch, run_item, versions
from rigcal.errors import InputError


@pytest.mark.parametrize(
    ("text", "kind", "host", "port"),
    [
        ("local", "local", "", 0),
        ("auto", "auto", "", 0),
        ("10.0.0.5:6379", "gcs", "10.0.0.5", 6379),
        ("head.lab.example:6379", "gcs", "head.lab.example", 6379),
        ("ray://head:10001", "client", "head", 10001),
        ("ray://[::1]:10001", "client", "::1", 10001),
    ],
)
def test_address_forms(text, kind, host, port):
    a = parse_address(text)
    assert (a.kind, a.host, a.port) == (kind, host, port)
    assert a.target == (text if kind != "client" or host != "::1" else "ray://[::1]:10001")


@pytest.mark.parametrize(
    "text",
    ["", "Auto", "head", "head:", ":6379", "head:0", "head:65536", "head:63x", "http://head:10001",
     "ray://head", "ray://:10001", "he ad:6379", "[::1:6379", "[zz]:1", "head:6379/x"],
)  # fmt: skip
def test_malformed_addresses_are_one_line(text):
    with pytest.raises(
        InputError, match=r"^--ray: got .*; expected auto, local, HOST:PORT or ray://HOST:PORT"
    ):
        parse_address(text)


def test_auto_takes_ray_address_and_checks_it(monkeypatch):
    monkeypatch.setenv("RAY_ADDRESS", "10.1.2.3:6379")
    assert resolve(parse_address("auto")) == RayAddress("auto", "gcs", "10.1.2.3", 6379)
    monkeypatch.setenv("RAY_ADDRESS", "local")
    with pytest.raises(InputError, match=r"RAY_ADDRESS \(from --ray auto\): got 'local'; expected HOST:PORT"):
        resolve(parse_address("auto"))
    monkeypatch.setenv("RAY_ADDRESS", "nowhere")
    with pytest.raises(InputError, match=r"RAY_ADDRESS \(from --ray auto\): got 'nowhere'"):
        resolve(parse_address("auto"))
    monkeypatch.delenv("RAY_ADDRESS")
    assert resolve(parse_address("auto")).kind == "auto"


def test_probe_of_a_closed_port_fails_at_once():
    with socket.socket() as s:  # a port nothing listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    t0 = time.perf_counter()
    with pytest.raises(
        InputError, match=rf"cannot connect to 127.0.0.1:{port} within 2 s: Connection refused"
    ):
        probe(parse_address(f"127.0.0.1:{port}"), 2.0)
    assert time.perf_counter() - t0 < 2


def _items(tmp_path: Path) -> list[Item]:
    t = tmp_path / "a.tum"
    t.write_text("\n".join(f"{0.1 * i:.1f} {x:.3f} 0 0 0 0 0 1" for i, x in enumerate(np.linspace(0, 1, 5))))
    return [Item("a", "evaluate", {"trajectory": t, "gt": t})]


def test_unreachable_cluster_is_one_line_before_anything_is_written(tmp_path):
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    for address in (f"127.0.0.1:{port}", f"ray://127.0.0.1:{port}"):
        with pytest.raises(InputError, match=rf"--ray: got '{address}'; expected a reachable Ray cluster"):
            run_batch(
                _items(tmp_path), tmp_path / "o", BatchSettings(ray_address=address, connect_timeout_s=2)
            )
    with pytest.raises(InputError, match=r"--ray: got 'ray:/x:1'; expected auto, local"):
        run_batch(_items(tmp_path), tmp_path / "o", BatchSettings(ray_address="ray:/x:1"))
    assert not (tmp_path / "o").exists() or not any((tmp_path / "o").glob("*/item.json"))


def test_the_cli_does_not_hang_on_a_port_without_scheme(tmp_path):
    """`--ray localhost:1` (the form that used to wait for minutes): one line, exit 3."""
    t = tmp_path / "a.tum"
    t.write_text("0 0 0 0 0 0 0 1\n0.1 1 0 0 0 0 0 1\n")
    cmd = [str(Path(sys.executable).with_name("rigcal")), "batch", str(t), "--command", "evaluate"]
    cmd += ["--set", f"gt={t}", "-o", str(tmp_path / "o"), "--ray", "localhost:1", "--ray-timeout", "3"]
    t0 = time.perf_counter()
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=120, check=False)
    assert done.returncode == 3, done.stderr
    last = done.stderr.strip().splitlines()[-1]
    assert last.startswith(
        "Error: --ray: got 'localhost:1'; expected a reachable Ray cluster (cannot connect"
    )
    assert last.endswith("localhost:1 within 3 s: Connection refused)")
    assert time.perf_counter() - t0 < 60


def test_a_worker_with_other_versions_does_not_run_the_item(tmp_path):
    item = _items(tmp_path)[0]
    same = run_item(item, tmp_path / "a", "rigcal batch", versions())
    assert same["exit_code"] == 0
    other = run_item(item, tmp_path / "b", "rigcal batch", {**versions(), "python": "3.11.9"})
    assert other["exit_code"] == 70
    assert (
        other["error"]
        == f"worker on {other['host']} runs python {versions()['python']} (driver: 3.11.9); not run"
    )
    assert other["stdout"] == ""


def test_records_of_item_json_version_1_are_resumed(tmp_path):
    """item.json 2 adds `node`; a finished record of version 1 is still skipped."""
    import json

    items = _items(tmp_path)
    out = tmp_path / "o"
    (first,) = run_batch(items, out, BatchSettings(workers=1))
    assert first.record["schema_version"] == 2
    assert first.record["node"] is None
    old = {k: v for k, v in first.record.items() if k != "node"} | {"schema_version": 1}
    (out / "a" / "item.json").write_text(json.dumps(old))
    (again,) = run_batch(items, out, BatchSettings(workers=1))
    assert again.resumed
    from rigcal.batch.summary import rows

    assert rows([again])[0]["node"] is None


def test_a_pool_that_refuses_new_items_fails_them_instead_of_the_batch():
    from concurrent.futures.process import BrokenProcessPool

    from rigcal.batch.runner import Task, _result, _submitted

    def broken(task):
        raise BrokenProcessPool("A child process terminated abruptly")

    item = Item("e", "evaluate", {"trajectory": "a.tum", "gt": "b.tum"})
    ran = _result(_submitted(broken, Task(item, Path("e"), "rigcal batch", ["evaluate"])))
    assert ran["exit_code"] == 70
    assert ran["error"] == "worker failed: BrokenProcessPool: A child process terminated abruptly"


def test_items_are_submitted_a_window_at_a_time(tmp_path, monkeypatch):
    """However long the manifest, at most `window` items are in the pool or the cluster."""
    import concurrent.futures as cf
    import contextlib
    import threading

    import rigcal.batch.runner as runner

    items = [Item(f"i{k}", "evaluate", _items(tmp_path)[0].options) for k in range(25)]
    live, peak, lock = [0], [0], threading.Lock()
    pool = cf.ThreadPoolExecutor(8)

    def work(task):
        with lock:
            live[0] += 1
            peak[0] = max(peak[0], live[0])
        time.sleep(0.01)
        with lock:
            live[0] -= 1
        # what run_item returns (it is not thread-safe: it redirects this process's stdout)
        return {"exit_code": 0, "stdout": "{}", "stderr": "", "error": None, "seconds": 0.01, "host": "h"}

    @contextlib.contextmanager
    def fake(settings, address, n_items, log):
        yield (lambda task: pool.submit(work, task)), 3

    monkeypatch.setattr(runner, "_executor", fake)
    outcomes = run_batch(items, tmp_path / "o", BatchSettings(workers=1))
    pool.shutdown()
    assert [o.record["status"] for o in outcomes] == ["ok"] * 25
    assert peak[0] == 3


def _id(k: int) -> str:
    """A node ID as Ray writes one (28 bytes in hex)."""
    return f"{k:056x}"


class _Ref:
    def __init__(self, node, answer):
        self.node, self.answer = node, answer


class _FakeRay:
    """What :func:`check_nodes` uses of ``ray``: nodes, pinned tasks, wait, get, cancel.
    ``answers`` per node IP: a versions dict, an exception, or None (never answers)."""

    def __init__(self, answers):
        self.answers = answers
        self.cancelled = []
        self.nodes_ = [
            {"NodeID": _id(k), "NodeManagerAddress": ip, "Alive": True} for k, ip in enumerate(answers)
        ]
        self.nodes_.append({"NodeID": _id(99), "NodeManagerAddress": "10.0.0.99", "Alive": False})

    def nodes(self):
        return self.nodes_

    def remote(self, **options):
        fake = self

        class Task:
            def __init__(self, fn, node=None):
                self.fn, self.node = fn, node

            def options(self, scheduling_strategy):
                return Task(self.fn, scheduling_strategy.node_id)

            def remote(self):
                ip = next(n["NodeManagerAddress"] for n in fake.nodes_ if n["NodeID"] == self.node)
                return _Ref(self.node, fake.answers[ip])

        return lambda fn: Task(fn)

    def wait(self, refs, num_returns, timeout):
        return [r for r in refs if r.answer is not None], [r for r in refs if r.answer is None]

    def get(self, ref):
        if isinstance(ref.answer, Exception):
            raise ref.answer
        return ref.answer

    def cancel(self, ref):
        self.cancelled.append(ref.node)


def test_nodes_with_other_versions_get_no_items():
    from rigcal.batch.raycluster import check_nodes

    same = versions()
    old = {**same, "rigcal": "0.0.9"}
    fake = _FakeRay(
        {"10.0.0.5": same, "10.0.0.6": old, "10.0.0.7": None, "10.0.0.8": ImportError("no rigcal")}
    )
    lines: list[str] = []
    options = check_nodes(fake, parse_address("10.0.0.5:6379"), 7.0, lines.append)
    assert options == {"label_selector": {"ray.io/node-id": f"!in({_id(1)},{_id(3)})"}}
    assert fake.cancelled == [_id(2)]
    assert lines == [
        "Ray: node 10.0.0.7 did not answer the version check within 7 s; its items are checked as they run",
        f"Ray: node 10.0.0.6 runs rigcal 0.0.9 (driver: {same['rigcal']}); no items are sent there",
        "Ray: node 10.0.0.8 cannot run rigcal's version check (ImportError: no rigcal); "
        "no items are sent there",
    ]
    assert check_nodes(_FakeRay({"10.0.0.5": same}), parse_address("auto"), 7.0, lines.append) == {}


def test_a_cluster_without_a_node_of_this_rigcal_is_one_line():
    from rigcal.batch.raycluster import check_nodes

    task_error = RuntimeError("\x1b[36mray::versions()\x1b[39m (pid=1)\nAttributeError: no versions\n")
    fake = _FakeRay({"10.0.0.6": {**versions(), "rigcal": "0.0.9"}, "10.0.0.7": task_error})
    with pytest.raises(InputError) as info:
        check_nodes(fake, parse_address("ray://head:10001"), 7.0, print)
    assert str(info.value) == (
        f"--ray: got 'ray://head:10001'; expected a node running rigcal {versions()['rigcal']} on Python "
        f"{versions()['python']} (node 10.0.0.6 runs rigcal 0.0.9 (driver: {versions()['rigcal']}); "
        "node 10.0.0.7 cannot run rigcal's version check (AttributeError: no versions))"
    )


def test_rays_multiline_reasons_become_one_line():
    from rigcal.batch.raycluster import _one_line

    exc = RuntimeError(
        "Version mismatch: The cluster was started with:\n    Ray: 2.60.0\n    Python: 3.13.0\n"
        "This process on node 127.0.0.3 was started with:\n    Ray: 2.60.0\n    Python: 3.12.1\n"
    )
    assert _one_line(exc) == (
        "RuntimeError: Version mismatch: The cluster was started with: Ray: 2.60.0 Python: 3.13.0 "
        "This process on node 127.0.0.3 was started with: Ray: 2.60.0 Python: 3.12.1"
    )
    long = _one_line(ValueError("x" * 1000))
    assert len(long) == 400
    assert long.endswith("...")


class _FlakyClientRay:
    """A ``ray`` whose init fails with the given errors first, then joins."""

    def __init__(self, errors: list[Exception]):
        self.errors = list(errors)
        self.inits = 0
        self.shutdowns = 0

    def init(self, **kwargs):
        self.inits += 1
        if self.errors:
            raise self.errors.pop(0)

    def shutdown(self):
        self.shutdowns += 1

    def nodes(self):
        return [{"Alive": True, "NodeManagerAddress": "10.0.0.5"}]

    def cluster_resources(self):
        return {"CPU": 2.0}


def _join(fake, monkeypatch, text):
    from rigcal.batch import raycluster

    monkeypatch.setattr(raycluster, "import_ray", lambda: fake)
    monkeypatch.setattr(raycluster, "token_available", lambda: False)
    monkeypatch.setattr(raycluster, "CLIENT_START_WAIT_S", 0.0)
    lines: list[str] = []
    with raycluster._join_cluster(parse_address(text), lines.append) as (_, session):
        return session.description, lines


def test_a_client_server_that_failed_to_start_is_asked_once_more(monkeypatch):
    from rigcal.batch.raycluster import CLIENT_START_FAILED

    fake = _FlakyClientRay([ConnectionAbortedError(f"{CLIENT_START_FAILED}: ray_client_server exited")])
    description, lines = _join(fake, monkeypatch, "ray://head:10001")
    assert fake.inits == 2
    assert fake.shutdowns == 1
    assert description == "joined ray://head:10001: 1 nodes, 2 CPUs"
    assert len(lines) == 1
    assert lines[0].startswith("Ray: the head did not start this client's server; trying once more")


def test_a_client_server_failing_every_attempt_or_other_errors_are_one_line(monkeypatch):
    from rigcal.batch.raycluster import CLIENT_START_ATTEMPTS, CLIENT_START_FAILED

    twice = _FlakyClientRay([ConnectionAbortedError(CLIENT_START_FAILED)] * (CLIENT_START_ATTEMPTS - 1))
    _, lines = _join(twice, monkeypatch, "ray://head:10001")  # the last attempt joins
    assert twice.inits == CLIENT_START_ATTEMPTS
    assert len(lines) == CLIENT_START_ATTEMPTS - 1
    traceback = "Initialization failure from server: Traceback (most recent call last): ..."
    setup = _FlakyClientRay([ConnectionAbortedError(traceback)])
    _, lines = _join(setup, monkeypatch, "ray://head:10001")
    assert setup.inits == 2
    assert len(lines) == 1
    always = _FlakyClientRay([ConnectionAbortedError(CLIENT_START_FAILED)] * CLIENT_START_ATTEMPTS)
    with pytest.raises(InputError, match=r"^--ray: got 'ray://head:10001'; expected a Ray cluster to join"):
        _join(always, monkeypatch, "ray://head:10001")
    assert always.inits == CLIENT_START_ATTEMPTS
    other = _FlakyClientRay([ConnectionError("connection refused")])
    with pytest.raises(InputError, match="connection refused"):
        _join(other, monkeypatch, "ray://head:10001")
    assert other.inits == 1
    gcs = _FlakyClientRay([ConnectionError(CLIENT_START_FAILED)])  # the retry is Ray Client's only
    with pytest.raises(InputError):
        _join(gcs, monkeypatch, "10.0.0.5:6379")
    assert gcs.inits == 1
