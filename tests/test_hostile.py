"""Hostile input end to end: a real node (``FrameLoop`` + ``ZenohTransport``) flooded with
mutated, forged, foreign, replayed, oversize and malformed messages on its inbox keys.

Nothing a peer sends may crash the node or touch its tracker state: every bad message is
rejected before the core sees it and counted by reason (``counters()["rejected"]``; replayed
old frames as ``late``), and the node's tracks equal those of the in-process reference run that
received no garbage at all.

Set-up (sync mode): node 0 (under test) runs its ``FrameLoop`` in a thread; node 1 (its
legitimate neighbour) is stepped frame by frame by the test. At a few frames ``k`` the test
holds node 1 back, so node 0 sits in ``collect(k)``, and floods node 0 through a third Zenoh
session. Each fuzz message is classified beforehand with the same rules as the transport
(key parse, size, ``codec.decode`` against the key): the expected counters are exact.
A mutation that still decodes into a valid frame-``>= k`` message from neighbour 1 is not sent:
it is indistinguishable from the neighbour's own message (only transport authentication stops
that -- see tests/test_security.py), so it is not "garbage" this layer could reject.

Also: in async (event-triggered) operation, replayed old messages change nothing in the core
(it keeps each neighbour's newest entry per tracker and fuses ``u, U`` once); and a flood of
future frames cannot push the awaited message out of the bounded inbox.
"""
from __future__ import annotations

import collections
import json
import threading
import time
from dataclasses import replace
from pathlib import Path

import msgpack
import numpy as np
import pytest

from edge_node.core.config import TrackerConfig
from edge_node.core.node import CameraNode
from edge_node.core.trigger import EventTrigger, TriggerConfig
from edge_node.formats.tracks import TrackWriter
from edge_node.runtime.config import load_node_config
from edge_node.runtime.loop import FrameLoop
from edge_node.runtime.preflight import tracker_config_for
from edge_node.runtime.output import StatusWriter, status_path
from edge_node.runtime.sources import open_source
from protocol import SCHEMA_VERSION, codec
from protocol.errors import ProtocolError
from protocol.keys import parse_link_key

from tests.loopback import ep, export_scenario, free_port, wait_for  # noqa: E402

NET = "hx"
FRAMES = 24
FUZZ_AT = (3, 8, 13, 19)  # frames at which node 0 is flooded while it waits for neighbour 1
PER_BATCH = 2600  # small fuzz messages per flood: 4 x 2600 = 10,400 in all
OVERSIZE_PER_BATCH = 3  # plus a few blobs just over Limits.max_bytes (1 MiB)
MAX_BYTES = codec.DEFAULT_LIMITS.max_bytes





@pytest.fixture(scope="module")
def export_dir(tmp_path_factory) -> Path:
    return export_scenario(tmp_path_factory.mktemp("export"), FRAMES)


class ListWriter(TrackWriter):
    """Keeps every frame's tracks in memory."""

    def __init__(self):
        super().__init__(None)
        self.frames: list[list] = []

    def write(self, tracks) -> None:
        self.frames.append(list(tracks))


def _node_config(tmp: Path, node: int, neighbours, listen, connect, export: Path):
    p = tmp / f"cam{node}.toml"
    p.write_text("\n".join([
        f"node = {node}", f'network = "{NET}"', f"neighbours = {list(neighbours)}",
        "[zenoh]", f"listen = {json.dumps(list(listen))}", f"connect = {json.dumps(list(connect))}",
        # long waits: node 0 must sit in collect(k) for as long as a flood takes
        "[runtime]", "startup_timeout_s = 30", "sync_timeout_s = 30",
        "[source]", 'kind = "det-file"', f'path = "{export}"', ""]))
    return load_node_config(p)


def _build(cfg, transport, status: StatusWriter | None = None):
    source = open_source(cfg)
    node = CameraNode(source.camera, cfg.neighbours, tracker_config_for(cfg, source), cfg.network,
                      node_id=cfg.node)
    writer = ListWriter()
    loop = FrameLoop(cfg, node, source, transport, mode="sync", frames=FRAMES, writer=writer,
                     status=status)
    return loop, writer


