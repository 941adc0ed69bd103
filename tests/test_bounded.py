"""A node runs for months: every table it keeps stays within its bound however many targets come
and go (issue 14). Small bounds, a stream of thousands of frames in which every bound is passed
many times over, and the tables checked after every frame of every node."""
from __future__ import annotations

import numpy as np
import pytest

from edge_node.core.config import TrackerConfig
from edge_node.core.node import CameraNode
from sim_cluster.network.inprocess import run_network
from sim_cluster.network.topology import build
from sim_cluster.scenarios.loader import open_scenario

FRAMES = 3000
OLD = 1  # max_old_trackers: the re-id store, and 10x that for ids, aliases and claims
OLD_MIB = 0.012  # 12 float16 descriptors of 512-d (a full gallery holds 20: over the budget)


def _check(node: CameraNode, cfg: TrackerConfig, seen: dict) -> None:
    book, screen = node.book, node.screen
    limit = 10 * cfg.max_old_trackers
    assert len(book.old) <= cfg.max_old_trackers
    assert book.old.nbytes <= cfg.max_old_mib * 2**20
    assert book.old.nbytes == sum(book.old[t].nbytes for t in book.old)
    assert all(book.old[t].matrix().dtype == np.float16 for t in book.old)
    assert set(book.last) <= set(book.old)  # where a tracker was dropped goes with its gallery
    assert len(book.aliases) <= limit
    keep = set(node.trackers) | set(book.old) | set(book.aliases) | set(book.aliases.values())
    assert len(book.born) <= max(2 * limit, len(keep))
    assert len(book._announce) <= limit * cfg.merge_announce_frames
    assert len(screen.claimed) <= limit and len(screen.relayed) <= limit
    window = cfg.kappa + cfg.merge_announce_frames
    for sender, heard in screen.heard.items():
        assert all(node.frame - f <= window + 1 for f in heard.values())
    assert len(node.inbound.taken) <= len(node.neighbours) * (cfg.kappa + 1)
    n = len(node.trackers)
    ev = node.manager.evidence  # co-motion evidence: pairs of trackers held, never more
    assert len(ev) <= n * (n - 1) // 2
    assert all(a in node.trackers and b in node.trackers for a, b in ev)
    assert ev.holders() <= set(node.trackers)  # the table's slots: trackers held, never more
    seen["ids"].update(node.trackers)
    seen["max_born"] = max(seen["max_born"], len(book.born))
    seen["max_store"] = max(seen["max_store"], book.old.nbytes)


@pytest.mark.slow  # 3000 frames, every table checked after every frame
def test_every_table_of_a_node_stays_bounded_while_ids_churn():
    data = open_scenario("terrace-sim", frames=FRAMES).first_cameras(2)
    cfg = TrackerConfig(max_old_trackers=OLD, max_old_mib=OLD_MIB)
    seen = {"ids": set(), "max_born": 0, "max_store": 0}

    def probe(k, i, cpu, node):
        _check(node, node.cfg, seen)

    result = run_network(data, build("chain", 2), cfg, on_frame=lambda k, now: None, probe=probe)
    limit = 10 * OLD
    assert len(seen["ids"]) > 3 * limit  # the ids churned through every bound several times
    assert seen["max_born"] > 2 * limit  # the birth table reached its bound and was pruned
    assert all(s.dropped > 10 * OLD for s in result.stats.values())
    assert seen["max_store"] > 0.5 * OLD_MIB * 2**20  # the store was used up to its budget
