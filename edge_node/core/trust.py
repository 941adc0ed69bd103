"""The trust role: which neighbours a node believes (a defence against plausible but wrong
peers; the paper assumes honest, working neighbours).

**Fault model.** At most ``trust_f`` neighbours of a node are faulty (F-local; default 1), and a
faulty neighbour may send any values the wire's schema allows, with a valid certificate. The
screen (``screen``) refuses what cannot be true; this role judges what is plausible but
inconsistent.

**Detection, per neighbour.** Every frame, each entry of a neighbour's message about a tracker
this node holds is compared with this node's own prediction ``x_bar, P`` (before the update,
so the neighbour's own information is not in it): a measured entry by its normalised innovation
``e^T (V + P + C)^-1 e`` (``z = U^-1 u`` the neighbour's measurement of the ground position,
``V`` its covariance, the position block; ``C``: ``calib_sigma``, what cameras honestly disagree
by even with their registration), an entry without a measurement by ``d^T (2 P + C)^-1 d`` on
its prediction ``x_bar_j``. A frame's
score of a neighbour is the median of its entries' (bounded at ``trust_cap``), robust to the few
honest entries a wrong association or a crossing puts far off. A one-sided CUSUM (Page 1954)
adds up ``score - allowance`` and never goes below zero; the allowance is ``trust_drift`` or,
when the other neighbours are inconsistent too (cameras that honestly disagree before their
registration converges, or where it cannot agree, as on EPFL Campus), ``trust_ratio`` times
their median score (a neighbour not heard this frame counts with its usual, smoothed score):
a faulty neighbour is the one that stands out. States: ``trusted``; ``suspect`` once the sum passes ``trust_suspect``;
``quarantined`` once it passes ``trust_quarantine``. A neighbour is trusted again after
``trust_readmit`` frames in a row whose score was within the allowance (the sum back at zero).

**Lag.** A neighbour that re-sends old frames as new (a box whose frames lag; ``stale`` in
``edge_node/forgery.py``) sends real measurements, each consistent with a person where he was
``tau`` seconds ago: its innovations ``e = z - x_bar`` lag the node's estimate by ``v tau``
(``v`` the node's velocity estimate), which the test above reads as a poor registration.
Per neighbour, the lag is estimated by least squares over its measured entries of settled
trackers (held ``comotion_frames``; ``z`` from the whole box's information, ``U^-1 u`` on
``(x, y, w, h)``) and over the frames, forgotten by ``1 - 1/trust_lag_frames``:
``e = b - tau v`` with an offset ``b`` (its registration), weighted by ``S^-1``, each ``e``
first brought to the message's own frame (``+ v (k - k_msg) dt``: a late message is not a
lagging one). Only ``tau`` is kept (``b`` eliminated); its variance is scaled by the fit's
residual ``chi^2`` per degree of freedom when above 1 (entries the model does not explain make
the lag uncertain, not significant). The same regression on the node's own cameras'
measurements gives the reference: a stale neighbour's information pulls the node's estimates
back, so its own cameras, and its honest neighbours, appear ahead by as much; the neighbour's
lag is taken against its own cameras' (against 0 when they tell no lag). The lag's excess
over ``trust_lag`` in standard errors, ``z = (tau_j - tau_own - trust_lag) / sqrt(var_j +
var_own)``, feeds a second one-sided CUSUM per neighbour, ``max(0, sum + z - trust_lag_z)``,
bounded at twice ``trust_quarantine``; the neighbour is suspect or quarantined when either sum
passes the thresholds, and is not calm in a frame its ``z`` passes ``trust_lag_z``. Fresh
again, its lag's sum falls by several a frame once the estimate has forgotten the old frames,
and it is trusted again after ``trust_readmit`` calm frames. The lag needs people walking in
different directions (a lag and an offset are the same thing when everyone walks alike) and
is blind to a box that lags while nobody moves.

**Refuted.** A neighbour whose detector sees people who are not there (rain, reflections, a
hallucinating network; ``hallucinate`` in ``edge_node/forgery.py``) sends measurements that
agree with its own trackers and with nothing else: where nobody else looks no test above sees
them. Where this node's own cameras look they are refuted: the node's negative evidence
(``views.OwnViews.expect``) counts the frames in
a row its cameras should have measured a tracker and did not, and past ``unseen_limit()`` (its
cameras have not missed a real person that long lately) the tracker is not there. Each entry
of this frame in which a neighbour claims to measure such a tracker (``U`` not zero) is refuted;
a third one-sided CUSUM per neighbour adds ``trust_refuted`` times (its refuted entries less
``trust_refuted_allow``) a frame, bounded at twice ``trust_quarantine``, against the same
thresholds (reason ``refuted``), which only quarantines (never makes a neighbour suspect). An
honest camera's claims are refuted too, one at a time: a person it sees that this node's
cameras cannot, behind something the tracker does not know of (a pillar), for as long as he
stays there, or a person one EPFL camera annotates and another does not box; with the
allowance at one entry a frame such a person adds nothing however long he stays. A
hallucinating detector's come several at once, for as long as it hallucinates. What it cannot
tell: one invented person at a time is an honest camera's pattern, and two or more real people
behind an unknown occluder at once are a hallucination's (each frame they stay adds to the
sum). A quarantined neighbour's trackers are not adopted (or, held before, are dropped once
nothing else supports them), so a distrusted sender's claims of trackers this node does not
hold are judged on their own (``_judge_unheld``; a trusted sender's new trackers are adopted and
counted by ``state.unseen`` from the next frame): the sender's state of the tracker
inside one of the node's cameras' views (``views.OwnViews.expected``, the node's own targets as
occluders) and no target the node measures this frame within ``tau_gda``, counted per sender
and tracker like ``state.unseen``; without that, nothing was left to refute once the
invented people were dropped, and the neighbour was re-admitted, its invented people adopted
again, 75 frames later, while it still hallucinated. A neighbour quarantined for it is not
calm while its refuted sum is above zero: it is trusted again ``trust_readmit`` frames after
the sum drained. (Distrusted for another reason, its calm is as before: an honest network
whose neighbour is suspect a while runs exactly as without this test.) A neighbour relaying a
tracker it does not measure claims nothing and is not refuted.

**Merges.** A merge a neighbour announces is a claim that two trackers are one person. It is
refused from anyone (``far_merge``) when this node's own cameras measure both trackers in this
frame, farther apart than twice the merge rules' reach, and it has held both for
``comotion_frames``: its own eyes see two people where the claim says one, and a forged merge
would hand one person's id to another. Each such pair adds ``trust_merge`` to its sender's sum
once. A merge of two settled trackers that are that far apart only in this node's estimates is
weaker evidence (honest networks announce such merges: on ring8-sim with late messages, pairs
3-4 m apart in the estimates of nodes two hops from where they were decided, where consensus
lags): it is applied from a trusted sender and adds ``trust_apart`` once per pair, so a node
announcing merges of many people apart is suspect (and its merges dropped) in the frame it does.
A sender is not calm (nor re-admitted) in a frame it announces a disputed merge, old or new.
Merges of pairs the co-motion evidence calls two people are not held against a sender: on
ring8-sim with late messages honest nodes announced pairs 0.3-0.8 m apart with the evidence at
its floor at every node (counting them quarantined honest nodes), and refusing them from trusted
neighbours cost 0.003 IDF1 on terrace-sim.

**What it costs a neighbour.** A quarantined neighbour's messages are still taken and counted,
but their entries are not used: no measurement information (eq. 3), no consensus term (eq. 4),
no ``ell`` (eq. 8), no adoption, no merge. A suspect neighbour's entries that fail the gate on
their own (``trust_gate``) are dropped, the others used as they are, and it may not add
trackers (its unknown ids are not adopted) or merge any. When no neighbour is suspect the
node's tracks are exactly those without this role.

**Why the honest consensus still converges.** Dropping a neighbour's entries removes its
edges from the frame's graph: eq. 4's step keeps its bound per node with the remaining degree
(``dkf``, "Stability of the consensus step"), so the honest nodes' iteration is the same
contraction on the honest subgraph. With F faulty neighbours per node and an honest subgraph
that stays connected (a ring of four with one faulty node leaves a chain of three), the honest
estimates agree again; what the faulty node can still do is withhold its own camera's view.
This is the W-MSR argument of LeBlanc, Zhang, Koutsoukos and Sundaram (IEEE JSAC 2013) with
the trimming decided by consistency over time rather than per value per frame, and the
sequential-test view of secure distributed estimation of Mitra and Sundaram (Automatica 2019):
a faulty neighbour is cut once its evidence is strong, never on one frame's outlier.

Counted per neighbour (``NodeStats.trust``): its state, the frames it spent suspect and
quarantined, the first frame it was quarantined, why it was last distrusted (``inconsistent``,
``lagging``, ``merges``, ``refuted``), its latest lag (s) and the frames its lag stood out, its
entries refuted and the largest its refuted sum reached. Pure and deterministic.
"""
from __future__ import annotations

