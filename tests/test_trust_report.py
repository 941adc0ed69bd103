"""``sim_cluster trust-report``'s figures (sim_cluster/experiments/trust.py), by hand."""
from types import SimpleNamespace

import numpy as np
import pytest

from sim_cluster.experiments.trust import settled_mota, summarise

FRAMES = 10


def one_person(fps: float = 1.0):
    """One person standing at the origin for ``FRAMES`` frames (1 frame a second: the 2 s a
    settled figure waits are 2 frames)."""
    truth = SimpleNamespace(ids=[np.array([1])] * FRAMES, xy=[np.array([[0.0, 0.0]])] * FRAMES,
                            wh=[np.array([[0.5, 1.7]])] * FRAMES, boxes=[])
    return SimpleNamespace(truth=truth, units_per_metre=1.0, num_cameras=2, frames=FRAMES,
                           fps=fps)


ON = ((0, 0), np.array([0.1, 0.0, 0.5, 1.7, 0.0, 0.0]))  # on the person
FAR = ((0, 9), np.array([30.0, 0.0, 0.5, 1.7, 0.0, 0.0]))  # nobody there


def test_settled_mota_counts_only_the_frames_two_seconds_after_each_change():
    """Fault from frame 3 to 6: frames 3-4 and 6-7 are the settling ones and do not count;
    5, 8 and 9 do. Node 0 misses the person at 3 and 4 (not counted) and at 8 (counted), and
    reports a far track at 7 (not counted) and at 9 (counted): 3 objects, 1 miss, 1 false
    positive, MOTA 1/3. Node 1 tracks the person throughout: 1. The median of the two: 2/3."""
    node0 = [[ON], [ON], [ON], [], [], [ON], [ON], [ON, FAR], [], [ON, FAR]]
    node1 = [[ON]] * FRAMES
    result = SimpleNamespace(tracks={0: node0, 1: node1})
    assert settled_mota(result, one_person(), [0, 1], 3, 6) == pytest.approx(2 / 3)
    assert settled_mota(result, one_person(), [0], 3, 6) == pytest.approx(1 / 3)
    # at 0.5 frames a second the 2 s are one frame: frames 4 and 7 count as well (node 0
    # misses at 4, and 7 holds a false positive): 5 objects, 2 misses, 2 false positives
    assert settled_mota(result, one_person(fps=0.5), [0], 3, 6) == pytest.approx(1 / 5)


def test_summary_takes_each_seeds_settled_ratio_against_its_fault_free_run():
    def row(seed, kind, settled, mota=0.9):
        return {"scenario": "s", "seed": seed, "kind": kind, "mode": "sync", "late": False,
                "trust": True, "ground": {"mota": mota, "idf1": mota}, "settled_mota": settled,
                "far": 0, "quarantine_frames": {"1": None}, "kept_ids": 1.0,
                "honest_quarantined": 0}
    rows = [row(0, "none", 0.8), row(1, "none", 0.5), row(2, "none", 1.0),
            row(0, "bumped", 0.4), row(1, "bumped", 0.5), row(2, "bumped", 0.9)]
    bumped = next(s for s in summarise(rows) if s["kind"] == "bumped")
    assert bumped["settled_ratio"] == pytest.approx(0.9)  # median of 0.5, 1.0 and 0.9


def test_tracker_config_reaches_every_cell_and_a_bad_file_is_one_typed_error(tmp_path):
    """``trust-report --tracker-config``: every planned run carries the file, and a file with an
    unknown parameter fails once, before any run, naming the file and the parameter."""
    from sim_cluster.experiments.trust import main, plan_cells
    cells = plan_cells(["terrace-sim"], [0, 1], ["hallucinate"], "dkf+lda+dtm", True, "t.toml")
    assert len(cells) == 2 * 4 and {c["tracker_file"] for c in cells} == {"t.toml"}
    bad = tmp_path / "bad.toml"
    bad.write_text("[tracker]\nreport_unsen = 10\n")
    args = SimpleNamespace(kinds="hallucinate", seeds="0", scenarios="terrace-sim",
                           config="dkf+lda+dtm", baseline=False, tracker_config=str(bad),
                           jobs=1, quiet=True, out=str(tmp_path / "out"))
    from protocol.errors import DmttError
    with pytest.raises(DmttError) as err:
        main(args)
    assert "bad.toml" in str(err.value) and "report_unsen" in str(err.value)
    assert not (tmp_path / "out").exists()


def test_baseline_from_a_report_of_other_tracker_parameters_is_refused(tmp_path):
    """``--baseline-from``: trust-off runs made with other tracker parameters (or another
    ``--config``) are not this report's; a typed error before any run, naming the file."""
    import json
    from protocol.errors import DmttError
    from sim_cluster.experiments.trust import main
    f = tmp_path / "t.toml"
    f.write_text("[tracker.reporter]\nreport_unseen = 10\n")
    old = tmp_path / "old.json"
    old.write_text(json.dumps({"meta": {"config": "dkf+lda+dtm", "tracker_config": None},
                               "rows": []}))
    args = SimpleNamespace(kinds="hallucinate", seeds="0", scenarios="terrace-sim",
                           config="dkf+lda+dtm", baseline=True, baseline_from=str(old),
                           tracker_config=str(f), jobs=1, quiet=True, out=str(tmp_path / "out"))
    with pytest.raises(DmttError) as err:
        main(args)
    assert "old.json" in str(err.value)
    args.tracker_config, args.config = None, "dkf+dtm"
    with pytest.raises(DmttError):
        main(args)
    assert not (tmp_path / "out").exists()
