"""All tracker parameters in one tree, one section per role, with the ablation switch of the
paper's Section IV-B.

``TrackerConfig`` holds one frozen section per role of a node (``[tracker.predictor]``,
``[tracker.associator]``, ... below), plus ``scene`` (units and time, shared) and ``parts`` (which
parts a node is assembled from). Every parameter is declared once, in its role's section, with
its rule and doc (``params``); parameter names are unique across sections, so a flat name
(``TrackerConfig(tau=2.5)``, ``cfg.tau``, ``[tracker] tau = 2.5`` in a file) reaches it in its
section. A role reads only its slice (``Slice``): the parameters it names, from whichever
sections they are declared in; ``node.assemble`` hands each role its own.

Units. Every length below is in **metres** (speeds in m/s) and is converted to the scenario's
ground units by ``units_per_metre`` (1 for the synthetic world; about 30 for EPFL, whose
homographies do not map to metres). The paper's values (``alpha_LDA = 2000``, ``alpha_GDA = 50``,
``tau = 0.5``, ``kappa = 15``, ``epsilon = 0.25``, gallery 20, ``N = 20``) are tied to its own
ground units and score normalisation; ``kappa``, ``epsilon``, the gallery size and ``N`` carry
over unchanged, while the gates are re-expressed here:

* ``tau`` is a gate on the Mahalanobis distance of eq. 5 in standard deviations (3.0 keeps 98.9%
  of true 2-D innovations); pairs outside it are never assigned (the paper scores them 1).
* ``alpha_lda`` normalises ``s_d = d / alpha`` (eq. 6); inside the gate it only scales all costs,
  so it does not change the optimal assignment. Default ``tau`` so ``s_d`` lies in ``[0, 1)``.
* ``tau_gda`` / ``alpha_gda`` are the Euclidean gate and normaliser (``V = I``) of the
  distributed global data association, in metres: ``tau_gda`` gates the second association
  stage (a left-over measurement against another camera's tracker); duplicate trackers merge
  within the tighter ``comotion_gate`` (:func:`edge_node.core.manager.pair_score`).
"""
from __future__ import annotations

import difflib
from dataclasses import dataclass, fields
from typing import Any

from edge_node.core.params import (ConfigError, boolean, check, declared, integer, nonnegative,
                                   number, pair, positive)

ABLATIONS = ("dkf", "dkf+lda", "dkf+lda+dtm")  # the paper's three (Sec. IV-B)
# ours: the manager without appearance (what a detector without re-id gives), and every
# configuration without online registration (":noreg", the paper's exact homographies)
CONFIGS = ABLATIONS + ("dkf+dtm",)
CONFIG_NAMES = CONFIGS + tuple(f"{c}:noreg" for c in CONFIGS)

__all__ = ["ABLATIONS", "CONFIGS", "CONFIG_NAMES", "ConfigError", "SECTIONS", "Slice", "TrackerConfig"]


@dataclass(frozen=True)
class SceneSection:
    """``[tracker.scene]``: units and time, shared by every role."""

    units_per_metre: float = positive(1.0, "ground units per metre")
    fps: float = positive(25.0, "frames per second")

    def __post_init__(self) -> None:
        check(self, "tracker.scene")


@dataclass(frozen=True)
class PartsSection:
    """``[tracker.parts]``: the ablation switches of the paper's Sec. IV-B and online registration (``assembly.assemble``)."""

    use_appearance: bool = boolean(True, "LDA: appearance score s_a in the association cost (eq. 7)")
    use_manager: bool = boolean(True, "DTM: global association/merge, consensus drop (eq. 8), re-id")
    registration: bool = boolean(True, "estimate and correct each camera's ground registration")

    def __post_init__(self) -> None:
        check(self, "tracker.parts")


@dataclass(frozen=True)
class PredictorSection:
    """``[tracker.predictor]``: the motion model, ``A`` and ``Q`` of eq. 1 (``predictor``, ``model``)."""

    accel_sigma: float = positive(1.0, "m/s^2, white-noise acceleration on the constant-velocity part")
    size_sigma: float = nonnegative(0.01, "m per frame, random walk on (w, h)")

    def __post_init__(self) -> None:
        check(self, "tracker.predictor")


