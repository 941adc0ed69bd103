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
"""
from __future__ import annotations

from dataclasses import dataclass
import math

import numpy as np

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


class AppearanceError(ValueError):
    """Appearance parameters that cannot produce descriptors."""


@dataclass(frozen=True)
class AppearanceParams:
    """Weights of the descriptor's components (see the module docstring for the distances).

    Defaults give mean cosine distances of about 0.10 (same person, same camera), 0.22 (same
    person, two cameras) and 0.80 (two people).
    """

    dim: int = 512
    identity: float = math.sqrt(0.58)
    view: float = math.sqrt(0.12)
    noise: float = math.sqrt(0.10)
    shared: float = math.sqrt(0.20)

    def __post_init__(self) -> None:
        if not isinstance(self.dim, int) or self.dim < 2:
            raise AppearanceError(f"dim must be an integer >= 2, got {self.dim!r}")
        for name in ("identity", "view", "noise", "shared"):
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

    def expected_distances(self) -> dict[str, float]:
        """The mean cosine distances these weights give (large-``dim`` limit)."""
        s = self.identity**2 + self.view**2 + self.noise**2 + self.shared**2
        return {
            "same_camera": self.noise**2 / s,
            "cross_camera": (self.view**2 + self.noise**2) / s,
            "different_person": 1.0 - self.shared**2 / s,
        }


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


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
        self._shared = p.shared * self._random_unit([self.seed, _TAG_SHARED])
        self._base: dict[tuple[int, int], np.ndarray] = {}  # least recently used first
        self._identity: dict[int, np.ndarray] = {}
        self._cameras: set[int] = set()  # the cameras served: the caches' size scales with them

    @property
    def dim(self) -> int:
        return self.params.dim

    def _random_unit(self, entropy: list[int]) -> np.ndarray:
        g = np.random.default_rng(entropy).standard_normal(self.params.dim)
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
        g = _unit(rng.standard_normal((n, 3, p.dim)))
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
