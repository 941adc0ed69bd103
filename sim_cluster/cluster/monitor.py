"""A passive Zenoh subscriber on every link of a network: what actually crossed the wire.

It opens its own peer session subscribed to ``dmtt/<net>/link/**`` (``protocol.keys``), counts
payload bytes and messages per link and keeps each message's frame and ``sent_at`` (decoded
after the run). It never publishes and declares no liveliness token, so the nodes behave as
without it (one extra TCP connection each). Why it must listen before the nodes start, and
connect to them as they come up: ``sim_cluster/experiments/bench_cluster.py``.
"""
from __future__ import annotations

import threading
import time
from dataclasses import dataclass, field

import zenoh

from edge_node.runtime.transport import zenoh_config
from protocol import codec
from protocol.errors import ProtocolError
from protocol.keys import all_links_key, parse_link_key


@dataclass
class LinkTally:
    bytes: int = 0
    messages: int = 0
    frames: dict[int, float] = field(default_factory=dict)  # frame -> sender's sent_at
    latency_s: list[float] = field(default_factory=list)  # receipt here minus sent_at
    last_recv: float = 0.0
    undecodable: int = 0


class LinkMonitor:
    """A Zenoh peer session that only listens: counts bytes and messages on every link key of
    ``network`` and keeps each message's frame and ``sent_at`` (decoded after the run)."""

    def __init__(self, network: str, listen: str, connect: list[str]):
        conf = zenoh_config([listen], connect)
        # retry the nodes' endpoints quickly: they are not listening yet when we open
        conf.insert_json5("connect/retry", '{"period_init_ms": 20, "period_max_ms": 100, '
                                           '"period_increase_factor": 1.5}')
        self.network = network
        self._raw: list[tuple[str, bytes, float]] = []
        self._lock = threading.Lock()
        self.session = zenoh.open(conf)
        self._sub = self.session.declare_subscriber(all_links_key(network), self._on_sample)

    def _on_sample(self, sample) -> None:
        now = time.time()
        payload = sample.payload.to_bytes()
        with self._lock:
            self._raw.append((str(sample.key_expr), payload, now))

    def count(self) -> int:
        with self._lock:
            return len(self._raw)

    def close(self) -> None:
        for obj in (self._sub, self.session):
            try:
                obj.undeclare() if obj is self._sub else obj.close()
            except Exception:  # noqa: BLE001 - best effort on the way out
                pass

    def tallies(self) -> dict[str, LinkTally]:
        """Per link ``"src->dst"``: bytes, messages, frames and latencies seen."""
        with self._lock:
            raw = list(self._raw)
        out: dict[str, LinkTally] = {}
        for key, payload, t in raw:
            try:
                _, src, dst = parse_link_key(key)
            except ProtocolError:
                continue
            tl = out.setdefault(f"{src}->{dst}", LinkTally())
            tl.bytes += len(payload)
            tl.messages += 1
            tl.last_recv = max(tl.last_recv, t)
            try:
                msg = codec.decode(payload, expect_network=self.network, expect_sender=src)
            except ProtocolError:
                tl.undecodable += 1
                continue
            tl.frames[msg.frame] = msg.sent_at
            if msg.sent_at > 0:
                tl.latency_s.append(t - msg.sent_at)
        return out
