"""Rerun view (issue 5): ``--rerun`` specs, the ``[viz]`` config table, recordings read back.

A short in-process run and a 2-node process cluster save ``.rrd`` files; Rerun's own reader
(``rerun.chunk.RrdReader``) reads them back: one recording, the entity paths, the number of
frames on the ``frame`` timeline, and per node and frame the track ids equal to the track files.
``--rerun off`` must not import Rerun at all.
"""
import json
import subprocess
import sys
from collections import defaultdict
from pathlib import Path

import numpy as np
import pytest

from edge_node.core.types import Track
from edge_node.formats.tracks import read_tracks
from edge_node.viz import (NullSink, VizSpecError, disagreement, fov_polygon, make_sink,
                           parse_spec, track_colour, track_label)

BIN = Path(sys.executable).parent
FRAMES = 40


# -- specs and config ---------------------------------------------------------------------------
def test_parse_spec():
    assert parse_spec(None).kind == "off" and not parse_spec("off").enabled
    assert str(parse_spec(["save", "a b/x.rrd"])) == "save a b/x.rrd"
    assert parse_spec("connect").arg == "rerun+http://127.0.0.1:9876/proxy"
    assert parse_spec("connect 10.0.0.5:9000").arg == "rerun+http://10.0.0.5:9000/proxy"
    assert parse_spec("serve 8080").arg == "8080"
    for bad in ("", "save", "spawn now", "connect nowhere", "serve x", "show"):
        with pytest.raises(VizSpecError):
            parse_spec(bad)
    assert isinstance(make_sink("off"), NullSink)


def _cfg(tmp_path, viz: str) -> Path:
    p = tmp_path / "cam0.toml"
    p.write_text('node = 0\nnetwork = "t"\n[source]\nkind = "scenario"\nscenario = "terrace-sim"\n'
                 f'frames = 5\n[viz]\n{viz}\n')
    return p


@pytest.mark.parametrize("viz, field", [('rerun = "show"', "viz.rerun"),
                                        ('rerun = "save"', "viz.rerun"),
                                        ("area = [0, 1, 2]", "viz.area"),
                                        ("area = [1, 0, 0, 1]", "viz.area"),
                                        ("blueprint = 1", "viz.blueprint"),
                                        ('colour = "red"', "viz.colour")])
def test_viz_config_errors_name_the_field(tmp_path, viz, field):
    from edge_node.runtime.config import NodeConfigError, load_node_config

    with pytest.raises(NodeConfigError) as e:
        load_node_config(_cfg(tmp_path, viz))
    assert e.value.field == field, str(e.value)


def test_viz_config_resolves_save_path(tmp_path):
    from edge_node.runtime.config import load_node_config

    cfg = load_node_config(_cfg(tmp_path, 'rerun = "save out/n0.rrd"\nrecording_id = "r1"'))
    assert cfg.viz.rerun == f"save {tmp_path / 'out' / 'n0.rrd'}"
    assert cfg.viz.recording_id == "r1" and cfg.to_dict()["viz"]["blueprint"] is True


@pytest.mark.integration
def test_edge_node_cli_rejects_bad_rerun(tmp_path):
    r = subprocess.run([str(BIN / "edge_node"), "run", "--config", str(_cfg(tmp_path, "")),
                        "--rerun", "show"], capture_output=True, text=True, timeout=60)
    assert r.returncode == 2 and "--rerun" in r.stderr, r.stderr


# -- pure helpers --------------------------------------------------------------------------------
@pytest.mark.integration
def test_track_colour_is_stable_and_spread():
    assert track_colour((2, 17)) == track_colour((2, 17))
    # the same in another process (no salted hash)
    out = subprocess.run([sys.executable, "-c", "from edge_node.viz import track_colour;"
                          "print(list(track_colour((2, 17))))"], capture_output=True, text=True)
    assert json.loads(out.stdout) == list(track_colour((2, 17)))
    colours = {track_colour((c, n)) for c in range(4) for n in range(30)}
    assert len(colours) > 100
    assert track_label((3, 12)) == "3:12"


