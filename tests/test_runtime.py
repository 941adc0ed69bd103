"""The camera-process runtime: Zenoh transport on loopback, frame loops, and an end-to-end run of
real ``edge_node run`` processes against the in-process reference. (Its config:
test_node_config.py; its sources: test_sources.py; the files it writes: test_formats.py.)"""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from edge_node.core.config import TrackerConfig
from edge_node.core.node import CameraNode
from edge_node.runtime.config import load_node_config
from edge_node.runtime.loop import FrameLoop
from edge_node.runtime.output import tracks_path
from protocol import codec
from protocol.keys import link_key
from protocol.messages import FrameMessage, TrackerInfo
from tests.fakes import det, topdown_camera
from tests.loopback import ep, export_scenario, free_port, wait_for
from tests.test_node_config import BASE

REPO = Path(__file__).resolve().parents[1]
FRAMES = 40


# -- fixtures -----------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def export_dir(tmp_path_factory) -> Path:
    return export_scenario(tmp_path_factory.mktemp("export"), FRAMES)


@pytest.fixture
def procs():
    """Subprocesses started by a test; whatever still runs at the end is killed."""
    started: list[subprocess.Popen] = []
    try:
        yield started
    finally:
        for p in started:
            if p.poll() is None:
                p.kill()
            try:
                p.wait(timeout=10)
            except subprocess.TimeoutExpired:
                pass
            for f in (p.stdout, p.stderr):
                if f:
                    f.close()


@pytest.fixture
def transports():
    """ZenohTransports opened by a test; all closed at the end."""
    opened = []
    try:
        yield opened
    finally:
        for t in opened:
            t.close()


def write_config(path: Path, node: int, neighbours, listen, connect, export: Path, *,
                 network: str = "rt", out: Path | None = None, extra: str = "") -> Path:
    lines = [
        f"node = {node}", f'network = "{network}"', f"neighbours = {list(neighbours)}",
        "[zenoh]", f"listen = {json.dumps(list(listen))}", f"connect = {json.dumps(list(connect))}",
        "[runtime]", "startup_timeout_s = 20", "sync_timeout_s = 5",
        "[source]", 'kind = "det-file"', f'path = "{export}"',
    ]
    if out is not None:
        lines += ["[output]", f'dir = "{out}"']
    path.write_text("\n".join(lines) + "\n" + extra)
    return path


def start_node(procs, config: Path, *args: str) -> subprocess.Popen:
    env = dict(os.environ, PYTHONPATH=str(REPO), PYTHONUNBUFFERED="1")
    p = subprocess.Popen([sys.executable, "-m", "edge_node.cli", "run", "--config", str(config),
                          "--log-level", "WARNING", *args],
                         cwd=str(REPO), env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                         text=True)
    procs.append(p)
    return p


# -- transport --------------------------------------------------------------------------------------------
def _pair(transports, network="tp", **kw):
    from edge_node.runtime.transport import ZenohTransport

    p0, p1 = free_port(), free_port()
    a = ZenohTransport(network, 0, [1], [ep(p0)], [ep(p1)], **kw)
    transports.append(a)
    b = ZenohTransport(network, 1, [0], [ep(p1)], [ep(p0)], **kw)
    transports.append(b)
    return a, b, p0, p1


def _msg(sender: int, frame: int, network="tp") -> FrameMessage:
    t = TrackerInfo((sender, 0), np.arange(6.0), np.zeros(6), np.zeros((6, 6)), 0)
    return FrameMessage(network, sender, frame, (t,), sent_at=time.time())


@pytest.mark.integration
def test_transport_delivers_and_barrier_passes(transports):
    a, b, _, _ = _pair(transports)
    assert a.wait_ready(5.0) < 5.0 and b.wait_ready(5.0) < 5.0
    assert a.alive_neighbours() == {1} and b.alive_neighbours() == {0}
    n = a.publish(codec.encode(_msg(0, 0)))
    got = b.collect(0, 2.0)
    assert list(got) == [0] and got[0].frame == 0 and got[0].sender == 0
    assert n == a.counters()["bytes_per_link"]["0->1"]
    assert b.counters()["received_per_link"] == {"0->1": 1}
    assert len(b.latency_samples()) == 1 and 0 <= b.latency_samples()[0] < 1.0
    # a late message (frame already collected) is dropped and counted
    a.publish(codec.encode(_msg(0, 0)))
    a.publish(codec.encode(_msg(0, 1)))
    assert list(b.collect(1, 2.0)) == [0]
    assert wait_for(lambda: b.counters()["late"] == {"0->1": 1})