import math
from collections import Counter, deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from itertools import chain
from statistics import median
from typing import Any

import numpy as np

from edge_node.core.config import Slice
from edge_node.core.state import NodeState
from protocol.messages import FrameMessage, TrackerId

TRUSTED, SUSPECT, QUARANTINED = "trusted", "suspect", "quarantined"
FAR = "far_merge"  # a merge of trackers this node's cameras measure apart: refused
APART = "apart"  # a merge of trackers apart in this node's estimates only: weak evidence
LEVEL_RATE = 0.05  # smoothing of a neighbour's usual score (about a second at 25 fps)
INCONSISTENT, LAGGING, MERGES, REFUTED = "inconsistent", "lagging", "merges", "refuted"  # why
_EYE = np.eye(4)  # in place of a 4 x 4 information matrix without an inverse


@dataclass(frozen=True)
class TrustSettings(Slice):
    """What the trust role reads; each parameter's rule and doc is in its section of
    ``config.TrackerConfig``."""

    trust_check: bool
    trust_drift: float
    trust_ratio: float
    trust_cap: float
    trust_merge: float
    trust_apart: float
    trust_gate: float
    trust_suspect: float
    trust_quarantine: float
    trust_readmit: int
    trust_lag: float
    trust_lag_z: float
    trust_lag_frames: int
    trust_refuted: float
    trust_refuted_allow: float
    calib_sigma: float
    comotion_gate: float
    comotion_frames: int
    tau_gda: float
    units_per_metre: float
    fps: float


