"""Evaluation: ``metrics`` (MOTA, IDF1, ... in the image and on the ground, py-motmetrics) and
``report`` (the per-node table ``run`` and ``up`` print)."""
