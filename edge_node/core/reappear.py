"""Re-identification by motion: a new tracker that goes on where a dropped one was heading takes
its id (our addition to the paper's III-C, which re-identifies old trackers by appearance only).

A person nobody sees for ``kappa`` frames is dropped (eq. 8); when some camera finds them again,
a new tracker is born, usually more than ``reid_gate`` from where the old one was dropped (it
walked on while hidden) or after ``reid_frames``, so the birth-time rule (``manager.reidentify``)
misses it and the person gets a second id. On Terrace without descriptors these rebirths were
the largest identity losses after the wrong merges: one person 907 frames, another 905, a third
584 under the new id (docs/tuning.md, "Re-identification by motion").

One frame cannot tell: at birth a tracker has no velocity of its own. So the decision is taken
on the track, ``reappear_age`` frames after the new tracker's birth. The gap between the
dropped tracker ``D`` (last seen at frame ``k_s``, dropped at ``k_D`` with state ``x_D``) and the
new tracker ``N`` (born at ``k_N`` where its camera measured ``o_N``, at ``p_N`` now, frame ``k``)
is bridged from both sides to its middle ``k_mid = (k_s + k_N) / 2``, each at constant velocity
(the model of eq. 1); ``N``'s is its average since birth, as its Kalman velocity is still pulled
towards the birth prior's zero::

    forward  = p_D + v_D (k_mid - k_D) dt
    v_N      = (p_N - o_N) / ((k - k_N) dt)
    backward = o_N - v_N (k_N - k_mid) dt
    d_mid    = |forward - backward|

and ``N`` is ``D`` when ``d_mid < reappear_gate + reappear_spread * (k_N - k_s) dt`` and
``k_N - k_s <= reappear_frames``: the meeting point is uncertain by a fixed amount and, if
``reappear_spread`` is set, by how far a walker's course can bend while hidden.
Pairs are decided nearest first, each tracker once, ties to the smaller ids: deterministic.
Where both trackers have galleries they must be within ``merge_appearance`` (they look alike).

Only the node whose camera created ``N`` (the id's camera) decides, so one decision is taken per
new tracker; it is a merge ``N -> D`` (``D`` is the older), announced and relayed like any other,
and every node ends with ``D``'s id. Every node hides ``N`` while such a decision may still come
(:func:`awaiting`), so a person re-identified this way never shows the second id.
Pure and deterministic.
"""
from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from edge_node.core.config import Slice
from edge_node.core.gallery import Gallery
from edge_node.core.model import POS, VEL
from protocol.messages import TrackerId


@dataclass(frozen=True)
class ReappearSettings(Slice):
    """What re-identification by motion reads; each parameter's rule and doc is in its section
    of ``config.TrackerConfig``."""

    merge_appearance: float
    reappear_age: int
    reappear_frames: int
    reappear_gate: float
    reappear_spread: float
    reappear_hide: int
    reid_speed: float
    units_per_metre: float
    fps: float


class Young(NamedTuple):
    """A tracker new enough to be a re-appearance: its id, birth frame, state and gallery."""

    id: TrackerId
    born: int
    x: np.ndarray
    gallery: Gallery
    origin: np.ndarray | None = None  # where its camera measured it at birth (creator only)


class Gone(NamedTuple):
    """A dropped tracker that may re-appear: its id, drop frame, the frame it was last seen,
    its state when dropped and its gallery."""

    id: TrackerId
    frame: int
    seen: int
    x: np.ndarray
    gallery: Gallery


def reach(gap: int, cfg: ReappearSettings) -> float:
    """The largest ``d_mid`` (ground units) of a re-appearance after ``gap`` frames unseen."""
    return cfg.m(cfg.reappear_gate) + cfg.m(cfg.reappear_spread) * gap * cfg.dt