@dataclass
class NeighbourTrust:
    """What a node thinks of one neighbour."""

    state: str = TRUSTED
    cusum: float = 0.0
    lag_sum: float = 0.0  # the lag's CUSUM (module docstring, "Lag")
    refuted_sum: float = 0.0  # the refuted claims' CUSUM (module docstring, "Refuted")
    refuted: int = 0  # its entries refuted by this node's cameras, over the run
    refuted_peak: float = 0.0  # the largest its refuted sum reached
    calm: int = 0  # frames in a row within the allowance
    suspect_frames: int = 0
    quarantined_frames: int = 0
    first_quarantine: int | None = None
    changes: list[tuple[int, str]] = field(default_factory=list)  # (frame, new state)
    disputed: deque = field(default_factory=lambda: deque(maxlen=256))  # pairs disputed, latest
    reason: str | None = None  # why it was last distrusted: inconsistent, lagging, merges, refuted
    lag: float = 0.0  # s, its latest lag estimate tau (module docstring, "Lag")
    lagging_frames: int = 0  # frames its lag stood out (added to its sum)
    N: list[float] = field(default_factory=lambda: [0.0] * 6)  # the lag's normal equations
    r: list[float] = field(default_factory=lambda: [0.0] * 5)  # (forgetting sums)

    def summary(self) -> dict:
        return {"state": self.state, "suspect_frames": self.suspect_frames,
                "quarantined_frames": self.quarantined_frames,
                "first_quarantine": self.first_quarantine, "changes": len(self.changes),
                "reason": self.reason, "lag_s": round(self.lag, 3),
                "lagging_frames": self.lagging_frames, "refuted": self.refuted,
                "refuted_peak": round(self.refuted_peak, 1)}


