"""Each camera's own view (the reporter's drawing half): where a node draws the network's
targets in its own camera's image (``Track.boxes``), what its track file holds and what the
paper's image-plane protocol scores.

A camera draws a target where it itself sees it: the network's estimate's ground point mapped
back through the camera's own registration (where its box's bottom edge lies), moved by where
the camera last measured the target against that estimate (``view_place``), at the box size the
camera itself measures for that target; both smoothed at ``view_rate`` (:meth:`OwnViews.saw`,
:meth:`OwnViews.boxes`), and learnt only from measurements that locate the target within
``view_locate``. It draws a target it measured within ``view_frames``; one it has not measured
for longer, or never, only while a nearer target it measures hides it (``view_behind``,
``view_depth``: the camera's detector cannot report it there, but the person is there); any
target with ``view_unseen``. It draws each only while it can see it (:meth:`OwnViews.visible`):
at least ``view_inside`` of the box's width inside the image, and, if ``view_hidden`` is below
1, not covered by a nearer drawn box once the camera has not measured it for ``view_fresh``
frames. docs/concepts.md ("Each camera's own view") says why and docs/tuning.md ("Each camera
draws what it sees") what was measured.

What each camera knows of each target is kept in the node's table, per camera
(``NodeState.view_k``, ``view_size``, ``view_off``, ``view_at``); every step works on all
trackers of a camera at once. This role reads only its own slice of the configuration
(:class:`ViewSettings`); the node gives it the table, the trackers to draw, their estimates and
its cameras' measurements. Pure and deterministic.
"""
from __future__ import annotations

from collections import deque
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from edge_node.core.config import Slice
from edge_node.core.measurement import BoxMeasurements, pixels_per_unit
from edge_node.core.registration import Registration
from edge_node.core.state import NodeState
from edge_node.geometry import Camera
from protocol.messages import TrackerId


#: which pairs of tracker ids a node knows for two people (``DistributedTrackerManager.two_people``)
TwoPeople = Callable[[Sequence[tuple[TrackerId, TrackerId]]], np.ndarray]
#: which pairs of boxes, two index arrays, may be one person (:meth:`OwnViews.visible`)
Same = Callable[[np.ndarray, np.ndarray], np.ndarray]
HIDDEN_COVER = 1.0 / 3.0  # a person a nearer one covers by a third may be missed by a detector
HEAD_CUT = 0.2  # a box whose top the image cuts by more than this fraction may be missed


def _overlap(x0: np.ndarray, y0: np.ndarray, x1: np.ndarray, y1: np.ndarray, a: np.ndarray,
             b: np.ndarray) -> np.ndarray:
    """The area ``(len(a), len(b))`` each box ``a`` shares with each box ``b`` (boxes by their
    edges ``x0, y0, x1, y1``)."""
    return ((np.minimum(x1[a, None], x1[None, b]) - np.maximum(x0[a, None], x0[None, b])).clip(0.0)
            * (np.minimum(y1[a, None], y1[None, b]) - np.maximum(y0[a, None], y0[None, b])).clip(0.0))


@dataclass(frozen=True)
class ViewSettings(Slice):
    """What each camera's own view reads (the ``view_*`` parameters of the configuration's
    ``reporter`` section, where their rules and docs are; ``units_per_metre``:
    ``view_locate`` is in metres)."""

    view_frames: int
    view_rate: float
    view_place: bool
    view_locate: float
    view_behind: float
    view_depth: float
    view_unseen: bool
    view_inside: float
    view_fresh: int
    view_hidden: float
    view_twin: float
    report_unseen: int
    unseen_runs: int
    unseen_tail: float
    units_per_metre: float


