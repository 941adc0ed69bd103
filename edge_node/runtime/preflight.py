"""What ``edge_node run`` does with a camera config before it opens a Zenoh session, as one
function ``edge_node check`` calls too, so that ``check`` accepts exactly the configs ``run``
starts with.

:func:`preflight` opens the source the way ``run`` does (``sources.open_source``: a det-files
camera's files are read and checked, a plug-in kind such as sim_cluster's ``scenario`` loads its
scenario and camera, a frame source opens its frames, detector and re-id weights), builds the
tracker configuration from it (``tracker_config_for``; in async mode ``heartbeat_frames`` is checked against its ``kappa``), reads the id counter a restarted
node resumes from (``[output] dir``'s ``state_node<id>.json``) and assembles the tracker core.
Errors are the ones ``run`` stops with at start-up (exit status 2): ``SourceError`` and
``NodeConfigError`` naming the file and the field.
"""
from __future__ import annotations

import json
from dataclasses import dataclass
from typing import Any

from edge_node.core.config import TrackerConfig
from edge_node.core.node import CameraNode
from edge_node.core.params import ConfigError
from edge_node.core.trigger import TriggerConfig, check_heartbeat
from edge_node.formats.text import read_text
from edge_node.runtime.config import NodeConfig, NodeConfigError
from edge_node.runtime.output import state_path
from edge_node.runtime.sources import Source, open_source


def tracker_config_for(cfg: NodeConfig, source: Source) -> TrackerConfig:
    """The tracker config as sim_cluster's reference run builds it: fps and units per metre from
    the source unless ``[tracker]`` sets them; ``[runtime] staleness_frames`` when given."""
    changes: dict[str, Any] = {}
    if "fps" not in cfg.tracker_explicit:
        changes["fps"] = source.fps
    if "units_per_metre" not in cfg.tracker_explicit:
        changes["units_per_metre"] = source.units_per_metre
    if cfg.runtime.staleness_frames is not None:
        changes["staleness_frames"] = cfg.runtime.staleness_frames
    return cfg.tracker.with_(**changes)



@dataclass
class Preflight:
    """A config that passed: its open source, the tracker config and the first id counter."""

    source: Source
    tracker: TrackerConfig
    first_counter: int

    def close(self) -> None:
        """Release the source (frames and cameras hold a file or a device open)."""
        close = getattr(self.source, "close", None)
        if close is not None:
            close()


COUNTERS = 2**63  # the message encoder holds ids as int64 (protocol/codec.py)


def first_counter(cfg: NodeConfig) -> int:
    """The id counter a restarted node resumes from (0 without a state file). A state file
    that is not UTF-8 JSON holding a ``next_counter`` in ``0..2**63-1`` is a
    ``NodeConfigError`` naming it (outside that range the message encoder would refuse the id
    of the node's first new tracker)."""
    if cfg.output.dir is None:
        return 0
    path = state_path(cfg.output.dir, cfg.node)
    if not path.exists():
        return 0
    try:
        counter = json.loads(read_text(path, lambda e: e))["next_counter"]
        if isinstance(counter, bool) or not isinstance(counter, int) \
                or not 0 <= counter < COUNTERS:
            raise ValueError(f"next_counter must be a whole number in 0..2**63-1, got {counter!r}")
        return counter
    except (OSError, ValueError, KeyError, TypeError) as e:
        raise NodeConfigError(cfg.name, "output.dir", f"has an unreadable {path.name} ({e}); "
                              "remove it to start the id counter at 0") from None


def preflight(cfg: NodeConfig) -> Preflight:
    """Open ``cfg``'s source and build its tracker as ``edge_node run`` does before Zenoh
    (module docstring); the caller closes the result."""
    ready = Preflight(open_source(cfg), cfg.tracker, 0)
    src = ready.source
    try:
        try:
            ready.tracker = tracker_config_for(cfg, src)
        except ConfigError as e:  # the source's fps or units per metre break a tracker rule
            raise NodeConfigError(cfg.name, e.field or "tracker",
                                  f"{e.message} (with the source's fps {src.fps:g} and "
                                  f"units_per_metre {src.units_per_metre:g})") from None
        if cfg.runtime.mode == "async":
            try:
                check_heartbeat(TriggerConfig(cfg.runtime.heartbeat_frames, cfg.runtime.drift_m,
                                              cfg.runtime.gain_nats),
                                ready.tracker.kappa, ready.tracker.hold_frames)
            except ConfigError as e:
                raise NodeConfigError(cfg.name, "runtime.heartbeat_frames", e.message) from None
        ready.first_counter = first_counter(cfg)
        CameraNode(src.camera, cfg.neighbours, ready.tracker, cfg.network, node_id=cfg.node,
                   first_counter=ready.first_counter)
    except BaseException:
        ready.close()
        raise
    return ready
