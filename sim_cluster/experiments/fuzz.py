"""Semantic fuzzing of running camera processes through their real Zenoh subscribers.

``sim_cluster fuzz --messages N`` starts two ``edge_node`` processes (cameras 0 and 1 of a
scenario, a chain 0 - 1 - 2) and plays node 2 itself: a Zenoh session that holds node 2's
liveliness token, hears node 1's frame-``k`` message and answers it. Twice:

* ``reference``: node 2 answers every frame with an empty message (a camera that sees nothing);
* ``attack``: node 2 answers with wire-valid hostile messages, every tracker entry and every
  merge announcement in them hostile (``U`` worth more than a 1 cm measurement; ``u, U``
  encoding a point far off the world; states at 1e30, 1e6 m/s, 1e5 m wide; ``ell`` 2**62; births in the future, earlier than the victim knows them, or against a
  camera's counter order; forged merges whose winner claims such a birth), under its own ids
  and under ids of cameras 0 and 1; plus replays of past frames, copies of the current frame,
  frames ahead, and messages to node 0, which is not its neighbour.

Pass: no victim exits other than normally, every hostile entry and merge that reached a node's
tracker is counted under a reason (exactly: messages used x (entries + merges) per message), and
both victims' tracks are byte for byte those of the reference run. What the screen cannot tell
from honest input (a plausible phantom under a fresh id, an ``ell`` of 0 that keeps a target
alive, a merge of two targets the sender was told about) is not sent here: it is tested, with
its bounded effect, in ``tests/test_trust.py`` and described in the README's threat model.
Information that is not a camera measurement (a ``U`` not positive definite on ``(x, y, w, h)``
or informing the velocity, a ``u`` outside ``U``'s range) cannot be written in wire schema 3:
the decoder refuses such bytes as malformed (``tests/test_protocol.py``), so it is not sent
here either.
"""
from __future__ import annotations

import json
import math
import os
import queue
import subprocess
import sys
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import zenoh

from edge_node.runtime.transport import zenoh_config
from protocol import codec
from protocol.keys import alive_key, link_key
from protocol.messages import FrameMessage, Merge, TrackerInfo
from sim_cluster.cluster.processes import free_ports
from sim_cluster.scenarios.loader import load_scenario

ATTACKER = 2
VICTIMS = (0, 1)
PHANTOM = 10**9  # counters of invented ids: far beyond anything a camera issues in a run

ENTRY_KINDS = ("huge_information", "off_world_measurement", "far_state", "fast_state",
               "huge_size", "huge_ell", "future_birth", "earlier_birth", "counter_order")
MERGE_KINDS = ("future_winner", "earlier_winner", "counter_order_winner")


@dataclass
class FuzzReport:
    messages: int = 0  # hostile messages published (all links, all kinds)
    to_node0: int = 0  # of which to node 0 (not node 2's neighbour: its codec refuses them)
    entries: int = 0  # hostile tracker entries in them
    merges: int = 0  # hostile merge announcements in them
    kinds: dict[str, int] = field(default_factory=dict)  # entries and merges sent, by kind
    frames: int = 0
    exit_codes: dict[str, list[int]] = field(default_factory=dict)  # run -> victims' exit codes
    rejected: dict[str, int] = field(default_factory=dict)  # victims' counters, by reason
    used: int = 0  # hostile messages a victim's tracker took (one per frame it got node 2's)
    expected_rejections: int = 0  # used x (entries + merges per message)
    semantic_rejections: int = 0
    identical: bool = False
    tracks_compared: int = 0  # track rows compared across the two runs
    seconds: float = 0.0

    @property
    def passed(self) -> bool:
        return (self.identical and self.semantic_rejections == self.expected_rejections
                and self.rejected.get("unknown_sender", 0) == self.to_node0
                and all(c == [0, 0] for c in self.exit_codes.values()))


