"""Other tools' detection files (``edge_node/formats/layouts.py``): flat MOTChallenge files and
sequence folders with homographies as JSON or NumPy and ground truth as ground points or boxes,
run end to end; the forms of the homography file; and the errors, each naming the file or field
and the layout expected. The data is a short synthetic scenario exported here and rearranged as
another tool would write it (MOTChallenge id column -1, no descriptors, no calibration.json)."""
from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from edge_node.formats.layouts import (ImportOptions, LayoutError, read_homographies,
                                       read_layout)
from sim_cluster import cli
from sim_cluster.scenarios.detfiles import export_detections, load_det_files
from sim_cluster.scenarios.loader import load_scenario

FRAMES = 80


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    """lab-sim's first frames as a det-files folder, and the scenario."""
    data = load_scenario("lab-sim", frames=FRAMES)
    out = tmp_path_factory.mktemp("export")
    export_detections(data, out, descriptor_dtype="float32")
    return out, data


def _mot_det(src: Path, dst: Path) -> None:
    """A det.txt as another detector writes it: id column -1."""
    dst.parent.mkdir(parents=True, exist_ok=True)
    rows = [r.split(",") for r in src.read_text().splitlines() if r]
    dst.write_text("".join(",".join([r[0], "-1", *r[2:]]) + "\n" for r in rows))


def _ground_points(src: Path, dst: Path) -> None:
    """gt_ground.csv (frame,id,x,y,w,h) as frame,id,X,Y."""
    rows = [r.split(",") for r in src.read_text().splitlines() if r and not r.startswith("#")]
    dst.write_text("".join(",".join(r[:4]) + "\n" for r in rows))


def flat_layout(exported, root: Path) -> Path:
    """cam0.txt .. cam3.txt, homographies.npy (cameras, 3, 3), gt_ground.txt frame,id,X,Y."""
    out, data = exported
    d = root / "flat"
    for c in range(data.num_cameras):
        _mot_det(out / f"c{c}" / "det.txt", d / f"cam{c}.txt")
    np.save(d / "homographies.npy", np.stack([cam.G for cam in data.cameras]))
    _ground_points(out / "gt_ground.csv", d / "gt_ground.txt")
    return d


def mot_folders(exported, root: Path) -> Path:
    """MOTChallenge sequence folders c0/det/det.txt, c0/gt/gt.txt, c0/seqinfo.ini and a
    homographies.json keyed by camera name; no ground points (the gt boxes give them)."""
    out, data = exported
    d = root / "mot"
    for c, cam in enumerate(data.cameras):
        _mot_det(out / f"c{c}" / "det.txt", d / f"c{c}" / "det" / "det.txt")
        (d / f"c{c}" / "gt").mkdir(parents=True)
        shutil.copy(out / f"c{c}" / "gt.txt", d / f"c{c}" / "gt" / "gt.txt")
        (d / f"c{c}" / "seqinfo.ini").write_text(
            f"[Sequence]\nname=c{c}\nframeRate=25\nseqLength={FRAMES}\n"
            f"imWidth={cam.image_size[0]}\nimHeight={cam.image_size[1]}\nimExt=.jpg\n")
    (d / "homographies.json").write_text(json.dumps(
        {f"c{c}": cam.G.tolist() for c, cam in enumerate(data.cameras)}))
    return d


def _run(capsys, scenario: Path, out: Path, *extra: str) -> tuple[dict, list[str]]:
    assert cli.main(["run", "--scenario", str(scenario), "--topology", "complete", "--quiet",
                     "--out", str(out), *extra]) == 0, capsys.readouterr().err
    return json.loads((out / "summary.json").read_text()), capsys.readouterr().out.splitlines()


def test_flat_motchallenge_files_run_end_to_end(exported, tmp_path, capsys):
    """cam0.txt .. cam3.txt without descriptors, homographies as .npy, ground truth as
    frame,id,X,Y: the run names what it read, says once that it tracks by geometry only, and
    tracks (ground MOTA of the complete network on lab-sim's first 80 frames)."""
    d = flat_layout(exported, tmp_path)
    summary, lines = _run(capsys, d, tmp_path / "run", "--image-size", "360x288")
    assert lines[0].startswith("flat: 4 camera(s) from flat det files: 0=cam0.txt, 1=cam1.txt")
    assert "homographies from homographies.npy" in lines[0]
    assert any("no units_per_metre given" in t for t in lines)
    geometry = [t for t in lines if "no appearance descriptors" in t]
    assert len(geometry) == 1 and "dkf+lda+dtm -> dkf+dtm" in geometry[0]
    assert summary["config"] == "dkf+dtm" and summary["nodes"] == 4
    g = summary["metrics"]["ground"]["median"]
    assert g["num_unique_objects"] == len({int(i) for ids in exported[1].truth.ids for i in ids})
    assert g["mota"] > 0.8


