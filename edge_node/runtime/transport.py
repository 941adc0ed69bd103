"""Zenoh transport of one camera node: per-link publishers, one inbox subscriber, liveliness.

Key expressions (protocol/keys.py): the node publishes frame messages on
``dmtt/<net>/link/<node>/<dst>`` for every neighbour ``dst`` and subscribes to
``dmtt/<net>/link/*/<node>``; its liveliness token is ``dmtt/<net>/alive/<node>`` and it watches
``dmtt/<net>/alive/*`` to know which neighbours are up.

Received bytes are validated by ``protocol.decode`` against the key they arrived on (network,
link source = payload sender, sender among the configured neighbours). A bad message is counted by
``ProtocolError.reason`` and logged (rate-limited), never raised: nothing a peer sends can stop
the node. Valid messages go into the node's inbox (``edge_node/runtime/inbox.py``: frame ``k``
for sync mode, whatever arrived for async mode, and where each neighbour is however far ahead:
``network_frame``).

Zenoh is peer-to-peer with explicit endpoints: multicast scouting off, gossip off unless asked,
``scouting/delay`` 0 (else ``open`` waits 500 ms when a neighbour is not listening yet). Peers do
not forward for each other, so every logical link must also be a Zenoh connection (configure
``connect`` on both sides of a link: reconnection after a restart is then fast).

Zenoh's shared-memory transport is off unless asked (``shared_memory``). Zenoh 1.x turns it on
by default between processes on one host, and a receiver keeps every sender's 16 MB pool and
1.25 MB metadata segment mapped (and locked) for its own lifetime, one pair per sending process
*generation* (eclipse-zenoh/zenoh#2787): each restart of a neighbour on the same host then
raised the survivor's resident memory by ~17 MB for good. Camera boxes are one per host, where
it never applied anyway.
"""
from __future__ import annotations

import json
import logging
import threading
import time
from collections import defaultdict
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import zenoh

from protocol import codec
from protocol.errors import DmttError, ProtocolError
from protocol.keys import (alive_key, alive_pattern, inbox_key, link_key, parse_alive_key,
                           parse_link_key, peers_key, peers_pattern)
from edge_node.runtime.inbox import FrameInbox
from protocol.messages import FrameMessage

log = logging.getLogger("edge_node.transport")

LATENCY_SAMPLES = 200_000  # newest one-hop latency samples kept for the summary


ID_SETTLE_S = 0.5  # how long a starting node listens for its own id before it takes it
ID_MISSES = 3  # ... and in how many polls in a row nobody may say the id is alive
ID_QUERY_TIMEOUT_S = 1.0  # a poll's wait for replies (returns as soon as every peer replied)


class LatencyRing:
    """The newest ``size`` samples in an array allocated (and touched) at start: a node's memory
    does not creep up over its first hours as a growing buffer would."""

    def __init__(self, size: int):
        self._a = np.full(size, np.nan)
        self._next = 0
        self._full = False

    def append(self, v: float) -> None:
        self._a[self._next] = v
        self._next += 1
        if self._next == len(self._a):
            self._next, self._full = 0, True

    def values(self) -> np.ndarray:
        return self._a.copy() if self._full else self._a[:self._next].copy()


class StartupError(DmttError, RuntimeError):
    """The start-up barrier timed out; ``missing`` are the neighbours that were not ready."""

    def __init__(self, node: int, missing: dict[int, list[str]], timeout: float,
                 interrupted: bool = False):
        self.node = node
        self.missing = sorted(missing)
        self.reasons = missing
        self.timeout = timeout
        self.interrupted = interrupted
        what = "; ".join(f"{n}: {', '.join(r)}" for n, r in sorted(missing.items()))
        head = "interrupted while waiting for" if interrupted else "timed out after " \
            f"{timeout:g} s waiting for"
        super().__init__(f"node {node}: {head} neighbour(s) "
                         f"{', '.join(map(str, self.missing))} ({what})")


class TransportError(DmttError, RuntimeError):
    """The Zenoh session or one of its declarations could not be set up."""


class DuplicateNodeError(TransportError):
    """This node's id is already alive on the network (another process holds it)."""


