"""Distributed Tracker Manager (paper Section III-C): its rules as pure functions, and the two
managers a node is assembled with.

* eq. 8, the drop counter ``ell``: 0 when a camera associates a measurement, otherwise the
  minimum over the inclusive neighbourhood plus one; a tracker is dropped once ``ell > kappa``.
* the distributed global data association: trackers of the same target coming from different
  cameras are found by Euclidean ground distance (``V = I``) and co-motion, with gallery
  appearance as a veto (:func:`pair_score`), and merged
  under a deterministic winner so that every camera converges on the same id. The paper names
  the smallest id for simultaneous initialisations; since duplicates also arise later (docs/concepts.md),
  the winner here is the *oldest* tracker, ``(born, id)`` smallest, which is the smallest id
  among simultaneous births and keeps an established id when a late duplicate is merged into it.
* re-identification: a new local tracker whose gallery matches an *old* (dropped) tracker's
  within ``epsilon`` takes the old id back; ours: without appearance, one born near where an old
  tracker was dropped, and one whose course continues an old tracker's
  (:mod:`edge_node.core.reappear`).
"""
from __future__ import annotations

import math
from collections.abc import Collection, Iterable, Mapping, Sequence
from dataclasses import dataclass
from itertools import chain

import numpy as np

from edge_node.core.evidence import PairEvidence
from edge_node.core.gallery import Gallery
from edge_node.core.identity import rank
from edge_node.core.reappear import Gone, ReappearSettings, Young, awaiting, reappearances
from edge_node.core.reidquality import ReidQuality, Thresholds
from edge_node.geometry import norms
from protocol.messages import TrackerId


@dataclass(frozen=True)
class ManagerSettings(ReappearSettings):
    """What the distributed tracker manager's rules read (merges, eq. 8, re-identification; and
    re-appearance's, ``ReappearSettings``); each parameter's rule and doc is in its section of
    ``config.TrackerConfig``."""

    tau_gda: float
    alpha_gda: float
    unknown_appearance: float
    appearance_gate: float
    comotion_gate: float
    comotion_miss: float
    comotion_split: float
    merge_llr: float
    merge_llr_floor: float
    merge_evidence: bool
    kappa: int
    epsilon: float
    reid_frames: int
    reid_gate: float
    reappear: bool
    heir_pending: bool
    stitch: bool


def ell_sent(observed: bool, ell_prev: int) -> int:
    """The counter a camera reports for frame ``k``: 0 if its camera saw the target, else
    its previous consensus value plus one (the two branches of eq. 8)."""
    return 0 if observed else ell_prev + 1


def ell_consensus(own: int, received: Iterable[int]) -> int:
    """Eq. 8: the minimum over the inclusive neighbourhood of the reported counters.

    A neighbour that saw the target reports 0, so the information that *someone* saw it
    spreads one hop per frame; when nobody sees it every camera's counter grows by one per
    frame and all drop it within ``kappa`` plus the network diameter.
    """
    return min([own, *received])


def ell_consensus_many(own: Sequence[int], rows: np.ndarray, received: np.ndarray) -> np.ndarray:
    """Eq. 8 for ``n`` trackers at once: ``own`` ``(n,)`` their counters as this camera reports
    them, ``received`` ``(m,)`` the neighbours' counters, ``rows`` ``(m,)`` the tracker each
    names. Returns ``(n,)`` int64: per tracker :func:`ell_consensus` of its own and received."""
    out = np.array(own, np.int64)
    np.minimum.at(out, rows, received)
    return out


@dataclass(eq=False, slots=True)
class MergeView:
    """What the global association needs of one tracker on this node (read only, not frozen:
    see ``association.Candidate``)."""

    id: TrackerId
    xy: np.ndarray
    gallery: Gallery
    new: bool  # born or adopted this frame (the paper's simultaneous-initialisation case)
    seen_by: frozenset[int]  # cameras of this node that associated a measurement this frame
    born: int = 0  # birth frame at the originating camera: the older tracker survives a merge
    measured_by: frozenset[int] = frozenset()  # neighbours whose camera saw it (node._received)
    started: bool = False  # born this frame from this node's own camera's observations
    since: int = 0  # frame it appeared on this node
    # frame of the news by which it appeared here (``Tracker.heard``): earlier than ``since``
    # when a neighbour's message told of it late; None: as ``since``
    heard: int | None = None

    @property
    def rank(self) -> tuple[int, TrackerId]:
        return rank(self.born, self.id)


