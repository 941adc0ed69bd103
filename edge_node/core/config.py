"""All tracker parameters in one object, with the ablation switch of the paper's Section IV-B.

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
* ``tau_gda_m`` / ``alpha_gda_m`` are the Euclidean gate and normaliser (``V = I``) of the
  distributed global data association, in metres.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass, fields, replace

ABLATIONS = ("dkf", "dkf+lda", "dkf+lda+dtm")


class ConfigError(ValueError):
    """A tracker parameter that is out of range or unknown; the message names the field."""


@dataclass(frozen=True)
class TrackerConfig:
    # --- ablation switches (paper Sec. IV-B) -------------------------------------------
    use_appearance: bool = True  # LDA: appearance score s_a in the association cost (eq. 7)
    use_manager: bool = True  # DTM: global association/merge, consensus drop (eq. 9), re-id

    # --- units and time ------------------------------------------------------------------
    units_per_metre: float = 1.0
    fps: float = 25.0

    # --- motion model (A, Q) ---------------------------------------------------------------
    accel_sigma: float = 1.0  # m/s^2, white-noise acceleration on the constant-velocity part
    size_sigma: float = 0.01  # m per frame, random walk on (w, h)

    # --- measurement model (H, R_i) ----------------------------------------------------------
    pixel_sigma: float = 2.0  # px, detector noise on box edges, propagated through the homography
    calib_sigma: float = 0.4  # m, per-camera ground offset (calibration + foot point), see DESIGN
    size_meas_floor: float = 0.05  # m, minimum sigma on measured w, h
    fixed_R: tuple[float, float] | None = None  # (sigma_xy, sigma_wh) in m: the paper's fixed R

    # --- birth prior (a new tracker, identical on every node that adopts it) ----------------
    birth_pos_sigma: float = 0.5  # m
    birth_size_sigma: float = 0.2  # m
    birth_vel_sigma: float = 1.5  # m/s

    # --- local data association (eqs. 5-7) -----------------------------------------------------
    tau: float = 3.0  # Mahalanobis gate (standard deviations)
    alpha_lda: float = 3.0  # s_d = d / alpha_lda
    unknown_appearance: float = 0.5  # s_a when a tracker has no gallery yet
    appearance_gate: float = 0.6  # pairs with s_a above this are never assigned (our addition)

    # --- gallery ------------------------------------------------------------------------------
    gallery_size: int = 20
    gallery_every: int = 20  # N: a new descriptor every N frames
    gallery_admit: float = 0.35  # a descriptor joins only if s_a to the gallery is below this

    # --- tracker initialisation -----------------------------------------------------------------
    init_observations: int = 2  # paper: two observations in the local gallery
    candidate_gate: float = 0.8  # m, how far a second observation may be from the first
    candidate_max_age: int = 3  # frames a single observation waits for its second
    candidate_appearance: float = 0.5  # max cosine distance between the two observations

    # --- distributed tracker manager --------------------------------------------------------------
    tau_gda: float = 1.5  # m, Euclidean gate (V = I) between trackers of two cameras
    alpha_gda: float = 1.5  # m, s_d normaliser of the global association
    merge_appearance: float = 0.4  # max gallery-to-gallery cosine distance to merge
    merge_frames: int = 3  # consecutive frames two established trackers must agree to merge
    merge_announce_frames: int = 3  # frames a merge announcement is repeated
    kappa: int = 15  # drop a tracker when ell exceeds kappa (eq. 9)
    epsilon: float = 0.25  # re-identification threshold on s_a against old trackers
    max_old_trackers: int = 200  # bounded memory of dropped trackers
    report_coast: int = 1  # frames a tracker nobody sees is still reported (kept until kappa)

    # --- asynchronous operation (event-triggered consensus) ----------------------------------
    staleness_frames: int = 2  # a neighbour's u, U older than this many frames is ignored

    def __post_init__(self) -> None:
        positive = ("units_per_metre", "fps", "accel_sigma", "pixel_sigma", "tau", "alpha_lda",
                    "birth_pos_sigma", "birth_size_sigma", "birth_vel_sigma", "candidate_gate",
                    "tau_gda", "alpha_gda", "size_meas_floor")
        for name in positive:
            v = getattr(self, name)
            if not isinstance(v, (int, float)) or isinstance(v, bool) or not v > 0:
                raise ConfigError(f"tracker.{name} must be a positive number, got {v!r}")
        nonneg = ("size_sigma", "calib_sigma", "unknown_appearance", "candidate_appearance",
                  "merge_appearance", "epsilon", "appearance_gate", "gallery_admit")
        for name in nonneg:
            v = getattr(self, name)
            if not isinstance(v, (int, float)) or isinstance(v, bool) or not v >= 0:
                raise ConfigError(f"tracker.{name} must be a non-negative number, got {v!r}")
        ints = ("gallery_size", "gallery_every", "init_observations", "candidate_max_age",
                "merge_frames", "merge_announce_frames", "kappa", "max_old_trackers")
        for name in ("staleness_frames", "report_coast"):
            v = getattr(self, name)
            if not isinstance(v, int) or isinstance(v, bool) or v < 0:
                raise ConfigError(f"tracker.{name} must be an integer >= 0, got {v!r}")
        for name in ints:
            v = getattr(self, name)
            if not isinstance(v, int) or isinstance(v, bool) or v < 1:
                raise ConfigError(f"tracker.{name} must be an integer >= 1, got {v!r}")
        if self.init_observations > self.gallery_size:
            raise ConfigError("tracker.init_observations must not exceed tracker.gallery_size")
        if self.fixed_R is not None:
            if (len(self.fixed_R) != 2 or not all(isinstance(v, (int, float)) and v > 0
                                                  for v in self.fixed_R)):
                raise ConfigError("tracker.fixed_R must be two positive sigmas (xy, wh) in metres")

    # -- derived -----------------------------------------------------------------------------
    @property
    def dt(self) -> float:
        return 1.0 / self.fps

    def m(self, metres: float) -> float:
        """Metres to ground units."""
        return metres * self.units_per_metre

    @property
    def ablation(self) -> str:
        if self.use_manager:
            return "dkf+lda+dtm" if self.use_appearance else "dkf+dtm"
        return "dkf+lda" if self.use_appearance else "dkf"

    @classmethod
    def for_ablation(cls, name: str, **overrides) -> "TrackerConfig":
        """The paper's three configurations: ``dkf``, ``dkf+lda``, ``dkf+lda+dtm``."""
        switches = {
            "dkf": dict(use_appearance=False, use_manager=False),
            "dkf+lda": dict(use_appearance=True, use_manager=False),
            "dkf+lda+dtm": dict(use_appearance=True, use_manager=True),
        }
        if name not in switches:
            raise ConfigError(f"unknown configuration {name!r}; choose one of {', '.join(ABLATIONS)}")
        return cls.from_dict({**switches[name], **overrides})

    @classmethod
    def from_dict(cls, d: dict, where: str = "tracker") -> "TrackerConfig":
        """Build from a (TOML) table, rejecting unknown keys with a clear message."""
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(d) - known)
        if unknown:
            raise ConfigError(f"{where}: unknown parameter(s) {', '.join(unknown)}")
        d = dict(d)
        if "fixed_R" in d and d["fixed_R"] is not None:
            d["fixed_R"] = tuple(d["fixed_R"])
        return cls(**d)

    def to_dict(self) -> dict:
        return asdict(self)

    def with_(self, **changes) -> "TrackerConfig":
        return replace(self, **changes)


