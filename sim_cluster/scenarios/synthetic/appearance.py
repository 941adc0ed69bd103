"""Synthetic appearance descriptors: identity + per-camera view + per-frame noise.

A descriptor stands in for a re-id network's embedding (the paper uses OSNet, 512-d). It is the
L2-normalised sum of four unit vectors with fixed weights::

    d = normalise(w_id * identity(person) + w_view * view(person, camera)
                  + w_noise * noise(frame) + w_shared * shared)

``identity`` is fixed per person, ``view`` per (person, camera) (the same person looks different
from another angle and under another camera's colours), ``noise`` is fresh every frame, and
``shared`` is common to everybody (real embeddings are not orthogonal between people: they all
live in a cone). In ``dim`` dimensions independent random unit vectors are nearly orthogonal
(inner product ~ N(0, 1/dim)), so with ``S = w_id^2 + w_view^2 + w_noise^2 + w_shared^2`` the
expected cosine distances are::

    same person, same camera, two frames:   w_noise^2 / S
    same person, two cameras:               (w_view^2 + w_noise^2) / S
    two different people:                   1 - w_shared^2 / S

Identity and view vectors are derived deterministically from ``(seed, person id[, camera])``,
so any integer person id works (including ids from real datasets) and nothing needs to be
registered in advance; only the per-frame noise comes from the generator the caller passes.

**Re-id quality.** Isotropic vectors in 512 dimensions are too easy to tell apart: every
distance sits within a few hundredths of its mean, so the defaults re-identify perfectly
(cross-camera rank-1 1.0). Real embeddings spread their variance over few directions. With
``decay > 0`` the identity and view vectors (and clutter's) are drawn with variance
``i ** -decay`` along axis ``i`` (a power-law spectrum, participation ratio
``(sum l_i)^2 / sum l_i^2`` the effective dimension) instead of isotropically: the mean distances
above stay where they are (independent vectors are still orthogonal on average, and the
tracker's thresholds keep their meaning) but spread out, so some people look alike and some
views of one person look like someone else -- the two ways real re-id fails, and persistent
ones, as a network's are (it confuses the same two people in every frame). The per-frame noise
stays isotropic: one camera's consecutive descriptors of a person stay as close as before.
:meth:`AppearanceParams.from_quality` picks the ``decay`` that gives a stated cross-camera
rank-1 (or mAP), measured by :func:`measure_quality` with the benchmark protocol of
:mod:`sim_cluster.evaluation.reid` on ``QUALITY_PEOPLE`` people seen by ``QUALITY_CAMERAS``
cameras (the number of people a preset shows over its run; rank-1 falls with more people).
"""
from __future__ import annotations

from dataclasses import dataclass, replace
import functools
import math

import numpy as np

from protocol.errors import DmttError
from sim_cluster.evaluation.reid import ReidScore, cross_camera_reid

_MASK64 = (1 << 64) - 1
_TAG_IDENTITY = 0x1D
_TAG_VIEW = 0x71E
_TAG_SHARED = 0x5A
_BLOCK = 512  # rows of noise drawn at a time
# Identity and view vectors are kept for the people recently asked for, at most this many per
# camera the model has served (least recently used out; derived again when needed): an endless
# world's people keep coming and a camera process runs for months, so a cache sized for 64
# cameras (4096 vectors of 4 kB each, twice) filled a one-camera process by 16 MB over an hour.
_KEEP_PER_CAMERA = 64  # a camera sees far fewer people at once (terrace: 9; corridor: 6.25)

#: The gallery a stated re-id quality refers to (:func:`measure_quality`): this many people, each
#: seen by every one of ``QUALITY_CAMERAS`` cameras in ``QUALITY_FRAMES`` frames, over
#: ``QUALITY_SEEDS`` appearance seeds (the mean). 20 people is about what the presets show over
#: their default run (terrace-sim 16 in its 600 frames, campus-sim 7) and the gallery of old
#: trackers a node holds. One 20-person scene's rank-1 varies with a std of about 0.06 between
#: seeds (some crowds hold more look-alikes): 64 seeds pin the mean within about 0.01.
QUALITY_PEOPLE = 20
QUALITY_CAMERAS = 4
QUALITY_FRAMES = 2
QUALITY_SEEDS = 64
#: The largest ``decay`` searched: there the descriptors have about one effective dimension,
#: the worst this family gets (measure_quality gives its rank-1, about 0.08 with 20 people);
#: below that, a re-id no better than chance is a detector without descriptors.
DECAY_MAX = 32.0


