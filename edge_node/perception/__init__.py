"""From camera frames to detections: frame sources, people detectors, re-identification.

The paper's nodes see images: a person detector gives boxes and OSNet gives each box a 512-d
appearance descriptor. This package turns frames into the tracker core's
:class:`~edge_node.core.types.Detection` objects, on a CPU, with nothing downloaded at run time:

* :mod:`.frames` -- where frames come from (a video file, a folder of images, the EPFL dataset
  layout, a live camera through OpenCV), each frame with its index and timestamp;
* :mod:`.detectors` -- :class:`~.detectors.Detector`: OpenCV's HOG people detector, MOG2 background
  subtraction (no weights), an ONNX person detector through OpenCV's DNN module (a model file the
  user gives);
* :mod:`.reid` -- :class:`~.reid.ReidExtractor`: OSNet (:mod:`.osnet`, torchreid checkpoints) or a
  colour-histogram descriptor, both 512-d and L2-normalised;
* :mod:`.pipeline` -- frame -> detections with descriptors;
* :mod:`.calibrate` -- the image-to-ground homography from point pairs (``edge_node calibrate``).

OpenCV is imported by the modules that need it, and torch only when OSNet is configured: the
tracker core (``edge_node.core``) and a node fed by detection files never import either.
"""
from __future__ import annotations

from protocol.errors import DmttError


class PerceptionError(DmttError, ValueError):
    """A perception component that cannot be built or used (a missing or unreadable model file,
    a bad checkpoint, a frame source that cannot be opened, a missing optional dependency).
    Raised at construction, so a node fails at start-up with a clear message, not mid-run."""


def require_cv2():
    """``cv2``, or a :class:`PerceptionError` saying how to install it."""
    try:
        import cv2  # noqa: PLC0415 - OpenCV is optional (the vision extra): only when used
    except ImportError as e:  # pragma: no cover - the vision extra is installed in dev
        raise PerceptionError("OpenCV is needed for frames and detectors: "
                              "pip install 'dmtt[vision]' (opencv-python-headless)"
                              f" ({e})") from None
    return cv2


__all__ = ["PerceptionError", "require_cv2"]
