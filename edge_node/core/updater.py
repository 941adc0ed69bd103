"""The updater role: eqs. 3-4 for every tracker at once (paper III-A; the maths is
``dkf``'s, one function per equation).

Eq. 3 sums this node's information and each neighbour's (``y``, ``S``) in the order the entries
arrive (sender order); eq. 4 corrects with ``M = (P^-1 + S)^-1`` and pulls towards the
neighbours' predictions by the consensus term, whose differences ``x_bar_j - x_bar`` use this
node's prediction as the neighbours received it (``x_bar_sent``, at the wire's precision), so
nodes that agree exactly see no pull. The entries passed the screen (``U`` positive
semi-definite, bounded), so with ``P`` positive definite ``I + P S`` is invertible and nothing
here can fail; should a correction fail numerically anyway, that tracker alone keeps its
prediction for the frame (counted in ``stats.numerical``) and every other tracker is corrected
as usual. Pure and deterministic.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

import edge_node.core.dkf as dkf
from edge_node.core.entries import Entries
from edge_node.core.model import STATE_DIM
from edge_node.core.state import NodeState
from edge_node.core.config import Slice


@dataclass(frozen=True)
class UpdaterSettings(Slice):
    """What the updater role reads; each parameter's rule and doc is in its section of
    ``config.TrackerConfig``."""

    consensus_bound: float
    units_per_metre: float


_FAILED = (np.linalg.LinAlgError, ValueError, FloatingPointError)


class Updater:
    """``consensus``: the configuration's consensus parameters (``consensus_bound``,
    ``units_per_metre``); ``stats``: the node's counters (``numerical``)."""

    def __init__(self, consensus, stats):
        self.upm = consensus.units_per_metre
        self.bound = consensus.consensus_bound
        self.stats = stats

    def __call__(self, state: NodeState, entries: Entries) -> None:
        """``x_hat, M`` (eq. 4) of every tracker from its prediction, this node's information
        and the neighbours' ``entries`` (gathered per tracker in the table's order); and
        ``informed``: whether the sum of eq. 3 had measurement information."""
        rows = entries.rows
        if not len(state):
            return
        x_bar, P = state.x_bar, state.P
        # eq. 3's y and eq. 4's consensus sum in one table: (u | x_bar_j - x_bar_sent) per entry
        y_diff = entries.summed(np.concatenate((state.u, np.zeros(x_bar.shape)), axis=1),
                                np.concatenate((entries.u, entries.x_bar
                                                - state.x_bar_sent.take(rows, axis=0)), axis=1))
        y, diff = y_diff[:, :STATE_DIM], y_diff[:, STATE_DIM:]
        S = entries.summed(state.U, entries.U)  # eq. 3
        deg = np.bincount(rows, minlength=len(state))  # terms of each consensus sum (eq. 4)
        try:
            x_hat, M = dkf.corrects(x_bar, P, y, S, diff, self.upm, degree=deg, bound=self.bound)
        except _FAILED:
            x_hat, M = np.full_like(x_bar, np.nan), np.full_like(P, np.nan)
            for i in range(len(state)):  # one at a time: a failure stays with its tracker
                try:
                    x_hat[i:i + 1], M[i:i + 1] = dkf.corrects(
                        x_bar[i:i + 1], P[i:i + 1], y[i:i + 1], S[i:i + 1], diff[i:i + 1],
                        self.upm, degree=deg[i:i + 1], bound=self.bound)
                except _FAILED:
                    pass
        bad = ~(np.isfinite(x_hat).all(axis=1) & np.isfinite(M).all(axis=(1, 2)))
        if bad.any():
            self.stats.numerical += int(bad.sum())
            x_hat[bad], M[bad] = x_bar[bad], P[bad]
        state.x_hat, state.M = x_hat, M
        state.estimated = np.ones(len(state), bool)
        state.informed = S[:, :2, :2].any(axis=(1, 2))
