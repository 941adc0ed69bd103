"""Re-identification: one appearance descriptor per box, 512-d and L2-normalised.

:class:`ReidExtractor` is the interface: ``extract(image, boxes) -> (n, dim)`` float32, one unit
row per box (an all-NaN row when a box has no usable pixels: the tracker then treats that
detection as having no descriptor). The tracker compares descriptors by cosine distance.

* :class:`OsnetReid` -- OSNet (:mod:`edge_node.perception.osnet`) on the CPU: every box of a frame
  is cropped, resized to 256 x 128, normalised with the ImageNet statistics torchreid trains with,
  and run as one batch. Weights come from a torchreid checkpoint the user gives; torch is imported
  when an ``OsnetReid`` is built, never before.
* :class:`HistogramReid` -- the classical fallback without weights: HSV colour histograms of the
  upper and lower body (16 hue x 4 saturation x 4 value bins each, 2 x 256 = 512 bins), taken
  over the central part of the box to leave out background at its sides, square-rooted (so the
  cosine of two descriptors is the Bhattacharyya coefficient of the histograms) and
  L2-normalised. Deterministic, about 0.1 ms per box.

Backends are registered by name in :data:`REID` (``[perception] reid``, ``sim_cluster up
--reid``); another package adds one in the entry-point group ``dmtt.reid`` with an object like
:class:`ReidKind` (``edge_node/plugins.py``).
"""
from __future__ import annotations

from pathlib import Path
from typing import Any, Protocol, runtime_checkable

import numpy as np

from edge_node.perception import PerceptionError, require_cv2
from edge_node.perception.options import drop_none, file_option
from edge_node.plugins import Registry

DIM = 512


@runtime_checkable
class ReidExtractor(Protocol):
    """Appearance descriptors for the boxes of one image."""

    name: str
    dim: int

    def extract(self, image: np.ndarray, boxes: np.ndarray,
                mask: np.ndarray | None = None) -> np.ndarray:
        """``image`` BGR ``(H, W, 3)`` uint8, ``boxes (n, 4)`` ``(x, y, w, h)`` pixels ->
        ``(n, dim)`` float32 unit rows (all-NaN for a box with no pixels in the image).
        ``mask``: the detector's foreground mask (``(H, W)`` uint8) when it has one; an
        extractor may use it to leave the background out."""


def _int_boxes(boxes: np.ndarray, shape: tuple[int, ...]) -> np.ndarray:
    """Boxes clipped to the image as integer ``(x0, y0, x1, y1)``; empty ones have x1 <= x0."""
    b = np.asarray(boxes, float).reshape(-1, 4)
    H, W = shape[:2]
    x0 = np.clip(np.floor(b[:, 0]), 0, W).astype(int)
    y0 = np.clip(np.floor(b[:, 1]), 0, H).astype(int)
    x1 = np.clip(np.ceil(b[:, 0] + b[:, 2]), 0, W).astype(int)
    y1 = np.clip(np.ceil(b[:, 1] + b[:, 3]), 0, H).astype(int)
    return np.stack([x0, y0, x1, y1], axis=1)


def l2_normalise(x: np.ndarray) -> np.ndarray:
    n = np.linalg.norm(x, axis=-1, keepdims=True)
    return x / np.where(n > 0, n, 1.0)


