"""What an event-triggered camera sends (the asynchronous variant, docs/concepts.md).

The paper notes (end of Sec. III-A) that the consensus filter lends itself to an asynchronous,
event-triggered implementation (He et al. 2017, information-matrix triggers). Here each
tracker's entry ``(ID, x_bar, u, U, ell)`` is sent only when the neighbours would learn
something material from it; between two sends they hold what they last got ("send on delta"):
``x_bar`` extrapolated at constant velocity, ``ell`` unchanged for up to ``hold_frames``
(``TrackerConfig``; ``NeighbourMemory`` applies both).

An entry is sent when

* news: the tracker is new to this sender (it carries appearance);
* information: the measurement information withheld since the last send would change the
  neighbours' estimate by more than ``gain`` nats: the Kullback-Leibler divergence of the
  posterior after fusing it from the prior ``N(x_bar, P)`` (eqs. 2-4 with this camera's own
  prediction standing in for the neighbours'),
  ``KL = 1/2 [tr((I + P U)^-1) - 6 + ln det(I + P U) + d^T P^-1 d]``,
  ``d = (P^-1 + U)^-1 (u - U x_bar)``: the first three terms are what the information adds
  (the uncertainty it removes), the last how far it moves the mean. ``gain = 0`` sends every
  measurement (every frame a camera sees the target). The default, 1 nat (with a 5-frame
  heartbeat), sends 0.44-0.46 of sync operation's bytes at ground MOTA within 0.5 % of sync on
  terrace-sim, terrace-gt, campus-sim and ring8-sim (README "Bandwidth";
  ``sim_cluster bandwidth-sweep`` measures the whole curve);
* drift: ``x_bar`` moved more than ``drift`` (metres) from what the neighbours extrapolate from
  the entry they last got;
* ``ell`` changed from the value last sent: the drop consensus (eq. 8) must hear that someone
  saw the target again, or that nobody does any more;
* heartbeat: ``heartbeat_frames`` since the entry was last sent.

Withheld information is not lost: measurement information adds up (eq. 3 is a sum), so a
withheld ``u, U`` is kept and added to the next one; carried from frame to frame along this
camera's velocity estimate (a measurement ``z`` of where the target was is moved to where it
is now: ``u <- u + U s``, ``s = dt v``, ``U`` unchanged), and sent, summed, with the entry's
next send. At most ``heartbeat_frames`` frames of information are summed.

A message goes out when it holds at least one entry or a merge announcement, or, as a liveness
beacon, ``heartbeat_frames`` after the previous message. Receivers keep each neighbour's newest
entry per tracker (``CameraNode.update(..., stale_ok=True)``). Keep ``heartbeat_frames`` at
most the receivers' ``hold_frames`` and below ``kappa``: a neighbour forgets an entry ``kappa``
frames after it.
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np

from edge_node.core.dkf import carried
from edge_node.core.model import STATE_DIM, transition
from edge_node.core.params import ConfigError, check, integer, nonnegative, positive
from protocol.messages import FrameMessage, TrackerId


@dataclass(frozen=True)
class TriggerConfig:
    heartbeat_frames: int = integer(5, lo=1, doc="frames between two sends of one tracker")
    drift: float = positive(0.1, "m, prediction drift that triggers a send")
    gain: float = nonnegative(1.0, "nats: withheld measurement information worth sending "
                                    "(KL divergence it causes); 0 sends every measurement")

    def __post_init__(self) -> None:
        check(self, "trigger")


def check_heartbeat(cfg: TriggerConfig, kappa: int, hold_frames: int | None = None) -> None:
    """``heartbeat_frames`` must be below the tracker's ``kappa``: a receiver forgets a
    neighbour's entry ``kappa`` frames after it (``NeighbourMemory``) and the drop consensus
    (eq. 8) ages it by one per frame, so a tracker that is only kept alive by heartbeats would
    be forgotten between two of them. It must also be at most the receivers' ``hold_frames``:
    they hold a silent neighbour's ``ell`` that long, so the sender must speak by then."""
    if cfg.heartbeat_frames >= kappa:
        raise ConfigError("heartbeat_frames", f"must be below tracker.kappa ({kappa}): a "
                          f"neighbour forgets an entry kappa frames after it, got "
                          f"{cfg.heartbeat_frames}")
    if hold_frames is not None and cfg.heartbeat_frames > hold_frames:
        raise ConfigError("heartbeat_frames", f"must be at most tracker.hold_frames ({hold_frames}): "
                          f"receivers hold a silent neighbour's ell that long, got "
                          f"{cfg.heartbeat_frames}")


@dataclass
class _Sent:
    frame: int
    x_bar: np.ndarray
    ell: int


@dataclass
class _Withheld:
    """Measurement information not sent yet, brought to ``frame``."""

    frame: int
    u: np.ndarray
    U: np.ndarray


