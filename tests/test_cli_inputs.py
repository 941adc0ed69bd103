"""What a user types into ``sim_cluster`` is checked before anything runs or is written: every
numeric option names itself when it is wrong. No process is started here."""
from __future__ import annotations

import os
import pytest

from sim_cluster import cli


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
def test_a_bad_number_on_the_command_line_names_the_option(tmp_path, capsys, argv, message):
    """``--frames -5`` used to be blamed on the scenario file ('lab-sim.toml: frames must be
    ...'); a negative timeout was found by every node after the launcher had started them; a
    negative --targets or --neighbours ended ``bench`` in a traceback."""
    os.chdir(tmp_path)  # nothing may be written, wherever it would go
    assert cli.main(argv) == 2
    assert capsys.readouterr().err.splitlines() == [f"sim_cluster: error: {message}"]
    assert list(tmp_path.iterdir()) == []