@dataclass(frozen=True)
class MeasurerSection:
    """``[tracker.measurer]``: the measurement model, ``H`` and ``R_i`` (``measurer``, ``measurement``)."""

    pixel_sigma: float = positive(2.0, "px, detector noise on box edges, through the homography")
    calib_sigma: float = nonnegative(0.4, "m, per-camera ground offset (calibration + foot point)")
    size_meas_floor: float = positive(0.05, "m, minimum sigma on measured w, h")
    border_px: float = nonnegative(1.0, "px, a box this close to the image border is cut by it")
    fixed_R: tuple[float, float] | None = pair(
        None, lo=0.0, lo_open=True, optional=True,
        doc="(sigma_xy, sigma_wh) in m: the paper's fixed R instead of the propagated one")

    def __post_init__(self) -> None:
        check(self, "tracker.measurer")


@dataclass(frozen=True)
class RegistrarSection:
    """``[tracker.registrar]``: online registration of each camera (``registrar``, ``registration``)."""

    reg_shift: float = positive(1.0, "m, prior sigma of a camera's ground translation error")
    reg_rotation: float = positive(3.0, "degrees, prior sigma of its rotation error")
    reg_scale: float = positive(0.03, "prior sigma of its scale error (a fraction)")
    reg_foot: float = positive(0.5, "m, prior sigma of its foot-point offset along the viewing ray")
    reg_drift: float = nonnegative(0.005, "m per frame, random walk of a registration (bumps)")
    reg_noise: float = positive(0.2, "m, sigma of a corrected foot point's error (stance, sway)")
    reg_gate: float = positive(13.8, "chi-square gate on a registration residual (2 dof, 99.9%)")
    reg_debias: bool = boolean(True, "compensate the errors-in-variables shrink of R2's scale")
    reg_fused: bool = boolean(False, "R2's regressor at the fused point of the camera's and the "
                                     "others' measurements (no shrink at any noise; replaces reg_debias)")
    reg_shared: bool = boolean(False, "R2 counts the other camera's registration uncertainty as "
                                      "large as this camera's own (both sides of a residual correct "
                                      "towards each other): for chains and networks whose cameras "
                                      "share few people; docs/tuning.md")
    reg_anchor: float = number(0.001, lo=0.0, hi=1.0,
                               doc="per frame, pull of every correction towards zero (common frame)")
    reg_relock: bool = boolean(True, "re-lock a camera whose map jumped (knocked) onto the others' "
                                     "targets (R7, edge_node/core/registration.py)")
    reg_relock_reach: float = positive(4.0, "m, the largest jump R7 looks for")
    reg_relock_min: float = positive(0.75, "m, the smallest jump R7 re-locks (smaller: R3 follows)")
    reg_relock_frames: float = positive(10.0, "frames, the memory of R7's votes")
    reg_relock_support: float = positive(15.0, "votes (pairs, decayed) the jump needs")
    reg_relock_ratio: float = positive(2.0, "votes for the jump against votes for no jump, pooled and per source")
    reg_relock_onset: float = positive(50.0, "frames R7 may take to re-lock after the camera's own "
                                             "people all moved at once (the knock's onset)")

    def __post_init__(self) -> None:
        check(self, "tracker.registrar")


