"""Fault injection shared by both shells (the in-process network and the process runtime).

A ``FaultPlan`` says, deterministically from a seed, what happens to each message on each link
in each frame (lost, delayed by some frames, duplicated, cut by a partition) and when nodes
crash and restart. Same plan + same seed = same faults, in one process or in many.

TOML form (``sim_cluster up --faults faults.toml``, ``sim_cluster run --faults``)::

    seed = 7
    [[link]]            # every field optional; src/dst omitted = every link
    src = 0
    dst = 1
    start = 100         # frames [start, stop)
    stop = 200
    loss = 0.1          # probability a message is lost
    delay = 2           # frames every message is late
    jitter = 2          # plus 0..jitter frames, uniformly (so messages reorder)
    duplicate = 0.05    # probability a message arrives twice
    [[partition]]       # links cut in both directions over a frame range
    between = [[0, 1]]  # node pairs; or groups = [[0, 1], [2, 3]]
    start = 300
    stop = 400
    [[node]]
    node = 2
    kill = 250          # the process dies before frame 250 ...
    restart = 300       # ... and a fresh one starts at frame 300 (omit: stays dead)
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from edge_node.settings import SettingsError, Table, read_toml


class FaultPlanError(SettingsError):
    """A fault file that cannot be used; the message names the file and the field."""


@dataclass(frozen=True)
class LinkFault:
    src: int | None = None
    dst: int | None = None
    start: int = 0
    stop: int | None = None
    loss: float = 0.0
    delay: int = 0
    jitter: int = 0
    duplicate: float = 0.0
    cut: bool = False

    def applies(self, src: int, dst: int, k: int) -> bool:
        return ((self.src is None or self.src == src) and (self.dst is None or self.dst == dst)
                and k >= self.start and (self.stop is None or k < self.stop))


@dataclass(frozen=True)
class NodeFault:
    node: int
    kill: int
    restart: int | None = None


@dataclass(frozen=True)
class FaultPlan:
    links: tuple[LinkFault, ...] = ()
    nodes: tuple[NodeFault, ...] = ()
    seed: int = 0

    def deliveries(self, src: int, dst: int, k: int) -> list[int]:
        """Delays (in frames) with which the frame-``k`` message on ``src -> dst`` arrives:
        ``[0]`` on time, ``[]`` lost, ``[2]`` two frames late, ``[0, 1]`` duplicated."""
        rules = [f for f in self.links if f.applies(src, dst, k)]
        if not rules:
            return [0]
        if any(f.cut for f in rules):
            return []
        rng = np.random.default_rng([self.seed, src, dst, k])
        loss = 1.0 - np.prod([1.0 - f.loss for f in rules])
        if rng.random() < loss:
            return []
        delay = sum(f.delay for f in rules)
        jitter = sum(f.jitter for f in rules)
        out = [delay + (int(rng.integers(0, jitter + 1)) if jitter else 0)]
        dup = 1.0 - np.prod([1.0 - f.duplicate for f in rules])
        if rng.random() < dup:
            out.append(delay + (int(rng.integers(0, jitter + 1)) if jitter else 0))
        return out

    def alive(self, node: int, k: int) -> bool:
        """Whether ``node`` runs at frame ``k``."""
        for f in self.nodes:
            if f.node == node and k >= f.kill and (f.restart is None or k < f.restart):
                return False
        return True

    def restarts_at(self, node: int, k: int) -> bool:
        return any(f.node == node and f.restart == k for f in self.nodes)

    @property
    def empty(self) -> bool:
        return not self.links and not self.nodes

    # -- loading -------------------------------------------------------------------------------
    @classmethod
    def from_dict(cls, d: dict, where: str = "faults") -> "FaultPlan":
        """A plan from its (TOML) tables; ``where`` names it in errors (the file)."""
        top = Table(d, where, error=FaultPlanError)
        seed = top.integer("seed", 0, lo=0)
        links: list[LinkFault] = [_link(t) for t in top.tables("link", required=False)]
        for t in top.tables("partition", required=False):
            links.extend(_partition(t))
        nodes = [_node(t) for t in top.tables("node", required=False)]
        top.finish()
        return cls(tuple(links), tuple(nodes), seed)

    @classmethod
    def load(cls, path: str | Path) -> "FaultPlan":
        path = Path(path)
        return cls.from_dict(read_toml(path, FaultPlanError, file=str(path), what="fault plan"),
                             where=str(path))


def _frames(t: Table) -> tuple[int, int | None]:
    """``start`` and ``stop`` of a rule: frames ``[start, stop)``."""
    start = t.integer("start", 0, lo=0)
    stop = t.integer("stop", None, lo=0)
    if stop is not None and stop <= start:
        raise t.error("stop", f"must be after start ({start}), got {stop}")
    return start, stop


def _link(t: Table) -> LinkFault:
    src = t.integer("src", None, lo=0)
    dst = t.integer("dst", None, lo=0)
    start, stop = _frames(t)
    fault = LinkFault(src, dst, start, stop, t.probability("loss", 0.0),
                      t.integer("delay", 0, lo=0), t.integer("jitter", 0, lo=0),
                      t.probability("duplicate", 0.0))
    t.finish()
    return fault


def _partition(t: Table) -> list[LinkFault]:
    start, stop = _frames(t)
    pairs: list[tuple[int, int]] = []
    for p in t.list("between", []):
        if not (isinstance(p, list) and len(p) == 2 and all(isinstance(v, int) for v in p)):
            raise t.error("between", f"must be a list of node pairs, got {p!r}")
        pairs.append((p[0], p[1]))
    groups = t.list("groups", [])
    if not all(isinstance(g, list) for g in groups):
        raise t.error("groups", "must be a list of node lists")
    for i, a in enumerate(groups):
        for b in groups[i + 1:]:
            pairs.extend((x, y) for x in a for y in b)
    t.finish()
    if not pairs:
        raise t.error(None, "needs 'between' or 'groups'")
    out = []
    for a, b in pairs:
        out.append(LinkFault(a, b, start, stop, cut=True))
        out.append(LinkFault(b, a, start, stop, cut=True))
    return out


def _node(t: Table) -> NodeFault:
    node, kill = t.integer("node", lo=0), t.integer("kill", lo=0)
    restart = t.integer("restart", None, lo=0)
    if restart is not None and restart <= kill:
        raise t.error("restart", f"must be after kill ({kill}), got {restart}")
    t.finish()
    return NodeFault(node, kill, restart)


NO_FAULTS = FaultPlan()