class HistogramReid:
    """HSV colour histograms of the upper and lower body, 512-d, L2-normalised (no weights).

    ``upper`` and ``lower`` are the row spans of the box (fractions of its height) whose pixels
    describe the torso and the legs; ``centre`` the central fraction of its width that is used.
    Only a person's own pixels count: with ``exclusive`` the pixels a box shares with another
    box of the same frame are left out (they may show the other person), and with the detector's
    foreground ``mask`` so is the background. A part (upper or lower) left with fewer than
    ``min_own`` of its pixels makes the descriptor missing (all-NaN): a mixed colour histogram
    teaches a track's gallery another person's look, a missing one only leaves the association
    to geometry.
    """

    name = "histogram"
    dim = DIM
    handles_overlap = True  # Perception need not hide overlapping boxes from it

    def __init__(self, bins: tuple[int, int, int] = (16, 4, 4),
                 upper: tuple[float, float] = (0.12, 0.5), lower: tuple[float, float] = (0.5, 0.92),
                 centre: float = 0.6, exclusive: bool = True, min_own: float = 0.3):
        if int(np.prod(bins)) * 2 != DIM:
            raise PerceptionError(f"histogram bins {bins} do not give {DIM} dimensions")
        if not 0 < centre <= 1:
            raise PerceptionError(f"centre must be in (0, 1], got {centre}")
        self.cv2 = require_cv2()
        self.bins = tuple(int(b) for b in bins)
        self.parts = (upper, lower)
        self.centre = float(centre)
        self.exclusive = bool(exclusive)
        self.min_own = float(min_own)

    def _part(self, hsv: np.ndarray, mask: np.ndarray | None = None) -> np.ndarray:
        h = self.cv2.calcHist([hsv], [0, 1, 2], mask, list(self.bins), [0, 180, 0, 256, 0, 256])
        h = np.sqrt(h.ravel())
        n = np.linalg.norm(h)
        return h / n if n > 0 else h

    def extract(self, image: np.ndarray, boxes: np.ndarray,
                mask: np.ndarray | None = None) -> np.ndarray:
        """See :class:`ReidExtractor` and the class docstring."""
        cv2 = self.cv2
        ib = _int_boxes(boxes, image.shape)
        out = np.full((len(ib), DIM), np.nan, np.float32)
        for i, (x0, y0, x1, y1) in enumerate(ib):
            w, h = x1 - x0, y1 - y0
            if w < 2 or h < 4:
                continue
            m = (1.0 - self.centre) / 2.0
            cx0, cx1 = x0 + int(round(m * w)), x1 - int(round(m * w))
            if cx1 <= cx0:
                cx0, cx1 = x0, x1
            hsv = cv2.cvtColor(np.ascontiguousarray(image[y0:y1, cx0:cx1]), cv2.COLOR_BGR2HSV)
            own = np.full((y1 - y0, cx1 - cx0), 255, np.uint8)
            if self.exclusive:
                for j, (ox0, oy0, ox1, oy1) in enumerate(ib):
                    if j == i:
                        continue
                    ax0, ax1 = max(ox0, cx0) - cx0, min(ox1, cx1) - cx0
                    ay0, ay1 = max(oy0, y0) - y0, min(oy1, y1) - y0
                    if ax1 > ax0 and ay1 > ay0:
                        own[ay0:ay1, ax0:ax1] = 0
            fg = None if mask is None else mask[y0:y1, cx0:cx1]
            parts = []
            for lo, hi in self.parts:
                r0, r1 = int(lo * h), max(int(hi * h), int(lo * h) + 1)
                pm = np.ascontiguousarray(own[r0:r1])
                if cv2.countNonZero(pm) < self.min_own * pm.size:
                    break
                if fg is not None:
                    both = cv2.bitwise_and(pm, np.ascontiguousarray(fg[r0:r1]))
                    if cv2.countNonZero(both) >= 0.15 * pm.size:
                        pm = both
                parts.append(self._part(np.ascontiguousarray(hsv[r0:r1]), pm))
            if len(parts) < len(self.parts):
                continue
            v = np.concatenate(parts)
            n = np.linalg.norm(v)
            if n > 0:
                out[i] = v / n
        return out


