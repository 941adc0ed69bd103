"""MOG2 background subtraction read with the camera's geometry (``detector = "mog2"``)."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from edge_node.perception import PerceptionError, require_cv2
from edge_node.perception.detectors.base import DETECTORS, Box, nms
from edge_node.perception.options import drop_none, file_option, pair_option


class Mog2Detector:
    """Background subtraction (MOG2) with morphology, fragment joining and blob splitting.

    ``camera`` (an :class:`edge_node.geometry.Camera`) and ``units_per_metre`` give the expected
    size of a person (``person_size_m`` = width, height in metres) at any foot point; without a
    camera a person is ``aspect`` times as wide as the blob is tall. ``background``: a video or image
    (array or path) of the empty scene the model starts from; ``learning_rate``: MOG2's (negative = its
    automatic ``1 / history``); a small rate keeps people who stand still in the foreground.
    """

    name = "mog2"

    def __init__(self, *, camera=None, units_per_metre: float = 1.0,
                 background: np.ndarray | str | Path | None = None, history: int = 500,
                 var_threshold: float = 16.0, learning_rate: float = -1.0,
                 min_area: int = 60, min_height: int = 12, open_px: int = 3, close_px: int = 5,
                 split: bool = True, person_size_m: tuple[float, float] = (0.5, 1.75),
                 aspect: float = 0.38, max_split: int = 6, min_visible_height: float = 0.8,
                 hidden_visible_height: float = 0.95, merge_m: float = 0.55):
        cv2 = require_cv2()
        self.cv2 = cv2
        if history < 1 or var_threshold <= 0 or min_area < 1:
            raise PerceptionError("mog2: history >= 1, var_threshold > 0, min_area >= 1 required")
        self.mog = cv2.createBackgroundSubtractorMOG2(history=int(history),
                                                      varThreshold=float(var_threshold),
                                                      detectShadows=False)
        self.learning_rate = float(learning_rate)
        self.min_area = int(min_area)
        self.min_height = int(min_height)
        self.k_open = (cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (open_px, open_px))
                       if open_px > 1 else None)
        self.k_close = (cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (close_px, close_px))
                        if close_px > 1 else None)
        self.split = bool(split)
        self.camera = camera
        self.upm = float(units_per_metre)
        self.person_m = (float(person_size_m[0]), float(person_size_m[1]))
        self.aspect = float(aspect)
        self.max_split = int(max_split)
        self.min_visible_height = float(min_visible_height)
        self.hidden_visible_height = float(hidden_visible_height)
        self.merge_m = float(merge_m)
        self.mask: np.ndarray | None = None  # the last cleaned foreground mask (for inspection)
        if background is not None:
            self.prime(background)

    @classmethod
    def options(cls, perception, base: Path, selected: bool) -> dict:
        """``[perception.mog2]``, every key optional (:class:`~.base.DetectorKind`)."""
        m = perception.optional_table("mog2")
        if m is None:
            return {}
        out = drop_none({
            "background": file_option(m, "background", base, "a video or image of the empty scene"),
            "history": m.integer("history", None, lo=1),
            "var_threshold": m.number("var_threshold", None, lo=0, lo_open=True),
            "learning_rate": m.number("learning_rate", None, lo=-1, hi=1),
            "min_area": m.integer("min_area", None, lo=1),
            "min_height": m.integer("min_height", None, lo=0),
            "open_px": m.integer("open_px", None, lo=0),
            "close_px": m.integer("close_px", None, lo=0),
            "split": m.boolean("split", None) if m.has("split") else None,
            "person_size_m": pair_option(m, "person_size_m", integer=False),
        })
        m.finish()
        return out

    @classmethod
    def from_options(cls, options: dict, *, camera=None, units_per_metre: float = 1.0):
        """The camera's geometry reads the blobs (``person_size_m`` a cylinder at each foot)."""
        opts = {"camera": camera, "units_per_metre": units_per_metre, **options}
        if "person_size_m" in opts:
            opts["person_size_m"] = tuple(opts["person_size_m"])
        return cls(**opts)

    def prime(self, background: np.ndarray | str | Path, repeats: int = 5) -> None:
        """Start the background model from the empty scene: an image (array or file) or a
        short video of it. A video is better: it shows the camera's noise and compression, so
        MOG2 learns each pixel's variance instead of starting from its default."""
        cv2 = self.cv2
        frames: list[np.ndarray] = []
        if isinstance(background, np.ndarray):
            frames = [background] * repeats
        else:
            path = Path(background)
            img = cv2.imread(str(path), cv2.IMREAD_COLOR) if path.is_file() else None
            if img is not None:
                frames = [img] * repeats
            elif path.is_file():
                cap = cv2.VideoCapture(str(path))
                while len(frames) < 500:
                    ok, f = cap.read()
                    if not ok or f is None:
                        break
                    frames.append(f)
                cap.release()
            if not frames:
                raise PerceptionError(f"mog2: cannot read the background {path} (an image or a "
                                      "video of the empty scene)")
        for i, f in enumerate(frames):  # a running average: every frame weighs the same
            self.mog.apply(f, learningRate=1.0 / (i + 1))

    # -- geometry -------------------------------------------------------------------------------
    def expected_size(self, u: float, v: float, blob_h: float) -> tuple[float, float]:
        """Width and height (px) of a person whose feet are at pixel ``(u, v)``."""
        cam = self.camera
        if cam is not None:
            try:
                g = cam.to_ground(np.array([[u, v]]))[0]
                if np.all(np.isfinite(g)) and cam.in_front(g[None])[0]:
                    w, h = self.person_m
                    box = cam.cylinder_to_box(np.array([g[0], g[1], w * self.upm, h * self.upm]))
                    if np.all(np.isfinite(box)) and box[2] > 0 and box[3] > 0:
                        return float(box[2]), float(box[3])
            except (ValueError, FloatingPointError, np.linalg.LinAlgError):
                pass
        return self.aspect * blob_h, blob_h

    # -- detection ------------------------------------------------------------------------------
    def foreground(self, image: np.ndarray) -> np.ndarray:
        cv2 = self.cv2
        fg = self.mog.apply(image, learningRate=self.learning_rate)
        _, fg = cv2.threshold(fg, 200, 255, cv2.THRESH_BINARY)
        if self.k_open is not None:
            fg = cv2.morphologyEx(fg, cv2.MORPH_OPEN, self.k_open)
        if self.k_close is not None:
            fg = cv2.morphologyEx(fg, cv2.MORPH_CLOSE, self.k_close)
        self.mask = fg
        return fg

    def detect(self, image: np.ndarray) -> list[Box]:
        cv2 = self.cv2
        fg = self.foreground(image)
        H, W = fg.shape[:2]
        n, labels, stats, _ = cv2.connectedComponentsWithStats(fg, connectivity=8)
        blobs = [list(map(int, stats[i, :4])) + [i] for i in range(1, n)
                 if stats[i, cv2.CC_STAT_AREA] >= max(8, self.min_area // 4)]
        groups = self._join(blobs)
        out: list[Box] = []
        for members in groups:
            x0 = min(b[0] for b in members)
            y0 = min(b[1] for b in members)
            x1 = max(b[0] + b[2] for b in members)
            y1 = max(b[1] + b[3] for b in members)
            ids = [b[4] for b in members]
            m = np.isin(labels[y0:y1, x0:x1], ids)
            if int(m.sum()) < self.min_area:
                continue
            for (px0, py0, px1, py1, area) in self._people(m, x0, y0, H):
                w, h = px1 - px0, py1 - py0
                if h < self.min_height or w < 2 or area < self.min_area:
                    continue
                if py1 >= H - 1.5:  # feet below the image: no foot point to measure
                    continue
                if px0 <= 0 or px1 >= W:  # cut by a side: keep only most of a person
                    ew, _ = self.expected_size((px0 + px1) / 2.0, py1, h)
                    if w < 0.5 * ew:
                        continue
                out.append((np.array([px0, py0, w, h], float),
                            float(min(1.0, area / float(max(w * h, 1))))))
        return self._merge_close(out)

    def _merge_close(self, found: list[Box]) -> list[Box]:
        """Two boxes whose foot points are closer on the ground than two bodies can stand
        (``merge_m``) are parts of one person: their union."""
        cam = self.camera
        if cam is None or len(found) < 2 or self.merge_m <= 0:
            return found
        boxes = [b for b, _ in found]
        scores = [s for _, s in found]
        feet = cam.to_ground(np.array([[b[0] + b[2] / 2.0, b[1] + b[3]] for b in boxes]))
        alive = [True] * len(boxes)
        lim = self.merge_m * self.upm
        for i in range(len(boxes)):
            for j in range(i + 1, len(boxes)):
                if not (alive[i] and alive[j]):
                    continue
                if np.all(np.isfinite(feet[[i, j]])) and np.hypot(*(feet[i] - feet[j])) < lim:
                    a, b = boxes[i], boxes[j]
                    x0, y0 = min(a[0], b[0]), min(a[1], b[1])
                    x1, y1 = max(a[0] + a[2], b[0] + b[2]), max(a[1] + a[3], b[1] + b[3])
                    boxes[i] = np.array([x0, y0, x1 - x0, y1 - y0])
                    scores[i] = max(scores[i], scores[j])
                    feet[i] = cam.to_ground(np.array([[x0 + (x1 - x0) / 2.0, y1]]))[0]
                    alive[j] = False
        return [(boxes[i], scores[i]) for i in range(len(boxes)) if alive[i]]

    def _join(self, blobs: list[list[int]]) -> list[list[list[int]]]:
        """Group fragments of one person: blobs sharing most of their columns, whose union is
        no taller than a person at the lower one's feet (greedy, largest first)."""
        blobs = sorted(blobs, key=lambda b: -b[2] * b[3])
        groups: list[list[list[int]]] = []
        for b in blobs:
            placed = False
            for g in groups:
                gx0 = min(c[0] for c in g)
                gx1 = max(c[0] + c[2] for c in g)
                gy0 = min(c[1] for c in g)
                gy1 = max(c[1] + c[3] for c in g)
                ov = min(gx1, b[0] + b[2]) - max(gx0, b[0])
                if ov < 0.5 * min(b[2], gx1 - gx0):
                    continue
                y0, y1 = min(gy0, b[1]), max(gy1, b[1] + b[3])
                _, eh = self.expected_size((gx0 + gx1) / 2.0, y1, y1 - y0)
                if y1 - y0 <= 1.15 * eh:
                    g.append(b)
                    placed = True
                    break
            if not placed:
                groups.append([b])
        return groups

    def _columns(self, m: np.ndarray, x0: int, y0: int) -> list[tuple[int, int]]:
        """Column spans of the people side by side in a blob: a blob wider than one person (at
        its foot point) is cut at its emptiest columns near the nominal cuts."""
        h, w = m.shape
        if not self.split:
            return [(0, w)]
        ew, _ = self.expected_size(x0 + w / 2.0, y0 + h, h)
        if w <= 1.35 * ew:
            return [(0, w)]
        k = min(max(2, int(round(w / max(ew, 1.0)))), self.max_split)
        cols = np.convolve(m.sum(axis=0).astype(float), np.ones(3) / 3.0, mode="same")
        cuts = []
        for j in range(1, k):
            c = j * w / k
            lo, hi = int(max(1, c - w / (3 * k))), int(min(w - 1, c + w / (3 * k)))
            if hi > lo:
                cuts.append(lo + int(np.argmin(cols[lo:hi])))
        edges = [0] + sorted(set(cuts)) + [w]
        return [(a, b) for a, b in zip(edges[:-1], edges[1:]) if b > a]

    def _people(self, m: np.ndarray, x0: int, y0: int, H: int
                ) -> list[tuple[int, int, int, int, int]]:
        """Boxes ``(x0, y0, x1, y1, area)`` of the people in one blob mask.

        Without a camera: column cuts only. With one, nearest first: people stand on the
        ground, so the lowest foreground pixels are the nearest person's feet. Their centre is
        the column run of foreground in the bottom rows that holds the lowest pixel; a person
        standing there (``expected_size``) claims the foreground in a box 1.6 widths wide and
        1.02 heights tall above it; the rest of the blob is analysed again. The box is centred
        on the feet, as wide as the claimed lower body. A part shorter than
        ``min_visible_height`` of a person standing at its lowest row is dropped (a fragment),
        and so is one shorter than ``hidden_visible_height`` whose lowest row rests on a nearer
        person's pixels: people stand on the ground, so a person seen shorter than a person
        standing there has hidden feet, and its lowest row is no foot point. (Placing hidden
        feet from the head's height would cost metres on the ground at these camera heights.)
        """
        if self.camera is None or not self.split:
            out = []
            for a, b in self._columns(m, x0, y0):
                sub = m[:, a:b]
                rows = np.flatnonzero(sub.any(axis=1))
                cols = np.flatnonzero(sub.any(axis=0))
                if len(rows):
                    out.append((x0 + a + int(cols[0]), y0 + int(rows[0]), x0 + a + int(cols[-1]) + 1,
                                y0 + int(rows[-1]) + 1, int(sub.sum())))
            return out
        hh, ww = m.shape
        rem = m.copy()
        claimed = np.zeros_like(m)
        out = []
        for _ in range(2 * self.max_split):
            if int(rem.sum()) < max(8, self.min_area // 2):
                break
            rows = np.flatnonzero(rem.any(axis=1))
            top, v1 = int(rows[0]), int(rows[-1]) + 1
            low = np.flatnonzero(rem[v1 - 1])
            ew, eh = self.expected_size(x0 + float(low.mean()), y0 + v1, v1 - top)
            band = rem[max(0, int(v1 - 0.15 * eh)):v1].any(axis=0)
            # the run of foot columns holding the lowest pixel (gaps up to 0.9 widths bridged:
            # a walker's feet are up to a stride apart)
            gap = max(1, int(0.9 * ew))
            cols = np.flatnonzero(band)
            seed = int(low[len(low) // 2])
            lo = hi = seed
            for c in cols[cols < seed][::-1]:
                if lo - c > gap:
                    break
                lo = int(c)
            for c in cols[cols > seed]:
                if c - hi > gap:
                    break
                hi = int(c)
            u = (lo + hi + 1) / 2.0
            ew, eh = self.expected_size(x0 + u, y0 + v1, v1 - top)
            half = 0.8 * ew
            if hi + 1 - lo > 1.5 * ew:  # feet of people side by side: one person's share
                k = min(max(2, int(round((hi + 1 - lo) / ew))), self.max_split)
                step = (hi + 1 - lo) / k
                j = min(int((seed - lo) / step), k - 1)
                u = lo + (j + 0.5) * step
                half = 0.5 * step
                ew, eh = self.expected_size(x0 + u, y0 + v1, v1 - top)
            cx0 = max(0, int(np.floor(u - half)))
            cx1 = min(ww, int(np.ceil(u + half)))
            cy0 = max(0, int(np.floor(v1 - 1.02 * eh)))
            claim = rem[cy0:v1, cx0:cx1]
            rr = np.flatnonzero(claim.any(axis=1))
            cc = np.flatnonzero(claim.any(axis=0))
            area = int(claim.sum())
            if len(rr) == 0:  # cannot happen (the lowest pixel is inside), but never loop forever
                rem[v1 - 1] = False
                continue
            by0, by1 = y0 + cy0 + int(rr[0]), y0 + v1
            # resting on a nearer person's pixels: the feet may be hidden, so be strict
            hidden = bool(claimed[v1:min(hh, v1 + 3), cx0:cx1].any())
            need = self.hidden_visible_height if hidden else self.min_visible_height
            if by1 - by0 >= need * eh:
                # width from the lower body (arms and whatever stands behind are above it),
                # centred on the feet
                lower = claim[max(0, int(rr[-1] + 1 - 0.6 * (rr[-1] + 1 - rr[0]))):]
                lc = np.flatnonzero(lower.any(axis=0))
                w = float(lc[-1] + 1 - lc[0]) if len(lc) else float(cc[-1] + 1 - cc[0])
                w = max(w, 0.6 * ew)
                xc = x0 + u
                out.append((xc - w / 2.0, by0, xc + w / 2.0, by1 - 0.5, area))
            claimed[cy0:v1, cx0:cx1] |= claim
            rem[cy0:v1, cx0:cx1] = False
        return out


DETECTORS.add("mog2", Mog2Detector)
