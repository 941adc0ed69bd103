"""What a user types into ``sim_cluster`` is checked before anything runs or is written: every
numeric option names itself when it is wrong, and ``up`` checks its whole input before it
touches the previous run's files in ``--out``. No process is started here."""
from __future__ import annotations

from pathlib import Path

import pytest

from sim_cluster import cli
from sim_cluster.cluster.state import ClusterState, NodeProc


@pytest.mark.parametrize("argv, message", [
    (["run", "--frames", "-5"], "argument --frames: must be an integer >= 1, got '-5'"),
    (["up", "--frames", "-5"], "argument --frames: must be an integer >= 1, got '-5'"),
    (["up", "--frames", "ten"], "argument --frames: must be an integer >= 1, got 'ten'"),
    (["fault-report", "--frames", "0"], "argument --frames: must be an integer >= 1, got '0'"),
    (["export-detections", "--frames", "0", "--out", "x"],
     "argument --frames: must be an integer >= 1, got '0'"),
    (["run", "--seed", "-1"], "argument --seed: must be an integer >= 0, got '-1'"),
    (["up", "--seed", "-1"], "argument --seed: must be an integer >= 0, got '-1'"),
    (["run", "--ground-threshold", "-1"], "argument --ground-threshold: must be a number > 0, "
                                          "got '-1'"),
    (["run", "--ground-threshold", "nan"], "argument --ground-threshold: must be a number > 0, "
                                           "got 'nan'"),
    (["up", "--nodes", "0"], "argument -n/--nodes: must be an integer >= 1, got '0'"),
    (["up", "--sync-timeout", "-1"], "argument --sync-timeout: must be a number > 0, got '-1'"),
    (["up", "--startup-timeout", "0"], "argument --startup-timeout: must be a number > 0, got '0'"),
    (["up", "--fps", "-3"], "argument --fps: must be a number >= 0, got '-3'"),
    (["up", "--network", "a b"], "argument --network: must be a non-empty name without '/', "
                                 "'*', '$', '?', '#' or spaces (at most 64 bytes), got 'a b'"),
    (["render", "--noise", "-1", "--out", "x"], "argument --noise: must be a number >= 0, "
                                                "got '-1'"),
    (["bench", "--targets", "5,-3"], "argument --targets: must be integers >= 0 like 5,20, "
                                     "got '5,-3'"),
    (["bench", "--neighbours", "-1"], "argument --neighbours: must be an integer >= 0, got '-1'"),
    (["bench", "--frames", "0"], "argument --frames: must be an integer >= 1, got '0'"),
    (["bench", "--repeats", "0"], "argument --repeats: must be an integer >= 1, got '0'"),
    (["bench-cluster", "--sync-timeout", "-1"],
     "argument --sync-timeout: must be a number > 0, got '-1'"),
    (["bench-cluster", "--seed", "-1"], "argument --seed: must be an integer >= 0, got '-1'"),
])
def test_a_bad_number_on_the_command_line_names_the_option(tmp_path, capsys, monkeypatch, argv,
                                                          message):
    """``--frames -5`` used to be blamed on the scenario file ('lab-sim.toml: frames must be
    ...'); a negative timeout was found by every node after the launcher had started them; a
    negative --targets or --neighbours ended ``bench`` in a traceback."""
    monkeypatch.chdir(tmp_path)  # nothing may be written, wherever it would go (restored after)
    assert cli.main(argv) == 2
    assert capsys.readouterr().err.splitlines() == [f"sim_cluster: error: {message}"]
    assert list(tmp_path.iterdir()) == []


# -- up: the previous run's files survive a bad input --------------------------------------------
def _previous_run(out: Path) -> dict[Path, tuple[bytes, int]]:
    """A finished 4-node run's folder, as ``up`` leaves it: state, configs, logs, node files,
    recordings, summary. Returns every file's bytes and modification time."""
    state = ClusterState(str(out), "sim", "lab-sim", 0, 5, "sync", "chain",
                         {"0": [1], "1": [0, 2], "2": [1, 3], "3": [2]})
    files = {"summary.json": "{}\n"}
    for i in range(4):
        state.nodes[str(i)] = NodeProc(i, str(out / "configs" / f"node{i}.toml"),
                                       str(out / "logs" / f"node{i}.log"), 7000 + i)
        files.update({f"configs/node{i}.toml": f"node = {i}\n", f"logs/node{i}.log": "done\n",
                      f"nodes/tracks_node{i}.csv": "frame,id\n",
                      f"nodes/counters_node{i}.json": "{}\n",
                      f"nodes/status_node{i}.json": "{}\n", f"rerun/node{i}.rrd": "rrd"})
    for name, text in files.items():
        (out / name).parent.mkdir(parents=True, exist_ok=True)
        (out / name).write_text(text)
    state.save()
    return {p: (p.read_bytes(), p.stat().st_mtime_ns) for p in out.rglob("*") if p.is_file()}


@pytest.mark.parametrize("extra, message", [
    (["--faults", "FAULTS"], "FAULTS: node[0].node names node 9, but the network has 4 nodes "
                             "(0, 1, 2, 3)"),
    (["--faults", "MISSING"], "MISSING: fault plan not found: MISSING"),
    (["--topology", "EDGES"], "EDGES:2: edge 0-0 joins node 0 to itself"),
    (["--nodes", "9"], "--nodes 9: scenario lab-sim has 4 cameras"),
    (["--scenario", "nope-sim"], "nope-sim: unknown scenario preset"),
    (["--sync-timeout", "-1"], "argument --sync-timeout: must be a number > 0, got '-1'"),
    (["--frames", "-5"], "argument --frames: must be an integer >= 1, got '-5'"),
    (["--rerun", "save"], "--rerun 'save' needs a file"),
    (["--source", "video", "--reid", "osnet_x0_25"],
     "--reid osnet_x0_25 needs --reid-weights (a torchreid checkpoint)"),
])
def test_up_checks_everything_before_it_touches_the_previous_run(tmp_path, capsys, extra,
                                                                  message):
    """``up --faults bad.toml --out prev`` used to delete prev's node files (and its
    recordings) before reading the plan; a negative timeout or a self-loop in the edge list
    was found only after the cluster had started."""
    faults, edges = tmp_path / "faults.toml", tmp_path / "edges.txt"
    faults.write_text("[[node]]\nnode = 9\nkill = 2\n")
    edges.write_text("0 1\n0 0\n")
    names = {"FAULTS": str(faults), "EDGES": str(edges), "MISSING": str(tmp_path / "no.toml")}
    prev = tmp_path / "prev"
    before = _previous_run(prev)
    argv = ["up", "--scenario", "lab-sim", "--frames", "5", "--out", str(prev), "--quiet",
            "--rerun", "save", str(prev / "run.rrd")]
    assert cli.main(argv + [names.get(a, a) for a in extra]) == 2
    err = capsys.readouterr().err.splitlines()
    for k, v in names.items():
        message = message.replace(k, v)
    assert len(err) == 1 and err[0].startswith(f"sim_cluster: error: {message}"), err
    after = {p: (p.read_bytes(), p.stat().st_mtime_ns) for p in prev.rglob("*") if p.is_file()}
    assert after == before
