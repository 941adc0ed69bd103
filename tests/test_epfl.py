"""EPFL loader: formats, data-root resolution and ground truth on tiny hand-made files; the real
Terrace/Campus data when present (skipped with the reason otherwise)."""
from __future__ import annotations

import json
import tomllib
from pathlib import Path

import numpy as np
import pytest

from sim_cluster.scenarios import epfl
from sim_cluster.scenarios.epfl import (DataNotFoundError, EpflFormatError, build_ground_truth,
                                        load_sequence, read_annotations, read_mot_csv, read_vatic,
                                        resolve_data_root, scenario_from_table, visible_fractions)

PRESETS = Path(epfl.__file__).resolve().parent / "presets"


# --- formats ---------------------------------------------------------------------------------------
def test_mot_csv_crlf_and_lost_rows(tmp_path):
    p = tmp_path / "c0.gt.csv"
    p.write_bytes(b"5,1,10,20,30,40,0,0,1,0\r\n3,0,1,2,3,4,0,0,0,0\r\n4,0,1,2,3,4,1,0,0,0\r\n")
    a = read_mot_csv(p)
    np.testing.assert_array_equal(a.frames, [3, 5])  # sorted by frame; the lost row is gone
    np.testing.assert_array_equal(a.ids, [0, 1])
    np.testing.assert_allclose(a.boxes, [[1, 2, 3, 4], [10, 20, 30, 40]])
    np.testing.assert_array_equal(a.generated, [False, True])


def test_vatic_format_and_auto_detection(tmp_path):
    p = tmp_path / "c0.txt"
    p.write_text('0 10 20 40 60 7 0 0 1 "PERSON"\n0 10 20 40 60 8 1 0 1 "PERSON"\n'
                 '2 0 0 5 10 6 0 1 0 "PERSON"\n')
    a = read_vatic(p)
    np.testing.assert_array_equal(a.frames, [6, 7])
    np.testing.assert_array_equal(a.ids, [2, 0])
    np.testing.assert_allclose(a.boxes, [[0, 0, 5, 10], [10, 20, 30, 40]])  # w = xmax - xmin
    b = read_annotations(p)  # auto: no commas -> vatic
    np.testing.assert_allclose(b.boxes, a.boxes)


def test_format_errors_name_file_and_line(tmp_path):
    p = tmp_path / "bad.csv"
    p.write_text("1,0,1,2,3,4,0,0,0,0\n2,0,x,2,3,4,0,0,0,0\n")
    with pytest.raises(EpflFormatError, match=r"bad.csv:2: field 'x'"):
        read_mot_csv(p)
    with pytest.raises(DataNotFoundError, match="nope.csv"):
        read_annotations(tmp_path / "nope.csv")



def test_binary_bytes_in_an_annotation_file_name_the_line_and_offset(tmp_path):
    """Binary bytes in an EPFL annotation file were a UnicodeDecodeError traceback."""
    p = tmp_path / "c0.gt.csv"
    p.write_bytes(b"1,0,1,2,3,4,0,0,0,0\n\xff\xfe\x00garbage\x80\x81\n")
    message = (f"{p}:2: not UTF-8 text: byte 0xff at offset 20 (a binary file, or another "
               "encoding)")
    for read in (read_mot_csv, read_vatic, read_annotations):
        with pytest.raises(EpflFormatError) as e:
            read(p)
        assert str(e.value) == message
    p.write_bytes(b"\xff\xfe\x00garbage\x80\x81\n")  # auto-detection reads the first row
    with pytest.raises(EpflFormatError, match=r"c0.gt.csv:1: not UTF-8 text: byte 0xff at "
                                              r"offset 0"):
        read_annotations(p)


@pytest.mark.parametrize("row, got", [
    ("1e12,0,1,2,3,4,0,0,0,0", "'1e12'"),  # was the length of the sequence
    ("-1,0,1,2,3,4,0,0,0,0", "'-1'"),  # was "negative frame index", no line
    ("2.5,0,1,2,3,4,0,0,0,0", "'2.5'"),  # was frame 2
    ("nan,0,1,2,3,4,0,0,0,0", "'nan'"),
])
def test_a_bad_frame_number_names_the_file_line_and_field(tmp_path, row, got):
    p = tmp_path / "c0.gt.csv"
    p.write_text(f"1,0,1,2,3,4,0,0,0,0\n{row}\n")
    with pytest.raises(EpflFormatError) as e:
        read_mot_csv(p)
    assert str(e.value) == (f"{p}:2: field 'frame' must be a whole number in 0..999999999 "
                            f"(0-based, MAX_FRAME), got {got}")
    v = tmp_path / "c0.txt"
    v.write_text(f'0 10 20 40 60 7 0 0 1 "PERSON"\n0 10 20 40 60 {row.split(",")[0]} 0 0 1 "P"\n')
    with pytest.raises(EpflFormatError, match=r"c0.txt:2: field 'frame' must be a whole number"):
        read_vatic(v)