@pytest.mark.integration
def test_barrier_timeout_names_missing_neighbour(transports):
    from edge_node.runtime.transport import StartupError, ZenohTransport

    t = ZenohTransport("tb", 0, [1, 2], [ep(free_port())], [ep(free_port())])
    transports.append(t)
    t0 = time.monotonic()
    with pytest.raises(StartupError) as e:
        t.wait_ready(0.3)
    assert 0.3 <= time.monotonic() - t0 < 2.0
    assert e.value.missing == [1, 2]
    assert "neighbour(s) 1, 2" in str(e.value) and "no liveliness token" in str(e.value)


@pytest.mark.integration
def test_garbage_is_counted_not_fatal(transports):
    import zenoh

    from edge_node.runtime.transport import ZenohTransport, zenoh_config

    p0 = free_port()
    a = ZenohTransport("tg", 0, [1], [ep(p0)], [])
    transports.append(a)
    raw = zenoh.open(zenoh_config([], [ep(p0)]))
    try:
        pubs = {}
        for src in (1, 7):
            pubs[src] = raw.declare_publisher(link_key("tg", src, 0))
            assert wait_for(lambda: pubs[src].matching_status.matching)
        pubs[1].put(b"\xc1garbage")
        pubs[1].put(codec.encode(_msg(2, 0, "tg")))  # payload sender 2 on the link of 1
        pubs[1].put(codec.encode(_msg(1, 0, "other")))  # another network's message
        pubs[7].put(codec.encode(_msg(7, 0, "tg")))  # not a neighbour
        pubs[1].put(codec.encode(_msg(1, 0, "tg")))  # finally a good one
        assert wait_for(lambda: sum(a.counters()["rejected"].values()) == 4)
        assert a.counters()["rejected"] == {"forged_source": 1, "malformed": 1,
                                            "unknown_network": 1, "unknown_sender": 1}
        assert wait_for(lambda: a.counters()["messages_received"] == 1)
        got = a.collect(0, 2.0)  # (the raw session has no liveliness token: nothing to wait for)
        assert list(got) == [1] and got[1].sender == 1
    finally:
        raw.close()


@pytest.mark.integration
def test_liveliness_loss_is_seen_and_not_waited_for(transports):
    a, b, _, _ = _pair(transports, network="tl")
    a.wait_ready(5.0)
    assert a.alive_neighbours() == {1}
    b.close()
    assert wait_for(lambda: a.alive_neighbours() == set(), timeout=3.0)
    t0 = time.monotonic()
    assert a.collect(0, 5.0) == {}  # a dead neighbour is not waited for
    assert time.monotonic() - t0 < 0.5
    assert a.counters()["timeouts"] == {}


@pytest.mark.integration
def test_a_lost_message_costs_no_timeout_once_a_later_one_arrived(transports):
    a, b, _, _ = _pair(transports, network="tq")
    assert a.wait_ready(5.0) < 5.0 and b.wait_ready(5.0) < 5.0
    a.publish(codec.encode(_msg(0, 0, "tq")))
    assert list(b.collect(0, 5.0)) == [0]
    a.publish(codec.encode(_msg(0, 2, "tq")))  # frame 1's message is lost on the way
    assert wait_for(lambda: b.counters()["received_per_link"] == {"0->1": 2})
    t0 = time.monotonic()
    assert b.collect(1, 5.0) == {}  # the link is ordered: frame 1 will not come
    assert time.monotonic() - t0 < 0.5
    c = b.counters()
    assert c["lost"] == {"0->1": 1} and c["timeouts"] == {}
    assert list(b.collect(2, 5.0)) == [0]  # and frame 2's is used as usual


