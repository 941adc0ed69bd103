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

import tomllib
from dataclasses import dataclass
from pathlib import Path

import numpy as np


class FaultPlanError(ValueError):
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
        known = {"seed", "link", "partition", "node"}
        unknown = sorted(set(d) - known)
        if unknown:
            raise FaultPlanError(f"{where}: unknown section(s) {', '.join(unknown)}")
        links: list[LinkFault] = []
        for i, t in enumerate(d.get("link", [])):
            links.append(_link(t, f"{where}: link[{i}]"))
        for i, t in enumerate(d.get("partition", [])):
            links.extend(_partition(t, f"{where}: partition[{i}]"))
        nodes = []
        for i, t in enumerate(d.get("node", [])):
            w = f"{where}: node[{i}]"
            _only(t, {"node", "kill", "restart"}, w)
            node, kill = _int(t, "node", w), _int(t, "kill", w)
            restart = t.get("restart")
            if restart is not None and (_int(t, "restart", w) <= kill):
                raise FaultPlanError(f"{w}.restart must be after kill ({kill}), got {restart}")
            nodes.append(NodeFault(node, kill, restart))
        seed = d.get("seed", 0)
        if not isinstance(seed, int) or isinstance(seed, bool) or seed < 0:
            raise FaultPlanError(f"{where}: seed must be an integer >= 0, got {seed!r}")
        return cls(tuple(links), tuple(nodes), seed)

    @classmethod
    def load(cls, path: str | Path) -> "FaultPlan":
        path = Path(path)
        try:
            d = tomllib.loads(path.read_text())
        except OSError as e:
            raise FaultPlanError(f"{path}: cannot read ({e.strerror})") from None
        except tomllib.TOMLDecodeError as e:
            raise FaultPlanError(f"{path}: not valid TOML ({e})") from None
        return cls.from_dict(d, where=str(path))


def _only(t: dict, keys: set[str], where: str) -> None:
    if not isinstance(t, dict):
        raise FaultPlanError(f"{where} must be a table")
    unknown = sorted(set(t) - keys)
    if unknown:
        raise FaultPlanError(f"{where}: unknown field(s) {', '.join(unknown)}")


def _int(t: dict, key: str, where: str, default: int | None = None) -> int:
    v = t.get(key, default)
    if not isinstance(v, int) or isinstance(v, bool) or v < 0:
        raise FaultPlanError(f"{where}.{key} must be an integer >= 0, got {v!r}")
    return v


def _prob(t: dict, key: str, where: str) -> float:
    v = t.get(key, 0.0)
    if not isinstance(v, (int, float)) or isinstance(v, bool) or not 0.0 <= v <= 1.0:
        raise FaultPlanError(f"{where}.{key} must be a probability in [0, 1], got {v!r}")
    return float(v)


def _link(t: dict, where: str) -> LinkFault:
    _only(t, {"src", "dst", "start", "stop", "loss", "delay", "jitter", "duplicate"}, where)
    src = _int(t, "src", where) if "src" in t else None
    dst = _int(t, "dst", where) if "dst" in t else None
    start = _int(t, "start", where, 0)
    stop = _int(t, "stop", where) if "stop" in t else None
    if stop is not None and stop <= start:
        raise FaultPlanError(f"{where}.stop must be after start ({start}), got {stop}")
    return LinkFault(src, dst, start, stop, _prob(t, "loss", where), _int(t, "delay", where, 0),
                     _int(t, "jitter", where, 0), _prob(t, "duplicate", where))


def _partition(t: dict, where: str) -> list[LinkFault]:
    _only(t, {"between", "groups", "start", "stop"}, where)
    start = _int(t, "start", where, 0)
    stop = _int(t, "stop", where) if "stop" in t else None
    pairs: list[tuple[int, int]] = []
    if "between" in t:
        for p in t["between"]:
            if not (isinstance(p, list) and len(p) == 2 and all(isinstance(v, int) for v in p)):
                raise FaultPlanError(f"{where}.between must be a list of node pairs, got {p!r}")
            pairs.append((p[0], p[1]))
    if "groups" in t:
        groups = t["groups"]
        if not (isinstance(groups, list) and all(isinstance(g, list) for g in groups)):
            raise FaultPlanError(f"{where}.groups must be a list of node lists")
        for i, a in enumerate(groups):
            for b in groups[i + 1:]:
                pairs.extend((x, y) for x in a for y in b)
    if not pairs:
        raise FaultPlanError(f"{where} needs 'between' or 'groups'")
    out = []
    for a, b in pairs:
        out.append(LinkFault(a, b, start, stop, cut=True))
        out.append(LinkFault(b, a, start, stop, cut=True))
    return out


NO_FAULTS = FaultPlan()