class OwnViews:
    """Draws a node's targets in its cameras' images; what each camera measured of each
    target is kept in the node's table (per camera: ``NodeState.view_k``, the last frame it
    measured the target; ``view_size``, the size it draws it at; ``view_off``, where it sees it
    against the estimate; ``view_at``, the foot point it measured, until :meth:`boxes`)."""

    def __init__(self, settings: ViewSettings, cameras: Sequence[Camera],
                 registrations: Mapping[int, Registration]):
        self.s = settings
        self.cameras = list(cameras)
        self.registrations = registrations  # the node's, live: corrections learnt since count
        # the latest ended runs of negative evidence (``expect``), the oldest first out, and
        # the limit they give (``unseen_limit``), computed when they change
        self.runs: deque[int] = deque(maxlen=max(1, settings.unseen_runs))
        self._limit = settings.report_unseen

    def saw(self, state: NodeState, k: int, raws: Mapping[int, BoxMeasurements]) -> None:
        """The frame's measurements (``state.raw``: per camera, the row of each tracker's box
        among ``raws[camera]``, -1 none): the size each camera draws a target at is smoothed
        towards the size it measured at ``view_rate``, all at once, and the measured foot point
        waits for the frame's estimate (``view_at``, :meth:`boxes`). A measurement whose foot
        point is uncertain by more than ``view_locate`` (one sigma along either ground axis: a
        box cut by the image border, or whose bottom edge lies near the horizon, where a pixel
        is metres) does not show where the camera sees the target nor how large: it changes
        neither (a first measurement still gives the size), but counts as measured."""
        s = self.s
        for c, cam in enumerate(self.cameras):
            rows = np.flatnonzero(state.raw[:, c] >= 0)
            if not len(rows):
                continue
            ms, js = raws[cam.id], state.raw[rows, c]
            size = np.array(ms.size.take(js, axis=0), float)
            R = ms.R.take(js, axis=0)
            with np.errstate(invalid="ignore"):
                spread = np.sqrt(np.maximum(R[:, 0, 0], R[:, 1, 1]))
                located = spread <= s.view_locate * s.units_per_metre
            held = state.view_k[rows, c] >= 0
            if held.any():
                before = state.view_size[rows[held], c]
                learnt = before + s.view_rate * (size[held] - before)
                size[held] = np.where(located[held, None], learnt, before)
            state.view_k[rows, c] = k
            state.view_size[rows, c] = size
            state.view_at[rows, c] = np.where(located[:, None], ms.z.take(js, axis=0)[:, :2], np.nan)
        if s.report_unseen:
            self.expect(state)

    def expect(self, state: NodeState) -> None:
        """Negative evidence (``state.unseen``): a tracker that one of the node's cameras
        should have measured this frame and none did counts one more frame; one that a camera
        measured starts again from zero; one no camera could see keeps its count. A camera
        should measure a target whose predicted box (``x_bar``, mapped back through the
        camera's own registration, at the network's size) lies inside its image, the feet in
        it, the head cut by at most a fifth, and that no nearer predicted box (its bottom edge
        lower) covers by ``HIDDEN_COVER`` of its area: a detector finds such a person nine
        times in ten, so a target it has missed for ``unseen_limit()`` frames in a row is not
        there (a neighbour's false person) or is not where the network puts it. All trackers
        of a camera at once."""
        n = len(state)
        if not n:
            return
        expected = self.expected(state.x_bar, n)
        measured = (state.raw >= 0).any(axis=1)
        if self.s.unseen_runs:  # runs a measurement ends: a real person missed that long
            ended = state.unseen[measured]
            self.learn(ended[ended > 0].tolist())
        state.unseen += expected
        state.unseen[measured] = 0

    def expected(self, x: np.ndarray, n: int) -> np.ndarray:
        """Which of the targets ``x`` (states, ``x_bar``'s layout) one of the node's cameras
        should measure (:meth:`expect`): the predicted box inside its image, the feet in it, the
        head cut by at most a fifth, and no nearer box of the first ``n`` targets (the node's
        own; ``x[n:]`` are judged, not occluders) covering ``HIDDEN_COVER`` of it."""
        m = len(x)
        expected = np.zeros(m, bool)
        for cam in self.cameras:
            reg = self.registrations.get(cam.id)
            g = x[:, :2] if reg is None else reg.to_camera_many(x[:, :2])
            W, H = cam.image_size
            with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
                foot, J = cam.image_and_jacobians(g)
                wh = x[:, 2:4] * pixels_per_unit(J)[:, None]
                x0, x1 = foot[:, 0] - wh[:, 0] / 2.0, foot[:, 0] + wh[:, 0] / 2.0
                y1 = foot[:, 1]
                y0 = y1 - wh[:, 1]
                drawn = np.isfinite(foot).all(axis=1) & (wh > 0).all(axis=1)
                inside = drawn & (x0 >= 0) & (x1 <= W) & (y1 > 0) & (y1 <= H) \
                    & (y0 >= -HEAD_CUT * wh[:, 1])
            a = (inside & ~expected).nonzero()[0]
            if not len(a):
                continue
            b = drawn[:n].nonzero()[0]
            cover = _overlap(x0, y0, x1, y1, a, b)
            nearer = y1[None, b] > y1[a, None]
            hidden = ((cover * nearer) >= HIDDEN_COVER * (wh[a, 0] * wh[a, 1])[:, None]).any(axis=1)
            expected[a[~hidden]] = True
        return expected

    def unseen_limit(self) -> int:
        """Frames of negative evidence after which the node stops reporting a target
        (``report_unseen``; 0: never). With ``unseen_runs`` learnt from how long the node's
        cameras missed the people they measured again: one more than the longest of the kept
        ended runs but a fraction ``unseen_tail`` of them, and never below ``report_unseen``.
        A detector whose misses are independent (nine finds in ten) gives runs of one or two
        frames, and the floor holds; one whose misses come in runs (a person it cannot find in
        a pose, at a distance) raises the limit to what it really does, and the node no longer
        hides the people it misses that long. A neighbour's false person is never measured
        again, so it never ends a run: it does not raise the limit."""
        return self._limit

    def learn(self, runs: list[int]) -> None:
        """Keep ``runs``, ended runs of misses (frames), and set the limit the kept ones give
        (``int(unseen_tail * len)`` of the longest may be passed)."""
        if not runs:
            return
        self.runs.extend(runs)
        longest = sorted(self.runs)[-1 - int(self.s.unseen_tail * len(self.runs))]
        self._limit = max(self.s.report_unseen, longest + 1) if self.s.report_unseen else 0

    def boxes(self, state: NodeState, rows: np.ndarray, k: int, x_hat: np.ndarray,
              two_people: TwoPeople | None = None) -> list[dict[int, np.ndarray]]:
        """Each tracker's box in each camera that draws it at frame ``k`` (``rows`` the
        trackers' rows of the table, ``x_hat`` ``(n, 6)`` their estimates, in order); all
        trackers of a camera at once. A camera that measured a tracker this frame first moves
        where it sees it against the estimate towards the measurement, at ``view_rate``
        (``view_place``). A target the camera never measured (with ``view_unseen``, not within
        ``view_frames``) is drawn at the network's size and estimate, and counts as not
        measured for ``view_frames + 1`` frames. ``two_people``: which pairs of tracker ids the
        node knows for two people (the manager's); without it no target is taken for another's
        twin (:meth:`visible`)."""
        s = self.s
        out: list[dict[int, np.ndarray]] = [{} for _ in range(len(rows))]
        for c, cam in enumerate(self.cameras):
            last = state.view_k[rows, c]
            known = last >= 0
            fresh = known & (k - last <= s.view_frames)
            if s.view_unseen:  # every target; only the fresh at the camera's own size and place
                pick, own = np.arange(len(rows)), fresh
            elif s.view_behind < 1.0:  # every target, to be drawn if it is hidden (visible)
                pick, own = np.arange(len(rows)), known
            else:
                pick = np.flatnonzero(fresh)
                own = np.ones(len(pick), bool)
            if not len(pick):
                continue
            at = rows[pick]
            sizes = np.where(own[:, None], state.view_size[at, c], x_hat[pick, 2:4])
            ages = np.where(own, k - last[pick], s.view_frames + 1)
            xy = x_hat[pick, :2]
            reg = self.registrations.get(cam.id)
            g = xy if reg is None else reg.to_camera_many(xy)
            if s.view_place:
                g = self._placed(state, at, c, k, own, g)
            with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
                foot, J = cam.image_and_jacobians(g)
                wh = sizes * pixels_per_unit(J)[:, None]
            box = np.concatenate([foot[:, :1] - wh[:, :1] / 2.0, foot[:, 1:] - wh[:, 1:], wh], axis=1)
            same = None
            if two_people is not None:
                ids = state.ids
                same = lambda a, b, at=at: ~two_people([(ids[i], ids[j])  # noqa: E731
                                                        for i, j in zip(at[a].tolist(), at[b].tolist())])
            drawn = self.visible(cam, box, np.asarray(ages), same)
            for i, b, ok in zip(pick.tolist(), box, drawn.tolist()):
                if ok:
                    out[i][cam.id] = b
        return out

    def _placed(self, state: NodeState, rows: np.ndarray, c: int, k: int, own: np.ndarray,
                g: np.ndarray) -> np.ndarray:
        """The ground points ``g`` (the estimates of table ``rows`` in camera ``c``'s own
        frame) moved by where the camera sees each target against its estimate (``own``: the
        targets drawn from what the camera knows of them; the others stay where ``g`` is); a
        measurement of this frame first moves that offset towards itself at ``view_rate`` (the
        first sets it). A measured foot point is used once."""
        off = state.view_off[rows, c]
        found = state.view_at[rows, c]
        pending = own & np.isfinite(found).all(axis=1)
        if pending.any():
            now = pending & (state.view_k[rows, c] == k)
            with np.errstate(invalid="ignore"):
                r = found - g
                learnt = np.where(np.isnan(off), r, off + self.s.view_rate * (r - off))
            off = np.where(now[:, None], learnt, off)
            state.view_off[rows[now], c] = off[now]
            state.view_at[rows[pending], c] = np.nan
        placed = own & np.isfinite(off).all(axis=1)
        return g + np.where(placed[:, None], off, 0.0)

    def _behind(self, box: np.ndarray, old: np.ndarray, now: np.ndarray) -> np.ndarray:
        """Which boxes of ``old`` (the rest False) stand behind a box of ``now``: covered by
        at least ``view_behind`` of their area, and its bottom edge at least ``view_depth`` of
        their height lower (never, with ``view_behind`` 1)."""
        out = np.zeros(len(box), bool)
        if self.s.view_behind >= 1.0 or not now.any():
            return out
        a, b = np.flatnonzero(old), np.flatnonzero(now)
        x0, y0, w, h = box.T
        x1, y1 = x0 + w, y0 + h
        cover = _overlap(x0, y0, x1, y1, a, b)
        nearer = y1[None, b] >= y1[a, None] + self.s.view_depth * h[a, None]
        out[a] = ((cover * nearer) >= self.s.view_behind * (w * h)[a, None]).any(axis=1)
        return out

    def _twins(self, box: np.ndarray, ok: np.ndarray, age: np.ndarray, same: Same) -> np.ndarray:
        """Which boxes of ``ok`` (the rest False) are the twin of another box of ``ok`` that
        the camera measured more recently (``age``, frames since it last measured each): an
        IoU of at least ``view_twin`` with it, their bottom edges within ``view_depth`` of the
        box's height (the same depth: not one behind the other), and ``same`` of the pair (the
        node does not know them for two people), that is itself drawn. All pairs at once."""
        out = np.zeros(len(box), bool)
        old = ok & (age > 0)
        if self.s.view_twin >= 1.0 or not old.any():
            return out
        a, b = old.nonzero()[0], ok.nonzero()[0]
        x0, y0, w, h = box.T
        x1, y1 = x0 + w, y0 + h
        inter = _overlap(x0, y0, x1, y1, a, b)
        area = w * h
        close = (inter >= self.s.view_twin * (area[a, None] + area[None, b] - inter)) \
            & (np.abs(y1[None, b] - y1[a, None]) < self.s.view_depth * h[a, None]) \
            & (age[None, b] < age[a, None])
        i, j = close.nonzero()
        if len(i):
            keep = same(a[i], b[j])
            i, j = i[keep], j[keep]
        # the most recently measured first: a box is left out only for a twin that is drawn
        # (three boxes in a row, each overlapping the next: the middle one hidden, the first
        # is drawn), so of each pair the camera draws one
        for r in sorted(set(i.tolist()), key=lambda r: (age[a[r]], a[r])):
            out[a[r]] = not out[b[j[i == r]]].all()
        return out

    def visible(self, cam: Camera, box: np.ndarray, age: np.ndarray,
                same: Same | None = None) -> np.ndarray:
        """Which of a camera's boxes ``(n, 4)`` it can see (``age``: frames since it last
        measured each target): finite, overlapping the image with at least ``view_inside`` of
        the box's width between its left and right edges (people walk in and out of a view
        sideways; one whose head or feet the frame cuts off is still there); and, for a target
        it has not measured for more than ``view_frames`` frames, hidden behind a nearer one it
        has: one box of those covers at least ``view_behind`` of it and its bottom edge lies at
        least ``view_depth`` of the box's height lower (the target stands behind it on the
        ground plane, not beside it). Such a target is there and the camera cannot report it;
        one nobody hides would be reported if it were there (it walked out, or the network's
        estimate is not this camera's person). Then, if ``view_hidden`` is below 1, a target
        the camera has not measured for more than ``view_fresh`` frames is left out when a
        nearer drawn box (its bottom edge lower in the image) covers ``view_hidden`` of it (for
        annotations that leave hidden people out). A target is not drawn where it is the twin
        of one the camera measured more recently (:meth:`_twins`, ``view_twin``): one person
        held by two trackers the node has not merged (cameras whose maps disagree by metres
        each measure the person as their own tracker, and this camera's detection goes to one
        of them one frame and to the other the next), whom its detector shows as one box;
        ``same(a, b)`` (index arrays of pairs of boxes) says which pairs may be one person, and
        without it none is. A target the camera measures now is drawn however crowded the
        scene."""
        s = self.s
        W, H = cam.image_size
        with np.errstate(invalid="ignore", over="ignore"):
            x0, y0 = box[:, 0], box[:, 1]
            x1, y1 = x0 + box[:, 2], y0 + box[:, 3]
            area = box[:, 2] * box[:, 3]
            across = (np.minimum(x1, W) - np.maximum(x0, 0.0)).clip(0.0)  # width in the image
            ok = np.isfinite(box).all(axis=1) & (area > 0) & (y1 > 0) & (y0 < H)
            ok &= (across > 0) & (across >= s.view_inside * box[:, 2])
        old = ok & (age > s.view_frames) if not s.view_unseen else np.zeros_like(ok)
        if old.any():
            ok &= ~old | self._behind(box, old, ok & ~old)
        if same is not None:
            ok &= ~self._twins(box, ok, age, same)
        stale = ok & (age > s.view_fresh)
        if s.view_hidden >= 1.0 or not stale.any() or ok.sum() < 2:
            return ok
        a, b = np.flatnonzero(stale), np.flatnonzero(ok)
        cover = _overlap(x0, y0, x1, y1, a, b)
        nearer = y1[None, b] > y1[a, None]
        hidden = ((cover * nearer) >= s.view_hidden * area[a, None]).any(axis=1)
        ok[a[hidden]] = False
        return ok