class OsnetReid:
    """OSNet features on the CPU, one batch per frame (chunks of ``batch`` boxes).

    ``weights``: a torchreid checkpoint (``{'state_dict': ...}`` or a bare state dict,
    ``module.`` prefixes allowed, ``classifier.*`` ignored); checked and loaded here, so a missing
    or wrong file fails at start-up. ``weights=None`` is allowed only with ``random_init=True``
    (benchmarks and tests: the features then carry no identity). ``threads``: torch intra-op
    threads (``None`` leaves torch's default).
    """

    MEAN = np.array([0.485, 0.456, 0.406], np.float32)
    STD = np.array([0.229, 0.224, 0.225], np.float32)

    def __init__(self, variant: str = "x1_0", weights: str | Path | None = None, *,
                 random_init: bool = False, batch: int = 32, input_size: tuple[int, int] = (256, 128),
                 threads: int | None = None, seed: int = 0):
        if weights is None and not random_init:
            raise PerceptionError("OSNet needs a weights file (a torchreid checkpoint); "
                                  "see docs/perception.md, or use reid = \"histogram\"")
        if weights is not None and not Path(weights).is_file():
            raise PerceptionError(f"OSNet weights file not found: {weights}")
        try:
            import torch  # noqa: PLC0415 - torch only when OSNet is configured
        except ImportError as e:  # pragma: no cover
            raise PerceptionError(f"OSNet needs torch: pip install 'dmtt[reid]' ({e})") from None
        from edge_node.perception import osnet as osn  # noqa: PLC0415 - it imports torch

        self.cv2 = require_cv2()
        self.torch = torch
        if threads is not None:
            torch.set_num_threads(int(threads))
        torch.manual_seed(seed)
        self.model = osn.osnet(variant)
        self.name = f"osnet_{variant.removeprefix('osnet_')}"
        self.report = {"loaded": 0, "ignored": []}
        if weights is not None:
            self.report = osn.load_torchreid_checkpoint(self.model, weights)
        self.model.eval()
        self.dim = self.model.feature_dim
        self.batch = max(1, int(batch))
        self.input_size = (int(input_size[0]), int(input_size[1]))  # (height, width)

    def preprocess(self, image: np.ndarray, boxes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(m, 3, H, W)`` float32 network input for the usable boxes, and their indices."""
        cv2 = self.cv2
        H, W = self.input_size
        ib = _int_boxes(boxes, image.shape)
        keep = np.flatnonzero((ib[:, 2] - ib[:, 0] >= 2) & (ib[:, 3] - ib[:, 1] >= 2))
        x = np.empty((len(keep), H, W, 3), np.float32)
        for j, i in enumerate(keep):
            x0, y0, x1, y1 = ib[i]
            crop = cv2.resize(image[y0:y1, x0:x1], (W, H), interpolation=cv2.INTER_LINEAR)
            x[j] = crop[:, :, ::-1]  # BGR -> RGB
        x = (x / 255.0 - self.MEAN) / self.STD
        return np.ascontiguousarray(x.transpose(0, 3, 1, 2)), keep

    def extract(self, image: np.ndarray, boxes: np.ndarray,
                mask: np.ndarray | None = None) -> np.ndarray:
        torch = self.torch
        boxes = np.asarray(boxes, float).reshape(-1, 4)
        out = np.full((len(boxes), self.dim), np.nan, np.float32)
        if len(boxes) == 0:
            return out
        x, keep = self.preprocess(image, boxes)
        if len(keep) == 0:
            return out
        feats = []
        with torch.inference_mode():
            for s in range(0, len(keep), self.batch):
                feats.append(self.model(torch.from_numpy(x[s:s + self.batch])).numpy())
        f = np.concatenate(feats).astype(np.float32)
        out[keep] = l2_normalise(f)
        return out


class ReidKind(Protocol):
    """What ``reid = "<name>"`` needs: the ``[perception.<table>]`` table it reads (kinds may
    share one: every OSNet variant reads ``[perception.osnet]``; ``None``: no table), and the
    extractor from what it read (``None``: no descriptors)."""

    table: str | None

    def options(self, perception: Any, base: Path, selected: bool) -> dict[str, Any]:
        """The kind's options from ``perception.optional_table(self.table)``, validated, with
        the table finished; ``selected``: a required key may be enforced."""

    def from_options(self, options: dict[str, Any]) -> ReidExtractor | None: ...


class _NoTable:
    table = None

    def options(self, perception, base: Path, selected: bool) -> dict:
        return {}


class _Histogram(_NoTable):
    """Colour histograms (:class:`HistogramReid`), no weights."""

    def from_options(self, options: dict) -> ReidExtractor:
        return HistogramReid()


class _Nothing(_NoTable):
    """No descriptors: the tracker associates by geometry alone."""

    def from_options(self, options: dict) -> None:
        return None


class _Osnet:
    """One OSNet variant (:class:`OsnetReid`) from ``[perception.osnet]``: ``weights`` (a
    torchreid checkpoint, required), ``batch``, ``threads``."""

    table = "osnet"

    def __init__(self, variant: str):
        self.variant = variant

    def options(self, perception, base: Path, selected: bool) -> dict:
        s = perception.optional_table("osnet")
        if s is None:
            if selected:
                raise perception.error("osnet", f"is required for reid = "
                                       f"\"osnet_{self.variant}\" ([perception.osnet] weights = "
                                       "\"...pth\", a torchreid checkpoint; see docs/perception.md)")
            return {}
        out = drop_none({
            "weights": file_option(s, "weights", base, "a torchreid OSNet checkpoint",
                                   required=selected),
            "batch": s.integer("batch", None, lo=1),
            "threads": s.integer("threads", None, lo=1),
        })
        s.finish()
        return out

    def from_options(self, options: dict) -> ReidExtractor:
        return OsnetReid(self.variant, options.get("weights"),
                         random_init=bool(options.get("random_init", False)),
                         batch=options.get("batch", 32), threads=options.get("threads"))


#: The re-id backends by name (``[perception] reid``; ``sim_cluster up --reid``).
REID: Registry[ReidKind] = Registry("re-id", "dmtt.reid", PerceptionError)
REID.add("histogram", _Histogram())
for _v in ("x1_0", "x0_25", "x0_75", "x0_5", "ibn_x1_0"):
    REID.add(f"osnet_{_v}", _Osnet(_v))
REID.add("none", _Nothing())


def make_reid(kind: str, *, weights: str | Path | None = None, random_init: bool = False,
              batch: int = 32, threads: int | None = None) -> ReidExtractor | None:
    """The extractor ``kind`` names (a :data:`REID` name); ``None`` for ``"none"``."""
    return REID.get(kind).from_options(drop_none({
        "weights": None if weights is None else str(weights), "random_init": random_init,
        "batch": batch, "threads": threads}))
