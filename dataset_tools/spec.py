"""Dataset specs: what a motion dataset fixes for every model trained on it.

A :class:`DatasetSpec` is everything about a dataset that models, sampling, rendering and
evaluation must agree on: the body (:mod:`dataset_tools.skeleton`), the frame rate, the snippet
length and the frame limits. The dataset's feature dimension identifies it (263: HumanML3D, 251:
KIT-ML; :class:`~dataset_tools.representation.FeatureLayout`); every checkpoint stores its spec,
so whatever reads a checkpoint knows, for example, to write a KIT-ML motion at 12.5 fps.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from dataset_tools.humanml3d import MEAN_FILE
from dataset_tools.representation import FeatureLayout
from dataset_tools.skeleton import KIT, SKELETONS, SMPL, SkeletonSpec


@dataclass(frozen=True)
class DatasetSpec:
    """What a motion dataset fixes for every model trained on it (frozen; stored in checkpoints).

    Attributes:
        name: "HumanML3D", "KIT-ML".
        skeleton: the body of its joints and features.
        fps: frames per second of its motions (and of everything generated from them).
        snippet_length: frames per snippet code (the movement autoencoder downsamples by this).
        min_frames: clips (or captioned sub-clips) shorter than this are skipped; generated
            motions are at least this long.
        max_frames: longest motion used (a multiple of ``snippet_length``); clips of
            ``max_frames`` .. ``length_limit - 1`` frames are cropped to it.
        length_limit: clips of this many frames or more are skipped.
    """

    name: str
    skeleton: SkeletonSpec
    fps: float
    snippet_length: int
    min_frames: int
    max_frames: int
    length_limit: int

    def __post_init__(self) -> None:
        if not self.fps > 0:
            raise ValueError(f"dataset spec {self.name!r}: fps must be positive, got {self.fps}")
        if self.snippet_length < 1 or self.max_frames % self.snippet_length:
            raise ValueError(
                f"dataset spec {self.name!r}: max_frames ({self.max_frames}) must be a multiple "
                f"of snippet_length ({self.snippet_length})"
            )
        if not 0 < self.min_frames <= self.max_frames < self.length_limit:
            raise ValueError(
                f"dataset spec {self.name!r}: need 0 < min_frames <= max_frames < length_limit, "
                f"got {self.min_frames}, {self.max_frames}, {self.length_limit}"
            )

    @property
    def num_joints(self) -> int:
        return self.skeleton.num_joints

    @property
    def layout(self) -> FeatureLayout:
        """The named slices of this dataset's feature vector."""
        return FeatureLayout(self.num_joints)

    @property
    def feature_dim(self) -> int:
        """D, features per frame (263 for HumanML3D, 251 for KIT-ML)."""
        return self.layout.dim

    @property
    def max_snippets(self) -> int:
        """Snippets of the longest motion (``max_frames // snippet_length``)."""
        return self.max_frames // self.snippet_length

    def to_dict(self) -> dict[str, Any]:
        """Plain values (the skeleton by name), as stored in checkpoints."""
        return {
            "name": self.name,
            "skeleton": self.skeleton.name,
            "fps": self.fps,
            "snippet_length": self.snippet_length,
            "min_frames": self.min_frames,
            "max_frames": self.max_frames,
            "length_limit": self.length_limit,
        }

    @classmethod
    def from_dict(cls, values: dict[str, Any]) -> DatasetSpec:
        """Inverse of :meth:`to_dict`; ValueError (one line) on missing, unknown or bad values."""
        if not isinstance(values, dict):
            raise ValueError(f"a dataset spec must be a dict, got {type(values).__name__}")
        expected = set(cls.__dataclass_fields__)
        if set(values) != expected:
            missing, unknown = expected - set(values), set(values) - expected
            raise ValueError(
                f"dataset spec: missing {sorted(missing)}, unknown {sorted(unknown)} keys"
            )
        skeleton = SKELETONS.get(values["skeleton"])
        if skeleton is None:
            raise ValueError(
                f"dataset spec: unknown skeleton {values['skeleton']!r} "
                f"(known: {', '.join(SKELETONS)})"
            )
        try:
            return cls(
                name=str(values["name"]),
                skeleton=skeleton,
                fps=float(values["fps"]),
                snippet_length=_whole(values["snippet_length"], "snippet_length"),
                min_frames=_whole(values["min_frames"], "min_frames"),
                max_frames=_whole(values["max_frames"], "max_frames"),
                length_limit=_whole(values["length_limit"], "length_limit"),
            )
        except (TypeError, ValueError) as error:
            raise ValueError(f"dataset spec: {error}") from None


def _whole(value: Any, name: str) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise ValueError(f"{name} must be a whole number, got {value!r}")
    return int(value)


HUMANML3D = DatasetSpec(
    name="HumanML3D",
    skeleton=SMPL,
    fps=20.0,
    snippet_length=4,
    min_frames=40,
    max_frames=196,
    length_limit=200,
)
# KIT-ML as the original T2M code reads it: 12.5 fps, clips from 24 frames (about 2 s) on.
KIT_ML = DatasetSpec(
    name="KIT-ML",
    skeleton=KIT,
    fps=12.5,
    snippet_length=4,
    min_frames=24,
    max_frames=196,
    length_limit=200,
)
DATASET_SPECS: dict[str, DatasetSpec] = {spec.name: spec for spec in (HUMANML3D, KIT_ML)}


def spec_for_dim(feature_dim: int) -> DatasetSpec:
    """The dataset spec whose features have ``feature_dim`` dimensions (263, 251)."""
    for spec in DATASET_SPECS.values():
        if spec.feature_dim == feature_dim:
            return spec
    raise ValueError(f"no known dataset has {feature_dim}-d features (263: HumanML3D, 251: KIT-ML)")


def spec_for_joints(num_joints: int) -> DatasetSpec:
    """The known dataset whose skeleton has ``num_joints`` joints (22: HumanML3D, 21: KIT-ML)."""
    for spec in DATASET_SPECS.values():
        if spec.num_joints == num_joints:
            return spec
    raise ValueError(f"no known dataset has {num_joints} joints (22: HumanML3D, 21: KIT-ML)")


def spec_for_folder(folder: str | Path) -> DatasetSpec:
    """The spec of a HumanML3D-layout dataset folder, identified by its ``Mean.npy``'s size."""
    path = Path(folder) / MEAN_FILE
    if not path.is_file():
        raise ValueError(f"{folder}: no {MEAN_FILE} (not a HumanML3D-layout dataset folder)")
    try:
        mean = np.load(path, mmap_mode="r", allow_pickle=False)
    except (OSError, ValueError) as error:
        raise ValueError(f"{path}: unreadable ({error})") from None
    if mean.ndim != 1:
        raise ValueError(f"{path}: expected a (D,) array, got shape {mean.shape}")
    try:
        return spec_for_dim(mean.shape[0])
    except ValueError as error:
        raise ValueError(f"{path}: {error}") from None
