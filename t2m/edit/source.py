"""The motion an edit starts from: read a file, bring it into the model's frame.

A source is joints (T, 22, 3) in metres, y-up: a ``.npy`` array (our ``sampleNN_repRR.npy``
included) at the dataset's frame rate unless told otherwise, or a BVH file read through the
dataset builder's importer and its joint mappings (``dataset_tools.sources.bvh``), resampled to
the dataset's frame rate. :func:`prepare_source` runs it through the dataset's own representation
(:func:`dataset_tools.representation.process_motion`: retarget to the target skeleton, floor,
frame-0 root at the origin facing +Z, features): what the model sees, and the frame every edit's
result is in.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from dataset_tools.command import UsageError
from dataset_tools.representation import process_motion
from dataset_tools.spec import HUMANML3D, DatasetSpec

logger = logging.getLogger(__name__)

MAX_SOURCE_SECONDS = 3600.0
"""The longest source read (an hour; edits use its first seconds): longer ones, or a frame rate
that makes them so, are refused before resampling."""


@dataclass(frozen=True)
class PreparedSource:
    """A source in the model's frame.

    Attributes:
        features: (T, D) de-normalised features (the dataset's representation).
        joints: (T, J, 3) joints recovered from them (what a kept frame reproduces exactly).
        half_yaw: (T,) half-angle of the world -> facing yaw per frame (the root's heading).
    """

    features: np.ndarray
    joints: np.ndarray
    half_yaw: np.ndarray

    @property
    def num_frames(self) -> int:
        return int(self.features.shape[0])


def load_source(
    path: str | Path,
    spec: DatasetSpec = HUMANML3D,
    mapping: str | None = None,
    fps: float | None = None,
) -> np.ndarray:
    """Joints (T, J, 3) float32, y-up metres at ``spec.fps``, of a ``.npy`` or ``.bvh`` file.

    Args:
        path: a joints array (T, J, 3) (``sampleNN_repRR.npy`` of ``t2m.sample`` is one) or BVH.
        spec: the models' dataset (joint count, frame rate).
        mapping: BVH joint mapping (a built-in name or a JSON file; default: detected).
        fps: the ``.npy`` array's frame rate (default ``spec.fps``); BVH files carry theirs.

    Raises UsageError (one line) for a missing or unreadable file, another joint count (a BVH
    needs a mapping to become 22 joints), NaN or infinite values.
    """
    from dataset_tools.io import load_npy
    from dataset_tools.segment import resample

    path = Path(path)
    suffix = path.suffix.lower()
    if suffix == ".bvh":
        from dataset_tools.sources.bvh import BvhOptions, load_bvh_motion

        try:
            motion = load_bvh_motion(path, BvhOptions(mapping=mapping))
        except ValueError as error:  # ClipError and mapping errors: the importer's one line
            raise UsageError(f"--source {path}: {error}") from None
        joints, source_fps = motion.joints, motion.fps
    elif suffix == ".npy":
        joints = load_npy(path, finite=False)
        source_fps = spec.fps if fps is None else fps
        if not 0 < source_fps < math.inf:
            raise UsageError(f"--source-fps must be above 0, got {source_fps}")
    else:
        raise UsageError(f"--source {path}: give a joints .npy (T, {spec.num_joints}, 3) or a .bvh")
    joints = np.asarray(joints)
    if joints.ndim != 3 or joints.shape[1:] != (spec.num_joints, 3):
        raise UsageError(
            f"--source {path}: joints must be (T, {spec.num_joints}, 3), got {joints.shape} "
            "(other skeletons: export a BVH and read it with --mapping)"
        )
    seconds = len(joints) / source_fps
    if seconds > MAX_SOURCE_SECONDS:
        raise UsageError(
            f"--source {path} lasts {seconds:.0f} s ({len(joints)} frames at {source_fps:g} fps); "
            f"an edit reads at most {MAX_SOURCE_SECONDS:g} s: trim it or check --source-fps"
        )
    if not np.all(np.isfinite(joints)):
        raise UsageError(f"--source {path} contains NaN or infinite values")
    if source_fps != spec.fps:
        joints = resample(joints, source_fps, spec.fps)
    return joints.astype(np.float32)


def prepare_source(
    joints: np.ndarray, spec: DatasetSpec = HUMANML3D, name: str = "the source"
) -> PreparedSource:
    """Bring joints (T, J, 3) (y-up metres at ``spec.fps``) into the model's frame.

    Raises UsageError (naming the source as ``name``: ``--source FILE`` when read from one) for
    NaN, another joint count, or a motion shorter than one snippet plus the frame the features'
    velocities need.
    """
    joints = np.asarray(joints, dtype=np.float64)
    if joints.ndim != 3 or joints.shape[1:] != (spec.num_joints, 3):
        raise UsageError(f"{name}: joints must be (T, {spec.num_joints}, 3), got {joints.shape}")
    if not np.all(np.isfinite(joints)):
        raise UsageError(f"{name} contains NaN or infinite values")
    if len(joints) < spec.snippet_length + 1:
        raise UsageError(
            f"{name} has {len(joints)} frames at {spec.fps:g} fps; an edit needs at least "
            f"{spec.snippet_length + 1} ({(spec.snippet_length + 1) / spec.fps:.2f} s)"
        )
    try:
        features, recovered = process_motion(joints)
    except ValueError as error:  # degenerate poses (no facing direction)
        raise UsageError(f"cannot use {name}: {error}") from None
    return PreparedSource(
        features.astype(np.float32), recovered.astype(np.float32), half_yaw_of(features)
    )


def half_yaw_of(features: np.ndarray) -> np.ndarray:
    """(..., T) unwrapped half-angles of the world -> facing yaw integrated from features
    (..., T, D) (as :func:`dataset_tools.representation.recover_root` integrates them)."""
    steps = np.cumsum(np.asarray(features, dtype=np.float64)[..., :-1, 0], axis=-1)
    return np.concatenate([np.zeros(steps.shape[:-1] + (1,)), steps], axis=-1)
