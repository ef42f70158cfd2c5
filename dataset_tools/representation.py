"""The HumanML3D motion representation: joints (T, J, 3) <-> features (T-1, D).

A feature vector holds, in this order (``FeatureLayout`` is the one definition):
root angular velocity about Y (1), root linear velocity on XZ in the facing frame (2), root height
(1), ric: joints 1..J-1 relative to the root's XZ in the facing frame (3(J-1)), local 6-D bone
rotations from inverse kinematics (6(J-1)), joint velocities in the facing frame (3J), foot
contacts left (2) and right (2). The root angular velocity is stored as the y component of the
per-frame yaw quaternion (the sine of half the yaw step), as HumanML3D does.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from dataset_tools.kinematics import (
    across_vector,
    forward_kinematics,
    inverse_kinematics,
    offsets_from_joints,
    retarget,
)
from dataset_tools.rotations import qbetween, qinv, qmul, qrot, quat_to_6d, sixd_to_quat
from dataset_tools.skeleton import SMPL, SkeletonSpec, skeleton_for

# HumanML3D smooths the facing used for velocities and rotations with this Gaussian (frames).
FACING_SMOOTH_SIGMA = 20.0


@dataclass(frozen=True)
class FeatureLayout:
    """Named slices of the feature vector for a body of ``num_joints`` joints."""

    num_joints: int
    root_rot_velocity: slice = field(init=False)
    root_linear_velocity: slice = field(init=False)
    root_height: slice = field(init=False)
    ric: slice = field(init=False)
    rot6d: slice = field(init=False)
    local_velocity: slice = field(init=False)
    foot_contact: slice = field(init=False)
    dim: int = field(init=False)

    def __post_init__(self) -> None:
        if self.num_joints < 2:
            raise ValueError(f"a feature layout needs at least 2 joints, got {self.num_joints}")
        sizes = [
            ("root_rot_velocity", 1),
            ("root_linear_velocity", 2),
            ("root_height", 1),
            ("ric", 3 * (self.num_joints - 1)),
            ("rot6d", 6 * (self.num_joints - 1)),
            ("local_velocity", 3 * self.num_joints),
            ("foot_contact", 4),
        ]
        start = 0
        for name, size in sizes:
            object.__setattr__(self, name, slice(start, start + size))
            start += size
        object.__setattr__(self, "dim", start)

    def groups(self) -> list[tuple[str, slice]]:
        """(name, slice) of every group, in vector order; they tile [0, dim)."""
        names = (
            "root_rot_velocity",
            "root_linear_velocity",
            "root_height",
            "ric",
            "rot6d",
            "local_velocity",
            "foot_contact",
        )
        return [(name, getattr(self, name)) for name in names]

    @property
    def root(self) -> slice:
        """The four root dimensions (angular velocity, linear velocity, height)."""
        return slice(0, self.root_height.stop)

    @classmethod
    def for_dim(cls, dim: int) -> FeatureLayout:
        """The layout whose vector has ``dim`` dimensions (263 -> 22 joints, 251 -> 21)."""
        num_joints, rest = divmod(dim + 1, 12)
        if rest or num_joints < 2:
            raise ValueError(
                f"no feature layout has {dim} dimensions (263 for 22 joints, 251 for 21)"
            )
        return cls(num_joints)


def _check_joints(joints: np.ndarray, skeleton: SkeletonSpec) -> np.ndarray:
    joints = np.asarray(joints, dtype=np.float64)
    if joints.ndim != 3 or joints.shape[1:] != (skeleton.num_joints, 3):
        raise ValueError(f"joints must be (T, {skeleton.num_joints}, 3), got {joints.shape}")
    if joints.shape[0] < 2:
        raise ValueError(f"a motion needs at least 2 frames, got {joints.shape[0]}")
    if not np.all(np.isfinite(joints)):
        raise ValueError("joints contain NaN or infinite values")
    return joints


def canonicalize(joints: np.ndarray, skeleton: SkeletonSpec = SMPL) -> np.ndarray:
    """Floor at y=0 (minimum over all frames and joints), frame-0 root at x=z=0, frame-0 facing
    turned to +Z (facing from the correct across vector of hips and shoulders)."""
    joints = _check_joints(joints, skeleton).copy()
    joints[..., 1] -= joints[..., 1].min()
    joints -= joints[0, 0] * np.array([1.0, 0.0, 1.0])
    forward = np.cross([0.0, 1.0, 0.0], across_vector(joints[0], skeleton, compat=False))
    if np.linalg.norm(forward) < 1e-9:
        raise ValueError("frame 0 has no horizontal across vector (hips and shoulders degenerate)")
    return qrot(qbetween(forward, np.array([0.0, 0.0, 1.0])), joints)


def foot_contacts(joints: np.ndarray, skeleton: SkeletonSpec = SMPL) -> np.ndarray:
    """Foot contacts (T-1, 4) (left pair, right pair): 1 where the squared per-frame displacement
    of the foot joint is under the skeleton's threshold."""
    feet = list(skeleton.feet_left) + list(skeleton.feet_right)
    displacement = np.sum((joints[1:, feet] - joints[:-1, feet]) ** 2, axis=-1)
    return (displacement < skeleton.contact_threshold).astype(np.float64)


