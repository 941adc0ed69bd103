"""Each camera's own view (the reporter's drawing half): where a node draws the network's
targets in its own camera's image (``Track.boxes``), what its track file holds and what the
paper's image-plane protocol scores.

A camera draws a target it measured within ``view_frames`` (or any target, with
``view_unseen``): the network's estimate's ground point mapped back through the camera's own
registration (where its box's bottom edge lies), at the box size the camera itself measures for
that target, smoothed at ``view_rate`` (:meth:`OwnViews.saw`). It draws it only while it can see
it (:meth:`OwnViews.visible`): at least ``view_inside`` of the box's width inside the image, and,
if ``view_hidden`` is below 1, not covered by a nearer drawn box once the camera has not
measured it for ``view_fresh`` frames. docs/concepts.md ("Each camera's own view") says why
and docs/tuning.md what was measured.

This role reads only its own slice of the configuration (:class:`ViewSettings`); the node
gives it the trackers to draw and their estimates. Pure and deterministic.
"""
from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from edge_node.core.config import Slice
from edge_node.core.measurement import pixels_per_unit
from edge_node.core.registration import Registration
from edge_node.core.measurement import BoxMeasurements
from edge_node.core.state import NodeState
from edge_node.geometry import Camera


@dataclass(frozen=True)
class ViewSettings(Slice):
    """What each camera's own view reads (the ``view_*`` parameters of the configuration's
    ``reporter`` section, where their rules and docs are)."""

    view_frames: int
    view_rate: float
    view_unseen: bool
    view_inside: float
    view_fresh: int
    view_hidden: float


class OwnViews:
    """Draws a node's targets in its cameras' images; the box sizes each camera measured are
    kept in the node's table (``NodeState.view_k``, ``view_size``: per camera, the last frame
    it measured the target and the size it draws it at)."""

    def __init__(self, settings: ViewSettings, cameras: Sequence[Camera],
                 registrations: Mapping[int, Registration]):
        self.s = settings
        self.cameras = list(cameras)
        self.registrations = registrations  # the node's, live: corrections learnt since count

    def saw(self, state: NodeState, k: int, raws: Mapping[int, BoxMeasurements]) -> None:
        """The frame's measurements (``state.raw``: per camera, the row of each tracker's box
        among ``raws[camera]``, -1 none): the size each camera draws a target at is smoothed
        towards the size it measured at ``view_rate``, all at once."""
        for c, cam in enumerate(self.cameras):
            rows = np.flatnonzero(state.raw[:, c] >= 0)
            if not len(rows):
                continue
            size = np.array(raws[cam.id].size.take(state.raw[rows, c], axis=0), float)
            held = state.view_k[rows, c] >= 0
            if held.any():
                before = state.view_size[rows[held], c]
                size[held] = before + self.s.view_rate * (size[held] - before)
            state.view_k[rows, c] = k
            state.view_size[rows, c] = size

    def boxes(self, state: NodeState, rows: np.ndarray, k: int,
              x_hat: np.ndarray) -> list[dict[int, np.ndarray]]:
        """Each tracker's box in each camera that draws it at frame ``k`` (``rows`` the
        trackers' rows of the table, ``x_hat`` ``(n, 6)`` their estimates, in order); all
        trackers of a camera at once."""
        s = self.s
        out: list[dict[int, np.ndarray]] = [{} for _ in range(len(rows))]
        for c, cam in enumerate(self.cameras):
            last = state.view_k[rows, c]
            fresh = (last >= 0) & (k - last <= s.view_frames)
            if s.view_unseen:
                pick = np.arange(len(rows))
                sizes = np.where(fresh[:, None], state.view_size[rows, c], x_hat[:, 2:4])
                ages = np.where(fresh, k - last, s.view_frames + 1)
            else:
                pick = np.flatnonzero(fresh)
                sizes = state.view_size[rows[pick], c]
                ages = k - last[pick]
            if not len(pick):
                continue
            xy = x_hat[pick, :2]
            reg = self.registrations.get(cam.id)
            g = xy if reg is None else reg.to_camera_many(xy)
            with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
                foot, J = cam.image_and_jacobians(g)
                wh = sizes * pixels_per_unit(J)[:, None]
            box = np.concatenate([foot[:, :1] - wh[:, :1] / 2.0, foot[:, 1:] - wh[:, 1:], wh], axis=1)
            drawn = self.visible(cam, box, np.asarray(ages))
            for i, b, ok in zip(pick.tolist(), box, drawn.tolist()):
                if ok:
                    out[i][cam.id] = b
        return out

    def visible(self, cam: Camera, box: np.ndarray, age: np.ndarray) -> np.ndarray:
        """Which of a camera's boxes ``(n, 4)`` it can see (``age``: frames since it last
        measured each target): finite, overlapping the image with at least ``view_inside`` of
        the box's width between its left and right edges (people walk in and out of a view
        sideways; one whose head or feet the frame cuts off is still there), and not hidden. A
        target the camera has not measured for more than ``view_fresh`` frames is hidden when
        a nearer visible box (its bottom edge lower in the image: the target stands closer on
        the ground plane) covers ``view_hidden`` of it; the camera's detector would not report
        it either, so drawing it could only add a false box. A target the camera measures now
        is drawn however crowded the scene."""
        s = self.s
        W, H = cam.image_size
        with np.errstate(invalid="ignore", over="ignore"):
            x0, y0 = box[:, 0], box[:, 1]
            x1, y1 = x0 + box[:, 2], y0 + box[:, 3]
            area = box[:, 2] * box[:, 3]
            across = (np.minimum(x1, W) - np.maximum(x0, 0.0)).clip(0.0)  # width in the image
            ok = np.isfinite(box).all(axis=1) & (area > 0) & (y1 > 0) & (y0 < H)
            ok &= (across > 0) & (across >= s.view_inside * box[:, 2])
        stale = ok & (age > s.view_fresh)
        if s.view_hidden >= 1.0 or not stale.any() or ok.sum() < 2:
            return ok
        a, b = np.flatnonzero(stale), np.flatnonzero(ok)
        cover = ((np.minimum(x1[a, None], x1[None, b]) - np.maximum(x0[a, None], x0[None, b])).clip(0.0)
                 * (np.minimum(y1[a, None], y1[None, b]) - np.maximum(y0[a, None], y0[None, b])).clip(0.0))
        nearer = y1[None, b] > y1[a, None]
        hidden = ((cover * nearer) >= s.view_hidden * area[a, None]).any(axis=1)
        ok[a[hidden]] = False
        return ok
