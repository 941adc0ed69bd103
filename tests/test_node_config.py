"""A camera process's config (``edge_node/runtime/config.py``): errors name the file and the
field, defaults and relative paths, ``edge_node check``."""
from __future__ import annotations

import json
from pathlib import Path

import pytest

from edge_node.runtime.config import NodeConfigError, load_node_config
from edge_node.runtime.sources import open_source
from tests.loopback import export_scenario

FRAMES = 40


@pytest.fixture(scope="module")
def export_dir(tmp_path_factory) -> Path:
    return export_scenario(tmp_path_factory.mktemp("export"), FRAMES)


BASE = """node = 0
network = "net"
neighbours = [1]
[zenoh]
listen = ["tcp/127.0.0.1:7447"]
connect = ["tcp/127.0.0.1:7448"]
[source]
kind = "det-file"
path = "EXPORT"
"""


@pytest.mark.parametrize("edit, expected", [
    (("tcp/127.0.0.1:7447", "x"),
     "cam0.toml: zenoh.listen[0] must be an endpoint like tcp/127.0.0.1:7447, got 'x'"),
    (("tcp/127.0.0.1:7448", "tcp/127.0.0.1:99999"), "cam0.toml: zenoh.connect[0] must be an endpoint"),
    (('network = "net"', 'network = "a/b"'), "cam0.toml: network must be a non-empty name"),
    (("neighbours = [1]", "neighbours = [0]"), "cam0.toml: neighbours[0] is this node itself"),
    (("neighbours = [1]", "neighbours = [1, 1]"), "cam0.toml: neighbours[1] repeats neighbour 1"),
    (("node = 0", "node = -1"), "cam0.toml: node must be a non-negative integer"),
    (("[zenoh]", "[zenoh]\nlissen = []"), "cam0.toml: zenoh.lissen is not a known field"),
    (("[source]", "[runtime]\nmode = \"fast\"\n[source]"),
     "cam0.toml: runtime.mode must be one of 'sync', 'async', got 'fast'"),
    (("[source]", "[runtime]\nsync_timeout_s = 0\n[source]"), "cam0.toml: runtime.sync_timeout_s must be > 0"),
    (('kind = "det-file"', 'kind = "hologram"'), "cam0.toml: source.kind must be one of"),
    (('path = "EXPORT"', 'path = "nowhere"'), "cam0.toml: source.path does not exist"),
    (("[source]", "[tracker]\ntau = -1\n[source]"), "cam0.toml: tracker.tau must be a positive number"),
    (("[source]", "[tracker]\nablation = \"x\"\n[source]"), "cam0.toml: tracker.ablation must be one of"),
    (("[source]", "[tracker]\ntua = 1\n[source]"), "cam0.toml: tracker: unknown parameter(s) tua"),
    (("[source]", "[camera]\nhomography = [[1, 0], [0, 1]]\nimage_size = [10, 10]\n[source]"),
     "cam0.toml: camera.homography must be a 3x3"),
    (("[source]", "[zenoh2]\n[source]"), "cam0.toml: zenoh2 is not a known field"),
])
def test_config_errors_name_file_and_field(tmp_path, export_dir, edit, expected):
    text = BASE.replace(*edit, 1).replace("EXPORT", str(export_dir))
    p = tmp_path / "cam0.toml"
    p.write_text(text)
    with pytest.raises(NodeConfigError) as e:
        load_node_config(p)
    assert str(e.value).startswith(expected), str(e.value)


def test_config_missing_source_and_bad_toml(tmp_path):
    p = tmp_path / "cam0.toml"
    p.write_text('node = 0\nnetwork = "n"\n')
    with pytest.raises(NodeConfigError, match=r"^cam0.toml: source is required"):
        load_node_config(p)
    p.write_text("node = \n")
    with pytest.raises(NodeConfigError, match=r"^cam0.toml: not valid TOML"):
        load_node_config(p)
    with pytest.raises(NodeConfigError, match="config file not found"):
        load_node_config(tmp_path / "nope.toml")


def test_config_defaults_and_relative_paths(tmp_path, export_dir):
    (tmp_path / "data").symlink_to(export_dir)
    p = tmp_path / "cam3.toml"
    p.write_text('node = 3\nnetwork = "n"\nneighbours = [2, 0]\n[source]\nkind = "det-file"\n'
                 'path = "data"\ncamera = 1\n[tracker]\nablation = "dkf"\nkappa = 9\n'
                 '[output]\ndir = "out"\n')
    cfg = load_node_config(p)
    assert cfg.neighbours == (0, 2) and cfg.runtime.mode == "sync"
    assert cfg.runtime.sync_timeout_s == 1.0 and cfg.runtime.startup_timeout_s == 5.0
    assert cfg.zenoh.scouting is False and cfg.zenoh.listen == ()
    assert cfg.zenoh.shared_memory is False
    assert cfg.source.path == tmp_path / "data" / "calibration.json"
    assert cfg.output.dir == tmp_path / "out"
    assert cfg.tracker.kappa == 9 and not cfg.tracker.use_manager and cfg.ablation == "dkf"
    src = open_source(cfg)
    assert src.camera.id == 3 and src.frames == FRAMES  # camera index 1 played by node 3
    json.dumps(cfg.to_dict())