@pytest.mark.integration
def test_a_message_shown_lost_that_comes_after_all_is_used_and_not_counted_lost(transports):
    """Node 1 waits for frame 1 from neighbours 0 and 2. Node 0's frame 2 came first (a hostile
    or broken sender reorders), so its frame 1 looks lost; while node 1 still waits for node 2,
    node 0's frame 1 arrives after all. It is used, and not counted lost (the fuzz test's
    accounting of used hostile messages relied on that: it counted one message too few)."""
    import threading

    from edge_node.runtime.transport import ZenohTransport

    p0, p1, p2 = free_port(), free_port(), free_port()
    a = ZenohTransport("tr", 0, [1], [ep(p0)], [ep(p1)])
    b = ZenohTransport("tr", 1, [0, 2], [ep(p1)], [ep(p0), ep(p2)])
    c = ZenohTransport("tr", 2, [1], [ep(p2)], [ep(p1)])
    transports.extend([a, b, c])
    assert all(t.wait_ready(5.0) < 5.0 for t in (a, b, c))
    a.publish(codec.encode(_msg(0, 2, "tr")))
    assert wait_for(lambda: b.counters()["received_per_link"].get("0->1") == 1)
    got = {}
    waiting = threading.Thread(target=lambda: got.update(b.collect(1, 5.0)))
    waiting.start()
    time.sleep(0.3)  # node 1 has seen node 0's frame 2 and waits for node 2
    a.publish(codec.encode(_msg(0, 1, "tr")))
    assert wait_for(lambda: b.counters()["received_per_link"].get("0->1") == 2)
    c.publish(codec.encode(_msg(2, 1, "tr")))
    waiting.join(6.0)
    assert sorted(got) == [0, 2] and got[0].frame == 1
    assert b.counters()["lost"] == {} and b.counters()["timeouts"] == {}


@pytest.mark.integration
def test_drain_hands_over_each_message_once_up_to_k(transports):
    a, b, _, _ = _pair(transports, network="ta")
    a.wait_ready(5.0)
    for f in (3, 1, 5, 3):
        a.publish(codec.encode(_msg(0, f, "ta")))
    assert wait_for(lambda: b.counters()["messages_received"] == 4)
    assert b.counters()["duplicates"] == {"0->1": 1}
    assert [m.frame for m in b.drain(4)] == [1, 3]  # frame 5 is in b's future: kept for later
    assert b.drain(4) == []
    a.publish(codec.encode(_msg(0, 2, "ta")))  # reordered: the core ignores what is older
    assert wait_for(lambda: b.counters()["messages_received"] == 5)
    assert [m.frame for m in b.drain(6)] == [2, 5]


# -- the async loop ---------------------------------------------------------------------------------------
class RecordingCore(CameraNode):
    """The real core, recording what the loop hands to ``update``."""

    def update(self, inbox, stale_ok: bool = False):
        self.calls = getattr(self, "calls", [])
        inbox = list(inbox)
        self.calls.append((self.frame, stale_ok, [m.frame for m in inbox]))
        return super().update(inbox, stale_ok=stale_ok)


class FakeTransport:
    neighbours = (1,)

    def __init__(self):
        self.sent: list[bytes] = []
        self.inbox: dict[int, FrameMessage] = {}

    def publish(self, payload):
        self.sent.append(payload)
        return len(payload)

    def drain(self, k):
        out = [m for m in self.inbox.values() if m.frame <= k]
        self.inbox = {s: m for s, m in self.inbox.items() if m.frame > k}
        return out

    def collect(self, k, timeout, stop=None):
        out = {s: m for s, m in self.inbox.items() if m.frame == k}
        self.inbox = {s: m for s, m in self.inbox.items() if m.frame > k}
        return out

    def alive_neighbours(self):
        return {1}

    def counters(self):
        return {}


def test_async_loop_sends_on_events_only(tmp_path, export_dir):
    p = tmp_path / "cam0.toml"
    p.write_text(BASE.replace("EXPORT", str(export_dir)) + "[runtime]\nmode = \"async\"\n")
    cfg = load_node_config(p)
    node = RecordingCore(topdown_camera(0), [1], TrackerConfig(), "net")
    dets = lambda k: [det(2.0, 3.0, 1)] if k < 6 else []  # a person seen, then gone
    tp = FakeTransport()
    tp.inbox = {1: _msg(1, 3, "net")}
    loop = FrameLoop(cfg, node, dets, tp, mode="async", frames=45)
    st = loop.run()
    assert st.frames_done == 45 and st.frames_sent + st.frames_skipped == 45
    # seen (0-5) and coasting until dropped (its ell changes every frame: sent), then silent
    # but for the heartbeat
    assert st.frames_skipped > 10 and st.bytes_saved > 0
    assert st.frames_sent == len(tp.sent)
    sent = [codec.decode(b) for b in tp.sent]
    assert all(0 < m.sent_at <= time.time() for m in sent)
    gaps = np.diff([m.frame for m in sent])
    assert gaps.max() <= cfg.runtime.heartbeat_frames  # a heartbeat at least
    # every frame: stale_ok; a neighbour's message handed over once, when its frame comes
    assert all(stale for _, stale, _ in node.calls)
    assert [frames for _, _, frames in node.calls] == [[]] * 3 + [[3]] + [[]] * 41


