"""Feature normalisation with the original's up-weighting of the root and foot-contact parts.

The dataset's ``Mean.npy`` / ``Std.npy`` are read; the std of the root (angular velocity, linear
velocity, height) and foot-contact dimensions is divided by ``feature_bias`` (5 in the original),
so that those dimensions weigh five times more in every L1 loss on normalised features.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TypeVar

import numpy as np
import torch

from dataset_tools.humanml3d import read_mean_std
from dataset_tools.representation import FeatureLayout

ArrayT = TypeVar("ArrayT", np.ndarray, torch.Tensor)


@dataclass
class Normalizer:
    """Per-dimension mean and (weighted) std, shape (D,) each, float32 (given as arrays or
    tensors)."""

    mean: np.ndarray
    std: np.ndarray

    def __post_init__(self) -> None:
        self.mean = np.asarray(self.mean, dtype=np.float32)
        self.std = np.asarray(self.std, dtype=np.float32)
        if self.mean.shape != self.std.shape or self.mean.ndim != 1:
            raise ValueError(f"mean {self.mean.shape} and std {self.std.shape} must be equal (D,)")
        if not (np.isfinite(self.mean).all() and np.isfinite(self.std).all()):
            raise ValueError("normalisation statistics contain NaN or inf")
        if (self.std <= 1e-8).any():
            bad = np.flatnonzero(self.std <= 1e-8)[:5].tolist()
            raise ValueError(f"normalisation std is zero at dimensions {bad} (rebuild Std.npy)")

    @property
    def dim(self) -> int:
        return int(self.mean.shape[0])

    @classmethod
    def from_dataset(cls, dataset_dir: str | Path, feature_bias: float = 5.0) -> Normalizer:
        """Read the feature statistics of a HumanML3D-layout folder
        (:func:`dataset_tools.humanml3d.read_mean_std`: a missing or malformed file is a
        one-line UsageError naming it) and up-weight them."""
        mean, std = read_mean_std(dataset_dir)
        return cls.weighted(mean, std, feature_bias)

    @classmethod
    def weighted(cls, mean: np.ndarray, std: np.ndarray, feature_bias: float) -> Normalizer:
        """Mean/std with the root and foot-contact std divided by ``feature_bias``."""
        std = np.array(std, dtype=np.float32)
        layout = FeatureLayout.for_dim(std.shape[-1])
        std[layout.root] /= feature_bias
        std[layout.foot_contact] /= feature_bias
        return cls(mean, std)

    def normalize(self, features: ArrayT) -> ArrayT:
        """(..., D) raw features -> normalised."""
        return (features - self._like(self.mean, features)) / self._like(self.std, features)

    def denormalize(self, features: ArrayT) -> ArrayT:
        """(..., D) normalised features -> raw."""
        return features * self._like(self.std, features) + self._like(self.mean, features)

    @staticmethod
    def _like(array: np.ndarray, reference: ArrayT) -> ArrayT:
        if isinstance(reference, torch.Tensor):
            return torch.as_tensor(array, dtype=reference.dtype, device=reference.device)
        return array.astype(reference.dtype, copy=False)

    def state(self) -> dict[str, torch.Tensor]:
        """What a checkpoint stores: ``mean`` and ``std`` as (D,) float32 tensors (so that it
        loads with ``torch.load(..., weights_only=True)``); ``Normalizer(**state)`` rebuilds it."""
        return {
            "mean": torch.from_numpy(self.mean.copy()),
            "std": torch.from_numpy(self.std.copy()),
        }