def test_cli_check(tmp_path, export_dir, capsys):
    from edge_node.cli import main

    p = tmp_path / "cam0.toml"
    p.write_text(BASE.replace("EXPORT", str(export_dir)))
    assert main(["check", "--config", str(p)]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["node"] == 0 and out["resolved"]["frames"] == FRAMES
    p.write_text(BASE.replace("EXPORT", str(export_dir)).replace("tcp/127.0.0.1:7447", "x"))
    assert main(["check", "--config", str(p)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "zenoh.listen[0]" in err


@pytest.mark.parametrize("source, message", [
    ('kind = "scenario"\nscenario = "nope-sim"\n',
     "cam0.toml: source.scenario: nope-sim: unknown scenario preset"),
    ('kind = "scenario"\nscenario = "lab-sim"\ncamera = 42\n',
     "cam0.toml: source.camera is 42, but scenario lab-sim has 4 cameras (0..3)"),
    ('kind = "det-file"\npath = "EXPORT"\ncamera = 7\n',
     "cam0.toml: source.camera is 7, but EXPORT/calibration.json has 4 cameras (0..3)"),
])
def test_check_rejects_what_run_rejects(tmp_path, export_dir, capsys, source, message):
    """``edge_node check`` passed a config whose scenario does not exist or whose camera index
    is out of range, which ``edge_node run`` then refused: both now open the source the same
    way (``edge_node/runtime/preflight.py``) and stop with the same one line, exit status 2."""
    from edge_node.cli import main

    p = tmp_path / "cam0.toml"
    p.write_text('node = 0\nnetwork = "net"\n[source]\n' + source.replace("EXPORT", str(export_dir)))
    assert main(["check", "--config", str(p)]) == 2
    check = capsys.readouterr().err.splitlines()
    assert main(["run", "--config", str(p)]) == 2  # stops before it opens a Zenoh session
    run = capsys.readouterr().err.splitlines()
    assert len(check) == 1 and check[0].startswith(
        "edge_node: error: " + message.replace("EXPORT", str(export_dir))), check
    assert run[-1] == check[0]


def test_check_rejects_a_det_file_folder_with_a_nan_box(tmp_path, export_dir, capsys):
    import shutil

    from edge_node.cli import main

    data = tmp_path / "data"
    shutil.copytree(export_dir, data)
    det = data / "c0" / "det.txt"
    rows = det.read_text().splitlines()
    f = rows[4].split(",")
    f[3] = "inf"
    rows[4] = ",".join(f)
    det.write_text("\n".join(rows) + "\n")
    p = tmp_path / "cam0.toml"
    p.write_text(BASE.replace("EXPORT", str(data)))
    assert main(["check", "--config", str(p)]) == 2
    assert capsys.readouterr().err.splitlines() == [
        f"edge_node: error: cam0.toml: source.path: {det}:5: det.txt field 'y' must be a finite "
        "number, got inf"]


def test_async_heartbeat_as_long_as_kappa_is_refused_by_check_and_run(tmp_path, capsys):
    """``[runtime] heartbeat_frames`` must be below ``[tracker] kappa`` in async mode (a
    neighbour forgets an entry kappa frames after it); check and run say so, naming the field."""
    from edge_node.cli import main

    p = tmp_path / "cam0.toml"
    p.write_text('node = 0\nnetwork = "net"\n[source]\nkind = "scenario"\nscenario = "lab-sim"\n'
                 '[runtime]\nmode = "async"\nheartbeat_frames = 15\n[tracker]\nkappa = 15\n')
    assert main(["check", "--config", str(p)]) == 2
    check = capsys.readouterr().err.splitlines()
    assert main(["run", "--config", str(p)]) == 2
    run = capsys.readouterr().err.splitlines()
    assert len(check) == 1 and "cam0.toml: runtime.heartbeat_frames must be below tracker.kappa " \
        "(15)" in check[0], check
    assert run[-1] == check[0]
    p.write_text(p.read_text().replace("heartbeat_frames = 15", "heartbeat_frames = 14"))
    assert main(["check", "--config", str(p)]) == 2  # receivers hold ell 5 frames (hold_frames)
    assert "runtime.heartbeat_frames must be at most tracker.hold_frames (5)" in capsys.readouterr().err
    p.write_text(p.read_text().replace("kappa = 15", "kappa = 15\nhold_frames = 14"))
    assert main(["check", "--config", str(p)]) == 0


@pytest.mark.parametrize("state, why", [
    (b"\xff\xfe\x00garbage\x80\x81", "STATE:1: not UTF-8 text: byte 0xff at offset 0 (a binary "
                                     "file, or another encoding)"),
    (b'{"next_counter": -3}', "next_counter must be a whole number in 0..2**63-1, got -3"),
    (b'{"next_counter": 2.5}', "next_counter must be a whole number in 0..2**63-1, got 2.5"),
])
def test_a_corrupt_state_file_is_one_line_naming_it(tmp_path, export_dir, capsys, state, why):
    """A restarted node resumes its id counter from state_node<id>.json: one of binary bytes
    was refused with Python's decoder message; a negative counter was taken (the message
    encoder refuses the id of the node's first new tracker) and 2.5 read as 2."""
    from edge_node.cli import main

    out = tmp_path / "out"
    out.mkdir()
    (out / "state_node0.json").write_bytes(state)
    p = tmp_path / "cam0.toml"
    p.write_text(BASE.replace("EXPORT", str(export_dir)) + f'[output]\ndir = "{out}"\n')
    assert main(["check", "--config", str(p)]) == 2
    why = why.replace("STATE", str(out / "state_node0.json"))
    assert capsys.readouterr().err.splitlines() == [
        f"edge_node: error: cam0.toml: output.dir has an unreadable state_node0.json ({why}); "
        "remove it to start the id counter at 0"]