def d_mid(young: Young, gone: Gone, k: int, cfg: ReappearSettings) -> float:
    """The distance between the dropped tracker's course carried forward and the new tracker's
    carried back from its ``origin``, at the middle of the gap (module docstring); or, when
    the new tracker would have walked from its ``origin`` faster than ``reid_speed`` (its
    camera's first measurement was not where the person stood), between the dropped tracker's
    course carried on to frame ``k`` and where the new tracker is. Before (terrace-full
    complete, no descriptors, seed 2, ``naive_yield``): a person hidden from every camera for
    39 frames came back in a box whose foot point lay 1.5 m from them; the new tracker,
    converged 1.2 m on within 4 frames, seemed to walk at 3.0 m/s, its course carried back
    missed the dropped one's by metres, and the person kept the new id for 1,405 frames."""
    v = (young.x[POS] - young.origin) / max(1, k - young.born)
    if float(np.linalg.norm(v)) > cfg.m(cfg.reid_speed) * cfg.dt:
        # no walker went from the origin to where the tracker is now (the first measurement
        # missed the person: a foot point the image cut, say): the new tracker's course is
        # unknown, and the dropped one's is carried on to now
        at, backward = k, young.x[POS]
    else:
        at = 0.5 * (gone.seen + young.born)
        backward = young.origin - v * (young.born - at)
    forward = gone.x[POS] + gone.x[VEL] * (at - gone.frame) * cfg.dt
    return float(np.linalg.norm(forward - backward))


def candidates(young: Young, gone: Sequence[Gone], cfg: ReappearSettings,
               veto: float | None = None) -> list[Gone]:
    """The dropped trackers ``young`` may be: dropped before it was born, at most
    ``reappear_frames`` before, and alike where both have galleries (within ``veto``, default
    ``merge_appearance``)."""
    veto = cfg.merge_appearance if veto is None else veto
    out = []
    for g in gone:
        if not (g.frame < young.born and young.born - g.seen <= cfg.reappear_frames):
            continue
        if young.gallery.unlike(g.gallery, veto):
            continue  # looks like someone else
        out.append(g)
    return out


def reappearances(young: Sequence[Young], gone: Sequence[Gone], k: int, cfg: ReappearSettings,
                  veto: float | None = None) -> list[tuple[TrackerId, TrackerId]]:
    """``(new, dropped)`` pairs decided at frame ``k``: the trackers of ``young`` created on
    this node (they have an ``origin``) that are ``reappear_age`` frames old now, linked to the dropped tracker whose course they continue
    (module docstring), nearest pair first, each tracker at most once."""
    scored = []
    for y in young:
        if y.origin is None or k - y.born != cfg.reappear_age:
            continue
        for g in candidates(y, gone, cfg, veto):
            d = d_mid(y, g, k, cfg)
            if d < reach(y.born - g.seen, cfg):
                scored.append((d, y.id, g.id))
    pairs: list[tuple[TrackerId, TrackerId]] = []
    used: set[TrackerId] = set()
    for _, new, old in sorted(scored):
        if new not in used and old not in used:
            used.update((new, old))
            pairs.append((new, old))
    return pairs


def awaiting(young: Young, gone: Sequence[Gone], k: int, cfg: ReappearSettings,
             veto: float | None = None) -> bool:
    """Whether ``young`` may still be linked to a dropped tracker (and so is not reported yet):
    within ``reappear_age`` plus ``reappear_hide`` frames of its birth (the decision and its
    announcement's hops), with a candidate that could have walked, at ``reid_speed``, from
    where it was dropped to where ``young`` is."""
    if not 0 <= k - young.born < cfg.reappear_age + cfg.reappear_hide:
        return False
    for g in candidates(young, gone, cfg, veto):
        far = cfg.m(cfg.reappear_gate) + cfg.m(cfg.reid_speed) * (k - g.seen) * cfg.dt
        if float(np.linalg.norm(young.x[POS] - g.x[POS])) < far:
            return True
    return False


def gone_trackers(old: Mapping[TrackerId, Gallery], last: Mapping[TrackerId, tuple[int, np.ndarray]],
                  motion: Mapping[TrackerId, tuple[int, np.ndarray]]) -> list[Gone]:
    """The dropped trackers of a re-identification store (``ReidStore.candidates``, its ``last``
    and ``motion``) whose state when dropped is known, in id order."""
    return [Gone(tid, last[tid][0], *motion[tid], old[tid])
            for tid in sorted(old) if tid in last and tid in motion]