@dataclass(frozen=True)
class AssociatorSection:
    """``[tracker.associator]``: local data association, eqs. 5-7, the gallery (eq. 7) and the node's measured re-id (``associator``, ``association``, ``gallery``, ``reidquality``)."""

    tau: float = positive(3.0, "Mahalanobis gate (standard deviations)")
    alpha_lda: float = positive(3.0, "s_d = d / alpha_lda")
    unknown_appearance: float = nonnegative(0.5, "s_a when a tracker has no gallery yet")
    appearance_gate: float = nonnegative(0.6, "pairs with s_a above this are never assigned")
    recover: bool = boolean(True, "second LDA stage: GDA gate and appearance for the left-overs")
    naive_bound: bool = boolean(True, "gate a tracker that only the consensus updates with a covariance bounded by ell")
    naive_yield: bool = boolean(True, "a tracker only the consensus updated last frame gives up a measurement to a nearer tracker this node measures (within comotion_gate); docs/tuning.md")
    gallery_size: int = integer(20, lo=1)
    gallery_every: int = integer(20, lo=1, doc="N: a new descriptor every N frames")
    gallery_admit: float = nonnegative(0.35, "a descriptor joins only if s_a to the gallery is below this")
    reid_learn: bool = boolean(True, "measure the re-id on the node's own frames and set the appearance thresholds by it (edge_node/core/reidquality.py)")
    reid_error: float = number(0.05, lo=0.0, lo_open=True, hi=0.5, doc="error rate each learned appearance threshold allows: one person's distances above it, two people's below")
    reid_samples: int = integer(500, lo=1, doc="distances of one person and of two people a node needs before its thresholds follow them")
    reid_memory: int = integer(20000, lo=1, doc="distances kept per side: halved above (a bounded memory that follows a change)")

    def __post_init__(self) -> None:
        check(self, "tracker.associator")


@dataclass(frozen=True)
class InitiatorSection:
    """``[tracker.initiator]``: local births and the birth prior, identical on every node that adopts a tracker (``initiator``, ``lifecycle``)."""

    init_observations: int = integer(2, lo=1, doc="paper: two observations in the local gallery")
    candidate_gate: float = positive(0.8, "m, how far a second observation may be from the first")
    candidate_max_age: int = integer(3, lo=1, doc="frames a single observation waits for its second")
    candidate_appearance: float = nonnegative(0.5, "max cosine distance between the two observations")
    birth_pos_sigma: float = positive(0.5, "m")
    birth_size_sigma: float = positive(0.2, "m")
    birth_vel_sigma: float = positive(1.5, "m/s")

    def __post_init__(self) -> None:
        check(self, "tracker.initiator")


@dataclass(frozen=True)
class InboundSection:
    """``[tracker.inbound]``: what a neighbour's message may claim (``screen``) and the event-triggered memory (``memory``)."""

    world_radius: float = positive(1000.0, "m, states farther than this from every camera of the node are implausible")
    max_size: float = positive(20.0, "m, largest plausible target width or height")
    max_trackers_per_neighbour: int = integer(1024, lo=1, doc="the most tracker entries one neighbour's message may bring (it relays the network's trackers: 1024 is 64 cameras of 16 people); entries beyond are dropped, those this node holds kept first")
    max_adoptions_per_frame: int = integer(64, lo=1, doc="new trackers adopted from one neighbour in one frame (people appear a few at a time; a restarted node takes the network's trackers over a few frames); the rest wait for the next frame")
    max_speed: float = positive(15.0, "m/s, largest plausible speed of an estimate, for walking people: no person runs faster than 12.4 m/s, and honest estimates reached 9.3 on campus-gt, where the cameras disagree by 2 m (a state relayed faster is refused as implausible_state: a faulty neighbour's cannot run away)")
    staleness_frames: int = integer(2, lo=0, doc="a neighbour's u, U older than this is ignored")
    hold_frames: int = integer(5, lo=0, doc="a silent neighbour's ell holds this many frames "
                               "(its trigger's heartbeat), then ages")

    def __post_init__(self) -> None:
        check(self, "tracker.inbound")


