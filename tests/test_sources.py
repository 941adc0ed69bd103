"""Where a camera process's detections come from (``edge_node/runtime/sources.py``): a det-files
camera equals the simulator's loader, source kinds that are plug-ins (``dmtt.sources``:
sim_cluster's ``scenario``), and a kind nobody installed."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from edge_node.runtime.config import NodeConfigError, load_node_config
from edge_node.runtime.sources import PLUGIN_GROUP, SourceError, plugin_kinds, source_plugin
from edge_node.runtime.sources import open_source
from sim_cluster.scenarios import replay
from sim_cluster.scenarios.detfiles import load_det_files
from sim_cluster.scenarios.loader import load_scenario
from tests.loopback import export_scenario
from tests.test_node_config import BASE

FRAMES = 40


@pytest.fixture(scope="module")
def export_dir(tmp_path_factory) -> Path:
    return export_scenario(tmp_path_factory.mktemp("export"), FRAMES)


def test_det_file_source_equals_sim_cluster_loader(tmp_path, export_dir):
    ref = load_det_files(export_dir)
    for c in range(ref.num_cameras):
        p = tmp_path / f"cam{c}.toml"
        p.write_text(BASE.replace("EXPORT", str(export_dir)).replace("node = 0", f"node = {c}")
                     .replace("neighbours = [1]", "neighbours = []"))
        src = open_source(load_node_config(p))
        assert src.frames == ref.frames and src.fps == ref.fps
        assert src.units_per_metre == ref.units_per_metre
        assert np.array_equal(src.camera.G, ref.cameras[c].G)
        for k in range(ref.frames):
            a, b = src(k), ref.detections[k][c]
            assert len(a) == len(b)
            for x, y in zip(a, b):
                assert np.array_equal(x.box, y.box) and x.score == y.score
                assert (x.descriptor is None) == (y.descriptor is None)
                if x.descriptor is not None:
                    assert x.descriptor.dtype == y.descriptor.dtype
                    assert np.array_equal(x.descriptor, y.descriptor)


def test_scenario_source_plays_back_one_camera(tmp_path):
    p = tmp_path / "cam2.toml"
    p.write_text('node = 2\nnetwork = "n"\n[source]\nkind = "scenario"\nscenario = "terrace-sim"\n'
                 "seed = 3\nframes = 5\n")
    src = open_source(load_node_config(p))
    ref = load_scenario("terrace-sim", seed=3, frames=5)
    assert src.frames == 5 and src.camera.id == 2 and np.array_equal(src.camera.G, ref.cameras[2].G)
    assert all(len(src(k)) == len(ref.detections[k][2]) for k in range(5))


def test_scenario_kind_is_sim_clusters_plug_in():
    assert "scenario" in plugin_kinds()
    assert source_plugin("scenario") is replay


def test_plug_in_fields_are_validated_naming_file_and_field(tmp_path):
    p = tmp_path / "cam0.toml"
    p.write_text('node = 0\nnetwork = "n"\n[source]\nkind = "scenario"\nscenario = "terrace-sim"\n'
                 "seed = -1\n")
    with pytest.raises(NodeConfigError, match=r"^cam0.toml: source.seed must be >= 0, got -1"):
        load_node_config(p)
    p.write_text('node = 0\nnetwork = "n"\n[source]\nkind = "scenario"\nscenario = "terrace-sim"\n'
                 "sed = 1\n")
    with pytest.raises(NodeConfigError, match=r"^cam0.toml: source.sed is not a known field "
                                              r"\(known: camera, data_root, frames, kind, "
                                              r"scenario, seed\)"):
        load_node_config(p)


def test_a_kind_nobody_installed_is_a_clear_error(tmp_path):
    with pytest.raises(SourceError, match=f"source kind 'hologram' is not installed.*{PLUGIN_GROUP}"):
        source_plugin("hologram")
    p = tmp_path / "cam0.toml"
    p.write_text('node = 0\nnetwork = "n"\n[source]\nkind = "hologram"\n')
    with pytest.raises(NodeConfigError, match=r"^cam0.toml: source.kind must be one of 'det-file', "
                                              r".*'scenario', got 'hologram' \(other kinds are "
                                              r"plug-ins"):
        load_node_config(p)
