"""Ray for ``rigcal batch --ray ADDRESS``: the address forms, connecting with a timeout,
and a local instance that listens on the loopback interface only (docs/batch.md).

Forms of ADDRESS:

- ``local``: start Ray on this machine for the run, on 127.0.0.1 only, with a one-run
  token and its session files in a folder of its own, removed when the run ends;
- ``auto``: join the cluster ``RAY_ADDRESS`` names, or else the one started last on this
  machine with ``ray start``;
- ``HOST:PORT``: join the cluster whose head (GCS) listens there, from one of its nodes;
- ``ray://HOST:PORT``: connect through Ray Client, from any machine.

A named address is first reached with a plain TCP connection within the connect timeout,
so an unreachable or mistyped address is one line, not a wait. Once joined, every node is
asked for its rigcal and Python versions; items are kept off a node whose versions differ
from the driver's (:func:`check_nodes`).
"""

from __future__ import annotations

import contextlib
import ipaddress
import os
import platform
import re
import secrets
import shutil
import socket
import sys
import tempfile
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from rigcal import __version__
from rigcal.errors import InputError

FORMS = "auto, local, HOST:PORT or ray://HOST:PORT"
# Ray Client's error when the head could not start the server process of this client
CLIENT_START_FAILED = "Starting Ray client server failed"
# Ray Client's error when the head failed while setting that server up (its traceback follows).
CLIENT_INIT_FAILED = "Initialization failure from server"
# Attempts at joining through Ray Client while the head fails to start this client's server,
# and the seconds waited before the next (a loaded head: CI's slow tests failed twice in a row).
CLIENT_START_ATTEMPTS = 3
CLIENT_START_WAIT_S = 2.0
LOOPBACK = "127.0.0.1"
_HOST_RE = re.compile(r"^[A-Za-z0-9]([A-Za-z0-9-]*[A-Za-z0-9])?(\.[A-Za-z0-9]([A-Za-z0-9-]*[A-Za-z0-9])?)*$")


# How long the nodes' version check waits for every node to answer (a loaded node may
# take tens of seconds to start a worker process); a node that has not answered by then
# keeps its items, each checked as it runs.
NODE_CHECK_TIMEOUT_S = 120.0


@dataclass(frozen=True)
class RayAddress:
    """A parsed ``--ray`` value: ``kind`` is local, auto, gcs (HOST:PORT) or client."""

    text: str
    kind: str
    host: str = ""
    port: int = 0

    @property
    def target(self) -> str:
        """What ``ray.init(address=...)`` is given."""
        if self.kind == "client":
            return f"ray://{_join(self.host, self.port)}"
        if self.kind == "gcs":
            return _join(self.host, self.port)
        return self.kind


def parse_address(text: str, key: str = "--ray") -> RayAddress:
    """Check a ``--ray`` value (or ``RAY_ADDRESS``) against the forms; raise
    :class:`InputError` naming ``key`` and the value otherwise."""
    if text in ("local", "auto"):
        return RayAddress(text, text)
    rest, kind = text, "gcs"
    if "://" in text:
        scheme, _, rest = text.partition("://")
        if scheme != "ray":
            raise InputError.at(None, key, text, f"{FORMS} (the only scheme is ray://)")
        kind = "client"
    host, port = _host_port(rest)
    if host is None or port is None:
        raise InputError.at(None, key, text, f"{FORMS}, PORT a number from 1 to 65535")
    return RayAddress(text, kind, host, port)


def _host_port(text: str) -> tuple[str | None, int | None]:
    if text.startswith("["):  # [IPv6]:PORT
        host, sep, port = text[1:].partition("]:")
        try:
            ipaddress.IPv6Address(host)
        except ValueError:
            return None, None
    else:
        host, sep, port = text.rpartition(":")
        if not _HOST_RE.match(host):
            return None, None
    if not sep or not port.isdigit() or not 1 <= int(port) <= 65535:
        return None, None
    return host, int(port)


def _join(host: str, port: int) -> str:
    return f"[{host}]:{port}" if ":" in host else f"{host}:{port}"