@dataclass(frozen=True)
class TrustSection:
    """``[tracker.trust]``: which neighbours a node believes, against a plausible but wrong peer
    (``trust``: a CUSUM per neighbour of its entries' consistency with the node's prediction)."""

    trust_check: bool = boolean(True, "judge each neighbour's consistency and quarantine one that stands out (edge_node/core/trust.py)")
    trust_drift: float = positive(6.0, "per frame, the score (median normalised distance of a neighbour's entries, 2 dof) an honest neighbour may reach without adding to its sum (the 95 % point of chi-square 2)")
    trust_ratio: float = positive(3.0, "the allowance is at least this times the other neighbours' median score: when all disagree (registration not converged), none stands out")
    trust_cap: float = positive(100.0, "bound on one entry's normalised distance (one frame cannot condemn)")
    trust_merge: float = positive(20.0, "added to a neighbour's sum once per pair of trackers it announces a merge of that this node's own cameras see as two people farther apart than the merge rules reach")
    trust_apart: float = positive(5.0, "added to a neighbour's sum once per pair of trackers it announces a merge of that are farther apart than the merge rules reach in this node's estimates only (honest networks announce a few: consensus lags two hops away)")
    trust_gate: float = positive(13.8, "a suspect neighbour's entry farther than this (chi-square 2, 99.9 %) is dropped")
    trust_suspect: float = positive(30.0, "sum at which a neighbour is suspect: its merges and new ids are not taken")
    trust_quarantine: float = positive(100.0, "sum at which a neighbour is quarantined: none of its entries is used")
    trust_readmit: int = integer(25, lo=1, doc="frames in a row within the allowance after which a suspect or quarantined neighbour is trusted again")
    trust_lag: float = positive(0.3, "s, the lag of a neighbour's measurements behind this node's own cameras' (least squares on its velocity estimates, beyond the lag of the message's own frame) above which it counts against the neighbour: a box re-sending old frames as new (stale)")
    trust_lag_z: float = positive(3.0, "standard errors by which a neighbour's lag must exceed trust_lag to count; each frame it does adds (z - trust_lag_z)^2 to its sum")
    trust_lag_frames: int = integer(50, lo=1, doc="frames the lag estimate remembers (its forgetting factor is 1 - 1/trust_lag_frames)")
    trust_refuted: float = nonnegative(2.0, "added to a neighbour's refuted sum per entry of this frame in which it claims to measure a target that this node's own cameras should have measured and have not for unseen_limit frames in a row (negative evidence, [tracker.reporter]): a detector that sees people who are not there; 0: off")
    trust_refuted_allow: float = nonnegative(1.0, "entries a frame that an honest neighbour may have refuted without adding to its refuted sum: one person it sees that this node's cameras cannot (behind something the tracker does not know of), for as long as he stays there")

    def __post_init__(self) -> None:
        check(self, "tracker.trust")


@dataclass(frozen=True)
class UpdaterSection:
    """``[tracker.updater]``: the consensus step of eq. 4 (``updater``, ``dkf``: the stability of the consensus step)."""

    consensus_bound: float = number(0.9, lo=0.0, lo_open=True, hi=1.0,
                                    doc="gamma of eq. 4 is scaled down where degree * ||gamma M||_2 would exceed this (below 1: every disagreement mode decays)")

    def __post_init__(self) -> None:
        check(self, "tracker.updater")


