"""Online registration of one camera's ground map (our extension; docs/concepts.md, registration).

The paper assumes exact image-to-ground homographies. Real ones are not: on EPFL Terrace the same
person's foot point from two cameras lands about 0.8 m apart, on Campus about 2 m. Fusing such
measurements as if unbiased puts every estimate between the cameras' views. Multi-sensor tracking
calls the remedy *sensor registration*, or bias estimation: each sensor estimates its own
systematic error from targets it shares with other sensors and corrects its measurements before
they are associated, fused or compared (Friedland 1969, bias as a separate state; Okello & Ristic
2003 and Lin, Bar-Shalom & Kirubarajan 2004 for registration from shared targets; Fortunati et al.
2011 for the relative, reference-free case). This module does it per camera, from the residuals
between the camera's measurement of a target and the other cameras' measurements of the same
target in the same frame.

Model (R1). The foot point ``g`` a camera measures for a target at ``p`` is off by a small
similarity of its ground map plus an offset along its viewing ray (the box's bottom edge lands on
the near side of the person, not under its centre):

    g + A(g) theta ~= p,    A(g) = [ I_2 | J (g - c0) | (g - c0) | a(g) ]       (2 x 5)

with ``theta = (t_x, t_y, phi, s, delta)``: a translation, a small rotation ``phi`` and scale
``s`` about the camera's reference point ``c0``, and ``delta`` along ``a(g)``, the unit ground
direction away from the camera at ``g``. ``J`` rotates by 90 degrees.

Measurement of theta (R2). For a target this camera measured at ``g`` and the other cameras (a
neighbour's ``u, U`` of the same frame, or another camera of the same node) measured at
``z_o = U_xy^-1 u_xy`` with covariance ``V_o = U_xy^-1``:

    r = z_o - (g + A(g) theta),     r ~ N(0, V),   V = R_px + sigma^2 I + V_o

The regressor ``A`` is taken at the noisy foot point ``g`` itself, whose noise is in ``r`` too:
an errors-in-variables bias that showed as a common scale of -2 % to -3 % on a perfectly
calibrated world (more with more box noise) and -1 % to -5 % on every EPFL camera. Taking
``A`` at the tracker's prediction instead removed it on synthetic data but lost 0.01-0.1 ground
MOTA on the real EPFL sequences (terrace-gt complete 0.940 -> 0.928, campus-gt 0.569 -> 0.441,
seeds 0-2). Instead the sums get back the expected part the noise takes out
(bias-compensated least squares, ``Registration._debias``, ``reg_debias``). That part is the
camera's pixel noise (2 px); on EPFL's annotations each camera's foot point is off by far more,
independently per camera (0.8 m between cameras on Terrace, 2 m on Campus), and every camera's
fit still pulls its own scale down: the cameras' relative equations then do not add up, and the
excess goes into the common scale that no residual sees (terrace-calib seed 2: all four cameras
at -3.6 to -3.9 %). ``reg_fused`` (an option, off) takes ``A`` at the fused point of this
camera's corrected foot point and ``z_o`` (``Registration._fused_bases``): the best linear
unbiased estimate from both, whose error is orthogonal to the residual, so no noise of either
side pulls the sums. It moves the learned scales up by 1-3 % (terrace-gt -1.8..-0.2 % ->
-0.2..+1.5 %, campus-gt -6.4..-1.4 % -> -3.1..+2.4 %, the calibration world's MOTP 0.218 ->
0.186 m) but costs campus-gt 0.034 ground MOTA and terrace-gt 0.004 (seeds 0-2): the shrink is
what makes these annotations' cameras agree best, and their mean is the ground truth.
docs/tuning.md, "The registration's gauge".

``R_px`` is the pixel noise through the homography, ``sigma`` what no registration removes (R4). A residual whose normalised square exceeds ``reg_gate`` against
``V + A Sigma A^T`` is a wrong association and is ignored.

Both sides of a residual (``reg_shared``, an option, off). The other camera's ``z_o`` carries
its own registration error, and the other camera learns from the same pair of measurements towards
this one; the wire carries that error only up to ``calib_sigma``. Fitting ``r`` against ``V``
alone, each camera of a pair takes nearly the whole disagreement at its first residuals (prior
``reg_shift`` 1 m against ``V`` of about (0.45 m)^2): the two move towards each other by almost
twice the disagreement and cross. On a chain, whose cameras share few targets in the first
minutes, two of Terrace's cameras moved by +1.22 m and -0.56 m on two and three residuals
(seed 3) and the nodes tracked worse than without registration for 1,200 frames. So the
residual is weighed with the other side's registration uncertainty taken as large as this
camera's own, ``V + A Sigma A^T`` (the gate's ``S``): a camera as uncertain as its partner
takes about half of their disagreement, and the term fades as ``Sigma`` shrinks. It mends
those chains (terrace-full chain seeds 2 and 3, ground MOTA 0.866 -> 0.909 and 0.812 -> 0.907)
but costs the calibration world's seed 2 0.032 ground MOTA and Campus 0.009 image MOTA
(medians, seeds 0-2): not the default (docs/tuning.md, "Both sides of a residual").

Update (R3): a Kalman filter on theta, one batch per frame in information form,

    Sigma+^-1 = Sigma^-1 + sum_i A_i^T V_i^-1 A_i,
    theta+ = theta + Sigma+ sum_i A_i^T V_i^-1 r_i,

and between frames ``theta <- (1 - eta) theta``, ``Sigma <- (1 - eta)^2 Sigma + Q`` (``Q`` a
random walk: a camera that is bumped is followed).

Common frame (R6). Residuals only fix the cameras' errors *relative* to each other; a common
shift, rotation or scale of every camera changes no residual. The network fixes its common frame
without a centre and without a word on the wire: every camera's correction is pulled towards zero
by the same small ``eta`` (``reg_anchor``, 0.001 per frame), so a shared part decays to zero
while the data hold the differences. The common frame is therefore the mean of the cameras' own
maps, and a camera that sees nobody else's targets keeps its own map. Two limits, measured on the
calibration-error world (``terrace-calib``: 0.6-1.3 m errors): cameras converge with different
gains, so the first frames leave a common offset of 0.2-0.4 m that ``eta`` removes only over
about 1000 frames (40 s); and the scale bias above. Relative errors are learned to about 0.03 m.
What was tried: removing the neighbourhood's mean correction each frame (each node sending its
mean correction, 20 bytes) removes the offset quickly on complete graphs but biases sparse ones
against the data (ring and chain lost up to 0.03 ground MOTA at a rate of 0.02; at 0.05 a
plain neighbourhood mean even amplifies the alternating mode of a ring); a network-wide average
(dynamic average consensus) would need a state that a restarted or dead node leaves biased.
Measured again without a word on the wire: the offset is born in the first
update (0.011 m at frame 1, 0.206 m at frame 2, each camera fitting its 2-4 residuals at full
gain) and none of an unbiased regressor (``reg_fused``), a smaller shift prior, folding the
first 25 frames at once, or a firmer pull of the scale alone removes it (the last also biases
the cameras' real relative scales: terrace-calib seed 2 ground MOTA 0.961 -> 0.76-0.80).

Noise (R4). ``sigma = reg_noise`` (0.2 m) is the error of a person's foot point that no
registration removes: stance, sway, detector jitter. It is a physical constant, not learned:
residuals between cameras do not see the errors cameras share (one pose, one annotation), and
learning it from them went wrong both ways (measured, in-process replays: MOG2 detections from
rendered video, ground MOTA 0.76 with ``sigma`` learned down to 0.02 m against 0.82 at 0.2 m;
EPFL Campus, image MOTA 0.75 with ``sigma`` learned up to 0.35 m against 0.84 at 0.2 m).

What enters the tracker (R5): the corrected ``z_xy = g + A(g) theta`` and
``R_xy = R_px + sigma^2 I + A Sigma A^T`` with the last term capped so that an unconverged
correction adds at most ``calib_sigma`` (what a camera without registration assumes).

Re-locking after a knock (R7). R3 follows a slow drift (``reg_drift``), not a camera knocked a
metre or more: its detections then land outside every gate, no residual passes R2's, and they
start new trackers beside the old ones that the neighbours adopt (a bumped camera in a ring
of 4 cost its honest neighbours 0.37 ground MOTA). So each frame every pair of one of the
camera's corrected foot points and one of the other cameras' measured targets within
``reg_relock_reach`` votes for its displacement, in a grid per source (neighbour, or another
camera of the node), the votes decaying over ``reg_relock_frames``; people's own pairs pile
up at one displacement, pairs of different people spread. When the pooled peak lies at least
``reg_relock_min`` from no displacement and outweighs both the votes for none and the
residuals R2 still lets in, at least two sources agree (a strict majority of those voting
there or at none), and the camera's own foot points moved at once by that jump between two of
its recent frames (the knock's onset: a vote without correspondences cannot tell a knock from
people walking side by side, each seen by other cameras, whose distance it holds as steadily,
nor from the parts of a real view where cameras disagree by metres; in neither do the camera's
own people all jump between two frames), the peak is added to the translation and ``Sigma``
starts again from the prior, so that R3 learns the rest of the knock (its rotation) from the
residuals that now pass (:meth:`Registration.vote`). This is the coarse step of point-set
registration (a Hough vote on displacements) before the fine one.

Deterministic: the same residuals in the same order give the same correction.
"""
from __future__ import annotations

