"""The semantic trust boundary: what a neighbour's message may change on this node.

``protocol.codec.decode`` checks a message's *form* (types, shapes, finite numbers, sizes). A
message can be well-formed and still hostile or simply broken: an information matrix ``U`` that
is not positive semi-definite makes ``I + P S`` singular in the DKF gain (eq. 4) or ``P``
indefinite; a state of 1e27 poisons every estimate it is fused with; a forged ``born = 0`` or a
forged merge announcement takes over established identities network-wide (identities rank by
``(born, id)``, paper III-C). ``Screen`` checks a decoded message's *meaning* against what this
node knows, entry by entry, before anything touches tracker state. An entry that fails is
dropped and counted under its reason; the rest of the message is used.

Tracker entry ``(ID, x_bar, u, U, ell, born)`` (paper III-D):

* ``bad_information``: ``U`` (eq. 2, ``H^T R^-1 H``) must be symmetric, carry nothing on the
  velocity (``H`` observes ``(x, y, w, h)`` only: rows and columns 4-5 and ``u[4:]`` are zero),
  be positive semi-definite, and ``u`` must be ``U z`` for some measurement ``z`` (``u = 0``
  when ``U = 0``: no measurement).
* ``implausible_information``: the largest eigenvalue of ``U`` above one measurement with a
  1 cm standard deviation (``1e4`` per m^2; honest runs: at most 282), or the measurement ``z``
  more than 100 of its own standard deviations (``INFO_GATE``, in the metric of ``U``) from the
  nearest plausible one: on the world (within ``world_radius`` of this node's cameras), width
  and height in ``[0, max_size]``. In the metric of ``U`` because honest measurements can be
  absurd where they are uncertain: a box cut near a camera's horizon gave a 56 m wide person
  250 m away, 400 m uncertain along the viewing ray, 24 standard deviations off (honest runs:
  at most 24.2).
* ``implausible_state``: ``x_bar`` off the world, a size above ``max_size`` or a speed above
  ``max_speed``.
* ``implausible_ell``: ``ell`` above ``2 kappa + 2`` (an honest sender drops a tracker once its
  ``ell`` exceeds ``kappa``, eq. 8, so it never reports more than ``kappa + 1``).
* ``future_birth``: ``born`` after the message's frame.
* ``born_moved``: an id whose birth this node knows (adopted, or first claimed in an entry it
  accepted), claimed earlier: ranks cannot be stolen, not even in two steps.
* ``implausible_birth``: an id new to this node claiming to be older than an id its camera
  created before it (a camera's counter grows with time, so ``(c, m) < (c, n)`` implies
  ``born_m <= born_n``: a forged old birth under a fresh counter is refused), or an id of the sender's own camera that it never mentioned although we have been
  hearing it without a gap since before that birth, more than ``kappa`` frames ago (a sender
  announces its own births at once; a sender we did not hear, partitioned or new, may bring
  old ones). The converse (a *larger* known counter born *earlier*) is not a reason: it
  protects no rank (the newcomer is the younger) and a flood of phantoms under huge fresh
  counters, born now, would make every later honest birth of that camera implausible.

Merge announcement ``loser -> winner``:

* a winner this node has not heard of (merges are relayed hop by hop): ``winner_born`` is
  checked as an entry's ``born`` is (``future_birth``, ``implausible_birth``); taking it on
  trust would let an invented id outrank an established one.
* ``forged_alias``: the loser may also be an id this node never heard of; such an alias is
  remembered, and an entry that later names that id with a birth *after* the merge proves it
  forged (honest merges link ids that exist; a forged one would hijack a target not yet
  born): the alias is removed (the entry itself is kept and counted here).

Bounds per neighbour (``CameraNode._bounded`` and its adoption, counted here too):

* ``too_many_trackers``: a message's entries beyond ``max_trackers_per_neighbour`` (the ids
  this node holds are kept first);
* ``adoption_rate``: trackers new to this node beyond ``max_adoptions_per_frame`` from one
  sender in one frame (they are adopted in a later frame if the sender still tells of them).

What stays possible for a peer that can publish on a link (no mTLS): entries that pass every
rule, i.e. a plausible phantom target under a fresh id of its own camera, born now; an ``ell``
of 0 that keeps a target alive; measurement information that pulls an estimate within the
gates. Those are indistinguishable from a camera that sees something (README, "Threat model").

Pure and deterministic; bounded memory (per neighbour, ids heard within the window).
"""
from __future__ import annotations