@dataclass(frozen=True)
class ManagerSection:
    """``[tracker.manager]``: the distributed tracker manager: eq. 8, merges, re-identification, scope (``lifecycle``, ``manager``, ``reappear``, ``identity``)."""

    tau_gda: float = positive(1.5, "m, Euclidean gate (V = I) of a left-over measurement to another camera's tracker")
    alpha_gda: float = positive(1.5, "m, s_d normaliser of the global association")
    merge_appearance: float = nonnegative(0.4, "galleries farther apart (cosine) are never merged")
    comotion_gate: float = positive(1.0, "m, how close two trackers of one target stay")
    comotion_frames: int = integer(25, lo=1, doc="frames a tracker counts as new on a node: hidden while on its way to a merge (hide_pending); 25 covers a merge at merge_llr when two cameras each measure one of the pair (22 frames of 1.39 nats)")
    comotion_miss: float = number(0.5, lo=0.0, lo_open=True, hi=0.99, doc="chance that a camera which sees two people within the comotion_gate measures only one of them (one hidden behind the other, a miss)")
    comotion_split: float = number(0.02, lo=0.0, lo_open=True, hi=0.5, doc="chance that a camera measures one person as two (its detector splits a person into two boxes)")
    merge_llr: float = positive(30.0, "nats of co-motion evidence (one target against two) at which two trackers merge")
    merge_llr_floor: float = number(-70.0, hi=0.0, doc="nats: the least co-motion evidence kept for a pair (two trackers once seen as two people merge after this much more)")
    merge_evidence: bool = boolean(False, "merge by co-motion only where this node's camera or a neighbour measures both trackers (README, What we tuned: large gains with look-alikes, Campus loses)")
    merge_announce_frames: int = integer(3, lo=1, doc="frames a merge announcement is repeated")
    kappa: int = integer(15, lo=1, doc="drop a tracker when ell exceeds kappa (eq. 8)")
    epsilon: float = nonnegative(0.25, "re-identification threshold on s_a against old trackers")
    max_old_trackers: int = integer(200, lo=1, doc="bounded memory of dropped trackers")
    max_old_mib: float = positive(4.0, "MiB, byte budget of the dropped trackers' galleries, kept as float16 (200 full galleries of 512-d descriptors take 3.9)")
    reid_frames: int = integer(50, lo=0, doc="without appearance: frames a dropped tracker may be re-identified")
    reid_gate: float = positive(1.5, "m, how near a new tracker's birth a dropped tracker must be (without appearance; with it, plus reid_speed x the time since the drop)")
    reid_speed: float = positive(2.0, "m/s, how fast a dropped person may have walked to where a new tracker re-identified as them is born")
    reappear: bool = boolean(True, "re-identification by motion: a new tracker that goes on where a dropped one was heading takes its id (edge_node/core/reappear.py)")
    reappear_age: int = integer(10, lo=1, doc="frames after a new tracker's birth at which its course since birth is compared with the dropped trackers'")
    reappear_frames: int = integer(150, lo=1, doc="frames from when a dropped tracker was last seen to a birth within which the new tracker may be it re-appearing")
    reappear_gate: float = positive(1.5, "m, how near the two courses, carried to the middle of the gap, must meet")
    reappear_spread: float = nonnegative(0.0, "m/s, how much farther apart the courses may meet per second of the gap (a hidden walker's course bends)")
    reappear_hide: int = integer(4, lo=0, doc="frames after reappear_age a new tracker that may re-appear is still not reported (the decision's announcement travels a hop a frame)")
    heir_pending: bool = boolean(True, "a tracker dropped while a younger one was on its way to merging into it (positive co-motion evidence) gives that one its id (manager.partner)")
    stitch: bool = boolean(False, "a tracker dropped while a younger one, born beside it since it was last seen, goes on where it was gives that one its id (tracklet stitching, manager.heir)")
    scope_hops: int = integer(0, lo=0, doc="regional scope (not in the paper; needs the DTM): a node keeps and sends a tracker only within this many hops of the cameras that see it; 0 = every node holds every tracker (the paper)")

    def __post_init__(self) -> None:
        check(self, "tracker.manager")