def _track(tid, x, y):
    return Track(tid, 0, np.array([x, y, 0.5, 1.7, 0, 0]), np.eye(6), True, 0)


def test_disagreement_is_max_pairwise_spread():
    d = disagreement({0: [_track((0, 1), 0, 0), _track((0, 2), 5, 5)],
                      1: [_track((0, 1), 3, 4)],
                      2: [_track((0, 1), 0, 1), _track((1, 0), 9, 9)]})
    assert d == {(0, 1): pytest.approx(5.0)}  # (0, 2) and (1, 0) are held by one node only


def test_fov_polygon_is_clipped_to_the_area():
    from sim_cluster.scenarios.loader import load_scenario

    data = load_scenario("terrace-sim", seed=0, frames=2)
    for cam in data.cameras:
        poly = fov_polygon(cam, data.area, margin=0.25)
        assert len(poly) >= 3
        assert poly[:, 0].min() >= -2.5 - 1e-9 and poly[:, 0].max() <= 12.5 + 1e-9
        assert len(fov_polygon(cam)) >= 3  # without an area: clipped around the camera


# -- recordings read back ------------------------------------------------------------------------
def read_rrd(path: Path):
    """``(recordings, blueprints, entity -> [record batches])`` with Rerun's own reader."""
    from rerun.chunk import RrdReader

    r = RrdReader(str(path))
    ent = defaultdict(list)
    for c in r.stream().to_chunks():
        ent[c.entity_path].append(c.to_record_batch())
    return r.recordings(), r.blueprints(), ent


def frames_of(batches) -> set[int]:
    return {f for b in batches if "frame" in b.schema.names for f in b.column("frame").to_pylist()}


def labels_per_frame(batches, column="LineStrips2D:labels") -> dict[int, set[str]]:
    out = {}
    for b in batches:
        if "frame" not in b.schema.names:
            continue
        for k, labels in zip(b.column("frame").to_pylist(), b.column(column).to_pylist()):
            out[k] = set(labels or [])
    return out


def check_recording(rrd: Path, csvs: dict[int, Path], cameras: int, *, live: bool):
    recs, blueprints, ent = read_rrd(rrd)
    assert len(recs) == 1 and recs[0].application_id == "dmtt"  # one recording, all nodes
    assert blueprints, "no blueprint in the file"
    paths = set(ent)
    world = {"/world/area", "/world/ground_truth", "/world/disagreement/max",
             "/world/disagreement/mean"}
    world |= {f"/world/cameras/{c}/{x}" for c in range(cameras) for x in ("fov", "position")}
    assert world <= paths, world - paths
    assert frames_of(ent["/world/ground_truth"]) == set(range(FRAMES))
    for node, csv in csvs.items():
        base = f"/nodes/{node}"
        need = {f"{base}/tracks", f"{base}/trails", f"{base}/measurements",
                f"{base}/stats/active_trackers"}
        if live:
            need |= {f"{base}/stats/{s}" for s in ("bytes_sent", "dropped", "rejected", "timeouts")}
        assert need <= paths, need - paths
        assert frames_of(ent[f"{base}/tracks"]) == set(range(FRAMES))
        got = labels_per_frame(ent[f"{base}/tracks"])
        ref = read_tracks(csv, FRAMES)
        for k in range(FRAMES):
            assert got[k] == {track_label(t.id) for t in ref[k]}, (node, k)
        assert any(got.values())
        if live:  # processes log wall-clock time too
            assert "wall_time" in ent[f"{base}/tracks"][0].schema.names


def test_run_saves_one_recording(tmp_path):
    from sim_cluster.cli import main

    rrd = tmp_path / "view" / "run.rrd"
    assert main(["run", "--scenario", "terrace-sim", "--frames", str(FRAMES), "--topology",
                 "chain", "--out", str(tmp_path), "--quiet", "--rerun", "save", str(rrd)]) == 0
    check_recording(rrd, {i: tmp_path / f"tracks_node{i}.csv" for i in range(4)}, 4, live=False)


