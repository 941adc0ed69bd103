"""The target model of paper Section III-A: a cylinder on the ground plane.

State ``x = (x, y, w, h, vx, vy)``: base centre, width, height, ground velocity.
``A``: constant velocity on position, no dynamics on size (eq. 1). ``H`` picks ``(x, y, w, h)``.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from edge_node.core.config import Slice


@dataclass(frozen=True)
class MotionSettings(Slice):
    """What the motion model reads (``A``, ``Q``); each parameter's rule and doc is in its
    section of ``config.TrackerConfig``."""

    accel_sigma: float
    size_sigma: float
    units_per_metre: float
    fps: float


STATE_DIM = 6
MEAS_DIM = 4
POS = slice(0, 2)
SIZE = slice(2, 4)
VEL = slice(4, 6)

H = np.hstack([np.eye(MEAS_DIM), np.zeros((MEAS_DIM, 2))])  # z = H x + v  (eq. 1)


def transition(dt: float) -> np.ndarray:
    """``A`` of eq. 1: ``p(k+1) = p(k) + dt v(k)``, ``v`` and ``(w, h)`` constant."""
    A = np.eye(STATE_DIM)
    A[0, 4] = dt
    A[1, 5] = dt
    return A


def process_noise(cfg: MotionSettings) -> np.ndarray:
    """``Q`` of eq. 1: white-noise acceleration on (p, v); random walk on (w, h)."""
    dt = cfg.dt
    qa = cfg.m(cfg.accel_sigma) ** 2
    Q = np.zeros((STATE_DIM, STATE_DIM))
    for p, v in ((0, 4), (1, 5)):
        Q[p, p] = qa * dt**4 / 4.0
        Q[p, v] = Q[v, p] = qa * dt**3 / 2.0
        Q[v, v] = qa * dt**2
    Q[2, 2] = Q[3, 3] = cfg.m(cfg.size_sigma) ** 2
    return Q


def birth_covariance(cfg: MotionSettings) -> np.ndarray:
    """Prior covariance of a new tracker: the same on every node, so adopters agree exactly."""
    s = [cfg.m(cfg.birth_pos_sigma)] * 2 + [cfg.m(cfg.birth_size_sigma)] * 2 \
        + [cfg.m(cfg.birth_vel_sigma)] * 2
    return np.diag(np.square(s))


def birth_state(z: np.ndarray) -> np.ndarray:
    """A new tracker's prior mean from its first observation ``z = (x, y, w, h)``; zero velocity."""
    return np.concatenate([np.asarray(z, float)[:MEAS_DIM], np.zeros(2)])


def quantize(x: np.ndarray) -> np.ndarray:
    """Round to float32 and back: what a neighbour receives of a vector sent on the wire."""
    return np.asarray(x, dtype=np.float32).astype(np.float64)