class AppearanceError(DmttError, ValueError):
    """Appearance parameters that cannot produce descriptors."""


@dataclass(frozen=True)
class AppearanceParams:
    """Weights of the descriptor's components (see the module docstring for the distances).

    Defaults give mean cosine distances of about 0.10 (same person, same camera), 0.22 (same
    person, two cameras) and 0.80 (two people), all within a few hundredths of their mean:
    perfect re-identification. ``decay`` (0: isotropic) spreads them out (see the module
    docstring); :meth:`from_quality` sets it from a stated rank-1 or mAP.
    """

    dim: int = 512
    identity: float = math.sqrt(0.58)
    view: float = math.sqrt(0.12)
    noise: float = math.sqrt(0.10)
    shared: float = math.sqrt(0.20)
    decay: float = 0.0

    def __post_init__(self) -> None:
        if not isinstance(self.dim, int) or self.dim < 2:
            raise AppearanceError(f"dim must be an integer >= 2, got {self.dim!r}")
        for name in ("identity", "view", "noise", "shared", "decay"):
            v = getattr(self, name)
            if not math.isfinite(v) or v < 0:
                raise AppearanceError(f"{name} weight must be finite and >= 0, got {v!r}")
        if self.identity <= 0:
            raise AppearanceError("identity weight must be > 0 (people would be indistinguishable)")

    @classmethod
    def from_distances(
        cls,
        same_camera: float = 0.10,
        cross_camera: float = 0.22,
        different_person: float = 0.80,
        dim: int = 512,
    ) -> "AppearanceParams":
        """Weights giving these expected cosine distances (``0 <= same <= cross < different <= 1``)."""
        if not (0.0 <= same_camera <= cross_camera < different_person <= 1.0):
            raise AppearanceError(
                "distances must satisfy 0 <= same_camera <= cross_camera < different_person <= 1, "
                f"got {same_camera}, {cross_camera}, {different_person}"
            )
        return cls(
            dim=dim,
            identity=math.sqrt(different_person - cross_camera),
            view=math.sqrt(cross_camera - same_camera),
            noise=math.sqrt(same_camera),
            shared=math.sqrt(1.0 - different_person),
        )

    @classmethod
    def from_quality(cls, rank1: float | None = None, mean_ap: float | None = None, *,
                     base: "AppearanceParams | None" = None,
                     people: int = QUALITY_PEOPLE) -> "AppearanceParams":
        """``base`` (default: the defaults) with the ``decay`` whose descriptors have this
        cross-camera ``rank1`` (or ``mean_ap``; give one) as :func:`measure_quality` measures
        it with ``people`` people. 1.0 is ``base`` itself (perfect re-id). Found by bisection
        on ``decay`` (the measurement uses fixed seeds: the same answer every time); the
        measured value is within about 0.005 of the target. A target below what the family
        reaches (``measure_quality`` at ``DECAY_MAX``, about 0.08 rank-1 with 20 people) is an
        error: that re-id is no better than none (run without descriptors instead)."""
        if (rank1 is None) == (mean_ap is None):
            raise AppearanceError("give one target re-id quality: rank1 or mean_ap")
        metric, target = ("rank1", rank1) if rank1 is not None else ("mean_ap", mean_ap)
        if not (isinstance(target, (int, float)) and math.isfinite(target) and 0 < target <= 1):
            raise AppearanceError(f"{metric} must be in (0, 1], got {target!r}")
        if not isinstance(people, int) or people < 2:
            raise AppearanceError(f"people must be an integer >= 2, got {people!r}")
        base = replace(base if base is not None else cls(), decay=0.0)
        return replace(base, decay=_calibrate(metric, float(target), base, people))

    def expected_distances(self) -> dict[str, float]:
        """The mean cosine distances these weights give (large-``dim`` limit; the same for
        any ``decay``)."""
        s = self.identity**2 + self.view**2 + self.noise**2 + self.shared**2
        return {
            "same_camera": self.noise**2 / s,
            "cross_camera": (self.view**2 + self.noise**2) / s,
            "different_person": 1.0 - self.shared**2 / s,
        }


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def spectrum_scale(dim: int, decay: float) -> np.ndarray | None:
    """Per-axis standard deviation ``i ** (-decay / 2)`` (``i = 1..dim``) of the random
    vectors, or None when isotropic (``decay == 0``: no scaling, the exact old stream)."""
    if decay == 0:
        return None
    return np.arange(1, dim + 1, dtype=np.float64) ** (-0.5 * decay)