class RateLimitedLog:
    """At most one log line per key every ``interval`` seconds; suppressed lines are counted."""

    def __init__(self, logger: logging.Logger, interval: float = 5.0):
        self.logger = logger
        self.interval = interval
        self._last: dict[str, float] = {}
        self._suppressed: dict[str, int] = defaultdict(int)
        self._lock = threading.Lock()

    def warning(self, key: str, msg: str) -> None:
        now = time.monotonic()
        with self._lock:
            if now - self._last.get(key, -float("inf")) < self.interval:
                self._suppressed[key] += 1
                return
            self._last[key] = now
            n = self._suppressed.pop(key, 0)
        self.logger.warning("%s%s", msg, f" ({n} similar suppressed)" if n else "")


def zenoh_config(listen: Sequence[str] = (), connect: Sequence[str] = (), scouting: bool = False,
                 config_file: str | Path | None = None, *, gossip: bool = False,
                 lease_ms: int | None = None, shared_memory: bool = False):
    """A peer-mode ``zenoh.Config``: from ``config_file`` when given, then our settings on top
    (``listen``/``connect`` replace the file's when non-empty, or always without a file;
    ``shared_memory`` always: see the module docstring)."""
    try:
        conf = zenoh.Config.from_file(str(config_file)) if config_file else zenoh.Config()
        conf.insert_json5("mode", '"peer"')
        if listen or not config_file:
            conf.insert_json5("listen/endpoints", json.dumps(list(listen)))
        if connect or not config_file:
            conf.insert_json5("connect/endpoints", json.dumps(list(connect)))
        conf.insert_json5("scouting/multicast/enabled", json.dumps(bool(scouting)))
        conf.insert_json5("scouting/gossip/enabled", json.dumps(bool(gossip)))
        conf.insert_json5("scouting/delay", "0")
        conf.insert_json5("transport/shared_memory/enabled", json.dumps(bool(shared_memory)))
        if lease_ms is not None:
            conf.insert_json5("transport/link/tx/lease", json.dumps(int(lease_ms)))
    except zenoh.ZError as e:
        raise TransportError(f"bad Zenoh configuration: {str(e).split(' at /')[0]}") from None
    return conf


