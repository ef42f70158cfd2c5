"""Metric functions against hand-computed values and closed forms.

All metrics run in float64. Bounds are rounding counts (``tests.tolerances.float64_bound``: any
summation order) at the values' magnitude, with the eigensolvers' backward error taken as
D u ||A|| (LAPACK's and MKL's symmetric solvers are backward stable with a modest p(D); D is
generous), times ``MARGIN`` = 10 for second-order terms and counting slack; values that are
copied or exactly representable are compared exactly. Sampling thresholds say so.
"""

import math

import numpy as np
import pytest
import scipy.linalg
import torch

from t2m.evaluate import metrics
from tests.tolerances import U64, float64_bound

MARGIN = 10


def _random_covariance(rng: np.random.Generator, dim: int) -> np.ndarray:
    a = rng.normal(size=(dim, dim))
    return a @ a.T + 0.1 * np.eye(dim)


def _distance_bound(a: np.ndarray, b: np.ndarray, exact: np.ndarray) -> np.ndarray:
    """Elementwise float64 bound on ``euclidean_distance_matrix(a, b)`` against ``exact``.

    After centring (both sets by the same centre, <= 1 rounding at |a - centre| per entry, and
    the mean's N roundings at |a|), ||x||^2 - 2 x.y + ||y||^2 carries gamma_{D+2} (|x| + |y|)^2 =
    E, and the root turns E into at most E / max(d, sqrt E): sqrt E where the distance is zero.
    """
    centre = 0.5 * (a.mean(axis=0) + b.mean(axis=0))
    slack = float64_bound(len(a) + len(b), np.abs(np.concatenate([a, b])).max())
    size_a = np.linalg.norm(a - centre, axis=1) + np.sqrt(a.shape[1]) * slack
    size_b = np.linalg.norm(b - centre, axis=1) + np.sqrt(b.shape[1]) * slack
    squared = float64_bound(a.shape[1] + 2, 1.0) * (size_a[:, None] + size_b[None, :]) ** 2
    return squared / np.maximum(exact, np.sqrt(squared)) + U64 * (exact + size_a[:, None])


def _frechet_bound(cov1: np.ndarray, cov2: np.ndarray, mean_diff: float = 0.0) -> float:
    """float64 bound on ``frechet_distance`` for these covariances.

    The computed sqrt(cov1) is the exact root of a matrix within D u ||cov1|| of cov1 (eigh is
    backward stable; the clamp of negative eigenvalues moves no more), and root1 @ cov2 @ root1
    and eigvalsh add 2 D and D more: the eigenvalues mu of sqrt(cov1) cov2 sqrt(cov1) (those of
    cov2^1/2 cov1 cov2^1/2) move by delta = 4 D u ||cov1|| ||cov2||; sqrt turns that into
    min(delta / (2 sqrt mu), sqrt delta), a sqrt where mu vanishes (singular covariances); the
    traces and ||dm||^2 carry D + 4 more at their own size.
    """
    dim = len(cov1)
    norm1, norm2 = np.linalg.norm(cov1, 2), np.linalg.norm(cov2, 2)
    delta = float64_bound(4 * dim, norm1 * norm2)
    values, vectors = np.linalg.eigh(cov1)
    root1 = (vectors * np.sqrt(np.maximum(values, 0))) @ vectors.T
    mu = np.maximum(np.linalg.eigvalsh(root1 @ cov2 @ root1), 0.0)
    roots = np.minimum(delta / (2 * np.sqrt(np.maximum(mu, 1e-300))), np.sqrt(delta))
    size = np.trace(cov1) + np.trace(cov2) + 2 * np.sqrt(mu).sum() + mean_diff
    return float(2 * roots.sum() + float64_bound(dim + 4, size))


# --- distances -------------------------------------------------------------------------------


