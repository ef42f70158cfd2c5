"""Dataset statistics: the per-feature Mean and the group-pooled Std that HumanML3D saves.

HumanML3D computes the mean and standard deviation of every feature over all frames of all clips
(mirrors included), then replaces each dimension's std by the mean std of its feature group
(root rotation velocity, root linear velocity, root height, ric, rot6d, local velocity, foot
contact), so that a group is normalised as a whole. We accumulate sums in float64 so the result
does not depend on how clips are batched.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np


class FeatureStats:
    """Streaming mean / std over frames of (T, D) feature arrays."""

    def __init__(self, dim: int):
        self.dim = dim
        self.count = 0
        self.total = np.zeros(dim, dtype=np.float64)
        self.total_sq = np.zeros(dim, dtype=np.float64)

    def add(self, features: np.ndarray) -> None:
        """Add (T, D) frames. Raises ValueError for a wrong width or non-finite values."""
        features = np.asarray(features, dtype=np.float64)
        if features.ndim != 2 or features.shape[1] != self.dim:
            raise ValueError(f"expected features (T, {self.dim}), got {features.shape}")
        if not np.isfinite(features).all():
            raise ValueError("features contain NaN or inf")
        self.count += features.shape[0]
        self.total += features.sum(axis=0)
        self.total_sq += np.square(features).sum(axis=0)

    def mean(self) -> np.ndarray:
        """(D,) per-feature mean."""
        if self.count == 0:
            raise ValueError("no frames were added")
        return self.total / self.count

    def std(self) -> np.ndarray:
        """(D,) per-feature population standard deviation (as numpy's default ddof=0)."""
        mean = self.mean()
        variance = np.maximum(self.total_sq / self.count - np.square(mean), 0.0)
        return np.sqrt(variance)


def pool_std(std: np.ndarray, groups: Sequence[tuple[str, slice]]) -> np.ndarray:
    """Replace each group's dims of (D,) ``std`` by the group's mean std (HumanML3D's Std.npy).

    ``groups`` is ``FeatureLayout.groups()``: (name, slice) covering all D dims.
    """
    pooled = np.asarray(std, dtype=np.float64).copy()
    covered = np.zeros(pooled.shape[0], dtype=bool)
    for _, group in groups:
        pooled[group] = pooled[group].mean()
        covered[group] = True
    if not covered.all():
        raise ValueError("feature groups do not cover every dimension")
    return pooled


def mean_and_pooled_std(
    stats: FeatureStats, groups: Sequence[tuple[str, slice]]
) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """(Mean (D,), pooled Std (D,), constant groups) as float32, ready for Mean.npy / Std.npy.

    A group that is constant over the dataset (std 0, e.g. no foot ever leaves the ground in a
    tiny corpus) would divide by zero at normalisation; its std is set to 1 and it is named in
    the returned list so that the caller can report it.
    """
    mean = stats.mean()
    std = pool_std(stats.std(), groups)
    constant = [name for name, group in groups if not (std[group] > 1e-12).all()]
    for name, group in groups:
        if name in constant:
            std[group] = 1.0
    return mean.astype(np.float32), std.astype(np.float32), constant
