"""``sim_cluster ablation``: a tiny grid run twice (one process, two processes); the aggregates are
recomputed here from results.csv, independently of ``sim_cluster.experiments.ablation.aggregate``."""
from __future__ import annotations

import csv
import json
import statistics
from collections import defaultdict

import pytest

from sim_cluster import cli
from sim_cluster.experiments import ablation

GRID = ["--scenarios", "terrace-sim", "--seeds", "0-1", "--frames", "15",
        "--configs", "dkf+lda,dkf+lda+dtm", "--topologies", "ring,centralized", "--orderings", "2",
        "--quiet"]
EXPECTED_RUNS = 2 * 2 * (2 + 1)  # seeds x configs x (ring orderings + centralized)


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    out = {}
    for jobs in (1, 2):
        d = tmp_path_factory.mktemp(f"ablation_j{jobs}")
        assert cli.main(["ablation", *GRID, "--jobs", str(jobs), "--out", str(d)]) == 0
        out[jobs] = d
    return out


def _rows(d):
    with open(d / "results.csv", newline="") as fh:
        return list(csv.DictReader(fh))


def _mean_std(vals):
    return statistics.fmean(vals), (statistics.stdev(vals) if len(vals) > 1 else 0.0)


def _per_seed(rows, col):
    """(topology, config) -> {seed: mean over orderings}."""
    acc = defaultdict(lambda: defaultdict(list))
    for r in rows:
        acc[(r["topology"], r["config"])][int(r["seed"])].append(float(r[col]))
    return {k: {s: statistics.fmean(v) for s, v in d.items()} for k, d in acc.items()}


@pytest.mark.integration
def test_csv_rows_and_columns(runs):
    rows = _rows(runs[1])
    assert len(rows) == EXPECTED_RUNS
    assert list(rows[0]) == list(ablation.CSV_COLS)
    ring = [r for r in rows if r["topology"] == "ring"]
    assert len(ring) == 8
    assert {(r["ordering"], r["order"]) for r in ring} == {("0", "0 1 2 3"), ("1", "0 1 3 2")}
    cent = [r for r in rows if r["topology"] == "centralized"]
    assert len(cent) == 4 and all(r["ordering"] == "0" and r["order"] == "" for r in cent)
    for r in rows:
        assert r["frames"] == "15" and r["nodes"] == "4"
        for col in ("ground_mota", "ground_idf1", "image_mota", "image_idf1", "bytes_per_frame"):
            float(r[col])  # defined on this grid
    # the centralized baseline's bandwidth is the raw detections sent to the server
    assert all(float(r["bytes_per_frame"]) > 0 for r in cent)
    # ordering order in the file follows the plan: scenario, seed, config, topology, ordering
    keys = [(int(r["seed"]), r["config"], r["topology"], int(r["ordering"])) for r in rows]
    assert keys == [(s, c, t, o) for s in (0, 1) for c in ("dkf+lda", "dkf+lda+dtm")
                    for t, n in (("ring", 2), ("centralized", 1)) for o in range(n)]


@pytest.mark.integration
def test_jobs_do_not_change_results(runs):
    assert (runs[1] / "results.csv").read_bytes() == (runs[2] / "results.csv").read_bytes()
    s1 = json.loads((runs[1] / "summary.json").read_text())
    s2 = json.loads((runs[2] / "summary.json").read_text())
    # each file names the code and the machine it was measured on (the docs' tables quote it);
    # the load average of the moment differs, nothing else
    p1, p2 = s1["meta"].pop("provenance"), s2["meta"].pop("provenance")
    assert p1["machine"] and p1["commit"] and p1["date"] and p1.keys() == p2.keys()
    assert s1 == s2