class Trust:
    """The trust role of a node with ``neighbours`` (module docstring)."""

    def __init__(self, settings: TrustSettings, neighbours: Sequence[int],
                 rejected: Counter | None = None,
                 views: Any = None):
        self.cfg = settings
        # the node's negative evidence (views.OwnViews: unseen_limit, expected), None: none
        has = hasattr(views, "unseen_limit") and hasattr(views, "expected")
        self.views = views if has else None
        # per sender and tracker it claims that this node does not hold: [frames in a row
        # this node's cameras should have measured it and did not, the frame last claimed]
        self._unheld: dict[tuple[int, TrackerId], list[int]] = {}
        self._refuted: Counter = Counter()  # per sender, this frame's refuted entries
        self.rejected = Counter() if rejected is None else rejected  # the screen's counter
        self.of: dict[int, NeighbourTrust] = {n: NeighbourTrust() for n in neighbours}
        self.scores: dict[int, float] = {}  # the last frame's score of each neighbour heard
        self.level: dict[int, float] = {}  # each neighbour's usual score (smoothed)
        self._lag_sums: dict[int, list[float]] = {}  # per sender, this frame's lag terms
        self._own_sums = [0.0] * 11  # this frame's lag terms of the own cameras
        self.own_N, self.own_r = [0.0] * 6, [0.0] * 5  # the own cameras' lag (reference)
        self.own_lag = 0.0  # s

    def __call__(self, state: NodeState, msgs: list[FrameMessage], k: int,
                 resolve: Callable[[TrackerId], TrackerId]) -> list[FrameMessage]:
        """Judge frame ``k``'s (screened) messages against this node's predictions, update
        every neighbour's trust, and return the messages as they may be used."""
        if not self.cfg.trust_check or not self.of:
            return msgs
        self.scores = {}
        disputed = Counter()  # per sender, its merges this node disputes
        novel = Counter()  # of those, what the pairs disputed for the first time weigh
        verdicts: list[list[str | None]] = []  # per message, why each of its merges is disputed
        for m in msgs:
            t = self.of.get(m.sender)
            verdicts.append([])
            for mg in m.merges:
                a, b = resolve(mg.loser), resolve(mg.winner)
                why = None if t is None else self._implausible_merge(state, k, a, b)
                verdicts[-1].append(why)
                if why is None:
                    continue
                disputed[m.sender] += 1
                pair = (min(a, b), max(a, b))
                if pair not in t.disputed:
                    t.disputed.append(pair)
                    novel[m.sender] += (self.cfg.trust_apart if why == APART
                                        else self.cfg.trust_merge)
        self._lag_sums = {}
        entries = self._statistics(state, msgs, resolve, k)  # a sender may send several
        cap = self.cfg.trust_cap  # (late ones, async): its score is the worst
        for m, (rows, stat) in zip(msgs, entries):
            if stat:
                s = median([min(v, cap) for v in stat])
                self.scores[m.sender] = max(s, self.scores.get(m.sender, 0.0))
        for n, s in self.scores.items():
            lv = self.level.get(n)
            self.level[n] = s if lv is None else lv + LEVEL_RATE * (s - lv)
        lagging = self._lagging()
        w, allow = self.cfg.trust_refuted, self.cfg.trust_refuted_allow
        for n, t in sorted(self.of.items()):
            refuted = self._refuted[n]
            t.refuted += refuted
            if w:  # bounded like the lag's: its claims no longer refuted, trusted again
                t.refuted_sum = min(2.0 * self.cfg.trust_quarantine,
                                    max(0.0, t.refuted_sum + w * (refuted - allow)))
                t.refuted_peak = max(t.refuted_peak, t.refuted_sum)
            draining = t.reason == REFUTED and t.refuted_sum > 0.0  # not calm until drained
            if n in self.scores:
                # the others' scores this frame, or their usual level when not heard (a lost or
                # late message must not leave a neighbour alone against the bare drift)
                others = [self.scores.get(j, lv) for j, lv in self.level.items() if j != n]
                allowance = max(self.cfg.trust_drift,
                                self.cfg.trust_ratio * median(others) if others else 0.0)
                step = self.scores[n] - allowance
                t.cusum = max(0.0, t.cusum + step) + novel[n]
                dz = lagging.get(n, 0.0)  # the lag's own CUSUM, bounded: fresh again, trusted
                t.lag_sum = min(2.0 * self.cfg.trust_quarantine, max(0.0, t.lag_sum + dz))
                t.calm = (t.calm + 1 if step <= 0.0 and dz <= 0.0 and not disputed[n]
                          and not draining else 0)
            elif disputed[n] or draining:
                t.cusum += novel[n]
                t.calm = 0
            why = (MERGES if novel[n] else REFUTED if t.refuted_sum > max(t.cusum, t.lag_sum)
                   else LAGGING if t.lag_sum > t.cusum else INCONSISTENT)
            self._transition(n, t, k, why)
        return [self._used(m, e, v) for m, e, v in zip(msgs, entries, verdicts)]

    def _implausible_merge(self, state: NodeState, k: int, a: TrackerId, b: TrackerId) -> str | None:
        """Why this node disputes a merge of ``a`` and ``b`` (module docstring), or None."""
        if a == b or a not in state or b not in state:
            return None
        i, j = state.row(a), state.row(b)
        settled = k - self.cfg.comotion_frames
        if state.since[i] > settled or state.since[j] > settled:
            return None  # just born here: cameras may still disagree (registration)
        reach = 2.0 * self.cfg.m(max(self.cfg.comotion_gate, self.cfg.tau_gda))
        if state.U[i, 0, 0] > 0.0 and state.U[j, 0, 0] > 0.0:  # both seen by its cameras now
            with np.errstate(all="ignore"):
                zi, zj = (np.linalg.lstsq(state.U[r, :4, :4], state.u[r, :4], rcond=None)[0][:2]
                          for r in (i, j))
            if float(np.hypot(*(zi - zj))) > reach:
                return FAR
        if float(np.hypot(*(state.x_bar[i, :2] - state.x_bar[j, :2]))) > reach:
            return APART
        return None

    def _statistics(self, state: NodeState, msgs: list[FrameMessage],
                    resolve: Callable[[TrackerId], TrackerId],
                    k: int) -> list[tuple[np.ndarray, list]]:
        """Per message: its rows naming a tracker this node holds, and each one's normalised
        distance from this node's prediction (module docstring); per sender, this frame's terms
        of its lag's normal equations (``_lag_sums``), and the own cameras' (``_own_sums``).
        Every message's entries in one batch, the 2 x 2 inverses written out: a fixed number of
        array operations a frame, whatever the number of neighbours and messages."""
        which, rows, held, U, u, xj, unheld = _entries(state, msgs, resolve)
        bounds = np.searchsorted(which, np.arange(len(msgs) + 1)).tolist()  # message i's
        # entries: bounds[i]:bounds[i + 1]
        P = state.P.take(held, axis=0)[:, :2, :2]
        x = state.x_bar.take(held, axis=0)
        c2 = self.cfg.m(self.cfg.calib_sigma) ** 2
        a, b, d = U[:, 0, 0], 0.5 * (U[:, 0, 1] + U[:, 1, 0]), U[:, 1, 1]
        det = a * d - b * b
        measured = det > 1e-12 * np.maximum(a + d, 1e-300) ** 2
        with np.errstate(all="ignore"):
            # measured: V = U^-1, z = V u, e = z - x, S = V + P + C
            va, vb, vd = d / det, -b / det, a / det
            z1, z2 = va * u[:, 0] + vb * u[:, 1], vb * u[:, 0] + vd * u[:, 1]
            e1 = np.where(measured, z1 - x[:, 0], xj[:, 0] - x[:, 0])  # without: x_bar_j - x
            e2 = np.where(measured, z2 - x[:, 1], xj[:, 1] - x[:, 1])
            w = np.where(measured, 1.0, 2.0)  # S = 2 P + C without a measurement
            s11 = np.where(measured, va, 0.0) + w * P[:, 0, 0] + c2
            s12 = np.where(measured, vb, 0.0) + w * 0.5 * (P[:, 0, 1] + P[:, 1, 0])
            s22 = np.where(measured, vd, 0.0) + w * P[:, 1, 1] + c2
            stat = (s22 * e1 ** 2 - 2.0 * s12 * e1 * e2 + s11 * e2 ** 2) / (s11 * s22 - s12 * s12)
        stat = np.where(np.isfinite(stat), stat, self.cfg.trust_cap)
        self._count_refuted(state, msgs, resolve, k, which, held, measured, unheld)
        self._lag_terms(state, k, msgs, which, bounds, held, U, u, stat < self.cfg.trust_cap)
        stat = stat.tolist()
        return [(rows[i:j], stat[i:j]) for i, j in zip(bounds, bounds[1:])]

    def _count_refuted(self, state: NodeState, msgs: list[FrameMessage],
                       resolve: Callable[[TrackerId], TrackerId], k: int, which: np.ndarray,
                       held: np.ndarray, measured: np.ndarray, unheld: tuple) -> None:
        """Per sender, its entries of this frame that claim a measurement of a tracker this
        node's own cameras should have measured and have not, ``unseen_limit()`` frames in a row
        (``_refuted``; module docstring, "Refuted"); a sender of several messages (late ones)
        counts with its largest. A tracker this node holds by its own count
        (``state.unseen``); one it does not (a quarantined or suspect sender's, not adopted) by
        a count per sender and tracker (:meth:`_judge_unheld`)."""
        self._refuted = Counter()
        limit = self.views.unseen_limit() if self.views is not None else 0
        if not limit or not self.cfg.trust_refuted:
            return
        per = np.bincount(which, weights=measured & (state.unseen[held] >= limit),
                          minlength=len(msgs)).tolist()
        refuted = self._judge_unheld(state, msgs, resolve, k, limit, *unheld)
        for m, c, d in zip(msgs, per, refuted):
            if c + d:
                self._refuted[m.sender] = max(self._refuted[m.sender], int(c + d))

    def _judge_unheld(self, state: NodeState, msgs: list[FrameMessage],
                      resolve: Callable[[TrackerId], TrackerId], k: int, limit: int,
                      which: np.ndarray, pos: np.ndarray, ids: list[TrackerId],
                      x: np.ndarray) -> list[int]:
        """Per message of a sender this node distrusts (whose new trackers it does not adopt;
        a trusted one's are adopted this frame and counted by ``state.unseen`` from the next),
        its measured entries of trackers this node does not hold (entry ``i``: message
        ``which[i]``, at ``pos[i]`` among all the messages' rows, whose ids are ``ids`` and
        states ``x``; the ids and states taken only when some sender is distrusted) that are
        refuted: their state (the sender's ``x_bar``) is where one of this node's cameras should
        measure them (``views.expected``, this node's targets as occluders) and no target this
        node's cameras measure this frame is within ``tau_gda``, ``limit`` frames in a row (a
        frame it cannot see keeps the count, one it measures a target there starts it again).
        Counts of claims not heard for ``trust_readmit`` frames are forgotten."""
        out = [0] * len(msgs)
        runs = self._unheld
        distrusted = [m.sender in self.of and self.of[m.sender].state != TRUSTED for m in msgs]
        pick = np.array(distrusted)[which].nonzero()[0] if any(distrusted) else ()
        if len(pick):
            which, pos = which[pick], pos[pick]
            x = x.take(pos, axis=0)
            keys = [(msgs[i].sender, resolve(ids[r]))
                    for i, r in zip(which.tolist(), pos.tolist())]
            n = len(state)
            expected = self.views.expected(np.concatenate([state.x_bar, x]), n)[n:]
            own = state.x_bar[(state.raw >= 0).any(axis=1), :2]
            gate = self.cfg.m(self.cfg.tau_gda)
            d = x[:, None, :2] - own[None]  # each claim against each target measured now
            near = (np.hypot(d[..., 0], d[..., 1]) < gate).any(axis=1)
            for i, key, e, nr in zip(which.tolist(), keys, expected.tolist(), near.tolist()):
                run = runs.setdefault(key, [0, k - 1])
                if run[1] != k:  # once a frame, whatever the sender's messages
                    run[0] = 0 if nr else run[0] + int(e)
                    run[1] = k
                out[i] += run[0] >= limit
        stale = k - self.cfg.trust_readmit
        for key in [key for key, run in runs.items() if run[1] < stale]:
            del runs[key]
        return out

    def _lag_terms(self, state: NodeState, k: int, msgs: list[FrameMessage], which: np.ndarray,
                   bounds: list[int], held: np.ndarray, U: np.ndarray, u: np.ndarray,
                   ok: np.ndarray) -> None:
        """This frame's terms of each sender's lag regression (module docstring, "Lag"): per
        measured entry of a settled tracker (``ok``: not capped), the innovation of its
        measurement brought to the message's own frame (entries ``bounds[i]:bounds[i + 1]`` of
        message ``i``, ``which`` each entry's); summed per message, then per sender. With them,
        in the same batch, the terms of the node's own cameras' measurements (``u, U`` of this
        frame), the reference every neighbour's lag is taken against (``_own_sums``)."""
        n = len(state)
        lag = np.array([(k - m.frame) * self.cfg.dt for m in msgs])[which]
        terms = self._measured(state, k, np.concatenate([np.arange(n), held]),
                               np.concatenate([state.U[:, :4, :4], U[:, :4, :4]]),
                               np.concatenate([state.u[:, :4], u[:, :4]]),
                               np.concatenate([np.zeros(n), lag]),
                               np.concatenate([np.ones(n, bool), ok]))
        self._own_sums = terms[:n].sum(axis=0).tolist()
        heard = [i for i, j in enumerate(bounds[1:]) if j > bounds[i]]  # messages with entries
        if not heard:
            return
        sums = np.add.reduceat(terms[n:], [bounds[i] for i in heard], axis=0).tolist()
        for i, t in zip(heard, sums):  # a few numbers a sender: Python's floats, not NumPy's
            s = msgs[i].sender
            self._lag_sums[s] = t if s not in self._lag_sums else _add(self._lag_sums[s], t)

    def _measured(self, state: NodeState, k: int, held: np.ndarray, U: np.ndarray,
                  u: np.ndarray, lag: np.ndarray, ok: np.ndarray) -> np.ndarray:
        """Per measurement ``u, U`` (eq. 2, on ``(x, y, w, h)``) of tracker row ``held`` made
        ``lag`` s before this frame: its terms of the lag's normal equations (``_terms``),
        the innovation ``e = z - x_bar + lag v`` of its ground position ``z = U^-1 u``
        (the whole box: a camera couples position and size) against the node's estimate at that
        time, ``S = V + P + C``; only settled trackers (``comotion_frames``) and ``ok``."""
        ok = ok & (U[:, 0, 0] > 0.0) & (state.since[held] <= k - self.cfg.comotion_frames)
        out = np.zeros((len(held), 11))
        if not ok.any():
            return out
        held, lag, U = held[ok], lag[ok], U[ok]
        with np.errstate(all="ignore"):
            det = np.linalg.det(U)
            good = np.isfinite(det) & (det > 0.0)
            U[~good] = _EYE  # no inverse: I in its place, its terms dropped (good)
            V = np.linalg.inv(U)
            z = np.einsum("nij,nj->ni", V, u[ok])[:, :2]
            x = state.x_bar.take(held, axis=0)
            v = x[:, 4:6]
            e = z - x[:, :2] + v * lag[:, None]
            P = state.P.take(held, axis=0)[:, :2, :2]
            c2 = self.cfg.m(self.cfg.calib_sigma) ** 2
            s11 = V[:, 0, 0] + P[:, 0, 0] + c2
            s12 = 0.5 * (V[:, 0, 1] + V[:, 1, 0] + P[:, 0, 1] + P[:, 1, 0])
            s22 = V[:, 1, 1] + P[:, 1, 1] + c2
            out[ok] = _terms(e, v, s11, s12, s22, good)
        return out

    def _lagging(self) -> dict[int, float]:
        """Per neighbour heard this frame, its lag's evidence (module docstring, "Lag"): its
        normal equations forgotten by ``1 - 1/trust_lag_frames`` and added this frame's terms,
        its lag ``tau`` and variance solved (the offset ``b`` eliminated), taken against the
        own cameras' lag; the step of its lag's CUSUM: ``z - trust_lag_z``, ``z`` its lag's
        excess over ``trust_lag`` in standard errors (bounded at ``trust_cap``). A neighbour
        whose velocities tell no lag gets no step."""
        keep = 1.0 - 1.0 / self.cfg.trust_lag_frames
        own = self._own_sums
        self.own_N = _add([keep * a for a in self.own_N], own[:6])
        self.own_r = _add([keep * a for a in self.own_r], own[6:])
        ref, ref_var = lag_estimate(self.own_N, self.own_r)
        if not math.isfinite(ref_var):  # its cameras tell no lag: the estimates are the reference
            ref, ref_var = 0.0, 0.0
        self.own_lag = ref
        out = {}
        for n, sums in self._lag_sums.items():
            t = self.of.get(n)
            if t is None:
                continue
            t.N = _add([keep * a for a in t.N], sums[:6])
            t.r = _add([keep * a for a in t.r], sums[6:])
            tau, var = lag_estimate(t.N, t.r)
            t.lag = tau - ref
            if not math.isfinite(var):
                continue
            z = (t.lag - self.cfg.trust_lag) / math.sqrt(var + ref_var)
            out[n] = min(self.cfg.trust_cap, z) - self.cfg.trust_lag_z
            t.lagging_frames += int(out[n] > 0.0)
        return out

    def _transition(self, n: int, t: NeighbourTrust, k: int, why: str) -> None:
        cfg = self.cfg
        new = t.state
        total = max(t.cusum, t.lag_sum)  # either test; the refuted sum only quarantines
        if max(total, t.refuted_sum) >= cfg.trust_quarantine:
            new = QUARANTINED
        elif t.state == TRUSTED and total >= cfg.trust_suspect:
            new = SUSPECT
        elif t.state != TRUSTED and t.calm >= cfg.trust_readmit:
            new = TRUSTED
            t.cusum = t.lag_sum = 0.0
        if new != t.state:
            t.state = new
            if new != TRUSTED:
                t.reason = why
            t.changes.append((k, new))
            if len(t.changes) > 64:  # bounded: the latest changes
                del t.changes[0]
            if new == QUARANTINED and t.first_quarantine is None:
                t.first_quarantine = k
        t.suspect_frames += t.state == SUSPECT
        t.quarantined_frames += t.state == QUARANTINED

    def _used(self, m: FrameMessage, entries: tuple[np.ndarray, list],
              verdicts: list[str | None]) -> FrameMessage:
        """``m`` as the node may use it: without the merges its own cameras refute
        (``verdicts``, one per merge); a quarantined sender's without entries or merges, a
        suspect sender's without merges and with only the entries about trackers this node
        holds that pass the gate alone (``entries``: their rows and statistics)."""
        t = self.of.get(m.sender)
        if t is None or t.state == TRUSTED:
            refused = sum(why == FAR for why in verdicts)
            if not refused:
                return m
            self.rejected[FAR] += refused
            return replace(m, merges=tuple(mg for mg, why in zip(m.merges, verdicts)
                                           if why != FAR))
        if t.state == QUARANTINED:
            return replace(m, block=m.block.take([]), merges=())
        rows, stat = entries  # held trackers' entries that pass alone
        keep = rows[np.asarray(stat, float) <= self.cfg.trust_gate]
        return replace(m, block=m.block.take(keep.tolist()), merges=())

    def summary(self) -> dict[int, dict]:
        return {n: t.summary() for n, t in sorted(self.of.items())}