def test_motchallenge_folders_with_gt_boxes_run_end_to_end(exported, tmp_path, capsys):
    """c<i>/det/det.txt with seqinfo.ini (image size, frame rate) and gt/gt.txt boxes; the
    ground truth comes from the boxes' foot points, within 0.5 m of the true positions."""
    d = mot_folders(exported, tmp_path)
    summary, lines = _run(capsys, d, tmp_path / "run")
    assert lines[0].startswith("mot: 4 camera(s) from folders det files: 0=c0/det/det.txt")
    assert any("ground truth from the cameras' gt boxes" in t for t in lines)
    assert summary["metrics"]["ground"]["median"]["mota"] > 0.7
    assert summary["metrics"]["image"]["median"]["mota"] is not None
    data, truth = load_scenario(d), exported[1].truth
    for k in (10, 40, 70):
        want = dict(zip(truth.ids[k].tolist(), truth.xy[k]))
        got = dict(zip(data.truth.ids[k].tolist(), data.truth.xy[k]))
        seen = set(got) & set(want)
        assert len(seen) >= len(want) - 1
        assert max(np.linalg.norm(got[i] - want[i]) for i in seen) < 0.5


def test_import_detections_writes_a_det_files_folder_that_runs_alike(exported, tmp_path, capsys):
    """``import-detections`` writes the folder other commands (``up``, camera processes) read:
    running it gives the tracks of running the layout directly."""
    d = flat_layout(exported, tmp_path)
    assert cli.main(["import-detections", str(d), "--image-size", "360x288",
                     "--units-per-metre", "1", "--out", str(tmp_path / "det")]) == 0
    printed = capsys.readouterr().out
    assert "wrote 4 cameras x 80 frames" in printed and "no units_per_metre" not in printed
    assert (tmp_path / "det" / "calibration.json").is_file()
    direct, _ = _run(capsys, d, tmp_path / "a", "--image-size", "360x288")
    imported, lines = _run(capsys, tmp_path / "det", tmp_path / "b")
    assert imported["tracks"] == direct["tracks"]
    assert len([t for t in lines if "no appearance descriptors" in t]) == 1
    a = (tmp_path / "a" / "tracks_node0.csv").read_text().splitlines()
    b = (tmp_path / "b" / "tracks_node0.csv").read_text().splitlines()
    assert [r.split(",")[:4] for r in a] == [r.split(",")[:4] for r in b]


# -- homography files ----------------------------------------------------------------------------
H = [np.eye(3) * (i + 1) for i in range(2)]
NAMES = ["cam0", "cam1"]


@pytest.mark.parametrize("name, write", [
    ("h.json", lambda p: p.write_text(json.dumps([h.tolist() for h in H]))),
    ("h.json", lambda p: p.write_text(json.dumps({"H": [h.tolist() for h in H],
                                                  "image_size": [640, 480],
                                                  "units_per_metre": 100, "fps": 10}))),
    ("h.json", lambda p: p.write_text(json.dumps({"cam1": {"H": H[1].tolist(),
                                                           "image_size": [640, 480]},
                                                  "cam0": H[0].tolist(),
                                                  "image_size": [640, 480]}))),
    ("h.npy", lambda p: np.save(p, np.stack(H))),
    ("h.npz", lambda p: np.savez(p, H=np.stack(H))),
    ("h.npz", lambda p: np.savez(p, cam1=H[1], cam0=H[0])),
])
def test_homography_file_forms(tmp_path, name, write):
    write(tmp_path / name)
    got = read_homographies(tmp_path / name, NAMES)
    for g, h in zip(got.H, H):
        np.testing.assert_array_equal(g, h)
    text = (tmp_path / name).read_text() if name.endswith(".json") else ""
    if "units" in text:
        assert (got.units_per_metre, got.fps, got.image_size) == (100, 10, [(640, 480)] * 2)
    if "cam1" in text:
        assert got.image_size == [(640, 480)] * 2