# -- the fuzzer -------------------------------------------------------------------------------------
LEGIT = f"dmtt/{NET}/link/1/0"  # neighbour 1's link into node 0
STRANGER = f"dmtt/{NET}/link/7/0"  # a node that is not a neighbour
SELF = f"dmtt/{NET}/link/0/0"  # node 0 "to itself"
BAD_KEYS = (f"dmtt/{NET}/link/01/0", f"dmtt/{NET}/link/one/0")  # match the inbox, do not parse
FUZZ_KEYS = (LEGIT, STRANGER, SELF) + BAD_KEYS

_POOL = [None, True, False, -1, 0, 1, 2**63, 2**64 - 1, -2**63, 1.5, float("nan"), float("inf"),
         "", "x", "hx", "other", b"", b"\x00" * 24, b"\xff" * 132, [], [1, 2], {"a": 1},
         [[]] * 3]


def expected_outcome(key: str, payload: bytes, k: int) -> str | None:
    """What node 0's transport must do with ``payload`` on ``key`` while it waits on frame ``k``:
    a rejection reason, ``"late"`` (valid but of a frame already processed), or ``None``
    (valid and current: indistinguishable from the neighbour's own message)."""
    try:
        _, src, _ = parse_link_key(key)
    except ProtocolError as e:
        return e.reason
    if len(payload) > MAX_BYTES:
        return "oversize"
    try:
        msg = codec.decode(payload, expect_network=NET, expect_sender=src, allowed_senders={1})
    except ProtocolError as e:
        return e.reason
    return "late" if msg.frame < k else None


def _mutate_structure(obj, rng):
    """Replace, delete, insert or duplicate one random node of a decoded msgpack tree."""
    path = []
    node = obj
    while isinstance(node, list) and node and rng.random() < 0.7:
        i = int(rng.integers(len(node)))
        path.append(i)
        node = node[i]
    parent = obj
    for i in path[:-1]:
        parent = parent[i]
    op = rng.integers(4)
    pick = _POOL[int(rng.integers(len(_POOL)))]
    if not path:
        return [pick] + obj[1:] if op == 0 else obj[: int(rng.integers(len(obj) + 1))]
    i = path[-1]
    if op == 0:
        parent[i] = pick
    elif op == 1:
        del parent[i]
    elif op == 2:
        parent.insert(i, pick)
    else:
        parent.insert(i, parent[i])  # duplicate (e.g. a tracker: duplicate ids)
    return obj