def extract_features(
    joints: np.ndarray, skeleton: SkeletonSpec = SMPL, compat: bool = True
) -> np.ndarray:
    """Features (T-1, D) of a retargeted, canonicalised motion (T, J, 3) at the dataset's fps."""
    joints = _check_joints(joints, skeleton)
    num_frames, num_joints = joints.shape[:2]
    local = inverse_kinematics(joints, skeleton, smooth_sigma=FACING_SMOOTH_SIGMA, compat=compat)
    facing = local[:, 0]  # (T, 4) world -> facing frame
    facing_per_joint = np.broadcast_to(facing[:, None], (num_frames, num_joints, 4))

    root_velocity = qrot(facing[1:], joints[1:, 0] - joints[:-1, 0])  # (T-1, 3)
    yaw_step = qmul(facing[1:], qinv(facing[:-1]))  # (T-1, 4)
    ric = joints.copy()
    ric[..., [0, 2]] -= joints[:, :1, [0, 2]]
    ric = qrot(facing_per_joint, ric)  # (T, J, 3)
    local_velocity = qrot(facing_per_joint[:-1], joints[1:] - joints[:-1])  # (T-1, J, 3)
    rot6d = quat_to_6d(local[:, 1:])  # (T, J-1, 6)

    layout = FeatureLayout(num_joints)
    features = np.empty((num_frames - 1, layout.dim))
    features[:, layout.root_rot_velocity] = np.arcsin(np.clip(yaw_step[:, 2:3], -1.0, 1.0))
    features[:, layout.root_linear_velocity] = root_velocity[:, [0, 2]]
    features[:, layout.root_height] = joints[:-1, 0, 1:2]
    features[:, layout.ric] = ric[:-1, 1:].reshape(num_frames - 1, -1)
    features[:, layout.rot6d] = rot6d[:-1].reshape(num_frames - 1, -1)
    features[:, layout.local_velocity] = local_velocity.reshape(num_frames - 1, -1)
    features[:, layout.foot_contact] = foot_contacts(joints, skeleton)
    return features


def process_motion(
    joints: np.ndarray,
    skeleton: SkeletonSpec = SMPL,
    target_offsets: np.ndarray | None = None,
    compat: bool = True,
) -> tuple[np.ndarray, np.ndarray]:
    """The whole HumanML3D step for one motion (T, J, 3), y-up metres at the dataset's fps.

    Retargets to the target skeleton (``target_offsets`` (J, 3), default the skeleton's own),
    canonicalises, extracts features (T-1, D) and recovers joints (T-1, J, 3) from them, which is
    what HumanML3D stores in ``new_joints``.
    """
    joints = _check_joints(joints, skeleton)
    retargeted = retarget(joints, skeleton, target_offsets, compat=compat)
    features = extract_features(canonicalize(retargeted, skeleton), skeleton, compat=compat)
    return features, recover_from_ric(features, skeleton.num_joints)