@pytest.mark.parametrize("name, write, message", [
    ("h.npy", lambda p: np.save(p, np.stack(H + H)),
     "h.npy: the array has 4 homographies for 2 cameras (cam0, cam1)"),
    ("h.json", lambda p: p.write_text("[[1, 0], [0, 1]]"),
     "h.json: the list must hold one 3x3 homography per camera"),
    ("h.json", lambda p: p.write_text(json.dumps({"cam0": H[0].tolist()})),
     "h.json: no homography for camera(s) ['cam1']"),
    ("h.json", lambda p: p.write_text("{oops"), "h.json: not valid JSON"),
    ("h.npz", lambda p: np.savez(p, a=H[0], b=H[1]),
     "h.npz: holds arrays ['a', 'b']; want one (cameras, 3, 3) array or one 3x3 array per "
     "camera named ['cam0', 'cam1']"),
    ("h.txt", lambda p: p.write_text("1 0 0"), "h.txt: homographies must be a .json, .npy or "
                                               ".npz file"),
])
def test_homography_file_errors_name_the_file_and_the_form(tmp_path, name, write, message):
    write(tmp_path / name)
    with pytest.raises(LayoutError) as e:
        read_homographies(tmp_path / name, NAMES)
    assert message in str(e.value)


# -- errors --------------------------------------------------------------------------------------
def _tiny(d: Path, cameras: int = 2) -> Path:
    d.mkdir(parents=True, exist_ok=True)
    for c in range(cameras):
        (d / f"cam{c}.txt").write_text("1,-1,10,10,20,50,0.9,-1,-1,-1\n")
    np.save(d / "homographies.npy", np.stack([np.eye(3)] * cameras))
    return d


def test_cli_errors_name_the_layout_file_and_field(tmp_path, capsys):
    """One line on stderr (no traceback), exit status 2, naming what is wrong and where."""
    def err(*argv):
        assert cli.main(list(argv)) == 2
        return capsys.readouterr().err

    empty = tmp_path / "empty"
    empty.mkdir()
    e = err("run", "--scenario", str(empty), "--quiet", "--out", str(tmp_path / "o"))
    assert "no calibration.json and no detection files in an accepted layout" in e
    assert "DIR/<cam>/det/det.txt" in e and "DIR/<cam>.txt" in e and "Traceback" not in e

    d = _tiny(tmp_path / "tiny")
    e = err("run", "--scenario", str(d), "--quiet", "--out", str(tmp_path / "o"))
    assert "image size of camera cam0 unknown: pass --image-size WxH" in e

    (d / "homographies.npy").unlink()
    e = err("run", "--scenario", str(d), "--image-size", "100x100", "--quiet", "--out",
            str(tmp_path / "o"))
    assert "no homographies for cameras cam0, cam1: pass --homographies FILE" in e

    d = _tiny(tmp_path / "gt")
    (d / "gt_ground.csv").write_text("1,1,10,10,20,50,1,1,1\n")  # a MOTChallenge gt.txt row
    e = err("run", "--scenario", str(d), "--image-size", "100x100", "--quiet", "--out",
            str(tmp_path / "o"))
    assert "gt_ground.csv: ground truth rows are frame,id,X,Y (or frame,id,X,Y,w,h)" in e
    assert "got 9 fields" in e

    d = _tiny(tmp_path / "bad")
    (d / "cam1.txt").write_text("1,-1,10,10,0,50\n")
    e = err("run", "--scenario", str(d), "--image-size", "100x100", "--quiet", "--out",
            str(tmp_path / "o"))
    assert "cam1.txt:1: det.txt field 'w' (box size) must be > 0" in e

    e = err("run", "--scenario", "lab-sim", "--homographies", "h.json", "--quiet")
    assert "--homographies apply to a folder of detection files without calibration.json" in e

    e = err("run", "--image-size", "12", "--quiet")
    assert "argument --image-size: must be WIDTHxHEIGHT in pixels" in e

    # camera processes read calibration.json folders: up says how to make one, writes nothing
    e = err("up", "--scenario", str(d), "--out", str(tmp_path / "up"))
    assert "the nodes read det-files folders with calibration.json; convert this one first: " \
           f"sim_cluster import-detections {d} --out DIR" in e
    assert not (tmp_path / "up").exists()


def test_calibration_json_folders_refuse_layout_options(exported, tmp_path, capsys):
    out, _ = exported
    assert cli.main(["run", "--scenario", str(out), "--units-per-metre", "30", "--quiet",
                     "--out", str(tmp_path / "o")]) == 2
    assert "declares the cameras, units and files: --units-per-metre apply to a folder " \
           "without it" in capsys.readouterr().err