def fuzz_batch(rng: np.random.Generator, genuine: list[bytes], k: int, n: int):
    """``n`` hostile ``(key, payload, expected)``; ``genuine`` are neighbour 1's messages of
    frames ``< k`` as they went over the wire. Half are first re-aimed at frames ``k..k+2``, so
    that a check that let them through would change what node 0 fuses."""
    out = []
    msgs = [codec.decode(p) for p in genuine]
    cache: dict[tuple, bytes] = {}  # encoding is the slow part: each variant once

    def enc(j: int, frame: int, **changes) -> bytes:
        ck = (j, frame, *sorted(changes.items()))
        if ck not in cache:
            cache[ck] = codec.encode(replace(msgs[j], frame=frame, **changes))
        return cache[ck]

    kinds = ("flip", "flip", "truncate", "extend", "structure", "structure", "forged", "network",
             "stranger", "self", "replay", "badkey", "random", "bomb", "version", "nan")
    while len(out) < n:
        kind = kinds[int(rng.integers(len(kinds)))]
        j = int(rng.integers(len(genuine)))
        base, frame = genuine[j], msgs[j].frame
        if rng.random() < 0.5:  # aim at the frame node 0 waits for (or just after it)
            frame = k + int(rng.integers(0, 3))
            base = enc(j, frame)
        key = LEGIT
        if kind == "flip":
            p = bytearray(base)
            for _ in range(int(rng.integers(1, 4))):
                p[int(rng.integers(len(p)))] ^= int(rng.integers(1, 256))
            payload = bytes(p)
        elif kind == "truncate":
            payload = base[: int(rng.integers(len(base)))]
        elif kind == "extend":
            payload = base + rng.bytes(int(rng.integers(1, 9)))
        elif kind == "structure":
            obj = msgpack.unpackb(base, raw=False)
            for _ in range(int(rng.integers(1, 3))):
                obj = _mutate_structure(obj, rng)
            payload = msgpack.packb(obj, use_bin_type=True)
        elif kind == "forged":  # another node's id in the payload, on neighbour 1's key
            payload = enc(j, frame, sender=int(rng.choice([0, 2, 3, 7, 2**40])))
        elif kind == "network":  # our inbox key, another network's message
            payload = enc(j, frame, network=str(rng.choice(["other", "hx2", "HX"])))
        elif kind == "stranger":  # a node that is not a neighbour, consistent key and payload
            key, payload = STRANGER, enc(j, frame, sender=7)
        elif kind == "self":
            key, payload = SELF, enc(j, frame, sender=0)
        elif kind == "replay":  # an old frame, byte for byte
            payload = base
        elif kind == "badkey":
            key, payload = BAD_KEYS[int(rng.integers(2))], base
        elif kind == "random":
            payload = rng.bytes(int(rng.integers(0, 300)))
        elif kind == "bomb":  # tiny on the wire, huge counts
            payload = msgpack.packb([SCHEMA_VERSION, NET, 1, k, 0.0, 0, 0, [[]] * 5000, [], b""])
        elif kind == "version":
            obj = msgpack.unpackb(base, raw=False)
            obj[0] = int(rng.choice([0, 1, 3, 99]))  # 1: the per-tracker layout before schema 2
            payload = msgpack.packb(obj, use_bin_type=True)
        else:  # NaN in a tracker's numbers
            obj = msgpack.unpackb(base, raw=False)  # schema 2: [.., n, widths, .., .., block]
            rows, widths = obj[5], obj[6]
            if not rows:
                continue
            ints = rows * sum(1 << ((widths >> 2 * c) & 3) for c in range(4))
            at = ints + (rows + 7) // 8 + 24 * int(rng.integers(rows))  # a random row's x_bar
            block = bytearray(obj[9])
            block[at : at + 4] = np.float32(np.nan).tobytes()
            obj[9] = bytes(block)
            payload = msgpack.packb(obj, use_bin_type=True)
        expected = expected_outcome(key, payload, k)
        if expected is None:  # a valid current/future message from neighbour 1: not garbage
            continue
        out.append((key, payload, expected))
    for _ in range(OVERSIZE_PER_BATCH):
        blob = genuine[-1] + rng.bytes(MAX_BYTES + 1 - len(genuine[-1]))
        out.append((LEGIT, blob, expected_outcome(LEGIT, blob, k)))
    return out


