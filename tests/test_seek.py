"""A simulated camera after its node skipped ahead (``Source.seek``): the world walks to the
new frame in a thread while the node runs on level with the network, its frames without an
image until the walk is there, and every frame it does read is the frame of a run without a
seek."""
from __future__ import annotations

import threading
import time

import numpy as np

from edge_node.core.config import TrackerConfig
from edge_node.core.node import CameraNode
from edge_node.runtime.config import load_node_config
from edge_node.runtime.loop import FrameLoop
from edge_node.runtime.sources import Source
from sim_cluster.scenarios.loader import open_scenario
from sim_cluster.scenarios.replay import SeekingCamera
from tests.fakes import det, topdown_camera
from tests.loopback import export_scenario
from tests.test_node_config import BASE
from tests.test_runtime import FakeTransport

GATE_S = 30.0  # the longest a gated walk may wait for the loop (a hang fails, not blocks)


class GatedWorld:
    """``read(k)``: one detection at x = k; a frame beyond ``free`` waits for ``gate`` (a walk
    that takes as long as the test wants). Records which frames were made, in which thread."""

    def __init__(self, free: int):
        self.free, self.gate, self.made = free, threading.Event(), []

    def __call__(self, k: int):
        if k > self.free and not self.gate.wait(GATE_S):
            raise TimeoutError(f"frame {k}: the gate stayed shut")
        self.made.append((k, threading.current_thread().name))
        return [det(float(k), 0.0, 1)]


def test_reads_wait_for_nobody_while_the_walk_runs_and_then_give_the_frames():
    world = GatedWorld(free=10)
    cam = SeekingCamera(world)
    src = Source(topdown_camera(0), 100, 25.0, 1.0, cam, seek=cam.seek)
    assert src(3)[0].box[0] == det(3.0, 0.0, 1).box[0]
    src.seek(50)
    assert [src(k) for k in range(50, 55)] == [[]] * 5  # the walk is held: no image, no wait
    assert src.frames_without_image == 5
    world.gate.set()
    cam._walker.join(GATE_S)
    # the walk chased the newest frame asked for (54), in its own thread
    assert [m for m in world.made if m[1] == "scenario-seek"][-1][0] == 54
    assert src(55)[0].box[0] == det(55.0, 0.0, 1).box[0] and src.frames_without_image == 5


def test_a_failed_walk_is_the_next_reads_error():
    def read(k):
        if k > 5:
            raise OSError("scenario file gone")
        return []
    cam = SeekingCamera(read)
    cam.seek(40)
    cam._walker.join(GATE_S)
    try:
        cam(41)
    except OSError as e:
        assert "scenario file gone" in str(e)
    else:
        raise AssertionError("the walk's error was swallowed")


def test_a_seeking_scenario_camera_gives_the_frames_of_a_straight_read():
    """terrace-sim camera 1 after a seek to frame 730 (a walk through 7 chunks) against the
    same scenario read straight through: the same detections, bit for bit."""
    straight = open_scenario("terrace-sim", seed=0, frames=2000).camera(1)
    cam = SeekingCamera(open_scenario("terrace-sim", seed=0, frames=2000).camera(1))
    cam(0)
    cam.seek(730)
    k = 730
    while cam(k) is None:  # frames the node predicts through, at 100 fps
        k += 1
        time.sleep(0.01)
        # a liveness guard, not a speed test (the freeze probe times the walk): 12 s of frames
        assert k < 1900, "the walk to frame 730 never finished"
    seen = 0
    for k in range(k, k + 30):
        a, b = cam(k), straight(k)
        assert len(a) == len(b)
        seen += len(b)
        for x, y in zip(a, b):
            assert np.array_equal(x.box, y.box) and x.score == y.score
            assert (x.descriptor is None) == (y.descriptor is None)
            assert x.descriptor is None or np.array_equal(x.descriptor, y.descriptor)
    assert seen > 30  # people were there to compare


def test_a_paced_loop_skips_runs_on_without_images_and_tracks_again(tmp_path):
    """A node 55 frames behind the network (a freeze) skips to the network's frame and tells
    its source. The simulated camera's walk there is held until the loop has run 10 frames past
    the skip: the loop must not wait for it (if it did, the gate would never open and the walk
    fails after GATE_S). Then the camera's frames come back."""
    export = export_scenario(tmp_path / "export", 5)
    p = tmp_path / "cam0.toml"
    p.write_text(BASE.replace("EXPORT", str(export)) + '[runtime]\nmode = "async"\nfps = 50\n')
    cfg = load_node_config(p)
    world = GatedWorld(free=10)
    cam = SeekingCamera(world)
    src = Source(topdown_camera(0), 120, 50.0, 1.0, cam, seek=cam.seek)
    seeks = []

    class Network(FakeTransport):
        def network_frame(self):
            return 60 if frames_read[-1] >= 5 else None

        def drain(self, k):
            if k >= 70:
                world.gate.set()
            return super().drain(k)

    frames_read = [0]
    node = CameraNode(topdown_camera(0), [1], TrackerConfig(), "net")

    def source(k):
        frames_read.append(k)
        return src(k)
    source.seek = lambda k: (seeks.append(k), src.seek(k))
    st = FrameLoop(cfg, node, source, Network(), mode="async", frames=100).run()
    assert seeks == [60] and st.catch_ups == 1 and st.frames_skipped_behind == 54
    assert 10 <= src.frames_without_image <= 40  # 60..70 at least, until the walk got there
    walked = [k for k, t in world.made if t == "scenario-seek"]
    assert walked and walked[0] >= 60
    assert frames_read[-1] == 99 and st.frames_done == 6 + 40
