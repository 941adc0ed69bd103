"""Registries of named kinds (``edge_node/plugins.py``): a detector, a re-id backend or a
topology is one module and one registration, and every place that offers a choice (the config
reader, the command line's choices and help, error messages) takes it from the registry.

The plug-ins here are real installed distributions (a ``*.dist-info`` folder with an
``entry_points.txt`` on ``sys.path``, what ``pip install`` leaves), not patched registries."""
from __future__ import annotations

import sys
import textwrap

import numpy as np
import pytest

from edge_node.perception import PerceptionError
from edge_node.perception.detectors import DETECTORS
from edge_node.perception.pipeline import build_perception
from edge_node.perception.reid import REID
from edge_node.perception.settings import parse_perception
from edge_node.plugins import PluginError, Registry
from edge_node.settings import SettingsError, Table
from sim_cluster import cli
from sim_cluster.experiments.ablation import ordered, topology_names
from sim_cluster.network import topology as topo

PLUGIN = '''
import numpy as np
from sim_cluster.network.topology import Topology


class Grid:
    """A detector that finds one person in the middle of every image."""

    name = "centre"

    def __init__(self, width_px=20):
        self.width_px = width_px

    @classmethod
    def options(cls, perception, base, selected):
        t = perception.optional_table("centre")
        if t is None:
            return {}
        out = {"width_px": t.integer("width_px", 20, lo=1)}
        t.finish()
        return out

    @classmethod
    def from_options(cls, options, *, camera, units_per_metre):
        return cls(**options)

    def detect(self, image):
        H, W = image.shape[:2]
        return [(np.array([W / 2 - self.width_px / 2, H / 4, self.width_px, H / 2]), 1.0)]


# nodes 0..n-1, each linked to the node two places on (a "skip" ring)
skip = Topology(lambda n, o: ((o[i], o[(i + 2) % n]) for i in range(n)), True,
                "each camera linked to the one two places on")
'''


@pytest.fixture
def installed(tmp_path, monkeypatch):
    """A distribution ``dmtt-extras`` installed on ``sys.path``: a detector ``centre``, a
    topology ``skip`` and a detector whose module is missing (``broken``)."""
    (tmp_path / "dmtt_extras.py").write_text(PLUGIN)
    info = tmp_path / "dmtt_extras-0.1.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: dmtt-extras\nVersion: 0.1\n")
    (info / "entry_points.txt").write_text(textwrap.dedent("""\
        [dmtt.detectors]
        centre = dmtt_extras:Grid
        broken = dmtt_extras_missing:Nothing
        mog2 = dmtt_extras:Grid

        [dmtt.topologies]
        skip = dmtt_extras:skip
        """))
    monkeypatch.syspath_prepend(str(tmp_path))
    yield tmp_path
    sys.modules.pop("dmtt_extras", None)
    for reg in (DETECTORS, topo.TOPOLOGIES):
        reg._loaded.clear()


def _perception(text: str, base):
    import tomllib
    return parse_perception(Table(tomllib.loads(text)["perception"], "node.toml", "perception"),
                            base)


def test_registry_keeps_order_refuses_a_second_kind_under_one_name_and_names_the_known():
    reg: Registry[int] = Registry("widget", "dmtt.test-widgets-none")
    reg.add("b", 2)
    reg.add("a", 1)
    assert reg.names() == ("b", "a") and reg.get("a") == 1 and "b" in reg and "c" not in reg
    with pytest.raises(ValueError, match="registered twice"):
        reg.add("a", 3)
    with pytest.raises(PluginError, match=r"unknown widget 'c' \(known: b, a;.*"
                                          r"'dmtt.test-widgets-none'"):
        reg.get("c")


def test_the_shipped_kinds_are_registered_where_they_are_defined():
    assert DETECTORS.builtin() == ("mog2", "hog", "onnx", "ssdlite")
    assert REID.builtin()[0] == "histogram" and REID.builtin()[-1] == "none"
    assert {REID.get(n).table for n in REID.builtin() if n.startswith("osnet_")} == {"osnet"}
    assert topo.TOPOLOGIES.builtin() == ("complete", "ring", "chain", "disconnected", "star")
    # the paper's orderings (Fig. 4) are averaged for ring and chain only
    assert [t for t in topo.TOPOLOGIES.builtin() if ordered(t)] == ["ring", "chain"]


def test_an_installed_detector_is_known_to_the_config_reader_and_the_command_line(installed):
    assert DETECTORS.names() == ("mog2", "hog", "onnx", "ssdlite", "broken", "centre")
    s = _perception('[perception]\ndetector = "centre"\nreid = "none"\n'
                    '[perception.centre]\nwidth_px = 30\n', installed)
    assert s.detector == "centre" and s.of("centre") == {"width_px": 30}
    p = build_perception(s)
    assert p.detector.width_px == 30
    (box, score), = p.detector.detect(np.zeros((100, 200, 3), np.uint8))
    assert box.tolist() == [85.0, 25.0, 30.0, 50.0] and score == 1.0
    # its table is validated by its own reader: a typo names the file and the key
    with pytest.raises(SettingsError, match=r"node.toml: perception.centre.width is not a known"):
        _perception('[perception]\ndetector = "centre"\n[perception.centre]\nwidth = 3\n',
                    installed)
    up = cli.build_parser().parse_args(["up", "--source", "video", "--detector", "centre"])
    assert up.detector == "centre"


def test_a_plug_in_cannot_take_a_shipped_name_and_a_broken_one_is_a_typed_error(installed):
    from edge_node.perception.detectors.mog2 import Mog2Detector
    assert DETECTORS.get("mog2") is Mog2Detector
    with pytest.raises(PerceptionError, match=r"detector 'broken': its plug-in "
                                              r"dmtt_extras_missing:Nothing cannot be loaded "
                                              r"\(ModuleNotFoundError"):
        DETECTORS.get("broken")
    with pytest.raises(SettingsError, match=r"perception.detector must be one of"):
        _perception('[perception]\ndetector = "nope"\n', installed)


def test_an_installed_topology_is_built_ordered_and_offered(installed):
    assert "skip" in topo.TOPOLOGIES and "skip" in topology_names() and ordered("skip")
    adj = topo.build("skip", 5)
    assert adj == {0: (2, 3), 1: (3, 4), 2: (0, 4), 3: (0, 1), 4: (1, 2)}
    # orderings of an ordered topology are distinct graphs
    graphs = {tuple(sorted(topo.build("skip", 5, o).items())) for o in topo.orderings("skip", 5, 3)}
    assert len(graphs) == 3
    assert "skip" in topo.help_text()
    with pytest.raises(topo.TopologyError, match=r"unknown topology 'skipp'.*skip"):
        topo.build("skipp", 5)