# -- the test ---------------------------------------------------------------------------------------
@pytest.mark.integration
def test_fuzzed_inbox_rejects_everything_and_tracks_equal_reference(tmp_path, export_dir):
    import zenoh

    from edge_node.runtime.transport import ZenohTransport, zenoh_config
    from sim_cluster.cluster.state import ClusterState, NodeProc, status_table
    from sim_cluster.scenarios.detfiles import load_det_files
    from sim_cluster.network.inprocess import run_network

    t_start = time.monotonic()
    p0, p1 = free_port(), free_port()
    cfg0 = _node_config(tmp_path, 0, [1], [ep(p0)], [ep(p1)], export_dir)
    cfg1 = _node_config(tmp_path, 1, [0], [ep(p1)], [ep(p0)], export_dir)
    out = tmp_path / "cluster"
    opened = []
    loop_a = None
    try:
        a = ZenohTransport(NET, 0, [1], [ep(p0)], [ep(p1)])
        opened.append(a)
        b = ZenohTransport(NET, 1, [0], [ep(p1)], [ep(p0)])
        opened.append(b)
        fz = zenoh.open(zenoh_config([], [ep(p0)]))  # the attacker: connected to node 0 only
        opened.append(fz)
        pubs = {key: fz.declare_publisher(key, congestion_control=zenoh.CongestionControl.BLOCK)
                for key in FUZZ_KEYS}
        assert wait_for(lambda: all(p.matching_status.matching for p in pubs.values()))
        a.wait_ready(10.0)
        b.wait_ready(10.0)

        loop_a, tracks_a = _build(cfg0, a, StatusWriter(status_path(out / "nodes", 0), 0.0))
        loop_b, tracks_b = _build(cfg1, b)
        genuine: list[bytes] = []  # what node 1 put on its link to node 0, frame by frame
        b_publish = b.publish

        def record(payload: bytes) -> int:
            genuine.append(payload)
            return b_publish(payload)

        b.publish = record

        errors: list[BaseException] = []

        def run_a():
            try:
                loop_a.run()
            except BaseException as e:  # noqa: BLE001 - reported by the test thread
                errors.append(e)

        thread = threading.Thread(target=run_a, daemon=True)
        thread.start()

        rng = np.random.default_rng(2024)
        expected: collections.Counter = collections.Counter()
        sent = 0
        flood_s = 0.0
        for k in range(FRAMES):
            if k in FUZZ_AT:
                # node 0 has published frame k (so it finished frame k - 1) and now waits for
                # neighbour 1's frame k, which the test holds back until the flood is absorbed
                assert wait_for(lambda: b.counters()["messages_received"] >= k + 1), k
                batch = fuzz_batch(rng, genuine, k, PER_BATCH)
                t0 = time.monotonic()
                for key, payload, why in batch:
                    pubs[key].put(payload)
                    expected[why] += 1
                sent += len(batch)

                def absorbed():
                    c = a.counters()
                    return sum(c["rejected"].values()) + sum(c["late"].values()) \
                        == sum(expected.values())

                assert wait_for(absorbed, timeout=30), (a.counters(), expected)
                flood_s += time.monotonic() - t0
                assert thread.is_alive() and not errors
                assert loop_a.stats.frames_done == k  # still waiting on frame k: nothing fused
            tracks_b.frames.append(loop_b.step_sync(k, first=(k == 0)))
        thread.join(timeout=30)
        assert not thread.is_alive() and not errors, errors
        loop_a.write_status("finished")
        c = a.counters()
    finally:
        if loop_a is not None:
            loop_a.stop.set()  # on failure: let node 0's thread end instead of waiting 30 s
        for o in reversed(opened):
            o.close()

    # >= 10,000 hostile messages, every one counted under the reason it was sent for
    assert sent >= 10_000
    late = expected.pop("late")
    assert c["rejected"] == dict(sorted(expected.items())), (c["rejected"], expected)
    assert c["late"] == {"1->0": late}
    assert c["duplicates"] == {} and c["overflow"] == {} and c["timeouts"] == {}
    assert c["messages_received"] == FRAMES + late  # the genuine frames, plus counted replays
    for reason in ("malformed", "forged_source", "unknown_network", "unknown_sender", "oversize",
                   "version", "non_finite", "key"):
        assert expected[reason] > 0, reason  # every kind of hostility was exercised
    assert late > 0
    assert loop_a.stats.frames_done == FRAMES  # the node kept completing frames afterwards

    # tracker state untouched: both nodes equal the in-process run that saw no garbage
    ref = run_network(load_det_files(export_dir), {0: (1,), 1: (0,), 2: (), 3: ()},
                      TrackerConfig(), network=NET)
    for n, got in ((0, tracks_a.frames), (1, tracks_b.frames)):
        assert len(got) == FRAMES
        for k in range(FRAMES):
            want = ref.tracks[n][k]
            assert [t.id for t in got[k]] == [t.id for t in want], (n, k)
            for x, y in zip(got[k], want):
                assert np.allclose(x.x, y.x, atol=1e-6, rtol=0), (n, k, x.id)
                assert x.observed == y.observed and x.ell == y.ell
    assert sum(len(f) for f in tracks_a.frames) > 0

    # visible in `sim_cluster status`: the node's status file carries the counts by reason
    st = json.loads(status_path(out / "nodes", 0).read_text())
    assert st["rejected"] == c["rejected"] and st["late"] == late
    state = ClusterState(out=str(out), network=NET, scenario="terrace-sim", seed=0, frames=FRAMES,
                         mode="sync", topology="chain", adjacency={"0": [1], "1": [0]},
                         nodes={"0": NodeProc(0, "", "", p0)})
    table = status_table(state)
    row = table.splitlines()[2].split()
    assert row[0] == "0" and row[6] == str(sum(c["rejected"].values())) and row[7] == str(late)
    assert f"node 0 rejected: forged_source {c['rejected']['forged_source']}, " in table
    assert f"unknown_sender {c['rejected']['unknown_sender']}" in table
    print(f"\n{sent} hostile messages absorbed in {flood_s:.2f} s "
          f"({sent / flood_s:.0f}/s); whole test {time.monotonic() - t_start:.1f} s; "
          f"rejected {c['rejected']}, late {late}")


