"""Files that survive crashes and full disks: the track file holds whole rows only, a torn last
line is repaired before a restart appends, readers skip a bad row and name it, the status,
counters and id-counter files are replaced atomically and still written on a full disk, and a
node's way out closes everything whatever fails (``edge_node/formats/tracks.py``,
``edge_node/runtime/output.py``, ``edge_node/runtime/loop.py``)."""
from __future__ import annotations

import errno
import json
import logging
import os
import subprocess
import uuid
from pathlib import Path

import numpy as np
import pytest

from edge_node.core.types import Track
from edge_node.formats import tracks as tracks_mod
from edge_node.formats.tracks import HEADER, TrackWriter, read_tracks
from edge_node.runtime.output import ReservedJson, clean_temporaries, write_json_atomic

X = np.array([1.0, 2.0, 0.5, 1.7, 0.1, -0.2])


def frame(k: int, n: int = 3) -> list[Track]:
    return [Track((1, c), k, X + c, np.eye(6), True, 0) for c in range(n)]


def rows_of(path: Path) -> list[str]:
    data = path.read_bytes()
    assert data.endswith(b"\r\n"), f"{path} ends mid-row: {data[-40:]!r}"
    lines = data.decode().split("\r\n")[:-1]
    assert lines[0] == ",".join(HEADER)
    assert all(len(line.split(",")) == len(HEADER) for line in lines[1:]), "a row not whole"
    return lines[1:]


class Clock:
    t = 0.0

    def __call__(self):
        return self.t


@pytest.fixture
def tmpfs(tmp_path):
    """A small tmpfs of our own (a disk that fills), unmounted afterwards."""
    mnt = tmp_path / "small"
    mnt.mkdir()
    r = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=256k", "tmpfs", str(mnt)],
                       capture_output=True, text=True)
    if r.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs to fill (needs root): {r.stderr.strip()}")
    try:
        yield mnt
    finally:
        subprocess.run(["umount", "-l", str(mnt)], capture_output=True)


def fill(mnt: Path) -> Path:
    """Fill the file system up to the last byte."""
    filler = mnt / f"filler-{uuid.uuid4().hex}"
    fd = os.open(filler, os.O_WRONLY | os.O_CREAT)
    try:
        while True:
            os.write(fd, b"\0" * 512)
    except OSError as e:
        assert e.errno == errno.ENOSPC
    finally:
        os.close(fd)
    return filler


# -- the track file ------------------------------------------------------------------------------
def test_a_write_cut_short_leaves_whole_rows_and_the_rows_wait(tmp_path, monkeypatch):
    path = tmp_path / "tracks_node1.csv"
    clock = Clock()
    w = TrackWriter(path, clock=clock)
    w.write(frame(0))
    assert w.flush()
    real_write = os.write
    calls = {"n": 0}

    def full_disk(fd, data):  # writes a part, then the disk is full (what write(2) does)
        calls["n"] += 1
        if calls["n"] == 1:
            return real_write(fd, bytes(data[:17]))
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(tracks_mod.os, "write", full_disk)
    w.write(frame(1))
    assert not w.flush() and w.failing and "ENOSPC" in w.error
    assert len(rows_of(path)) == 3  # the 17 bytes written were cut back: whole rows only
    w.write(frame(2))
    clock.t += 0.1
    assert not w.flush() and calls["n"] == 2  # backing off: not retried before its time
    monkeypatch.setattr(tracks_mod.os, "write", real_write)
    clock.t += 10.0
    assert w.flush() and not w.failing  # the disk has room again: every waiting row written
    w.close()
    back = read_tracks(path)
    assert [len(f) for f in back] == [3, 3, 3] and w.frames_dropped == 0


def test_rows_that_wait_are_bounded_and_the_oldest_dropped_counted(tmp_path, monkeypatch):
    path = tmp_path / "t.csv"
    w = TrackWriter(path, max_pending_bytes=2000)
    monkeypatch.setattr(tracks_mod.os, "write",
                        lambda fd, d: (_ for _ in ()).throw(OSError(errno.ENOSPC, "full")))
    for k in range(20):
        w.write(frame(k))
    assert w.pending_bytes <= 2000 and w.frames_dropped > 0
    assert not w.close()  # never raises; says the rows were not written


def test_a_full_disk_then_freed_keeps_whole_rows_and_the_status_written(tmpfs):
    path = tmpfs / "tracks_node1.csv"
    status = ReservedJson(tmpfs / "status_node1.json")
    status.write({"phase": "running"})
    clock = Clock()
    w = TrackWriter(path, clock=clock)
    w.write(frame(0, n=9))
    assert w.flush()
    filler = fill(tmpfs)
    k = 1
    while not w.failing:  # a disk full at whatever byte the next chunk crosses it
        for _ in range(40):
            w.write(frame(k, n=9))
            k += 1
        w.flush()
    rows_of(path)
    status.write({"phase": "degraded", "why": w.error})  # its space was reserved
    assert json.loads((tmpfs / "status_node1.json").read_text())["phase"] == "degraded"
    filler.unlink()
    clock.t += 60.0
    assert w.flush()
    w.close()
    got = read_tracks(path)
    assert len(got) == k and all(len(f) == 9 for f in got)


def test_a_torn_last_line_is_cut_before_a_restart_appends(tmp_path, caplog):
    path = tmp_path / "tracks_node2.csv"
    with TrackWriter(path) as w:
        for k in range(5):
            w.write(frame(k))
    whole = path.stat().st_size
    with open(path, "ab") as f:
        f.write(b"217,4,0,")  # killed mid-row
    with caplog.at_level(logging.WARNING, "edge_node.formats"):
        w = TrackWriter(path, append=True)
    assert f"{path}" in caplog.text and f"at byte {whole}" in caplog.text
    assert w.last_frame == 4  # a restarted node starts after it
    w.write(frame(5))
    w.close()
    assert len(rows_of(path)) == 18 and [len(f) for f in read_tracks(path)] == [3] * 6


