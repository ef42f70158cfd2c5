"""Metric functions against hand-computed values and closed forms."""

import math

import numpy as np
import pytest
import scipy.linalg
import torch

from t2m.evaluate import metrics


def _random_covariance(rng: np.random.Generator, dim: int) -> np.ndarray:
    a = rng.normal(size=(dim, dim))
    return a @ a.T + 0.1 * np.eye(dim)


# --- distances -------------------------------------------------------------------------------


def test_distance_matrix_hand_values():
    a = np.array([[0.0, 0.0], [3.0, 4.0]])
    b = np.array([[0.0, 0.0], [6.0, 8.0], [3.0, 0.0]])
    expected = np.array([[0.0, 10.0, 3.0], [5.0, 5.0, 4.0]])
    np.testing.assert_allclose(metrics.euclidean_distance_matrix(a, b), expected, atol=1e-12)


def test_distance_of_identical_large_vectors_is_zero_not_nan():
    # ||a||^2 - 2ab + ||b||^2 cancels catastrophically here; the clamp must keep it real.
    a = np.full((4, 512), 1e4) + np.arange(512) * 1e-3
    dist = metrics.euclidean_distance_matrix(a, a)
    assert np.all(np.isfinite(dist))
    np.testing.assert_allclose(np.diag(dist), 0.0, atol=1e-3)
    np.testing.assert_allclose(metrics.paired_distances(a, a), 0.0)


def test_metrics_reject_nan_and_bad_shapes():
    good = np.zeros((32, 4))
    bad = good.copy()
    bad[3, 1] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        metrics.r_precision(bad, good)
    with pytest.raises(ValueError, match="NaN"):
        metrics.fid(good, bad)
    with pytest.raises(ValueError, match="shape"):
        metrics.euclidean_distance_matrix(np.zeros(4), np.zeros((2, 4)))
    with pytest.raises(ValueError, match="full batch"):
        metrics.r_precision(np.zeros((31, 4)), np.zeros((31, 4)))


def test_torch_tensors_are_accepted():
    x = torch.arange(12, dtype=torch.float32).reshape(3, 4)
    np.testing.assert_allclose(metrics.paired_distances(x, x + 1.0), 2.0)


# --- R-precision -----------------------------------------------------------------------------


def test_r_precision_of_a_perfect_embedding_is_one():
    rng = np.random.default_rng(0)
    text = rng.normal(size=(96, 512))
    motion = text + 1e-3 * rng.normal(size=text.shape)
    for query in ("motion", "text"):
        np.testing.assert_array_equal(metrics.r_precision(text, motion, query=query), [1, 1, 1])
    assert metrics.multimodal_distance(text, text) == 0.0


def test_r_precision_hand_case_and_orientation():
    # One batch of 3 on a line. Motions m0=0, m1=1, m2=10; captions t0=0.6, t1=5, t2=9.
    # motion query:  m0 -> t0(.6) t1(5) t2(9): own at rank 1
    #                m1 -> t0(.4) t1(4) t2(8): own at rank 2
    #                m2 -> t2(1) t1(5) t0(9.4): own at rank 1      => top1 2/3, top2 3/3
    # text query:    t0 -> m0(.6) m1(.4): m1 first, m0 second
    #                t1 -> m1(4) m0(5) m2(5): own first
    #                t2 -> m2(1): own first                        => top1 2/3, top2 3/3
    text = np.array([[0.6], [5.0], [9.0]])
    motion = np.array([[0.0], [1.0], [10.0]])
    by_motion = metrics.r_precision(text, motion, top_k=3, batch_size=3, query="motion")
    np.testing.assert_allclose(by_motion, [2 / 3, 1.0, 1.0])
    by_text = metrics.r_precision(text, motion, top_k=2, batch_size=3, query="text")
    np.testing.assert_allclose(by_text, [2 / 3, 1.0])
    # MM-Dist: mean of |0.6 - 0|, |5 - 1|, |9 - 10| = 5.6 / 3
    assert metrics.multimodal_distance(text, motion) == pytest.approx(5.6 / 3)


def test_r_precision_uses_only_full_batches_and_pools_within_a_batch():
    # 64 clips where each motion equals the caption of the clip 32 rows later: inside each batch
    # of 32 the true partner is far, so within-batch ranking fails; a 65th row is ignored.
    rng = np.random.default_rng(1)
    text = rng.normal(size=(65, 16))
    motion = text.copy()
    assert metrics.r_precision(text, motion)[0] == 1.0
    shifted = np.roll(text, 32, axis=0)
    score = metrics.r_precision(text, shifted, top_k=3)
    assert score[2] < 0.5
    assert np.all(np.diff(score) >= 0)


def test_r_precision_of_random_embedding_is_near_chance():
    rng = np.random.default_rng(2)
    text = rng.normal(size=(3200, 8))
    motion = rng.normal(size=(3200, 8))
    top = metrics.r_precision(text, motion)
    np.testing.assert_allclose(top, [1 / 32, 2 / 32, 3 / 32], atol=0.015)


# --- FID -------------------------------------------------------------------------------------


def test_fid_of_identical_sets_is_zero():
    rng = np.random.default_rng(3)
    x = rng.normal(size=(200, 64))
    assert metrics.fid(x, x) == pytest.approx(0.0, abs=1e-8)