def resolve(address: RayAddress) -> RayAddress:
    """``auto`` with ``RAY_ADDRESS`` set: that address, checked as ``--ray`` would be."""
    if address.kind == "auto" and os.environ.get("RAY_ADDRESS"):
        env = os.environ["RAY_ADDRESS"]
        named = parse_address(env, "RAY_ADDRESS (from --ray auto)")
        if named.kind in ("gcs", "client"):
            return RayAddress(address.text, named.kind, named.host, named.port)
        raise InputError.at(None, "RAY_ADDRESS (from --ray auto)", env, "HOST:PORT or ray://HOST:PORT")
    return address


def probe(address: RayAddress, timeout_s: float) -> None:
    """Open and close a TCP connection to a named address within ``timeout_s``.

    Raises:
        InputError: the host does not resolve or nothing answers in time.
    """
    try:
        with socket.create_connection((address.host, address.port), timeout=timeout_s):
            pass
    except OSError as exc:
        reason = "timed out" if isinstance(exc, TimeoutError) else exc.strerror or str(exc)
        raise InputError.at(
            None,
            "--ray",
            address.text,
            f"a reachable Ray cluster (cannot connect to {_join(address.host, address.port)} "
            f"within {timeout_s:g} s: {reason})",
        ) from None


def token_available() -> bool:
    """A Ray authentication token is where Ray looks for one: ``RAY_AUTH_TOKEN``, the
    file ``RAY_AUTH_TOKEN_PATH`` names, or ``~/.ray/auth_token``."""
    if os.environ.get("RAY_AUTH_TOKEN"):
        return True
    path = os.environ.get("RAY_AUTH_TOKEN_PATH") or str(Path.home() / ".ray" / "auth_token")
    return Path(path).is_file()


@contextlib.contextmanager
def _environ(changes: dict[str, str]) -> Iterator[None]:
    """Set variables not set already; restore them after."""
    added = [k for k in changes if k not in os.environ]
    for k in added:
        os.environ[k] = changes[k]
    try:
        yield
    finally:
        for k in added:
            os.environ.pop(k, None)


def versions() -> dict[str, str]:
    """The rigcal and Python versions of this process, which every worker must share."""
    return {"rigcal": __version__, "python": platform.python_version()}


def differ(mine: dict[str, str], expect: dict[str, str]) -> str | None:
    """``rigcal 0.0.9 (driver: 0.1.0)``: the versions in ``mine`` that are not the
    driver's ``expect``, or None when all are the same."""
    parts = [f"{k} {mine.get(k)} (driver: {v})" for k, v in expect.items() if mine.get(k) != v]
    return ", ".join(parts) or None


@dataclass
class Session:
    """A connected Ray: what the batch reports about it, and the options its item tasks
    take (``label_selector`` keeping them off nodes installed differently)."""

    description: str
    temp_dir: Path | None = None
    task_options: dict[str, Any] = field(default_factory=dict)


@contextlib.contextmanager
def connect(
    address: RayAddress, cpus: int, timeout_s: float, log: Callable[[str], None]
) -> Iterator[tuple[Any, Session]]:
    """Connect to (or start) Ray for one batch; shut it down after.

    Yields:
        The ``ray`` module and the session's description.

    Raises:
        InputError: Ray is not installed, or the cluster cannot be reached or joined.
    """
    ray = sys.modules.get("ray")
    if ray is not None and ray.is_initialized():
        # the Python API inside a program that connected already: use its Ray as it is
        log("Ray: the connection this process made already")
        yield ray, Session("the connection this process made already")
        return
    address = resolve(address)
    if address.kind in ("gcs", "client"):
        probe(address, timeout_s)
    cm = _local(cpus, log) if address.kind == "local" else _join_cluster(address, log)
    with cm as (ray, session):
        log(f"Ray: {session.description}")
        try:
            if address.kind != "local":  # a local instance runs this very installation
                session.task_options = check_nodes(ray, address, NODE_CHECK_TIMEOUT_S, log)
            yield ray, session
        finally:
            ray.shutdown()