@dataclass(frozen=True)
class ReporterSection:
    """``[tracker.reporter]``: what a node reports and draws in each camera's own view (``reporter``, ``views``)."""

    report_coast: int = integer(1, lo=0, doc="frames a tracker nobody sees is still reported")
    report_age: int = integer(10, lo=0, doc="frames a new tracker must have lived, counted from its birth at its camera, before it is reported if it is tentative (report_near; docs/tuning.md)")
    report_near: float = number(2.0, lo=0.0, doc="m, a new tracker is tentative (report_age) while a tracker of earlier rank is this near it that the node's co-motion evidence does not know for a second person, until it is first reported; 0: every new tracker is")
    hide_pending: bool = boolean(True, "a tracker new on this node (within comotion_frames) that "
                                 "agrees with an older one towards a merge is not reported "
                                 "until the pair merges or parts")
    pending_alias: bool = boolean(True, "a tracker on its way to merging into an older one (positive co-motion evidence) is reported under the older id while the older is not reported (docs/tuning.md)")
    view_frames: int = integer(100, lo=0, doc="frames a camera keeps drawing a target it last saw")
    view_rate: float = number(0.2, lo=0.0, hi=1.0,
                              doc="smoothing of a camera's own box: its size and where it sits")
    view_place: bool = boolean(True, "draw a target where the camera last saw it against the "
                               "network's estimate, not at the estimate alone")
    view_locate: float = positive(0.5, "m, a measurement whose foot point is less sure than this "
                                  "(one sigma) teaches a camera's view neither size nor place")
    view_behind: float = number(0.5, lo=0.0, hi=1.0,
                                doc="fraction of a box a nearer measured target's box must cover "
                                "to draw a target the camera has not measured for view_frames "
                                "(1: such targets are not drawn)")
    view_depth: float = nonnegative(0.2, "how much nearer that target stands: its box's bottom "
                                    "edge lower by this fraction of the hidden box's height")
    view_unseen: bool = boolean(False, "draw targets a camera has not seen (at the network's size)")
    report_unseen: int = integer(10, lo=0, doc="the least number of frames in a row one of the "
                                 "node's cameras should have measured a target (its box inside the "
                                 "image, no nearer target covering a third of it) and none did, "
                                 "after which the node no longer reports it (a neighbour's false "
                                 "person); the limit itself is learnt, unseen_runs (0: never; "
                                 "docs/tuning.md)")
    unseen_runs: int = integer(200, lo=0, doc="with report_unseen: how many of the node's latest "
                               "ended runs of such frames (a target it should have measured, "
                               "missed, then measured again: a real person it misses that long) "
                               "it keeps to learn how long its cameras miss real people; the "
                               "limit is then above the longest of them but a fraction "
                               "unseen_tail, and report_unseen only its floor (0: report_unseen "
                               "alone)")
    unseen_tail: float = number(0.0, lo=0.0, hi=0.5, doc="fraction of the kept runs, rounded "
                                "down, the learnt limit may fall below (the longest real misses, "
                                "which then hide a real person for what they run beyond it)")
    view_inside: float = number(0.9, lo=0.0, hi=1.0,
                                doc="least fraction of a drawn box inside the image (0: any overlap)")
    view_fresh: int = integer(50, lo=0, doc="frames since the camera's last measurement of a target "
                              "after which a nearer target can hide it")
    view_hidden: float = number(1.0, lo=0.0, hi=1.0,
                                doc="fraction of a box a nearer drawn box must cover to hide it (1: never; docs/tuning.md)")
    view_twin: float = number(0.5, lo=0.0, lo_open=True, hi=1.0,
                              doc="IoU with the drawn box of a target the camera measured more "
                              "recently, at the same depth (view_depth), from which a target is "
                              "that person drawn twice and is not drawn, unless the node knows "
                              "the two for two people (1: never; docs/tuning.md)")

    def __post_init__(self) -> None:
        check(self, "tracker.reporter")


#: the tree's sections in order: section name -> its dataclass
SECTIONS: dict[str, type] = {
    "scene": SceneSection, "parts": PartsSection, "predictor": PredictorSection,
    "measurer": MeasurerSection, "registrar": RegistrarSection, "associator": AssociatorSection,
    "initiator": InitiatorSection, "inbound": InboundSection, "trust": TrustSection,
    "updater": UpdaterSection,
    "manager": ManagerSection, "reporter": ReporterSection,
}
#: every parameter's section (names are unique across sections: a test checks it)
SECTION_OF: dict[str, str] = {f.name: s for s, cls in SECTIONS.items() for f in fields(cls)}


def _unknown(names: list[str], known) -> str:
    """Unknown parameter names, each with the known names it could be a misspelling of, and
    where the known ones are listed."""
    out = []
    for n in sorted(names):
        close = difflib.get_close_matches(n, list(known), n=3, cutoff=0.6)
        out.append(f"{n} (did you mean {' or '.join(close)}?)" if close else n)
    where = ", ".join(f"[tracker.{s}]" for s in SECTIONS)
    return (f"{', '.join(out)}; every parameter is in one section of {where} "
            "(edge_node check prints the tree; docs/api.md lists them)")


