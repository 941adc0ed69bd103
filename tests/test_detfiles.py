"""det-files: export a scenario to MOTChallenge-style files and load it back unchanged."""
from __future__ import annotations

import numpy as np
import pytest

from edge_node.core.types import Detection
from edge_node.geometry import Camera
from sim_cluster.scenarios.data import GroundTruth, ScenarioData
from edge_node.formats.detfile import open_det, open_gt, open_gt_ground
from sim_cluster.scenarios.detfiles import (DetFilesError, export_detections, load_det_files,
                                            scenario_from_table)
from sim_cluster.scenarios.files import ScenarioError
from sim_cluster.scenarios.loader import load_scenario
from sim_cluster.scenarios.synthetic.schema import camera_from_pose


def hand_scenario(frames: int = 6, dim: int = 16) -> ScenarioData:
    """Two cameras (one homography-only with pixel scale 2, one with P), random fractional boxes,
    descriptors, scores, false positives, an empty frame, and one detection without descriptor."""
    rng = np.random.default_rng(3)
    cams = [Camera(id=0, image_size=(360, 288), G=np.array([[1.0, 0.1, 3.0], [0.0, 1.2, -4.0],
                                                              [0.0, 0.001, 1.0]]), pixel_scale=2.0),
            camera_from_pose(1, (640, 480), np.array([0.0, 0.0, 3.0]), 45.0, 20.0, fov_deg=60.0)]
    dets, truth = [], []
    for k in range(frames):
        dk, tk = [], []
        for c in range(2):
            n = 0 if k == 2 else int(rng.integers(1, 4))
            ds = []
            for i in range(n):
                box = rng.uniform(0, 200, 4) + np.array([0, 0, 5, 5])
                desc = rng.standard_normal(dim)
                desc = None if (k, c, i) == (1, 0, 0) else desc / np.linalg.norm(desc)
                ds.append(Detection(box=box, descriptor=desc, score=float(rng.uniform(0.3, 1))))
            dk.append(ds)
            tk.append(np.array([int(rng.integers(-1, 5)) for _ in range(n)], dtype=np.int64))
        dets.append(dk)
        truth.append(tk)
    ids = [np.array([0, 3]) for _ in range(frames)]
    xy = [rng.uniform(0, 10, (2, 2)) for _ in range(frames)]
    wh = [np.array([[0.5, 1.7], [0.55, 1.8]]) for _ in range(frames)]
    boxes = [[(np.array([3]), rng.uniform(0, 100, (1, 4)) + 5) for _ in range(frames)] for _ in range(2)]
    return ScenarioData(name="hand", cameras=cams, frames=frames, fps=25.0, units_per_metre=1.0,
                        detections=dets, truth=GroundTruth(ids, xy, wh, boxes),
                        detection_truth=truth, area=(0.0, 10.0, 0.0, 10.0), seed=7)


def assert_same(a: ScenarioData, b: ScenarioData, desc_atol: float) -> None:
    assert (b.frames, b.num_cameras, b.fps, b.units_per_metre, b.seed) == (
        a.frames, a.num_cameras, a.fps, a.units_per_metre, a.seed)
    assert b.area == pytest.approx(a.area)
    for ca, cb in zip(a.cameras, b.cameras):
        assert (cb.id, cb.image_size, cb.pixel_scale, cb.fps) == (ca.id, ca.image_size,
                                                                   ca.pixel_scale, ca.fps)
        np.testing.assert_allclose(cb.G, ca.G)
        assert (ca.P is None) == (cb.P is None)
        if ca.P is not None:
            np.testing.assert_allclose(cb.P, ca.P)
    for k in range(a.frames):
        for c in range(a.num_cameras):
            da, db = a.detections[k][c], b.detections[k][c]
            assert len(da) == len(db)
            for x, y in zip(da, db):
                np.testing.assert_allclose(y.box, x.box, atol=1e-3)
                assert y.score == pytest.approx(x.score, rel=1e-5)
                assert (x.descriptor is None) == (y.descriptor is None)
                if x.descriptor is not None:
                    np.testing.assert_allclose(y.descriptor, x.descriptor, atol=desc_atol)
            np.testing.assert_array_equal(b.detection_truth[k][c], a.detection_truth[k][c])
            (ia, ba), (ib, bb) = a.truth.boxes[c][k], b.truth.boxes[c][k]
            np.testing.assert_array_equal(ib, ia)
            np.testing.assert_allclose(bb.reshape(-1, 4), ba.reshape(-1, 4), atol=1e-3)
        np.testing.assert_array_equal(b.truth.ids[k], a.truth.ids[k])
        np.testing.assert_allclose(b.truth.xy[k], a.truth.xy[k], atol=1e-5)
        np.testing.assert_allclose(b.truth.wh[k], a.truth.wh[k], atol=1e-5)