def simultaneous(a: MergeView, b: MergeView) -> bool:
    """Whether two trackers are simultaneous initialisations (paper III-C): each started
    without news of the other. Both new on this node, or, when the news of one came late
    (event-triggered operation over late links, ``MergeView.heard``), the other appeared here
    no earlier than that news was sent: on time both would have been new together. Before,
    with every message 1-4 frames late, the cameras that started the same person in the same
    frame heard of each other's tracker after their own, and the pair waited for
    ``comotion_frames`` or was never merged (terrace-gt, whose cameras place one person up to a
    metre apart: 68 false positives on node 0 in the first 40 frames, none in sync or now)."""
    if a.new and b.new:
        return True
    return (a.new and a.heard is not None and b.since >= a.heard) or \
        (b.new and b.heard is not None and a.since >= b.heard)


def merge_reach(cfg: ManagerSettings) -> float:
    """The farthest apart two trackers may be merged by any rule of :func:`pair_score`."""
    return max(cfg.m(cfg.comotion_gate), cfg.m(cfg.tau_gda))


def pair_score(a: MergeView, b: MergeView, cfg: ManagerSettings, th: Thresholds | None = None,
               d: float | None = None, s_a: float | None = None) -> tuple[float, bool] | None:
    """Global association of two trackers on this node: ``(score, at_once)`` when they may be
    one target, the score ``s_a * d / alpha_gda`` (eqs. 5-7 with ``V = I``; ``s_a`` is
    ``unknown_appearance`` where a gallery is missing) and whether they merge this frame
    (``False``: only once the co-motion evidence, :func:`comotion_llr` summed over frames, says
    so); ``None`` when they cannot be one target.

    Appearance merges at once only where the deciding node can vouch for it; elsewhere place
    and co-motion decide and appearance can only forbid (the paper merges on appearance
    within a distance gate):

    * Appearance known on both sides and ``s_a > veto``: two people.
    * At once within ``tau_gda``, appearance matching (``s_a <= match``), no camera seeing them as two (neither
      this node's, which associated them to two different measurements this frame, nor a
      neighbour's whose camera saw both: its entries carry measurement information or say
      ``ell`` 0): a tracker this node's camera started this frame (the camera sees the target
      and nobody else beside it), or two simultaneous initialisations (the paper's;
      :func:`simultaneous`: both new on this node, or, over a late link, as they would have been
      had the news come on time).
    * At once by place: a tracker new on this node within half the ``comotion_gate`` of
      another, no camera seeing them as two.
    * Otherwise by co-motion: within ``comotion_gate`` of each other, until the evidence of
      the cameras (:func:`comotion_llr`) adds up to ``merge_llr``.
    * With ``merge_evidence`` (off by default), co-motion only while this node's camera or a
      neighbour measures each of the two: a node that only hears of both through consensus
      cannot tell two look-alikes walking together from a duplicate.

    Why not more appearance: a real re-id network confuses some people (cross-camera rank-1
    around 0.8). Merging on appearance anywhere (within ``tau_gda`` at once for a new tracker,
    after three frames otherwise) merged look-alikes walking near each other; a wrong merge
    takes one person's track away, their camera starts a new one next to the merged track,
    which is merged again. At rank-1 0.8 terrace-sim issued 10.5 ids per person and tracked
    worse than without descriptors (ground MOTA 0.837 against 0.957); keeping the at-once rule
    for trackers adopted from neighbours, ring8-sim issued 13.3 ids per person (0.890). With
    this rule 1.7 and 7.1, ground MOTA 0.967 and 0.943, and with perfect re-id the same figures
    as before on terrace-sim, terrace-gt and ring8-sim (docs/tuning.md).

    ``th``: the node's appearance thresholds (``reidquality``: ``veto`` and ``match`` learned
    from its re-id; default both ``merge_appearance``). Where ``s_a`` lies between them
    appearance cannot tell, and co-motion decides as without descriptors.
    """
    th = th or Thresholds.of(cfg)
    if d is None:  # (the merge search passes the pair's distances, computed for all at once)
        d = float(np.linalg.norm(a.xy - b.xy))
    if d >= merge_reach(cfg):
        return None
    if s_a is None:
        s_a = a.gallery.distance_to(b.gallery)
    known = not np.isnan(s_a)
    if known and s_a > th.veto:
        return None
    score = max(s_a if known else cfg.unknown_appearance, 1e-3) * d / cfg.m(cfg.alpha_gda)
    seen_as_two = bool(a.seen_by & b.seen_by or a.measured_by & b.measured_by)
    if (not seen_as_two and known and s_a <= th.match
            and (a.started or b.started or simultaneous(a, b))
            and d < cfg.m(cfg.tau_gda)):
        return score, True
    if d >= cfg.m(cfg.comotion_gate):
        return None
    if cfg.merge_evidence and not ((a.seen_by or a.measured_by) and (b.seen_by or b.measured_by)):
        return None  # neither this node's camera nor a neighbour measures both: it cannot tell
    return score, not seen_as_two and (a.new or b.new) and d < cfg.m(cfg.comotion_gate) / 2.0


