"""From camera frames: frame sources, detectors, re-id (OSNet, histogram), calibration, the
rendered synthetic video and an end-to-end cluster run from it. Everything is made here (no
download); OSNet runs with random weights saved and loaded in torchreid's checkpoint format."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

cv2 = pytest.importorskip("cv2")

from edge_node.perception import PerceptionError  # noqa: E402
from edge_node.perception.detectors import (HogDetector, Mog2Detector, OnnxDetector,  # noqa: E402
                                            hog_available, nms)
from edge_node.perception.reid import HistogramReid  # noqa: E402

REPO = Path(__file__).resolve().parent.parent

# A small close-up world: one camera 2.5 m up, three people 3-6 m away (60-130 px tall), so that
# HOG's 64x128 window (image upscaled 2x) sees them.
CLOSE_SCENE = """
name = "close-up"
seed = 3
frames = 24
fps = 25.0
[area]
xmin = 0.0
xmax = 5.0
ymin = 0.0
ymax = 4.0
[[cameras]]
image_size = [320, 240]
position = [2.5, -2.5, 2.2]
look_at = [2.5, 2.0, 0.9]
fov_deg = 62.0
[people]
concurrent = 3
initial = 3
personal_space_m = 1.2
pause_probability = 0.0
stay_s = [30.0, 40.0]
"""


@pytest.fixture(scope="module")
def close_world(tmp_path_factory):
    from sim_cluster.scenarios.synthetic.render import Renderer, load_world, world_trajectories
    from sim_cluster.scenarios.synthetic.world import generate

    path = tmp_path_factory.mktemp("scene") / "close.toml"
    path.write_text(CLOSE_SCENE)
    cfg = load_world(path)
    data = generate(cfg)
    r = Renderer(list(cfg.cameras), cfg.area, world_trajectories(cfg), cfg.seed)
    return data, r


def _iou(a, b) -> float:
    x0, y0 = max(a[0], b[0]), max(a[1], b[1])
    x1, y1 = min(a[0] + a[2], b[0] + b[2]), min(a[1] + a[3], b[1] + b[3])
    i = max(0.0, x1 - x0) * max(0.0, y1 - y0)
    return i / (a[2] * a[3] + b[2] * b[3] - i)


def _recall(data, found_per_frame, frames, iou=0.3) -> float:
    hit = tot = 0
    for k in frames:
        _, gt = data.truth.boxes[0][k]
        for g in gt:
            tot += 1
            hit += any(_iou(b, g) >= iou for b, _ in found_per_frame[k])
    return hit / max(tot, 1)


# -- OSNet ------------------------------------------------------------------------------------------
torch = pytest.importorskip("torch")


@pytest.mark.parametrize("variant", ["x1_0", "x0_25"])
def test_osnet_forward_shapes_and_unit_features(variant):
    from edge_node.perception.osnet import osnet
    from edge_node.perception.reid import OsnetReid

    model = osnet(variant).eval()
    with torch.inference_mode():
        f = model(torch.randn(3, 3, 128, 64))
    assert f.shape == (3, 512)
    reid = OsnetReid(variant, random_init=True, input_size=(128, 64))
    img = np.random.default_rng(0).integers(0, 255, (120, 160, 3), dtype=np.uint8)
    boxes = np.array([[10, 10, 30, 80], [60, 5, 40, 100], [150, 100, 30, 40], [500, 0, 5, 5]])
    d = reid.extract(img, boxes)
    assert d.shape == (4, 512) and d.dtype == np.float32
    np.testing.assert_allclose(np.linalg.norm(d[:3], axis=1), 1.0, rtol=1e-5)
    assert np.all(np.isnan(d[3]))  # a box outside the image has no descriptor


def test_torchreid_checkpoint_round_trip(tmp_path):
    from edge_node.perception.osnet import load_torchreid_checkpoint, osnet
    from edge_node.perception.reid import OsnetReid

    torch.manual_seed(1)
    model = osnet("x0_25", num_classes=751)
    with torch.no_grad():  # non-trivial BN statistics, so a missed buffer would show
        for m in model.modules():
            if isinstance(m, (torch.nn.BatchNorm2d, torch.nn.BatchNorm1d)):
                m.running_mean.uniform_(-0.1, 0.1)
                m.running_var.uniform_(0.5, 1.5)
    model.eval()
    sd = {"module." + k: v for k, v in model.state_dict().items()}  # DataParallel prefixes
    assert "module.classifier.weight" in sd
    path = tmp_path / "osnet_x0_25_random.pth.tar"
    torch.save({"state_dict": sd, "epoch": 3, "rank1": 0.0}, path)

    reid = OsnetReid("x0_25", weights=path, input_size=(128, 64))  # 1000-class head: ignored
    assert reid.report["loaded"] == len(sd) - 2 and len(reid.report["ignored"]) == 2
    x = torch.randn(2, 3, 128, 64)
    with torch.inference_mode():
        np.testing.assert_allclose(reid.model(x).numpy(), model(x).numpy(), rtol=1e-5, atol=1e-6)

    fresh = osnet("x0_25")
    load_torchreid_checkpoint(fresh, path)  # the loader on its own
    fresh.eval()
    with torch.inference_mode():
        np.testing.assert_allclose(fresh(x).numpy(), model(x).numpy(), rtol=1e-5, atol=1e-6)


def test_bad_checkpoints_are_clear_errors(tmp_path):
    from edge_node.perception.osnet import load_torchreid_checkpoint, osnet
    from edge_node.perception.reid import OsnetReid

    with pytest.raises(PerceptionError, match="not found"):
        OsnetReid("x0_25", weights=tmp_path / "nope.pth")
    with pytest.raises(PerceptionError, match="needs a weights file"):
        OsnetReid("x0_25")
    junk = tmp_path / "junk.pth"
    junk.write_bytes(b"this is not a checkpoint")
    with pytest.raises(PerceptionError, match="cannot read"):
        OsnetReid("x0_25", weights=junk)
    wrong = tmp_path / "x1_0.pth"  # another width
    torch.save({"state_dict": osnet("x1_0").state_dict()}, wrong)
    with pytest.raises(PerceptionError, match="shape mismatch"):
        load_torchreid_checkpoint(osnet("x0_25"), wrong)
    partial = tmp_path / "partial.pth"
    sd = osnet("x0_25").state_dict()
    sd.pop("conv5.conv.weight")
    sd["extra.weight"] = torch.zeros(1)
    torch.save(sd, partial)
    with pytest.raises(PerceptionError, match=r"missing keys: conv5\.conv\.weight.*unexpected keys: "
                                              r"extra\.weight"):
        load_torchreid_checkpoint(osnet("x0_25"), partial)
    notdict = tmp_path / "list.pth"
    torch.save([1, 2, 3], notdict)
    with pytest.raises(PerceptionError, match="not a torchreid checkpoint"):
        load_torchreid_checkpoint(osnet("x0_25"), notdict)


# -- detectors on rendered frames --------------------------------------------------------------------
def test_mog2_finds_rendered_people(close_world):
    data, r = close_world
    det = Mog2Detector(camera=data.cameras[0], background=r.background(0))
    found = [det.detect(r.frame(0, k)) for k in range(data.frames)]
    assert _recall(data, found, range(2, data.frames)) > 0.5
    # without the camera's geometry (no blob splitting by person size) it still finds people
    plain = Mog2Detector(background=r.background(0))
    found = [plain.detect(r.frame(0, k)) for k in range(data.frames)]
    assert _recall(data, found, range(2, data.frames)) > 0.5


@pytest.mark.skipif(not hog_available(), reason="this OpenCV has no HOG (OpenCV 5 moved it to "
                                                 "opencv-contrib)")
def test_hog_finds_rendered_people(close_world):
    data, r = close_world
    det = HogDetector(upscale=2.0, win_stride=4)  # trained on photographs: a finer scan
    frames = range(0, data.frames, 2)
    found = {k: det.detect(r.frame(0, k)) for k in frames}
    assert _recall(data, found, frames) > 0.5


def test_hog_missing_is_a_clear_error():
    if hog_available():
        pytest.skip("this OpenCV has HOG, so there is no missing-HOG error to check")
    with pytest.raises(PerceptionError, match="opencv-contrib"):
        HogDetector()


def test_mog2_splits_people_side_by_side():
    """Two people touching in the image: one blob, two boxes (the camera says how wide one is)."""
    from sim_cluster.scenarios.synthetic.schema import camera_from_pose

    cam = camera_from_pose(0, (320, 240), np.array([0.0, -6.0, 2.5]), 90.0, 15.0, fov_deg=60.0)
    bg = np.full((240, 320, 3), 90, np.uint8)
    det = Mog2Detector(camera=cam, background=bg)
    img = bg.copy()
    boxes = [cam.cylinder_to_box(np.array([x, 0.0, 0.5, 1.75])) for x in (-0.27, 0.27)]
    for b, col in zip(boxes, ((40, 40, 220), (220, 60, 40))):
        x, y, w, h = b
        cv2.rectangle(img, (int(x), int(y)), (int(x + w), int(y + h)), col, -1)
    found = det.detect(img)
    assert len(found) == 2
    feet = sorted(cam.to_ground(np.array([[b[0] + b[2] / 2, b[1] + b[3]]]))[0][0] for b, _ in found)
    np.testing.assert_allclose(feet, [-0.27, 0.27], atol=0.12)


def test_onnx_detector_checks_its_model_at_construction(tmp_path):
    with pytest.raises(PerceptionError, match="model file not found"):
        OnnxDetector(tmp_path / "missing.onnx")
    bad = tmp_path / "bad.onnx"
    bad.write_bytes(b"\x00\x01 definitely not protobuf")
    with pytest.raises(PerceptionError, match="cannot load the model"):
        OnnxDetector(bad)


def test_onnx_output_layouts_decode():
    det = OnnxDetector.__new__(OnnxDetector)  # decoding needs no network
    det.score_threshold, det.class_id, det.layout = 0.5, 0, "auto"
    v8 = np.zeros((1, 6, 10), np.float32)  # (4 + 2 classes, N anchors)
    v8[0, :, 0] = [100, 100, 20, 60, 0.9, 0.1]  # a person
    v8[0, :, 1] = [50, 50, 20, 20, 0.2, 0.95]  # another class
    v8[0, :, 2] = [10, 10, 5, 5, 0.3, 0.0]  # too weak
    xyxy, s = det._decode(v8)
    np.testing.assert_allclose(xyxy, [[90, 70, 110, 130]])
    np.testing.assert_allclose(s, [0.9], rtol=1e-6)
    v5 = np.zeros((1, 10, 7), np.float32)  # (N anchors, 5 + 2 classes)
    v5[0, 0] = [100, 100, 20, 60, 0.9, 0.9, 0.1]
    v5[0, 1] = [100, 100, 20, 60, 0.4, 0.9, 0.1]
    xyxy, s = det._decode(v5)
    assert len(s) == 1 and s[0] == pytest.approx(0.81)
    assert list(nms(np.array([[0, 0, 10, 10], [1, 1, 10, 10], [50, 50, 5, 5]]),
                    np.array([0.5, 0.9, 0.3]), 0.5)) == [1, 2]


# -- re-id on rendered people -------------------------------------------------------------------------
def test_histogram_reid_separates_rendered_identities(close_world):
    data, r = close_world
    reid = HistogramReid()
    desc: dict[int, list[np.ndarray]] = {}
    for k in range(0, data.frames, 3):
        ids, boxes = data.truth.boxes[0][k]
        img = r.frame(0, k)
        alone = [i for i, b in enumerate(boxes)
                 if all(_iou(b, o) == 0 for j, o in enumerate(boxes) if j != i)]
        d = reid.extract(img, boxes[alone])
        for i, row in zip(alone, d):
            if np.all(np.isfinite(row)):
                desc.setdefault(int(ids[i]), []).append(row)
    people = [p for p, v in desc.items() if len(v) >= 2]
    assert len(people) >= 2
    np.testing.assert_allclose(np.linalg.norm(desc[people[0]][0]), 1.0, rtol=1e-5)
    for a in people:
        same = max(1 - float(x @ y) for i, x in enumerate(desc[a]) for y in desc[a][i + 1:])
        for b in people:
            if b != a:
                diff = min(1 - float(x @ y) for x in desc[a] for y in desc[b])
                assert same < diff, (a, b, same, diff)


# -- calibration -------------------------------------------------------------------------------------
@pytest.mark.integration
def test_calibrate_recovers_a_known_homography(tmp_path):
    from edge_node.perception.calibrate import fit_homography, read_pairs, report
    from sim_cluster.scenarios.synthetic.schema import camera_from_pose

    cam = camera_from_pose(0, (360, 288), np.array([-1.0, -1.0, 3.0]), 45.0, 20.0, fov_deg=62.0)
    ground = np.array([[2, 2], [6, 2], [6, 6], [2, 6], [4, 3], [3, 5]], float)
    pixels = cam.to_image(ground) + np.random.default_rng(0).normal(0, 0.5, (6, 2))
    f = tmp_path / "pairs.csv"
    f.write_text("u,v,x,y\n" + "\n".join(f"{u:.3f}, {v:.3f}, {x}, {y}  # mark {i}"
                                          for i, ((u, v), (x, y)) in enumerate(zip(pixels, ground))))
    img, gnd = read_pairs(f)
    cal = fit_homography(img, gnd)
    probe = np.array([[100.0, 250.0], [200.0, 180.0], [300.0, 220.0]])
    truth = cam.to_ground(probe)
    q = np.hstack([probe, np.ones((3, 1))]) @ cal.G.T
    np.testing.assert_allclose(q[:, :2] / q[:, 2:], truth, atol=0.15)
    assert cal.summary()["image_rms_px"] < 1.5
    out = subprocess.run([sys.executable, "-m", "edge_node.cli", "calibrate", "--points", str(f),
                          "--image-size", "360", "288"], capture_output=True, text=True, cwd=REPO)
    assert out.returncode == 0, out.stderr
    import tomllib

    table = tomllib.loads(out.stdout.split("\n\n")[0])["camera"]
    np.testing.assert_allclose(np.array(table["homography"]), cal.G, rtol=1e-6, atol=1e-9)
    assert table["image_size"] == [360, 288]
    # a pair 6 px off: without RANSAC it is fitted with the others and reported as used (OpenCV
    # 5's mask of the plain fit marks the pairs within its threshold); RANSAC leaves it out
    pixels[4] += (6.0, 0.0)
    cal = fit_homography(pixels, ground)
    assert cal.inliers.all() and cal.summary()["inliers"] == 6
    assert cal.image_error[4] > 3.0  # (what the plain fit's mask would have called an outlier)
    assert "(outlier" not in report(cal)
    robust = fit_homography(pixels, ground, ransac_px=3.0)
    assert not robust.inliers[4] and robust.inliers.sum() == 5
    f.write_text("1,2,3,4\n5,6,7,8\n")
    bad = subprocess.run([sys.executable, "-m", "edge_node.cli", "calibrate", "--points", str(f)],
                         capture_output=True, text=True, cwd=REPO)
    assert bad.returncode == 2 and "at least 4" in bad.stderr



@pytest.mark.integration  # runs edge_node calibrate as a process
def test_calibrate_with_a_binary_points_file_is_one_line_and_exit_2(tmp_path):
    """A point pairs file of binary bytes was a UnicodeDecodeError traceback (exit 1)."""
    from edge_node.perception.calibrate import read_pairs

    f = tmp_path / "pairs.csv"
    f.write_bytes(b"u,v,x,y\n\xff\xfe\x00garbage\x80\x81\n")
    message = (f"{f}:2: not UTF-8 text: byte 0xff at offset 8 (a binary file, or another "
               "encoding)")
    with pytest.raises(PerceptionError) as e:
        read_pairs(f)
    assert str(e.value) == message
    out = subprocess.run([sys.executable, "-m", "edge_node.cli", "calibrate", "--points", str(f)],
                         capture_output=True, text=True)
    assert (out.returncode, out.stderr) == (2, f"edge_node: error: {message}\n")



@pytest.mark.parametrize("bad", [b"[]", b"\xff\xfe\x00garbage\x80\x81"])
def test_a_render_json_that_cannot_be_read_renders_again(tmp_path, bad):
    """``up --source video`` reuses a folder's videos when its render.json says they are this
    scenario's; a render.json of other JSON ended it in an AttributeError traceback."""
    from sim_cluster.scenarios.synthetic.render import ensure_rendered

    (tmp_path / "render.json").write_bytes(bad)
    done = ensure_rendered("lab-sim", tmp_path, 0, 2, cameras=[0])
    assert done["frames"] == 2 and Path(done["cameras"]["0"]["frames"]).is_file()
    assert ensure_rendered("lab-sim", tmp_path, 0, 2, cameras=[0]) == done  # reused now