def test_round_trip_hand_scenario(tmp_path):
    sc = hand_scenario()
    cal = export_detections(sc, tmp_path / "f16")
    assert cal.name == "calibration.json"
    assert np.load(tmp_path / "f16" / "c0" / "det.npy").dtype == np.float16
    assert_same(sc, load_det_files(tmp_path / "f16"), desc_atol=1e-3)
    export_detections(sc, tmp_path / "f32", descriptor_dtype="float32")
    assert_same(sc, load_det_files(tmp_path / "f32" / "calibration.json"), desc_atol=1e-6)


def test_round_trip_synthetic_world(tmp_path):
    sc = load_scenario("terrace-sim", frames=20)
    export_detections(sc, tmp_path)
    back = load_det_files(tmp_path)
    assert back.name == sc.name
    assert_same(sc, back, desc_atol=1e-3)


def test_motchallenge_files_written_by_hand(tmp_path):
    (tmp_path / "c0").mkdir()
    (tmp_path / "calibration.json").write_text(
        '{"units_per_metre": 30, "cameras": [{"image_size": [360, 288], '
        '"G": [[1,0,0],[0,1,0],[0,0,1]]}]}')
    (tmp_path / "c0" / "det.txt").write_bytes(
        b"1,-1,10.5,20,30,60,0.9,-1,-1,-1\r\n3,-1,1,2,3,4,0.5,-1,-1,-1\r\n1,-1,50,60,10,20,0.7,-1,-1,-1\r\n")
    (tmp_path / "c0" / "gt.txt").write_text(
        "1,4,10,20,30,60,1,1,1\n1,5,0,0,9,9,0,1,1\n2,4,11,20,30,60,1,1,0.8\n2,6,0,0,9,9,1,7,1\n")
    sc = load_det_files(tmp_path)
    assert sc.frames == 3 and sc.units_per_metre == 30.0  # frames: the last frame in any file
    assert [len(d) for d in (sc.detections[0][0], sc.detections[1][0], sc.detections[2][0])] == [2, 0, 1]
    np.testing.assert_allclose(sc.detections[0][0][1].box, [50, 60, 10, 20])  # file order kept
    assert sc.detections[0][0][0].descriptor is None and sc.detections[0][0][0].score == 0.9
    # consider = 0 and class 7 (static person) rows are skipped, as in MOTChallenge evaluation
    assert sc.truth.boxes[0][0][0].tolist() == [4] and sc.truth.boxes[0][1][0].tolist() == [4]
    assert all(len(i) == 0 for i in sc.truth.ids)  # no gt_ground.csv: empty ground truth


def test_errors_name_the_file(tmp_path):
    with pytest.raises(DetFilesError, match="calibration.json"):
        load_det_files(tmp_path)
    bad = tmp_path / "det.txt"
    bad.write_text("1,-1,1,2,3,4,0.9,-1,-1,-1\n2,-1,1,two,3,4,0.9,-1,-1,-1\n")
    with pytest.raises(DetFilesError, match=r"det.txt:2"):
        open_det(bad)
    bad.write_text("0,-1,1,2,3,4,0.9,-1,-1,-1\n")
    with pytest.raises(DetFilesError, match="1-based"):
        open_det(bad)
    bad.write_text("1,-1,1,2,3,4,0.9,-1,-1,-1\n")
    np.save(tmp_path / "det.npy", np.zeros((2, 8)))
    with pytest.raises(DetFilesError, match=r"det.npy.*1 rows"):
        open_det(bad, descriptors=tmp_path / "det.npy")


def test_scenario_kind_from_a_toml_table(tmp_path):
    export_detections(hand_scenario(), tmp_path / "data")
    toml = tmp_path / "mine.toml"
    sc = scenario_from_table({"name": "mine", "source": {"kind": "det-files", "path": "data"}},
                             toml, 0, 4)
    assert (sc.name, sc.frames, sc.seed) == ("mine", 4, 0)
    with pytest.raises(ScenarioError, match="path"):
        scenario_from_table({"source": {"kind": "det-files"}}, toml, 0, None)
    with pytest.raises(ScenarioError, match="calibration.json"):
        scenario_from_table({"source": {"kind": "det-files", "path": "nowhere"}}, toml, 0, None)