@contextlib.contextmanager
def _local(cpus: int, log: Callable[[str], None]) -> Iterator[tuple[Any, Session]]:
    """Ray on this machine, on 127.0.0.1 only. Ray puts a node on the machine's outward
    address unless told it runs single-node (``RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER=0``, read
    when ``ray`` is imported), and then binds every server to the node's address."""
    temp = Path(tempfile.mkdtemp(prefix="rigcal-ray-"))
    env = {"RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER": "0", "RAY_USAGE_STATS_ENABLED": "0"}
    if "RAY_AUTH_MODE" not in os.environ and "RAY_AUTH_TOKEN" not in os.environ:
        # a token of this run only, handed to Ray's processes in their environment
        env |= {"RAY_AUTH_MODE": "token", "RAY_AUTH_TOKEN": secrets.token_hex(32)}
    try:
        with _environ(env):
            ray = import_ray()
            _init_local(ray, cpus, temp, log)
            ips = sorted({n["NodeManagerAddress"] for n in ray.nodes() if n.get("Alive")})
            if ips != [LOOPBACK]:
                ray.shutdown()
                raise InputError.at(
                    None, "--ray", "local", f"Ray on {LOOPBACK} only (it started on {', '.join(ips)})"
                )
            n_cpus = int(ray.cluster_resources().get("CPU", 0))
            yield (
                ray,
                Session(
                    f"a local instance on {LOOPBACK} only, {n_cpus} CPUs; session files in {temp} "
                    "(removed at the end)",
                    temp,
                ),
            )
    finally:
        shutil.rmtree(temp, ignore_errors=True)
        if temp.exists():
            log(f"Ray: could not remove its session files in {temp}")


def _init_local(ray: Any, cpus: int, temp: Path, log: Callable[[str], None]) -> None:
    """``ray.init`` of a local instance, tried twice: Ray's raylet gives its agents a
    fixed 15 s to start (ray-project/ray#65983), which a loaded machine can miss."""
    for attempt in (1, 2):
        try:
            ray.init(
                num_cpus=cpus or None,
                include_dashboard=False,
                _temp_dir=str(temp),
                _node_ip_address=LOOPBACK,
                log_to_driver=False,
            )
            return
        except Exception as exc:  # Ray's own errors: no common base class
            with contextlib.suppress(Exception):
                ray.shutdown()
            first = _one_line(exc)
            if attempt == 2 or "timed out during startup" not in first:
                raise InputError.at(
                    None, "--ray", "local", f"a Ray instance started here ({first})"
                ) from None
            log(f"Ray: the local instance did not start in time; trying once more ({first})")


@contextlib.contextmanager
def _join_cluster(address: RayAddress, log: Callable[[str], None]) -> Iterator[tuple[Any, Session]]:
    """Join a running cluster. A token found where Ray looks for one turns token
    authentication on for the connection (Ray does so itself only for a cluster it
    finds on this machine, not for a named address).

    Through Ray Client the head starts a server process for each client; on a loaded head
    that start can fail ("Starting Ray client server failed", or "Initialization failure
    from server" with the head's traceback) and succeed when asked again, so those errors
    alone are tried up to :data:`CLIENT_START_ATTEMPTS` times, the
    wait before each next attempt :data:`CLIENT_START_WAIT_S` times the attempts so far."""
    env = {"RAY_AUTH_MODE": "token"} if token_available() else {}
    with _environ(env):
        ray = import_ray()
        for attempt in range(1, CLIENT_START_ATTEMPTS + 1):
            try:
                ray.init(address=address.target, log_to_driver=False)
                break
            except Exception as exc:  # ConnectionError, AuthenticationError, RuntimeError, ...
                with contextlib.suppress(Exception):
                    ray.shutdown()
                first = _one_line(exc)
                last = attempt == CLIENT_START_ATTEMPTS
                server_side = CLIENT_START_FAILED in str(exc) or CLIENT_INIT_FAILED in str(exc)
                if not last and address.kind == "client" and server_side:
                    log(f"Ray: the head did not start this client's server; trying once more ({first})")
                    time.sleep(CLIENT_START_WAIT_S * attempt)
                    continue
                hint = ""
                if "uthentication" in str(exc) or "token" in str(exc):
                    hint = "; the cluster's token: RAY_AUTH_TOKEN, RAY_AUTH_TOKEN_PATH or ~/.ray/auth_token"
                raise InputError.at(
                    None, "--ray", address.text, f"a Ray cluster to join ({first}{hint})"
                ) from None
        nodes = [n for n in ray.nodes() if n.get("Alive")]
        n_cpus = int(ray.cluster_resources().get("CPU", 0))
        where = address.target if address.kind != "auto" else "the cluster of this machine"
        yield ray, Session(f"joined {where}: {len(nodes)} nodes, {n_cpus} CPUs")