def test_distance_matrix_hand_values():
    a = np.array([[0.0, 0.0], [3.0, 4.0]])
    b = np.array([[0.0, 0.0], [6.0, 8.0], [3.0, 0.0]])
    expected = np.array([[0.0, 10.0, 3.0], [5.0, 5.0, 4.0]])
    bound = MARGIN * _distance_bound(a, b, expected)  # 1.4e-7 at the zero distance, 1e-14 at others
    np.testing.assert_array_less(np.abs(metrics.euclidean_distance_matrix(a, b) - expected), bound)


def test_distance_of_identical_large_vectors_is_zero_not_nan():
    # ||a||^2 - 2ab + ||b||^2 cancels catastrophically here; the clamp must keep it real.
    a = np.full((4, 512), 1e4) + np.arange(512) * 1e-3
    dist = metrics.euclidean_distance_matrix(a, a)
    assert np.all(np.isfinite(dist))
    # The zero distance from the centred expansion (without centring its error would be
    # sqrt(u) |a| ~ 2e-4 per entry, 0.02 here); observed exactly 0.
    bound = MARGIN * np.diag(_distance_bound(a, a, np.zeros((4, 4))))
    np.testing.assert_array_less(np.diag(dist), bound)
    np.testing.assert_array_equal(metrics.paired_distances(a, a), 0.0)  # a - a is exactly 0


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
    # Small integers: x + 1, the differences, squares, their sum 4 and its root are exact.
    np.testing.assert_array_equal(metrics.paired_distances(x, x + 1.0), 2.0)


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
    # hits / count, one division each side: exact.
    np.testing.assert_array_equal(by_motion, [2 / 3, 1.0, 1.0])
    by_text = metrics.r_precision(text, motion, top_k=2, batch_size=3, query="text")
    np.testing.assert_array_equal(by_text, [2 / 3, 1.0])
    # MM-Dist: mean of |0.6 - 0|, |5 - 1|, |9 - 10| = 5.6 / 3. Positive terms, so relative
    # bounds: a square, a root, two sums and a division (5), and 5.6 / 3's own 2.
    expected = 5.6 / 3
    bound = MARGIN * float64_bound(5 + 2)
    assert metrics.multimodal_distance(text, motion) == pytest.approx(expected, rel=bound, abs=0)


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
    # A sampling threshold, not rounding: over 3,200 queries the top-k hit rate's binomial
    # standard error is sqrt(p (1 - p) / 3200) = 0.003 to 0.005, so 0.015 is 3 to 5 of them
    # (observed 0.0016 at most); a leak of the partner gives 1, a wrong pool 1/100.
    np.testing.assert_allclose(top, [1 / 32, 2 / 32, 3 / 32], rtol=0, atol=0.015)


# --- FID -------------------------------------------------------------------------------------


def test_fid_of_identical_sets_is_zero():
    rng = np.random.default_rng(3)
    x = rng.normal(size=(200, 64))
    # Both covariances are the same numbers; eigenvalues 0.23 .. 2.3 keep the roots Lipschitz:
    # 2 * 64 * delta / (2 sqrt mu) and the traces' 68 (1.6e-11; observed 0, the clamp at zero).
    cov = np.cov(x, rowvar=False)
    assert metrics.fid(x, x) == pytest.approx(0.0, abs=MARGIN * _frechet_bound(cov, cov))


def test_fid_of_a_translated_set_is_the_squared_shift():
    rng = np.random.default_rng(4)
    x = rng.normal(size=(300, 32))
    shift = rng.normal(size=32)
    # The covariances differ only by x + shift's rounding (u |x + shift| per entry), which the
    # Fréchet distance feels to second order; the means differ from shift by that rounding and
    # 2 N roundings of the column means at |x + shift|, through 2 |shift| in ||dm||^2; and the
    # Fréchet sum's own rounding (2.9e-11 against 48.8; observed 2e-14).
    cov = np.cov(x, rowvar=False)
    means = float64_bound(2 * len(x) + 1, np.abs(x + shift).max())
    mean_error = 2 * np.abs(shift).sum() * means
    bound = MARGIN * (_frechet_bound(cov, cov, float(shift @ shift)) + mean_error)
    assert metrics.fid(x, x + shift) == pytest.approx(float(shift @ shift), rel=0, abs=bound)