class ZenohTransport:
    """One node's Zenoh session (see the module docstring). Use as a context manager."""

    def __init__(self, network: str, node: int, neighbours: Iterable[int],
                 listen: Sequence[str] = (), connect: Sequence[str] = (), scouting: bool = False,
                 config_file: str | Path | None = None, *, gossip: bool = False,
                 lease_ms: int | None = None, max_pending_frames: int = 256,
                 id_wait_s: float | None = None, shared_memory: bool = False):
        self.network = network
        self.node = int(node)
        self.neighbours = tuple(sorted(set(int(n) for n in neighbours) - {self.node}))
        self._neigh = frozenset(self.neighbours)
        self.max_pending_frames = max_pending_frames
        self.limits = codec.DEFAULT_LIMITS  # what a received message may be (protocol.codec)
        self._cond = threading.Condition()
        self._closed = False
        self._rlog = RateLimitedLog(log)
        self.inbox = FrameInbox(self.node, self.neighbours, max_pending_frames, cond=self._cond,
                                warn=self._rlog.warning)
        self._alive_any: set[int] = set()  # every alive node seen (direct connections only)
        self._self_seen = False  # start-up: our own id's token seen from another process
        self.running_at_start: dict[int, int] = {}  # neighbours already running when we came
        # counters
        self.bytes_sent: dict[int, int] = defaultdict(int)
        self.messages_sent: dict[int, int] = defaultdict(int)
        self.publish_calls = 0
        self.receive_cpu_s = 0.0  # Zenoh callback threads: time.thread_time spent in _on_sample
        self.bytes_received: dict[int, int] = defaultdict(int)
        self.messages_received: dict[int, int] = defaultdict(int)
        self.rejected: dict[str, int] = defaultdict(int)
        self.liveliness_events: list[tuple[float, int, str]] = []
        self._latency = LatencyRing(LATENCY_SAMPLES)

        conf = zenoh_config(listen, connect, scouting, config_file, gossip=gossip,
                            lease_ms=lease_ms, shared_memory=shared_memory)
        try:
            self.session = zenoh.open(conf)
        except zenoh.ZError as e:
            raise TransportError(f"node {node}: cannot open the Zenoh session: "
                                 f"{str(e).split(' at /')[0]}") from None
        self._pubs: dict[int, Any] = {}
        self._sub = self._alive_sub = self._token = self._peers_q = None
        try:
            # receive first, announce last: once our token is visible we can take messages
            self._sub = self.session.declare_subscriber(inbox_key(network, self.node),
                                                        self._on_sample)
            self._alive_sub = self.session.liveliness().declare_subscriber(
                alive_pattern(network), self._on_alive, history=True)
            for dst in self.neighbours:
                self._pubs[dst] = self.session.declare_publisher(
                    link_key(network, self.node, dst),
                    congestion_control=zenoh.CongestionControl.BLOCK)
            self._peers_q = self.session.declare_queryable(peers_key(network, self.node),
                                                           self._on_peers_query)
            wait = (lease_ms or 10_000) / 1000.0 + 0.5 if id_wait_s is None else id_wait_s
            t0 = time.monotonic()  # one settle window for connecting and listening
            self._await_peers(len(connect), ID_SETTLE_S)
            holders = self._id_holders(wait, since=t0)
            if holders:
                self.close()
                raise DuplicateNodeError(
                    f"node {node}: id {node} is already alive on network {network!r} (seen by "
                    f"{holders}); every camera needs its own node id (docs/deploy.md, 'Setting up the "
                    f"boxes')")
            self._token = self.session.liveliness().declare_token(alive_key(network, self.node))
        except zenoh.ZError as e:
            self.close()
            raise TransportError(f"node {node}: Zenoh declaration failed: "
                                 f"{str(e).split(' at /')[0]}") from None

    # -- one identity per node id -----------------------------------------------------------------
    def _await_peers(self, n: int, timeout: float) -> None:
        """Wait up to ``timeout`` s until ``n`` peers are connected (the ``connect`` endpoints;
        with multicast scouting, whatever is found meanwhile): ``open`` returns before the
        connections are made, and the id check must reach the network."""
        deadline = time.monotonic() + timeout
        while n and time.monotonic() < deadline:
            if len(list(self.session.info.peers_zid())) >= n:
                return
            time.sleep(0.02)

    def _id_holders(self, wait_s: float, settle_s: float = ID_SETTLE_S,
                    since: float | None = None) -> list[str]:
        """Who says this node's id is alive: its own token (the liveliness subscriber and a
        liveliness query), or a connected peer that sees it (peers do not forward tokens, so
        the neighbours are asked through their ``peers`` queryable). Declarations arrive a
        moment after the connections: nobody is trusted to be absent before ``settle_s``. A
        previous life of this node (killed, restarting) vanishes within the lease: wait up to
        ``wait_s`` for that before concluding the id is taken."""
        start = time.monotonic() if since is None else since
        absent_since, misses = start, 0  # nobody seen since, in so many polls in a row
        while True:
            holders = ["its token"] if self._self_seen else []
            for r in self.session.liveliness().get(alive_key(self.network, self.node),
                                                   timeout=ID_QUERY_TIMEOUT_S):
                if r.ok is not None:
                    holders.append("its token")
            for r in self.session.get(peers_pattern(self.network), timeout=ID_QUERY_TIMEOUT_S):
                if r.ok is None:
                    continue
                try:
                    seen = json.loads(r.ok.payload.to_bytes())
                    if isinstance(seen, dict) and self.node in seen.get("alive", []):
                        holders.append(f"node {int(seen['node'])}")
                    frame, peer = seen.get("frame"), int(seen["node"])
                    if isinstance(frame, int) and frame > 0 and peer in self._neigh:
                        self.running_at_start[peer] = frame
                except (ValueError, TypeError, KeyError, AttributeError):
                    continue
            now = time.monotonic()
            if holders:
                absent_since, misses = None, 0
                if now - start >= wait_s:
                    return sorted(set(holders))
            else:
                # a holder is gone only when no poll has seen it for settle_s, in several polls:
                # one reply late under load is not a vanished holder (one empty poll after
                # seeing the holder let half of the duplicates of a busy cluster's node in)
                absent_since = now if absent_since is None else absent_since
                misses += 1
                if now - start >= settle_s and now - absent_since >= settle_s and misses >= ID_MISSES:
                    return []
            time.sleep(0.05)

    def _on_peers_query(self, query) -> None:
        try:
            with self._cond:
                alive = sorted(self._alive_any)
            query.reply(query.key_expr, json.dumps({"node": self.node, "alive": alive,
                                                    "frame": self.inbox.frame_now}))
        except Exception as e:  # noqa: BLE001 - a callback must never raise into Zenoh
            self._rlog.warning("peers", f"node {self.node}: peers query failed: {e}")

    # -- callbacks (Zenoh threads): never raise ------------------------------------------------
    def _reject(self, reason: str, detail: str) -> None:
        with self._cond:
            self.rejected[reason] += 1
        self._rlog.warning(f"reject:{reason}", f"node {self.node}: rejected a message "
                           f"({reason}): {detail[:200]}")

    def _on_sample(self, sample) -> None:
        c0 = time.thread_time()
        try:
            self._receive(sample)
        finally:
            spent = time.thread_time() - c0  # this callback thread's CPU for the message
            with self._cond:
                self.receive_cpu_s += spent

    def _receive(self, sample) -> None:
        try:
            now = time.time()
            key = str(sample.key_expr)
            try:
                net, src, dst = parse_link_key(key)
            except ProtocolError as e:
                self._reject(e.reason, str(e))
                return
            if net != self.network or dst != self.node:
                self._reject("key", f"message on foreign key {key[:120]!r}")
                return
            size = len(sample.payload)
            if size > self.limits.max_bytes:  # before copying or parsing a single byte
                self._reject("oversize", f"on {key}: {size} bytes > {self.limits.max_bytes}")
                return
            payload = sample.payload.to_bytes()
            try:
                msg = codec.decode(payload, limits=self.limits, expect_network=self.network,
                                   expect_sender=src, allowed_senders=self._neigh)
            except ProtocolError as e:
                self._reject(e.reason, f"on {key}: {e}")
                return
            self._accept(src, msg, len(payload), now)
        except Exception as e:  # noqa: BLE001 - a callback must never raise into Zenoh
            self._reject("internal", f"{type(e).__name__}: {e}")

    def _accept(self, src: int, msg: FrameMessage, nbytes: int, now: float) -> None:
        with self._cond:
            if self._closed:
                return
            self.messages_received[src] += 1
            self.bytes_received[src] += nbytes
            if msg.sent_at > 0:
                self._latency.append(now - msg.sent_at)
        self.inbox.accept(src, msg)

    def _on_alive(self, sample) -> None:
        try:
            try:
                net, n = parse_alive_key(sample.key_expr)
            except ProtocolError:
                return
            gone = sample.kind == zenoh.SampleKind.DELETE
            if net == self.network and n == self.node and self._token is None:
                self._self_seen = not gone  # another process holds our id (start-up check)
            if net != self.network or n == self.node:
                return
            with self._cond:
                if gone:
                    self._alive_any.discard(n)
                else:
                    self._alive_any.add(n)
                self.liveliness_events.append((time.time(), n, "gone" if gone else "alive"))
                del self.liveliness_events[:-1000]
                self.inbox.liveliness(n, gone)
            if n in self._neigh:
                log.info("node %d: neighbour %d %s", self.node, n, "gone" if gone else "alive")
        except Exception as e:  # noqa: BLE001
            self._rlog.warning("alive", f"node {self.node}: liveliness callback failed: {e}")

    # -- the node's side -------------------------------------------------------------------------
    def publish(self, payload: bytes) -> int:
        """Put ``payload`` on every outgoing link; returns the bytes handed to Zenoh."""
        total = 0
        for dst, pub in self._pubs.items():
            pub.put(payload)
            self.bytes_sent[dst] += len(payload)
            self.messages_sent[dst] += 1
            total += len(payload)
        self.publish_calls += 1
        return total

    def publish_to(self, dst: int, payload: bytes) -> int:
        """Put ``payload`` on the link to neighbour ``dst`` only (per-link resync, faults)."""
        self._pubs[dst].put(payload)
        self.bytes_sent[dst] += len(payload)
        self.messages_sent[dst] += 1
        return len(payload)

    def wait_first_frame(self, timeout: float, stop: threading.Event | None = None) -> int | None:
        """The newest frame any neighbour has sent us (``FrameInbox.wait_first_frame``)."""
        return self.inbox.wait_first_frame(timeout, stop)

    def alive_neighbours(self) -> set[int]:
        with self._cond:
            return set(self.inbox.alive)

    def alive_nodes(self) -> set[int]:
        """Every other node whose token is visible (with gossip off: directly connected ones)."""
        with self._cond:
            return set(self._alive_any)

    def not_ready(self) -> dict[int, list[str]]:
        """Neighbours that are not alive or have no subscriber matching our link to them."""
        with self._cond:
            alive = set(self.inbox.alive)
        out: dict[int, list[str]] = {}
        for n in self.neighbours:
            why = []
            if n not in alive:
                why.append("no liveliness token")
            if not self._pubs[n].matching_status.matching:
                why.append(f"no subscriber on {link_key(self.network, self.node, n)}")
            if why:
                out[n] = why
        return out

    def wait_ready(self, timeout: float, stop: threading.Event | None = None,
                   partial: bool = False) -> float:
        """Block until every neighbour is alive and subscribed to our link to it; returns the
        seconds waited. On timeout raises :class:`StartupError` naming the missing ones, or
        with ``partial`` returns anyway: the node starts with the neighbours that are there, and
        a late one joins as a restarted node does (also raised when ``stop`` is set)."""
        t0 = time.monotonic()
        deadline = t0 + timeout
        while True:
            missing = self.not_ready()
            if not missing:
                return time.monotonic() - t0
            if stop is not None and stop.is_set():
                raise StartupError(self.node, missing, timeout, interrupted=True)
            now = time.monotonic()
            if now >= deadline:
                if partial:
                    return now - t0
                raise StartupError(self.node, missing, timeout)
            with self._cond:
                self._cond.wait(min(0.01, deadline - now))

    def network_frame(self) -> int | None:
        """Where the running network is (``FrameInbox.network_frame``)."""
        return self.inbox.network_frame()

    def network_lead(self) -> int | None:
        """The most advanced neighbour's frame (``FrameInbox.network_lead``)."""
        return self.inbox.network_lead()

    def skip_to(self, frame: int) -> None:
        """This node skips ahead to ``frame`` (``FrameInbox.skip_to``)."""
        self.inbox.skip_to(frame)

    def collect(self, frame: int, timeout: float, stop: threading.Event | None = None, *,
                silent_grace: float | None = None) -> dict[int, FrameMessage]:
        """Sync mode: frame ``frame``'s messages (``FrameInbox.collect``)."""
        return self.inbox.collect(frame, timeout, stop, silent_grace=silent_grace)

    def drain(self, frame: int) -> list[FrameMessage]:
        """Async mode: what arrived up to frame ``frame`` (``FrameInbox.drain``)."""
        return self.inbox.drain(frame)

    def counters(self) -> dict:
        """A JSON-serialisable snapshot of the wire counters (bytes, messages, rejections...)."""
        def links_out(d):
            return {f"{self.node}->{n}": v for n, v in sorted(d.items())}

        def links_in(d):
            return {f"{n}->{self.node}": v for n, v in sorted(d.items())}

        with self._cond:
            return {
                "bytes_sent": sum(self.bytes_sent.values()),
                "bytes_per_link": links_out(self.bytes_sent),
                "messages_sent": sum(self.messages_sent.values()),
                "messages_per_link": links_out(self.messages_sent),
                "frames_published": self.publish_calls,
                # CPU of Zenoh's callback threads in this node's code (checks and decoding)
                "receive_cpu_s": self.receive_cpu_s,
                "bytes_received": sum(self.bytes_received.values()),
                "bytes_received_per_link": links_in(self.bytes_received),
                "messages_received": sum(self.messages_received.values()),
                "received_per_link": links_in(self.messages_received),
                "rejected": dict(sorted(self.rejected.items())),
                **self.inbox.counters(),
            }

    def latency_samples(self) -> np.ndarray:
        """The newest one-hop latencies (seconds, receipt time minus the sender's ``sent_at``)."""
        with self._cond:
            return self._latency.values()

    # -- teardown ---------------------------------------------------------------------------------
    def close(self) -> None:
        """Undeclare everything and close the session (idempotent)."""
        with self._cond:
            if self._closed:
                return
            self._closed = True
        self.inbox.close()
        for obj in [self._token, self._peers_q, *self._pubs.values(), self._alive_sub, self._sub]:
            if obj is None:
                continue
            try:
                obj.undeclare()
            except Exception as e:  # noqa: BLE001 - best effort on the way out
                log.debug("undeclare failed: %s", e)
        try:
            self.session.close()
        except Exception as e:  # noqa: BLE001
            log.debug("session close failed: %s", e)

    @property
    def closed(self) -> bool:
        return self._closed

    def __enter__(self) -> "ZenohTransport":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