class _Units:
    """``m()`` and ``dt`` of anything with ``units_per_metre`` and ``fps``."""

    def m(self, metres: float) -> float:
        """Metres to ground units."""
        return metres * self.units_per_metre

    @property
    def dt(self) -> float:
        return 1.0 / self.fps


@dataclass(frozen=True, init=False, repr=False)
class TrackerConfig(_Units):
    """The tracker's parameters: one frozen section per role (module docstring).

    ``TrackerConfig(tau=2.5, registration=False)`` or ``TrackerConfig(associator=...)``: flat
    parameter names go to their sections, a section may be given whole (a section object or a
    table of its parameters; flat names given beside it change it). ``cfg.associator.tau`` and
    ``cfg.tau`` read the same value. Immutable; ``with_(**changes)`` (or
    ``dataclasses.replace``) makes a changed copy."""

    scene: SceneSection
    parts: PartsSection
    predictor: PredictorSection
    measurer: MeasurerSection
    registrar: RegistrarSection
    associator: AssociatorSection
    initiator: InitiatorSection
    inbound: InboundSection
    trust: TrustSection
    updater: UpdaterSection
    manager: ManagerSection
    reporter: ReporterSection

    def __init__(self, **values: Any):
        unknown = [n for n in values if n not in SECTIONS and n not in SECTION_OF]
        if unknown:
            raise ConfigError(None, f"tracker: unknown parameter(s) {_unknown(unknown, SECTION_OF)}")
        given: dict[str, dict[str, Any]] = {s: {} for s in SECTIONS}
        whole: dict[str, Any] = {}
        flat: set[str] = set()
        for name, v in values.items():
            if name in SECTIONS:
                if isinstance(v, SECTIONS[name]):
                    whole[name] = v
                elif isinstance(v, dict):
                    known = [f.name for f in fields(SECTIONS[name])]
                    unknown = sorted(set(v) - set(known))
                    if unknown:
                        raise ConfigError(None, f"tracker.{name}: unknown parameter(s) "
                                          f"{_unknown(unknown, known)}")
                    given[name].update(v)
                else:
                    raise ConfigError(f"tracker.{name}", f"must be a table, got {v!r}")
            else:
                given[SECTION_OF[name]][name] = v
                flat.add(name)
        for s, cls in SECTIONS.items():
            try:
                section = (cls(**{**{f.name: getattr(whole[s], f.name) for f in fields(cls)},
                                  **given[s]}) if s in whole and given[s]
                           else whole.get(s) or cls(**given[s]))
            except ConfigError as e:  # name the field as it was written: flat, or in its table
                name = (e.field or "").rsplit(".", 1)[-1]
                raise ConfigError(f"tracker.{name}" if name in flat else e.field, e.message) from None
            object.__setattr__(self, s, section)
        if self.scope_hops and not self.use_manager:
            raise ConfigError("tracker.scope_hops", "regional scope needs the DTM (use_manager): "
                              "without the ell consensus, ell does not measure hops")
        if self.init_observations > self.gallery_size:
            raise ConfigError("tracker.init_observations", "must not exceed tracker.gallery_size")

    def __getattr__(self, name: str) -> Any:
        """A parameter by its flat name, from its section."""
        s = SECTION_OF.get(name)
        if s is None:
            raise AttributeError(f"TrackerConfig has no parameter {name!r}")
        return getattr(object.__getattribute__(self, s), name)

    def __repr__(self) -> str:
        changed = {k: v for k, v in self.flat().items() if v != _DEFAULTS[k]}
        return f"TrackerConfig({', '.join(f'{k}={v!r}' for k, v in changed.items())})"

    # -- derived -----------------------------------------------------------------------------
    @property
    def ablation(self) -> str:
        if self.use_manager:
            name = "dkf+lda+dtm" if self.use_appearance else "dkf+dtm"
        else:
            name = "dkf+lda" if self.use_appearance else "dkf"
        return name if self.registration else name + ":noreg"

    @classmethod
    def for_ablation(cls, name: str, **overrides) -> "TrackerConfig":
        """The paper's three configurations ``dkf``, ``dkf+lda``, ``dkf+lda+dtm``; ``dkf+dtm``
        (the manager without appearance); each with ``:noreg`` for no online registration.
        ``overrides``: flat parameters or whole sections' tables."""
        switches = {
            "dkf": dict(use_appearance=False, use_manager=False),
            "dkf+lda": dict(use_appearance=True, use_manager=False),
            "dkf+lda+dtm": dict(use_appearance=True, use_manager=True),
            "dkf+dtm": dict(use_appearance=False, use_manager=True),
        }
        base, _, suffix = name.partition(":")
        if base not in switches or suffix not in ("", "noreg"):
            raise ConfigError("config", f"unknown configuration {name!r}; choose one of "
                              f"{', '.join(CONFIG_NAMES)}")
        reg = {"registration": False} if suffix == "noreg" else {}
        return cls.from_dict({**switches[base], **reg, **overrides})

    @classmethod
    def from_dict(cls, d: dict, where: str = "tracker") -> "TrackerConfig":
        """Build from a (TOML) table of flat parameters and section tables; unknown names are
        rejected naming every known one. A parameter given both flat and in its section's
        table is an error."""
        d = dict(d)
        for s in SECTIONS:
            if isinstance(d.get(s), dict):
                twice = sorted(set(d[s]) & set(d))
                if twice:
                    raise ConfigError(f"{where}.{twice[0]}", f"is given twice: flat and in [{where}.{s}]")
        def pairs(values: dict, cls: type) -> dict:  # lists from TOML become the tuples held
            rules = {f.name: f.metadata["rule"] for f in declared(cls)}
            return {k: tuple(v) if isinstance(v, list) and k in rules and rules[k].kind == "pair"
                    else v for k, v in values.items()}
        for s, c in SECTIONS.items():
            if isinstance(d.get(s), dict):
                d[s] = pairs(d[s], c)
        d = {k: (pairs({k: v}, SECTIONS[SECTION_OF[k]])[k] if k in SECTION_OF else v)
             for k, v in d.items()}
        try:
            return cls(**d)
        except ConfigError as e:
            if where == "tracker" or e.field is None or not e.field.startswith("tracker."):
                raise
            raise ConfigError(where + e.field[len("tracker"):], e.message) from None

    def with_(self, **changes) -> "TrackerConfig":
        """A copy with ``changes`` (flat names)."""
        return TrackerConfig(**{**self.flat(), **changes})

    def flat(self) -> dict[str, Any]:
        """Every parameter by its flat name, in the sections' order."""
        return {f.name: getattr(getattr(self, s), f.name)
                for s, c in SECTIONS.items() for f in fields(c)}

    def to_dict(self) -> dict[str, dict[str, Any]]:
        """The tree: section -> parameter -> value."""
        return {s: {f.name: getattr(getattr(self, s), f.name) for f in fields(c)}
                for s, c in SECTIONS.items()}

    @staticmethod
    def names(d: dict) -> frozenset[str]:
        """The parameter names a (TOML) table sets, flat or in a section's table."""
        out = set()
        for k, v in d.items():
            if k in SECTIONS and isinstance(v, dict):
                out.update(v)
            else:
                out.add(k)
        return frozenset(out)


_DEFAULTS = TrackerConfig().flat()


class Slice(_Units):
    """A role's view of the configuration: a frozen dataclass whose fields are named as the
    parameters it reads (and ``units_per_metre`` and ``fps`` for ``m()`` and ``dt``), filled from
    the tree by :meth:`of`. A role is given its slice, never the whole tree: what it reads is
    written in one place, and a test checks that no role holds more."""

    @classmethod
    def of(cls, cfg: "TrackerConfig | Slice", **changes) -> "Slice":
        """This slice of ``cfg`` (the tree, or a slice that has every field), with ``changes``."""
        return cls(**{**{f.name: getattr(cfg, f.name) for f in fields(cls)}, **changes})