def _entries(state: NodeState, msgs: list[FrameMessage],
             resolve: Callable[[TrackerId], TrackerId]) -> tuple[np.ndarray, ...]:
    """The messages' entries naming a tracker this node holds, in message order: each one's
    message, its row in the message, the tracker's row here, and its ``U, u, x_bar``; then the
    measured entries naming a tracker it does not hold: each one's message, its id and
    ``x_bar``."""
    sizes = [len(m.block) for m in msgs]
    ids = list(chain.from_iterable(m.block.ids() for m in msgs))
    index = state.index  # each id resolved once (the neighbours name mostly the same ones)
    row = {t: index.get(resolve(t), -1) for t in set(ids)}
    here = np.fromiter(map(row.__getitem__, ids), np.intp, len(ids))
    at = np.flatnonzero(here >= 0)  # among all the messages' rows
    of = np.repeat(np.arange(len(msgs)), sizes)  # each row's message
    which = of[at]
    rows = at - np.cumsum([0] + sizes[:-1], dtype=np.intp)[which]
    U, u, x = (np.concatenate(c) for c in ([m.block.U for m in msgs] or [np.zeros((0, 6, 6))],
                                            [m.block.u for m in msgs] or [np.zeros((0, 6))],
                                            [m.block.x_bar for m in msgs] or [np.zeros((0, 6))]))
    out = np.flatnonzero((here < 0) & (U[:, 0, 0] > 0.0))  # measured, not held here
    return (which, rows, here[at], U.take(at, axis=0), u.take(at, axis=0), x.take(at, axis=0),
            (of[out], out, ids, x))


