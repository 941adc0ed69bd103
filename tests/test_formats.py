"""File formats (``edge_node/formats``), shared by camera processes and the simulator: the track
file, det-files, ``calibration.json`` and EPFL's ``homographies.json``."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from edge_node.core.config import TrackerConfig
from edge_node.core.types import Track
from edge_node.formats.calibration import (CALIBRATION, camera_entry, read_calibration,
                                           write_calibration)
from edge_node.formats.detfile import DetFilesError, write_gt_ground
from edge_node.formats.homographies import (HomographiesError, read_homographies,
                                            sequence_cameras, sequence_entry)
from edge_node.formats.tracks import HEADER, TrackWriter, read_tracks, write_tracks
from edge_node.geometry import Camera
from sim_cluster.network.inprocess import run_network
from sim_cluster.scenarios.detfiles import load_det_files
from tests.loopback import export_scenario

FRAMES = 40


@pytest.fixture(scope="module")
def export_dir(tmp_path_factory) -> Path:
    return export_scenario(tmp_path_factory.mktemp("export"), FRAMES)


# -- track files ----------------------------------------------------------------------------------
def test_track_writer_matches_sim_cluster(tmp_path, export_dir):
    r = run_network(load_det_files(export_dir), {0: (1,), 1: (0,), 2: (), 3: ()}, TrackerConfig(),
                    frames=10)
    write_tracks(tmp_path / "ref.csv", r.tracks[0])
    with TrackWriter(tmp_path / "mine.csv") as w:
        for frame in r.tracks[0]:
            w.write(frame)
    assert (tmp_path / "ref.csv").read_bytes() == (tmp_path / "mine.csv").read_bytes()


def test_track_file_reads_back_and_a_restart_appends(tmp_path):
    x = np.array([1.0, 2.0, 0.5, 1.7, 0.1, -0.2])
    t0 = Track((1, 2), 0, x, np.eye(6), True, 0)
    t1 = Track((3, 4), 1, x + 1, np.eye(6), False, 2)
    path = tmp_path / "tracks_node0.csv"
    with TrackWriter(path) as w:
        w.write([t0])
    with TrackWriter(path, append=True) as w:  # a restarted node continues the file
        w.write([t1])
    assert path.read_text().splitlines()[0] == ",".join(HEADER)
    back = read_tracks(path, 3)
    assert [[t.id for t in f] for f in back] == [[(1, 2)], [(3, 4)], []]
    assert np.allclose(back[1][0].x, x + 1) and back[1][0].ell == 2 and not back[1][0].observed
    (tmp_path / "bad.csv").write_text("a,b\n")
    with pytest.raises(ValueError, match="not a track file"):
        read_tracks(tmp_path / "bad.csv")


def test_track_file_rotates_by_size_keeping_whole_frames(tmp_path):
    x = np.array([1.0, 2.0, 0.5, 1.7, 0.1, -0.2])
    path = tmp_path / "tracks_node0.csv"
    row_bytes = len("0,1000002,1,2,1.000000,2.000000,0.500000,1.700000,0.100000,-0.200000,1,0,,,,\r\n")
    frames = 40
    with TrackWriter(path, rotate_bytes=10 * row_bytes, keep=2) as w:  # ~9 two-row frames a file
        for k in range(frames):
            w.write([Track((1, 2), k, x, np.eye(6), True, 0), Track((1, 3), k, x, np.eye(6), True, 0)])
    files = [path, path.with_name(path.name + ".1"), path.with_name(path.name + ".2")]
    assert all(f.exists() for f in files) and not path.with_name(path.name + ".3").exists()
    seen = []
    for f in reversed(files):  # oldest kept first
        lines = f.read_text().splitlines()
        assert lines[0] == ",".join(HEADER)  # every file reads on its own
        ks = [int(line.split(",")[0]) for line in lines[1:]]
        assert all(ks.count(k) == 2 for k in set(ks))  # whole frames only
        seen += sorted(set(ks))
    assert seen == list(range(seen[0], frames))  # newest frames kept, in order, none lost between
    # the header is shorter than a row, so the 5th two-row frame passes 10 rows' bytes: a file
    # holds 5 frames, 40 frames make 8 rotations, and the last two full files are 30..39
    assert len(",".join(HEADER)) + 2 < row_bytes
    assert w.rotations == frames // 5 and seen == list(range(frames - 10, frames))
    # logrotate moved the file away: reopen starts a fresh one with a header
    with TrackWriter(path) as w:
        w.write([Track((1, 2), 0, x, np.eye(6), True, 0)])
        path.rename(tmp_path / "moved.csv")
        w.reopen()
        w.write([Track((1, 2), 1, x, np.eye(6), True, 0)])
    assert [[t.frame for t in f] for f in read_tracks(path, 2)] == [[], [1]]
    assert [[t.frame for t in f] for f in read_tracks(tmp_path / "moved.csv", 2)] == [[0], []]


# -- calibration.json -----------------------------------------------------------------------------
def _camera(cid: int) -> Camera:
    return Camera(id=cid, image_size=(360, 288), G=np.diag([0.01, 0.01, 1.0]), fps=25.0)


def test_calibration_round_trip_and_frame_count_from_the_files(tmp_path):
    entries = [camera_entry(_camera(c), f"c{c}/det.txt", f"c{c}/gt.txt") for c in range(2)]
    cal_path = write_calibration(tmp_path, name="x", frames=7, fps=12.5, units_per_metre=30.0,
                                 area=(0, 1, 2, 3), seed=4, cameras=entries)
    assert cal_path == tmp_path / CALIBRATION
    cal = read_calibration(tmp_path)
    assert (cal.name, cal.frames, cal.fps, cal.units_per_metre, cal.seed) == ("x", 7, 12.5, 30.0, 4)
    assert cal.area == (0.0, 1.0, 2.0, 3.0) and [c.id for c in cal.cameras] == [0, 1]
    assert cal.files[1].det == tmp_path / "c1/det.txt" and not cal.files[1].descriptors_required
    assert cal.files[1].descriptors == tmp_path / "c1/det.npy"
    doc = json.loads(cal_path.read_text())
    del doc["frames"]  # then: the last frame in any file
    cal_path.write_text(json.dumps(doc))
    write_gt_ground(tmp_path / "gt_ground.csv", [np.array([1])] * 9, [np.zeros((1, 2))] * 9,
                    [np.ones((1, 2))] * 9)
    assert read_calibration(cal_path).frame_count() == 9


@pytest.mark.parametrize("doc, message", [
    ("{", "not valid JSON"),
    ('{"cameras": []}', "'cameras' must be a non-empty list"),
    ('{"cameras": [{"image_size": [1, 2]}]}', "cameras[0] lacks field 'G'"),
    ('{"cameras": [{"G": [[1, 0, 0], [0, 1, 0], [0, 0, 1]]}]}', "cameras[0].image_size"),
    ('{"units_per_metre": 0, "cameras": [{"image_size": [4, 4], '
     '"G": [[1, 0, 0], [0, 1, 0], [0, 0, 1]]}]}', "units_per_metre must be positive"),
    *[('{"frames": %s, "cameras": [{"image_size": [4, 4], '
       '"G": [[1, 0, 0], [0, 1, 0], [0, 0, 1]]}]}' % v,
       f"frames must be a whole number in 1..1000000000 (MAX_FRAME), got {got}")
      for v, got in (("1e12", "1000000000000.0"), ("0", "0"), ("-3", "-3"), ("2.5", "2.5"),
                     ('"ten"', "'ten'"), ("true", "True"), ("1e999", "inf"), ("NaN", "nan"))],
])
def test_calibration_errors_name_the_file_and_field(tmp_path, doc, message):
    (tmp_path / CALIBRATION).write_text(doc)
    with pytest.raises(DetFilesError) as e:
        read_calibration(tmp_path)
    assert str(tmp_path / CALIBRATION) in str(e.value) and message in str(e.value)
    with pytest.raises(DetFilesError, match="calibration file not found"):
        read_calibration(tmp_path / "elsewhere")


# -- EPFL homographies.json ------------------------------------------------------------------------
def test_homographies_cameras_of_a_sequence_and_errors(tmp_path):
    path = tmp_path / "homographies.json"
    path.write_text(json.dumps({"_doc": "x", "terrace": {
        "sequence": "terrace1", "image_scale": 2.0, "image_size_annotations": [64, 48],
        "H": [np.eye(3).tolist(), [[1, 0, 0], [0, 2, 0], [0, 0, 1]]]}}))
    doc = read_homographies(path)
    cams = sequence_cameras(sequence_entry(doc, "terrace", path), "terrace", path, fps=10.0)
    assert [c.id for c in cams] == [0, 1] and cams[1].G[1, 1] == 2.0
    assert cams[0].pixel_scale == 2.0 and cams[0].image_size == (64, 48) and cams[0].fps == 10.0
    assert sequence_entry(doc, "terrace1", path, loose=True) is doc["terrace"]  # a video's name
    with pytest.raises(HomographiesError, match=r"no sequence 'terrace1' \(has \['terrace'\]\)"):
        sequence_entry(doc, "terrace1", path)
    with pytest.raises(HomographiesError, match=r"campus.H \(per-camera homographies\) is missing"):
        sequence_cameras({}, "campus", path, fps=25.0)
    with pytest.raises(HomographiesError, match=r"terrace.H\[0\]"):
        sequence_cameras({"H": [[[1, 0], [0, 1]]]}, "terrace", path, fps=25.0)


def test_binary_calibration_or_homographies_json_names_the_line_and_offset(tmp_path):
    """A calibration.json or homographies.json of binary bytes was a UnicodeDecodeError
    traceback; it is the reader's error naming the file, the line and the byte offset."""
    bad = b'{"cameras": [\n\xff\xfe\x00garbage\x80\x81]}'
    problem = "2: not UTF-8 text: byte 0xff at offset 14 (a binary file, or another encoding)"
    (tmp_path / CALIBRATION).write_bytes(bad)
    with pytest.raises(DetFilesError) as e:
        read_calibration(tmp_path)
    assert str(e.value) == f"{tmp_path / CALIBRATION}:{problem}"
    (tmp_path / "homographies.json").write_bytes(bad)
    with pytest.raises(HomographiesError) as e:
        read_homographies(tmp_path / "homographies.json")
    assert str(e.value) == f"{tmp_path / 'homographies.json'}:{problem}"


@pytest.mark.parametrize("chunk", [1, 2, 3, 7, 1 << 16])
def test_the_first_bad_byte_is_found_across_read_blocks(tmp_path, monkeypatch, chunk):
    """The offset and line of the first byte that is not UTF-8, whichever block of the file it
    falls in and whether a character's bytes straddle two blocks (or the file ends inside one)."""
    from edge_node.formats import text

    monkeypatch.setattr(text, "CHUNK", chunk)
    f = tmp_path / "t.txt"
    good = "é,€\n𝄞 x\r\n".encode()  # 2-, 3- and 4-byte characters, CRLF
    for tail, at in ((b"\xff", 0), (b"\xe2\x82", 0), (b"\xc3(", 0), (b"ab\xf0\x9d\x84", 2)):
        f.write_bytes(good * 3 + tail)
        for read in (text.read_text, lambda p, err: list(text.text_lines(p, err))):
            with pytest.raises(text.NotText) as e:
                read(f, lambda e: e)
            offset = len(good) * 3 + at
            assert (e.value.offset, e.value.line, e.value.byte) == (offset, 7, tail[at])
    f.write_bytes(good)
    assert text.read_text(f, lambda e: e) == "é,€\n𝄞 x\n"