def comotion_llr(a: MergeView, b: MergeView, cfg: ManagerSettings) -> float:
    """This frame's log-likelihood ratio, one target against two people, of what the cameras
    measured of two trackers within the ``comotion_gate`` (ours; the paper merges at once
    within its gate). A camera that measured one of the two and not the other counts
    ``log(1 / comotion_miss)``: it saw one person there, as it would of a duplicate, while of two
    people within a metre it measures only one with probability ``comotion_miss`` (one hidden
    behind the other, a miss). A camera that measured both counts
    ``log(comotion_split / (1 - comotion_miss))``: two people, unless its detector split one
    person into two boxes (``comotion_split``). Cameras that measured neither say nothing.
    (``seen_by`` are this node's cameras, ``measured_by`` its neighbours', whose entries carry
    measurement information or say ``ell`` 0.)"""
    sa, sb = a.seen_by | a.measured_by, b.seen_by | b.measured_by
    one, both = len(sa ^ sb), len(sa & sb)
    return one * -math.log(cfg.comotion_miss) + both * both_term(cfg)


def both_term(cfg: ManagerSettings) -> float:
    """What one camera that measured both trackers of a pair says (nats): two people, unless
    its detector split one person into two boxes, ``ln(comotion_split / (1 - comotion_miss))``."""
    return math.log(cfg.comotion_split / (1.0 - cfg.comotion_miss))


def far_apart(ordered: Sequence[MergeView], dist: np.ndarray,
              evidence: PairEvidence, cfg: ManagerSettings) -> None:
    """What a camera says of two trackers it measures at once farther apart than the merge
    rules reach (``ordered`` in id order, ``dist`` their distances): two people. One person
    gives a camera's detector one box, two only when it splits the person (``comotion_split``),
    and a split's two boxes lie within a body's width of each other, never metres apart; so
    each camera that measured both adds :func:`both_term` to the pair's evidence, as within the
    ``comotion_gate`` (:func:`comotion_llr`; cameras measuring one of the two say nothing
    here), down to ``merge_llr_floor``, kept while both trackers live (:func:`find_merges`).
    Before (terrace-full chain, no descriptors, seed 2, ``naive_yield``): two people measured
    as two by cameras 0 and 1 for 25 frames while 2-3 m apart walked together, 0.7-0.9 m
    apart, with one hidden behind the other from both cameras for 20 frames while only camera
    3, two hops from node 1, saw them both; node 1's evidence started from nothing at the gate,
    reached ``merge_llr`` and merged them on every node."""
    by = [v.seen_by | v.measured_by for v in ordered]  # the cameras that measured each
    cams = sorted(set().union(*by))
    if not cams:
        return
    # which trackers each camera measured (here or a neighbour's), then per pair how many
    # cameras measured both at once: one product, not a loop over the cameras' pairs
    n, reach = len(ordered), merge_reach(cfg)
    B = np.zeros((n, len(cams)), np.int64)
    B[np.repeat(np.arange(n), [len(cs) for cs in by]),
      np.searchsorted(cams, np.fromiter(chain.from_iterable(by), np.int64))] = 1
    both = B @ B.T
    i, j = np.triu((both > 0) & (dist >= reach), 1).nonzero()  # i < j, in (i, j) order
    if not len(i):
        return
    evidence.seen_apart([v.id for v in ordered], i, j, both[i, j] * both_term(cfg),
                        cfg.merge_llr_floor)


