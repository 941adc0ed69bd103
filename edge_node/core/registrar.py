"""The registrar: one frame's registration residuals of a node's cameras (``registration``,
R2-R3), each camera against what the other cameras measured of the same targets in the same
frame: the neighbours' ``u, U`` and this node's other cameras (their information summed, eq. 3,
the ground position's block: ``z_o = U_o^-1 u_o``, ``V_o = U_o^-1``). Pure and deterministic.
"""
from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from edge_node.core.entries import Entries
from edge_node.core.measurement import BoxMeasurements
from edge_node.core.registration import Registration
from edge_node.core.state import NodeState


class Registrar:
    """The registrar role: ``registrations``, the node's (camera id -> ``Registration``; empty
    when it does not register its cameras); ``cameras``: the node's camera ids, in its table's
    camera columns."""

    def __init__(self, registrations: Mapping[int, Registration], cameras: Sequence[int]):
        self.registrations = registrations
        self.cameras = list(cameras)

    def __call__(self, state: NodeState, entries: Entries,
                 raws: Mapping[int, BoxMeasurements]) -> None:
        """:func:`learn` of the frame (nothing without registrations)."""
        if self.registrations:
            learn(self.registrations, entries, state, self.cameras, raws)


def learn(registrations: Mapping[int, Registration], entries: Entries, state: NodeState,
          cameras: Sequence[int], raws: Mapping[int, BoxMeasurements]) -> None:
    """Feed each camera's :class:`Registration` this frame's residuals and end its frame.
    ``entries``: the neighbours' entries of the frame, gathered per tracker (the table's rows,
    in its order); ``state``: the node's table, whose frame columns say what this node's
    cameras (``cameras``, its camera columns' ids) measured of each tracker (``raw``: the row
    of its box among ``raws[camera]``; ``residual``: a measurement inside the gate)."""
    n = len(state)
    u_o, U_o = np.zeros((n, 2)), np.zeros((n, 2, 2))  # the neighbours' measured entries
    count = np.zeros(n, np.intp)
    if len(entries.rows):  # (rows of 2: np.add.at costs less than Entries.summed)
        seen = (entries.U[:, 0, 0] > 0).nonzero()[0]
        at = entries.rows.take(seen)
        np.add.at(u_o, at, entries.u[:, :2].take(seen, axis=0))
        np.add.at(U_o, at, entries.U[:, :2, :2].take(seen, axis=0))
        np.add.at(count, at, 1)
    votes: list[tuple[np.ndarray, np.ndarray]] = []  # R7: the others' measured targets, by source
    if len(entries.rows) and next(iter(registrations.values())).cfg.reg_relock:
        told = entries.U[:, 0, 0] > 0
        Ue, ue = entries.U[:, :2, :2].compress(told, axis=0), entries.u[:, :2].compress(told, axis=0)
        det = Ue[:, 0, 0] * Ue[:, 1, 1] - Ue[:, 0, 1] * Ue[:, 1, 0]
        ok = det > 1e-9 * (Ue[:, 0, 0] + Ue[:, 1, 1]) ** 2
        if ok.any():
            votes.append((np.linalg.solve(Ue.compress(ok, axis=0), ue.compress(ok, axis=0)[..., None])[..., 0],
                          entries.sender.compress(told).compress(ok)))

    def compared(cam_id: int) -> tuple[np.ndarray, np.ndarray]:
        """What R7 compares camera ``cam_id`` with: the neighbours' measured targets and this
        node's other cameras' corrected foot points (source ``-1 - camera``)."""
        parts = list(votes)
        for o in cameras:
            if o != cam_id and o in raws and len(raws[o].z):
                ms = raws[o]
                z = ms.z[:, :2] if o not in registrations else registrations[o].corrects(ms)[0][:, :2]
                z = z.compress(~ms.cut, axis=0)
                parts.append((z, np.full(len(z), -1 - o, np.int64)))
        if not parts:
            return np.zeros((0, 2)), np.zeros(0, np.int64)
        return np.concatenate([p[0] for p in parts]), np.concatenate([p[1] for p in parts])

    # per camera: its raw measurements, the trackers' rows, and this node's other cameras'
    # information on them (None: the neighbours' alone)
    rows: dict[int, tuple[list, list, list]] = {c: ([], [], []) for c in registrations}
    if len(cameras) == 1:  # (a node of one camera has no other of its own: all at once)
        take = np.flatnonzero(state.residual[:, 0] & (count > 0))
        if len(take) and cameras[0] in rows:
            rows[cameras[0]] = (state.raw[take, 0].tolist(), take.tolist(), [None] * len(take))
    else:
        order = sorted(range(len(cameras)), key=lambda c: cameras[c])  # camera id order
        has = (state.raw >= 0).tolist()
        for i in range(n):
            mine = [c for c in order if has[i][c]]
            for c in mine:
                own = [(state.cam_u[i, o], state.cam_U[i, o]) for o in mine if o != c] \
                    if len(mine) > 1 else ()
                if not state.residual[i, c] or not (count[i] or own):
                    continue
                picked, idx, others = rows[cameras[c]]
                picked.append(int(state.raw[i, c]))
                idx.append(i)
                others.append((sum(u[:2] for u, _ in own), sum(U[:2, :2] for _, U in own))
                              if own else None)
    for cam_id in sorted(registrations):
        picked, idx, others = rows[cam_id]
        if picked:
            at = np.array(idx, np.intp)
            # copies: the other cameras' part is added in place
            us, Us = u_o.take(at, axis=0), U_o.take(at, axis=0)
            for j, other in enumerate(others):
                if other is not None:
                    us[j] += other[0]
                    Us[j] += other[1]
            # only where the others measured the ground position in both directions: a
            # neighbour's U may honestly be PSD with a singular position block (one
            # direction only), and z_o needs U_o^-1 (a wire-valid entry like that crashed
            # update before)
            det = Us[:, 0, 0] * Us[:, 1, 1] - Us[:, 0, 1] * Us[:, 1, 0]
            ok = (det > 1e-9 * (Us[:, 0, 0] + Us[:, 1, 1]) ** 2).nonzero()[0]
            if len(ok):
                V_o = np.linalg.inv(Us.take(ok, axis=0))
                z_o = (V_o @ us.take(ok, axis=0)[..., None])[..., 0]
                registrations[cam_id].observe_many(raws[cam_id].take(np.array(picked)[ok]),
                                                   z_o, V_o)
        if cam_id in raws and registrations[cam_id].cfg.reg_relock:
            z, src = compared(cam_id)
            registrations[cam_id].vote(raws[cam_id], z, src)
        registrations[cam_id].end_frame()