# -- frame sources and configs ---------------------------------------------------------------------------
def test_frame_sources(tmp_path):
    from edge_node.perception.frames import EpflLayout, ImageFolder, VideoFile, open_frames

    imgs = [np.full((48, 64, 3), 10 * i, np.uint8) for i in range(12)]
    vw = cv2.VideoWriter(str(tmp_path / "terrace1-c1.avi"), cv2.VideoWriter_fourcc(*"MJPG"), 10.0,
                         (64, 48))
    for im in imgs:
        vw.write(im)
    vw.release()
    v = VideoFile(tmp_path / "terrace1-c1.avi")
    frames = list(v)
    assert [f.index for f in frames] == list(range(12)) and v.fps == pytest.approx(10.0)
    assert frames[5].timestamp == pytest.approx(0.5, abs=0.11) and frames[0].image.shape == (48, 64, 3)
    (tmp_path / "imgs").mkdir()
    for i in (1, 2, 10):
        cv2.imwrite(str(tmp_path / "imgs" / f"f{i}.png"), imgs[i])
    folder = ImageFolder(tmp_path / "imgs", fps=5.0)
    got = list(folder)
    assert [int(f.image[0, 0, 0]) for f in got] == [10, 20, 100]  # natural order: f2 before f10
    assert got[2].timestamp == pytest.approx(0.4)
    (tmp_path / "homographies.json").write_text(json.dumps({"terrace": {
        "sequence": "terrace1", "image_scale": 1.0, "image_size_annotations": [64, 48],
        "H": [np.eye(3).tolist(), [[1, 0, 0], [0, 2, 0], [0, 0, 1]]]}}))
    e = EpflLayout(tmp_path, "terrace1", 1)
    assert e.frames == 12 and e.camera(5).G[1, 1] == pytest.approx(2.0)
    with pytest.raises(PerceptionError, match="no terrace1-c3.avi"):
        open_frames("epfl", path=tmp_path, sequence="terrace1", camera=3)
    with pytest.raises(PerceptionError, match="not found"):
        VideoFile(tmp_path / "nope.avi")
    (tmp_path / "broken.avi").write_bytes(b"garbage" * 100)
    with pytest.raises(PerceptionError):
        VideoFile(tmp_path / "broken.avi")


