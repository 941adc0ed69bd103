"""``units_per_metre`` from the people in the data (``edge_node/perception/scale.py``,
``sim_cluster check-scale``): a synthetic world whose ground units are changed by a known factor
and whose cameras are known by their homographies only (as real cameras are) gives that factor
back within 10 %; a declared value more than 20 % off is reported."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from edge_node.perception.scale import ScaleEstimate, projection_from_homography
from sim_cluster import cli
from sim_cluster.scenarios.loader import load_scenario
from sim_cluster.scenarios.scale import scenario_scale

FRAMES = 300


@pytest.fixture(scope="module", params=["terrace-sim", "campus-sim"])
def world(request):
    return load_scenario(request.param, frames=FRAMES)


def in_units(data, k: float):
    """``data`` with ground units of 1/k m: homographies, ground truth and area scaled by k,
    cameras without their projection ``P`` (a homography only), units_per_metre declared 1."""
    S = np.diag([k, k, 1.0])
    cams = [replace(c, G=S @ c.G, P=None) for c in data.cameras]
    truth = replace(data.truth, xy=[np.asarray(xy) * k for xy in data.truth.xy])
    return replace(data, cameras=cams, truth=truth, units_per_metre=1.0)


def test_a_homography_gives_back_the_worlds_camera(world):
    """The world's cameras are pinholes with square pixels and the principal point at the image
    centre: their projection follows from the ground homography alone (up to scale)."""
    for cam in world.cameras:
        P = projection_from_homography(replace(cam, P=None))
        a, b = P / np.linalg.norm(P), cam.P / np.linalg.norm(cam.P)
        assert min(np.abs(a - b).max(), np.abs(a + b).max()) < 1e-6


@pytest.mark.parametrize("k", [30.0, 100.0])
def test_known_scale_is_recovered_within_10_percent(world, k):
    est = scenario_scale(in_units(world, k))
    assert est.from_heights == pytest.approx(k, rel=0.10)
    assert all(v == pytest.approx(k, rel=0.10) for v in est.per_camera)
    assert est.from_speed == pytest.approx(k, rel=0.15)  # coarser: people walk 0.7-1.7 m/s
    assert est.disagrees and "what the people in the data give" in est.warning()
    right = replace(in_units(world, k), units_per_metre=k)
    assert not scenario_scale(right).disagrees and scenario_scale(right).warning() is None


def test_the_warning_is_for_more_than_20_percent():
    assert ScaleEstimate(declared=1.25, from_heights=1.0).disagrees
    assert ScaleEstimate(declared=0.75, from_heights=1.0).disagrees
    assert not ScaleEstimate(declared=1.15, from_heights=1.0).disagrees
    assert not ScaleEstimate(declared=0.85, from_heights=1.0).disagrees
    only_speed = ScaleEstimate(declared=2.0, from_speed=1.0)
    assert only_speed.disagrees and "walking speed 1 units/m" in only_speed.warning()
    assert not ScaleEstimate(declared=5.0).disagrees  # nothing measured: nothing to say


def test_check_scale_prints_the_estimate(capsys):
    assert cli.main(["check-scale", "--scenario", "lab-sim", "--frames", "200"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[0] == "lab-sim: units_per_metre declared 1"
    assert out[1].startswith("  box heights: ") and "per camera:" in out[1]
    assert out[2].startswith("  walking speed: ")
    assert out[3].startswith("  declared 1 agrees with")
