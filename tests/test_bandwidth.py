"""``sim_cluster bandwidth-sweep``: a tiny sweep end to end (terrace-sim, 60 frames, gains 0 and
10, late at 0), checked against runs made here with ``run_once``; EPFL data is not needed (a
terrace-gt in the list is skipped with one line: ``--data-root`` points at an empty folder)."""
from __future__ import annotations

import contextlib
import csv
import io
import math

import pytest

from edge_node.core.config import TrackerConfig
from edge_node.core.trigger import TriggerConfig
from edge_node.faults import FaultPlan
from sim_cluster import cli
from sim_cluster.experiments import bandwidth
from sim_cluster.experiments.run import run_once
from sim_cluster.scenarios.loader import load_scenario

FRAMES = 60
ARGS = ["--scenarios", "terrace-sim,terrace-gt", "--frames", str(FRAMES), "--gains", "10,0",
        "--late", "0", "--quiet"]


@pytest.fixture(scope="module")
def sweep(tmp_path_factory):
    """The command's output folder and what it printed (stdout, stderr)."""
    out = tmp_path_factory.mktemp("bandwidth")
    empty = tmp_path_factory.mktemp("no_epfl_data")
    stdout, stderr = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(stdout), contextlib.redirect_stderr(stderr):
        code = cli.main(["bandwidth-sweep", *ARGS, "--data-root", str(empty), "--out", str(out)])
    assert code == 0, stderr.getvalue()
    return out, (stdout.getvalue(), stderr.getvalue())


@pytest.fixture(scope="module")
def terrace():
    return load_scenario("terrace-sim", frames=FRAMES)


def _rows(out):
    with open(out / "bandwidth.csv", newline="") as fh:
        return list(csv.DictReader(fh))


def _find(rows, mode, gain=None, late="False"):
    (r,) = [r for r in rows if r["mode"] == mode and r["late"] == late
            and (gain is None or (r["gain"] and float(r["gain"]) == gain))]
    return r


@pytest.mark.integration
def test_csv_columns_rows_and_skip_notice(sweep):
    out, (stdout, stderr) = sweep
    rows = _rows(out)
    assert list(rows[0]) == list(bandwidth.CSV_COLS)
    # plan order: sync, async by increasing gain, late; terrace-gt skipped (no data)
    assert [(r["scenario"], r["mode"], r["gain"], r["late"]) for r in rows] == [
        ("terrace-sim", "sync", "", "False"), ("terrace-sim", "async", "0.0", "False"),
        ("terrace-sim", "async", "10.0", "False"), ("terrace-sim", "async", "0.0", "True")]
    for r in rows:
        assert r["topology"] == "ring" and r["config"] == "dkf+lda+dtm"
        assert r["frames"] == str(FRAMES) and r["nodes"] == "4"
        for col in ("bytes_per_frame", "bytes_ratio", "ground_mota", "ground_idf1", "image_mota",
                    "image_idf1", "mota_ratio", "idf1_ratio"):
            assert math.isfinite(float(r[col]))
    skips = [line for line in stderr.splitlines() if "skipping terrace-gt" in line]
    assert len(skips) == 1 and skips[0].startswith("bandwidth-sweep: skipping terrace-gt: ")
    assert (out / "bandwidth.png").stat().st_size > 10_000
    assert "terrace-sim" in stdout and "gain (largest within 2%)" in stdout


@pytest.mark.integration
def test_sync_bytes_equal_the_runs_own_counters(sweep, terrace):
    """The sweep's sync and gain-10 rows against runs made here, bytes from the wire counters."""
    rows = _rows(sweep[0])
    cfg = TrackerConfig.for_ablation("dkf+lda+dtm")
    for row, kw in ((_find(rows, "sync"), {}),
                    (_find(rows, "async", 10.0), {"mode": "async",
                                                   "trigger": TriggerConfig(gain=10.0)}),
                    (_find(rows, "async", 0.0, late="True"),
                     {"mode": "async", "trigger": TriggerConfig(gain=0.0),
                      "faults": FaultPlan.from_dict({"seed": 1,
                                                     "link": [{"delay": 1, "jitter": 3}]})})):
        result, summary = run_once(terrace, "ring", cfg, **kw)
        assert float(row["bytes_per_frame"]) == pytest.approx(
            sum(result.wire.bytes_per_link.values()) / FRAMES, rel=1e-12)
        assert int(row["messages"]) == result.wire.messages
        assert float(row["ground_mota"]) == pytest.approx(
            summary["metrics"]["ground"]["median"]["mota"], rel=1e-12)
        assert float(row["image_idf1"]) == pytest.approx(
            summary["metrics"]["image"]["median"]["idf1"], rel=1e-12)


