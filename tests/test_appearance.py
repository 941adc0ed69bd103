"""Synthetic appearance descriptors: calibrated distances, determinism, any person id."""
from __future__ import annotations

import numpy as np
import pytest

from sim_cluster.scenarios.synthetic.appearance import (AppearanceError, AppearanceModel,
                                                        AppearanceParams, cosine_distance)


def _distances(model: AppearanceModel, n: int = 60, seed: int = 0) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(seed)
    ids = np.arange(100, 100 + n)
    a = model.descriptors(ids, 0, rng)
    b = model.descriptors(ids, 0, rng)  # same camera, another frame
    c = model.descriptors(ids, 3, rng)  # another camera
    return {
        "same_camera": cosine_distance(a, b),
        "cross_camera": cosine_distance(a, c),
        "different_person": cosine_distance(a, np.roll(a, 1, axis=0)),
        "false_positive": cosine_distance(model.false_positive_descriptors(n, rng), a),
    }


def test_default_distances_fall_in_the_calibrated_ranges():
    d = _distances(AppearanceModel(seed=7))
    assert 0.05 <= d["same_camera"].min() and d["same_camera"].max() <= 0.15
    assert 0.15 <= d["cross_camera"].min() and d["cross_camera"].max() <= 0.30
    assert 0.60 <= d["different_person"].min() and d["different_person"].max() <= 1.0
    assert 0.60 <= d["false_positive"].min()
    expected = AppearanceParams().expected_distances()
    assert d["same_camera"].mean() == pytest.approx(expected["same_camera"], abs=0.01)
    assert d["cross_camera"].mean() == pytest.approx(expected["cross_camera"], abs=0.015)
    assert d["different_person"].mean() == pytest.approx(expected["different_person"], abs=0.03)
    # Same person in two cameras is similar, but never as similar as in one camera.
    assert np.all(d["cross_camera"] > d["same_camera"])


def test_from_distances_round_trips_and_shapes_the_sampled_distances():
    p = AppearanceParams.from_distances(0.05, 0.3, 0.9, dim=256)
    e = p.expected_distances()
    assert (e["same_camera"], e["cross_camera"], e["different_person"]) == pytest.approx((0.05, 0.3, 0.9))
    d = _distances(AppearanceModel(p, seed=1))
    assert d["same_camera"].mean() == pytest.approx(0.05, abs=0.01)
    assert d["cross_camera"].mean() == pytest.approx(0.30, abs=0.02)
    assert d["different_person"].mean() == pytest.approx(0.90, abs=0.03)


def test_descriptors_are_unit_float64_and_deterministic():
    m1, m2 = AppearanceModel(seed=5), AppearanceModel(seed=5)
    ids = np.array([3, 1, 3, -7, 2**40])  # repeated, negative and huge ids all work
    a = m1.descriptors(ids, 2, np.random.default_rng(9))
    b = m2.descriptors(ids, 2, np.random.default_rng(9))
    assert a.dtype == np.float64 and a.shape == (5, 512)
    np.testing.assert_allclose(np.linalg.norm(a, axis=1), 1.0, atol=1e-12)
    np.testing.assert_array_equal(a, b)
    # Identity does not depend on the call order or on which other people were asked for.
    np.testing.assert_array_equal(m1.identity(-7), AppearanceModel(seed=5).identity(-7))
    # Another seed: other people.
    c = AppearanceModel(seed=6).descriptors(ids, 2, np.random.default_rng(9))
    assert np.all(cosine_distance(a, c) > 0.5)


def test_noise_draws_exactly_n_times_dim_normals():
    m = AppearanceModel(AppearanceParams(dim=32), seed=0)
    r1, r2 = np.random.default_rng(4), np.random.default_rng(4)
    m.descriptors(np.array([1, 2, 3]), 0, r1)
    r2.standard_normal((3, 32))
    assert r1.random() == r2.random()
    single = m.descriptor(1, 0, np.random.default_rng(8))
    batch = m.descriptors(np.array([1]), 0, np.random.default_rng(8))[0]
    np.testing.assert_array_equal(single, batch)


def test_bad_parameters_raise_typed_errors():
    with pytest.raises(AppearanceError, match="dim"):
        AppearanceParams(dim=1)
    with pytest.raises(AppearanceError, match="noise"):
        AppearanceParams(noise=-0.1)
    with pytest.raises(AppearanceError, match="distances"):
        AppearanceParams.from_distances(0.3, 0.2, 0.8)
