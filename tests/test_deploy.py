"""The deploy/ examples are real: the camera configs validate and Zenoh accepts the json5."""
from pathlib import Path

import pytest

from edge_node.runtime.config import load_node_config
from sim_cluster.scenarios.detfiles import export_detections
from sim_cluster.scenarios.loader import load_scenario

DEPLOY = Path(__file__).resolve().parent.parent / "deploy"


@pytest.mark.parametrize("name", ["peer.json5", "peer-mtls.json5", "peer-acl.json5"])
def test_zenoh_configs_parse(name):
    import zenoh

    cfg = zenoh.Config.from_file(str(DEPLOY / "zenoh" / name))
    assert '"peer"' in cfg.get_json("mode")
    assert cfg.get_json("scouting/multicast/enabled") == "false"


def test_example_network_configs_validate(tmp_path):
    export_detections(load_scenario("terrace-sim", frames=5), tmp_path / "det")
    examples = sorted((DEPLOY / "examples" / "terrace4").glob("cam*.toml"))
    assert len(examples) == 4
    neighbours = {}
    for path in examples:
        text = path.read_text()
        text = text.replace("/etc/dmtt/peer.json5", str(DEPLOY / "zenoh" / "peer.json5"))
        text = text.replace("/var/lib/dmtt/detections/calibration.json",
                            str(tmp_path / "det" / "calibration.json"))
        text = text.replace("/var/lib/dmtt/out", str(tmp_path / "out"))
        local = tmp_path / path.name
        local.write_text(text)
        cfg = load_node_config(local)
        neighbours[cfg.node] = set(cfg.neighbours)
        assert cfg.runtime.mode == "async"
    # the four boxes form a ring, each link configured on both ends
    assert neighbours == {0: {3, 1}, 1: {0, 2}, 2: {1, 3}, 3: {2, 0}}


@pytest.mark.parametrize("name", [None, "peer.json5"])
def test_shared_memory_is_off_unless_asked(name):
    """Zenoh 1.x enables its shared-memory transport by default, and a receiver keeps every
    same-host sender's 16 MB pool mapped for its lifetime: one more per neighbour restart."""
    from edge_node.runtime.transport import zenoh_config

    file = DEPLOY / "zenoh" / name if name else None
    assert zenoh_config([], [], config_file=file).get_json(
        "transport/shared_memory/enabled") == "false"
    assert zenoh_config([], [], config_file=file, shared_memory=True).get_json(
        "transport/shared_memory/enabled") == "true"