@pytest.mark.integration
def test_cluster_up_saves_one_merged_recording(tmp_path):
    rrd = tmp_path / "cluster.rrd"
    r = subprocess.run([str(BIN / "sim_cluster"), "up", "--scenario", "terrace-sim", "--nodes", "2",
                        "--frames", str(FRAMES), "--out", str(tmp_path / "c"), "--quiet",
                        "--sync-timeout", "30", "--rerun", "save", str(rrd)],
                       capture_output=True, text=True, timeout=240)
    assert r.returncode == 0, r.stdout + r.stderr
    assert f"rerun {rrd}" in r.stdout  # the command that opens it
    parts = sorted(p.name for p in (tmp_path / "c" / "rerun").glob("*.rrd"))
    assert parts == ["node0.rrd", "node1.rrd", "world.rrd"]
    csvs = {i: tmp_path / "c" / "nodes" / f"tracks_node{i}.csv" for i in range(2)}
    check_recording(rrd, csvs, 2, live=True)
    _, _, ent = read_rrd(rrd)
    sent = [v for b in ent["/nodes/0/stats/bytes_sent"] if "frame" in b.schema.names
            for v in b.column("Scalars:scalars").to_pylist()]
    assert sent[-1][0] > 0 and sent == sorted(sent)  # cumulative bytes


@pytest.mark.integration
def test_a_cluster_with_an_isolated_node_finishes_and_merges_its_recording(tmp_path):
    """A node without neighbours has no latency samples: the launcher's latency summary used
    to end ``up`` in a TypeError after the run, before the recording was merged."""
    edges = tmp_path / "edges.txt"
    edges.write_text("0 1\n")  # node 2 alone
    rrd = tmp_path / "cluster.rrd"
    r = subprocess.run([str(BIN / "sim_cluster"), "up", "--scenario", "lab-sim", "--nodes", "3",
                        "--topology", str(edges), "--frames", str(FRAMES), "--quiet",
                        "--out", str(tmp_path / "c"), "--rerun", "save", str(rrd)],
                       capture_output=True, text=True, timeout=240)
    assert r.returncode == 0, r.stdout + r.stderr
    line = next(x for x in r.stdout.splitlines() if x.startswith("one-hop latency"))
    assert line.startswith("one-hop latency: median of node medians ")
    assert line.endswith(" ms (no samples: node 2)")
    csvs = {i: tmp_path / "c" / "nodes" / f"tracks_node{i}.csv" for i in range(3)}
    check_recording(rrd, csvs, 3, live=True)


@pytest.mark.integration
def test_rerun_off_imports_no_rerun(tmp_path):
    code = f"""
import sys
from sim_cluster.cli import main
assert main(["run", "--scenario", "terrace-sim", "--frames", "5", "--out", {str(tmp_path)!r},
             "--quiet", "--rerun", "off"]) == 0
import edge_node.runtime.loop, edge_node.viz
from edge_node.runtime.config import load_node_config
from edge_node.viz import open_node_sink
cfg = load_node_config({str(_cfg(tmp_path, ''))!r})
assert type(open_node_sink(cfg, None)).__name__ == "NullSink"
bad = sorted(m for m in sys.modules if m == "rerun" or m.startswith(("rerun.", "rerun_")))
print("RERUN", bad)
"""
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert "RERUN []" in r.stdout, r.stdout