def test_sync_loop_with_fake_transport_uses_frame_k_only(tmp_path, export_dir):
    p = tmp_path / "cam0.toml"
    p.write_text(BASE.replace("EXPORT", str(export_dir)))
    cfg = load_node_config(p)
    node = RecordingCore(topdown_camera(0), [1], TrackerConfig(), "net")
    tp = FakeTransport()
    tp.inbox = {1: _msg(1, 2, "net")}
    st = FrameLoop(cfg, node, lambda k: [], tp, mode="sync", frames=5).run()
    assert st.frames_sent == 5 and len(tp.sent) == 5
    assert [frames for _, _, frames in node.calls] == [[], [], [2], [], []]
    assert not any(stale for _, stale, _ in node.calls)


# -- processes --------------------------------------------------------------------------------------------
@pytest.mark.integration
def test_two_processes_equal_the_in_process_run(tmp_path, export_dir, procs):
    from sim_cluster.scenarios.detfiles import load_det_files
    from sim_cluster.network.inprocess import run_network
    from edge_node.formats.tracks import read_tracks

    out = tmp_path / "out"
    p0, p1 = free_port(), free_port()
    c0 = write_config(tmp_path / "cam0.toml", 0, [1], [ep(p0)], [ep(p1)], export_dir, out=out)
    c1 = write_config(tmp_path / "cam1.toml", 1, [0], [ep(p1)], [ep(p0)], export_dir, out=out)
    runs = [start_node(procs, c0), start_node(procs, c1)]
    for p in runs:
        _, err = p.communicate(timeout=60)
        assert p.returncode == 0, err

    ref = run_network(load_det_files(export_dir), {0: (1,), 1: (0,), 2: (), 3: ()},
                      TrackerConfig(), network="rt")
    for n in (0, 1):
        got = read_tracks(tracks_path(out, n), FRAMES)
        for k in range(FRAMES):
            want = ref.tracks[n][k]
            assert [t.id for t in got[k]] == [t.id for t in want], (n, k)
            for a, b in zip(got[k], want):
                assert np.allclose(a.x, b.x, atol=1e-6, rtol=0), (n, k, a.id)
                assert a.observed == b.observed and a.ell == b.ell
        c = json.loads((out / f"counters_node{n}.json").read_text())
        assert c["exit_code"] == 0 and c["frames_done"] == FRAMES
        assert c["messages_sent"] == FRAMES and c["messages_received"] == FRAMES
        assert c["rejected"] == {} and c["late"] == {} and c["timeouts"] == {}
        assert c["latency"]["count"] == FRAMES and c["latency"]["median_ms"] < 100
        s = json.loads((out / f"status_node{n}.json").read_text())
        assert s["finished"] and s["phase"] == "finished" and s["frame"] == FRAMES - 1
    # bytes on the wire equal the reference's encoded bytes (sent_at is a fixed-size float64)
    c0j = json.loads((out / "counters_node0.json").read_text())
    assert c0j["bytes_per_link"]["0->1"] == ref.wire.bytes_per_link[(0, 1)]


