"""The predictor role: every tracker from its last estimate to frame ``k`` (eq. 1's model:
``x_bar = A x_hat``, ``P = A M A^T + Q``; :func:`edge_node.core.dkf.predict`), through any
frames the node skipped. Pure and deterministic."""
from __future__ import annotations

import edge_node.core.dkf as dkf
from edge_node.core.model import process_noise, transition
from edge_node.core.state import NodeState


class Predictor:
    """``A`` and ``Q`` of the motion model (``model``), from the configuration's motion
    parameters."""

    def __init__(self, motion):
        self.A = transition(motion.dt)
        self.Q = process_noise(motion)

    def __call__(self, state: NodeState, steps: int) -> None:
        """Predict every tracker ``steps`` frames ahead (0: nothing to do)."""
        if not steps or not len(state):
            return
        x_bar, P = dkf.predict(state.x_hat, state.M, self.A, self.Q)
        for _ in range(steps - 1):
            x_bar, P = dkf.predict(x_bar, P, self.A, self.Q)
        state.x_bar, state.P = x_bar, P