def find_merges(views: Sequence[MergeView], evidence: PairEvidence,
                cfg: ManagerSettings, th: Thresholds | None = None,
                learn: ReidQuality | None = None,
                distances: dict[tuple[TrackerId, TrackerId], tuple[int, int, float]] | None = None
                ) -> list[tuple[TrackerId, TrackerId]]:
    """Pairs ``(loser, winner)`` to merge this frame; updates ``evidence`` in place.

    ``evidence`` holds, per pair of trackers, the co-motion log-likelihood ratio summed over
    the frames they were within the ``comotion_gate`` (:func:`comotion_llr`, at least
    ``merge_llr_floor``); a pair merges once it reaches ``merge_llr`` (or at once, by the rules
    of :func:`pair_score`). Evidence that they are one target is forgotten when they part;
    evidence that they are two people (a camera saw both) is kept while both trackers live, so
    two people who were seen apart and then walk together, hidden from every camera but one,
    are not merged after a moment of agreement (terrace-full, no descriptors: 4 such merges of
    two people on one node cost 0.09 IDF1, docs/tuning.md).

    The paper merges "two or more" trackers of one target at once (three cameras that start
    the same person in the same frame): pairs join groups, best score first (ties broken by
    ids, so the outcome is deterministic); two groups join only if every pair across them may
    be one target (scored this frame, with no evidence against). Each group keeps its oldest
    tracker, ``(born, id)`` smallest; every other member is merged into it.

    ``th``: the appearance thresholds (:func:`pair_score`); ``learn``: the node's measured
    re-id, given the gallery distances of the nearby pairs some camera sees as two people this
    frame (the look-alikes an appearance match must tell apart, ``reidquality``).

    ``distances``: the pairs' gallery distances kept from earlier frames with the galleries'
    versions (``Gallery.version``); a pair's is computed again only when either gallery
    changed (a tracker's gallery takes a descriptor every ``gallery_every`` frames at most), so
    the cached number is the one ``distance_to`` gives.
    """
    cache = {} if distances is None else distances
    used: set[tuple[TrackerId, TrackerId]] = set()

    def s_a(a: MergeView, b: MergeView) -> float:
        key, va, vb = (a.id, b.id), a.gallery.version, b.gallery.version
        used.add(key)
        hit = cache.get(key)
        if hit is not None and hit[0] == va and hit[1] == vb:
            return hit[2]
        got = a.gallery.distance_to(b.gallery)
        cache[key] = (va, vb, got)
        return got

    scored: list[tuple[float, MergeView, MergeView, bool]] = []
    two: list[float] = []  # gallery distances of nearby pairs seen as two people
    alive: set[tuple[TrackerId, TrackerId]] = set()
    ordered = sorted(views, key=lambda v: v.id)
    if len(ordered) > 1:
        xy = np.array([v.xy for v in ordered])
        dist = norms(xy[:, None] - xy[None], axis=2)
        idx = np.arange(len(ordered))
        rows, cols = ((dist < merge_reach(cfg)) & (idx[:, None] < idx)).nonzero()  # nearby pairs
        for i, j, d in zip(rows.tolist(), cols.tolist(), dist[rows, cols].tolist()):  # i < j alone
            a, b = ordered[i], ordered[j]
            s = s_a(a, b)
            if learn is not None and (a.seen_by & b.seen_by or a.measured_by & b.measured_by):
                two.append(s)
            scored_pair = pair_score(a, b, cfg, th, d, s)
            if scored_pair is None:
                continue
            s, at_once = scored_pair
            key = (a.id, b.id)
            e = max(evidence.get(key, 0.0) + comotion_llr(a, b, cfg), cfg.merge_llr_floor)
            evidence[key] = e
            if at_once or e >= 0.0:
                alive.add(key)
                scored.append((s, a, b, at_once or e >= cfg.merge_llr))
        far_apart(ordered, dist, evidence, cfg)
    if learn is not None and two:
        learn.learn(np.zeros(0), np.array(two))
    if len(cache) > 2 * len(used) + 64:  # bounded: the pairs that were near lately
        for key in [key for key in cache if key not in used]:
            del cache[key]
    # seen as two people: remembered while both live; parted (or gone): what spoke for one
    # target is forgotten
    evidence.settle({v.id for v in ordered}, alive)
    group: dict[TrackerId, list[MergeView]] = {}  # tracker -> its group (shared list)
    for s, a, b, ready in sorted(scored, key=lambda e: (e[0], e[1].id, e[2].id)):
        if not ready:
            continue
        ga, gb = group.get(a.id, [a]), group.get(b.id, [b])
        if ga is gb or not all((min(x.id, y.id), max(x.id, y.id)) in alive
                               for x in ga for y in gb):
            continue
        ga.extend(gb)
        for v in ga:
            group[v.id] = ga
        evidence.pop((a.id, b.id), None)
    merges: list[tuple[TrackerId, TrackerId]] = []
    done: set[int] = set()
    for g in group.values():
        if id(g) in done:
            continue
        done.add(id(g))
        winner = min(g, key=lambda v: v.rank)
        merges.extend((v.id, winner.id) for v in sorted(g, key=lambda v: v.id) if v is not winner)
    return sorted(merges, key=lambda m: (m[1], m[0]))