def _add(a: list[float], b: list[float]) -> list[float]:
    """``a + b`` elementwise."""
    return [x + y for x, y in zip(a, b)]


def _terms(e: np.ndarray, v: np.ndarray, s11: np.ndarray, s12: np.ndarray, s22: np.ndarray,
           ok: np.ndarray) -> np.ndarray:
    """Per entry, its terms of the lag's normal equations (``lag_estimate``) for the innovation
    ``e = b - tau v`` with covariance ``S`` (``s11, s12, s22``), ``W = S^-1``, ``A = [I, -v]``:
    ``A^T W A`` (``W``'s three entries, ``-W v``, ``v^T W v``), ``A^T W e`` (``W e``,
    ``-v^T W e``), ``e^T W e`` and 1; zero where not ``ok``. (Under the caller's
    ``np.errstate``.)"""
    v1, v2, e1, e2 = v[:, 0], v[:, 1], e[:, 0], e[:, 1]
    det = s11 * s22 - s12 * s12
    w11, w12, w22 = s22 / det, -s12 / det, s11 / det
    wv1, wv2 = w11 * v1 + w12 * v2, w12 * v1 + w22 * v2
    we1, we2 = w11 * e1 + w12 * e2, w12 * e1 + w22 * e2
    terms = np.array([w11, w12, w22, -wv1, -wv2, v1 * wv1 + v2 * wv2, we1, we2,
                      -(v1 * we1 + v2 * we2), e1 * we1 + e2 * we2, np.ones(len(v))]).T
    ok = ok & np.isfinite(terms).all(axis=1)
    return np.where(ok[:, None], terms, 0.0)


