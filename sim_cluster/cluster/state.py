"""A cluster's state file (``<out>/cluster.json``: its nodes, their configs, logs, ports and
process ids) and what its nodes write beside it (status and counters files, read back here).
``status``, ``kill``, ``restart`` and ``down`` act on a detached cluster through this file; one
that is not a state file (not UTF-8 JSON of the fields below) is a :class:`ClusterError` naming
it. A node's status or counters file that cannot be read is no status yet (``{}``).
"""
from __future__ import annotations

import json
import os
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

from edge_node.formats.text import read_text
from edge_node.runtime.output import counters_path, status_path
from protocol.errors import DmttError
from sim_cluster.cluster.processes import alive

STATE = "cluster.json"


class ClusterError(DmttError):
    """A cluster that cannot be started or acted on; the message says why."""


@dataclass
class NodeProc:
    node: int
    config: str
    log: str
    port: int
    pid: int | None = None
    restarts: int = 0


@dataclass
class ClusterState:
    out: str
    network: str
    scenario: str
    seed: int
    frames: int | None
    mode: str
    topology: str
    adjacency: dict[str, list[int]]
    nodes: dict[str, NodeProc] = field(default_factory=dict)
    started_at: float = 0.0
    data_root: str | None = None

    def save(self) -> None:
        path = Path(self.out) / STATE
        tmp = path.with_suffix(".tmp")
        tmp.write_text(json.dumps(asdict(self), indent=2))
        os.replace(tmp, path)

    @classmethod
    def load(cls, out: str | Path) -> "ClusterState":
        path = Path(out) / STATE
        try:
            d = json.loads(read_text(path, lambda e: ClusterError(str(e))))
        except FileNotFoundError:
            raise ClusterError(f"no cluster at {out} (no {STATE}); start one with "
                               f"'sim_cluster up --out {out}'") from None
        except json.JSONDecodeError as e:
            raise ClusterError(f"{path}: not a cluster state file ({e})") from None
        try:
            d["nodes"] = {k: NodeProc(**v) for k, v in d["nodes"].items()}
            return cls(**d)
        except (KeyError, TypeError, AttributeError) as e:  # JSON, but not of these fields
            raise ClusterError(f"{path}: not a cluster state file ({type(e).__name__}: "
                               f"{e})") from None


# -- what the nodes write ----------------------------------------------------------------------
def _node_file(path: Path) -> dict:
    """A node's JSON file, ``{}`` when missing or not a JSON object (bytes that are not UTF-8,
    a write cut short)."""
    try:
        d = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):  # JSONDecodeError, UnicodeDecodeError
        return {}
    return d if isinstance(d, dict) else {}


def node_status(state: ClusterState, node: int) -> dict:
    """Node ``node``'s live status file (``{}`` while it has none)."""
    return _node_file(status_path(Path(state.out) / "nodes", node))


def node_counters(state: ClusterState, node: int) -> dict:
    """Node ``node``'s wire counters, written when it exits (``{}`` before)."""
    return _node_file(counters_path(Path(state.out) / "nodes", node))


def health(st: dict, running: bool, now: float | None = None) -> str:
    """A node's phase as ``status`` shows it: what its status file says, but ``stalled`` for a
    running node whose file has not been rewritten for its ``stall_after_s`` (a frozen process
    cannot say so itself) and ``exited`` for a node that is gone without saying it finished."""
    phase = st.get("phase", "-")
    if not running:
        return phase if phase in ("finished", "stopped", "failed") else ("exited" if st else "-")
    if phase in ("finished", "stopped", "failed"):
        return phase
    updated = st.get("updated_at")
    after = st.get("stall_after_s") or 5.0
    if updated is not None and (time.time() if now is None else now) - updated > after:
        return "stalled"
    return phase


def status_table(state: ClusterState) -> str:
    """``sim_cluster status``: one row per node, then the reasons of rejected messages and the
    neighbours each node distrusts (suspect or quarantined)."""
    rows = [f"cluster {state.out}: {len(state.nodes)} nodes, {state.topology}, {state.mode}, "
            f"scenario {state.scenario} seed {state.seed}",
            f"{'node':>4} {'pid':>7} {'alive':>5} {'frame':>6} {'trackers':>8} {'bytes sent':>11} "
            f"{'rejected':>8} {'late':>5} {'timeouts':>8}  phase"]
    reasons = []  # hostile or broken input, by ProtocolError reason (protocol/errors.py)
    for key, p in sorted(state.nodes.items(), key=lambda kv: int(kv[0])):
        st = node_status(state, p.node)
        rejected = sum((st.get("rejected") or {}).values())
        if rejected:
            reasons.append(f"node {p.node} rejected: " + ", ".join(
                f"{r} {n}" for r, n in sorted(st["rejected"].items())))
        frame = st.get("frame")
        running = alive(p.pid)
        phase = health(st, running)
        distrusted = {n: v for n, v in (st.get("trust") or {}).items() if v != "trusted"}
        why = st.get("trust_reason") or {}
        if distrusted:  # a neighbour this node no longer believes (edge_node/core/trust.py)
            reasons.append(f"node {p.node} distrusts: " + ", ".join(
                f"neighbour {n} {v}" + (f" ({why[n]})" if why.get(n) else "")
                for n, v in sorted(distrusted.items(), key=lambda kv: int(kv[0]))))
        if st.get("output_errors") and running:
            reasons.append(f"node {p.node} output failing: " + ", ".join(
                f"{k} ({v})" for k, v in sorted(st["output_errors"].items())))
        rows.append(f"{p.node:>4} {p.pid or '-':>7} {'yes' if running else 'no':>5} "
                    f"{'-' if frame is None else frame:>6} {st.get('trackers', '-'):>8} "
                    f"{st.get('bytes_sent', '-'):>11} {rejected:>8} {st.get('late', '-'):>5} "
                    f"{st.get('timeouts', '-'):>8}  {phase}")
    return "\n".join(rows + reasons)
