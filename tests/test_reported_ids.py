"""What id a person is reported under while the network decides whether two trackers are one
(issue: no retroactive id switches). Figures come from the configuration alone."""
import numpy as np

from edge_node.core import Detection, TrackerConfig
from fakes import det, make_nodes, step


def walk(k):
    """One person shuffling along x at 5 cm/s (metres): slow enough that the older tracker,
    coasting where it was last seen, stays within the co-motion gate of the younger."""
    return 2.0 + 0.002 * k, 2.0


def _run(alias: bool, frames: int = 60, hidden_from: int = 5):
    """Two cameras start their own tracker of one person in frame 1, 0.7 m apart (camera 1's
    calibration is off): too far to merge at once, so the pair gathers co-motion evidence.
    From ``hidden_from`` on camera 0 no longer sees the person: the older tracker, (0, 0),
    coasts unreported while the younger, camera 1's (1, 0), goes on being measured."""
    cfg = TrackerConfig(registration=False, pending_alias=alias)
    nodes = make_nodes({0: (1,), 1: (0,)}, cfg, offsets={1: (0.7, 0.0)})
    rng = np.random.default_rng(5)
    reported, held = [], []
    for k in range(frames):
        d = [Detection(det(*walk(k), pid=0, rng=rng).box, None)]
        out = step(nodes, k, {0: d if k < hidden_from else [], 1: d})
        reported.append({n: [t.id for t in out[n]] for n in out})
        held.append({n: sorted(nodes[n].trackers.ids()) for n in nodes})
    return cfg, reported, held


def test_a_duplicate_is_reported_under_the_older_id_while_the_older_is_unseen():
    """Without the alias every node shows the person as (0, 0), then as (1, 0) while (0, 0)
    coasts unreported, then as (0, 0) again once (0, 0) is dropped and its id goes to the
    tracker that was merging into it (``heir_pending``): two switches, one of them back. With
    ``pending_alias`` the younger is reported under the older id while it agrees with it
    towards a merge and the older is not reported: one id throughout."""
    cfg, plain, held = _run(alias=False)
    _, aliased, held_a = _run(alias=True)
    assert held == held_a  # reporting only: what the nodes hold is the same
    # the older tracker is dropped kappa frames after the last frame a camera saw it
    drop = next(k for k, h in enumerate(held) if k > 1 and len(h[0]) == 1)
    assert drop == 5 + cfg.kappa  # last seen in frame 4: ell 1..16 over frames 5..20
    assert held[drop][0] == [(0, 0)]  # the younger took the dropped id (heir_pending)
    for n in (0, 1):
        ids_plain = [r[n] for r in plain[2:]]
        ids_alias = [r[n] for r in aliased[2:]]
        assert all(len(i) == 1 for i in ids_plain + ids_alias)  # one person, one track
        seq = [i[0] for i in ids_plain]
        changes = [k for k in range(1, len(seq)) if seq[k] != seq[k - 1]]
        assert len(changes) == 2 and seq[0] == seq[-1] == (0, 0)  # there and back
        assert {i[0] for i in ids_alias} == {(0, 0)}  # one id throughout