GOOD_ROW = "1,-1,10,20,30,60,0.9,-1,-1,-1"


@pytest.mark.parametrize("row, field", [
    ("1,-1,10,20,nan,60,0.9,-1,-1,-1", "'w' must be a finite number, got nan"),
    ("1,-1,inf,20,30,60,0.9,-1,-1,-1", "'x' must be a finite number, got inf"),
    ("1,-1,10,20,30,-inf,0.9,-1,-1,-1", "'h' must be a finite number, got -inf"),
    ("1,-1,10,20,0,60,0.9,-1,-1,-1", "'w' (box size) must be > 0, got 0"),
    ("1,-1,10,20,30,-5,0.9,-1,-1,-1", "'h' (box size) must be > 0, got -5"),
    ("nan,-1,10,20,30,60,0.9,-1,-1,-1", "'frame' must be a finite number, got nan"),
    ("1.5,-1,10,20,30,60,0.9,-1,-1,-1", "'frame' must be a whole number, got 1.5"),
    ("0,-1,10,20,30,60,0.9,-1,-1,-1",
     "'frame' must be >= 1 (MOTChallenge frames are 1-based), got 0"),
    ("1,2.5,10,20,30,60,0.9,-1,-1,-1", "'id' must be a whole number, got 2.5"),
])
def test_a_bad_box_is_an_error_naming_file_line_and_field(tmp_path, row, field):
    """A NaN / inf / non-positive box used to reach the tracker's assignment (scipy raised
    'matrix contains invalid numeric entries' and the node died); it is a load-time error now,
    naming the line of the file (comments and blank lines counted)."""
    det = tmp_path / "det.txt"
    det.write_text(f"# a comment\n{GOOD_ROW}\n\n{row}\n{GOOD_ROW}\n")
    with pytest.raises(DetFilesError) as e:
        open_det(det)
    assert str(e.value) == f"{det}:4: det.txt field {field}"


def test_a_nan_confidence_still_reads_as_one(tmp_path):
    det = tmp_path / "det.txt"
    det.write_text("1,-1,10,20,30,60,nan,-1,-1,-1\n")
    assert open_det(det).detections(0)[0].score == 1.0


def test_a_partly_nan_or_inf_descriptor_is_an_error(tmp_path):
    det = tmp_path / "det.txt"
    det.write_text(f"{GOOD_ROW}\n{GOOD_ROW}\n{GOOD_ROW}\n")
    desc = np.ones((3, 4))
    desc[0] = np.nan  # all NaN: no descriptor, fine
    np.save(tmp_path / "det.npy", desc)
    dets = open_det(det, descriptors=tmp_path / "det.npy").detections(0)
    assert dets[0].descriptor is None and dets[1].descriptor is not None
    desc[2, 1] = np.inf
    np.save(tmp_path / "det.npy", desc)
    with pytest.raises(DetFilesError, match=r"det.npy: row 2 \(descriptor of det.txt's data row "
                                            r"3\) has NaN or inf values"):
        open_det(det, descriptors=tmp_path / "det.npy")


def test_ground_truth_files_need_finite_fields_too(tmp_path):
    gt = tmp_path / "gt.txt"
    gt.write_text("1,4,10,20,30,60,1,1,1\n1,5,nan,0,9,9,1,1,1\n")
    with pytest.raises(DetFilesError, match=r"gt.txt:2: gt.txt field 'x' must be a finite"):
        open_gt(gt, 1)
    ground = tmp_path / "gt_ground.csv"
    ground.write_text("# frame,id,x,y,w,h\n1,4,1.0,inf,0.5,1.7\n")
    with pytest.raises(DetFilesError, match=r"gt_ground.csv:2: gt_ground.csv field 'y'"):
        open_gt_ground(ground, 1)


