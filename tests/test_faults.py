"""Fault plans (``edge_node/faults.py``) are checked against the network they drive: node ids,
links, partition groups, kill windows and frames; errors name the file and the field, in the
in-process run, the launcher and the camera process alike."""
from __future__ import annotations

import pytest

from edge_node.faults import FaultPlan, FaultPlanError, Network
from edge_node.runtime.config import NodeConfigError, load_node_config
from sim_cluster import cli
from sim_cluster.network.topology import build

CHAIN4 = Network(build("chain", 4), frames=100)  # 0 - 1 - 2 - 3


def _error(doc: dict, network: Network = CHAIN4) -> str:
    with pytest.raises(FaultPlanError) as e:
        FaultPlan.from_dict(doc, "plan.toml", network)
    return str(e.value)


@pytest.mark.parametrize("doc, message", [
    # structure: wrong whatever the network
    ({"link": [{"src": 1, "dst": 1}]}, "link[0].dst is src (1): a link joins two different nodes"),
    ({"partition": [{"groups": [[0, 1], [1, 2]]}]},
     "partition[0].groups[1] repeats node 1 of groups[0]: groups are disjoint"),
    ({"partition": [{"groups": [[0, 0], [2]]}]},
     "partition[0].groups[0] repeats node 0 of groups[0]: groups are disjoint"),
    ({"partition": [{"groups": [[0, 1]]}]},
     "partition[0].groups must hold at least two node lists, got [[0, 1]]"),
    ({"partition": [{"groups": [[0, 1], []]}]},
     "partition[0].groups[1] must be a non-empty list of node ids, got []"),
    ({"partition": [{"groups": [[0, "a"], [2]]}]},
     "partition[0].groups[0] must hold node ids (non-negative integers), got 'a'"),
    ({"partition": [{"between": [[0, -1]]}]},
     "partition[0].between[0] must hold node ids (non-negative integers), got -1"),
    ({"partition": [{"between": [[2, 2]]}]}, "partition[0].between[0] pairs node 2 with itself"),
    ({"node": [{"node": 1, "kill": 0}]}, "node[0].kill must be >= 1, got 0"),
    ({"node": [{"node": 1, "kill": 20, "restart": 20}]},
     "node[0].restart must be after kill (20), got 20"),
    ({"node": [{"node": 1, "kill": 10}, {"node": 1, "kill": 30, "restart": 40}]},
     "node[1].kill is 30, while node 1 is dead (node[0]: kill 10, restart never)"),
    ({"node": [{"node": 1, "kill": 10, "restart": 40}, {"node": 1, "kill": 30}]},
     "node[1].kill is 30, while node 1 is dead (node[0]: kill 10, restart 40)"),
    # against the 4-node chain of 100 frames
    ({"node": [{"node": 9, "kill": 5}]},
     "node[0].node names node 9, but the network has 4 nodes (0, 1, 2, 3)"),
    ({"link": [{"src": 4, "loss": 0.1}]},
     "link[0].src names node 4, but the network has 4 nodes (0, 1, 2, 3)"),
    ({"link": [{"src": 0, "dst": 2, "loss": 0.1}]},
     "link[0].dst names 0 -> 2, which is not a link of the network (node 0's neighbours: 1)"),
    ({"partition": [{"groups": [[0, 1], [2, 9]]}]},
     "partition[0].groups[1] names node 9, but the network has 4 nodes (0, 1, 2, 3)"),
    ({"partition": [{"between": [[1, 3]]}]},
     "partition[0].between[0] names 1 -> 3, which is not a link of the network (node 1's "
     "neighbours: 0, 2)"),
    ({"link": [{"start": 100, "loss": 0.5}]}, "link[0].start is 100, after the run's last frame (99)"),
    ({"node": [{"node": 2, "kill": 100}]}, "node[0].kill is 100, after the run's last frame (99)"),
    ({"node": [{"node": 2, "kill": 50, "restart": 120}]},
     "node[0].restart is 120, after the run's last frame (99)"),
])
def test_a_bad_plan_names_the_file_and_the_field(doc, message):
    assert _error(doc) == f"plan.toml: {message}"


