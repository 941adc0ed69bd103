"""Generated layouts (issue 15): corridor-<N> and grid-<N> keep the people density per camera
across N, every camera's view overlaps its layout neighbours', frames are deterministic and
independent of the run's length, people walk across many cameras, each camera's pruned
projection equals projecting everybody, and a 256-camera scenario opens without making frames."""
from __future__ import annotations

import time

import numpy as np
import pytest

from sim_cluster.network.topology import lattice
from sim_cluster.scenarios.files import ScenarioError
from sim_cluster.scenarios.loader import open_scenario
from sim_cluster.scenarios.synthetic.appearance import AppearanceModel
from sim_cluster.scenarios.synthetic.layout import (LayoutError, LayoutParams, LayoutWalk,
                                                    LayoutWorldStream, regional_chunk)
from sim_cluster.scenarios.synthetic.world import _chunk, _trajectories
from tests.test_streaming import _same_frame

PEOPLE_PER_CAMERA = 6.25
DENSITY_TOLERANCE = 0.15  # people in view per camera: within 15 % of their mean over N


def _in_view(cam, pts: np.ndarray) -> np.ndarray:
    """Ground points whose foot point is in front of ``cam`` and inside its image."""
    uv = cam.to_image(pts)
    W, H = cam.image_size
    return (cam.in_front(pts) & (uv[:, 0] >= 0) & (uv[:, 0] < W) & (uv[:, 1] >= 0)
            & (uv[:, 1] < H))


def test_density_per_camera_is_constant_across_sizes():
    """People in the world per camera is the layout's 6.25 (within 10 %), and the people a
    camera has in view (its image ground truth), averaged over cameras and 100 frames, stays
    within 15 % of its mean over 4, 16 and 64 cameras."""
    in_view = {}
    for n in (4, 16, 64):
        s = open_scenario(f"corridor-{n}", frames=100)
        frames = [s.frame(k) for k in range(0, 100, 5)]
        world = np.mean([len(f.ids) for f in frames]) / n
        assert abs(world - PEOPLE_PER_CAMERA) <= 0.1 * PEOPLE_PER_CAMERA, (n, world)
        in_view[n] = np.mean([len(f.boxes[c][0]) for f in frames for c in range(n)])
    mean = np.mean(list(in_view.values()))
    for n, v in in_view.items():
        assert abs(v - mean) <= DENSITY_TOLERANCE * mean, in_view