def test_frechet_distance_closed_forms():
    # 1-D: (m1 - m2)^2 + (s1 - s2)^2.
    value = metrics.frechet_distance([1.0], [[4.0]], [3.0], [[9.0]])
    assert value == pytest.approx(4.0 + 1.0, rel=0, abs=MARGIN * _frechet_bound([[4.0]], [[9.0]]))
    # Diagonal covariances: ||dm||^2 + sum (sqrt(a) - sqrt(b))^2.
    a = np.array([1.0, 4.0, 0.25])
    b = np.array([9.0, 1.0, 0.25])
    m1 = np.array([0.0, 1.0, 2.0])
    m2 = np.array([1.0, 1.0, 0.0])
    expected = 5.0 + (1 - 3) ** 2 + (2 - 1) ** 2 + 0.0
    got = metrics.frechet_distance(m1, np.diag(a), m2, np.diag(b))
    bound = MARGIN * _frechet_bound(np.diag(a), np.diag(b), 5.0)  # exact terms: 1e-13
    assert got == pytest.approx(expected, rel=0, abs=bound)


def test_frechet_distance_matches_scipy_sqrtm_for_full_covariances():
    rng = np.random.default_rng(5)
    c1, c2 = _random_covariance(rng, 20), _random_covariance(rng, 20)
    m1, m2 = rng.normal(size=20), rng.normal(size=20)
    product = c1 @ c2
    covmean = scipy.linalg.sqrtm(product).real
    expected = float((m1 - m2) @ (m1 - m2) + np.trace(c1) + np.trace(c2) - 2 * np.trace(covmean))
    # scipy's side a posteriori: covmean^2 misses c1 c2 by its residual (plus the residual's own
    # D-term rounding at ||covmean||^2), which moves the eigenvalues of c1 c2 (= those of the
    # symmetric c1^1/2 c2 c1^1/2, eigenvectors c1^1/2 W: condition <= sqrt(cond c1) = 25) by
    # at most 25 times that, and their roots as in ``_frechet_bound``; the trace sum's D + 4.
    residual = np.linalg.norm(covmean @ covmean - product, 2)
    residual += float64_bound(20, np.linalg.norm(covmean, 2) ** 2 + np.linalg.norm(product, 2))
    shift = np.sqrt(np.linalg.cond(c1)) * residual
    mu = np.linalg.eigvals(product).real
    scipy_error = np.minimum(shift / (2 * np.sqrt(mu)), np.sqrt(shift)).sum() * 2
    bound = MARGIN * (_frechet_bound(c1, c2, float((m1 - m2) @ (m1 - m2))) + scipy_error)
    # (7e-9 against 263, all but 4e-10 scipy's; observed 4.5e-13)
    assert metrics.frechet_distance(m1, c1, m2, c2) == pytest.approx(expected, rel=0, abs=bound)


def test_fid_of_sampled_gaussians_approaches_the_closed_form():
    rng = np.random.default_rng(6)
    dim = 4
    c1, c2 = _random_covariance(rng, dim), _random_covariance(rng, dim)
    m1, m2 = np.zeros(dim), np.full(dim, 0.5)
    x = rng.multivariate_normal(m1, c1, size=40000)
    y = rng.multivariate_normal(m2, c2, size=40000)
    exact = metrics.frechet_distance(m1, c1, m2, c2)
    # A sampling threshold, not rounding: from 40,000 draws per set the estimate's relative
    # standard deviation is about 0.6% (over other seeds), so 5% is 8 of them (observed 0.2%); a
    # wrong factor or a missing term is off by tens of percent.
    assert metrics.fid(x, y) == pytest.approx(exact, rel=0.05)


