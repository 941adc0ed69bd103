"""``NodeStats``: what a node counts over its life (births, merges, drops, refused input by
reason). The roles that count are given the node's one object; nothing here decides anything."""
from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field


@dataclass
class NodeStats:
    births: int = 0
    reidentified: int = 0
    adopted: int = 0
    reactivated: int = 0
    merged: int = 0
    stitched: int = 0  # dropped trackers whose id a younger tracker took (manager.heir: heir_pending or stitch)
    reappeared: int = 0  # new trackers that took a dropped one's id by its course (reappear.py)
    dropped: int = 0
    out_of_scope: int = 0  # trackers let go because the target is beyond scope_hops (regional scope)
    ignored_messages: int = 0  # other network, not a neighbour, future or too old a frame
    duplicate_messages: int = 0  # a sender's frame already taken
    bad_detections: int = 0  # boxes with NaN, inf or a non-positive size: not measured
    numerical: int = 0  # tracker corrections that failed numerically (kept the prediction)
    rejected: dict[str, int] = field(default_factory=dict)  # neighbours' entries, by reason
    trust: dict[int, dict] = field(default_factory=dict)  # per neighbour: trust.NeighbourTrust.summary

    def add(self, other: "NodeStats") -> "NodeStats":
        """The sum of two lives of a node (before and after a restart)."""
        out = NodeStats(**{f: getattr(self, f) + getattr(other, f)
                           for f in vars(self) if f not in ("rejected", "trust")})
        out.rejected = dict(Counter(self.rejected) + Counter(other.rejected))
        out.trust = dict(other.trust or self.trust)  # the later life's judgement
        return out