class Hostile:
    """Builds hostile entries and merges from what the victim told node 2 (ids, births)."""

    def __init__(self, seed: int, units_per_metre: float, entries: int, merges: int):
        self.rng = np.random.default_rng(seed)
        self.upm = units_per_metre
        self.n_entries, self.n_merges = entries, merges
        self.known: dict[tuple[int, int], int] = {}  # ids node 1 sent us -> their birth
        self.kinds: dict[str, int] = {}
        self.serial = 0

    def learn(self, msg: FrameMessage) -> None:
        for t in msg.trackers:
            self.known.setdefault(t.id, t.born)

    def _fresh(self, camera: int = ATTACKER) -> tuple[int, int]:
        self.serial += 1
        return (camera, PHANTOM + self.serial)

    def _plausible(self) -> np.ndarray:
        return np.array([2.0, 3.0, 0.5, 1.7, 0.3, 0.0]) * self.upm

    def _older(self) -> tuple[tuple[int, int], int] | None:
        """A known id born after frame 0 (its birth can be claimed earlier)."""
        ids = sorted(t for t, b in self.known.items() if b > 0)
        return None if not ids else (ids[self.rng.integers(len(ids))], self.known[ids[0]])

    def entry(self, kind: str, k: int) -> TrackerInfo:
        x, u, U = self._plausible(), np.zeros(6), np.zeros((6, 6))
        tid, born, ell = self._fresh(int(self.rng.integers(0, 3))), k, 0
        z = x.copy()
        z[4:] = 0
        if kind == "huge_information":
            U[:4, :4] = np.eye(4) * 10.0 ** self.rng.uniform(9, 30)
            # measured exactly at x_bar as the wire carries it (float32): an innovation of even
            # 1e-6 m would be beyond float16 at these precisions
            u = U @ z.astype(np.float32).astype(np.float64)
        elif kind == "off_world_measurement":
            # 1e4 standard deviations from the plausible state (schema 3 carries up to 65504):
            # far beyond the screen's gate of 100 off the world
            far = z.copy()
            far[:2] = self.rng.choice([-1, 1], 2) * 10.0 ** self.rng.uniform(4, 6) * self.upm
            sigma = np.abs(far[:2] - z[:2]).max() / 1e4
            U[:4, :4] = np.eye(4) / sigma**2
            u = U @ far
        elif kind == "far_state":
            x[:2] = self.rng.choice([-1, 1], 2) * 10.0 ** self.rng.uniform(7, 30) * self.upm
        elif kind == "fast_state":
            x[4:] = self.rng.choice([-1, 1], 2) * 10.0 ** self.rng.uniform(4, 30) * self.upm
        elif kind == "huge_size":
            x[2 + int(self.rng.integers(2))] = self.rng.choice([-1, 1]) * 1e5 * self.upm
        elif kind == "huge_ell":
            ell = int(2**62)
        elif kind == "future_birth":
            born = k + 1 + int(self.rng.integers(0, 10**6))
        elif kind == "earlier_birth":
            old = self._older()
            if old is None:
                return self.entry("future_birth", k)
            tid = old[0]
            born = int(self.rng.integers(0, self.known[tid]))
        elif kind == "counter_order":
            old = self._older()
            if old is None:
                return self.entry("future_birth", k)
            tid, born = self._fresh(old[0][0]), 0
        self.kinds[kind] = self.kinds.get(kind, 0) + 1
        return TrackerInfo(tid, x, u, 0.5 * (U + U.T), ell, None, born)

    def merge(self, kind: str, k: int) -> Merge:
        loser = self._fresh()
        if kind == "earlier_winner":
            old = self._older()
            if old is not None:
                self.kinds[kind] = self.kinds.get(kind, 0) + 1
                return Merge(loser, old[0], int(self.rng.integers(0, self.known[old[0]])))
            kind = "future_winner"
        if kind == "counter_order_winner":
            old = self._older()
            if old is not None:
                self.kinds[kind] = self.kinds.get(kind, 0) + 1
                return Merge(loser, self._fresh(old[0][0]), 0)
            kind = "future_winner"
        self.kinds["future_winner"] = self.kinds.get("future_winner", 0) + 1
        return Merge(loser, self._fresh(), k + 1 + int(self.rng.integers(0, 10**6)))

    def message(self, network: str, k: int) -> FrameMessage:
        entries = tuple(self.entry(ENTRY_KINDS[self.rng.integers(len(ENTRY_KINDS))], k)
                        for _ in range(self.n_entries))
        seen, unique = set(), []
        for e in entries:  # one entry per id in a message (the codec's rule)
            if e.id in seen:
                self.kinds["earlier_birth"] -= 1  # only known ids repeat
                e = self.entry("future_birth", k)
            seen.add(e.id)
            unique.append(e)
        merges = tuple(self.merge(MERGE_KINDS[self.rng.integers(len(MERGE_KINDS))], k)
                       for _ in range(self.n_merges))
        return FrameMessage(network, ATTACKER, k, tuple(unique), merges, sent_at=time.time())


