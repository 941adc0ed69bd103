"""No zombie nodes (real processes on loopback): a node frozen for longer than its inbox window
catches up, a full disk makes a node ``degraded`` that keeps tracking and sending and writes whole
rows, a finished cluster is not restarted into duplicate rows, and a camera absent at boot
holds up only its own neighbours. The figures against the goals come from ``sim_cluster probe``
(README, "Faults"); these tests check the behaviour with margins a busy machine keeps."""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
import uuid
from collections import Counter
from pathlib import Path

import pytest

from edge_node.formats.tracks import iter_tracks
from sim_cluster.cluster.processes import alive
from sim_cluster.cluster.state import ClusterState

pytestmark = pytest.mark.integration

EXE = str(Path(sys.executable).parent / "sim_cluster")


def up(out: Path, *args: str, timeout: float = 120) -> subprocess.CompletedProcess:
    return subprocess.run([EXE, "up", "--scenario", "terrace-sim", "--out", str(out), "--quiet",
                           *args], capture_output=True, text=True, timeout=timeout)


def status(out: Path, node: int) -> dict:
    try:
        return json.loads((out / "nodes" / f"status_node{node}.json").read_text())
    except (OSError, ValueError):
        return {}


def counters(out: Path, node: int) -> dict:
    return json.loads((out / "nodes" / f"counters_node{node}.json").read_text())


def wait(pred, timeout: float, every: float = 0.1) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if pred():
            return True
        time.sleep(every)
    return False


def frame(out: Path, node: int) -> int:
    f = status(out, node).get("frame")
    return -1 if f is None else int(f)


def down(out: Path) -> None:
    subprocess.run([EXE, "down", "--out", str(out)], capture_output=True, text=True, timeout=60)


def pids(out: Path) -> list[int]:
    return [p.pid for p in ClusterState.load(out).nodes.values()]


def rows(path: Path) -> list[tuple[int, tuple[int, int]]]:
    """(frame, id) of every row; the file must be whole (ends with a row's end)."""
    assert path.read_bytes().endswith(b"\r\n"), f"{path} ends mid-row"
    return [(t.frame, t.id) for t in iter_tracks(path)]


@pytest.mark.slow  # a paced 3-node cluster per mode, frozen 7 s, then watched catching up
@pytest.mark.parametrize("mode", ["sync", "async"])
def test_a_node_frozen_past_the_inbox_window_catches_up(tmp_path, mode):
    """SIGSTOP the middle node of a paced chain for longer than its inbox keeps frames ahead
    (256 frames, 5.1 s at 50 fps): after SIGCONT it learns the network's frame and skips there
    (before, it never caught up: 2,622 frames behind 78 s after a 30 s freeze)."""
    out = tmp_path / mode
    fps = 50
    r = up(out, "--nodes", "3", "--topology", "chain", "--mode", mode, "--fps", str(fps),
           "--frames", "100000", "--detach")
    assert r.returncode == 0, r.stderr
    try:
        assert wait(lambda: min(frame(out, i) for i in range(3)) > fps, 60)
        p1 = pids(out)[1]
        os.kill(p1, signal.SIGSTOP)
        try:
            time.sleep(7.0)
        finally:
            os.kill(p1, signal.SIGCONT)
        behind = lambda: min(frame(out, 0), frame(out, 2)) - frame(out, 1)  # noqa: E731
        assert wait(lambda: behind() <= fps, 30), (frame(out, 0), frame(out, 1), frame(out, 2))
        # level, and staying level (status files are written every 0.5 s: a second of frames)
        time.sleep(2.0)
        assert behind() <= fps and status(out, 1).get("catch_ups", 0) >= 1
        assert status(out, 1)["frames_skipped_behind"] > 256
    finally:
        down(out)
    assert counters(out, 1)["exit_code"] == 0


@pytest.fixture
def small_disk(tmp_path):
    mnt = tmp_path / "c" / "nodes"
    mnt.mkdir(parents=True)
    r = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=2m", "tmpfs", str(mnt)],
                       capture_output=True, text=True)
    if r.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs to fill (needs root): {r.stderr.strip()}")
    try:
        yield mnt
    finally:
        subprocess.run(["umount", "-l", str(mnt)], capture_output=True)


def _fill(mnt: Path) -> Path:
    filler = mnt / f"filler-{uuid.uuid4().hex}"
    fd = os.open(filler, os.O_WRONLY | os.O_CREAT)
    try:
        while True:
            os.write(fd, b"\0" * 512)
    except OSError:
        pass
    finally:
        os.close(fd)
    return filler


