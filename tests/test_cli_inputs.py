"""What a user types into ``sim_cluster`` is checked before anything runs or is written: every
numeric option names itself when it is wrong, and ``up`` checks its whole input before it
touches the previous run's files in ``--out``. Every file ``sim_cluster`` and ``edge_node`` read
is one line on stderr and exit status 2 when its bytes are not UTF-8 (the command lines run as
processes, which stop at the file: integration tests). No node process is started here."""
from __future__ import annotations

import json
import shutil
import subprocess
import sys
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
     "--reid osnet_x0_25: perception.osnet.weights is required (a torchreid OSNet checkpoint); "
     "give it with --reid-weights FILE"),
    (["--source", "video", "--detector", "onnx"],
     "--detector onnx: perception.onnx is required"),
    (["--source", "video", "--detector", "onnx", "--detector-option", "model=MISSING"],
     "--detector onnx: perception.onnx.model names a file that does not exist"),
    (["--source", "video", "--detector", "ssdlite", "--detector-option", "tiles=9"],
     "--detector ssdlite: perception.ssdlite.tiles must be"),
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


# -- bytes that are not UTF-8, in every file a command reads -------------------------------------
GARBAGE = b"\xff\xfe\x00garbage\x80\x81"
NOT_UTF8 = "not UTF-8 text: byte 0xff at offset {} (a binary file, or another encoding)"


@pytest.fixture(scope="module")
def det_dir(tmp_path_factory) -> Path:
    """A 5-frame det-files folder of lab-sim (4 cameras)."""
    from sim_cluster.scenarios.detfiles import export_detections
    from sim_cluster.scenarios.loader import load_scenario

    d = tmp_path_factory.mktemp("det") / "det"
    export_detections(load_scenario("lab-sim", frames=5), d)
    return d


def _epfl_mini(root: Path) -> Path:
    """A two-camera EPFL-style data root and a scenario file of kind epfl-gt reading it."""
    d = root / "epfl_pom"
    (d / "mini").mkdir(parents=True)
    (d / "homographies.json").write_text(json.dumps({"mini": {
        "sequence": "mini1", "image_size_annotations": [100, 100],
        "H": [[[1, 0, 0], [0, 1, 0], [0, 0, 1]], [[1, 0, 10], [0, 1, 0], [0, 0, 1]]]}}))
    (d / "mini" / "mini1-c0.gt.csv").write_text("10,0,10,20,10,30,0,0,0,0\n")
    (d / "mini" / "mini1-c1.gt.csv").write_text("10,0,0,22,10,30,0,0,0,0\n")
    toml = root / "mini.toml"
    toml.write_text(f'name = "mini-gt"\nframes = 1\n[source]\nkind = "epfl-gt"\n'
                    f'sequence = "mini"\nunits_per_metre = 30.0\ndata_root = "{root}"\n')
    return toml