def test_a_nan_box_in_a_scenario_folder_is_exit_2_naming_the_line(tmp_path, capsys):
    """``sim_cluster run --scenario FOLDER`` with a NaN width used to exit 1 with scipy's
    traceback from linear_sum_assignment."""
    from sim_cluster import cli

    export_detections(load_scenario("lab-sim", frames=5), tmp_path / "det")
    det = tmp_path / "det" / "c1" / "det.txt"
    lines = det.read_text().splitlines()
    f = lines[2].split(",")
    f[4] = "nan"
    lines[2] = ",".join(f)
    det.write_text("\n".join(lines) + "\n")
    assert cli.main(["run", "--scenario", str(tmp_path / "det"), "--quiet",
                     "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"sim_cluster: error: {det}:3: det.txt field 'w' must be a finite number, "
                   "got nan"]
    assert not (tmp_path / "out").exists()


GARBAGE = b"\xff\xfe\x00garbage\x80\x81"
NOT_UTF8 = "not UTF-8 text: byte 0x{:02x} at offset {} (a binary file, or another encoding)"


@pytest.mark.parametrize("name, open_file", [
    ("det.txt", lambda p: open_det(p)),
    ("gt.txt", lambda p: open_gt(p, 5)),
    ("gt_ground.csv", lambda p: open_gt_ground(p, 5)),
])
def test_binary_bytes_in_a_det_or_truth_file_name_the_line_and_offset(tmp_path, name, open_file):
    """Binary garbage in a det.txt, gt.txt or gt_ground.csv was a UnicodeDecodeError traceback
    (from the text file's decoder, whose offset is within its 8 KiB block, not the file)."""
    f = tmp_path / name
    good = f"{GOOD_ROW}\n".encode() * 1000  # past the decoder's first block
    f.write_bytes(good + GARBAGE + b"\n" + good)
    with pytest.raises(DetFilesError) as e:
        open_file(f)
    assert str(e.value) == f"{f}:1001: " + NOT_UTF8.format(0xff, len(good))


def test_a_frame_past_max_frame_or_the_stated_frames_is_refused_naming_line_and_field(tmp_path):
    """A det.txt frame number of 1e12 was accepted without a word (and made the run a trillion
    frames long); a row after the frames calibration.json states was silently never read."""
    from edge_node.formats.detfile import MAX_FRAME, FrameBound

    det = tmp_path / "det.txt"
    det.write_text(f"{GOOD_ROW}\n1000000000000,-1,10,20,30,60,0.9,-1,-1,-1\n")
    with pytest.raises(DetFilesError) as e:
        open_det(det)
    assert str(e.value) == (f"{det}:2: det.txt field 'frame' must be <= {MAX_FRAME} (MAX_FRAME: "
                            "the source states no number of frames), got 1000000000000")
    det.write_text(f"{GOOD_ROW}\n{MAX_FRAME},-1,10,20,30,60,0.9,-1,-1,-1\n")  # the last allowed
    assert open_det(det, frames=2).frames == 2
    cal = tmp_path / "calibration.json"
    det.write_text(f"{GOOD_ROW}\n6,-1,10,20,30,60,0.9,-1,-1,-1\n")
    for call, what in ((lambda: open_det(det, 5, bound=FrameBound(5, cal)), "det.txt"),
                       (lambda: open_gt(det, 5, bound=FrameBound(5, cal)), "gt.txt"),
                       (lambda: open_gt_ground(det, 5, bound=FrameBound(5, cal)), "gt_ground.csv")):
        with pytest.raises(DetFilesError) as e:
            call()
        assert str(e.value) == (f"{det}:2: {what} field 'frame' must be <= 5 (the number of "
                                f"frames {cal} states), got 6")


def test_a_det_files_folder_with_a_row_past_its_frames_is_exit_2(tmp_path, capsys):
    from sim_cluster import cli

    export_detections(load_scenario("lab-sim", frames=5), tmp_path / "det")
    (tmp_path / "det" / "c2" / "det.npy").unlink()  # rows and descriptors must match
    det = tmp_path / "det" / "c2" / "det.txt"
    det.write_text(det.read_text() + "6,-1,10,20,30,60,0.9,-1,-1,-1\n")
    assert cli.main(["run", "--scenario", str(tmp_path / "det"), "--quiet",
                     "--out", str(tmp_path / "out")]) == 2
    lines = det.read_text().count("\n")
    assert capsys.readouterr().err.splitlines() == [
        f"sim_cluster: error: {det}:{lines}: det.txt field 'frame' must be <= 5 (the number of "
        f"frames {tmp_path / 'det' / 'calibration.json'} states), got 6"]
    assert not (tmp_path / "out").exists()
