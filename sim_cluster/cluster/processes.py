"""The operating-system side of a cluster: free loopback ports, one ``edge_node run`` process
started in its own session, whether a process runs, and ending processes (SIGTERM, then SIGKILL).
"""
from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time

TERM_GRACE_S = 5.0
KILL_WAIT_S = 2.0  # after SIGKILL, how long terminate waits for the processes to be gone


def free_ports(n: int) -> list[int]:
    """``n`` distinct free TCP ports on 127.0.0.1 (held open together so they differ)."""
    socks = []
    try:
        for _ in range(n):
            s = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
            s.bind(("127.0.0.1", 0))
            socks.append(s)
        return [s.getsockname()[1] for s in socks]
    finally:
        for s in socks:
            s.close()


def alive(pid: int | None) -> bool:
    """Whether ``pid`` is a running (not zombie) process."""
    if not pid:
        return False
    try:
        os.kill(pid, 0)
    except (ProcessLookupError, PermissionError):
        return False
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().split(")")[-1].split()[0] != "Z"
    except OSError:
        return True


def spawn(config: str, log: str, join: bool = False) -> subprocess.Popen:
    """Start one ``edge_node run --config config`` in its own session, output appended to ``log``
    (Ctrl-C on the launcher's terminal reaches the launcher, which ends its nodes in order).
    ``join``: a restart into a running network."""
    out = open(log, "ab")
    try:
        return subprocess.Popen([sys.executable, "-m", "edge_node.cli", "run", "--config", config,
                                 *(["--join"] if join else [])],
                                stdout=out, stderr=subprocess.STDOUT,
                                stdin=subprocess.DEVNULL, start_new_session=True)
    finally:
        out.close()


def _signal(pids: list[int], sig: int) -> None:
    for pid in pids:
        if alive(pid):
            try:
                os.kill(pid, sig)
            except ProcessLookupError:
                pass


def _wait_gone(pids: list[int], seconds: float) -> None:
    deadline = time.time() + seconds
    while time.time() < deadline and any(alive(p) for p in pids):
        time.sleep(0.02)


def terminate(pids: list[int], grace: float = TERM_GRACE_S) -> None:
    """SIGTERM (a node finishes its frame and flushes), then SIGKILL whatever is left, and
    wait for that to be gone too (a killed process takes a moment)."""
    _signal(pids, signal.SIGTERM)
    _wait_gone(pids, grace)
    _signal(pids, signal.SIGKILL)
    _wait_gone(pids, KILL_WAIT_S)