def test_a_rotated_file_tells_the_last_frame_too(tmp_path):
    path = tmp_path / "t.csv"
    with TrackWriter(path, rotate_bytes=200, keep=2) as w:
        for k in range(4):
            w.write(frame(k))
    assert rows_of(path) == []  # rotated after the last frame: only a header here
    assert TrackWriter(path, append=True).last_frame == 3


def test_a_reader_skips_a_bad_row_and_names_it(tmp_path, caplog):
    path = tmp_path / "t.csv"
    with TrackWriter(path) as w:
        w.write(frame(0))
        w.write(frame(1))
    text = path.read_bytes().split(b"\r\n")
    text.insert(2, b"217,4,0,1,2,3,4,5,6,7,8,9,10,11,12,13,14,15,16,0.887428")  # 20 fields
    text.insert(4, b"\xff\xfe\x00garbage\x80")
    path.write_bytes(b"\r\n".join(text))
    with caplog.at_level(logging.WARNING, "edge_node.formats"):
        back = read_tracks(path)
    assert [len(f) for f in back] == [3, 3]
    assert "skipped 2 row(s)" in caplog.text and "line(s) 3, 5" in caplog.text


# -- small JSON files ------------------------------------------------------------------------------
def test_reserved_json_is_replaced_atomically_and_reads_back(tmp_path):
    f = ReservedJson(tmp_path / "status_node0.json", reserve=4096)
    for i in range(3):
        f.write({"i": i, "pad": "x" * i})
        assert json.loads((tmp_path / "status_node0.json").read_text()) == {"i": i, "pad": "x" * i}
    spare = tmp_path / ".status_node0.json.spare"
    assert spare.stat().st_size == 4096 and not (tmp_path / ".status_node0.json.prev").exists()
    f.write({"big": "y" * 5000})  # beyond the reserve: a plain atomic write
    assert json.loads((tmp_path / "status_node0.json").read_text())["big"] == "y" * 5000


def test_a_failed_atomic_write_leaves_no_temporary(tmp_path, monkeypatch):
    def refuse(src, dst):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(os, "replace", refuse)
    with pytest.raises(OSError):
        write_json_atomic(tmp_path / "counters_node2.json", {"a": 1})
    assert list(tmp_path.iterdir()) == []


def test_temporaries_of_an_earlier_life_are_cleaned(tmp_path):
    stale = tmp_path / ".status_node2.json.4242.tmp"
    stale.write_bytes(b"")
    other = tmp_path / ".status_node3.json.4242.tmp"  # another node's: not ours to remove
    other.write_bytes(b"")
    assert clean_temporaries(tmp_path, 2) == [stale]
    assert not stale.exists() and other.exists()


# -- a node's way out --------------------------------------------------------------------------------
class FakeTransport:
    neighbours = ()

    def __init__(self, status_file: Path):
        self.status_file = status_file
        self.phase_at_close = None
        self.closed = False

    def __call__(self, *a, **k):  # the transport factory
        return self

    def counters(self):
        return {"bytes_sent": 0}

    def latency_samples(self):
        return np.zeros(0)

    def close(self):
        self.closed = True
        self.phase_at_close = json.loads(self.status_file.read_text())["phase"]


def test_every_way_out_closes_the_transport_first_and_runs_every_step(tmp_path, monkeypatch):
    """An internal error inside a frame, and a Rerun sink whose close fails too: the transport
    is closed first (its liveliness token withdrawn while the node still says 'running'), then
    the status and counters files say what happened, the track file holds the frames done,
    whole, and the error reaches the caller (before: a failing close in the way out masked the
    rest and left the Zenoh session open: a hung process that looked alive)."""
    from edge_node.runtime import loop as loop_mod
    from edge_node.runtime.config import load_node_config
    from tests.loopback import export_scenario

    export = export_scenario(tmp_path / "export", 10)
    out = tmp_path / "out"
    cfg_path = tmp_path / "cam0.toml"
    cfg_path.write_text(f'node = 0\nnetwork = "x"\nneighbours = []\n[source]\nkind = "det-file"\n'
                        f'path = "{export}"\n[output]\ndir = "{out}"\n')
    real_output = loop_mod.FrameLoop._output

    def boom(self, k, tracks):
        if k == 3:
            raise RuntimeError("boom")
        real_output(self, k, tracks)

    class BadSink:
        enabled, url, dropped = False, None, 0

        def close(self):
            raise RuntimeError("viewer gone")

    monkeypatch.setattr(loop_mod.FrameLoop, "_output", boom)
    monkeypatch.setattr(loop_mod, "open_node_sink", lambda *a, **k: BadSink())
    fake = FakeTransport(out / "status_node0.json")
    with pytest.raises(RuntimeError, match="boom"):
        loop_mod.run_node(load_node_config(cfg_path), transport_factory=fake,
                          install_signals=False)
    assert fake.closed and fake.phase_at_close == "running"
    st = json.loads((out / "status_node0.json").read_text())
    assert st["phase"] == "failed" and st["error"] == "RuntimeError: boom" and st["exit_code"] == 1
    assert json.loads((out / "counters_node0.json").read_text())["exit_code"] == 1
    back = read_tracks(out / "tracks_node0.csv")  # frames 0-2 done (tracks from frame 1 on)
    assert len(back) == 3 and back[2] and rows_of(out / "tracks_node0.csv")