def test_video_config_is_validated(tmp_path):
    from edge_node.runtime.config import NodeConfigError, load_node_config

    video = tmp_path / "cam.avi"
    video.write_bytes(b"x")
    base = f'node = 0\nnetwork = "n"\n[source]\nkind = "video"\npath = "{video}"\n'
    cam = '[camera]\nhomography = [[1,0,0],[0,1,0],[0,0,1]]\nimage_size = [64, 48]\n'
    f = tmp_path / "c.toml"
    f.write_text(base)
    with pytest.raises(NodeConfigError, match="camera is required"):
        load_node_config(f)
    f.write_text(base + cam + '[perception]\ndetector = "onnx"\n')
    with pytest.raises(NodeConfigError, match="perception.onnx is required"):
        load_node_config(f)
    f.write_text(base + cam + '[perception]\ndetector = "onnx"\n[perception.onnx]\nmodel = "m.onnx"\n')
    with pytest.raises(NodeConfigError, match="perception.onnx.model names a file that does not exist"):
        load_node_config(f)
    f.write_text(base + cam + '[perception]\nreid = "osnet_x0_25"\n')
    with pytest.raises(NodeConfigError, match="perception.osnet is required"):
        load_node_config(f)
    f.write_text(base + cam + '[perception]\nreid = "histogram"\n[perception.mog2]\nhistory = 100\n'
                 'split = false\nperson_size_m = [0.5, 1.8]\n')
    cfg = load_node_config(f)
    assert cfg.perception.of("mog2") == {"history": 100, "split": False, "person_size_m": [0.5, 1.8]}
    assert json.dumps(cfg.to_dict())  # edge_node check prints it
    f.write_text(base.replace('"video"', '"scenario"').replace(f'path = "{video}"',
                                                                 'scenario = "terrace-sim"')
                 + '[perception]\ndetector = "mog2"\n')
    with pytest.raises(NodeConfigError, match="applies to frame sources"):
        load_node_config(f)