def _bad(path: Path, head: bytes = b"") -> Path:
    """``path`` holding ``head`` then binary garbage (made with its folders)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(head + GARBAGE + b"\n")
    return path


NODE = 'node = 0\nnetwork = "net"\n[source]\nkind = "det-file"\npath = "{det}"\n'


@pytest.fixture(scope="module")
def cases(tmp_path_factory, det_dir) -> dict[str, tuple[list[str], str]]:
    """Per reader: the command line (with the broken file made) and the stderr line expected
    (no command writes anything: each stops at its broken file)."""
    tmp = tmp_path_factory.mktemp("inputs")
    def copy() -> Path:
        d = tmp / f"det{len(list(tmp.glob('det*')))}"
        shutil.copytree(det_dir, d)
        return d

    cases = {}
    d = copy()
    f = _bad(d / "c1" / "det.txt", b"1,-1,10,20,30,60,0.9,-1,-1,-1\n")
    cases["det.txt"] = (["sim_cluster", "run", "--scenario", str(d), "--quiet", "--out",
                         str(tmp / "o")], f"{f}:2: {NOT_UTF8.format(30)}")
    d = copy()
    f = _bad(d / "gt_ground.csv")
    cases["gt_ground.csv"] = (["sim_cluster", "export-detections", "--scenario", str(d), "--out",
                               str(tmp / "o")], f"{f}:1: {NOT_UTF8.format(0)}")
    d = copy()
    f = _bad(d / "calibration.json", b"{\n")
    cases["calibration.json"] = (["sim_cluster", "check-scale", "--scenario", str(d)],
                                 f"{f}:2: {NOT_UTF8.format(2)}")
    d = copy()  # a frame past the frames calibration.json states (5): was silently never read
    f = d / "c0" / "det.txt"
    (d / "c0" / "det.npy").unlink()
    f.write_text(f.read_text() + "1000000000000,-1,10,20,30,60,0.9,-1,-1,-1\n")
    cases["frame 1e12"] = (["sim_cluster", "run", "--scenario", str(d), "--quiet", "--out",
                            str(tmp / "o")],
                           f"{f}:{f.read_text().count(chr(10))}: det.txt field 'frame' must be <= "
                           f"5 (the number of frames {d / 'calibration.json'} states), got "
                           "1000000000000")
    f = _bad(tmp / "scenario.toml", b"# a scenario\n")
    cases["scenario"] = (["sim_cluster", "run", "--scenario", str(f), "--quiet", "--out",
                          str(tmp / "o")], f"scenario.toml: line 2: {NOT_UTF8.format(13)}")
    f = _bad(tmp / "faults.toml")
    cases["fault plan"] = (["sim_cluster", "run", "--scenario", "lab-sim", "--frames", "2",
                            "--faults", str(f), "--quiet", "--out", str(tmp / "o")],
                           f"{f}: line 1: {NOT_UTF8.format(0)}")
    f = _bad(tmp / "tracker.toml")
    cases["tracker file"] = (["sim_cluster", "run", "--scenario", "lab-sim", "--frames", "2",
                              "--tracker-config", str(f), "--quiet", "--out", str(tmp / "o")],
                             f"{f}: line 1: {NOT_UTF8.format(0)}")
    f = _bad(tmp / "edges.txt", b"0 1\n")
    cases["topology"] = (["sim_cluster", "up", "--scenario", "lab-sim", "--frames", "2",
                          "--topology", str(f), "--out", str(tmp / "up")],
                         f"{f}:2: {NOT_UTF8.format(4)}")
    f = _bad(tmp / "cluster" / "cluster.json")
    cases["cluster.json"] = (["sim_cluster", "status", "--out", str(f.parent)],
                             f"{f}:1: {NOT_UTF8.format(0)}")
    layout = tmp / "layout"
    for c in range(2):
        (layout / f"cam{c}.txt").parent.mkdir(parents=True, exist_ok=True)
        (layout / f"cam{c}.txt").write_text("1,-1,10,10,20,50,0.9,-1,-1,-1\n")
    f = _bad(layout / "homographies.json", b"[\n")
    cases["layout homographies"] = (["sim_cluster", "import-detections", str(layout),
                                     "--image-size", "100x100", "--out", str(tmp / "o")],
                                    f"{f}:2: {NOT_UTF8.format(2)}")
    toml = _epfl_mini(tmp / "epfl")
    f = _bad(tmp / "epfl" / "epfl_pom" / "mini" / "mini1-c1.gt.csv", b"10,0,0,22,10,30,0,0,0,0\n")
    cases["EPFL annotations"] = (["sim_cluster", "run", "--scenario", str(toml), "--quiet",
                                  "--out", str(tmp / "o")],
                                 f"mini.toml: {f}:2: {NOT_UTF8.format(24)}")
    toml = _epfl_mini(tmp / "epfl2")
    f = _bad(tmp / "epfl2" / "epfl_pom" / "homographies.json")
    cases["EPFL homographies"] = (["sim_cluster", "run", "--scenario", str(toml), "--quiet",
                                   "--out", str(tmp / "o")],
                                  f"mini.toml: {f}:1: {NOT_UTF8.format(0)}")
    # edge_node
    f = _bad(tmp / "cam0.toml", b'node = 0\n')
    for cmd in ("check", "run"):
        cases[f"node config ({cmd})"] = (["edge_node", cmd, "--config", str(f)],
                                         f"cam0.toml: line 2: {NOT_UTF8.format(9)}")
    d = copy()
    f = _bad(d / "c0" / "det.txt")
    node = tmp / "node_det.toml"
    node.write_text(NODE.format(det=d))
    for cmd in ("check", "run"):
        cases[f"det-file source ({cmd})"] = (["edge_node", cmd, "--config", str(node)],
                                             f"node_det.toml: source.path: {f}:1: "
                                             f"{NOT_UTF8.format(0)}")
    f = _bad(tmp / "out" / "state_node0.json")
    node = tmp / "node_state.toml"
    node.write_text(NODE.format(det=det_dir) + f'[output]\ndir = "{f.parent}"\n')
    cases["state file"] = (["edge_node", "check", "--config", str(node)],
                           f"node_state.toml: output.dir has an unreadable state_node0.json "
                           f"({f}:1: {NOT_UTF8.format(0)}); remove it to start the id counter "
                           "at 0")
    f = _bad(tmp / "pairs.csv", b"u,v,x,y\n")
    cases["point pairs"] = (["edge_node", "calibrate", "--points", str(f)],
                            f"{f}:2: {NOT_UTF8.format(8)}")
    return cases


CASES = ["det.txt", "gt_ground.csv", "calibration.json", "frame 1e12", "scenario", "fault plan",
         "tracker file", "topology", "cluster.json", "layout homographies", "EPFL annotations",
         "EPFL homographies", "node config (check)", "node config (run)",
         "det-file source (check)", "det-file source (run)", "state file", "point pairs"]


@pytest.mark.integration  # runs each command line as a process
@pytest.mark.parametrize("case", CASES)
def test_binary_bytes_in_any_file_a_command_reads_are_one_line_and_exit_2(cases, case):
    """The goal of "No zombie nodes", Input: binary garbage in each file reader of both command
    lines is exit status 2 and one line on stderr naming the file and the line and byte offset
    (a frame number past the source's length: the line and the field), never a traceback. Each
    of these was a UnicodeDecodeError traceback, exit status 1 (the frame: accepted)."""
    assert sorted(cases) == sorted(CASES)
    argv, message = cases[case]
    out = subprocess.run([sys.executable, "-m", f"{argv[0]}.cli", *argv[1:]],
                         capture_output=True, text=True, timeout=120)
    assert "Traceback" not in out.stderr, out.stderr
    assert (out.returncode, out.stderr.splitlines()) == (2, [f"{argv[0]}: error: {message}"])


@pytest.mark.parametrize("cmd", [["status"], ["down"], ["kill", "1"], ["restart", "1"]])
@pytest.mark.parametrize("doc", ["{}", "[]", '{"out": "x", "nodes": {"0": {"pid": 1}}}'])
def test_a_cluster_json_of_other_fields_is_one_line_and_exit_2(tmp_path, capsys, cmd, doc):
    """JSON that is not a cluster state file was a KeyError / TypeError traceback."""
    (tmp_path / "cluster.json").write_text(doc)
    assert cli.main([*cmd, "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1 and err[0].startswith(
        f"sim_cluster: error: {tmp_path / 'cluster.json'}: not a cluster state file ("), err


def test_status_shows_a_node_whose_status_file_is_binary_as_without_one(tmp_path, capsys):
    """A node's status file of binary bytes ended ``status`` in a UnicodeDecodeError traceback;
    it reads as no status yet, as a missing or half-written one does."""
    out = tmp_path / "prev"
    _previous_run(out)
    (out / "nodes" / "status_node2.json").write_bytes(GARBAGE)
    (out / "nodes" / "status_node3.json").write_text("[1, 2]")  # JSON, not an object
    assert cli.main(["status", "--out", str(out)]) == 0
    rows = capsys.readouterr().out.splitlines()
    assert [r.split()[0] for r in rows[2:]] == ["0", "1", "2", "3"]
    empty = ["-", "-", "-", "0", "-", "-", "-"]  # frame .. phase of node 0, whose file is {}
    assert [r.split()[3:] for r in rows[2:]] == [empty] * 4


def test_every_file_readers_error_is_an_input_error():
    """Each file reader raises its own class: sim_cluster reports each as one line, exit 2
    (HomographiesError and PerceptionError, of EPFL's homographies.json and the perception
    files, were missing: their readers' callers wrap them today, a new caller would not)."""
    from edge_node.formats.homographies import HomographiesError
    from edge_node.formats.layouts import LayoutError
    from edge_node.perception import PerceptionError
    from edge_node.settings import SettingsError
    from sim_cluster.cluster.state import ClusterError
    from sim_cluster.network.topology import TopologyError
    from sim_cluster.scenarios.detfiles import DetFilesError
    from sim_cluster.scenarios.epfl import DataNotFoundError, EpflFormatError

    for cls in (SettingsError, DetFilesError, LayoutError, HomographiesError, EpflFormatError,
                DataNotFoundError, TopologyError, ClusterError, PerceptionError):
        assert issubclass(cls, cli.INPUT_ERRORS), cls
