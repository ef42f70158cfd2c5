"""Physical plausibility of motions: foot skating, jerk, ground penetration and floating.

The figures animators look at first, computed the way the field computes them, from joint
positions (T, J, 3) in metres, y-up, the floor at y = 0 (where the HumanML3D representation puts
it), at the dataset's frame rate, and from the four foot-contact channels of the features (left
ankle, left toe, right ankle, right toe; a channel above 0.5 is a predicted contact). SMPL's joint
numbering is used through :mod:`dataset_tools.skeleton` (KIT-ML's 21 joints work the same way).

Definitions (per motion; a row of the evaluation averages them over its motions):

- **Foot skating ratio** (as in GMD, OmniControl and MotionLCM): the toe joints ("foot" joints 10
  and 11 of SMPL). Per frame step t (t = 0..T-2) and foot, the horizontal speed
  ``|p[t+1]_xz - p[t]_xz| * fps`` and its 5-step centred moving average (zero outside the motion,
  as ``scipy.ndimage.uniform_filter1d(mode="constant")``). A foot skates at step t when it is
  below 5 cm at frames t and t+1 and both its speed and its averaged speed exceed 0.5 m/s; the
  step skates when either foot does. Ratio = skating steps / (T - 1).
- **Jerk**: the third finite difference of every joint's position times fps^3 (m/s^3); per
  frame, the sum of its absolute x, y and z components, then the largest over joints: a curve of
  T - 3 values. A motion's mean and peak are the mean and the maximum of its curve. Between two
  rows, the *jerk area* is the integral over time (seconds) of the absolute difference of their
  mean curves (the mean over the row's motions at each frame index, over the frames at least half
  of the motions of both rows reach), in m/s^2: 0 when a row's motions jitter like the real ones.
- **Penetration**: per frame, how far the lowest foot joint (ankles and toes) is below the floor,
  in millimetres (0 when above); the motion's value is the mean over frames.
- **Floating**: the fraction of frames in which a contact is predicted (any of the four channels)
  while the lowest foot joint is more than 5 cm above the floor.
- **Bone stretch**: how far a bone's length strays from its own length within the motion. Per
  bone (every joint but the root, to its parent) and frame, ``|length - median length over the
  motion|``, in metres, and that divided by the median length (relative); the motion's figures
  are the maximum and the mean over bones and frames. A rigid body gives 0 (every real clip of a
  HumanML3D-processed dataset; every output of the finishing step, :mod:`dataset_tools.rigid`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.ndimage import uniform_filter1d

from dataset_tools.representation import FeatureLayout, recover_from_ric
from dataset_tools.skeleton import SkeletonSpec, skeleton_for

CONTACT_HEIGHT_M = 0.05
"""A foot joint below this height is near the floor (skating); above it, floating."""
SKATE_SPEED_MPS = 0.5
"""Horizontal foot speed above which a foot near the floor skates."""
SKATE_WINDOW = 5
"""Frames of the centred moving average of the foot speed."""
CONTACT_THRESHOLD = 0.5
"""A contact channel above this is a predicted contact."""

METRIC_NAMES = (
    "skating_ratio",
    "jerk_mean",
    "jerk_peak",
    "penetration_mm",
    "floating_ratio",
    "bone_stretch_max_m",
    "bone_stretch_mean_m",
    "bone_stretch_max_rel",
    "bone_stretch_mean_rel",
)
"""The per-motion figures; a row adds ``jerk_area`` (see :func:`rows_physics`)."""
ROW_METRIC_NAMES = (*METRIC_NAMES, "jerk_area")


def _check_joints(joints: np.ndarray, fps: float) -> np.ndarray:
    joints = np.asarray(joints, dtype=np.float64)
    if joints.ndim != 3 or joints.shape[-1] != 3:
        raise ValueError(f"joints must be (T, J, 3), got {joints.shape}")
    if len(joints) < 2:
        raise ValueError(f"a motion needs at least 2 frames, got {len(joints)}")
    if not fps > 0:
        raise ValueError(f"fps must be positive, got {fps}")
    return joints


def _toes(skeleton: SkeletonSpec) -> list[int]:
    """The skating joints: the second foot joint of each side (SMPL's 10 and 11)."""
    return [skeleton.feet_left[1], skeleton.feet_right[1]]


def _feet(skeleton: SkeletonSpec) -> list[int]:
    """Every foot joint (ankle and toe of each side)."""
    return [*skeleton.feet_left, *skeleton.feet_right]


def skating_steps(joints: np.ndarray, fps: float) -> np.ndarray:
    """(T-1,) bool: which frame steps skate (see the module docstring). ``joints`` (T, J, 3)."""
    joints = _check_joints(joints, fps)
    toes = joints[:, _toes(skeleton_for(joints.shape[1]))]  # (T, 2, 3)
    speed = np.linalg.norm(np.diff(toes[..., [0, 2]], axis=0), axis=-1) * fps  # (T-1, 2)
    windowed = uniform_filter1d(speed, SKATE_WINDOW, axis=0, mode="constant")
    low = toes[..., 1] < CONTACT_HEIGHT_M  # (T, 2)
    near_floor = low[1:] & low[:-1]
    skating = near_floor & (speed > SKATE_SPEED_MPS) & (windowed > SKATE_SPEED_MPS)
    return skating.any(axis=1)


def skating_ratio(joints: np.ndarray, fps: float) -> float:
    """Skating steps / (T - 1) of one motion (T, J, 3)."""
    return float(skating_steps(joints, fps).mean())


def jerk_curve(joints: np.ndarray, fps: float) -> np.ndarray:
    """(T-3,) per frame the largest over joints of the summed absolute xyz jerk, m/s^3
    (empty for fewer than 4 frames)."""
    joints = _check_joints(joints, fps)
    if len(joints) < 4:
        return np.zeros(0)
    jerk = np.abs(np.diff(joints, n=3, axis=0)) * fps**3  # (T-3, J, 3)
    return jerk.sum(axis=-1).max(axis=-1)


def penetration_mm(joints: np.ndarray) -> float:
    """Mean over frames of the depth of the lowest foot joint below the floor, mm."""
    joints = _check_joints(joints, 1.0)
    lowest = joints[:, _feet(skeleton_for(joints.shape[1])), 1].min(axis=1)
    return float(np.maximum(-lowest, 0.0).mean() * 1000.0)


def floating_ratio(joints: np.ndarray, contacts: np.ndarray) -> float:
    """Fraction of frames with a predicted contact while the lowest foot joint is above 5 cm.

    Args:
        joints: (T, J, 3).
        contacts: (T, 4) the features' foot-contact channels (> 0.5: contact).
    """
    joints = _check_joints(joints, 1.0)
    contacts = np.asarray(contacts)
    if contacts.shape != (len(joints), 4):
        raise ValueError(f"contacts must be ({len(joints)}, 4), got {contacts.shape}")
    lowest = joints[:, _feet(skeleton_for(joints.shape[1])), 1].min(axis=1)
    in_contact = (contacts > CONTACT_THRESHOLD).any(axis=1)
    return float(np.mean(in_contact & (lowest > CONTACT_HEIGHT_M)))


def bone_stretch(joints: np.ndarray) -> dict[str, float]:
    """Bone stretch of one motion (T, J, 3) (see the module docstring): ``max_m``, ``mean_m``
    (metres), ``max_rel``, ``mean_rel`` (shares of each bone's median length)."""
    joints = _check_joints(joints, 1.0)
    lengths = skeleton_for(joints.shape[1]).bone_lengths_of(joints)[:, 1:]  # (T, J - 1)
    median = np.median(lengths, axis=0)
    stretch = np.abs(lengths - median)
    relative = stretch / np.maximum(median, 1e-9)
    return {
        "max_m": float(stretch.max()),
        "mean_m": float(stretch.mean()),
        "max_rel": float(relative.max()),
        "mean_rel": float(relative.mean()),
    }


def motion_metrics(joints: np.ndarray, contacts: np.ndarray, fps: float) -> dict[str, float]:
    """Every figure of :data:`METRIC_NAMES` for one motion: joints (T, J, 3), contacts (T, 4)."""
    curve = jerk_curve(joints, fps)
    stretch = bone_stretch(joints)
    return {
        "skating_ratio": skating_ratio(joints, fps),
        "jerk_mean": float(curve.mean()) if curve.size else 0.0,
        "jerk_peak": float(curve.max()) if curve.size else 0.0,
        "penetration_mm": penetration_mm(joints),
        "floating_ratio": floating_ratio(joints, contacts),
        **{f"bone_stretch_{name}": value for name, value in stretch.items()},
    }


def mean_curve(curves: Sequence[np.ndarray]) -> np.ndarray:
    """(N,) mean of curves of different lengths at each index, over the indices that at least
    half of the curves reach."""
    if not curves:
        return np.zeros(0)
    lengths = np.sort([len(c) for c in curves])[::-1]
    reach = int(lengths[(len(curves) - 1) // 2])  # the median-ranked length, rounding down
    total = np.zeros(reach)
    count = np.zeros(reach)
    for curve in curves:
        n = min(len(curve), reach)
        total[:n] += curve[:n]
        count[:n] += 1
    return total / np.maximum(count, 1)


def curve_area(curve: np.ndarray, reference: np.ndarray, fps: float) -> float:
    """Integral over time of ``|curve - reference|`` over their common frames (rectangle rule,
    1 / fps seconds per frame)."""
    n = min(len(curve), len(reference))
    return float(np.abs(curve[:n] - reference[:n]).sum() / fps)


@dataclass
class RowPhysics:
    """The physical figures of a set of motions: per-metric means and the mean jerk curve."""

    metrics: dict[str, float]
    jerk_curve: np.ndarray


def joints_and_contacts(features: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Raw (de-normalised) features (T, D) -> joints (T, J, 3) and contact channels (T, 4)."""
    layout = FeatureLayout.for_dim(features.shape[-1])
    return recover_from_ric(features, layout.num_joints), np.asarray(
        features[:, layout.foot_contact]
    )


def row_physics(motions: Sequence[np.ndarray], fps: float) -> RowPhysics:
    """Figures of motions given as raw features (T_i, D), averaged over the motions."""
    if not motions:
        raise ValueError("no motions")
    per_motion, curves = [], []
    for features in motions:
        joints, contacts = joints_and_contacts(features)
        per_motion.append(motion_metrics(joints, contacts, fps))
        curves.append(jerk_curve(joints, fps))
    metrics = {name: float(np.mean([m[name] for m in per_motion])) for name in METRIC_NAMES}
    return RowPhysics(metrics, mean_curve(curves))


def rows_physics(
    rows: dict[str, RowPhysics], reference: RowPhysics, fps: float
) -> dict[str, dict[str, float]]:
    """Per row, its figures plus ``jerk_area``: the area between its mean jerk curve and the
    ``reference``'s (real motions drawn apart from every row, as FID's reference is)."""
    return {
        name: {**row.metrics, "jerk_area": curve_area(row.jerk_curve, reference.jerk_curve, fps)}
        for name, row in rows.items()
    }


__all__ = [
    "CONTACT_HEIGHT_M",
    "CONTACT_THRESHOLD",
    "METRIC_NAMES",
    "ROW_METRIC_NAMES",
    "SKATE_SPEED_MPS",
    "SKATE_WINDOW",
    "RowPhysics",
    "bone_stretch",
    "curve_area",
    "floating_ratio",
    "jerk_curve",
    "joints_and_contacts",
    "mean_curve",
    "motion_metrics",
    "penetration_mm",
    "row_physics",
    "rows_physics",
    "skating_ratio",
    "skating_steps",
]