from collections import Counter, OrderedDict
from dataclasses import dataclass, replace

import numpy as np

from edge_node.core.config import Slice
from edge_node.core.identity import IdentityBook
from edge_node.geometry import Camera, norms
from protocol.messages import VELOCITY_PLACES, FrameMessage, Merge, TrackerId


@dataclass(frozen=True)
class ScreenSettings(Slice):
    """What the screen reads (what a neighbour may claim); each parameter's rule and doc is in
    its section of ``config.TrackerConfig``."""

    world_radius: float
    max_size: float
    max_speed: float
    kappa: int
    max_old_trackers: int
    merge_announce_frames: int
    units_per_metre: float
    fps: float


RANK_TOL = 1e-9  # eigenvalues of U below this fraction of the largest count as unmeasured
FLOAT_TOL = 1e-6  # float32 rounding on the wire: negative eigenvalues of U and components of u
# in unmeasured directions up to this fraction are rounding, not a fault
INFO_GATE = 1e4  # squared standard deviations a measurement may lie off the plausible world
MIN_SIGMA_M = 0.01  # m: no camera measures a foot point better than 1 cm

BIRTH_REASONS = ("future_birth", "born_moved", "implausible_birth")
REASONS = ("bad_information", "implausible_information", "implausible_state", "implausible_ell",
           *BIRTH_REASONS, "forged_alias", "too_many_trackers", "adoption_rate")


def anchors(cameras: list[Camera]) -> np.ndarray:
    """One ground point per camera: where the bottom centre of its image looks (in front)."""
    pts = [c.to_ground(np.array([[c.image_size[0] / 2.0, float(c.image_size[1])]]))[0]
           for c in cameras]
    return np.array([p for p in pts if np.all(np.isfinite(p))]).reshape(-1, 2)


def _factors(blocks) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """The measurement factors of decoded blocks, stacked as one block's would be, or ``None``
    if a block with rows has none (not decoded; an empty block has nothing to factor)."""
    factors = [b.measurement_factor() for b in blocks if len(b)]
    if not factors or any(f is None for f in factors):
        return None
    if len(factors) == 1:
        return factors[0]
    return tuple(np.concatenate(columns) for columns in zip(*factors))


