"""Helpers for tests that talk over loopback: free ports, endpoints, polling."""
from __future__ import annotations

import socket
import time
from pathlib import Path


_HANDED_OUT: set[int] = set()


def free_port() -> int:
    """A free TCP port on 127.0.0.1, never one this session handed out before: a test takes its
    ports one call at a time and binds them only later (a node listens once it has started), so
    the kernel could otherwise give the same still-unbound port to two calls."""
    for _ in range(1000):
        with socket.socket() as s:
            s.bind(("127.0.0.1", 0))
            port = s.getsockname()[1]
        if port not in _HANDED_OUT:
            _HANDED_OUT.add(port)
            return port
    raise RuntimeError("no free loopback port left that this session has not handed out")


def ep(port: int, proto: str = "tcp") -> str:
    return f"{proto}/127.0.0.1:{port}"


def wait_for(pred, timeout: float = 10.0, every: float = 0.01) -> bool:
    """Poll ``pred`` until it holds or ``timeout`` s pass; its last value."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if pred():
            return True
        time.sleep(every)
    return pred()


def export_scenario(directory: Path, frames: int, scenario: str = "terrace-sim") -> Path:
    """A det-files export of ``scenario`` (what file-source nodes play back)."""
    from sim_cluster.scenarios.detfiles import export_detections
    from sim_cluster.scenarios.loader import load_scenario

    export_detections(load_scenario(scenario, frames=frames), directory)
    return directory
