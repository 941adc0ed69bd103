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
    [[faulty]]          # a node that runs but lies or sees wrong (edge_node/forgery.py)
    node = 0
    kind = "hijack"     # hijack | phantom | bumped | hallucinate | stale | forged_merge
    start = 100         # frames [start, stop)
    stop = 300
    seed = 3            # optional: the plan's seed otherwise
    offset = 4.0        # hijack: metres the states are moved (4); bumped: the pose jumps (2)
    rotation = 5.0      # bumped: degrees the camera turns
    count = 3           # phantom, hallucinate: invented people at once
    lag = 25            # stale: frames old the message re-sent as new is

Rules (each a :class:`FaultPlanError` naming the file and the field): node ids are non-negative
integers; a ``[[link]]`` joins two different nodes; ``between`` pairs two different nodes;
``groups`` are at least two non-empty, disjoint node lists; ``kill >= 1`` (a node runs its first
frame in both shells) and ``restart > kill``; a node's kill windows do not overlap. Checked
against the network the plan drives (``load`` / ``from_dict`` with a :class:`Network`): every
node named exists, a ``[[link]]`` with ``src`` and ``dst`` and every ``between`` pair is a link
of the topology, and ``start``, ``kill`` and ``restart`` fall inside the run. A camera process
knows only its own links (:meth:`Network.of_node`) and checks those.
"""
from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from edge_node.settings import SettingsError, Table, read_toml


class FaultPlanError(SettingsError):
    """A fault file that cannot be used; the message names the file and the field."""


@dataclass(frozen=True)
class Network:
    """What a plan is checked against: the topology it drives (``{node: neighbours}``) and the
    run's frame count (``None``: unknown). ``partial``: only the listed nodes' links are known
    (a camera process knows itself and its neighbours), so other node ids are not judged."""

    adjacency: Mapping[int, Iterable[int]]
    frames: int | None = None
    partial: bool = False

    @classmethod
    def of_node(cls, node: int, neighbours: Iterable[int]) -> "Network":
        """What one camera process knows: its id and its neighbours."""
        return cls({node: tuple(neighbours)}, partial=True)

    def node_problem(self, v: int) -> str | None:
        """Why node ``v`` cannot be named (``None`` when it can)."""
        if self.partial or v in self.adjacency:
            return None
        return (f"names node {v}, but the network has {len(self.adjacency)} nodes "
                f"({', '.join(map(str, sorted(self.adjacency)))})")

    def link_problem(self, a: int, b: int) -> str | None:
        """Why ``a`` and ``b`` are not a link (``None`` when they are, or it is not known)."""
        for x, y in ((a, b), (b, a)):
            if x in self.adjacency:
                if y in self.adjacency[x]:
                    return None
                near = ", ".join(map(str, sorted(self.adjacency[x]))) or "none"
                return (f"names {a} -> {b}, which is not a link of the network (node {x}'s "
                        f"neighbours: {near})")
        return None

    def frame_problem(self, k: int) -> str | None:
        if self.frames is None or k < self.frames:
            return None
        return f"is {k}, after the run's last frame ({self.frames - 1})"


ANY_NETWORK = Network({}, partial=True)  # checks nothing that depends on the network


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


#: faulty-node kinds: what a node that runs but lies (or sees wrong) does (edge_node/forgery.py)
FAULTY_KINDS = ("hijack", "phantom", "bumped", "hallucinate", "stale", "forged_merge")
#: the kinds that change what the node's camera detects; the others change what it sends
DETECTION_KINDS = ("bumped", "hallucinate")


@dataclass(frozen=True)
class FaultyNode:
    """A node that runs but is faulty over frames ``[start, stop)`` (the fault model of
    docs/deploy.md: any values the schema allows): ``hijack`` moves the states of the trackers
    it sends ``offset`` metres and claims a sharp measurement there; ``phantom`` adds ``count``
    invented people walking plausible paths; ``stale`` re-sends the message of ``lag`` frames
    ago as this frame's; ``forged_merge`` announces merges of the trackers it sends into one
    another; ``bumped`` moves its camera's true pose ``offset`` metres and ``rotation`` degrees
    (not malicious: its detections land elsewhere); ``hallucinate`` makes its detector see
    ``count`` people who are not there."""

    node: int
    kind: str
    start: int = 0
    stop: int | None = None
    seed: int = 0
    offset: float = 4.0
    rotation: float = 5.0
    count: int = 3
    lag: int = 25

    def active(self, k: int) -> bool:
        return k >= self.start and (self.stop is None or k < self.stop)


@dataclass(frozen=True)
class FaultPlan:
    links: tuple[LinkFault, ...] = ()
    nodes: tuple[NodeFault, ...] = ()
    seed: int = 0
    faulty: tuple[FaultyNode, ...] = ()

    def faults_of(self, node: int) -> tuple[FaultyNode, ...]:
        """The faulty-node rules of ``node``."""
        return tuple(f for f in self.faulty if f.node == node)

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
        return not self.links and not self.nodes and not self.faulty

    # -- loading -------------------------------------------------------------------------------
    @classmethod
    def from_dict(cls, d: dict, where: str = "faults",
                  network: Network = ANY_NETWORK) -> "FaultPlan":
        """A plan from its (TOML) tables, checked against ``network`` (module docstring);
        ``where`` names it in errors (the file)."""
        top = Table(d, where, error=FaultPlanError)
        seed = top.integer("seed", 0, lo=0)
        links: list[LinkFault] = [_link(t, network) for t in top.tables("link", required=False)]
        for t in top.tables("partition", required=False):
            links.extend(_partition(t, network))
        nodes = _nodes(top.tables("node", required=False), network)
        faulty = tuple(_faulty(t, network, seed) for t in top.tables("faulty", required=False))
        top.finish()
        return cls(tuple(links), tuple(nodes), seed, faulty)

    @classmethod
    def load(cls, path: str | Path, network: Network = ANY_NETWORK) -> "FaultPlan":
        """The plan in the TOML file ``path``, checked against ``network``."""
        path = Path(path)
        return cls.from_dict(read_toml(path, FaultPlanError, file=str(path), what="fault plan"),
                             where=str(path), network=network)


def _check(t: Table, key: str, problem: str | None) -> None:
    if problem is not None:
        raise t.error(key, problem)


def _node_id(t: Table, key: str, v, net: Network) -> int:
    """``v`` (read from ``key``) as a node id of ``net``."""
    if isinstance(v, bool) or not isinstance(v, int) or v < 0:
        raise t.error(key, f"must hold node ids (non-negative integers), got {v!r}")
    _check(t, key, net.node_problem(v))
    return v


def _frames(t: Table, net: Network) -> tuple[int, int | None]:
    """``start`` and ``stop`` of a rule: frames ``[start, stop)``."""
    start = t.integer("start", 0, lo=0)
    stop = t.integer("stop", None, lo=0)
    if stop is not None and stop <= start:
        raise t.error("stop", f"must be after start ({start}), got {stop}")
    _check(t, "start", net.frame_problem(start))
    return start, stop


def _link(t: Table, net: Network) -> LinkFault:
    src = t.integer("src", None, lo=0)
    dst = t.integer("dst", None, lo=0)
    for key, v in (("src", src), ("dst", dst)):
        if v is not None:
            _check(t, key, net.node_problem(v))
    if src is not None and dst is not None:
        if src == dst:
            raise t.error("dst", f"is src ({src}): a link joins two different nodes")
        _check(t, "dst", net.link_problem(src, dst))
    start, stop = _frames(t, net)
    fault = LinkFault(src, dst, start, stop, t.probability("loss", 0.0),
                      t.integer("delay", 0, lo=0), t.integer("jitter", 0, lo=0),
                      t.probability("duplicate", 0.0))
    t.finish()
    return fault


def _partition(t: Table, net: Network) -> list[LinkFault]:
    start, stop = _frames(t, net)
    pairs: list[tuple[int, int]] = []
    for i, p in enumerate(t.list("between", [])):
        key = f"between[{i}]"
        if not (isinstance(p, list) and len(p) == 2):
            raise t.error(key, f"must be a pair of node ids [a, b], got {p!r}")
        a, b = (_node_id(t, key, v, net) for v in p)
        if a == b:
            raise t.error(key, f"pairs node {a} with itself")
        _check(t, key, net.link_problem(a, b))
        pairs.append((a, b))
    groups = t.list("groups", [])
    if groups and len(groups) < 2:
        raise t.error("groups", f"must hold at least two node lists, got {groups!r}")
    seen: dict[int, int] = {}  # node -> its group
    for i, g in enumerate(groups):
        key = f"groups[{i}]"
        if not isinstance(g, list) or not g:
            raise t.error(key, f"must be a non-empty list of node ids, got {g!r}")
        for v in g:
            v = _node_id(t, key, v, net)
            if v in seen:
                raise t.error(key, f"repeats node {v} of groups[{seen[v]}]: groups are disjoint")
            seen[v] = i
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


def _nodes(tables: list[Table], net: Network) -> list[NodeFault]:
    """The ``[[node]]`` tables; one node's kill windows must not overlap."""
    out: list[tuple[Table, NodeFault]] = []
    for t in tables:
        node = t.integer("node", lo=0)
        _check(t, "node", net.node_problem(node))
        kill = t.integer("kill", lo=1)
        _check(t, "kill", net.frame_problem(kill))
        restart = t.integer("restart", None, lo=0)
        if restart is not None and restart <= kill:
            raise t.error("restart", f"must be after kill ({kill}), got {restart}")
        if restart is not None:
            _check(t, "restart", net.frame_problem(restart))
        t.finish()
        out.append((t, NodeFault(node, kill, restart)))
    for t, f in out:
        for u, g in out:
            if g is not f and g.node == f.node and g.kill <= f.kill and (
                    g.restart is None or g.restart > f.kill):
                back = "never" if g.restart is None else g.restart
                raise t.error("kill", f"is {f.kill}, while node {f.node} is dead ({u.where}: "
                              f"kill {g.kill}, restart {back})")
    return [f for _, f in out]


def _faulty(t: Table, net: Network, seed: int) -> FaultyNode:
    node = t.integer("node", lo=0)
    _check(t, "node", net.node_problem(node))
    kind = t.string("kind", choices=FAULTY_KINDS)
    start, stop = _frames(t, net)
    d = FaultyNode(node, kind)
    f = FaultyNode(node, kind, start, stop, t.integer("seed", seed, lo=0),
                   t.number("offset", 2.0 if kind == "bumped" else d.offset, lo=0), t.number("rotation", d.rotation),
                   t.integer("count", d.count, lo=1, hi=64), t.integer("lag", d.lag, lo=1, hi=1000))
    t.finish()
    return f


NO_FAULTS = FaultPlan()