def effective_dimension(dim: int, decay: float) -> float:
    """The participation ratio ``(sum l)^2 / sum l^2`` of the spectrum ``l_i = i ** -decay``:
    about how many directions the random vectors use (``dim`` when isotropic)."""
    lam = np.arange(1, dim + 1, dtype=np.float64) ** (-float(decay))
    return float(lam.sum() ** 2 / (lam**2).sum())


class QualityBench:
    """The gallery a re-id quality is measured on: ``people`` people (ids 0..) each seen by
    ``cameras`` cameras in ``frames`` frames, for appearance seeds ``seed0 .. seed0 + seeds - 1``
    (noise of camera ``c`` from ``default_rng([seed, 0x9E1D, c])``).

    It holds the random draws behind those descriptors (the same ones :class:`AppearanceModel`
    makes) and makes the descriptors of any parameters from them with the model's arithmetic
    (``tests/test_reid.py`` checks they are the model's): a bisection over ``decay`` rescales
    the same draws instead of deriving every person's vectors again.
    """

    def __init__(self, dim: int, people: int = QUALITY_PEOPLE, cameras: int = QUALITY_CAMERAS,
                 frames: int = QUALITY_FRAMES, seeds: int = QUALITY_SEEDS, seed0: int = 0):
        self.dim, self.people, self.cameras, self.frames = dim, people, cameras, frames
        self.seeds = list(range(seed0, seed0 + seeds))
        ids = range(people)
        self._identity = np.stack([[np.random.default_rng(
            [_key(s), _TAG_IDENTITY, _key(p)]).standard_normal(dim) for p in ids]
            for s in self.seeds])  # (S, P, dim)
        self._view = np.stack([[[np.random.default_rng(
            [_key(s), _TAG_VIEW, _key(p), _key(c)]).standard_normal(dim) for p in ids]
            for c in range(cameras)] for s in self.seeds])  # (S, C, P, dim)
        self._shared = _unit(np.stack([np.random.default_rng([_key(s), _TAG_SHARED])
                                       .standard_normal(dim) for s in self.seeds]))  # (S, dim)
        noise = np.empty((len(self.seeds), cameras, frames, people, dim))
        for i, s in enumerate(self.seeds):
            for c in range(cameras):
                rng = np.random.default_rng([s, 0x9E1D, c])
                for f in range(frames):
                    rng.standard_normal(out=noise[i, c, f])
        self._noise = noise / np.sqrt(np.einsum("...j,...j->...", noise, noise))[..., None]
        self.person = np.tile(np.arange(people), cameras * frames)
        self.camera = np.repeat(np.arange(cameras), frames * people)

    def descriptors(self, params: AppearanceParams, i: int) -> np.ndarray:
        """``(cameras * frames * people, dim)``: what ``AppearanceModel(params, seed)
        .descriptors(arange(people), c, rng)`` gives for the ``i``-th seed, camera ``c = 0..``
        and frame after frame (rows ordered camera, frame, person)."""
        if params.dim != self.dim:
            raise AppearanceError(f"a bench of dimension {self.dim} for descriptors of "
                                  f"{params.dim}")
        scale = spectrum_scale(self.dim, params.decay)
        ident, view = self._identity[i], self._view[i]
        if scale is not None:
            ident, view = ident * scale, view * scale
        ident = ident / np.linalg.norm(ident, axis=-1, keepdims=True)
        view = view / np.linalg.norm(view, axis=-1, keepdims=True)
        base = params.identity * ident + params.view * view + params.shared * self._shared[i]
        out = base[:, None] + params.noise * self._noise[i]  # (C, F, P, dim)
        out /= np.sqrt(np.einsum("...j,...j->...", out, out))[..., None]
        return out.reshape(-1, self.dim)

    def score(self, params: AppearanceParams) -> ReidScore:
        """Cross-camera rank-1 and mAP averaged over the seeds (``queries`` their total)."""
        scores = [cross_camera_reid(self.descriptors(params, i), self.person, self.camera)
                  for i in range(len(self.seeds))]
        return ReidScore(rank1=float(np.mean([x.rank1 for x in scores])),
                         mean_ap=float(np.mean([x.mean_ap for x in scores])),
                         queries=int(sum(x.queries for x in scores)), people=self.people)