@pytest.mark.integration
def test_a_neighbour_missing_at_boot_costs_only_its_view(tmp_path, export_dir, procs):
    """Boot in any order: the start-up barrier waits ``startup_timeout_s``, then the node starts
    with the neighbours that are there (here: none), says which one is missing, and runs every
    frame; before, it exited with status 3 and its neighbours stopped."""
    c = write_config(tmp_path / "cam0.toml", 0, [1], [ep(free_port())], [ep(free_port())],
                     export_dir, out=tmp_path / "out")
    c.write_text(c.read_text().replace("startup_timeout_s = 20", "startup_timeout_s = 0.5"))
    t0 = time.monotonic()
    p = start_node(procs, c)
    _, err = p.communicate(timeout=60)
    assert p.returncode == 0, err
    assert "starting without neighbour(s) [1]" in err and "no liveliness token" in err
    s = json.loads((tmp_path / "out" / "status_node0.json").read_text())
    assert s["phase"] == "finished" and s["frames_done"] == FRAMES
    c = json.loads((tmp_path / "out" / "counters_node0.json").read_text())
    assert c["exit_code"] == 0 and 0.5 <= c["startup_s"] < 5.0
    assert time.monotonic() - t0 < 30


@pytest.mark.integration
def test_sigterm_finishes_the_frame_and_exits_0(tmp_path, export_dir, procs):
    out = tmp_path / "out"
    c = write_config(tmp_path / "cam0.toml", 0, [], [ep(free_port())], [], export_dir, out=out,
                     extra="")
    c.write_text(c.read_text().replace("sync_timeout_s = 5", "sync_timeout_s = 5\nfps = 10")
                 .replace("[output]", "[output]\nstatus_interval_s = 0.1"))
    p = start_node(procs, c)
    status = out / "status_node0.json"
    assert wait_for(lambda: status.exists() and json.loads(status.read_text())["frames_done"] >= 3,
                    timeout=20)
    p.send_signal(signal.SIGTERM)
    _, err = p.communicate(timeout=10)
    assert p.returncode == 0, err
    s = json.loads(status.read_text())
    assert s["phase"] == "stopped" and s["stopped"] and 3 <= s["frames_done"] < FRAMES
    rows = tracks_path(out, 0).read_text().splitlines()[1:]
    assert max(int(r.split(",")[0]) for r in rows) == s["frame"]


@pytest.mark.integration
def test_sigterm_during_startup_exits_0(tmp_path, export_dir, procs):
    out = tmp_path / "out"
    c = write_config(tmp_path / "cam0.toml", 0, [1], [ep(free_port())], [ep(free_port())],
                     export_dir, out=out)
    p = start_node(procs, c)
    status = out / "status_node0.json"
    assert wait_for(lambda: status.exists(), timeout=20)
    assert json.loads(status.read_text())["phase"] == "starting"
    p.send_signal(signal.SIGTERM)
    _, err = p.communicate(timeout=10)
    assert p.returncode == 0, err
    s = json.loads(status.read_text())
    assert s["phase"] == "stopped" and s["frames_done"] == 0 and s["exit_code"] == 0


@pytest.mark.integration
def test_a_node_id_already_alive_is_refused_and_a_restart_is_not():
    """A second process with an id already alive on the network is refused at start
    (``DuplicateNodeError``, exit status 5 from ``edge_node run``), whether it connects to the
    holder itself (its token) or only to a neighbour (who is asked: peers do not forward
    tokens). The holder goes on. Once the holder is gone (a restart), the id is free at once."""
    from edge_node.runtime.transport import DuplicateNodeError, ZenohTransport

    transports = []
    try:
        a, b, p0, p1 = _pair(transports, network="dup")
        with pytest.raises(DuplicateNodeError, match=r"id 0 is already alive .*node 1"):
            ZenohTransport("dup", 0, [1], [ep(free_port())], [ep(p1)], id_wait_s=0.3)
        with pytest.raises(DuplicateNodeError, match="its token"):
            ZenohTransport("dup", 0, [], [ep(free_port())], [ep(p0)], id_wait_s=0.3)
        assert wait_for(lambda: b.alive_neighbours() == {0}, 5.0)  # the holder is untouched
        a.close()
        assert wait_for(lambda: b.alive_neighbours() == set(), 5.0)
        t0 = time.monotonic()
        c = ZenohTransport("dup", 0, [1], [ep(free_port())], [ep(p1)])
        transports.append(c)
        assert time.monotonic() - t0 < 2.0
        assert wait_for(lambda: b.alive_neighbours() == {0}, 5.0)
    finally:
        for t in transports:
            t.close()



