"""Topologies (``sim_cluster/network/topology.py``): edge-list files are checked line by line."""
from __future__ import annotations

import pytest

from sim_cluster import cli
from sim_cluster.network.topology import TopologyError, build


def edges(tmp_path, text: str):
    p = tmp_path / "edges.txt"
    p.write_text(text)
    return p


def test_an_edge_list_in_every_spelling(tmp_path):
    p = edges(tmp_path, "# a chain\n0 1\n1-2  # dash\n\n2,3\n")
    assert build(str(p), 5) == {0: (1,), 1: (0, 2), 2: (1, 3), 3: (2,), 4: ()}


@pytest.mark.parametrize("text, message", [
    ("0 1\n0 0\n", ":2: edge 0-0 joins node 0 to itself"),  # was silently dropped
    ("0 1\n1 2\n2-1\n", ":3: edge 2-1 repeats line 2"),
    ("0 1\n# x\n0 1\n", ":3: edge 0-1 repeats line 1"),
    ("0 1\n1 4\n", ":2: node 4 is not in 0..3"),
    ("-1 2\n", ":1: node -1 is not in 0..3"),  # was read as the edge 1-2
    ("0 1 2\n", ":1: expected two node ids, got '0 1 2'"),
    ("a b\n", ":1: expected two node ids, got 'a b'"),
])
def test_a_bad_edge_names_the_file_and_line(tmp_path, text, message):
    p = edges(tmp_path, text)
    with pytest.raises(TopologyError) as e:
        build(str(p), 4)
    assert str(e.value) == f"{p}{message}"


def test_a_self_loop_on_the_command_line_is_exit_2(tmp_path, capsys):
    p = edges(tmp_path, "0 1\n0 0\n")
    assert cli.main(["run", "--scenario", "lab-sim", "--frames", "2", "--quiet", "--topology",
                     str(p), "--out", str(tmp_path / "out")]) == 2
    assert capsys.readouterr().err.splitlines() == [
        f"sim_cluster: error: {p}:2: edge 0-0 joins node 0 to itself"]
    assert not (tmp_path / "out").exists()


def test_binary_bytes_in_an_edge_list_name_the_line_and_offset(tmp_path):
    """An edge list of binary bytes was a UnicodeDecodeError traceback (and was decoded in the
    locale's encoding, not UTF-8)."""
    p = tmp_path / "edges.txt"
    p.write_bytes(b"0 1\n\xff\xfe\x00garbage\x80\x81\n")
    with pytest.raises(TopologyError) as e:
        build(str(p), 4)
    assert str(e.value) == (f"{p}:2: not UTF-8 text: byte 0xff at offset 4 (a binary file, or "
                            "another encoding)")