def lag_estimate(N: Sequence[float], r: Sequence[float]) -> tuple[float, float]:
    """The least-squares lag ``tau`` (s) and its variance from the normal equations of
    ``e = b - tau v`` (``N``: ``W``'s three entries, ``-W v``'s two, ``v^T W v``; ``r``: ``W e``,
    ``-v^T W e``, then ``e^T W e`` and the entries' count), the offset ``b`` eliminated (its
    Schur complement). The variance is scaled by the fit's residual ``chi^2`` per degree of
    freedom when above 1: entries the model does not explain (a registration that varies over
    the ground, a hijack's offsets per id) make the lag uncertain, not significant.
    ``(0, inf)`` when the velocities do not tell a lag from an offset."""
    a, b, d, g1, g2, h = (float(x) for x in N)
    rb1, rb2, rt, ewe, n = (float(x) for x in r)
    det = a * d - b * b
    dof = 2.0 * n - 3.0
    if not (det > 0.0 and dof > 0.0):
        return 0.0, float("inf")
    m1, m2 = (d * g1 - b * g2) / det, (a * g2 - b * g1) / det  # N_bb^-1 g
    schur = h - (g1 * m1 + g2 * m2)
    if not schur > 1e-12 * max(h, 1e-300):
        return 0.0, float("inf")
    tau = (rt - (m1 * rb1 + m2 * rb2)) / schur
    # residual: e^T W e - r^T N^-1 r = e^T W e - r_b^T N_bb^-1 r_b - schur tau^2
    rss = ewe - (d * rb1 * rb1 - 2.0 * b * rb1 * rb2 + a * rb2 * rb2) / det - schur * tau * tau
    return tau, max(1.0, rss / dof) / schur