def test_a_full_disk_makes_a_degraded_node_that_keeps_tracking(tmp_path, small_disk):
    """The nodes' output folder on a small disk that fills mid-run: they say ``degraded``, keep
    tracking and sending, and once space is back write every frame they held, whole rows only;
    SIGTERM ends them cleanly (before: an internal error, a hung process that looked alive, a
    track file ending mid-row)."""
    out = tmp_path / "c"
    r = up(out, "--nodes", "2", "--topology", "chain", "--fps", "25", "--frames", "100000",
           "--detach")
    assert r.returncode == 0, r.stderr
    try:
        assert wait(lambda: min(frame(out, i) for i in range(2)) > 25, 60)
        filler = _fill(small_disk)
        try:
            assert wait(lambda: all(status(out, i).get("phase") == "degraded" for i in range(2)),
                        20), [status(out, i).get("phase") for i in range(2)]
            f0, sent0 = frame(out, 0), status(out, 0)["messages_sent"]
            assert wait(lambda: frame(out, 0) > f0 + 25, 20)  # tracking on
            assert status(out, 0)["messages_sent"] > sent0  # and sending
            st = subprocess.run([EXE, "status", "--out", str(out)], capture_output=True,
                                text=True).stdout
            assert "degraded" in st and "output failing" in st
        finally:
            filler.unlink()
        assert wait(lambda: all(status(out, i).get("phase") == "running" for i in range(2)), 60)
    finally:
        down(out)
    for i in range(2):
        c = counters(out, i)
        assert c["exit_code"] == 0 and c["output"]["failures"] > 0
        got = rows(out / "nodes" / f"tracks_node{i}.csv")
        assert max(Counter(got).values()) == 1  # no (frame, id) twice
        frames = sorted({k for k, _ in got})
        assert frames[-1] - frames[0] + 1 >= len(frames) > 100
        assert c["output"]["track_frames_dropped"] == 0
    assert not list(small_disk.glob(".*.tmp"))


def test_restart_of_a_finished_cluster_is_refused_and_duplicates_nothing(tmp_path):
    out = tmp_path / "f"
    r = up(out, "--nodes", "2", "--topology", "chain", "--frames", "40")
    assert r.returncode == 0, r.stderr
    before = (out / "nodes" / "tracks_node1.csv").read_bytes()
    r = subprocess.run([EXE, "restart", "1", "--out", str(out)], capture_output=True, text=True,
                       timeout=60)
    assert r.returncode == 2 and "finished its run" in r.stderr and len(r.stderr.splitlines()) == 1
    # the node itself, run again into its finished file: nothing to do, nothing appended
    cfg = ClusterState.load(out).nodes["1"].config
    p = subprocess.run([sys.executable, "-m", "edge_node.cli", "run", "--config", cfg, "--join",
                        "--log-level", "WARNING"], capture_output=True, text=True, timeout=60)
    assert p.returncode == 0 and "nothing to do" in p.stderr
    assert (out / "nodes" / "tracks_node1.csv").read_bytes() == before
    assert not any(alive(pid) for pid in pids(out))


def test_a_camera_absent_at_boot_holds_up_only_its_neighbours(tmp_path):
    """A paced chain 0-1-2-3 whose camera 3 never comes: node 2 waits for it (at most its
    startup_timeout_s, 5 s) and node 0, which does not border it, runs at camera rate meanwhile
    (before, every node waited for the absent camera: node 0 stalled at its first frames until
    node 2's start-up timeout)."""
    from sim_cluster.cluster.launcher import Cluster
    from sim_cluster.cluster.processes import spawn, terminate

    out = tmp_path / "b"
    c = Cluster.create(out, network="boot", scenario="terrace-sim", seed=0, frames=100000,
                       mode="sync", topology="chain", nodes=4)
    c.write_configs(config="dkf+lda+dtm", sync_timeout_s=1.0, startup_timeout_s=5.0, fps=25.0)
    procs = [spawn(c.state.nodes[str(i)].config, c.state.nodes[str(i)].log) for i in range(3)]
    try:
        seen: dict[str, float] = {}

        def progress():
            now = time.monotonic()
            if frame(out, 0) >= 25:
                seen.setdefault("node 0 at frame 25", now)
            if frame(out, 2) >= 0:
                seen.setdefault("node 2 at frame 0", now)
            return len(seen) == 2

        assert wait(progress, 60, every=0.05), seen
        assert seen["node 0 at frame 25"] < seen["node 2 at frame 0"], seen
        assert wait(lambda: frame(out, 2) > 50, 30)
    finally:
        terminate([p.pid for p in procs])
        for p in procs:
            p.wait()