class Screen:
    """Checks neighbours' messages for meaning; counts what it drops in ``rejected``."""

    def __init__(self, cfg: ScreenSettings, cameras: list[Camera], node_id: int):
        self.cfg = cfg
        self.node_id = node_id
        self.anchors = anchors(cameras)
        self.radius = cfg.m(cfg.world_radius)
        self.max_size = cfg.m(cfg.max_size)
        self.max_speed = cfg.m(cfg.max_speed)
        self.max_info = 1.0 / cfg.m(MIN_SIGMA_M) ** 2
        self.window = cfg.kappa + cfg.merge_announce_frames
        self.rejected: Counter[str] = Counter()
        # the first birth accepted for every id not yet adopted here (bounded, oldest out)
        self.claimed: OrderedDict[TrackerId, int] = OrderedDict()
        self.relayed: OrderedDict[TrackerId, int] = OrderedDict()  # unknown merge losers -> frame
        self.heard: dict[int, dict[TrackerId, int]] = {}  # sender -> id -> last frame mentioned
        self._heard_low: dict[int, int] = {}  # sender -> at most the oldest frame in heard[sender]
        # sender -> (first, last) frame of its messages without a gap longer than kappa
        self.stretch: dict[int, tuple[int, int]] = {}

    # -- whole messages -------------------------------------------------------------------
    def messages(self, msgs: list[FrameMessage], book: IdentityBook) -> list[FrameMessage]:
        """:meth:`message` of a frame's messages in order, the numbers of all their entries
        checked in one batch."""
        blocks = [m.block for m in msgs]  # the messages' numbers as arrays (the codec's form)
        infos = self.informations(np.concatenate([b.u for b in blocks]).reshape(-1, 6),
                                  np.concatenate([b.U for b in blocks]).reshape(-1, 6, 6),
                                  factor=_factors(blocks)) if blocks else []
        bad = self.states(np.concatenate([b.x_bar for b in blocks]).reshape(-1, 6)).tolist() \
            if blocks else []
        out, i = [], 0
        for m in msgs:
            n = len(m.block)
            out.append(self.message(m, book, (infos[i:i + n], bad[i:i + n])))
            i += n
        return out

    def message(self, m: FrameMessage, book: IdentityBook,
                verdicts: tuple[list, list] | None = None) -> FrameMessage:
        """``m`` without the entries and merges that fail (each counted under its reason).
        ``verdicts``: :meth:`informations` and :meth:`states` of its entries, if known."""
        s = m.sender
        since, last = self.stretch.get(s, (m.frame, m.frame))
        if m.frame - last > self.cfg.kappa:  # silent for a while (partition, restart): anew
            since = m.frame
        self.stretch[s] = (min(since, m.frame), max(last, m.frame))
        heard = self.heard.setdefault(s, {})
        low = self._heard_low.get(s, m.frame)
        if m.frame - low > self.window:  # an id may be older than the window: forget those
            for tid in [t for t, f in heard.items() if m.frame - f > self.window]:
                del heard[tid]
            low = min(heard.values(), default=m.frame)
        # (the frames in heard only grow, and new ones are m.frame: low stays a lower bound, and
        # the ids are scanned only when one may be forgotten, not for every message)
        self._heard_low[s] = min(low, m.frame)
        b = m.block
        if verdicts is None:
            verdicts = (self.informations(b.u, b.U, factor=b.measurement_factor()),
                        self.states(b.x_bar).tolist())
        keep: list[int] = []
        frame, ell_max, known = m.frame, 2 * self.cfg.kappa + 2, book.born
        for i, (tid, born, ell, info, bad_state) in enumerate(
                zip(b.ids(), b.born.tolist(), b.ell.tolist(), *verdicts)):
            # the common entry, inlined (the message's entries are the update's hot loop): a
            # tracker held here, sound numbers, its birth as known; what :meth:`entry` says
            k_born = known.get(tid)
            if (info is None and not bad_state and ell <= ell_max and k_born is not None
                    and k_born <= born <= frame):
                h = heard.get(tid)
                heard[tid] = frame if h is None or h < frame else h
                if self.relayed and self.alias_born_later(tid, born, book):
                    self.rejected["forged_alias"] += 1
                keep.append(i)
                continue
            reason = self.entry(tid, born, ell, m, book, heard, info, bad_state)
            if reason not in BIRTH_REASONS:  # mentioned: the never-mentioned rule is not for it
                heard[tid] = max(m.frame, heard.get(tid, m.frame))
            if reason:
                self.rejected[reason] += 1
                continue
            if self.relayed and self.alias_born_later(tid, born, book):
                self.rejected["forged_alias"] += 1
            if tid not in book.born:
                self.claimed.setdefault(tid, born)
                while len(self.claimed) > 10 * self.cfg.max_old_trackers:
                    self.claimed.popitem(last=False)
            keep.append(i)
        merges: list[Merge] = []
        for mg in m.merges:
            reason = self.merge(mg, book, heard, m.frame, m.sender)
            if reason:
                self.rejected[reason] += 1
                continue
            merges.append(mg)
        if len(keep) == len(b) and len(merges) == len(m.merges):
            return m
        return replace(m, block=b.take(keep), merges=tuple(merges))

    # -- one entry ------------------------------------------------------------------------
    def entry(self, tid: TrackerId, born: int, ell: int, m: FrameMessage, book: IdentityBook,
              heard: dict[TrackerId, int], info: str | None = None,
              bad_state: bool = False) -> str | None:
        """The reason to drop the entry ``(tid, born, ell)`` of message ``m``, or ``None``
        (``info`` and ``bad_state``: the verdicts of :meth:`informations` and :meth:`states`,
        computed for the whole message at once)."""
        reason = info or ("implausible_state" if bad_state else None)
        if reason:
            return reason
        if ell > 2 * self.cfg.kappa + 2:
            return "implausible_ell"
        return self.birth(tid, born, m.frame, m.sender, book, heard)

    def information(self, u: np.ndarray, U: np.ndarray) -> str | None:
        """Eq. 2's ``u, U`` as a camera produces them, or why not."""
        return self.informations(np.asarray(u, float)[None], np.asarray(U, float)[None])[0]

    def informations(self, u: np.ndarray, U: np.ndarray,
                     factor: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
                     ) -> list[str | None]:
        """:meth:`information` of a message's entries at once: ``u (n, 6)``, ``U (n, 6, 6)``.
        ``factor``: ``u, U`` are the decoder's, and this is the factor they were built from
        (:meth:`TrackerBlock.measurement_factor`: which rows are measured, their ``L`` and
        ``v``), so the form checks hold by construction and are skipped (``U = L L^T`` exactly
        symmetric, nothing on the velocity, ``u = 0`` where ``U = 0``), and so is the
        factorisation."""
        n = len(u)
        if not n:
            return []
        bad = np.zeros(n, bool)
        if factor is not None:
            measured, L, v = factor
            todo = measured.nonzero()[0]
        else:
            flat = U.reshape(n, 36)
            vel = flat[:, VELOCITY_PLACES].any(axis=1) | u[:, 4:].any(axis=1)
            # symmetry of the measured block: outside it an entry without ``vel`` is zero (and
            # symmetric), and one with ``vel`` is bad anyway
            B = U[:, :4, :4]
            asym = (np.abs(B - B.transpose(0, 2, 1)) > 1e-6 * np.abs(B)).reshape(n, 16).any(axis=1)
            zero = ~flat.any(axis=1)
            bad = asym | vel | (zero & u.any(axis=1))
            todo = (~(asym | vel | zero)).nonzero()[0]
        implausible = np.zeros(n, bool)
        if len(todo):
            U4 = U[:, :4, :4].take(todo, axis=0)  # (see stacks)
            if factor is None:
                sure, far = self._measured(u[:, :4].take(todo, axis=0), U4)
            else:
                sure, far = self._measured(None, U4, (L, v))
            implausible[todo[sure]] = far[sure]
            unsure = (~sure).nonzero()[0]
            if len(unsure):
                b, i = self._eigen(u[:, :4].take(todo.take(unsure), axis=0), U4.take(unsure, axis=0))
                bad[todo[unsure]] |= b
                implausible[todo[unsure]] = i
        if not (bad.any() or implausible.any()):  # (the common case: every entry sound)
            return [None] * n
        return ["bad_information" if b else "implausible_information" if i else None
                for b, i in zip(bad.tolist(), implausible.tolist())]

    def _measured(self, u4: np.ndarray | None, U4: np.ndarray,
                  Lv: tuple[np.ndarray, np.ndarray] | None = None) -> tuple[np.ndarray, np.ndarray]:
        """The common case of :meth:`_eigen` without eigenvalues: for each ``U4 (m, 4, 4)`` whether
        it is ``sure``ly positive definite with every direction measured and none above
        ``max_info``, and for those whether the measurement ``z = U^-1 u`` is ``far``
        (``(z - p)^T U (z - p) > INFO_GATE``, ``p`` the plausible point nearest ``z``).

        The Cholesky factor ``U = L L^T`` in closed form, one array operation per element of
        ``L`` over all ``m`` matrices: for a frame's 80 4 x 4 matrices NumPy's batched ``eigh``
        alone costs 0.55 M instructions, its ``cholesky`` and ``solve`` 0.49 M (and
        ``cholesky`` fails the whole batch for one matrix that is not positive definite), all of
        this about 0.5 M, a bad matrix only making its own row NaN. A decoder's entries come
        with their factor (``Lv``: ``L`` and ``v = L^-1 u``, what the closed form computes, to
        rounding), which saves half of that. Bounds instead of
        eigenvalues: ``lambda_max <= tr U``, and the product of the other three being at most
        ``(tr U / 3)^3`` (their mean cubed), ``lambda_min >= 27 det U / (tr U)^3`` with ``det U =
        prod(diag L)^2``. So ``27 det U > 10 RANK_TOL (tr U)^4`` proves every eigenvalue above
        ``10 RANK_TOL lambda_max`` (all "seen", none negative; the factor 10 for the rounding of
        ``eigh``), and ``tr U <= max_info`` proves none huge: then :meth:`_eigen` says exactly
        "implausible" where ``far``, and nothing else. Entries that are not sure go to
        :meth:`_eigen`: the bound holds for every condition number up to 10^3, and for most
        far beyond (honest runs of five presets: 2 entries of 100,000 went to :meth:`_eigen`,
        both on campus-gt with condition numbers about 10^6)."""
        a = U4.reshape(len(U4), 16).T  # a[4 i + j] = U[:, i, j]
        with np.errstate(all="ignore"):  # not positive definite: NaN, and not sure
            if Lv is None:
                b = u4.T
                l00 = np.sqrt(a[0])
                l10, l20, l30 = a[4] / l00, a[8] / l00, a[12] / l00
                l11 = np.sqrt(a[5] - l10 * l10)
                l21, l31 = (a[9] - l20 * l10) / l11, (a[13] - l30 * l10) / l11
                l22 = np.sqrt(a[10] - l20 * l20 - l21 * l21)
                l32 = (a[14] - l30 * l20 - l31 * l21) / l22
                l33 = np.sqrt(a[15] - l30 * l30 - l31 * l31 - l32 * l32)
                # z = U^-1 u: L y = u forward, then L^T z = y backward
                y0 = b[0] / l00
                y1 = (b[1] - l10 * y0) / l11
                y2 = (b[2] - l20 * y0 - l21 * y1) / l22
                y3 = (b[3] - l30 * y0 - l31 * y1 - l32 * y2) / l33
            else:
                f = Lv[0].reshape(len(U4), 16).T
                l00, l10, l11, l20, l21, l22, l30, l31, l32, l33 = (
                    f[0], f[4], f[5], f[8], f[9], f[10], f[12], f[13], f[14], f[15])
                y0, y1, y2, y3 = Lv[1].T
            trace = a[0] + a[5] + a[10] + a[15]
            det_root = l00 * l11 * l22 * l33
            sure = (27 * det_root * det_root > 10 * RANK_TOL * trace ** 4) & (trace <= self.max_info)
            z3 = y3 / l33
            z2 = (y2 - l32 * z3) / l22
            z1 = (y1 - l21 * z2 - l31 * z3) / l11
            z0 = (y0 - l10 * z1 - l20 * z2 - l30 * z3) / l00
            z = np.empty((len(z0), 4))
            z[:, 0], z[:, 1], z[:, 2], z[:, 3] = z0, z1, z2, z3
            e = z - self._plausible(z)
            d2 = ((e[:, None, :] @ U4) @ e[:, :, None])[:, 0, 0]
        return sure, ~(d2 <= INFO_GATE)

    def _eigen(self, u4: np.ndarray, U4: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Whether each well-formed measured entry (``u4 (m, 4)``, symmetric ``U4 (m, 4, 4)``) is
        bad or implausible, from ``U``'s eigen-decomposition (one batched call): negative
        eigenvalues, ``u`` outside ``U``'s range, the largest eigenvalue, and the distance of
        ``z`` (the pseudo-inverse's) from the plausible world in the measured directions."""
        ev, V = np.linalg.eigh(0.5 * (U4 + U4.transpose(0, 2, 1)))
        w = np.einsum("nji,nj->ni", V, u4)  # u in U's eigenbasis
        top = ev[:, -1:]
        not_psd = ev[:, 0] < -FLOAT_TOL * top[:, 0]
        huge = top[:, 0] > self.max_info
        seen = ev > RANK_TOL * top  # the directions U measures
        norm_w = norms(w, axis=1, keepdims=True)
        off_range = np.any(~seen & (np.abs(w) > FLOAT_TOL * norm_w), axis=1)  # u = U z for no z
        with np.errstate(all="ignore"):
            z = np.einsum("nij,nj->ni", V, np.where(seen, w / np.where(seen, ev, 1.0), 0.0))
            e = np.einsum("nji,nj->ni", V, z - self._plausible(z))
            d2 = np.sum(np.where(seen, ev * e**2, 0.0), axis=1)
        far = ~(d2 <= INFO_GATE)
        return not_psd | (~huge & off_range), ~not_psd & (huge | (~off_range & far))

    def states(self, x: np.ndarray) -> np.ndarray:
        """Whether each ``x_bar`` of ``x (n, 6)`` is implausible: off the world, a size above
        ``max_size`` or a speed above ``max_speed``."""
        with np.errstate(all="ignore"):
            return (~self._on_world(x[:, :2]) | (~(np.abs(x[:, 2:4]) <= self.max_size)).any(axis=1)
                    | ~(np.hypot(x[:, 4], x[:, 5]) <= self.max_speed))

    def birth(self, tid: TrackerId, born: int, frame: int, sender: int, book: IdentityBook,
              heard: dict[TrackerId, int]) -> str | None:
        if born > frame:
            return "future_birth"
        known = self.known_birth(tid, book)
        if known is not None:
            return "born_moved" if born < known else None
        since = self.stretch[sender][0]
        if tid[0] == sender and since <= born < frame - self.cfg.kappa and tid not in heard:
            return "implausible_birth"  # born while we heard the sender, never mentioned
        if not self._in_counter_order(tid, born, book):
            return "implausible_birth"
        return None

    def known_birth(self, tid: TrackerId, book: IdentityBook) -> int | None:
        """The birth of ``tid`` as this node knows it: adopted or heard of, or first claimed in
        an entry it accepted (a later claim cannot move it earlier)."""
        return book.born.get(tid, self.claimed.get(tid))

    def merge(self, mg: Merge, book: IdentityBook, heard: dict[TrackerId, int],
              k: int, sender: int) -> str | None:
        """A merge may only link ids whose rank this node can check (module docstring)."""
        if book.resolve(mg.loser) == book.resolve(mg.winner):
            return None  # already one id here: a repeated announcement changes nothing
        known = self.known_birth(mg.winner, book)
        if known is None:  # a winner first heard of here: its claimed birth is checked as an entry's
            reason = self.birth(mg.winner, mg.winner_born, k, sender, book, heard)
            if reason:
                return reason
        elif mg.winner_born < known:
            return "born_moved"
        if mg.loser not in book.born and mg.loser not in heard:
            self.relayed[mg.loser] = k  # an id not heard of yet: it must have been born by now
            while len(self.relayed) > 10 * self.cfg.max_old_trackers:
                self.relayed.popitem(last=False)
        return None

    def alias_born_later(self, tid: TrackerId, born: int, book: IdentityBook) -> bool:
        """An entry names id ``tid``, born at ``born``, that a relayed merge aliased before it
        was born: that merge was forged (an honest merge only links ids that exist). The alias
        is removed."""
        at = self.relayed.get(tid)
        if at is None or born <= at:
            return False
        del self.relayed[tid]
        book.aliases.pop(tid, None)
        return True

    # -- helpers --------------------------------------------------------------------------
    def _plausible(self, z: np.ndarray) -> np.ndarray:
        """The plausible measurements nearest ``z (n, 4)``: on the world, sizes in
        ``[0, max_size]``."""
        c = np.array(z, float)
        np.clip(c[:, 2:4], 0.0, self.max_size, out=c[:, 2:4])
        if len(self.anchors):
            d = norms(c[:, None, :2] - self.anchors[None], axis=2)  # (n, anchors)
            out = (d.min(axis=1) > self.radius).nonzero()[0]
            if len(out):  # onto the circle of the nearest anchor
                d = d[out]
                i = np.argmin(d, axis=1)
                a, di = self.anchors[i], d[np.arange(len(out)), i]
                c[out, :2] = a + (c[out, :2] - a) * (self.radius / di)[:, None]
        return c

    def _on_world(self, xy: np.ndarray) -> np.ndarray:
        """Whether each ground point of ``xy (n, 2)`` lies within ``world_radius`` of a camera."""
        if not len(self.anchors):
            return np.ones(len(xy), bool)
        d = norms(xy[:, None] - self.anchors[None], axis=2)
        return d.min(axis=1) <= self.radius

    @staticmethod
    def _in_counter_order(tid: TrackerId, born: int, book: IdentityBook) -> bool:
        """A camera's counter grows with time: no id of ``tid``'s camera with a smaller counter
        is known to be born after ``born`` (module docstring: only this direction)."""
        cam, n = tid
        for (c, m), b in book.born.items():
            if c == cam and m < n and b > born:
                return False
        return True