class Node2:
    """Node 2 as a Zenoh session: answers node 1's frame-``k`` message (see module docstring)."""

    def __init__(self, network: str, listen: str, connect: list[str], hostile: Hostile | None,
                 per_frame: int, frames: int):
        self.network, self.hostile, self.per_frame, self.frames = network, hostile, per_frame, frames
        # node 0 waits for node 1 only while node 1 keeps up: behind under the attack on a slow
        # machine, node 1 let node 0 finish 3 frames ahead and messages to it went unheard
        self.tail = max(3, frames // 10)
        self.session = zenoh.open(zenoh_config([listen], connect))
        self.inbox: queue.Queue[bytes] = queue.Queue()
        self.sub = self.session.declare_subscriber(link_key(network, 1, ATTACKER),
                                                   lambda s: self.inbox.put(s.payload.to_bytes()))
        self.pubs = {v: self.session.declare_publisher(link_key(network, ATTACKER, v),
                                                       congestion_control=zenoh.CongestionControl.BLOCK)
                     for v in VICTIMS}
        self.token = self.session.liveliness().declare_token(alive_key(network, ATTACKER))
        self.report = FuzzReport()

    def _put(self, dst: int, msg: FrameMessage) -> None:
        self.pubs[dst].put(codec.encode(msg))
        if self.hostile is not None:
            self.report.messages += 1
            self.report.to_node0 += dst == 0
            self.report.entries += len(msg.trackers)
            self.report.merges += len(msg.merges)

    def answer(self, k: int) -> None:
        if self.hostile is None:
            self.pubs[1].put(codec.encode(FrameMessage(self.network, ATTACKER, k, sent_at=time.time())))
            return
        h = self.hostile
        self._put(1, h.message(self.network, k))  # the message node 1 waits for
        for i in range(self.per_frame - 1):
            r = i % 4
            if r == 0 and k > 0:  # a replay of a past frame: late
                self._put(1, h.message(self.network, int(h.rng.integers(max(0, k - 20), k))))
            elif r == 1:  # another copy of this frame: a duplicate
                self._put(1, h.message(self.network, k))
            elif r == 2 and k + 3 < self.frames:  # a frame ahead, taken when node 1 gets there
                self._put(1, h.message(self.network, k + 1 + int(h.rng.integers(0, 3))))
            elif k + self.tail < self.frames:  # to node 0, whose neighbour node 2 is not:
                self._put(0, h.message(self.network, k))  # refused by its codec (not in the
            else:                             # last tenth: node 0 may have stopped listening)
                self._put(1, h.message(self.network, k))

    def serve(self, procs: list[subprocess.Popen], timeout: float) -> None:
        deadline = time.monotonic() + timeout
        # connected to both victims before the first answer: what is sent is then received
        while len(list(self.session.info.peers_zid())) < len(VICTIMS) \
                and time.monotonic() < deadline and all(p.poll() is None for p in procs):
            time.sleep(0.02)
        while time.monotonic() < deadline and any(p.poll() is None for p in procs):
            try:
                payload = self.inbox.get(timeout=0.1)
            except queue.Empty:
                continue
            try:
                msg = codec.decode(payload, expect_sender=1)
            except Exception:  # noqa: BLE001 - node 1 is honest; nothing else arrives here
                continue
            if self.hostile is not None:
                self.hostile.learn(msg)
            self.answer(msg.frame)

    def close(self) -> None:
        for obj in (self.token, self.sub, *self.pubs.values()):
            obj.undeclare()
        self.session.close()


def _victim_config(out: Path, node: int, ports: dict[int, int], network: str, scenario: str,
                   frames: int, fps: float, sync_timeout_s: float) -> Path:
    neighbours = {0: [1], 1: [0, ATTACKER]}[node]
    connect = [f"tcp/127.0.0.1:{ports[n]}" for n in neighbours]
    text = "\n".join([
        f"node = {node}", f'network = "{network}"', f"neighbours = {neighbours}",
        "[zenoh]", f'listen = ["tcp/127.0.0.1:{ports[node]}"]', f"connect = {json.dumps(connect)}",
        "[runtime]", f"fps = {fps}", "startup_timeout_s = 30", f"sync_timeout_s = {sync_timeout_s}",
        "[source]", 'kind = "scenario"', f'scenario = "{scenario}"', f"camera = {node}",
        f"frames = {frames}", "[output]", f'dir = "{out}"', ""])
    path = out / f"node{node}.toml"
    path.write_text(text)
    return path


def _run_once(out: Path, hostile: Hostile | None, *, scenario: str, frames: int, fps: float,
              per_frame: int, network: str, sync_timeout_s: float) -> tuple[Node2, list[int]]:
    out.mkdir(parents=True, exist_ok=True)
    ports = dict(zip((0, 1, ATTACKER), free_ports(3)))
    node2 = Node2(network, f"tcp/127.0.0.1:{ports[ATTACKER]}",
                  [f"tcp/127.0.0.1:{ports[n]}" for n in VICTIMS], hostile, per_frame, frames)
    procs = []
    try:
        env = dict(os.environ, PYTHONUNBUFFERED="1")
        for n in VICTIMS:
            cfg = _victim_config(out, n, ports, network, scenario, frames, fps, sync_timeout_s)
            log = open(out / f"node{n}.log", "w")
            procs.append(subprocess.Popen([sys.executable, "-m", "edge_node.cli", "run",
                                           "--config", str(cfg), "--log-level", "WARNING"],
                                          env=env, stdout=log, stderr=subprocess.STDOUT))
        node2.serve(procs, timeout=60 + 3 * frames / max(fps, 1.0) + 2 * sync_timeout_s)
        codes = []
        for p in procs:
            try:
                codes.append(p.wait(timeout=30))
            except subprocess.TimeoutExpired:
                p.kill()
                codes.append(p.wait())
        return node2, codes
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()
        node2.close()


def run(messages: int = 10_000, out: str | Path = "runs/fuzz", *, scenario: str = "lab-sim",
        fps: float = 50.0, per_frame: int = 40, entries: int = 4, merges: int = 2,
        seed: int = 0, sync_timeout_s: float = 2.0, progress=None) -> FuzzReport:
    """The reference and the attack run; the report (see the module docstring). ``fps`` 0: as
    fast as the nodes go; ``sync_timeout_s``: how long a victim waits for a neighbour's frame
    (the test runs unpaced with a long one, so a victim starved of CPU on a busy machine does not
    time out its neighbour and make the two runs' tracks differ)."""
    t0 = time.monotonic()
    out = Path(out)
    # a tenth more frames than ``messages`` needs: a victim that falls behind under the attack
    # skips a frame (it catches up with the network), and node 2 answers only the frames it
    # hears; on a slow machine 1-2 of 250 were skipped and the run fell short of ``messages``
    frames = max(20, math.ceil(1.1 * messages / per_frame))
    upm = load_scenario(scenario, seed=None, frames=2).units_per_metre
    network = f"fuzz{os.getpid()}"
    results = {}
    for name, hostile in (("reference", None),
                          ("attack", Hostile(seed, upm, entries, merges))):
        if progress:
            progress(f"{name}: {frames} frames at {fps:g} fps")
        node2, codes = _run_once(out / name, hostile, scenario=scenario, frames=frames, fps=fps,
                                 per_frame=per_frame, network=f"{network}{name[0]}",
                                 sync_timeout_s=sync_timeout_s)
        results[name] = (node2, codes)
    attack = results["attack"][0]
    rep = attack.report
    rep.kinds = dict(sorted(attack.hostile.kinds.items()))
    rep.frames = frames
    rep.exit_codes = {name: codes for name, (_, codes) in results.items()}
    c1 = json.loads((out / "attack" / "counters_node1.json").read_text())
    c0 = json.loads((out / "attack" / "counters_node0.json").read_text())
    rejected: dict[str, int] = {}
    for c in (c0, c1):  # the codec's refusals and the screen's, by reason
        for key, n in c.get("rejected", {}).items():
            rejected[key] = rejected.get(key, 0) + n
        for key in ("late", "duplicates", "overflow"):
            rejected[key] = rejected.get(key, 0) + sum(c.get(key, {}).values())
    rep.rejected = dict(sorted(rejected.items()))
    rep.semantic_rejections = sum(c1["node_stats"]["rejected"].values())
    # frames node 1 finished without the attacker's message: timed out, or shown lost by a
    # newer message of the attacker's (its frames ahead) before frame k's answer came
    rep.used = c1["frames_done"] - sum(n for key in ("timeouts", "lost")
                                       for link, n in c1.get(key, {}).items()
                                       if link.startswith(f"{ATTACKER}->"))
    rep.expected_rejections = rep.used * (entries + merges)
    rep.identical, rep.tracks_compared = _same_tracks(out / "reference", out / "attack")
    rep.seconds = time.monotonic() - t0
    (out / "fuzz.json").write_text(json.dumps({**asdict(rep), "passed": rep.passed}, indent=1))
    return rep


def _same_tracks(a: Path, b: Path) -> tuple[bool, int]:
    rows = 0
    for n in VICTIMS:
        ta = (a / f"tracks_node{n}.csv").read_bytes()
        tb = (b / f"tracks_node{n}.csv").read_bytes()
        if ta != tb:
            return False, rows
        rows += ta.count(b"\n")
    return True, rows


def main(args) -> int:
    def say(text: str) -> None:
        if not args.quiet:
            print(f"fuzz: {text}", file=sys.stderr, flush=True)
    rep = run(args.messages, args.out, scenario=args.scenario, fps=args.fps, seed=args.seed,
              progress=say)
    print(f"hostile messages {rep.messages:,} ({rep.entries:,} tracker entries, "
          f"{rep.merges:,} merges) over {rep.frames} frames in {rep.seconds:.0f} s")
    print("sent by kind: " + ", ".join(f"{k} {v}" for k, v in rep.kinds.items()))
    print("victims' counters: " + ", ".join(f"{k} {v}" for k, v in rep.rejected.items()))
    print(f"node 1 used {rep.used} hostile messages: {rep.semantic_rejections} of "
          f"{rep.expected_rejections} entries and merges rejected; node 0 refused "
          f"{rep.rejected.get('unknown_sender', 0)} of the {rep.to_node0} sent to it")
    print(f"exit codes {rep.exit_codes}; tracks identical to the reference run: "
          f"{rep.identical} ({rep.tracks_compared} rows)")
    print("PASS" if rep.passed else "FAIL")
    return 0 if rep.passed else 1