# --- data root -------------------------------------------------------------------------------------
def test_data_root_resolution_order(tmp_path, monkeypatch):
    a, b = tmp_path / "a", tmp_path / "b"
    a.mkdir()
    b.mkdir()
    monkeypatch.setenv("DMTT_DATA", str(b))
    assert resolve_data_root(a) == a.resolve()  # argument beats the environment
    assert resolve_data_root() == b.resolve()  # then the environment
    with pytest.raises(DataNotFoundError, match="missing"):
        resolve_data_root(tmp_path / "missing")  # an explicit root is not a fall-through
    monkeypatch.setenv("DMTT_DATA", str(tmp_path / "gone"))
    with pytest.raises(DataNotFoundError, match=r"DMTT_DATA.*gone"):
        resolve_data_root()
    monkeypatch.delenv("DMTT_DATA")
    cands = epfl.data_root_candidates()
    assert cands[0] == epfl.repo_root().parent / "shared" / "data"
    assert cands[1] == Path.cwd() / ".." / "shared" / "data"


# --- ground truth on a tiny hand-made sequence -----------------------------------------------------
def write_mini(root: Path) -> None:
    """Two 100x100 cameras: c0 with G = I (ground = pixels), c1 shifted by +10 in x."""
    d = root / "epfl_pom"
    (d / "mini").mkdir(parents=True)
    shift = [[1, 0, 10], [0, 1, 0], [0, 0, 1]]
    (d / "homographies.json").write_text(json.dumps({"mini": {
        "sequence": "mini1", "image_scale": 1.0, "image_size_annotations": [100, 100],
        "H": [np.eye(3).tolist(), shift]}}))
    # person 0: c0 foot (15, 50) -> ground (15, 50); c1 foot (5, 52) -> ground (15, 52)
    (d / "mini" / "mini1-c0.gt.csv").write_text("10,0,10,20,10,30,0,0,0,0\r\n")
    (d / "mini" / "mini1-c1.gt.csv").write_text(
        "10,0,0,22,10,30,0,0,0,0\r\n11,1,40,40,20,40,0,0,1,0\r\n")


def test_ground_truth_by_hand(tmp_path):
    write_mini(tmp_path)
    seq = load_sequence("mini", data_root=tmp_path)
    assert seq.frame_range == (10, 11)
    gt = build_ground_truth(seq, 10, 2, units_per_metre=30.0)
    np.testing.assert_array_equal(gt.ids[0], [0])
    np.testing.assert_allclose(gt.xy[0], [[15.0, 51.0]])  # mean of the two projected foot points
    np.testing.assert_array_equal(gt.ids[1], [1])
    np.testing.assert_allclose(gt.xy[1], [[60.0, 80.0]])  # c1 foot (50, 80) + (10, 0)
    # box_to_cylinder with G = I: width = box width, height = width * box aspect
    np.testing.assert_allclose(gt.wh[0], [[10.0, 30.0]])
    np.testing.assert_allclose(gt.wh[1], [[20.0, 40.0]])
    ids, boxes = gt.boxes[1][0]
    np.testing.assert_array_equal(ids, [0])
    np.testing.assert_allclose(boxes, [[0, 22, 10, 30]])
    assert len(gt.boxes[0][1][0]) == 0


def test_visible_fraction_by_hand():
    # box 1 (bottom 30) stands in front of box 0 (bottom 20) and hides its right half.
    b = np.array([[0, 0, 10, 20], [5, 0, 10, 30], [100, 0, 10, 10]], float)
    np.testing.assert_allclose(visible_fractions(b), [0.5, 1.0, 1.0])
    # per frame: boxes in different frames do not hide each other
    np.testing.assert_allclose(visible_fractions(b[:2], np.array([0, 1])), [1.0, 1.0])


