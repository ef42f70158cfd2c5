"""The text-to-motion evaluation metrics of Guo et al. (CVPR 2022), on evaluator embeddings.

Every function is pure and works on numpy arrays (torch tensors are accepted and copied to
float64 numpy first). Embeddings are rows: ``(N, D)``, with ``D = 512`` for the contrastive
evaluator but any ``D`` works. Randomised metrics (diversity, multimodality) take an explicit
``numpy.random.Generator`` so that a replication's seed fixes its result.

Conventions pinned here, because published numbers depend on them:

- Distances are Euclidean. Squared distances are clamped at zero before the square root, so
  rounding never turns a zero distance into NaN.
- R-precision is computed in batches of ``batch_size`` (32) consecutive rows; rows that do not fill
  a last batch are left out, as the original evaluation loader drops its last incomplete batch.
  By default each *caption* ranks the batch's motions, as the original evaluation code does
  (its distance matrix is captions x motions, sorted along the motions), so the numbers are
  comparable with published tables; ``query="motion"`` gives the paper's wording (each motion
  ranks its caption among 32). The two agree for a perfect embedding and differ slightly
  otherwise.
- FID uses the eigen-decomposition form ``tr sqrt(S1 S2) = tr sqrt(sqrt(S1) S2 sqrt(S1))``, which
  stays real and finite for singular or nearly singular covariances (the usual
  ``scipy.linalg.sqrtm`` route can return complex or NaN values there).
- Confidence intervals are ``1.96 * std / sqrt(n)`` with the population standard deviation
  (``ddof=0``), as in the original code.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

R_PRECISION_BATCH_SIZE = 32
DIVERSITY_PAIRS = 300
MULTIMODALITY_PAIRS = 10
CONFIDENCE_Z = 1.96


def as_float64(x: Any, name: str = "array") -> np.ndarray:
    """Return ``x`` (numpy array, torch tensor or nested sequence) as a float64 numpy array.

    Raises ValueError when it holds NaN or infinite values, so that a broken embedding shows up
    as an error instead of a NaN metric.
    """
    if hasattr(x, "detach"):  # a torch tensor; metrics never need gradients
        x = x.detach().cpu().numpy()
    array = np.asarray(x, dtype=np.float64)
    if not np.all(np.isfinite(array)):
        raise ValueError(f"{name} contains NaN or infinite values")
    return array


def _check_rows(x: Any, name: str) -> np.ndarray:
    array = as_float64(x, name)
    if array.ndim != 2:
        raise ValueError(f"{name} must have shape (N, D), got {array.shape}")
    return array


def euclidean_distance_matrix(a: Any, b: Any) -> np.ndarray:
    """Pairwise Euclidean distances between the rows of two sets.

    Args:
        a: (N, D) embeddings.
        b: (M, D) embeddings.

    Returns:
        (N, M) float64 distances, ``out[i, j] = ||a[i] - b[j]||``; never NaN.
    """
    a = _check_rows(a, "a")
    b = _check_rows(b, "b")
    if a.shape[1] != b.shape[1]:
        raise ValueError(f"embedding sizes differ: {a.shape[1]} vs {b.shape[1]}")
    # Distances are translation invariant; centring first keeps the norms small, so the
    # expansion below loses little to cancellation when the embeddings sit far from the origin.
    centre = 0.5 * (a.mean(axis=0) + b.mean(axis=0))
    a = a - centre
    b = b - centre
    squared = (
        np.sum(a * a, axis=1)[:, None] - 2.0 * (a @ b.T) + np.sum(b * b, axis=1)[None, :]
    )  # (N, M)
    # The expansion can dip slightly below zero from cancellation; clamp before the root.
    return np.sqrt(np.maximum(squared, 0.0))


def paired_distances(a: Any, b: Any) -> np.ndarray:
    """Distances between matching rows: (N, D), (N, D) -> (N,), ``||a[i] - b[i]||``."""
    a = _check_rows(a, "a")
    b = _check_rows(b, "b")
    if a.shape != b.shape:
        raise ValueError(f"paired sets must have the same shape, got {a.shape} and {b.shape}")
    return np.sqrt(np.maximum(np.sum((a - b) ** 2, axis=1), 0.0))


def _num_full_batches(num_rows: int, batch_size: int) -> int:
    if batch_size < 1:
        raise ValueError(f"batch_size must be >= 1, got {batch_size}")
    num_batches = num_rows // batch_size
    if num_batches == 0:
        raise ValueError(
            f"need at least one full batch of {batch_size} rows for R-precision, got {num_rows}"
        )
    return num_batches


def r_precision(
    text_embeddings: Any,
    motion_embeddings: Any,
    top_k: int = 3,
    batch_size: int = R_PRECISION_BATCH_SIZE,
    query: str = "text",
) -> np.ndarray:
    """R-precision at ranks 1..top_k over batches of matched (caption, motion) pairs.

    Row ``i`` of both sets belongs to the same clip. Within each batch of ``batch_size``
    consecutive rows, each query (a caption by default, or a motion with ``query="motion"``)
    ranks the batch's other-modality items by Euclidean distance; a hit at rank k means its own partner
    is among the k nearest. Ties keep the lower index first (stable sort).

    Args:
        text_embeddings: (N, D) caption embeddings.
        motion_embeddings: (N, D) motion embeddings.
        top_k: number of ranks to report.
        batch_size: size of each pool (32 in the protocol); an incomplete last batch is dropped.
        query: "text" (each caption ranks motions, the original code) or "motion" (each motion
            ranks captions).

    Returns:
        (top_k,) float64 fractions in [0, 1], non-decreasing: element k-1 is top-k accuracy.
    """
    text = _check_rows(text_embeddings, "text_embeddings")
    motion = _check_rows(motion_embeddings, "motion_embeddings")
    if text.shape != motion.shape:
        raise ValueError(
            f"text and motion embeddings must have the same shape, got {text.shape} and "
            f"{motion.shape}"
        )
    if query not in ("motion", "text"):
        raise ValueError(f"query must be 'motion' or 'text', got {query!r}")
    if not 1 <= top_k <= batch_size:
        raise ValueError(f"top_k must be in 1..{batch_size}, got {top_k}")
    num_batches = _num_full_batches(len(text), batch_size)
    hits = np.zeros(top_k, dtype=np.int64)
    for b in range(num_batches):
        rows = slice(b * batch_size, (b + 1) * batch_size)
        if query == "motion":
            dist = euclidean_distance_matrix(motion[rows], text[rows])  # (B, B) motion x caption
        else:
            dist = euclidean_distance_matrix(text[rows], motion[rows])  # (B, B) caption x motion
        order = np.argsort(dist, axis=1, kind="stable")[:, :top_k]  # (B, top_k)
        own = order == np.arange(batch_size)[:, None]  # (B, top_k), at most one True per row
        hits += np.cumsum(own, axis=1).sum(axis=0)
    return hits / float(num_batches * batch_size)


def multimodal_distance(
    text_embeddings: Any, motion_embeddings: Any, batch_size: int | None = None
) -> float:
    """MultiModal distance (MM-Dist): mean distance between each motion and its own caption.

    Args:
        text_embeddings: (N, D).
        motion_embeddings: (N, D).
        batch_size: when given, only rows that fill whole batches count (the original code
            averages over the same full batches it uses for R-precision).

    Returns:
        The mean paired distance (float, >= 0).
    """
    distances = paired_distances(text_embeddings, motion_embeddings)
    if batch_size is not None:
        distances = distances[: _num_full_batches(len(distances), batch_size) * batch_size]
    if len(distances) == 0:
        raise ValueError("multimodal_distance needs at least one pair")
    return float(distances.mean())


@dataclass(frozen=True)
class GaussianStats:
    """Mean (D,) and covariance (D, D) of a set of embeddings."""

    mean: np.ndarray
    covariance: np.ndarray


def gaussian_statistics(embeddings: Any) -> GaussianStats:
    """Fit a Gaussian to (N, D) embeddings: mean and unbiased covariance (needs N >= 2)."""
    x = _check_rows(embeddings, "embeddings")
    if len(x) < 2:
        raise ValueError(f"need at least 2 embeddings to estimate a covariance, got {len(x)}")
    return GaussianStats(mean=x.mean(axis=0), covariance=np.atleast_2d(np.cov(x, rowvar=False)))


def _psd_sqrt(matrix: np.ndarray) -> np.ndarray:
    """Square root of a symmetric positive semi-definite matrix; negative eigenvalues from
    rounding are clamped to zero so the result stays real."""
    symmetric = 0.5 * (matrix + matrix.T)
    eigenvalues, eigenvectors = np.linalg.eigh(symmetric)
    roots = np.sqrt(np.maximum(eigenvalues, 0.0))
    return (eigenvectors * roots) @ eigenvectors.T


def trace_sqrt_product(cov1: np.ndarray, cov2: np.ndarray) -> float:
    """``tr sqrt(cov1 @ cov2)`` for symmetric PSD matrices, computed stably.

    ``cov1 @ cov2`` is similar to the symmetric PSD matrix ``sqrt(cov1) cov2 sqrt(cov1)``, so both
    have the same (real, non-negative) eigenvalues; the trace of the root is the sum of their
    square roots.
    """
    root1 = _psd_sqrt(cov1)
    inner = root1 @ cov2 @ root1
    eigenvalues = np.linalg.eigvalsh(0.5 * (inner + inner.T))
    return float(np.sum(np.sqrt(np.maximum(eigenvalues, 0.0))))


def frechet_distance(mean1: Any, cov1: Any, mean2: Any, cov2: Any) -> float:
    """Fréchet distance between two Gaussians N(mean1, cov1) and N(mean2, cov2).

    ``||mean1 - mean2||^2 + tr(cov1) + tr(cov2) - 2 tr sqrt(cov1 cov2)``, in float64; rounding can
    leave a tiny negative value for identical inputs, so the result is clamped at zero.

    Args:
        mean1, mean2: (D,) means.
        cov1, cov2: (D, D) symmetric positive semi-definite covariances.

    Returns:
        The distance (float, >= 0, finite).
    """
    mean1 = as_float64(mean1, "mean1").reshape(-1)
    mean2 = as_float64(mean2, "mean2").reshape(-1)
    cov1 = np.atleast_2d(as_float64(cov1, "cov1"))
    cov2 = np.atleast_2d(as_float64(cov2, "cov2"))
    dim = mean1.shape[0]
    if mean2.shape != (dim,) or cov1.shape != (dim, dim) or cov2.shape != (dim, dim):
        raise ValueError(
            f"inconsistent Gaussian shapes: means {mean1.shape}, {mean2.shape}; "
            f"covariances {cov1.shape}, {cov2.shape}"
        )
    diff = mean1 - mean2
    value = (
        float(diff @ diff)
        + float(np.trace(cov1))
        + float(np.trace(cov2))
        - 2.0 * trace_sqrt_product(cov1, cov2)
    )
    return max(value, 0.0)


def fid(embeddings1: Any, embeddings2: Any) -> float:
    """Fréchet Inception-style distance between two sets of (N, D) embeddings."""
    stats1 = gaussian_statistics(embeddings1)
    stats2 = gaussian_statistics(embeddings2)
    if stats1.mean.shape != stats2.mean.shape:
        raise ValueError(
            f"embedding sizes differ: {stats1.mean.shape[0]} vs {stats2.mean.shape[0]}"
        )
    return frechet_distance(stats1.mean, stats1.covariance, stats2.mean, stats2.covariance)


def diversity(
    embeddings: Any, num_pairs: int = DIVERSITY_PAIRS, rng: np.random.Generator | None = None
) -> float:
    """Diversity: mean distance over ``num_pairs`` random pairs of motions.

    As in the original code, two index lists of length ``num_pairs`` are each drawn without
    replacement and paired element-wise (so a pair may repeat an index across the lists).

    Args:
        embeddings: (N, D) motion embeddings, N >= num_pairs.
        num_pairs: number of pairs (300 in the protocol).
        rng: random generator (a fresh ``default_rng(0)`` when omitted).

    Returns:
        The mean pair distance (float, >= 0).
    """
    x = _check_rows(embeddings, "embeddings")
    if num_pairs < 1:
        raise ValueError(f"num_pairs must be >= 1, got {num_pairs}")
    if len(x) < num_pairs:
        raise ValueError(
            f"diversity over {num_pairs} pairs needs >= {num_pairs} motions, got {len(x)}"
        )
    rng = np.random.default_rng(0) if rng is None else rng
    first = rng.choice(len(x), num_pairs, replace=False)
    second = rng.choice(len(x), num_pairs, replace=False)
    return float(paired_distances(x[first], x[second]).mean())


def multimodality(
    embeddings: Any, num_pairs: int = MULTIMODALITY_PAIRS, rng: np.random.Generator | None = None
) -> float:
    """MultiModality: mean distance between generations of the same caption.

    Args:
        embeddings: (C, S, D): S generated motions for each of C captions, S >= num_pairs.
        num_pairs: pairs drawn per caption (10 in the protocol); the same index pairs are used
            for every caption, as in the original code.
        rng: random generator (a fresh ``default_rng(0)`` when omitted).

    Returns:
        The mean distance over C * num_pairs pairs (float, >= 0).
    """
    x = as_float64(embeddings, "embeddings")
    if x.ndim != 3:
        raise ValueError(f"embeddings must have shape (C, S, D), got {x.shape}")
    if num_pairs < 1:
        raise ValueError(f"num_pairs must be >= 1, got {num_pairs}")
    num_samples = x.shape[1]
    if num_samples < num_pairs or num_samples < 2 or x.shape[0] == 0:
        raise ValueError(
            f"multimodality over {num_pairs} pairs needs >= {max(num_pairs, 2)} samples per "
            f"caption and >= 1 caption, got shape {x.shape}"
        )
    rng = np.random.default_rng(0) if rng is None else rng
    first = rng.choice(num_samples, num_pairs, replace=False)
    second = rng.choice(num_samples, num_pairs, replace=False)
    diff = x[:, first] - x[:, second]  # (C, P, D)
    return float(np.sqrt(np.maximum(np.sum(diff * diff, axis=-1), 0.0)).mean())


def confidence_interval(values: Sequence[float] | np.ndarray) -> tuple[float, float]:
    """Mean and 95% half-width ``1.96 * std / sqrt(n)`` (population std) of replications.

    A single replication gives a half-width of 0.
    """
    array = as_float64(values, "values").reshape(-1)
    if array.size == 0:
        raise ValueError("confidence_interval needs at least one value")
    return float(array.mean()), float(CONFIDENCE_Z * array.std() / math.sqrt(array.size))
