"""The tracker core of paper Section III: pure, deterministic, no I/O, no clock, no randomness.

Nothing here imports Zenoh, Rerun, torch or OpenCV. The public entry point::

    from edge_node.core import CameraNode, TrackerConfig, Detection

    node = CameraNode(camera, neighbours=(1, 2), config=TrackerConfig())
    msg = node.prepare(k, detections)      # send msg to every neighbour
    tracks = node.update(neighbour_messages_of_frame_k)

Modules, one job each: ``model`` (state, ``A``, ``Q``, ``H``), ``measurement`` (box -> ``z, R``),
``dkf`` (eqs. 2-4), ``association`` (LDA, eqs. 5-7), ``gallery`` (appearance, eq. 7),
``initiator`` (local births), ``manager`` (DTM, eq. 8, merges, re-id), ``identity`` (ids, ranks,
aliases, dropped trackers), ``memory`` (event-triggered input), ``trigger`` (event-triggered
output), ``tracker`` (a tracker's state), ``node`` (the loop that composes them), ``config`` and
``params`` (parameters and their rules).
"""
from edge_node.core.config import ABLATIONS, ConfigError, TrackerConfig
from edge_node.core.node import CameraNode, Components, NodeStats, assemble
from edge_node.core.types import Detection, Track

__all__ = ["ABLATIONS", "CameraNode", "Components", "ConfigError", "Detection", "NodeStats",
           "Track", "TrackerConfig", "assemble"]