@pytest.mark.integration
def test_perception_modules_do_not_import_torch():
    code = ("import sys; import edge_node.perception.pipeline, edge_node.perception.settings, "
            "edge_node.runtime.sources, edge_node.core.node; "
            "print('torch' in sys.modules, 'cv2' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=REPO)
    assert out.stdout.split() == ["False", "False"], out.stderr


# -- end to end: rendered video -> detector -> re-id -> tracker, one process per camera --------------
@pytest.mark.integration
@pytest.mark.slow  # renders 4 cameras' video, then runs the 4-node cluster and the reference
def test_cluster_from_rendered_video_tracks_at_least_0_8_of_simulated(tmp_path):
    """Issue 7's bar: one process per camera from rendered frames (MOG2 + histogram re-id) reaches
    at least 0.8 x the ground MOTA of the same scenario from simulated detections (the in-process
    run, which the cluster reproduces exactly from simulated detections: test_cluster.py). A sync
    timeout long enough that a node starved of CPU (a busy machine) is waited for, not fused
    without: the accuracy is then the detector's, not the machine's load."""
    out = tmp_path / "run"
    r = subprocess.run([sys.executable, "-m", "sim_cluster.cli", "up", "--scenario", "terrace-sim",
                        "--source", "video", "--frames", "300", "--sync-timeout", "60", "--out",
                        str(out), "--quiet"],
                       capture_output=True, text=True, cwd=REPO, timeout=600)
    assert r.returncode == 0, r.stdout + r.stderr
    cfg = (out / "configs" / "node1.toml").read_text()
    assert 'kind = "video"' in cfg and "[perception.mog2]" in cfg
    assert (out / "video" / "c1.avi").is_file() and (out / "video" / "background_c1.avi").is_file()
    summary = json.loads((out / "summary.json").read_text())
    assert summary["nodes"] == 4
    log = (out / "logs" / "node0.log").read_text()
    assert "video" in log and "mog2 + histogram" in log
    ref = tmp_path / "ref"
    r = subprocess.run([sys.executable, "-m", "sim_cluster.cli", "run", "--scenario", "terrace-sim",
                        "--topology", "chain", "--frames", "300", "--out", str(ref), "--quiet"],
                       capture_output=True, text=True, cwd=REPO, timeout=600)
    assert r.returncode == 0, r.stdout + r.stderr
    simulated = json.loads((ref / "summary.json").read_text())["metrics"]["ground"]["median"]
    video = summary["metrics"]["ground"]["median"]
    assert simulated["mota"] > 0.9
    assert video["mota"] >= 0.8 * simulated["mota"], (video, simulated)


@pytest.mark.integration
def test_cluster_runs_osnet_from_a_torchreid_checkpoint(tmp_path):
    """The OSNet path end to end: random weights saved as a torchreid checkpoint, loaded by each
    node at start-up (the features carry no identity; this checks the plumbing, not accuracy)."""
    from edge_node.perception.osnet import osnet

    ckpt = tmp_path / "osnet_x0_25_random.pth"
    torch.save({"state_dict": {"module." + k: v
                               for k, v in osnet("x0_25", num_classes=751).state_dict().items()}},
               ckpt)
    out = tmp_path / "run"
    r = subprocess.run([sys.executable, "-m", "sim_cluster.cli", "up", "--scenario", "terrace-sim",
                        "--source", "video", "--reid", "osnet_x0_25", "--reid-weights", str(ckpt),
                        "--frames", "20", "-n", "2", "--out", str(out), "--quiet"],
                       capture_output=True, text=True, cwd=REPO, timeout=240)
    assert r.returncode == 0, r.stdout + r.stderr
    assert "mog2 + osnet_x0_25" in (out / "logs" / "node1.log").read_text()
    assert json.loads((out / "summary.json").read_text())["frames"] == 20
