"""The one validating TOML reader (``edge_node/settings.py``) that camera configs, fault plans,
scenarios and tracker files share: errors name the file and the field, a misspelt field's error
lists every known one, and the core's parameter rules come through as the file's errors."""
from __future__ import annotations

import pytest

from edge_node.core.config import TrackerConfig
from edge_node.core.params import build
from edge_node.core.trigger import TriggerConfig
from edge_node.faults import FaultPlan, FaultPlanError
from edge_node.runtime.config import NodeConfigError
from edge_node.settings import SettingsError, Table, read_toml
from sim_cluster.experiments.run import tracker_config
from sim_cluster.scenarios.files import ScenarioError


def test_every_file_kind_raises_its_own_settings_error():
    for cls in (NodeConfigError, FaultPlanError, ScenarioError):
        e = cls("f.toml", "a.b", "must be x")
        assert isinstance(e, SettingsError) and isinstance(e, ValueError)
        assert (str(e), e.file, e.field) == ("f.toml: a.b must be x", "f.toml", "a.b")
    assert str(SettingsError("f.toml", None, "bad")) == "f.toml: bad"


def test_errors_name_file_and_nested_field():
    t = Table({"cams": [{"fov": 200}], "area": {"x": "a"}}, "s.toml", error=ScenarioError)
    with pytest.raises(ScenarioError, match=r"^s.toml: cams\[0\].fov must be in \(0, 180\), got 200$"):
        t.tables("cams")[0].number("fov", lo=0, hi=180, lo_open=True, hi_open=True)
    with pytest.raises(ScenarioError, match=r"^s.toml: area.x must be a number, got 'a'$"):
        t.table("area").number("x")
    with pytest.raises(ScenarioError, match=r"^s.toml: area.y is required$"):
        t.table("area").number("y")
    with pytest.raises(ScenarioError, match=r"^s.toml: area: needs x or y$"):
        raise t.table("area").error(None, "needs x or y")


def test_a_misspelt_field_lists_every_known_one_read_or_declared():
    t = Table({"mode": "sync", "sync_timout_s": 2.0}, "cam0.toml", "runtime")
    t.string("mode", "sync", choices=("sync", "async"))
    t.number("sync_timeout_s", 1.0)  # absent: its default, and known
    t.declare("homography", "position")  # another branch's fields
    with pytest.raises(SettingsError) as e:
        t.finish()
    assert str(e.value) == ("cam0.toml: runtime.sync_timout_s is not a known field (known: "
                            "homography, mode, position, sync_timeout_s)")


def test_absent_fields_give_their_defaults_and_present_ones_are_checked():
    t = Table({"n": 3, "flag": True, "name": "x", "span": [1, 2], "v": [1, 2, 3]}, "f.toml")
    assert t.integer("n", 0, lo=1) == 3 and t.integer("m", 7) == 7
    assert t.boolean("flag") is True and t.string("name") == "x" and t.string("other", None) is None
    assert t.span("span") == (1.0, 2.0) and list(t.vector("v", 3)) == [1, 2, 3]
    assert t.probability("p", 0.5) == 0.5 and t.optional_table("sub") is None
    assert t.tables("rows", required=False) == []
    t.finish()
    with pytest.raises(SettingsError, match=r"^f.toml: p must be a probability in \[0, 1\], got 2"):
        Table({"p": 2}, "f.toml").probability("p")
    with pytest.raises(SettingsError, match=r"^f.toml: mode must be one of 'a', 'b', got 'c'"):
        Table({"mode": "c"}, "f.toml").string("mode", choices=("a", "b"))


def test_core_parameter_rules_become_the_files_errors():
    t = Table({"tau": -1}, "cam0.toml", "tracker")
    with pytest.raises(SettingsError, match=r"^cam0.toml: tracker.tau must be a positive number"):
        t.built(lambda: TrackerConfig.from_dict(t.data))
    t = Table({"tua": 1}, "cam0.toml", "tracker")
    with pytest.raises(SettingsError, match=r"^cam0.toml: tracker: unknown parameter\(s\) tua "
                                            r"\(did you mean tau\?\); every parameter is in one "
                                            r"section of \[tracker.scene\], .*\[tracker.reporter\]"):
        t.built(lambda: TrackerConfig.from_dict(t.data))
    # a table that spells a field its own way: the error uses the table's name for it
    t = Table({"drift_m": 0}, "cam0.toml", "runtime")
    with pytest.raises(SettingsError, match=r"^cam0.toml: runtime.drift_m must be a positive"):
        t.built(lambda: build(TriggerConfig, {"drift": t.raw("drift_m")}, "runtime"),
                keys={"drift": "drift_m"})


def test_read_toml_names_the_file(tmp_path):
    bad = tmp_path / "x.toml"
    bad.write_text("a = \n")
    with pytest.raises(ScenarioError, match=r"^x.toml: invalid TOML"):
        read_toml(bad, ScenarioError, invalid="invalid TOML")
    with pytest.raises(NodeConfigError, match=r"^y.toml: config file not found: "):
        read_toml(tmp_path / "y.toml", NodeConfigError, what="config file")
    bad.write_text("[[link]]\nloss = 0.1\nlos = 0.2\n")
    with pytest.raises(FaultPlanError, match=r"x.toml: link\[0\].los is not a known field \(known: "
                                             r"delay, dst, duplicate, jitter, loss, src, start, "
                                             r"stop\)"):
        FaultPlan.load(bad)


def test_tracker_file_over_an_ablation(tmp_path):
    f = tmp_path / "t.toml"
    f.write_text("[tracker]\nkappa = 9\n")
    cfg = tracker_config("dkf", f)
    assert cfg.kappa == 9 and not cfg.use_manager
    f.write_text("kapa = 9\n")
    with pytest.raises(SettingsError, match=f"^{f}: tracker: unknown parameter"):
        tracker_config("dkf", f)


GARBAGE = b"\xff\xfe\x00garbage\x80\x81"


def test_binary_bytes_in_any_settings_file_are_its_error_naming_line_and_offset(tmp_path):
    """Bytes that are not UTF-8 in a camera config, fault plan, scenario or tracker file used
    to end in a UnicodeDecodeError traceback; they are the file's own error now, naming the
    line and the byte offset of the first bad byte."""
    from edge_node.runtime.config import load_node_config
    from sim_cluster.scenarios.loader import load_scenario

    f = tmp_path / "x.toml"
    f.write_bytes(b"# fine\nnode = 0\n" + GARBAGE)
    problem = "line 3: not UTF-8 text: byte 0xff at offset 16 (a binary file, or another encoding)"
    for call, cls, name in ((lambda: load_node_config(f), NodeConfigError, "x.toml"),
                            (lambda: FaultPlan.load(f), FaultPlanError, str(f)),
                            (lambda: load_scenario(f), ScenarioError, "x.toml"),
                            (lambda: tracker_config("dkf", f), SettingsError, str(f))):
        with pytest.raises(cls) as e:
            call()
        assert str(e.value) == f"{name}: {problem}"