@pytest.mark.integration
def test_aggregates_match_csv(runs):
    rows = _rows(runs[1])
    summary = json.loads((runs[1] / "summary.json").read_text())
    cells = summary["cells"]["terrace-sim"]
    md = (runs[1] / "results.md").read_text()
    for col in ("ground_mota", "ground_idf1", "image_mota", "image_idf1", "bytes_per_frame",
                "ground_fp", "ground_track_ids", "ground_ids_per_person", "ground_mt",
                "ground_fragmentations"):
        for (topo, cfg), seeds in _per_seed(rows, col).items():
            mean, std = _mean_std(list(seeds.values()))
            cell = cells[topo][cfg][col]
            assert cell["n"] == 2
            assert cell["mean"] == pytest.approx(mean, rel=1e-12, abs=1e-12)
            assert cell["std"] == pytest.approx(std, rel=1e-9, abs=1e-12)
            if col in ("ground_mota", "ground_idf1", "image_mota", "image_idf1"):
                assert f"{mean:.3f} ± {std:.3f}" in md


@pytest.mark.integration
def test_identity_counts_in_csv_table_and_printout(runs):
    """Every run has its people, track ids, ids per person and MT/PT/ML (of one run's nodes:
    MT + PT + ML is the number of people); results.md and the printed table show the means."""
    rows = _rows(runs[1])
    for r in rows:
        people = float(r["ground_people"])
        assert people > 0 and float(r["ground_track_ids"]) >= 1
        assert float(r["ground_ids_per_person"]) >= 1.0
        assert float(r["ground_mt"]) + float(r["ground_pt"]) + float(r["ground_ml"]) \
            == pytest.approx(people, abs=1.0)  # medians over nodes of each: within one
    md = (runs[1] / "results.md").read_text()
    assert "**Identity (ground)**" in md and "ids/person" in md
    summary = json.loads((runs[1] / "summary.json").read_text())
    text = ablation.identity_text({"cells": summary["cells"]}, summary["meta"])
    tracks = summary["cells"]["terrace-sim"]["ring"]["dkf+lda+dtm"]["ground_track_ids"]["mean"]
    line = next(t for t in text.splitlines() if " ring " in t and " dkf+lda+dtm " in t)
    assert f"{tracks:.1f}" in line.split()


@pytest.mark.integration
def test_orderings_are_averaged_within_a_seed(runs):
    rows = _rows(runs[1])
    cell = json.loads((runs[1] / "summary.json").read_text())["cells"]["terrace-sim"]
    for cfg in ("dkf+lda", "dkf+lda+dtm"):
        for col in ("ground_mota", "ground_idf1", "image_mota"):
            vals = {(int(r["seed"]), int(r["ordering"])): float(r[col]) for r in rows
                    if r["topology"] == "ring" and r["config"] == cfg}
            seed_means = [(vals[(s, 0)] + vals[(s, 1)]) / 2 for s in (0, 1)]
            got = cell["ring"][cfg][col]
            assert got["mean"] == pytest.approx(statistics.fmean(seed_means))
            assert got["std"] == pytest.approx(statistics.stdev(seed_means))
    # and the aggregation itself, on hand-made rows: orderings 1, 3 (seed 0) and 5 (seed 1)
    hand = [dict(scenario="x", seed=0, config="dkf", topology="ring", ground_mota=1.0),
            dict(scenario="x", seed=0, config="dkf", topology="ring", ground_mota=3.0),
            dict(scenario="x", seed=1, config="dkf", topology="ring", ground_mota=5.0)]
    got = ablation.aggregate(hand)["cells"]["x"]["ring"]["dkf"]["ground_mota"]
    assert got == {"mean": 3.5, "std": pytest.approx(statistics.stdev([2.0, 5.0])), "n": 2}


@pytest.mark.integration
def test_ratio_to_centralized(runs):
    rows = _rows(runs[1])
    summary = json.loads((runs[1] / "summary.json").read_text())
    for col in ("ground_mota", "ground_idf1"):
        ps = _per_seed(rows, col)
        dist, cent = ps[("ring", "dkf+lda+dtm")], ps[("centralized", "dkf+lda+dtm")]
        mean, std = _mean_std([dist[s] / cent[s] for s in (0, 1)])
        got = summary["ratios"]["terrace-sim"]["ring"][col]
        assert got["mean"] == pytest.approx(mean) and got["std"] == pytest.approx(std)
    md = (runs[1] / "results.md").read_text()
    assert "Distributed / centralized" in md and "1215" in md and "16.38" in md and "0.78" in md


