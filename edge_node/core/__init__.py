"""The tracker core of paper Section III: pure, deterministic, no I/O, no clock, no randomness.

Nothing here imports Zenoh, Rerun, torch or OpenCV. The public entry point::

    from edge_node.core import CameraNode, TrackerConfig, Detection

    node = CameraNode(camera, neighbours=(1, 2), config=TrackerConfig())
    msg = node.prepare(k, detections)      # send msg to every neighbour
    tracks = node.update(neighbour_messages_of_frame_k)

``node`` composes roles, one job each, over one table of every tracker quantity (``state``):
``predictor`` (eq. 1's model, ``model``), ``measurer`` (box -> ``z, R``, ``measurement``,
``registration``), ``associator`` (LDA, eqs. 5-7, ``association``, ``gallery``), ``initiator``
(local births), ``inbound`` (accept, bound, screen, ``memory``), ``updater`` (eqs. 3-4,
``dkf``), ``registrar`` (registration residuals), ``lifecycle`` (the DTM's decisions applied:
births, adoptions, eq. 8, merges, drops; rules in ``manager``, ``reappear``, ``identity``),
``outbound`` (the message; ``trigger`` for event-triggered output), ``reporter`` (tracks,
``views``); ``config`` and ``params`` hold the parameters and their rules.
"""
from edge_node.core.config import ABLATIONS, ConfigError, TrackerConfig
from edge_node.core.node import CameraNode, Components, NodeStats, assemble
from edge_node.core.types import Detection, Track

__all__ = ["ABLATIONS", "CameraNode", "Components", "ConfigError", "Detection", "NodeStats",
           "Track", "TrackerConfig", "assemble"]
