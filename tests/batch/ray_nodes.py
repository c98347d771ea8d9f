"""A Ray cluster of separate node processes on this machine's loopback interface, started
the way docs/batch.md tells a user to start one (``ray get-auth-token --generate``,
``RAY_AUTH_MODE=token``, ``ray start --head``, ``ray start --address``), for the cluster
tests and benchmarks/bench_batch.py.

Everything the cluster starts carries a marker in its environment, so that stopping it
ends exactly its own processes (never ``ray stop``, which ends every Ray process of the
user on the machine), and its files live in its own folders, removed at the end.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
import uuid
from dataclasses import dataclass, field
from pathlib import Path

import yaml

from rigcal.sim.box_session import SessionSpec, generate_session, write_session

RAY = str(Path(sys.executable).with_name("ray"))
RIGCAL = str(Path(sys.executable).with_name("rigcal"))

# Loopback addresses other than 127.0.0.1: Ray replaces 127.0.0.1 and localhost by the
# machine's outward address on Linux (ray._private.services.resolve_ip_for_localhost)
# unless it runs single-node, so a multi-node loopback cluster names other addresses
# of 127.0.0.0/8.
HEAD_IP = "127.0.0.2"
NODE_IPS = ("127.0.0.3", "127.0.0.4", "127.0.0.5")
# The tests' start_nice (see LoopbackCluster.start_nice): a higher priority when allowed.
TEST_NICE = -10 if os.geteuid() == 0 else 0


def free_port(host: str = "127.0.0.1") -> int:
    with socket.socket() as s:
        s.bind((host, 0))
        return int(s.getsockname()[1])


@dataclass
class Node:
    ip: str
    temp_dir: Path
    log: Path
    pgid: int = 0


@dataclass
class LoopbackCluster:
    """A head and ``workers`` more nodes, ``cpus`` CPUs each, on loopback addresses.

    Use as a context manager; ``env`` is the environment a driver (``rigcal batch``)
    on this machine needs: the token's home, ``RAY_AUTH_MODE``, the marker.
    """

    root: Path
    workers: int = 1
    cpus: int = 1
    attempts: int = 5
    # A higher CPU priority (negative niceness, root only) for the nodes' start, back to
    # normal once they are up: Ray's raylet gives its agents a fixed 15 s to start
    # (ray-project/ray#65983), which a machine shared by many can miss every time. With
    # the kernel's autogroups (sched_autogroup_enabled), each node's session is scheduled
    # as one group against the machine's other sessions, so the group's niceness is set too.
    start_nice: int = 0
    marker: str = field(default_factory=lambda: uuid.uuid4().hex)
    nodes: list[Node] = field(default_factory=list)
    port: int = 0
    client_port: int = 0

    @property
    def address(self) -> str:
        return f"{HEAD_IP}:{self.port}"

    @property
    def client_address(self) -> str:
        return f"ray://{HEAD_IP}:{self.client_port}"

    @property
    def env(self) -> dict[str, str]:
        env = dict(os.environ)
        env.pop("RAY_ADDRESS", None)
        env |= {
            "HOME": str(self.root / "home"),
            "RAY_AUTH_MODE": "token",
            "RIGCAL_TEST_RAY_CLUSTER": self.marker,
            "RAY_USAGE_STATS_ENABLED": "0",
            # The head's Ray Client proxy waits this long for a client's own server process
            # (30 s by default), which a loaded 2-core machine can take longer to start.
            "RAY_CLIENT_SERVER_CHECK_CHANNEL_TIMEOUT_S": "120",
        }
        return env

    def driver_env(self, **extra: str) -> dict[str, str]:
        """A driver's environment as the docs set it up: the token in ~/.ray/auth_token
        (rigcal turns authentication on when it finds one), nothing else."""
        env = self.env
        env.pop("RAY_AUTH_MODE")
        return env | extra

    def __enter__(self) -> LoopbackCluster:
        try:
            self.start()
        except BaseException:
            self.stop()
            raise
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def start(self) -> None:
        (self.root / "home").mkdir(parents=True, exist_ok=True)
        # docs/batch.md, step 2: one token for the cluster, in ~/.ray/auth_token
        _run([RAY, "get-auth-token", "--generate"], self.env, timeout=120)
        self.port, self.client_port = free_port(HEAD_IP), free_port(HEAD_IP)
        self.nodes.append(
            self._start_node(
                HEAD_IP,
                [
                    "--head",
                    "--port",
                    str(self.port),
                    "--ray-client-server-port",
                    str(self.client_port),
                    "--include-dashboard",
                    "false",
                ],
            )
        )
        for k in range(self.workers):
            self.add_node(NODE_IPS[k])

    def add_node(self, ip: str, env: dict[str, str] | None = None) -> Node:
        """A node joining the head; ``env``: variables of its own (``PYTHONPATH``)."""
        node = self._start_node(ip, ["--address", self.address], env=env)
        self.nodes.append(node)
        return node

    def try_node(self, ip: str, ray: str) -> tuple[int, str]:
        """``ray start --address`` with another installation's ``ray`` (another Python),
        once: its exit code and output. A node that started is stopped again."""
        node, code = self._launch(ip, ["--address", self.address], ray, {}, "try")
        text = node.log.read_text(errors="replace")
        self._kill(node, signal.SIGKILL)
        return code, text

    def _start_node(self, ip: str, args: list[str], env: dict[str, str] | None = None) -> Node:
        """``ray start`` with its own temp folder and ports; retried because Ray's raylet
        gives its agents a fixed 15 s to start (ray-project/ray#65983), too short on a
        loaded machine."""
        for attempt in range(self.attempts):
            node, code = self._launch(ip, args, RAY, env or {}, str(attempt))
            if code == 0:
                for pid in own_processes(self.marker, ip):
                    with contextlib.suppress(OSError):
                        os.setpriority(os.PRIO_PROCESS, pid, 0)
                        _autogroup_nice(pid, 0)
                return node
            self._kill(node, signal.SIGKILL)
        raise RuntimeError(f"ray start {' '.join(args)} failed {self.attempts} times; see {node.log}")

    def _launch(self, ip: str, args: list[str], ray: str, env: dict[str, str], tag: str) -> tuple[Node, int]:
        """One ``ray start``, its output in ``root/node-IP-TAG.log``; its exit code (-1
        when it has not returned in 240 s)."""
        node = Node(ip, Path(tempfile.mkdtemp(prefix="rgr")), self.root / f"node-{ip}-{tag}.log")
        ports = {
            "--node-manager-port": free_port(ip),
            "--object-manager-port": free_port(ip),
            "--dashboard-agent-listen-port": free_port(ip),
            "--dashboard-agent-grpc-port": free_port(ip),
            "--runtime-env-agent-port": free_port(ip),
            "--metrics-export-port": free_port(ip),
        }
        prefix = ["nice", "-n", str(self.start_nice)] if self.start_nice else []
        cmd = [*prefix, ray, "start", *args, "--node-ip-address", ip, "--num-cpus", str(self.cpus)]
        # no log monitor: one Python process fewer competing with the agents' start
        cmd += [
            "--temp-dir",
            str(node.temp_dir),
            "--disable-usage-stats",
            "--include-log-monitor",
            "false",
        ]
        for flag, port in ports.items():
            cmd += [flag, str(port)]
        with open(node.log, "w") as log:
            proc = subprocess.Popen(
                cmd,
                env=self.env | env | {"RIGCAL_TEST_RAY_NODE": ip},
                stdout=log,
                stderr=subprocess.STDOUT,
                start_new_session=True,
            )
            node.pgid = proc.pid
            if self.start_nice:
                _autogroup_nice(proc.pid, self.start_nice)
            try:
                code = proc.wait(timeout=240)
            except subprocess.TimeoutExpired:
                code = -1
        return node, code

    def kill_node(self, node: Node) -> None:
        """End one node at once (SIGKILL), as a machine that dies."""
        self._kill(node, sig=signal.SIGKILL)
        self.nodes.remove(node)

    def _kill(self, node: Node, sig: int = signal.SIGTERM) -> None:
        with contextlib.suppress(ProcessLookupError, PermissionError):
            os.killpg(node.pgid, sig)
        for pid in own_processes(self.marker, node.ip):
            _signal(pid, sig)
        shutil.rmtree(node.temp_dir, ignore_errors=True)

    def stop(self) -> None:
        """End every process the cluster started (its node process groups, then any
        process still carrying the marker) and remove its temp folders."""
        for node in reversed(self.nodes):
            with contextlib.suppress(ProcessLookupError, PermissionError):
                os.killpg(node.pgid, signal.SIGTERM)
        deadline = time.monotonic() + 20
        while own_processes(self.marker) and time.monotonic() < deadline:
            time.sleep(0.5)
        for pid in own_processes(self.marker):
            _signal(pid, signal.SIGKILL)
        for node in self.nodes:
            shutil.rmtree(node.temp_dir, ignore_errors=True)
        self.nodes.clear()


def _autogroup_nice(pid: int, nice: int) -> None:
    """The niceness of the scheduler autogroup (the session) of ``pid``, where the kernel
    has autogroups and allows it."""
    with contextlib.suppress(OSError):
        Path(f"/proc/{pid}/autogroup").write_text(f"{nice}\n")


def own_processes(marker: str, node_ip: str | None = None) -> list[int]:
    """Processes whose environment carries ``RIGCAL_TEST_RAY_CLUSTER=marker`` (and
    ``RIGCAL_TEST_RAY_NODE=node_ip`` when given)."""
    needles = [f"RIGCAL_TEST_RAY_CLUSTER={marker}".encode()]
    if node_ip is not None:
        needles.append(f"RIGCAL_TEST_RAY_NODE={node_ip}".encode())
    out = []
    for d in os.listdir("/proc"):
        if not d.isdigit() or int(d) == os.getpid():
            continue
        try:
            with open(f"/proc/{d}/environ", "rb") as f:
                env = f.read().split(b"\0")
                if all(n in env for n in needles):
                    out.append(int(d))
        except OSError:
            continue
    return out


def running_items(marker: str, node_ip: str | None = None) -> int:
    """How many Ray workers of the cluster (of one node when given) run an item now (a
    worker's process title names its task)."""
    count = 0
    for pid in own_processes(marker, node_ip):
        try:
            with open(f"/proc/{pid}/cmdline", "rb") as f:
                count += f.read().startswith(b"ray::run_item")
        except OSError:
            continue
    return count


def _signal(pid: int, sig: int) -> None:
    with contextlib.suppress(ProcessLookupError, PermissionError):
        os.kill(pid, sig)


def _run(cmd: list[str], env: dict[str, str], timeout: float) -> str:
    done = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=timeout, check=False)
    if done.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed: {done.stderr[-2000:]}")
    return done.stdout


def listening_sockets(pids: list[int]) -> list[tuple[str, str, int]]:
    """The TCP sockets in LISTEN state and the bound UDP sockets that ``pids`` hold, as
    (protocol, address, pid), read from /proc/PID/fd and /proc/net/{tcp,tcp6,udp,udp6}."""
    inodes: dict[str, int] = {}
    for pid in pids:
        try:
            fds = os.listdir(f"/proc/{pid}/fd")
        except OSError:
            continue
        for fd in fds:
            try:
                link = os.readlink(f"/proc/{pid}/fd/{fd}")
            except OSError:
                continue
            if link.startswith("socket:["):
                inodes[link[8:-1]] = pid
    out = []
    for proto in ("tcp", "tcp6", "udp", "udp6"):
        with open(f"/proc/net/{proto}") as f:
            next(f)
            for line in f:
                cols = line.split()
                local, state, inode = cols[1], cols[3], cols[9]
                if inode in inodes and (state == "0A" or proto.startswith("udp")):
                    out.append((proto, _address(local), inodes[inode]))
    return out


def _address(hex_addr: str) -> str:
    """``0100007F:1F90`` -> ``127.0.0.1:8080``; IPv6 as 8 groups (v4-mapped as IPv4)."""
    host, port = hex_addr.split(":")
    raw = bytes.fromhex(host)
    if len(raw) == 4:
        ip = socket.inet_ntop(socket.AF_INET, raw[::-1])
    else:
        words = b"".join(raw[i : i + 4][::-1] for i in range(0, 16, 4))
        ip = socket.inet_ntop(socket.AF_INET6, words)
        if ip.startswith("::ffff:") and "." in ip:
            ip = ip.removeprefix("::ffff:")
    return f"{ip}:{int(port, 16)}"


def descendants(root: int) -> list[int]:
    """``root`` and every process below it."""
    children: dict[int, list[int]] = {}
    for d in os.listdir("/proc"):
        if not d.isdigit():
            continue
        try:
            with open(f"/proc/{d}/stat") as f:
                ppid = int(f.read().rsplit(")", 1)[1].split()[1])
        except (OSError, IndexError, ValueError):
            continue
        children.setdefault(ppid, []).append(int(d))
    out, todo = [], [root]
    while todo:
        pid = todo.pop()
        out.append(pid)
        todo += children.get(pid, [])
    return out


def solve_manifest(base: Path, n_items: int, seed: int) -> Path:
    """``base/solves.yaml``: ``n_items`` solves of simulated sessions (a few seconds each)."""
    items = []
    for k in range(n_items):
        write_session(generate_session(SessionSpec(n_captures=10, seed=seed + k)), base / f"s{k}", False)
        items.append({"name": f"s{k}", "picks": f"s{k}/picks.yaml"})
    doc = {"schema_version": 1, "command": "solve", "defaults": {"seed": 3}, "items": items}
    (base / "solves.yaml").write_text(yaml.safe_dump(doc))
    return base / "solves.yaml"


def batch(
    manifest: Path, out: Path, *args: str, env: dict[str, str] | None = None, timeout: float = 900
) -> subprocess.CompletedProcess[str]:
    """``rigcal batch MANIFEST -o OUT ARGS...``, its output captured."""
    return subprocess.run(
        [RIGCAL, "batch", str(manifest), "-o", str(out), *args],
        capture_output=True,
        text=True,
        env=env,
        timeout=timeout,
        check=False,
    )


def item_nodes(out: Path) -> dict[str, str | None]:
    """Per item of a batch's summary: the Ray node that ran it."""
    return {r["name"]: r["node"] for r in json.loads((out / "summary.json").read_text())["items"]}