@pytest.mark.integration
def test_large_gain_sends_fewer_bytes_and_ratios(sweep):
    rows = _rows(sweep[0])
    sync, g0, g10 = _find(rows, "sync"), _find(rows, "async", 0.0), _find(rows, "async", 10.0)
    assert float(g10["bytes_per_frame"]) < float(g0["bytes_per_frame"]) < \
        float(sync["bytes_per_frame"])
    for r in rows:
        assert float(r["bytes_ratio"]) == pytest.approx(
            float(r["bytes_per_frame"]) / float(sync["bytes_per_frame"]))
        assert float(r["mota_ratio"]) == pytest.approx(
            float(r["ground_mota"]) / float(sync["ground_mota"]))
    assert float(sync["bytes_ratio"]) == 1.0


@pytest.mark.integration
def test_markdown_tables(sweep):
    out, (stdout, _) = sweep
    md = (out / "bandwidth.md").read_text()
    rows = _rows(out)
    sync = _find(rows, "sync")
    assert "- **terrace-gt skipped**" in md
    assert ("Reproduce with `sim_cluster bandwidth-sweep --scenarios terrace-sim,terrace-gt "
            f"--gains 0,10 --late 0 --frames {FRAMES}`.") in md
    assert "| scenario | sync B/frame | gain (largest within 2%) | bytes ratio |" in md
    assert "## terrace-sim" in md
    # the per-scenario table: one line per run, numbers as in the CSV
    assert (f"| sync | – | {float(sync['bytes_per_frame']):.0f} | "
            f"{float(sync['bytes_per_tracker_frame']):.1f} | 1.000 | "
            f"{float(sync['ground_mota']):.3f} |") in md
    g10 = _find(rows, "async", 10.0)
    assert f"| async | 10 | {float(g10['bytes_per_frame']):.0f} |" in md
    assert "| async, late | 0 |" in md
    # the summary names the largest gain within 2% of sync and its bytes ratio
    within = [r for r in rows if r["mode"] == "async" and r["late"] == "False"
              and float(r["mota_ratio"]) >= 0.98]
    best = max(within, key=lambda r: float(r["gain"]))
    line = next(line for line in md.splitlines() if line.startswith("| terrace-sim |"))
    assert f"| {float(best['gain']):g} | {float(best['bytes_ratio']):.3f} |" in line
    assert "largest gain within 2% of sync MOTA" in md


def test_summary_picks_the_largest_gain_within_2_percent():
    def row(mode, gain, mota, b, late=False):
        return {"scenario": "s", "mode": mode, "gain": gain, "late": late, "nodes": 4,
                "frames": 10, "bytes_per_frame": b, "bytes_per_tracker_frame": 50.0,
                "ground_mota": mota, "ground_idf1": mota, "image_mota": mota, "image_idf1": mota}

    rows = bandwidth.with_ratios([row("sync", None, 1.0, 100.0), row("async", 0.0, 0.99, 90.0),
                                  row("async", 0.1, 0.97, 60.0), row("async", 1.0, 0.985, 50.0),
                                  row("async", 3.0, 0.9, 40.0),
                                  row("async", 0.0, 0.96, 95.0, late=True)])
    s = bandwidth.summary(rows)["s"]
    assert s["best"]["gain"] == 1.0 and s["best"]["bytes_ratio"] == 0.5
    assert s["failing_below"] == [0.1]
    assert s["late"][0.0]["mota_ratio"] == pytest.approx(0.96)
    text = bandwidth.markdown(rows, bandwidth.summary(rows), {
        "topology": "ring", "config": "dkf+lda+dtm", "seed": 0, "frames": 10})
    assert "1 (but gain(s) 0.1 below it are not), bytes 0.500 of sync (meets" in text
    assert "Late, gain 0: ground MOTA 0.960 of sync (meets >= 0.95)" in text
    none = bandwidth.summary(bandwidth.with_ratios([row("sync", None, 1.0, 100.0),
                                                    row("async", 0.0, 0.5, 90.0)]))["s"]
    assert none["best"] is None


def test_plan_order():
    tasks = bandwidth.plan(["a", "b"], [0.0, 1.0], [0.0])
    assert [(t.scenario, t.mode, t.gain, t.late) for t in tasks] == [
        ("a", "sync", None, False), ("a", "async", 0.0, False), ("a", "async", 1.0, False),
        ("a", "async", 0.0, True),
        ("b", "sync", None, False), ("b", "async", 0.0, False), ("b", "async", 1.0, False),
        ("b", "async", 0.0, True)]
    assert [t.index for t in tasks] == list(range(8))


def test_bad_gains_are_one_line_errors(capsys, tmp_path):
    assert bandwidth.parse_gains("1,0,0.1,1") == [0.0, 0.1, 1.0]
    assert bandwidth.parse_gains("none", "--late", allow_empty=True) == []
    for bad in (["--gains", "0,-1"], ["--gains", "x"], ["--gains", ""], ["--late", "nan"],
                ["--topology", "rnig"], ["--topology", "centralized"], ["--scenarios", "nope"]):
        assert cli.main(["bandwidth-sweep", "--scenarios", "lab-sim", *bad, "--out",
                         str(tmp_path), "--quiet"]) == 2
        err = capsys.readouterr().err
        assert err.startswith("sim_cluster: error: ") and len(err.strip().splitlines()) == 1
    assert not any(tmp_path.iterdir())  # nothing written