def test_mini_scenario_through_a_table(tmp_path):
    write_mini(tmp_path)
    raw = {"name": "mini-gt", "frames": 2, "source": {"kind": "epfl-gt", "sequence": "mini",
           "units_per_metre": 30.0, "data_root": str(tmp_path)},
           "detector": {"miss_rate": 0.0, "false_positives_per_frame": 0.0, "box_noise_px": 0.0}}
    sc = scenario_from_table(raw, tmp_path / "mini.toml", 0, None).materialise()
    assert (sc.name, sc.frames, sc.num_cameras, sc.units_per_metre) == ("mini-gt", 2, 2, 30.0)
    np.testing.assert_array_equal(sc.detection_truth[0][0], [0])
    np.testing.assert_allclose(sc.detections[0][1][0].box, [0, 22, 10, 30])  # no noise
    assert sc.detections[0][1][0].descriptor.shape == (512,)
    from sim_cluster.scenarios.files import ScenarioError
    raw["source"]["typo"] = 1
    with pytest.raises(ScenarioError, match="typo"):
        scenario_from_table(raw, tmp_path / "mini.toml", 0, None)


# --- the real data ---------------------------------------------------------------------------------
def _real_root() -> Path:
    try:
        root = resolve_data_root()
    except DataNotFoundError as e:
        pytest.skip(f"EPFL data not available: {e}")
    if not (root / "epfl_pom" / "homographies.json").is_file():
        pytest.skip(f"EPFL data not available: no epfl_pom/homographies.json under {root}")
    return root


def _preset(name: str, frames: int):
    p = PRESETS / f"{name}.toml"
    return scenario_from_table(tomllib.loads(p.read_text()), p, 0, frames).materialise()


@pytest.mark.epfl
def test_terrace_preset_loads_consistently():
    _real_root()
    sc = _preset("terrace-gt", 100)
    assert (sc.frames, sc.num_cameras, sc.units_per_metre) == (100, 4, 30.0)
    assert all(cam.image_size == (360, 288) for cam in sc.cameras)
    for k in range(sc.frames):
        seen = set()
        for c in range(4):
            seen |= set(sc.truth.boxes[c][k][0].tolist())
            assert set(sc.detection_truth[k][c].tolist()) <= set(sc.truth.boxes[c][k][0].tolist()) | {-1}
        assert seen == set(sc.truth.ids[k].tolist())
    # Camera order and scale: own-camera foot points lie near the cross-camera mean
    # (PROVENANCE: cross-camera disagreement median ~25 units).
    d = []
    for k in range(0, sc.frames, 5):
        pos = dict(zip(sc.truth.ids[k].tolist(), sc.truth.xy[k]))
        for c, cam in enumerate(sc.cameras):
            for i, b in zip(*sc.truth.boxes[c][k]):
                d.append(np.linalg.norm(cam.box_to_cylinder(b)[:2] - pos[int(i)]))
    assert np.median(d) < 25.0
    again = _preset("terrace-gt", 100)
    assert all(np.array_equal(a.box, b.box) for a, b in zip(sc.detections[50][2], again.detections[50][2]))


@pytest.mark.epfl
def test_campus_preset_loads():
    _real_root()
    sc = _preset("campus-gt", 50)
    assert (sc.frames, sc.num_cameras) == (50, 3)
    assert sum(len(i) for i in sc.truth.ids) > 0


@pytest.mark.epfl
def test_own_camera_oracle_scores_perfectly_in_the_image_plane():
    """Each node's tracks = cylinders of its own camera's annotated boxes: image MOTA 1 in every
    camera (catches camera order, pixel scale and homography sign conventions)."""
    from sim_cluster.evaluation.metrics import evaluate_image

    _real_root()
    for name, n in (("terrace-gt", 60), ("campus-gt", 60)):
        sc = _preset(name, n)
        tracks = {c: [[((c, int(i)), np.r_[cam.box_to_cylinder(b), 0.0, 0.0])
                       for i, b in zip(*sc.truth.boxes[c][k])] for k in range(n)]
                  for c, cam in enumerate(sc.cameras)}
        res = evaluate_image(tracks, sc)
        for node, m in res["per_node"].items():
            if m["num_objects"]:
                assert m["mota"] == pytest.approx(1.0), (name, node)
                assert m["motp"] > 0.999


def test_the_default_data_root_is_beside_the_repository(monkeypatch):
    root = epfl.repo_root()
    assert (root / "pyproject.toml").is_file() and (root / "sim_cluster").is_dir()
    monkeypatch.delenv("DMTT_DATA", raising=False)
    assert root.parent / "shared" / "data" in epfl.data_root_candidates()