def test_one_sequence_folder_is_one_camera_and_both_layouts_at_once_is_an_error(tmp_path):
    seq = tmp_path / "MOT17-02"
    (seq / "det").mkdir(parents=True)
    (seq / "det" / "det.txt").write_text("1,-1,10,10,20,50,0.9,-1,-1,-1\n")
    (seq / "seqinfo.ini").write_text("[Sequence]\nimWidth=1920\nimHeight=1080\nframeRate=30\n")
    got = read_layout(seq, ImportOptions(homographies=_tiny(tmp_path / "h", 1) /
                                         "homographies.npy"))
    assert got.names == ("MOT17-02",) and got.calibration.fps == 30
    assert got.calibration.cameras[0].image_size == (1920, 1080)
    d = _tiny(tmp_path / "both")
    (d / "c9").mkdir()
    (d / "c9" / "det.txt").write_text("1,-1,10,10,20,50\n")
    with pytest.raises(LayoutError, match="both camera folders"):
        read_layout(d)


def test_help_of_run_lists_every_scenario_form(capsys):
    assert cli.main(["run", "--help"]) == 0
    text = capsys.readouterr().out
    for form in ("a preset name", "corridor-<N>, grid-<N>", "FILE.toml", "DIR/calibration.json",
                 "DIR/<cam>/det/det.txt", "DIR/<cam>/det.txt", "DIR/<cam>.txt", ".npy", ".npz",
                 "frame,id,X,Y", "--homographies", "--ground-truth", "--units-per-metre",
                 "--image-size", "geometry only"):
        assert form in text, form


def test_det_files_loader_reads_the_imported_layout_like_run(exported, tmp_path):
    """``load_det_files`` (what camera processes and tests use) takes the layout options too."""
    d = flat_layout(exported, tmp_path)
    data = load_det_files(d, options=ImportOptions(image_size=(360, 288)))
    assert data.num_cameras == 4 and data.frames == FRAMES and not data.has_descriptors()
    assert data.notes and data.notes[0].startswith("flat: 4 camera(s)")


@pytest.mark.parametrize("name", ["cam1.txt", "homographies.json", "gt_ground.csv",
                                  "cam0/seqinfo.ini"])
def test_binary_bytes_in_a_layout_file_name_it_with_line_and_offset(tmp_path, capsys, name):
    """Binary bytes in another tool's det file, homographies JSON or ground truth were a
    UnicodeDecodeError traceback (seqinfo.ini: Python's decoder message); each is one line
    naming the file, the line and the byte offset, exit status 2."""
    d = tmp_path / "tiny"
    if name.startswith("cam0/"):  # MOTChallenge sequence folders, one per camera
        for c in range(2):
            (d / f"cam{c}" / "det").mkdir(parents=True)
            (d / f"cam{c}" / "det" / "det.txt").write_text("1,-1,10,10,20,50,0.9,-1,-1,-1\n")
        np.save(d / "homographies.npy", np.stack([np.eye(3)] * 2))
    else:
        _tiny(d)
    if name.endswith(".json"):
        (d / "homographies.npy").unlink()
    (d / name).write_bytes(b"1,-1,10,10,20,50\n\xff\xfe\x00garbage\x80\x81\n")
    assert cli.main(["import-detections", str(d), "--image-size", "100x100",
                     "--out", str(tmp_path / "o")]) == 2
    assert capsys.readouterr().err.splitlines() == [
        f"sim_cluster: error: {d / name}:2: not UTF-8 text: byte 0xff at offset 17 (a binary "
        "file, or another encoding)"]
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("name", ["cam1.txt", "gt_ground.csv"])
def test_a_frame_number_of_1e12_is_refused_naming_the_line_and_field(tmp_path, capsys, name):
    """import-detections took a det file's (or the ground truth's) frame 1e12 as the length of
    the sequence: it wrote nothing for minutes while its memory grew past 13 GB."""
    d = _tiny(tmp_path / "tiny")
    (d / name).write_text("1,-1,10,10,20,50\n1e12,-1,10,10,20,50\n")
    assert cli.main(["import-detections", str(d), "--image-size", "100x100",
                     "--out", str(tmp_path / "o")]) == 2
    assert capsys.readouterr().err.splitlines() == [  # found by the frame count's first read
        f"sim_cluster: error: {d / name}:2: {name} field 'frame' must be <= 1000000000 "
        "(MAX_FRAME: the source states no number of frames), got 1000000000000"]
    assert not (tmp_path / "o").exists()
