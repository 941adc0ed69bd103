"""Inputs and outputs of the tracker core."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from protocol.messages import TrackerId


@dataclass(frozen=True, eq=False)
class Detection:
    """One detector output in one image: a box ``(x, y, w, h)`` in pixels (top-left, size)
    and, when a re-id network ran, its appearance descriptor ``(D,)``."""

    box: np.ndarray
    descriptor: np.ndarray | None = None
    score: float = 1.0


@dataclass(frozen=True, eq=False)
class Track:
    """One target as a node knows it after ``update`` of frame ``frame``.

    ``x`` is the corrected state ``x_hat = (x, y, w, h, vx, vy)``; ``P`` its covariance (the
    information-form ``M`` of eq. 4); ``observed`` is whether this node's own camera associated
    a detection to it this frame; ``ell`` the drop counter of eq. 8.

    ``boxes``: the target in this node's own image(s), ``{camera: (x, y, w, h) px}``, for the
    cameras that saw it recently (``TrackerConfig.view_frames``), or that see a nearer target
    they measure hide it (``view_behind``): the network's estimate mapped back through the
    camera's own registration, moved by where the camera last measured the target against the
    estimate (``view_place``), at the size the camera itself measures it (``views.OwnViews``).
    Otherwise not drawn: a camera that does not see a target has no box of it. ``None`` when
    unknown (tracks read back from files without boxes).
    """

    id: TrackerId
    frame: int
    x: np.ndarray
    P: np.ndarray
    observed: bool
    ell: int
    boxes: dict[int, np.ndarray] | None = None

    @classmethod
    def _built(cls, id: TrackerId, frame: int, x: np.ndarray, P: np.ndarray, observed: bool,
               ell: int, boxes: dict[int, np.ndarray] | None) -> "Track":
        """``Track(...)`` with every field given, without the frozen dataclass's checked
        ``__setattr__`` per field (the core builds one per tracker a frame; half the cost)."""
        t = object.__new__(cls)
        t.__dict__.update(id=id, frame=frame, x=x, P=P, observed=observed, ell=ell, boxes=boxes)
        return t