from dataclasses import dataclass

import math
from collections import deque
from collections.abc import Sequence

import numpy as np

from edge_node.core.config import Slice
from edge_node.core.measurement import BoxMeasurement, BoxMeasurements, away_direction
from edge_node.core.stacks import times
from edge_node.geometry import Camera


@dataclass(frozen=True)
class RegistrationSettings(Slice):
    """What a camera's online registration reads; each parameter's rule and doc is in its
    section of ``config.TrackerConfig``."""

    calib_sigma: float
    reg_shift: float
    reg_rotation: float
    reg_scale: float
    reg_foot: float
    reg_drift: float
    reg_noise: float
    reg_gate: float
    reg_debias: bool
    reg_fused: bool
    reg_shared: bool
    reg_anchor: float
    reg_relock: bool
    reg_relock_reach: float
    reg_relock_min: float
    reg_relock_frames: float
    reg_relock_support: float
    reg_relock_ratio: float
    reg_relock_onset: float
    units_per_metre: float
    fps: float


N_PARAMS = 5
RELOCK_CELL_M = 0.25  # m, R7's grid of displacements
RELOCK_NEAR = 1  # R7's peak and no jump are sums over (2 RELOCK_NEAR + 1)^2 cells (0.75 m)
RELOCK_SOURCES = 64  # R7 keeps votes of at most this many sources (neighbours and own cameras)
_ROT90 = np.array([[0.0, -1.0], [1.0, 0.0]])
_I2 = np.eye(2)


