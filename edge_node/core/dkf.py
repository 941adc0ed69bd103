"""Distributed Kalman-Consensus Filter in information form (paper Section III-A, eqs. 2-4;
Olfati-Saber's Kalman-consensus filter).

Per camera ``i`` and target: measurement information ``u_i = H^T R_i^-1 z_i``,
``U_i = H^T R_i^-1 H`` (eq. 2); sums over the inclusive neighbourhood ``y_i``, ``S_i`` (eq. 3);
``M_i = (P_i^-1 + S_i)^-1``; correction with a consensus term on the neighbours' predictions
(eq. 4); then ``P_i <- A M_i A^T + Q``. Pure functions; covariances kept symmetric, inverses
replaced by solves.
"""
from __future__ import annotations

from collections.abc import Iterable

import numpy as np

from edge_node.core.model import H, MEAS_DIM, STATE_DIM


def symmetric(M: np.ndarray) -> np.ndarray:
    return 0.5 * (M + M.T)


def information(z: np.ndarray, R: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Eq. 2: ``u = H^T R^-1 z``, ``U = H^T R^-1 H``."""
    Rinv_H = np.linalg.solve(R, H)  # R^-1 H, (4, 6)
    U = symmetric(H.T @ Rinv_H)
    u = Rinv_H.T @ np.asarray(z, float)  # H^T R^-1 z  (R symmetric)
    return u, U


def no_information() -> tuple[np.ndarray, np.ndarray]:
    """What a camera without a measurement of the target contributes: ``u = 0``, ``U = 0``."""
    return np.zeros(STATE_DIM), np.zeros((STATE_DIM, STATE_DIM))


def fuse(contributions: Iterable[tuple[np.ndarray, np.ndarray]]) -> tuple[np.ndarray, np.ndarray]:
    """Eq. 3: ``y_i = sum_j u_j``, ``S_i = sum_j U_j`` over the inclusive neighbourhood."""
    y = np.zeros(STATE_DIM)
    S = np.zeros((STATE_DIM, STATE_DIM))
    for u, U in contributions:
        y = y + u
        S = S + U
    return y, S


def gain(P: np.ndarray, S: np.ndarray) -> np.ndarray:
    """``M = (P^-1 + S)^-1`` computed as ``(I + P S)^-1 P`` (no inverse of ``P``)."""
    M = np.linalg.solve(np.eye(STATE_DIM) + P @ S, P)
    return symmetric(M)


def consensus_gamma(M: np.ndarray) -> float:
    """``gamma = 1 / (1 + ||M||)`` (Frobenius norm), the consensus step of eq. 4."""
    return 1.0 / (1.0 + float(np.linalg.norm(M)))


def correct(x_bar: np.ndarray, P: np.ndarray, y: np.ndarray, S: np.ndarray,
            neighbour_x_bars: Iterable[np.ndarray] = (),
            own_x_bar_sent: np.ndarray | None = None,
            units_per_metre: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """Eq. 4: ``x_hat = x_bar + M (y - S x_bar) + gamma M sum_j (x_bar_j - x_bar)``.

    ``own_x_bar_sent`` is this camera's prediction as its neighbours received it (rounded to the
    wire's precision); the consensus differences use it so that cameras that agree exactly see a
    zero consensus term. Returns ``(x_hat, M)``.

    Units: the consensus term ``gamma M sum(...)`` is not unit-invariant (``M`` carries squared
    ground units). It is evaluated with ``M`` in metres, ``M_m = M / units_per_metre^2``, so the
    filter behaves identically whatever the calibration's ground unit (EPFL's is ~1/30 m; taken
    literally there, every neighbour pulls with a weight near 1 and three neighbours oscillate).
    """
    M = gain(P, S)
    x_hat = x_bar + M @ (y - S @ x_bar)
    ref = x_bar if own_x_bar_sent is None else own_x_bar_sent
    diff = np.zeros(STATE_DIM)
    for xj in neighbour_x_bars:
        diff = diff + (np.asarray(xj, float) - ref)
    if np.any(diff):
        M_m = M / units_per_metre**2
        x_hat = x_hat + consensus_gamma(M_m) * (M_m @ diff)
    return x_hat, M


def predict(x_hat: np.ndarray, M: np.ndarray, A: np.ndarray, Q: np.ndarray
            ) -> tuple[np.ndarray, np.ndarray]:
    """``x_bar(k+1) = A x_hat(k)``, ``P(k+1) = A M A^T + Q``."""
    return A @ x_hat, symmetric(A @ M @ A.T + Q)


__all__ = ["information", "no_information", "fuse", "gain", "consensus_gamma", "correct",
           "predict", "symmetric", "MEAS_DIM"]