# -- async: a replayed old frame resets nothing -------------------------------------------------------
def _async_pair(data, frames: int, replay: bool, seed: int = 5):
    """Two neighbours in event-triggered (async) operation, messages through the codec; with
    ``replay`` each node also gets, every frame, copies of the neighbour's older messages (random
    frames, within and beyond ``kappa``) and a second copy of the current one."""
    cfg = TrackerConfig().with_(fps=data.fps, units_per_metre=data.units_per_metre)
    nodes = {i: CameraNode(data.cameras[i], [1 - i], cfg, NET) for i in (0, 1)}
    trig = {i: EventTrigger(TriggerConfig(), cfg.dt, cfg.units_per_metre) for i in (0, 1)}
    history: dict[int, list[bytes]] = {0: [], 1: []}
    tracks = {0: [], 1: []}
    rng = np.random.default_rng(seed)
    replayed = 0
    for k in range(frames):
        inbox: dict[int, list] = {0: [], 1: []}
        for i in (0, 1):
            msg = trig[i].filter(nodes[i].prepare(k, data.detections[k][i]))
            if msg is not None:
                payload = codec.encode(msg)
                history[i].append(payload)
                inbox[1 - i].append(codec.decode(payload))
        for i in (0, 1):
            got = inbox[i]
            old = history[1 - i]
            if replay and old:
                picks = [old[int(j)] for j in rng.integers(len(old), size=4)]
                got = got + [codec.decode(p) for p in picks] + got
                replayed += len(picks)
            tracks[i].append(nodes[i].update(got, stale_ok=True))
    return tracks, replayed


def test_async_replayed_old_frames_change_nothing(export_dir):
    from sim_cluster.scenarios.detfiles import load_det_files

    data = load_det_files(export_dir)
    clean, _ = _async_pair(data, FRAMES, replay=False)
    dirty, replayed = _async_pair(data, FRAMES, replay=True)
    assert replayed > 50
    for i in (0, 1):
        assert sum(len(f) for f in clean[i]) > 0
        for k in range(FRAMES):
            assert [t.id for t in dirty[i][k]] == [t.id for t in clean[i][k]], (i, k)
            for x, y in zip(dirty[i][k], clean[i][k]):
                assert np.array_equal(x.x, y.x) and np.array_equal(x.P, y.P), (i, k, x.id)
                assert x.observed == y.observed and x.ell == y.ell


# -- a flood of future frames cannot push out the message a node waits for ---------------------------
@pytest.mark.integration
def test_future_frame_flood_keeps_the_awaited_message():
    """Valid-looking messages of frames far ahead, on a neighbour's key (what an unauthenticated
    spoofer can send; tests/test_security.py shows how mTLS + access control stop it), fill the
    bounded inbox: the frames farthest ahead are dropped (counted as overflow), never the frame
    the node is about to use."""
    import zenoh

    from edge_node.runtime.transport import ZenohTransport, zenoh_config
    from protocol.messages import FrameMessage

    p0 = free_port()
    a = ZenohTransport(NET, 0, [1], [ep(p0)], [], max_pending_frames=16)
    raw = None
    try:
        raw = zenoh.open(zenoh_config([], [ep(p0)]))
        pub = raw.declare_publisher(LEGIT, congestion_control=zenoh.CongestionControl.BLOCK)
        assert wait_for(lambda: pub.matching_status.matching)
        pub.put(codec.encode(FrameMessage(NET, 1, 0, sent_at=time.time())))  # the real frame 0
        for f in range(1000, 1100):
            pub.put(codec.encode(FrameMessage(NET, 1, f, sent_at=time.time())))
        assert wait_for(lambda: a.counters()["messages_received"] == 101)
        assert a.counters()["overflow"] == {"1->0": 101 - 16}
        got = a.collect(0, 1.0)  # (the raw session has no liveliness token: nothing to wait for)
        assert list(got) == [1] and got[1].frame == 0
        assert [m.frame for m in a.drain(2000)] == list(range(1000, 1015))
    finally:
        if raw is not None:
            raw.close()
        a.close()