def reidentify(gallery: Gallery, old: Mapping[TrackerId, Gallery], cfg: ManagerSettings,
               k: int = 0, xy: np.ndarray | None = None,
               last: Mapping[TrackerId, tuple[int, np.ndarray]] | None = None,
               epsilon: float | None = None) -> TrackerId | None:
    """The old tracker whose gallery best matches ``gallery`` with ``s_a < epsilon`` (eq. 7;
    default ``cfg.epsilon``, a node's learned one from ``reidquality``),
    among those that could have walked from where they were dropped to ``xy``, where the new
    tracker is born at frame ``k`` (within ``reid_gate`` plus ``reid_speed`` times the time
    since; ours: with a real re-id's look-alikes, appearance alone handed a person entering late
    the dropped id of someone who had left elsewhere). Without ``xy`` or ``last``, appearance
    alone."""
    best: tuple[float, TrackerId] | None = None
    for tid, g in old.items():
        s = gallery.distance_to(g)
        if np.isnan(s) or s >= (cfg.epsilon if epsilon is None else epsilon):
            continue
        if xy is not None and last is not None and tid in last:
            frame, where = last[tid]
            reach = cfg.m(cfg.reid_gate) + cfg.m(cfg.reid_speed) * max(0, k - frame) * cfg.dt
            if float(np.linalg.norm(np.asarray(where) - xy)) > reach:
                continue
        if best is None or (s, tid) < best:
            best = (s, tid)
    return None if best is None else best[1]


def heir(lost: MergeView, ell: int, others: Sequence[MergeView], k: int,
         evidence: Mapping[tuple[TrackerId, TrackerId], float], cfg: ManagerSettings,
         veto: float | None = None) -> TrackerId | None:
    """The tracker that took over the target of ``lost``, dropped at frame ``k`` after nobody
    saw it for ``ell`` frames (eq. 8), or ``None`` (ours; tracklet stitching). A duplicate born
    beside a tracker while both were measured can take the person's measurements (they go to
    whichever tracker the association finds nearer), and the older tracker, unmeasured, is
    dropped: without this the person keeps the younger id, a second id for one person
    (terrace-full, no descriptors: person 1 tracked 2,320 frames as one id, then 909 as the
    duplicate born 33 frames before the first was dropped). The heir is the nearest tracker
    younger than ``lost`` that appeared on this node no earlier than ``ell + 2 kappa`` frames
    ago, within ``reid_gate`` plus ``reid_speed`` times the ``ell`` frames unseen of where
    ``lost`` was estimated last, that no camera ever saw beside it as a second person (the
    pair's co-motion ``evidence`` is not negative), and whose gallery, where both are known, is
    within ``veto`` (default ``merge_appearance``) of the lost one's. It takes the older id by a merge,
    announced like any other, so every node ends with the same id."""
    reach = cfg.m(cfg.reid_gate) + cfg.m(cfg.reid_speed) * ell * cfg.dt
    since = k - ell - 2 * cfg.kappa
    best: tuple[float, TrackerId] | None = None
    for v in others:
        if v.id == lost.id or v.since < since or v.rank <= lost.rank:
            continue
        if evidence.get((min(v.id, lost.id), max(v.id, lost.id)), 0.0) < 0.0:
            continue
        if v.gallery.unlike(lost.gallery, cfg.merge_appearance if veto is None else veto):
            continue  # looks like someone else
        d = float(np.linalg.norm(v.xy - lost.xy))
        if d < reach and (best is None or (d, v.id) < best):
            best = (d, v.id)
    return None if best is None else best[1]