def test_fid_of_a_translated_set_is_the_squared_shift():
    rng = np.random.default_rng(4)
    x = rng.normal(size=(300, 32))
    shift = rng.normal(size=32)
    assert metrics.fid(x, x + shift) == pytest.approx(float(shift @ shift), rel=1e-8)


def test_frechet_distance_closed_forms():
    # 1-D: (m1 - m2)^2 + (s1 - s2)^2.
    assert metrics.frechet_distance([1.0], [[4.0]], [3.0], [[9.0]]) == pytest.approx(4.0 + 1.0)
    # Diagonal covariances: ||dm||^2 + sum (sqrt(a) - sqrt(b))^2.
    a = np.array([1.0, 4.0, 0.25])
    b = np.array([9.0, 1.0, 0.25])
    m1 = np.array([0.0, 1.0, 2.0])
    m2 = np.array([1.0, 1.0, 0.0])
    expected = 5.0 + (1 - 3) ** 2 + (2 - 1) ** 2 + 0.0
    got = metrics.frechet_distance(m1, np.diag(a), m2, np.diag(b))
    assert got == pytest.approx(expected, rel=1e-12)


def test_frechet_distance_matches_scipy_sqrtm_for_full_covariances():
    rng = np.random.default_rng(5)
    c1, c2 = _random_covariance(rng, 20), _random_covariance(rng, 20)
    m1, m2 = rng.normal(size=20), rng.normal(size=20)
    covmean = scipy.linalg.sqrtm(c1 @ c2).real
    expected = float((m1 - m2) @ (m1 - m2) + np.trace(c1) + np.trace(c2) - 2 * np.trace(covmean))
    assert metrics.frechet_distance(m1, c1, m2, c2) == pytest.approx(expected, rel=1e-9)


def test_fid_of_sampled_gaussians_approaches_the_closed_form():
    rng = np.random.default_rng(6)
    dim = 4
    c1, c2 = _random_covariance(rng, dim), _random_covariance(rng, dim)
    m1, m2 = np.zeros(dim), np.full(dim, 0.5)
    x = rng.multivariate_normal(m1, c1, size=40000)
    y = rng.multivariate_normal(m2, c2, size=40000)
    exact = metrics.frechet_distance(m1, c1, m2, c2)
    assert metrics.fid(x, y) == pytest.approx(exact, rel=0.05)


def test_fid_with_singular_covariances_is_finite():
    # 10 samples in 128 dimensions: rank-deficient covariances, where sqrtm is fragile.
    rng = np.random.default_rng(7)
    x = rng.normal(size=(10, 128))
    y = rng.normal(size=(10, 128)) + 0.1
    value = metrics.fid(x, y)
    assert math.isfinite(value) and value > 0
    assert metrics.fid(x, x) == pytest.approx(0.0, abs=1e-6)


# --- diversity / multimodality ---------------------------------------------------------------


def test_diversity_of_equidistant_points():
    # Basis vectors: distinct points are sqrt(2) apart, so the mean is sqrt(2) times the fraction
    # of pairs whose two indices differ (replaying the generator's draws).
    points = np.eye(400)
    value = metrics.diversity(points, num_pairs=300, rng=np.random.default_rng(8))
    replay = np.random.default_rng(8)
    first = replay.choice(400, 300, replace=False)
    second = replay.choice(400, 300, replace=False)
    assert value == pytest.approx(math.sqrt(2) * np.mean(first != second))
    assert metrics.diversity(np.ones((300, 5)), rng=np.random.default_rng(0)) == 0.0


def test_diversity_is_seeded_and_scales_linearly():
    x = np.random.default_rng(9).normal(size=(500, 16))
    d1 = metrics.diversity(x, rng=np.random.default_rng(1))
    assert metrics.diversity(x, rng=np.random.default_rng(1)) == d1
    assert metrics.diversity(3.0 * x, rng=np.random.default_rng(1)) == pytest.approx(3.0 * d1)
    with pytest.raises(ValueError, match="300"):
        metrics.diversity(x[:100])


def test_multimodality_stays_within_each_caption():
    # Caption c's samples are 100*c + basis vectors: pairs within a caption are 0 or sqrt(2)
    # apart, pairs across captions would be ~100 apart.
    num_captions, num_samples = 5, 30
    samples = np.tile(np.eye(num_samples), (num_captions, 1, 1))  # (C, S, S)
    samples += 100.0 * np.arange(num_captions)[:, None, None]
    value = metrics.multimodality(samples, num_pairs=10, rng=np.random.default_rng(10))
    replay = np.random.default_rng(10)
    first = replay.choice(num_samples, 10, replace=False)
    second = replay.choice(num_samples, 10, replace=False)
    assert value == pytest.approx(math.sqrt(2) * np.mean(first != second))
    assert metrics.multimodality(np.ones((3, 30, 4))) == 0.0
    with pytest.raises(ValueError, match="samples per caption"):
        metrics.multimodality(np.ones((3, 5, 4)), num_pairs=10)


# --- aggregation -----------------------------------------------------------------------------


def test_confidence_interval_hand_values():
    mean, half = metrics.confidence_interval([1.0, 2.0, 3.0, 4.0])
    assert mean == 2.5
    assert half == pytest.approx(1.96 * math.sqrt(1.25) / 2.0)
    assert metrics.confidence_interval([7.0]) == (7.0, 0.0)
    with pytest.raises(ValueError):
        metrics.confidence_interval([])