def measure_quality(params: AppearanceParams, people: int = QUALITY_PEOPLE,
                    cameras: int = QUALITY_CAMERAS, frames: int = QUALITY_FRAMES,
                    seeds: int = QUALITY_SEEDS, seed0: int = 0) -> ReidScore:
    """Cross-camera rank-1 and mAP (:func:`~sim_cluster.evaluation.reid.cross_camera_reid`) of
    the descriptors ``params`` generates (:class:`QualityBench`: ``people`` people each seen by
    ``cameras`` cameras in ``frames`` frames), averaged over appearance seeds
    ``seed0 .. seed0 + seeds - 1``. ``queries`` is the total over the seeds."""
    return QualityBench(params.dim, people, cameras, frames, seeds, seed0).score(params)


@functools.lru_cache(maxsize=64)
def _calibrate(metric: str, target: float, base: AppearanceParams, people: int) -> float:
    """The ``decay`` at which ``base``'s measured ``metric`` falls to ``target`` (bisection;
    the measurement is nearly monotone in ``decay``: the same random draws, rescaled)."""
    bench = QualityBench(base.dim, people)

    def measured(decay: float) -> float:
        return getattr(bench.score(replace(base, decay=decay)), metric)

    if measured(0.0) <= target:
        return 0.0
    floor = measured(DECAY_MAX)
    if floor > target:
        raise AppearanceError(
            f"{metric} {target:g} is below what the synthetic descriptors reach with {people} "
            f"people ({floor:.2f}, effective dimension about 1): a re-id that poor is no better "
            "than none; run without descriptors instead")
    lo, hi = 0.0, DECAY_MAX
    while hi - lo > 2e-3:
        mid = 0.5 * (lo + hi)
        if measured(mid) > target:
            lo = mid
        else:
            hi = mid
    return round(hi, 4)


def _recall(cache: dict, key):
    """The value remembered for ``key`` (now the most recently used), or ``None``."""
    value = cache.pop(key, None)
    if value is not None:
        cache[key] = value
    return value


def _keep(cache: dict, key, value, limit: int) -> None:
    """Remember ``value``, forgetting the least recently used entries beyond ``limit`` (values
    are derived from their key, so forgetting changes nothing but time)."""
    cache[key] = value
    while len(cache) > limit:
        del cache[next(iter(cache))]


def _key(x: int) -> int:
    """A non-negative seed word for any Python integer (negative ids included)."""
    return int(x) & _MASK64