def partner(lost: MergeView, others: Sequence[MergeView],
            evidence: Mapping[tuple[TrackerId, TrackerId], float]) -> TrackerId | None:
    """The younger tracker that was on its way to being merged into ``lost`` (positive co-motion
    evidence, :func:`find_merges`) when ``lost`` is dropped, or ``None``: the most evidence,
    ties to the smaller id (ours). The duplicate took the person's measurements before the
    merge was due and the older tracker, unmeasured, went; without this the person keeps the
    duplicate's id (terrace-full, no descriptors: 914 frames of one person)."""
    best: tuple[float, TrackerId] | None = None
    for v in others:
        if v.id == lost.id or v.rank <= lost.rank:
            continue
        e = evidence.get((min(v.id, lost.id), max(v.id, lost.id)), 0.0)
        if e > 0.0 and (best is None or (-e, v.id) < best):
            best = (-e, v.id)
    return None if best is None else best[1]


class DistributedTrackerManager:
    """The DTM of the paper's complete configuration (``dkf+lda+dtm``): drop by the ``ell``
    consensus (eq. 8), global association and merging of duplicate trackers, and
    re-identification of dropped trackers by their galleries."""

    keeps_galleries = True  # dropped trackers' galleries are kept for re-identification

    def __init__(self, cfg: ManagerSettings, quality: ReidQuality | None = None):
        self.cfg = cfg
        #: co-motion evidence per pair of trackers (:func:`find_merges`)
        self.evidence = PairEvidence()
        #: the nearby pairs' gallery distances, with the galleries' versions (:func:`find_merges`)
        self.distances: dict[tuple[TrackerId, TrackerId], tuple[int, int, float]] = {}
        #: the node's measured re-id, shared with its association (``reidquality``), or None
        self.quality = quality

    @property
    def thresholds(self) -> Thresholds:
        """The appearance thresholds this node decides with now."""
        return self.quality.thresholds if self.quality is not None else Thresholds.of(self.cfg)

    def ell(self, own: int, received: Sequence[int]) -> int:
        return ell_consensus(own, received)

    def ells(self, own: Sequence[int], rows: np.ndarray, received: np.ndarray) -> np.ndarray:
        """``ell`` of every tracker at once (:func:`ell_consensus_many`)."""
        return ell_consensus_many(own, rows, received)

    def merges(self, views: Sequence[MergeView]) -> list[tuple[TrackerId, TrackerId]]:
        return find_merges(views, self.evidence, self.cfg, self.thresholds, self.quality,
                           self.distances)

    def pending(self, born: Mapping[TrackerId, int]) -> list[tuple[TrackerId, TrackerId]]:
        """Pairs ``(younger, older)`` on their way to being merged: every pair agreeing towards
        a merge (:func:`find_merges`' evidence for one target; ``born`` maps the trackers this
        node holds to their birth frames), in a deterministic order. The younger is most likely a duplicate
        of the older, and if it is, it is merged into it within ``comotion_frames``: reporting
        it meanwhile shows a second id for one person (a fragment and, once merged, a switch
        back)."""
        out = []
        for (a, b), e in self.evidence.positive():
            if a in born and b in born:
                old, young = sorted((a, b), key=lambda t: rank(born[t], t))
                out.append((young, old))
        return out

    def forget(self, tid: TrackerId) -> None:
        """``tid`` is gone (merged or dropped): forget the co-motion evidence of its pairs, so
        that the table holds pairs of trackers the node holds, never more."""
        self.evidence.forget(tid)
        for key in [key for key in self.distances if tid in key]:
            del self.distances[key]

    def two_people(self, pairs: Sequence[tuple[TrackerId, TrackerId]]) -> np.ndarray:
        """Which ``pairs`` of trackers the node knows for two people: their co-motion evidence
        is below zero (:meth:`PairEvidence.apart`); a pair it has no evidence of may be one
        person held twice (each camera's own view, ``views.OwnViews``)."""
        return self.evidence.apart(pairs)

    def may_adopt(self, tid: TrackerId, dropped: Collection[TrackerId]) -> bool:
        return True

    def heir(self, lost: MergeView, ell: int, others: Sequence[MergeView], k: int
             ) -> TrackerId | None:
        """The tracker that takes ``lost``'s id as it is dropped: with ``stitch`` the one that
        took over its target (:func:`heir`), else with ``heir_pending`` the one on its way to
        merging into it (:func:`partner`)."""
        if self.cfg.stitch:
            return heir(lost, ell, others, k, self.evidence, self.cfg, self.thresholds.veto)
        return partner(lost, others, self.evidence) if self.cfg.heir_pending else None

    def reappearances(self, young: Sequence[Young], gone: Sequence[Gone], k: int
                      ) -> list[tuple[TrackerId, TrackerId]]:
        """New trackers that go on where dropped ones were heading, ``(new, dropped)``
        (:func:`edge_node.core.reappear.reappearances`; none unless ``reappear``)."""
        if not self.cfg.reappear:
            return []
        return reappearances(young, gone, k, self.cfg, self.thresholds.veto)

    def awaiting(self, young: Young, gone: Sequence[Gone], k: int) -> bool:
        """Whether ``young`` may still be linked to a dropped tracker (:func:`awaiting`)."""
        return self.cfg.reappear and awaiting(young, gone, k, self.cfg, self.thresholds.veto)

    def reidentify(self, gallery: Gallery, old: Mapping[TrackerId, Gallery],
                   k: int = 0, xy: np.ndarray | None = None,
                   last: Mapping[TrackerId, tuple[int, np.ndarray]] | None = None
                   ) -> TrackerId | None:
        """A dropped tracker that a new local tracker is (paper III-C): by appearance when the
        new tracker has a gallery; without appearance (our addition), the one dropped at most
        ``reid_frames`` ago nearest to where it is born, within ``reid_gate``."""
        if not old:
            return None
        if len(gallery):
            return reidentify(gallery, old, self.cfg, k, xy, last, self.thresholds.epsilon)
        if xy is None or not last:
            return None
        best = None
        for tid, (frame, where) in last.items():
            if tid not in old or len(old[tid]) or k - frame > self.cfg.reid_frames:
                continue
            d = float(np.linalg.norm(where - xy))
            if d < self.cfg.m(self.cfg.reid_gate) and (best is None or (d, tid) < best):
                best = (d, tid)
        return None if best is None else best[1]