def test_a_good_plan_passes_and_means_what_it_did():
    doc = {"seed": 3, "link": [{"src": 0, "dst": 1, "loss": 0.2}, {"delay": 1}],
           "partition": [{"groups": [[0, 1], [2, 3]], "start": 10, "stop": 20},
                         {"between": [[2, 3]], "start": 50}],
           "node": [{"node": 2, "kill": 10, "restart": 20}, {"node": 2, "kill": 30, "restart": 40},
                    {"node": 3, "kill": 60}]}
    plan = FaultPlan.from_dict(doc, "plan.toml", CHAIN4)
    assert plan == FaultPlan.from_dict(doc)  # the network changes nothing but the checks
    assert plan.deliveries(1, 2, 15) == [] and plan.deliveries(0, 3, 15) == []  # cut
    assert not plan.alive(2, 35) and plan.alive(2, 45) and not plan.alive(3, 99)


def test_a_camera_process_checks_the_links_it_knows():
    """Node 1 of the chain knows its neighbours 0 and 2 only: a rule on one of its own links
    must name a neighbour; node ids elsewhere are the launcher's to judge."""
    me = Network.of_node(1, (0, 2))
    FaultPlan.from_dict({"node": [{"node": 9, "kill": 5}],
                         "link": [{"src": 5, "dst": 7}, {"src": 1, "dst": 2}]}, "p", me)
    assert _error({"link": [{"src": 1, "dst": 3}]}, me) == (
        "plan.toml: link[0].dst names 1 -> 3, which is not a link of the network (node 1's "
        "neighbours: 0, 2)")
    assert _error({"partition": [{"between": [[3, 1]]}]}, me).startswith(
        "plan.toml: partition[0].between[0] names 3 -> 1, which is not a link")


def test_a_node_config_with_a_plan_naming_a_non_neighbour_is_rejected(tmp_path):
    plan = tmp_path / "faults.toml"
    plan.write_text("[[link]]\nsrc = 0\ndst = 3\nloss = 0.5\n")
    cfg = tmp_path / "cam0.toml"
    cfg.write_text('node = 0\nnetwork = "n"\nneighbours = [1]\n[source]\nkind = "scenario"\n'
                   'scenario = "lab-sim"\n[faults]\nfile = "faults.toml"\n')
    with pytest.raises(NodeConfigError) as e:
        load_node_config(cfg)
    assert str(e.value) == (f"cam0.toml: faults.file is not a usable fault plan: {plan}: "
                            "link[0].dst names 0 -> 3, which is not a link of the network "
                            "(node 0's neighbours: 1)")



def test_a_node_config_with_a_plan_shows_it_resolved(tmp_path):
    """``edge_node check`` prints the resolved config: the plan's file, resolved against the
    config's folder, is part of it (it was left out)."""
    (tmp_path / "faults.toml").write_text("[[link]]\nsrc = 0\ndst = 1\nloss = 0.5\n")
    cfg = tmp_path / "cam0.toml"
    cfg.write_text('node = 0\nnetwork = "n"\nneighbours = [1]\n[source]\nkind = "scenario"\n'
                   'scenario = "lab-sim"\n[faults]\nfile = "faults.toml"\n')
    assert load_node_config(cfg).to_dict()["faults"] == {"file": str(tmp_path / "faults.toml")}
    cfg.write_text('node = 0\nnetwork = "n"\nneighbours = [1]\n[source]\nkind = "scenario"\n'
                   'scenario = "lab-sim"\n')
    assert load_node_config(cfg).to_dict()["faults"] is None

@pytest.mark.parametrize("plan, topology, message", [
    ("[[node]]\nnode = 9\nkill = 5\n", "chain",
     "node[0].node names node 9, but the network has 4 nodes (0, 1, 2, 3)"),
    ("[[partition]]\ngroups = [[0, 1], [1, 2]]\n", "ring",
     "partition[0].groups[1] repeats node 1 of groups[0]: groups are disjoint"),
    ("[[link]]\nloss = 0.1\n", "centralized",
     "the centralized topology has no links or camera nodes to fault: pick another topology "
     "or drop --faults"),
])
def test_run_with_a_plan_that_does_not_fit_the_network_is_exit_2(tmp_path, capsys, plan,
                                                                   topology, message):
    """``sim_cluster run --faults`` used to run such plans silently (a fault on node 9 of 4
    never happens, a node in two groups is cut from both)."""
    p = tmp_path / "faults.toml"
    p.write_text(plan)
    assert cli.main(["run", "--scenario", "lab-sim", "--frames", "20", "--topology", topology,
                     "--faults", str(p), "--quiet", "--out", str(tmp_path / "out")]) == 2
    assert capsys.readouterr().err.splitlines() == [f"sim_cluster: error: {p}: {message}"]
    assert not (tmp_path / "out").exists()
