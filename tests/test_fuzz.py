"""The semantic fuzz test of issue 13 through the real Zenoh subscribers of two running nodes
(``sim_cluster/experiments/fuzz.py``): 10,000 wire-valid hostile messages."""
import pytest

from sim_cluster.experiments import fuzz


@pytest.mark.integration
def test_ten_thousand_hostile_messages_crash_nothing_and_change_no_honest_track(tmp_path):
    # unpaced, with a sync timeout long enough that a victim starved of CPU (a busy machine)
    # never times out waiting for its neighbour: the attack run's tracks must equal the
    # reference run's, which holds only when no frame was fused without a neighbour's message
    rep = fuzz.run(10_000, tmp_path, fps=0.0, sync_timeout_s=60.0)
    assert rep.messages >= 10_000
    assert rep.exit_codes == {"reference": [0, 0], "attack": [0, 0]}
    # every hostile entry and merge node 1's tracker took was dropped and counted
    assert rep.used >= 0.9 * rep.frames
    assert rep.semantic_rejections == rep.expected_rejections == rep.used * 6
    # every kind was sent, and every reason the kinds map to was counted
    assert set(rep.kinds) == set(fuzz.ENTRY_KINDS) | set(fuzz.MERGE_KINDS)
    for reason in ("implausible_information", "implausible_state",
                   "implausible_ell", "future_birth", "born_moved", "implausible_birth"):
        assert rep.rejected.get(reason, 0) > 0, reason
    # the transport's own refusals: not a neighbour of node 0, replays, copies
    assert rep.rejected["unknown_sender"] == rep.to_node0 > 0  # each one counted
    assert all(rep.rejected.get(r, 0) > 0 for r in ("late", "duplicates"))
    # the honest nodes' tracks: byte for byte those of the run without the attacker
    assert rep.identical and rep.tracks_compared > 500