def divergences(x_bar: np.ndarray, P: np.ndarray, u: np.ndarray, U: np.ndarray) -> np.ndarray:
    """KL divergence (nats) of the posterior after fusing ``u, U`` (eq. 3-4's information
    update) from the prior ``N(x_bar, P)``, for stacks ``(n, 6)``, ``(n, 6, 6)``."""
    n = len(x_bar)
    eye = np.broadcast_to(np.eye(STATE_DIM), (n, STATE_DIM, STATE_DIM))
    G = eye + P @ U  # I + P U = P (P^-1 + U)
    Ginv = np.linalg.solve(G, eye)
    _, logdet = np.linalg.slogdet(G)
    d = (Ginv @ P @ (u - (U @ x_bar[..., None])[..., 0])[..., None])[..., 0]  # (P^-1 + U)^-1 (u - U x)
    maha = np.einsum("ni,ni->n", d, np.linalg.solve(P, d[..., None])[..., 0])
    return 0.5 * (np.trace(Ginv, axis1=1, axis2=2) - STATE_DIM + logdet + maha)


class EventTrigger:
    """Filters a camera's messages down to what its neighbours need, frame by frame."""

    def __init__(self, cfg: TriggerConfig, dt: float, units_per_metre: float = 1.0,
                 kappa: int | None = None, hold_frames: int | None = None):
        if kappa is not None:
            check_heartbeat(cfg, kappa, hold_frames)
        self.cfg = cfg
        self.dt = dt
        self.drift = cfg.drift * units_per_metre
        self._last_message: int | None = None
        self._sent: dict[TrackerId, _Sent] = {}
        self._withheld: dict[TrackerId, _Withheld] = {}
        self.entries_sent = 0
        self.entries_skipped = 0
        self.sent = 0  # messages
        self.skipped = 0

    def _withhold(self, t, k: int) -> _Withheld | None:
        """This frame's information of entry ``t`` added to what was withheld before (brought
        to frame ``k`` along ``t``'s velocity); ``None`` when there is none."""
        w = self._withheld.get(t.id)
        measured = bool(t.U[0, 0] > 0)
        if w is None:
            return _Withheld(k, np.array(t.u, float), np.array(t.U, float)) if measured else None
        if w.frame != k:  # z moved to where the target is now
            w.u = carried(w.u, w.U, (k - w.frame) * self.dt * np.asarray(t.x_bar)[4:6])
            w.frame = k
        if measured:
            w.u += t.u
            w.U += t.U
        return w

    def _needed(self, t, k: int, w: _Withheld | None) -> bool | None:
        """Whether entry ``t`` of frame ``k`` must be sent for a reason other than its
        information; ``None`` when only the information test can say."""
        last = self._sent.get(t.id)
        if last is None or t.appearance is not None:
            return True
        age = k - last.frame
        if age >= self.cfg.heartbeat_frames or t.ell != last.ell:
            return True
        expected = transition(age * self.dt) @ last.x_bar
        if np.linalg.norm(np.asarray(t.x_bar)[:2] - expected[:2]) > self.drift:
            return True
        if w is None:
            return False
        return None if self.cfg.gain > 0 else True

    def filter(self, msg: FrameMessage,
               covariance: Callable[[], np.ndarray] | None = None) -> FrameMessage | None:
        """The part of ``msg`` worth sending, or ``None`` to stay silent this frame.

        ``covariance()``: the sender's predicted covariances ``(n, 6, 6)`` of ``msg``'s rows
        (the prior of the information test, asked for only when needed); without it any
        withheld information is sent."""
        k = msg.frame
        infos = msg.trackers
        withheld = [self._withhold(t, k) for t in infos]
        needed = [self._needed(t, k, w) for t, w in zip(infos, withheld)]
        ask = [i for i, n in enumerate(needed) if n is None]
        if ask:
            if covariance is None:
                for i in ask:
                    needed[i] = True
            else:
                rows = np.array(ask)
                kl = divergences(np.array([infos[i].x_bar for i in ask]), np.asarray(covariance())[rows],
                                 np.array([withheld[i].u for i in ask]),
                                 np.array([withheld[i].U for i in ask]))
                for i, v in zip(ask, kl.tolist()):
                    needed[i] = not v <= self.cfg.gain  # NaN: send
        keep = []
        for t, w, send in zip(infos, withheld, needed):
            if not send:
                if w is not None:
                    self._withheld[t.id] = w
                continue
            self._withheld.pop(t.id, None)
            keep.append(t if w is None or w.frame == k and np.array_equal(w.U, t.U) and np.array_equal(w.u, t.u)
                        else replace(t, u=w.u, U=w.U))
        self.entries_sent += len(keep)
        self.entries_skipped += len(infos) - len(keep)
        beacon = self._last_message is None or k - self._last_message >= self.cfg.heartbeat_frames
        current = {t.id for t in infos}
        for tid in [tid for tid in self._withheld if tid not in current]:
            del self._withheld[tid]  # dropped or merged here
        if not keep and not msg.merges and not beacon:
            self.skipped += 1
            return None
        for t in keep:
            self._sent[t.id] = _Sent(k, np.asarray(t.x_bar, float), int(t.ell))
        for tid in [tid for tid in self._sent if tid not in current]:
            del self._sent[tid]  # dropped or merged here: a re-appearance is news again
        self._last_message = k
        self.sent += 1
        return replace(msg, trackers=tuple(keep))
