"""What an event-triggered camera sends (the asynchronous variant, DESIGN.md "Runtime modes").

The paper notes (end of Sec. III-A) that the consensus filter lends itself to an asynchronous,
event-triggered implementation (He et al. 2017). Here each tracker's entry ``(ID, x_bar, u, U,
ell)`` is sent only when the neighbours would learn something from it:

* measurement information: ``u != 0`` (this camera saw the target);
* news: the tracker is new to this sender (it carries appearance);
* drift: ``x_bar`` moved more than ``drift`` (metres) from what the neighbours extrapolate from
  the entry they last got (its ``x_bar`` predicted forward with the constant-velocity model);
* ``ell`` fell below what the neighbours infer (last sent ``ell`` plus the frames since): someone
  saw the target, and the drop consensus (eq. 8) must hear of it;
* a per-tracker heartbeat: ``heartbeat_frames`` since the entry was last sent.

A message goes out when it holds at least one entry or a merge announcement, or, as a liveness
beacon, ``heartbeat_frames`` after the previous message. Receivers keep each neighbour's newest
entry per tracker and age it (``CameraNode.update(..., stale_ok=True)``). Keep
``heartbeat_frames`` below ``kappa``: a neighbour forgets an entry ``kappa`` frames after it.
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from edge_node.core.model import transition
from edge_node.core.params import ConfigError, check, integer, positive
from protocol.messages import FrameMessage, TrackerId


@dataclass(frozen=True)
class TriggerConfig:
    heartbeat_frames: int = integer(10, lo=1, doc="frames between two sends of one tracker")
    drift: float = positive(0.1, "m, prediction drift that triggers a send")

    def __post_init__(self) -> None:
        check(self, "trigger")


def check_heartbeat(cfg: TriggerConfig, kappa: int) -> None:
    """``heartbeat_frames`` must be below the tracker's ``kappa``: a receiver forgets a
    neighbour's entry ``kappa`` frames after it (``NeighbourMemory``) and the drop consensus
    (eq. 8) ages it by one per frame, so a tracker that is only kept alive by heartbeats would
    be forgotten between two of them."""
    if cfg.heartbeat_frames >= kappa:
        raise ConfigError("heartbeat_frames", f"must be below tracker.kappa ({kappa}): a "
                          f"neighbour forgets an entry kappa frames after it, got "
                          f"{cfg.heartbeat_frames}")


@dataclass
class _Sent:
    frame: int
    x_bar: np.ndarray
    ell: int


class EventTrigger:
    """Filters a camera's messages down to what its neighbours need, frame by frame."""

    def __init__(self, cfg: TriggerConfig, dt: float, units_per_metre: float = 1.0,
                 kappa: int | None = None):
        if kappa is not None:
            check_heartbeat(cfg, kappa)
        self.cfg = cfg
        self.dt = dt
        self.drift = cfg.drift * units_per_metre
        self._last_message: int | None = None
        self._sent: dict[TrackerId, _Sent] = {}
        self.entries_sent = 0
        self.entries_skipped = 0
        self.sent = 0  # messages
        self.skipped = 0

    def needed(self, t, k: int) -> bool:
        """Whether tracker entry ``t`` of frame ``k`` must be sent."""
        last = self._sent.get(t.id)
        if last is None or t.appearance is not None or np.any(t.u):
            return True
        age = k - last.frame
        if age >= self.cfg.heartbeat_frames or t.ell < last.ell + age:
            return True
        expected = transition(age * self.dt) @ last.x_bar
        return bool(np.linalg.norm(np.asarray(t.x_bar)[:2] - expected[:2]) > self.drift)

    def filter(self, msg: FrameMessage) -> FrameMessage | None:
        """The part of ``msg`` worth sending, or ``None`` to stay silent this frame."""
        k = msg.frame
        keep = [t for t in msg.trackers if self.needed(t, k)]
        self.entries_sent += len(keep)
        self.entries_skipped += len(msg.trackers) - len(keep)
        beacon = self._last_message is None or k - self._last_message >= self.cfg.heartbeat_frames
        if not keep and not msg.merges and not beacon:
            self.skipped += 1
            return None
        for t in keep:
            self._sent[t.id] = _Sent(k, np.asarray(t.x_bar, float), int(t.ell))
        current = {t.id for t in msg.trackers}
        for tid in [tid for tid in self._sent if tid not in current]:
            del self._sent[tid]  # dropped or merged here: a re-appearance is news again
        self._last_message = k
        self.sent += 1
        return replace(msg, trackers=tuple(keep))