class _PeerReplies:
    """A Zenoh session whose peers (node 1) say whether node 0 is alive: ``pattern`` gives,
    poll by poll, whether the answer arrives (True), or is late and missed (False)."""

    def __init__(self, pattern):
        self.pattern, self.polls = list(pattern), 0

    def liveliness(self):
        return self

    def get(self, key, timeout):
        from types import SimpleNamespace

        if "/alive/" in str(key):  # the liveliness query: no token of ours reaches us
            return []
        answered = self.pattern[min(self.polls, len(self.pattern) - 1)]
        self.polls += 1
        payload = json.dumps({"node": 1, "alive": [0], "frame": 10}).encode()
        ok = SimpleNamespace(payload=SimpleNamespace(to_bytes=lambda: payload))
        return [SimpleNamespace(ok=ok)] if answered else []


def _checker(session):
    from edge_node.runtime.transport import ZenohTransport

    t = object.__new__(ZenohTransport)
    t.network, t.node, t._neigh, t._self_seen = "dup", 0, {1}, False
    t.session, t.running_at_start = session, {}
    return t


@pytest.mark.parametrize("pattern, refused", [
    ([True, False] * 100, True),  # every other answer late: the holder is there all along
    ([True, True, False, False, True] * 40, True),  # two late in a row
    ([True] * 3 + [False] * 200, False),  # the holder is gone (a restart): the id is free
    ([False] * 200, False),  # nobody holds it
])
def test_the_id_check_does_not_take_one_late_answer_for_a_free_id(pattern, refused):
    """``_id_holders``: a holder seen is taken to be gone only when nobody has said it is alive
    for ``ID_SETTLE_S`` and ``ID_MISSES`` polls in a row; before, the first poll past the settle
    time whose answer came late freed the id (half the duplicates of a busy cluster got in)."""
    from edge_node.runtime import transport

    session = _PeerReplies(pattern)
    t0 = time.monotonic()
    holders = _checker(session)._id_holders(wait_s=1.5, since=t0)
    took = time.monotonic() - t0
    assert holders == (["node 1"] if refused else [])
    if refused:
        assert took >= 1.5  # it waited the lease for a previous life to vanish
    else:
        assert took >= transport.ID_SETTLE_S and session.polls >= transport.ID_MISSES


def test_a_camera_process_keeps_large_blocks_out_of_its_heap():
    """``steady_allocator`` (called as a camera process starts) fixes glibc's mmap threshold:
    a freed array of a few MB (a source's chunk) leaves the process at once instead of raising
    the threshold and staying in the heap until a trim. Run in fresh interpreters: with the
    default, the same array freed twice leaves ~4 MB free in the heap; fixed, none."""
    code = ("import sys, numpy as np\n"
            "from edge_node.runtime.memory import heap, steady_allocator\n"
            "fixed = sys.argv[1] == 'fixed' and steady_allocator()\n"
            "for _ in range(3):\n"
            "    a = np.ones(500_000); del a\n"
            "print(int(fixed), heap()['free_mb'])\n")
    free = {}
    for mode in ("default", "fixed"):
        out = subprocess.run([sys.executable, "-c", code, mode], capture_output=True, text=True,
                             check=True, cwd=Path(__file__).resolve().parents[1]).stdout.split()
        if mode == "fixed" and out[0] != "1":
            pytest.skip("not glibc: no mallopt")
        free[mode] = float(out[1])
    assert free["default"] > 3.0  # the 4 MB array stayed in the heap after its free
    assert free["fixed"] < 1.0


def test_a_camera_process_freezes_its_start_up_objects_out_of_the_collector():
    """``freeze_startup`` (called before a camera process's first frame) leaves the objects of
    its imports to reference counting alone: a later full collection does not traverse them.
    Run in a fresh interpreter, not this test process."""
    code = ("import gc, numpy, edge_node.cli\n"
            "from edge_node.runtime.memory import freeze_startup\n"
            "n = len(gc.get_objects())\n"
            "freeze_startup()\n"
            "print(n, gc.get_freeze_count(), len(gc.get_objects()))\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                         cwd=Path(__file__).resolve().parents[1]).stdout.split()
    before, frozen, tracked = map(int, out)
    assert before > 10_000  # a real process's worth of objects
    assert frozen >= 0.9 * before  # all but the garbage the collection freed
    assert tracked < 100  # what the collector still traverses