def _check_features(features: np.ndarray, num_joints: int) -> tuple[np.ndarray, FeatureLayout]:
    features = np.asarray(features)
    layout = FeatureLayout(num_joints)
    if features.ndim < 2 or features.shape[-1] != layout.dim:
        raise ValueError(
            f"features must be (..., T, {layout.dim}) for {num_joints} joints, got {features.shape}"
        )
    return features, layout


def recover_root(features: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Root yaw quaternions (..., T, 4) (world -> facing) and root positions (..., T, 3),
    integrated from the root features (the first four dimensions)."""
    features = np.asarray(features, dtype=np.float64)
    half_yaw = np.zeros(features.shape[:-1])
    half_yaw[..., 1:] = np.cumsum(features[..., :-1, 0], axis=-1)
    facing = np.zeros(features.shape[:-1] + (4,))
    facing[..., 0] = np.cos(half_yaw)
    facing[..., 2] = np.sin(half_yaw)
    step = np.zeros(features.shape[:-1] + (3,))
    step[..., 1:, 0] = features[..., :-1, 1]
    step[..., 1:, 2] = features[..., :-1, 2]
    root = np.cumsum(qrot(qinv(facing), step), axis=-2)
    root[..., 1] = features[..., 3]
    return facing, root


def recover_from_ric(features: np.ndarray, num_joints: int | None = None) -> np.ndarray:
    """Joints (..., T, J, 3) from features (..., T, D): integrate the root, rotate ric back."""
    features = np.asarray(features)
    num_joints = (
        FeatureLayout.for_dim(features.shape[-1]).num_joints if num_joints is None else num_joints
    )
    features, layout = _check_features(features, num_joints)
    facing, root = recover_root(features)
    ric = (
        features[..., layout.ric]
        .astype(np.float64)
        .reshape(features.shape[:-1] + (num_joints - 1, 3))
    )
    positions = qrot(qinv(facing)[..., None, :], ric)
    positions[..., 0] += root[..., None, 0]
    positions[..., 2] += root[..., None, 2]
    return np.concatenate([root[..., None, :], positions], axis=-2).astype(
        features.dtype if features.dtype.kind == "f" else np.float64
    )


def recover_from_rot(
    features: np.ndarray, skeleton: SkeletonSpec = SMPL, offsets: np.ndarray | None = None
) -> np.ndarray:
    """Joints (..., T, J, 3) by forward kinematics of the 6-D rotations with the target offsets."""
    features, layout = _check_features(features, skeleton.num_joints)
    facing, root = recover_root(features)
    local = sixd_to_quat(
        features[..., layout.rot6d]
        .astype(np.float64)
        .reshape(features.shape[:-1] + (skeleton.num_joints - 1, 6))
    )
    local = np.concatenate([facing[..., None, :], local], axis=-2)
    return forward_kinematics(
        local, root, skeleton.offsets if offsets is None else offsets, skeleton
    )


def target_offsets_from_example(
    example_joints: np.ndarray, skeleton: SkeletonSpec | None = None
) -> np.ndarray:
    """Target offsets (J, 3) from one example frame (>= J, 3) of the target skeleton (HumanML3D
    uses frame 0 of clip 000021; extra joints, such as SMPL-H hands, are ignored)."""
    example_joints = np.asarray(example_joints, dtype=np.float64)
    skeleton = skeleton or SMPL
    return offsets_from_joints(example_joints[: skeleton.num_joints], skeleton)


__all__ = [
    "FACING_SMOOTH_SIGMA",
    "FeatureLayout",
    "canonicalize",
    "extract_features",
    "foot_contacts",
    "process_motion",
    "recover_from_ric",
    "recover_from_rot",
    "recover_root",
    "skeleton_for",
    "target_offsets_from_example",
]