def check_nodes(
    ray: Any, address: RayAddress, timeout_s: float, log: Callable[[str], None]
) -> dict[str, Any]:
    """Ask every node of the cluster for the rigcal and Python versions its workers run
    (one task pinned to each node, using no CPU, so that a busy node answers too).

    A node whose versions differ from this process's gets one line on ``log`` and no
    items: the returned task options select the other nodes by Ray's ``ray.io/node-id``
    label. A node that has not answered within ``timeout_s`` keeps its items, each
    checked by the worker as it runs (as on a node that joins during the batch).

    Raises:
        InputError: no node of the cluster runs this process's versions.
    """
    from ray.util.scheduling_strategies import NodeAffinitySchedulingStrategy

    expect = versions()
    nodes = {n["NodeID"]: n["NodeManagerAddress"] for n in ray.nodes() if n.get("Alive")}
    task = ray.remote(num_cpus=0, max_retries=0)(versions)
    pinned = {n: NodeAffinitySchedulingStrategy(n, soft=False) for n in nodes}
    asked = {task.options(scheduling_strategy=pinned[n]).remote(): n for n in nodes}
    answered, late = ray.wait(list(asked), num_returns=len(asked), timeout=timeout_s)
    bad: dict[str, str] = {}
    for ref in answered:
        try:
            reason = differ(ray.get(ref), expect)
            reason = None if reason is None else f"runs {reason}"
        except Exception as exc:  # a node whose rigcal cannot even run the check
            reason = f"cannot run rigcal's version check ({_cause(exc)})"
        if reason is not None:
            bad[asked[ref]] = f"node {nodes[asked[ref]]} {reason}"
    for ref in late:
        ray.cancel(ref)
        log(
            f"Ray: node {nodes[asked[ref]]} did not answer the version check within {timeout_s:g} s; "
            "its items are checked as they run"
        )
    if bad and len(bad) == len(nodes):
        raise InputError.at(
            None,
            "--ray",
            address.text,
            f"a node running rigcal {expect['rigcal']} on Python {expect['python']} "
            f"({'; '.join(bad.values())})",
        )
    for line in bad.values():
        log(f"Ray: {line}; no items are sent there")
    return {"label_selector": {"ray.io/node-id": f"!in({','.join(sorted(bad))})"}} if bad else {}


def _cause(exc: BaseException) -> str:
    """A failed task's reason: the last line of its text, where Ray's task errors put the
    worker's own exception (``AttributeError: ... 'versions' on <module ...>``)."""
    lines = [line.strip() for line in _ANSI.sub("", str(exc)).splitlines() if line.strip()]
    if len(lines) > 1:
        return lines[-1]
    return f"{type(exc).__name__}: {lines[0] if lines else ''}"


_ANSI = re.compile(r"\x1b\[[0-9;]*m")


def _one_line(exc: BaseException, limit: int = 400) -> str:
    """An exception as one line: Ray's multi-line reasons (a version mismatch names the
    cluster's and this process's versions on lines of their own) joined, then shortened."""
    text = f"{type(exc).__name__}: {' '.join(str(exc).split())}"
    return text if len(text) <= limit else text[: limit - 3] + "..."


def import_ray() -> Any:
    """The ``ray`` module, or a one-line error naming the extra to install."""
    try:
        import ray
    except ImportError:
        raise InputError.at(None, "--ray", "ray", "Ray installed (pip install 'rigcal[ray]')") from None
    return ray
