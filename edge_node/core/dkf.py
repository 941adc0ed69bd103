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

from edge_node.core.model import MEAS_DIM, STATE_DIM


def symmetric(M: np.ndarray) -> np.ndarray:
    """``(M + M^T) / 2`` of one matrix or of a stack ``(n, d, d)``."""
    return 0.5 * (M + np.swapaxes(M, -1, -2))


def information(z: np.ndarray, R: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Eq. 2: ``u = H^T R^-1 z``, ``U = H^T R^-1 H``."""
    u, U = informations(np.asarray(z, float)[None], np.asarray(R, float)[None])
    return u[0], U[0]


def informations(z: np.ndarray, R: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Eq. 2 for a stack of measurements ``z`` ``(n, 4)``, ``R`` ``(n, 4, 4)``: ``u`` ``(n, 6)``,
    ``U`` ``(n, 6, 6)``. ``H`` only picks the first four state components, so ``H^T R^-1 H`` is
    ``R^-1`` padded with zeros and ``H^T R^-1 z`` is ``R^-1 z`` padded (solves, no inverse)."""
    n = len(z)
    Rinv = np.linalg.solve(R, np.broadcast_to(np.eye(MEAS_DIM), (n, MEAS_DIM, MEAS_DIM)))
    U = np.zeros((n, STATE_DIM, STATE_DIM))
    U[:, :MEAS_DIM, :MEAS_DIM] = symmetric(Rinv)
    u = np.zeros((n, STATE_DIM))
    u[:, :MEAS_DIM] = (np.swapaxes(Rinv, -1, -2) @ z[..., None])[..., 0]  # R^-T z = R^-1 z
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
    """``M = (P^-1 + S)^-1`` computed as ``(I + P S)^-1 P`` (no inverse of ``P``); one matrix
    or a stack ``(n, 6, 6)``."""
    M = np.linalg.solve(np.eye(STATE_DIM) + P @ S, P)
    return symmetric(M)


def consensus_gamma(M: np.ndarray) -> float | np.ndarray:
    """``gamma = 1 / (1 + ||M||)`` (Frobenius norm), the consensus step of eq. 4; one matrix or
    a stack ``(n, 6, 6)`` (then one ``gamma`` per matrix)."""
    g = 1.0 / (1.0 + np.linalg.norm(M, axis=(-2, -1)))
    return float(g) if np.ndim(g) == 0 else g


def correct(x_bar: np.ndarray, P: np.ndarray, y: np.ndarray, S: np.ndarray,
            neighbour_x_bars: Iterable[np.ndarray] = (),
            own_x_bar_sent: np.ndarray | None = None,
            units_per_metre: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """Eq. 4 for one tracker (see :func:`corrects`): ``x_bar_j`` are the neighbours'
    predictions and ``own_x_bar_sent`` this camera's prediction as they received it (rounded to
    the wire's precision; ``x_bar`` when ``None``). Returns ``(x_hat, M)``."""
    ref = x_bar if own_x_bar_sent is None else own_x_bar_sent
    diff = np.zeros(STATE_DIM)
    for xj in neighbour_x_bars:
        diff = diff + (np.asarray(xj, float) - ref)
    x_hat, M = corrects(x_bar[None], P[None], y[None], S[None], diff[None], units_per_metre)
    return x_hat[0], M[0]


def corrects(x_bar: np.ndarray, P: np.ndarray, y: np.ndarray, S: np.ndarray, diff: np.ndarray,
             units_per_metre: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """Eq. 4 for ``n`` trackers at once: ``x_hat = x_bar + M (y - S x_bar) + gamma M diff``
    with ``diff = sum_j (x_bar_j - x_bar)`` over the neighbours (shapes ``(n, 6)`` and
    ``(n, 6, 6)``). Returns ``(x_hat, M)``.

    ``diff`` uses this camera's prediction as its neighbours received it (rounded to the wire's
    precision), so that cameras that agree exactly see a zero consensus term.

    Units: the consensus term ``gamma M diff`` is not unit-invariant (``M`` carries squared
    ground units). It is evaluated with ``M`` in metres, ``M_m = M / units_per_metre^2``, so the
    filter behaves identically whatever the calibration's ground unit (EPFL's is ~1/30 m; taken
    literally there, every neighbour pulls with a weight near 1 and three neighbours oscillate).
    """
    M = gain(P, S)
    x_hat = x_bar + (M @ (y - (S @ x_bar[..., None])[..., 0])[..., None])[..., 0]
    pull = np.any(diff != 0, axis=1)
    if pull.any():
        M_m = M[pull] / units_per_metre**2
        gamma = consensus_gamma(M_m)
        x_hat[pull] = x_hat[pull] + gamma[:, None] * (M_m @ diff[pull][..., None])[..., 0]
    return x_hat, M


def predict(x_hat: np.ndarray, M: np.ndarray, A: np.ndarray, Q: np.ndarray
            ) -> tuple[np.ndarray, np.ndarray]:
    """``x_bar(k+1) = A x_hat(k)``, ``P(k+1) = A M A^T + Q``; one tracker ``(6,)``, ``(6, 6)``
    or a stack ``(n, 6)``, ``(n, 6, 6)``."""
    return x_hat @ A.T, symmetric(A @ M @ A.T + Q)


__all__ = ["information", "informations", "no_information", "fuse", "gain", "consensus_gamma",
           "correct", "corrects", "predict", "symmetric", "MEAS_DIM"]