def test_fid_with_singular_covariances_is_finite():
    # 10 samples in 128 dimensions: rank-deficient covariances, where sqrtm is fragile.
    rng = np.random.default_rng(7)
    x = rng.normal(size=(10, 128))
    y = rng.normal(size=(10, 128)) + 0.1
    value = metrics.fid(x, y)
    assert math.isfinite(value) and value > 0
    # 118 of the 128 eigenvalues vanish, where the root turns the eigensolver's rounding delta
    # into sqrt(delta) each: 9.7e-4 in all (observed 0, the clamp at zero), against 218 for y.
    cov = np.cov(x, rowvar=False)
    assert metrics.fid(x, x) == pytest.approx(0.0, abs=MARGIN * _frechet_bound(cov, cov))


# --- diversity / multimodality ---------------------------------------------------------------


def test_diversity_of_equidistant_points():
    # Basis vectors: distinct points are sqrt(2) apart, so the mean is sqrt(2) times the fraction
    # of pairs whose two indices differ (replaying the generator's draws).
    points = np.eye(400)
    value = metrics.diversity(points, num_pairs=300, rng=np.random.default_rng(8))
    replay = np.random.default_rng(8)
    first = replay.choice(400, 300, replace=False)
    second = replay.choice(400, 300, replace=False)
    # Differences and squares of 0 and 1 are exact; a root (1) and the mean of 300 positive
    # terms (301) against the expected's root, mean and product (3), relative.
    bound = MARGIN * float64_bound(1 + 301 + 3)
    assert value == pytest.approx(math.sqrt(2) * np.mean(first != second), rel=bound, abs=0)
    assert metrics.diversity(np.ones((300, 5)), rng=np.random.default_rng(0)) == 0.0


def test_diversity_is_seeded_and_scales_linearly():
    x = np.random.default_rng(9).normal(size=(500, 16))
    d1 = metrics.diversity(x, rng=np.random.default_rng(1))
    assert metrics.diversity(x, rng=np.random.default_rng(1)) == d1
    # 3 x rounds each entry once, and a distance sums cancelling differences: relative error
    # <= u (|a| + |b|) / |a - b| per pair (2 u per entry), then D + 2 for the sum and root and 301
    # for the mean, on both sides (observed 1 rounding).
    replay = np.random.default_rng(1)
    first = replay.choice(500, 300, replace=False)
    second = replay.choice(500, 300, replace=False)
    distinct = first != second
    spread = np.linalg.norm(np.abs(x[first]) + np.abs(x[second]), axis=1)[distinct]
    cancellation = (spread / np.linalg.norm(x[first] - x[second], axis=1)[distinct]).max()
    bound = MARGIN * (2 * float64_bound(2 * cancellation) + 2 * float64_bound(16 + 2 + 301))
    scaled = metrics.diversity(3.0 * x, rng=np.random.default_rng(1))
    assert scaled == pytest.approx(3.0 * d1, rel=bound, abs=0)
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
    # Integers: differences and squares exact; a root and the mean of 50 (51), relative, and
    # the expected's 3.
    bound = MARGIN * float64_bound(1 + 51 + 3)
    assert value == pytest.approx(math.sqrt(2) * np.mean(first != second), rel=bound, abs=0)
    assert metrics.multimodality(np.ones((3, 30, 4))) == 0.0
    with pytest.raises(ValueError, match="samples per caption"):
        metrics.multimodality(np.ones((3, 5, 4)), num_pairs=10)


# --- aggregation -----------------------------------------------------------------------------


def test_confidence_interval_hand_values():
    mean, half = metrics.confidence_interval([1.0, 2.0, 3.0, 4.0])
    assert mean == 2.5
    # Deviations, squares, their sum 5 and the variance 1.25 are exact; then the same correctly
    # rounded sqrt, product by 1.96 and exact division by sqrt(4) = 2 on both sides: exact.
    assert half == 1.96 * math.sqrt(1.25) / 2.0
    assert metrics.confidence_interval([7.0]) == (7.0, 0.0)
    with pytest.raises(ValueError):
        metrics.confidence_interval([])
