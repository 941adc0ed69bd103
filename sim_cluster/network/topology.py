"""Communication graphs between cameras ``0..N-1`` (paper Sec. IV-B: complete, ring, chain,
disconnected; plus star and an explicit edge list).

A topology is an undirected adjacency ``{node: (neighbours...)}``. Ring and chain take an optional
``order`` (a permutation of the nodes), as the paper's Fig. 4 averages several orderings.

The named graphs are :class:`Topology` kinds in the registry :data:`TOPOLOGIES` (``edge_node/plugins.py``):
adding one is one ``TOPOLOGIES.add(name, Topology(...))`` here, or an entry point in the group
``dmtt.topologies`` of another package; every command's ``--topology`` choices and help come
from it (:func:`help_text`).
"""
from __future__ import annotations

import itertools
import re
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from typing import NamedTuple

from edge_node.formats.text import read_text
from edge_node.plugins import Registry
from protocol.errors import DmttError

Adjacency = dict[int, tuple[int, ...]]


class TopologyError(DmttError, ValueError):
    """An unknown topology name or an edge list that does not describe a graph on ``0..N-1``."""


class Topology(NamedTuple):
    """A named graph: ``edges(n, order)`` the undirected edges on nodes ``0..n-1`` with the
    cameras in ``order`` (a permutation); ``ordered``: experiments average it over several
    camera orderings, as the paper's Fig. 4 does for ring and chain (``orderings``);
    ``summary`` one line for the help."""

    edges: Callable[[int, list[int]], Iterable[tuple[int, int]]]
    ordered: bool
    summary: str


#: The named topologies (``--topology``), the paper's four first.
TOPOLOGIES: Registry[Topology] = Registry("topology", "dmtt.topologies", TopologyError)
TOPOLOGIES.add("complete", Topology(lambda n, o: itertools.combinations(range(n), 2), False,
                                    "every camera linked to every other"))
TOPOLOGIES.add("ring", Topology(lambda n, o: zip(o, o[1:] + o[:1]) if n > 2 else zip(o, o[1:]),
                                True, "each camera linked to the next, the last to the first"))
TOPOLOGIES.add("chain", Topology(lambda n, o: zip(o, o[1:]), True,
                                 "each camera linked to the next"))
TOPOLOGIES.add("disconnected", Topology(lambda n, o: (), False, "no links: lone cameras"))
TOPOLOGIES.add("star", Topology(lambda n, o: ((o[0], x) for x in o[1:]), False,
                                "the first camera linked to every other"))
NAMES = TOPOLOGIES.builtin()  # the names this package ships


def help_text(*extra: str) -> str:
    """``--topology`` help: every registered name, then ``extra`` forms, then an edge list."""
    return " | ".join((*TOPOLOGIES.names(), *extra, "edge-list file"))


def _from_edges(n: int, edges) -> Adjacency:
    adj: dict[int, set[int]] = {i: set() for i in range(n)}
    for a, b in edges:
        if a == b:
            continue
        adj[a].add(b)
        adj[b].add(a)
    return {i: tuple(sorted(v)) for i, v in adj.items()}


def build(name: str, n: int, order: Sequence[int] | None = None) -> Adjacency:
    """The graph ``name`` on ``n`` nodes (``name`` may also be a path to an edge-list file)."""
    if n < 1:
        raise TopologyError(f"a network needs at least one node, got {n}")
    order = list(range(n)) if order is None else list(order)
    if sorted(order) != list(range(n)):
        raise TopologyError(f"order {order} is not a permutation of 0..{n - 1}")
    if name in TOPOLOGIES:
        return _from_edges(n, TOPOLOGIES.get(name).edges(n, order))
    path = Path(name)
    if path.suffix or path.exists():
        return from_file(path, n)
    raise TopologyError(f"unknown topology {name!r}: use one of {', '.join(TOPOLOGIES.names())}, "
                        "'centralized', or a path to an edge-list file")


_EDGE_RE = re.compile(r"(-?\d+)\s*(?:-|,|\s)\s*(-?\d+)")


def from_file(path: Path, n: int) -> Adjacency:
    """An edge list: one edge per line as ``a b``, ``a-b`` or ``a,b``; ``#`` starts a comment.

    Each edge joins two different nodes of ``0..n-1`` and appears once (``a b`` and ``b a`` are
    the same edge); anything else, and bytes that are not UTF-8 (their byte offset too), is a
    :class:`TopologyError` naming the file and the line."""
    try:
        text = read_text(path, lambda e: TopologyError(str(e)))
    except OSError as e:
        raise TopologyError(f"{path}: cannot read edge list ({e.strerror})") from None
    edges: dict[tuple[int, int], int] = {}  # edge -> the line it was first given on
    for lineno, line in enumerate(text.splitlines(), 1):
        line = line.split("#", 1)[0].strip()
        if not line:
            continue
        m = _EDGE_RE.fullmatch(line)
        if m is None:
            raise TopologyError(f"{path}:{lineno}: expected two node ids, got {line!r}")
        a, b = int(m.group(1)), int(m.group(2))
        for v in (a, b):
            if not 0 <= v < n:
                raise TopologyError(f"{path}:{lineno}: node {v} is not in 0..{n - 1}")
        if a == b:
            raise TopologyError(f"{path}:{lineno}: edge {a}-{b} joins node {a} to itself")
        key = (min(a, b), max(a, b))
        if key in edges:
            raise TopologyError(f"{path}:{lineno}: edge {a}-{b} repeats line {edges[key]}")
        edges[key] = lineno
    return _from_edges(n, edges)


def orderings(name: str, n: int, count: int) -> list[list[int]]:
    """Up to ``count`` distinct orderings of an ordered topology (ring, chain: distinct graphs),
    deterministic."""
    if name not in TOPOLOGIES or not TOPOLOGIES.get(name).ordered:
        return [list(range(n))]
    seen, out = set(), []
    for perm in itertools.permutations(range(n)):
        g = tuple(sorted((min(a, b), max(a, b)) for a, lst in build(name, n, perm).items()
                         for b in lst))
        if g not in seen:
            seen.add(g)
            out.append(list(perm))
        if len(out) >= count:
            break
    return out


def lattice(rows: int, cols: int) -> Adjacency:
    """Cameras on a ``rows x cols`` lattice, numbered row by row (node ``r * cols + c``), each
    linked to its 4-neighbours: the neighbour graph of a generated layout (one row is a chain)."""
    if rows < 1 or cols < 1:
        raise TopologyError(f"a lattice needs rows, cols >= 1, got {rows} x {cols}")
    edges = [(r * cols + c, r * cols + c + 1) for r in range(rows) for c in range(cols - 1)]
    edges += [(r * cols + c, (r + 1) * cols + c) for r in range(rows - 1) for c in range(cols)]
    return _from_edges(rows * cols, edges)


def diameter(adj: Adjacency) -> int:
    """Longest shortest path (hops) between connected nodes; 0 for isolated nodes."""
    best = 0
    for s in adj:
        dist = {s: 0}
        frontier = [s]
        while frontier:
            nxt = []
            for u in frontier:
                for v in adj[u]:
                    if v not in dist:
                        dist[v] = dist[u] + 1
                        nxt.append(v)
            frontier = nxt
        best = max(best, max(dist.values()))
    return best


def links(adj: Adjacency) -> list[tuple[int, int]]:
    """Directed links ``(src, dst)``: one message per frame on each."""
    return [(a, b) for a in sorted(adj) for b in adj[a]]