def _centroid(grid: np.ndarray, i: int, j: int, h: int) -> np.ndarray:
    """The vote-weighted mean offset (cells, from the grid's centre) of the ``(2h + 1)^2``
    cells of ``grid`` around cell ``(i, j)``."""
    B = grid.shape[0]
    c = B // 2
    window = grid[max(i - h, 0):i + h + 1, max(j - h, 0):j + h + 1]
    ii, jj = np.meshgrid(np.arange(max(i - h, 0), min(i + h + 1, B)),
                         np.arange(max(j - h, 0), min(j + h + 1, B)), indexing="ij")
    w = window / window.sum()
    return np.array([(w * (ii - c)).sum(), (w * (jj - c)).sum()])


def reference_point(camera: Camera) -> np.ndarray:
    """``c0``: the ground point the camera sees at the middle of its image's lower half (a point
    in the area it watches, so rotation and scale decouple from translation)."""
    W, H = camera.image_size
    for v in (0.75 * H, 0.9 * H, H - 1.0):
        g = camera.to_ground(np.array([[W / 2.0, v]]))[0]
        if np.all(np.isfinite(g)):
            return g
    return np.zeros(2)


class Registration:
    """The registration correction ``theta`` of one camera and its covariance ``Sigma``."""

    def __init__(self, camera: Camera, cfg: RegistrationSettings):
        self.camera = camera
        self.cfg = cfg
        self.c0 = reference_point(camera)
        m = cfg.m
        prior = [m(cfg.reg_shift), m(cfg.reg_shift), math.radians(cfg.reg_rotation),
                 cfg.reg_scale, m(cfg.reg_foot)]
        self.theta = np.zeros(N_PARAMS)
        self.Sigma = np.diag(np.square(prior))
        drift = m(cfg.reg_drift)
        scale_drift = drift / max(m(cfg.reg_shift), 1e-12)  # the same per-frame drift, relative
        self.Q = np.diag(np.square([drift, drift, math.radians(cfg.reg_rotation) * scale_drift,
                                    cfg.reg_scale * scale_drift, drift]))
        self.noise_var = m(cfg.reg_noise) ** 2  # sigma^2 of R4
        self.cap = m(cfg.calib_sigma) ** 2
        self.residuals = 0  # residuals used
        self.rejected = 0  # residuals outside the gate
        self._info = np.zeros((N_PARAMS, N_PARAMS))
        self._vec = np.zeros(N_PARAMS)
        self._prior = self.Sigma.copy()
        self._min_jump = m(cfg.reg_relock_min)
        # R7: the votes, one (B, B) grid of displacements per source; the jump to apply
        self.relocks = 0
        self.last_jump = np.zeros(2)  # m, the jump R7 last undid
        self._cell = m(RELOCK_CELL_M)
        self._bins = 2 * int(math.ceil(m(cfg.reg_relock_reach) / self._cell)) + 1
        self._votes = np.zeros((0, self._bins, self._bins))
        self._sources: dict[int, int] = {}  # source id -> its grid in _votes
        self._jump: np.ndarray | None = None
        self._fits = 0.0  # residuals inside R2's gate, decaying as the votes
        # R7's onset: the camera's own foot points of its last frames (as measured)
        self._history: deque[np.ndarray] = deque(maxlen=int(cfg.reg_relock_onset) + 1)

    # -- R1 and R5 ------------------------------------------------------------------------------
    def basis(self, g: np.ndarray, away: np.ndarray) -> np.ndarray:
        """``A(g)`` of R1 (2 x 5)."""
        return self.bases(np.asarray(g, float)[None], np.asarray(away, float)[None])[0]

    def bases(self, g: np.ndarray, away: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """``A(g)`` of R1 at ``(n, 2)`` ground points with their away directions: ``(n, 2, 5)``
        (into ``out``, an earlier ``bases`` of as many points, when given)."""
        e = g - self.c0
        if out is None:
            A = np.zeros((len(e), 2, N_PARAMS))
            A[:, 0, 0] = A[:, 1, 1] = 1.0
        else:
            A = out  # columns 0 and 1 hold the identity already; 2 to 4 are all overwritten
        A[:, :, 2] = e @ _ROT90.T
        A[:, :, 3] = e
        A[:, :, 4] = away
        return A

    def corrects(self, ms: BoxMeasurements | Sequence[BoxMeasurement]) -> tuple[np.ndarray, np.ndarray]:
        """R5: the corrected ``z`` ``(n, 4)`` and ``R`` ``(n, 4, 4)`` of box measurements."""
        ms = BoxMeasurements.of(ms)
        z = ms.z.copy()
        R = ms.R.copy()
        A = self.bases(z[:, :2], ms.away)
        z[:, :2] += times(A, self.theta)
        R[:, :2, :2] += _I2 * self.noise_var + self._capped(A)
        return z, R

    def _capped(self, A: np.ndarray) -> np.ndarray:
        """``A Sigma A^T`` of R5 at bases ``A`` ``(n, 2, 5)``, capped: an unconverged correction
        counts at most as ``calib_sigma``."""
        C = times(A, self.Sigma) @ A.transpose(0, 2, 1)
        top = np.linalg.eigvalsh(C)[:, -1]
        room = max(self.cap - self.noise_var, 0.0)
        return np.where((top > room)[:, None, None], C * (room / np.maximum(top, 1e-300))[:, None, None], C)

    def to_camera_many(self, xy: np.ndarray) -> np.ndarray:
        """The foot points this camera would measure for targets at corrected ground points
        ``xy (n, 2)`` (R1 inverted by fixed-point iteration): where its own boxes' bottom edges
        lie. A point whose iterate leaves the image's half-plane keeps that iterate."""
        g = np.array(xy, float)
        live = np.ones(len(g), bool)
        A = None
        with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
            for _ in range(3):
                foot, J = self.camera.image_and_jacobians(g)
                live &= np.isfinite(foot).all(axis=1)
                A = self.bases(g, away_direction(J), A)
                g = np.where(live[:, None], xy - times(A, self.theta), g)
        return g

    # -- R2 to R4 --------------------------------------------------------------------------------
    def observe(self, m: BoxMeasurement, z_other: np.ndarray, V_other: np.ndarray) -> bool:
        """One residual of this frame (R2); it is used at ``end_frame``. False when gated out."""
        return bool(self.observe_many([m], np.asarray(z_other, float)[None],
                                      np.asarray(V_other, float)[None])[0])

    def observe_many(self, ms: BoxMeasurements | Sequence[BoxMeasurement], z_other: np.ndarray,
                     V_other: np.ndarray) -> np.ndarray:
        """R2 for ``n`` residuals at once (``z_other`` ``(n, 2)``, ``V_other`` ``(n, 2, 2)``):
        which were used (not cut by the image border, inside the gate)."""
        ms = BoxMeasurements.of(ms)
        used = ~ms.cut
        if not used.any():
            return used
        idx = used.nonzero()[0]
        # (rows by take: see stacks; sliced first, so that each result is contiguous)
        z = ms.z[:, :2].take(idx, axis=0)
        away = ms.away.take(idx, axis=0)
        A = self.bases(z, away)
        Vo = V_other.take(idx, axis=0)
        V = ms.R[:, :2, :2].take(idx, axis=0) + _I2 * self.noise_var + Vo
        zo = z_other.take(idx, axis=0)
        r = zo - (z + times(A, self.theta))
        S = V + times(A, self.Sigma) @ A.transpose(0, 2, 1)
        if self.cfg.reg_fused:
            A = self._fused_bases(z, away, A, Vo, zo, ms.R[:, :2, :2].take(idx, axis=0))
        nis = np.einsum("ni,ni->n", r, np.linalg.solve(S, r[..., None])[..., 0])
        ok = nis <= self.cfg.reg_gate  # False for nan too
        self.rejected += int(len(idx) - ok.sum())
        used[idx] = ok
        if ok.any():
            if self.cfg.reg_shared:  # the other side's uncertainty, taken as this side's (R2)
                V = S
            A, V, r = A.compress(ok, axis=0), V.compress(ok, axis=0), r.compress(ok, axis=0)
            W = np.linalg.inv(V)
            AtW = A.transpose(0, 2, 1) @ W  # A^T V^-1 per residual
            self._info += (AtW @ A).sum(axis=0)
            self._vec += (AtW @ r[..., None])[..., 0].sum(axis=0)
            if self.cfg.reg_debias and not self.cfg.reg_fused:
                self._vec += self._debias(W, ms.R[:, :2, :2].take(idx, axis=0).compress(ok, axis=0))
            self.residuals += int(ok.sum())
            self._fits += float(ok.sum())
        return used

    def _fused_bases(self, g: np.ndarray, away: np.ndarray, A: np.ndarray, Vo: np.ndarray,
                     zo: np.ndarray, Rpx: np.ndarray) -> np.ndarray:
        """R2's regressor at the fused point of this camera's corrected foot point (its
        covariance as the wire carries it, ``R5``) and the others' ``z_o, V_o``: the
        best linear unbiased estimate of the target from both, whose error is uncorrelated with
        the residual ``z_o - y`` (the estimate's error is orthogonal to the innovation), so the
        regressor's noise no longer pulls the sums (errors in variables) whatever the noise."""
        y = g + times(A, self.theta)
        Ry = Rpx + _I2 * self.noise_var + self._capped(A)
        Wy, Wo = np.linalg.inv(Ry), np.linalg.inv(Vo)
        x = np.linalg.solve(Wy + Wo, ((Wy @ y[..., None]) + (Wo @ zo[..., None])))[..., 0]
        return self.bases(x - (y - g), away)

    @staticmethod
    def _debias(W: np.ndarray, Rg: np.ndarray) -> np.ndarray:
        """The errors-in-variables term R2's sums lack (``W`` ``(n, 2, 2)`` the residuals'
        ``V^-1``, ``Rg`` the covariance of this camera's own foot point ``g`` through its pixels,
        ``R_px``: the stance part ``sigma`` is the person's, shared by every camera's view of
        them, so no noise of ``g`` about the point the cameras agree on). ``A`` is taken at
        the noisy ``g = p + n``, whose noise ``n`` is in ``r`` too with the opposite sign, so
        ``E[A^T W r]`` holds ``-E[(J n)^T W n] = -tr(J^T W Rg)`` in the rotation's row and
        ``-E[n^T W n] = -tr(W Rg)`` in the scale's: summed over residuals, a pull towards a
        smaller, turned map that is no error of the camera's (the -1 % to -5 % shrink measured
        on every EPFL camera and on the perfectly calibrated synthetic world). Added back here
        (bias-compensated least squares), so the expected sum is that of noise-free
        regressors."""
        WR = W @ Rg
        out = np.zeros(N_PARAMS)
        out[2] = float(np.einsum("ij,nji->", _ROT90.T, WR))  # sum of tr(J^T W Rg)
        out[3] = float(np.trace(WR, axis1=1, axis2=2).sum())  # sum of tr(W Rg)
        return out

    # -- R7 ------------------------------------------------------------------------------------
    def vote(self, ms: BoxMeasurements, z_other: np.ndarray, source: np.ndarray) -> None:
        """R7: this frame's votes on where this camera's map has jumped to. Every pair of one of
        its corrected foot points (``ms``, not cut) and one of the other cameras' measured
        targets of the frame (``z_other`` ``(m, 2)``, each from ``source`` ``(m,)``, a neighbour's
        id or this node's other camera's) within ``reg_relock_reach`` votes for its displacement
        ``z_other - y`` in a grid of ``RELOCK_CELL_M`` cells, one grid per source, the votes
        decaying over ``reg_relock_frames``. A jump is taken (:meth:`end_frame`) when the grid
        pooled over the sources has its peak (3 x 3 cells) at least ``reg_relock_min`` from no
        jump, with ``reg_relock_support`` votes and ``reg_relock_ratio`` times both the votes for
        no jump and the residuals R2's gate let in over the same memory (a map that still fits
        its associated targets has not jumped: on EPFL's annotations the cameras' foot points
        disagree by up to 2 m in parts of a view, and the displacements' peak wanders there),
        beyond R2's gate on the translation's own uncertainty (a camera still learning its map,
        ``Sigma`` near the prior, is left to R3: re-locking then put the calibration world's
        rotations 1.1 degrees off at frame 290 instead of within 1), and a strict majority of
        the sources that vote there or at no jump, at least two, say the same (a camera seen by
        two neighbours that agree moved; a neighbour of a knocked camera, told of a jump by it
        alone and of none by its other neighbour, did not; and of two cameras that only see each
        other, neither can tell which of them moved: both would jump, and disagree again the
        other way, so neither does), and the camera's own foot points of its last
        ``reg_relock_onset`` frames show the knock's onset (:meth:`_knocked`)."""
        cfg = self.cfg
        if not cfg.reg_relock:
            return
        self._votes *= 1.0 - 1.0 / cfg.reg_relock_frames
        self._fits *= 1.0 - 1.0 / cfg.reg_relock_frames
        take = (~ms.cut).nonzero()[0]
        g = ms.z[:, :2].take(take, axis=0)
        self._history.append(g)
        if not len(take) or not len(z_other):
            return
        y = g + times(self.bases(g, ms.away.take(take, axis=0)), self.theta)
        B, cell = self._bins, self._cell
        D = z_other[None] - y[:, None]  # (n, m, 2)
        heard, which = np.unique(source, return_inverse=True)
        slots = np.array([self._slot(int(src)) for src in heard.tolist()], np.intp).take(which)
        at = np.floor(D / cell + B / 2.0).astype(np.intp)  # (n, m, 2)
        within = at.astype(np.uintp) < B  # (a cell below 0 wraps to a huge unsigned one)
        inside = within[..., 0] & within[..., 1] & (slots >= 0)[None]
        flat = (slots[None] * B + at[..., 0]) * B + at[..., 1]
        S = len(self._sources)
        self._votes += np.bincount(flat[inside], minlength=S * B * B).reshape(S, B, B)
        self._decide()

    def _knocked(self, jump: np.ndarray) -> bool:
        """R7's onset: whether this camera's own foot points (as measured, before any
        correction), between two consecutive frames of the last ``reg_relock_onset``, moved at
        once by the jump the votes undo (``-jump``) rather than staying put: pairs of a foot
        point and one of the frame before whose displacement lies within ``reg_relock_min`` of
        ``-jump``, at least two and ``reg_relock_ratio`` times those within ``reg_relock_min``
        of none. A knock moves every person the camera sees between two frames (by the jump
        near the view's reference point, more or less with the rotation farther off); a person
        walks a few centimetres. People walking side by side, whose distance the votes against
        the other cameras hold as steadily as a knock's, and the parts of a view where EPFL's
        cameras disagree by metres, never move at once in the camera's own frames."""
        r2 = self._min_jump ** 2
        frames = list(self._history)
        for prev, now in zip(frames, frames[1:]):
            if len(prev) and len(now):
                D = now[:, None] - prev[None]
                moved = int((((D + jump) ** 2).sum(axis=2) < r2).sum())
                stayed = int(((D ** 2).sum(axis=2) < r2).sum())
                if moved >= 2 and moved >= self.cfg.reg_relock_ratio * stayed:
                    return True
        return False

    def _slot(self, source: int) -> int:
        """The grid of ``source`` in ``_votes`` (a new one, empty, for a source first heard;
        -1, no votes, beyond ``RELOCK_SOURCES``: the memory stays bounded)."""
        slot = self._sources.get(source)
        if slot is None:
            if len(self._sources) >= RELOCK_SOURCES:
                return -1
            slot = self._sources[source] = len(self._sources)
            self._votes = np.concatenate([self._votes, np.zeros((1, self._bins, self._bins))])
        return slot

    def _decide(self) -> None:
        """R7's test on the votes (:meth:`vote`); sets the jump to take at :meth:`end_frame`."""
        cfg, B = self.cfg, self._bins
        h = RELOCK_NEAR  # the peak's and no jump's window: (2h + 1) x (2h + 1) cells
        total = self._votes.sum(axis=0)  # pooled over the sources, then over each window
        padded = np.pad(total, h)
        pooled = sum(padded[a:a + B, b:b + B] for a in range(2 * h + 1) for b in range(2 * h + 1))
        i, j = divmod(int(pooled.argmax()), B)
        c = B // 2
        if math.hypot(i - c, j - c) * self._cell < self._min_jump or pooled[i, j] < cfg.reg_relock_support \
                or pooled[i, j] < cfg.reg_relock_ratio * max(pooled[c, c], self._fits):
            return
        # each source's votes in the two windows the test reads
        there = self._votes[:, max(i - h, 0):i + h + 1, max(j - h, 0):j + h + 1].sum(axis=(1, 2))
        none = self._votes[:, c - h:c + h + 1, c - h:c + h + 1].sum(axis=(1, 2))
        voting = (there + none) > 0.0
        agree = voting & (there > cfg.reg_relock_ratio * none)
        if int(agree.sum()) < 2 or 2 * int(agree.sum()) <= int(voting.sum()):
            return
        reach = self.cfg.reg_gate * float(np.linalg.eigvalsh(self.Sigma[:2, :2])[-1])
        if ((i - c) ** 2 + (j - c) ** 2) * self._cell ** 2 <= reach:
            return  # within what R3 still expects of its translation: R3 follows it
        jump = _centroid(total, i, j, h) * self._cell
        if self._knocked(jump):  # the camera's own people jumped at once (:meth:`_knocked`)
            self._jump = jump

    def end_frame(self) -> None:
        """R3: fold this frame's residuals into ``theta``, then step to the next frame (R6's
        pull, and the random walk). R7: a jump found this frame (:meth:`vote`) is added to the
        translation instead, ``Sigma`` starts again from the prior (the rotation and scale of
        the knock are then learned by R3 from the residuals that now pass the gate) and the
        votes start again."""
        if self._jump is not None:
            self.theta = self.theta.copy()
            self.theta[:2] += self._jump
            self.last_jump = self._jump / self.cfg.units_per_metre
            self.Sigma = self._prior.copy()
            self._info = np.zeros((N_PARAMS, N_PARAMS))
            self._vec = np.zeros(N_PARAMS)
            self._votes = np.zeros_like(self._votes)
            self._jump = None
            self._history.clear()
            self.relocks += 1
        if self._info.any():
            info = np.linalg.inv(self.Sigma) + self._info
            Sigma = np.linalg.inv(info)
            self.theta = self.theta + Sigma @ self._vec
            self.Sigma = 0.5 * (Sigma + Sigma.T)
            self._info = np.zeros((N_PARAMS, N_PARAMS))
            self._vec = np.zeros(N_PARAMS)
        keep = 1.0 - self.cfg.reg_anchor
        self.theta = keep * self.theta
        self.Sigma = keep * keep * self.Sigma + self.Q

    # -- reading -----------------------------------------------------------------------------------
    def snapshot(self) -> "Registration":
        """A copy of the current estimate (for a record of how it evolved)."""
        r = Registration.__new__(Registration)
        r.__dict__.update(self.__dict__)
        r.theta, r.Sigma = self.theta.copy(), self.Sigma.copy()
        r._info, r._vec = self._info.copy(), self._vec.copy()
        r._votes, r._sources = self._votes.copy(), dict(self._sources)
        r._history = deque(self._history, maxlen=self._history.maxlen)
        return r

    def correction_at(self, xy: np.ndarray) -> np.ndarray:
        """``A(g) theta`` at ground point ``g`` as this camera measures it (its foot point)."""
        xy = np.asarray(xy, float)
        foot = self.camera.to_image(xy[None])[0]
        away = away_direction(self.camera.ground_jacobian(foot)) if np.all(np.isfinite(foot)) \
            else np.zeros(2)
        return self.basis(xy, away) @ self.theta

    def summary(self, units_per_metre: float = 1.0) -> dict:
        t = self.theta
        return {"shift_m": [float(t[0]) / units_per_metre, float(t[1]) / units_per_metre],
                "rotation_deg": math.degrees(float(t[2])), "scale": float(t[3]),
                "foot_m": float(t[4]) / units_per_metre, "residuals": self.residuals,
                "rejected": self.rejected, "relocks": self.relocks}