class IndependentTrackers:
    """No DTM (the paper's ``dkf`` and ``dkf+lda``): every camera drops on its own counter, a
    dropped id stays dropped, nothing is merged or re-identified."""

    keeps_galleries = False

    def __init__(self, cfg: ManagerSettings):
        self.cfg = cfg

    def ell(self, own: int, received: Sequence[int]) -> int:
        return own

    def ells(self, own: Sequence[int], rows: np.ndarray, received: np.ndarray) -> np.ndarray:
        return np.array(own, np.int64)

    def merges(self, views: Sequence[MergeView]) -> list[tuple[TrackerId, TrackerId]]:
        return []

    def pending(self, born: Mapping[TrackerId, int]) -> list[tuple[TrackerId, TrackerId]]:
        return []  # nothing is ever merged

    def forget(self, tid: TrackerId) -> None:
        pass

    def two_people(self, pairs: Sequence[tuple[TrackerId, TrackerId]]) -> np.ndarray:
        """Every pair: nothing is ever merged, so each tracker is its own target."""
        return np.ones(len(pairs), bool)

    def may_adopt(self, tid: TrackerId, dropped: Collection[TrackerId]) -> bool:
        return tid not in dropped  # a camera's drop decision is its own and final

    def heir(self, lost: MergeView, ell: int, others: Sequence[MergeView], k: int
             ) -> TrackerId | None:
        return None  # nothing is ever merged

    def reappearances(self, young: Sequence[Young], gone: Sequence[Gone], k: int
                      ) -> list[tuple[TrackerId, TrackerId]]:
        return []  # a dropped id stays dropped

    def awaiting(self, young: Young, gone: Sequence[Gone], k: int) -> bool:
        return False

    def reidentify(self, gallery: Gallery, old: Mapping[TrackerId, Gallery],
                   k: int = 0, xy: np.ndarray | None = None,
                   last: Mapping[TrackerId, tuple[int, np.ndarray]] | None = None
                   ) -> TrackerId | None:
        return None
