"""The core computes the tracks it computed when they were recorded (issue 15, re-recorded for
wire schema 3 in issue 16).

``tests/data/core_reference.npz`` holds the tracks of ``core_reference.RUNS`` as recorded (see
``tests/core_reference.py`` for how and from which core: first the per-tracker core, which the
batched core matched to 1e-9; then, once the wire's rounding changed, the batched core).
The same runs through the current core must report the same ids in every frame, and the same
``x`` and ``P`` to 1e-9 (relative, or absolute below 1): batched numpy (stacked solves and
products) may round differently from one call per tracker, but no more than that.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from tests.core_reference import RUNS, flatten, run

REFERENCE = Path(__file__).parent / "data" / "core_reference.npz"
RTOL = 1e-9


@pytest.fixture(scope="module")
def reference():
    with np.load(REFERENCE) as z:
        return {key: z[key] for key in z.files}


def _rel(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.max(np.abs(a - b) / np.maximum(1.0, np.abs(b)), initial=0.0))


@pytest.mark.parametrize("name", list(RUNS))
def test_same_tracks_as_recorded(name, reference):
    got = flatten(run(name))
    rows = reference[f"{name}/rows"]
    assert len(rows) > 500  # a run with tracks in it
    np.testing.assert_array_equal(got["rows"], rows)  # same ids, nodes and frames
    assert got["x"].shape == reference[f"{name}/x"].shape
    assert got["P"].shape == reference[f"{name}/P"].shape
    assert _rel(got["x"], reference[f"{name}/x"]) < RTOL
    assert _rel(got["P"], reference[f"{name}/P"]) < RTOL


def test_the_comparison_can_fail(reference):
    """A change of one part in 1e8 in one estimate is caught."""
    x = reference["calib-ring-sync/x"].copy()
    x[len(x) // 2, 0] *= 1 + 1e-8
    assert _rel(x, reference["calib-ring-sync/x"]) > RTOL
