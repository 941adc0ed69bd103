"""What the probes and the soak do to a running cluster besides signals: fill its disk, flood a
node with one message of phantoms, read a process's resident memory
(``sim_cluster/experiments/probe.py``, ``soak.py``)."""
from __future__ import annotations

import os
import time
import uuid
from pathlib import Path

import numpy as np
import zenoh

from edge_node.runtime.transport import zenoh_config
from protocol.messages import FrameMessage, TrackerInfo


def rss_kb(pid: int | None) -> int | None:
    """Resident set size of a process (kB), from /proc; ``None`` when it is gone."""
    try:
        with open(f"/proc/{pid}/status") as f:
            for line in f:
                if line.startswith("VmRSS:"):
                    return int(line.split()[1])
    except (OSError, TypeError, ValueError):
        return None
    return None


def fill(where: Path) -> Path:
    """A file that takes every free byte of ``where``'s file system."""
    filler = where / f".filler-{uuid.uuid4().hex}"
    fd = os.open(filler, os.O_WRONLY | os.O_CREAT)
    try:
        for block in (1 << 20, 4096, 1):  # large writes first: a 1 GiB tmpfs fills in a blink
            try:
                while True:
                    os.write(fd, b"\0" * block)
            except OSError:
                pass
    finally:
        os.close(fd)
    return filler


PHANTOM_COUNTER = 10**8  # the phantoms' ids: (sender, PHANTOM_COUNTER + i), beyond any honest counter


def phantom_message(network: str, sender: int, frame: int, n: int, seed: int = 0) -> FrameMessage:
    """``n`` plausible trackers under fresh ids of ``sender``'s camera, born now, ell 0: what
    the screen cannot tell from a camera that sees that many people."""
    rng = np.random.default_rng(seed)
    infos = tuple(TrackerInfo((sender, PHANTOM_COUNTER + i),  # on the terrace, walking (metres)
                              np.array([rng.uniform(0, 10), rng.uniform(0, 10), 0.5, 1.7,
                                        rng.uniform(-1, 1), rng.uniform(-1, 1)]),
                              np.zeros(6), np.zeros((6, 6)), 0, born=frame)
                  for i in range(n))
    return FrameMessage(network, sender, frame, infos, sent_at=time.time())


def publish_once(network: str, connect: list[str], key: str, payload: bytes) -> None:
    """Open a Zenoh session to ``connect``, put ``payload`` on ``key`` once, close."""
    s = zenoh.open(zenoh_config([], connect))
    try:
        deadline = time.monotonic() + 5.0
        while not list(s.info.peers_zid()) and time.monotonic() < deadline:
            time.sleep(0.02)
        pub = s.declare_publisher(key, congestion_control=zenoh.CongestionControl.BLOCK)
        time.sleep(0.3)  # the subscriber's declaration reaches us
        pub.put(payload)
        time.sleep(0.3)
        pub.undeclare()
    finally:
        s.close()