@pytest.mark.integration
def test_png_written(runs):
    data = (runs[1] / "ablation.png").read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n" and data[12:16] == b"IHDR"
    width, height = int.from_bytes(data[16:20], "big"), int.from_bytes(data[20:24], "big")
    assert width > 100 and height > 100


def test_parse_seeds():
    assert ablation.parse_seeds("0-4") == [0, 1, 2, 3, 4]
    assert ablation.parse_seeds("0,2,5") == [0, 2, 5]
    assert ablation.parse_seeds("5,0-1,1") == [0, 1, 5]
    for bad in ("", "a", "3-1", "-1", "1-2-3", "0,,1"):
        with pytest.raises(ablation.AblationError):
            ablation.parse_seeds(bad)


def test_plan_is_deterministic_and_complete():
    tasks = ablation.plan(["a", "b"], [0, 1], ["dkf", "dkf+lda+dtm"],
                          ["complete", "ring", "chain", "disconnected", "centralized"],
                          cameras={"a": 4, "b": 3}, orderings=3)
    # a: 4 cameras -> 3 ring and 3 chain orderings; b: 3 cameras -> 1 ring, 3 chains
    assert len(tasks) == 2 * 2 * (1 + 3 + 3 + 1 + 1) + 2 * 2 * (1 + 1 + 3 + 1 + 1)
    assert [t.index for t in tasks] == list(range(len(tasks)))
    rings = {t.order for t in tasks if t.scenario == "a" and t.topology == "ring"}
    assert len(rings) == 3
    assert all(t.order is None for t in tasks if t.topology not in ("ring", "chain"))
    assert tasks == ablation.plan(["a", "b"], [0, 1], ["dkf", "dkf+lda+dtm"],
                                  ["complete", "ring", "chain", "disconnected", "centralized"],
                                  cameras={"a": 4, "b": 3}, orderings=3)


@pytest.mark.parametrize("args, message", [
    (["--scenarios", "no-such-scenario"], "no-such-scenario"),
    (["--configs", "dkf,bogus"], "unknown config 'bogus'"),
    (["--topologies", "ring,mesh"], "unknown topology 'mesh'"),
    (["--seeds", "4-2"], "bad --seeds"),
    (["--jobs", "0"], "--jobs"),
])
def test_bad_arguments_exit_2(tmp_path, capsys, args, message):
    assert cli.main(["ablation", "--scenarios", "terrace-sim", "--seeds", "0", *args,
                     "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("sim_cluster: error:") and message in err[0]


def test_missing_data_is_skipped_with_a_reason(tmp_path, capsys):
    info, skipped = ablation.probe(["terrace-gt"], 0, str(tmp_path / "nowhere"))
    assert info == {} and "terrace-gt" in skipped
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "skipping terrace-gt" in err and "nowhere" in err
    # only missing scenarios: nothing to run is a user error
    assert cli.main(["ablation", "--scenarios", "terrace-gt", "--seeds", "0",
                     "--data-root", str(tmp_path / "nowhere"), "--out", str(tmp_path)]) == 2


def test_a_failed_run_is_reported_and_left_out(tmp_path, monkeypatch, capsys):
    real = ablation.run_task

    def flaky(task):
        if task.topology == "disconnected":
            raise RuntimeError("boom")
        return real(task)

    monkeypatch.setattr(ablation, "run_task", flaky)
    rc = cli.main(["ablation", "--scenarios", "campus-sim", "--seeds", "0", "--frames", "8",
                   "--configs", "dkf+lda+dtm", "--topologies", "complete,disconnected",
                   "--jobs", "1", "--quiet", "--out", str(tmp_path)])
    assert rc == 1
    assert "run failed (campus-sim s0 dkf+lda+dtm disconnected): RuntimeError: boom" in \
        capsys.readouterr().err
    rows = _rows(tmp_path)
    assert [r["topology"] for r in rows] == ["complete"]
    assert "1 run(s) failed" in (tmp_path / "results.md").read_text()