@pytest.mark.integration
def test_cluster_up_streams_to_a_running_viewer(tmp_path):
    """``--rerun connect ADDR``: the launcher and every node stream into one recording of a
    running Rerun server (here a headless one that saves what it receives)."""
    import os
    import signal
    import socket
    import time

    import rerun_cli

    from tests.loopback import free_port

    port = free_port()
    got = tmp_path / "received.rrd"
    server = subprocess.Popen([str(Path(rerun_cli.__file__).parent / "rerun"), "--bind",
                               "127.0.0.1", "--port", str(port), "--save", str(got)],
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        deadline = time.time() + 20
        while True:  # wait for the server to listen
            try:
                socket.create_connection(("127.0.0.1", port), timeout=1).close()
                break
            except OSError:
                assert time.time() < deadline, "rerun server did not start"
                time.sleep(0.2)
        r = subprocess.run([str(BIN / "sim_cluster"), "up", "--scenario", "terrace-sim",
                            "--nodes", "2", "--frames", "20", "--out", str(tmp_path / "c"),
                            "--quiet", "--sync-timeout", "30", "--rerun", "connect",
                            f"127.0.0.1:{port}"], capture_output=True, text=True, timeout=240)
        assert r.returncode == 0, r.stdout + r.stderr
        time.sleep(1.0)
    finally:
        server.send_signal(signal.SIGINT)
        try:
            server.wait(10)
        except subprocess.TimeoutExpired:
            os.kill(server.pid, signal.SIGKILL)
            server.wait()
    from rerun.chunk import RrdReader

    import warnings

    with warnings.catch_warnings():  # a streamed file has no footer: read it with stream()
        warnings.simplefilter("ignore")
        reader = RrdReader(str(got))
    recs = reader.recordings()
    assert len(recs) == 1 and recs[0].application_id == "dmtt"
    paths = {c.entity_path for c in reader.stream().to_chunks()}
    assert {"/nodes/0/tracks", "/nodes/1/tracks", "/world/ground_truth",
            "/world/disagreement/max", "/world/cameras/1/fov"} <= paths


def _unused_port() -> int:
    from tests.loopback import free_port

    return free_port()


def test_closing_a_sink_whose_viewer_cannot_be_reached_is_bounded_and_does_not_raise(monkeypatch):
    """``connect`` to an address nothing listens on: the flush gives up after
    ``FLUSH_TIMEOUT_S`` and says so (``False``); it used to wait forever (a finished node never
    exited) or, interrupted, raise past the code that writes a node's last files."""
    import time

    from edge_node.viz import rerun_log

    monkeypatch.setattr(rerun_log, "FLUSH_TIMEOUT_S", 1.0)
    sink = make_sink(f"connect 127.0.0.1:{_unused_port()}")
    sink.log_frame(0, [_track((0, 1), 1.0, 2.0)], node=0)
    t = time.monotonic()
    assert sink.close() is False
    # the bounded flush, then Rerun's own shutdown of the connection (up to 5 s)
    assert time.monotonic() - t < rerun_log.FLUSH_TIMEOUT_S + 10
    assert NullSink().close() is True


@pytest.mark.integration
@pytest.mark.slow  # each node waits out its sink's flush timeout at exit
def test_a_cluster_streaming_to_no_viewer_finishes_and_stops_every_node(tmp_path):
    """``sim_cluster up --rerun connect ADDR`` with nothing at ADDR: the run ends as without
    Rerun (summary, every node's counters with exit code 0) and no node is left running; the
    nodes used to hang at exit and ignore SIGTERM, and Ctrl-C left them orphaned."""
    import json
    import os

    out = tmp_path / "c"
    r = subprocess.run([str(BIN / "sim_cluster"), "up", "--scenario", "terrace-sim", "--nodes", "2",
                        "--frames", "10", "--out", str(out), "--quiet", "--sync-timeout", "30",
                        "--rerun", "connect", f"127.0.0.1:{_unused_port()}"],
                       capture_output=True, text=True, timeout=240)
    assert r.returncode == 0, r.stdout + r.stderr
    assert (out / "summary.json").exists()
    assert "the data not delivered is dropped" in r.stderr
    for i in range(2):
        counters = json.loads((out / "nodes" / f"counters_node{i}.json").read_text())
        assert counters["exit_code"] == 0 and counters["frames_done"] == 10
        pid = json.loads((out / "nodes" / f"status_node{i}.json").read_text())["pid"]
        with pytest.raises(ProcessLookupError):
            os.kill(pid, 0)


@pytest.mark.integration
@pytest.mark.slow  # each node waits out its sink's flush timeout at exit
def test_down_stops_a_detached_cluster_streaming_to_no_viewer_and_keeps_its_files(tmp_path):
    """``up --detach --rerun connect ADDR`` with nothing at ADDR, then ``down``: every node is
    gone when ``down`` returns (it said 'could not be stopped': it looked right after SIGKILL),
    and each node wrote its counters and status before closing its sink (a node waiting on an
    unreachable viewer outlives the SIGTERM grace)."""
    import json
    import time

    out = tmp_path / "c"
    r = subprocess.run([str(BIN / "sim_cluster"), "up", "--scenario", "terrace-sim", "--nodes", "2",
                        "--frames", "600", "--fps", "25", "--out", str(out), "--quiet", "--detach",
                        "--rerun", "connect", f"127.0.0.1:{_unused_port()}"],
                       capture_output=True, text=True, timeout=240)
    assert r.returncode == 0, r.stdout + r.stderr
    status = [out / "nodes" / f"status_node{i}.json" for i in range(2)]
    deadline = time.time() + 60
    while not all(p.exists() and json.loads(p.read_text()).get("frames_done", 0) > 5 for p in status):
        assert time.time() < deadline, "the nodes did not start"
        time.sleep(0.2)
    pids = [json.loads(p.read_text())["pid"] for p in status]
    d = subprocess.run([str(BIN / "sim_cluster"), "down", "--out", str(out)],
                       capture_output=True, text=True, timeout=60)
    assert d.returncode == 0, d.stdout + d.stderr
    from sim_cluster.cluster.processes import alive  # (a zombie is not alive)

    for i, pid in enumerate(pids):
        assert not alive(pid)
        counters = json.loads((out / "nodes" / f"counters_node{i}.json").read_text())
        assert counters["exit_code"] == 0 and counters["stopped"] is True
        assert counters["viz_dropped"] >= 0  # counted (edge_node/viz/live.py)
        assert json.loads(status[i].read_text())["phase"] == "stopped"



class _Recorder:
    """A sink that records its calls; ``gate``: each call waits for it (a stuck viewer)."""

    def __init__(self, gate=None):
        import threading

        from edge_node.viz import VizSpec

        self.spec, self.url, self.calls, self.gate, self.closed = VizSpec("connect", "x"), None, [], gate, 0
        self.entered = threading.Event()

    def log_frame(self, k, tracks, **kw):
        self.entered.set()
        if self.gate is not None:
            self.gate.wait()
        self.calls.append(k)

    def close(self):
        self.closed += 1
        return True


def test_a_live_sink_delivers_every_call_in_order_to_a_viewer_that_keeps_up():
    from edge_node.viz.live import LiveSink

    rec = _Recorder()
    live = LiveSink(rec, depth=1000, timeout=5.0)
    for k in range(500):
        live.log_frame(k, [])
    assert live.close() is True
    assert rec.calls == list(range(500)) and rec.closed == 1 and live.dropped == 0


def test_a_live_sink_never_blocks_its_caller_on_a_stuck_viewer():
    """Rerun blocks ``log`` once its buffer for an unreachable viewer is full: the frame loop
    must go on. Calls beyond the queue are dropped and counted; ``close`` gives up after its
    timeout and says so."""
    import threading
    import time

    from edge_node.viz.live import LiveSink

    gate = threading.Event()  # never set: the first call blocks for good
    rec = _Recorder(gate)
    live = LiveSink(rec, depth=8, timeout=0.5)
    t = time.monotonic()
    live.log_frame(0, [])
    assert rec.entered.wait(5.0)  # the logging thread is in the sink, stuck
    for k in range(1, 1000):
        live.log_frame(k, [])
    assert time.monotonic() - t < 0.5  # the caller never waited
    assert live.dropped == 1000 - 8 - 1  # the queue's 8 and the one stuck in the sink
    t = time.monotonic()
    assert live.close() is False
    assert 0.4 < time.monotonic() - t < 2.0 and rec.closed == 0
    gate.set()
