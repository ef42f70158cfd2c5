"""Skeleton definitions: the SMPL 22-joint body of HumanML3D, the KIT-ML 21-joint body.

The dataset specs built on them (frame rate, snippet length, frame limits) are
:mod:`dataset_tools.spec`.

Conventions: y-up, metres. ``rest_directions[j]`` is the unit direction of the bone that ends at
joint ``j`` in the rest (T-) pose, expressed in the parent's frame; the root's is zero. A bone's
offset is ``rest_directions[j] * bone_lengths[j]``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

SMPL_JOINT_NAMES: tuple[str, ...] = (
    "pelvis",
    "left_hip",
    "right_hip",
    "spine1",
    "left_knee",
    "right_knee",
    "spine2",
    "left_ankle",
    "right_ankle",
    "spine3",
    "left_foot",
    "right_foot",
    "neck",
    "left_collar",
    "right_collar",
    "head",
    "left_shoulder",
    "right_shoulder",
    "left_elbow",
    "right_elbow",
    "left_wrist",
    "right_wrist",
)

KIT_JOINT_NAMES: tuple[str, ...] = (
    "root",
    "BP",
    "BT",
    "BLN",
    "BUN",
    "LS",
    "LE",
    "LW",
    "RS",
    "RE",
    "RW",
    "LH",
    "LK",
    "LA",
    "LMrot",
    "LF",
    "RH",
    "RK",
    "RA",
    "RMrot",
    "RF",
)


@dataclass(frozen=True)
class SkeletonSpec:
    """Everything the representation needs to know about one body.

    Attributes:
        name: short identifier ("smpl", "kit").
        joint_names: one name per joint, index order.
        parents: parent index per joint, -1 for the root; parents precede children.
        chains: kinematic chains, each starting at a joint already placed (root or a chain joint).
        rest_directions: (J, 3) unit rest directions of the bones (zero for the root).
        bone_lengths: (J,) target bone lengths in metres (zero for the root).
        left_right: pairs (left, right) of joints swapped by mirroring.
        face_joints: (right hip, left hip, right shoulder, left shoulder).
        feet_left / feet_right: joints whose speed decides the foot contacts.
        leg_joints: the two joints whose bone lengths make the leg length (retargeting scale).
        contact_threshold: squared per-frame displacement under which a foot is in contact.
    """

    name: str
    joint_names: tuple[str, ...]
    parents: tuple[int, ...]
    chains: tuple[tuple[int, ...], ...]
    rest_directions: np.ndarray
    bone_lengths: np.ndarray
    left_right: tuple[tuple[int, int], ...]
    face_joints: tuple[int, int, int, int]
    feet_left: tuple[int, int]
    feet_right: tuple[int, int]
    leg_joints: tuple[int, int]
    contact_threshold: float

    @property
    def num_joints(self) -> int:
        return len(self.parents)

    @property
    def offsets(self) -> np.ndarray:
        """(J, 3) target bone offsets: rest direction times target length."""
        return self.rest_directions * self.bone_lengths[:, None]

    def joint(self, name: str) -> int:
        """Index of the joint called ``name`` (ValueError naming the skeleton if none is)."""
        if name not in self.joint_names:
            raise ValueError(f"skeleton {self.name!r} has no joint {name!r}")
        return self.joint_names.index(name)

    @property
    def mirror_permutation(self) -> np.ndarray:
        """(J,) index array that swaps every left joint with its right twin."""
        perm = np.arange(self.num_joints)
        for left, right in self.left_right:
            perm[left], perm[right] = right, left
        return perm

    def bone_lengths_of(self, joints: np.ndarray) -> np.ndarray:
        """Bone lengths (..., J) measured on joint positions (..., J, 3); zero at the root."""
        joints = np.asarray(joints, dtype=np.float64)
        parents = np.asarray(self.parents)
        lengths = np.linalg.norm(joints[..., 1:, :] - joints[..., parents[1:], :], axis=-1)
        return np.concatenate([np.zeros(lengths.shape[:-1] + (1,)), lengths], axis=-1)


def _parents_from_chains(num_joints: int, chains: tuple[tuple[int, ...], ...]) -> tuple[int, ...]:
    parents = [-1] * num_joints
    for chain in chains:
        for parent, child in zip(chain[:-1], chain[1:]):
            parents[child] = parent
    return tuple(parents)


_SMPL_CHAINS = (
    (0, 2, 5, 8, 11),
    (0, 1, 4, 7, 10),
    (0, 3, 6, 9, 12, 15),
    (9, 14, 17, 19, 21),
    (9, 13, 16, 18, 20),
)
_SMPL_REST = np.array([
    [0, 0, 0], [1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, -1, 0], [0, 1, 0], [0, -1, 0],
    [0, -1, 0], [0, 1, 0], [0, 0, 1], [0, 0, 1], [0, 1, 0], [1, 0, 0], [-1, 0, 0], [0, 0, 1],
    [0, -1, 0], [0, -1, 0], [0, -1, 0], [0, -1, 0], [0, -1, 0], [0, -1, 0],
], dtype=np.float64)  # fmt: skip
# Joints 1..21 to their parents, metres: the HumanML3D target skeleton (clip 000021, frame 0).
_SMPL_LENGTHS = np.array([
    0.0, 0.1031, 0.1099, 0.1316, 0.3936, 0.3902, 0.1432, 0.4324, 0.4256, 0.0574, 0.1434, 0.1494,
    0.2194, 0.1375, 0.1434, 0.1030, 0.1316, 0.1230, 0.2568, 0.2631, 0.2660, 0.2699,
])  # fmt: skip

SMPL = SkeletonSpec(
    name="smpl",
    joint_names=SMPL_JOINT_NAMES,
    parents=_parents_from_chains(22, _SMPL_CHAINS),
    chains=_SMPL_CHAINS,
    rest_directions=_SMPL_REST,
    bone_lengths=_SMPL_LENGTHS,
    left_right=((1, 2), (4, 5), (7, 8), (10, 11), (13, 14), (16, 17), (18, 19), (20, 21)),
    face_joints=(2, 1, 17, 16),
    feet_left=(7, 10),
    feet_right=(8, 11),
    leg_joints=(5, 8),
    contact_threshold=0.002,
)

_KIT_CHAINS = (
    (0, 11, 12, 13, 14, 15),
    (0, 16, 17, 18, 19, 20),
    (0, 1, 2, 3, 4),
    (3, 5, 6, 7),
    (3, 8, 9, 10),
)
_KIT_REST = np.array([
    [0, 0, 0], [0, 1, 0], [0, 1, 0], [0, 1, 0], [0, 1, 0], [1, 0, 0], [0, -1, 0], [0, -1, 0],
    [-1, 0, 0], [0, -1, 0], [0, -1, 0], [1, 0, 0], [0, -1, 0], [0, -1, 0], [0, 0, 1], [0, 0, 1],
    [-1, 0, 0], [0, -1, 0], [0, -1, 0], [0, 0, 1], [0, 0, 1],
], dtype=np.float64)  # fmt: skip
# KIT-ML is in millimetres in the original; these are typical adult lengths in metres, used only
# when no example skeleton is given.
_KIT_LENGTHS = np.array([
    0.0, 0.12, 0.12, 0.2, 0.12, 0.2, 0.3, 0.25, 0.2, 0.3, 0.25, 0.1, 0.42, 0.4, 0.06, 0.1, 0.1,
    0.42, 0.4, 0.06, 0.1,
])  # fmt: skip

KIT = SkeletonSpec(
    name="kit",
    joint_names=KIT_JOINT_NAMES,
    parents=_parents_from_chains(21, _KIT_CHAINS),
    chains=_KIT_CHAINS,
    rest_directions=_KIT_REST,
    bone_lengths=_KIT_LENGTHS,
    left_right=((5, 8), (6, 9), (7, 10), (11, 16), (12, 17), (13, 18), (14, 19), (15, 20)),
    face_joints=(11, 16, 5, 8),
    feet_left=(19, 20),
    feet_right=(14, 15),
    leg_joints=(17, 18),
    contact_threshold=0.05,
)

SKELETONS: dict[str, SkeletonSpec] = {"smpl": SMPL, "kit": KIT}


def skeleton_for(num_joints: int) -> SkeletonSpec:
    """The skeleton with ``num_joints`` joints (22: SMPL, 21: KIT)."""
    for spec in SKELETONS.values():
        if spec.num_joints == num_joints:
            return spec
    raise ValueError(f"no skeleton has {num_joints} joints (known: 22 for SMPL, 21 for KIT)")