@pytest.mark.parametrize("name", ["corridor-16", "grid-16"])
def test_every_camera_overlaps_its_layout_neighbours(name):
    """The neighbour graph is the lattice, and for every edge the two cameras see a common
    piece of the layout's floor of at least 4 m^2 (0.25 m sampling)."""
    s = open_scenario(name, frames=10)
    rows = 1 if name.startswith("corridor") else 4
    assert s.neighbours == lattice(rows, s.num_cameras // rows)
    xmin, xmax, ymin, ymax = s.area
    gx, gy = np.meshgrid(np.arange(xmin, xmax, 0.25), np.arange(ymin, ymax, 0.25))
    pts = np.stack([gx.ravel(), gy.ravel()], axis=1)
    seen = [_in_view(c, pts) for c in s.cameras]
    for a, nbs in s.neighbours.items():
        for b in nbs:
            assert np.sum(seen[a] & seen[b]) * 0.25 ** 2 >= 4.0, (a, b)


def test_same_seed_same_frames_and_frame_k_independent_of_run_length():
    short = open_scenario("corridor-16", seed=3, frames=150)
    again = open_scenario("corridor-16", seed=3, frames=150)
    long = open_scenario("corridor-16", seed=3, frames=1000)
    for k in (0, 99, 149):
        _same_frame(short.frame(k), again.frame(k))
    for k in (149, 3, 120):  # backwards across chunks: the walk restarts from frame 0
        _same_frame(short.frame(k), long.frame(k))
    other = open_scenario("corridor-16", seed=4, frames=150)
    assert not np.array_equal(short.frame(120).xy, other.frame(120).xy)


@pytest.mark.slow  # 400 frames of a 64-camera world
def test_people_walk_across_many_cameras():
    """In a 64-camera corridor some people cross at least 4 cameras' views in 400 frames."""
    s = open_scenario("corridor-64", frames=400)
    cams: dict[int, set[int]] = {}
    for k in range(0, 400, 2):
        for c, (ids, _) in enumerate(s.frame(k).boxes):
            for p in ids:
                cams.setdefault(int(p), set()).add(c)
    crossing = [p for p, c in cams.items() if len(c) >= 4]
    assert len(crossing) >= 10, sorted(len(c) for c in cams.values())[-10:]


def test_pruned_projection_equals_projecting_everybody():
    """Each camera projecting only the people inside its view's bounds gives the frames of
    projecting everybody into every camera (world._chunk): the bounds miss nobody."""
    s = open_scenario("corridor-4", frames=100)
    maker: LayoutWorldStream = s.chunk
    walk = maker._walk()
    traj = _trajectories([walk.next() for _ in range(100)])
    app = AppearanceModel(maker.config.appearance, int(maker.config.seed))
    dense = _chunk(maker.config, app, 0, 0, traj)
    app = AppearanceModel(maker.config.appearance, int(maker.config.seed))
    pruned = regional_chunk(maker.config, maker.bounds, app, 0, 0, traj)
    assert sum(len(f.boxes[c][0]) for f in dense for c in range(4)) > 1000
    for a, b in zip(dense, pruned):
        _same_frame(a, b)


def test_memory_holds_the_people_in_the_world_only():
    """After many departures the walk holds about the layout's people, not everybody born."""
    lay = LayoutParams(kind="corridor", cameras=4, trip_m=(2.0, 6.0))
    s = open_scenario("corridor-4", frames=10)
    walk = LayoutWalk(lay, 25.0, s.chunk.config.people, np.random.default_rng(0))
    for _ in range(1500):
        walk.next()
    assert walk.born > 4 * lay.people
    assert len(walk.active) <= 1.3 * lay.people


def test_a_256_camera_scenario_opens_quickly():
    # CPU time, not wall time: the work of opening it, whatever else the machine runs
    t0 = time.process_time()
    s = open_scenario("grid-256", frames=100_000)
    assert time.process_time() - t0 < 3.0
    assert s.num_cameras == 256 and s._held is None  # no frame made yet
    assert s.neighbours[17] == (1, 16, 18, 33)


def test_bad_layouts_are_named_errors():
    assert open_scenario("grid-15", frames=1).neighbours == lattice(3, 5)
    with pytest.raises(ScenarioError, match="grid of 14 cameras"):
        open_scenario("grid-14")
    with pytest.raises(ScenarioError, match="cameras must be"):
        open_scenario("corridor-0")
    with pytest.raises(LayoutError):
        LayoutParams(kind="ring")


def test_a_fault_plan_is_checked_against_the_layout_network(tmp_path):
    """``--topology layout --faults``: the plan's nodes and links are the layout's lattice (a
    grid has no named topology), so a link of the lattice is accepted and a non-link refused."""
    from edge_node.faults import FaultPlanError
    from sim_cluster.experiments.run import load_faults

    data = open_scenario("grid-4", seed=0, frames=50).materialise()
    assert data.neighbours == lattice(2, 2)
    ok = tmp_path / "ok.toml"
    ok.write_text('[[link]]\nsrc = 0\ndst = 1\nloss = 0.5\n')
    assert not load_faults(ok, data, "layout").empty
    bad = tmp_path / "bad.toml"
    bad.write_text('[[link]]\nsrc = 0\ndst = 3\nloss = 0.5\n')  # diagonal: not a lattice link
    with pytest.raises(FaultPlanError):
        load_faults(bad, data, "layout")
