"""``sim_cluster fault-report``: every standard case runs, nothing crashes, ratios add up."""
import pytest

# every standard fault case over a 4-node network, each beside its fault-free run
pytestmark = pytest.mark.slow

from sim_cluster.experiments.faultreport import run_report, standard_cases, table
from sim_cluster.scenarios.loader import load_scenario


@pytest.fixture(scope="module")
def report():
    return run_report(load_scenario("lab-sim", seed=0, frames=160))


def test_every_case_runs_without_crashes(report):
    names = [c.name for c in standard_cases(160)]
    assert [r["case"] for r in report["cases"]] == names
    assert all(r["crashes"] == 0 and "got" in r for r in report["cases"])


def test_ratios_and_recovery_are_consistent(report):
    for r in report["cases"]:
        for m in ("mota", "idf1"):
            assert r["ratio"][m] == pytest.approx(r["got"][m] / r["fault_free"][m])
        if r["case"] in ("kill and restart", "partition {0,1} / {2,3}"):
            assert r["frames_to_recover"] is not None and r["frames_to_recover"] >= 0
        else:
            assert r["frames_to_recover"] is None
    # the faults cost something but the network keeps tracking
    assert all(r["ratio"]["mota"] > 0.8 for r in report["cases"] if "faulty" not in r["case"])
    # the lies the trust role defends against (edge_node/core/trust.py: a hijack is quarantined,
    # forged merges of people apart refused): the honest nodes track on; the faulty node is
    # not scored, every kind
    for kind in ("hijack", "forged_merge"):
        (r,) = [r for r in report["cases"] if r["case"] == f"faulty node 0: {kind}"]
        assert r["ratio"]["mota"] > 0.8, r
    assert all(r["survivors"] == [1, 2, 3] for r in report["cases"] if "faulty" in r["case"])


def test_table_lists_every_case(report):
    text = table(report)
    for r in report["cases"]:
        assert r["case"] in text