class AppearanceModel:
    """Descriptors for (person, camera) pairs; deterministic given ``seed`` and the noise rng."""

    def __init__(self, params: AppearanceParams | None = None, seed: int = 0):
        self.params = params if params is not None else AppearanceParams()
        self.seed = _key(seed)
        p = self.params
        self._scale = spectrum_scale(p.dim, p.decay)
        # the component common to everybody is their mean: isotropic whatever the spectrum
        self._shared = p.shared * _unit(
            np.random.default_rng([self.seed, _TAG_SHARED]).standard_normal(p.dim))
        self._base: dict[tuple[int, int], np.ndarray] = {}  # least recently used first
        self._identity: dict[int, np.ndarray] = {}
        self._cameras: set[int] = set()  # the cameras served: the caches' size scales with them

    @property
    def dim(self) -> int:
        return self.params.dim

    def _random_unit(self, entropy: list[int]) -> np.ndarray:
        g = np.random.default_rng(entropy).standard_normal(self.params.dim)
        if self._scale is not None:
            g *= self._scale
        return _unit(g)

    def identity(self, person_id: int) -> np.ndarray:
        """The person's unit identity vector (the same for every camera)."""
        pid = int(person_id)
        v = _recall(self._identity, pid)
        if v is None:
            v = self._random_unit([self.seed, _TAG_IDENTITY, _key(pid)])
            _keep(self._identity, pid, v, self._limit)
        return v

    @property
    def _limit(self) -> int:
        """How many vectors each cache keeps (``_KEEP_PER_CAMERA`` per camera served)."""
        return _KEEP_PER_CAMERA * max(1, len(self._cameras))

    def base(self, person_id: int, camera: int) -> np.ndarray:
        """The noise-free (unnormalised) descriptor of a person as seen by a camera."""
        key = (int(person_id), int(camera))
        b = _recall(self._base, key)
        if b is None:
            self._cameras.add(key[1])
            p = self.params
            view = self._random_unit([self.seed, _TAG_VIEW, _key(key[0]), _key(key[1])])
            b = p.identity * self.identity(key[0]) + p.view * view + self._shared
            _keep(self._base, key, b, self._limit)
        return b

    def descriptors(self, person_ids: np.ndarray, camera: int, rng: np.random.Generator) -> np.ndarray:
        """``(n, dim)`` L2-normalised descriptors of these people in one camera at one frame.

        Draws exactly ``n * dim`` standard normals from ``rng`` (in row order).
        """
        ids = np.asarray(person_ids, dtype=np.int64).reshape(-1)
        n = len(ids)
        out = np.empty((n, self.params.dim))
        if n == 0:
            return out
        uniq, inverse = np.unique(ids, return_inverse=True)
        bases = np.stack([self.base(int(pid), camera) for pid in uniq])
        np.take(bases, inverse.reshape(-1), axis=0, out=out)
        # Noise in row blocks through one reused buffer (same stream as one big draw).
        buf = np.empty((min(n, _BLOCK), self.params.dim))
        for s in range(0, n, _BLOCK):
            blk = buf[: min(_BLOCK, n - s)]
            rng.standard_normal(out=blk)
            blk *= (self.params.noise / np.sqrt(np.einsum("ij,ij->i", blk, blk)))[:, None]
            out[s:s + len(blk)] += blk
        out /= np.sqrt(np.einsum("ij,ij->i", out, out))[:, None]
        return out

    def descriptor(self, person_id: int, camera: int, rng: np.random.Generator) -> np.ndarray:
        """One L2-normalised ``(dim,)`` descriptor of a person in a camera (fresh frame noise)."""
        return self.descriptors(np.array([person_id]), camera, rng)[0]

    def false_positive_descriptors(self, n: int, rng: np.random.Generator) -> np.ndarray:
        """``(n, dim)`` descriptors of clutter: a random identity, unlike everybody (distance
        to any person about ``different_person``)."""
        p = self.params
        out = np.empty((n, p.dim))
        if n == 0:
            return out
        g = rng.standard_normal((n, 3, p.dim))
        if self._scale is not None:  # a random person's look: identity and view (noise: any)
            g[:, :2] *= self._scale
        g = _unit(g)
        out[:] = p.identity * g[:, 0] + p.view * g[:, 1] + p.noise * g[:, 2] + self._shared
        return _unit(out)

    def false_positive_descriptor(self, rng: np.random.Generator) -> np.ndarray:
        """One clutter descriptor (see :meth:`false_positive_descriptors`)."""
        return self.false_positive_descriptors(1, rng)[0]


def cosine_distance(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Cosine distance ``1 - a.b / (|a| |b|)`` between rows of ``a`` and rows of ``b`` (broadcast)."""
    a = np.asarray(a, float)
    b = np.asarray(b, float)
    return 1.0 - np.sum(_unit(a) * _unit(b), axis=-1)
