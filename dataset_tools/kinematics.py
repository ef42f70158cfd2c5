"""Forward and inverse kinematics on a ``SkeletonSpec``, and retargeting to a target skeleton.

Shapes: joints ``(T, J, 3)`` (any leading batch shape for FK), local rotations ``(..., J, 4)``
w-first quaternions. The local rotation of joint ``j`` rotates the rest direction of the bone that
ends at ``j``; the rotations compose down each kinematic chain starting from the root rotation
(HumanML3D convention: every chain, including the arms that start at the spine, starts from the
root rotation).
"""

from __future__ import annotations

import numpy as np
from scipy.ndimage import gaussian_filter1d

from dataset_tools.rotations import qbetween, qinv, qmul, qrot
from dataset_tools.skeleton import SMPL, SkeletonSpec

_UP = np.array([0.0, 1.0, 0.0])
_FORWARD = np.array([0.0, 0.0, 1.0])
_EPS = 1e-9


def across_vector(joints: np.ndarray, skeleton: SkeletonSpec, compat: bool = True) -> np.ndarray:
    """Left-to-right body axis (..., 3) from hips and shoulders of joints (..., J, 3).

    The correct axis is (right hip - left hip) + (right shoulder - left shoulder). With ``compat``
    the hip term has the opposite sign, as in HumanML3D's inverse kinematics; the published
    features (and every evaluator trained on them) depend on that quirk.
    """
    r_hip, l_hip, r_shoulder, l_shoulder = skeleton.face_joints
    hips = joints[..., r_hip, :] - joints[..., l_hip, :]
    shoulders = joints[..., r_shoulder, :] - joints[..., l_shoulder, :]
    return (-hips if compat else hips) + shoulders


def facing_direction(
    joints: np.ndarray,
    skeleton: SkeletonSpec,
    compat: bool = True,
    smooth_sigma: float | None = None,
) -> np.ndarray:
    """Unit horizontal facing directions (T, 3) = up x across, optionally Gaussian-smoothed in time.

    Raises ValueError where the across vector vanishes or is vertical (no facing is defined).
    """
    across = across_vector(joints, skeleton, compat)
    across_norm = np.linalg.norm(across, axis=-1, keepdims=True)
    if np.any(across_norm < _EPS):
        raise ValueError("the hips and shoulders give a zero across vector")
    # Smooth before normalising, weighting frames by the horizontal part of the unit across
    # vector, as HumanML3D does.
    forward = np.cross(_UP, across / across_norm)
    if smooth_sigma:
        forward = gaussian_filter1d(forward, smooth_sigma, axis=0, mode="nearest")
    norm = np.linalg.norm(forward, axis=-1, keepdims=True)
    if np.any(norm < _EPS):
        raise ValueError("the hips and shoulders give no horizontal facing direction")
    forward = forward / norm
    return forward


def _chain_order(skeleton: SkeletonSpec) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per non-root joint, in chain order: the joint, its parent, and the joint whose global
    rotation its local rotation is relative to (0, the root rotation, where a chain starts)."""
    children, parents, above = [], [], []
    for chain in skeleton.chains:
        for i, (parent, child) in enumerate(zip(chain[:-1], chain[1:])):
            children.append(child)
            parents.append(parent)
            above.append(0 if i == 0 else parent)
    return np.array(children), np.array(parents), np.array(above)


def _depth_levels(skeleton: SkeletonSpec) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Joints grouped by depth in the tree: (children, parents, rotation sources) per level, so
    forward kinematics loops over depth (7 levels for SMPL) rather than over bones."""
    depth = {0: 0}
    levels: dict[int, list[tuple[int, int, int]]] = {}
    for child, parent, above in zip(*_chain_order(skeleton)):
        depth[int(child)] = depth[int(parent)] + 1
        levels.setdefault(depth[int(child)], []).append((child, parent, above))
    return [tuple(np.array(column) for column in zip(*levels[d])) for d in sorted(levels)]


def inverse_kinematics(
    joints: np.ndarray,
    skeleton: SkeletonSpec = SMPL,
    smooth_sigma: float | None = None,
    compat: bool = True,
) -> np.ndarray:
    """Swing-only local rotations (T, J, 4) that carry the rest pose onto joints (T, J, 3).

    The root rotation turns the facing direction onto +Z (frame 0's is the identity, as in
    HumanML3D); each bone's rotation is the shortest arc from its rest direction to its observed
    direction, expressed relative to the rotation above it in its chain (the root's where a chain
    starts). All bones are solved at once: a swing-only chain needs no sequential pass.
    """
    joints = np.asarray(joints, dtype=np.float64)
    if joints.ndim != 3 or joints.shape[1:] != (skeleton.num_joints, 3):
        raise ValueError(f"joints must be (T, {skeleton.num_joints}, 3), got {joints.shape}")
    num_frames = joints.shape[0]
    forward = facing_direction(joints, skeleton, compat, smooth_sigma)
    root = qbetween(forward, np.broadcast_to(_FORWARD, forward.shape))
    root[0] = (1.0, 0.0, 0.0, 0.0)

    children, parents, above = _chain_order(skeleton)
    bones = joints[:, children] - joints[:, parents]  # (T, B, 3)
    lengths = np.linalg.norm(bones, axis=-1, keepdims=True)
    if np.any(lengths < _EPS):
        frame, bone = np.argwhere(lengths[..., 0] < _EPS)[0]
        raise ValueError(
            f"zero-length bone between joints {parents[bone]} and {children[bone]} (frame {frame})"
        )
    swing = qbetween(
        np.broadcast_to(skeleton.rest_directions[children], bones.shape), bones / lengths
    )
    global_rot = np.empty((num_frames, skeleton.num_joints, 4))
    global_rot[:, 0] = root
    global_rot[:, children] = swing
    local = np.zeros((num_frames, skeleton.num_joints, 4))
    local[:, 0] = root
    local[:, children] = qmul(qinv(global_rot[:, above]), swing)
    return local


def forward_kinematics(
    local_quats: np.ndarray,
    root_positions: np.ndarray,
    offsets: np.ndarray,
    skeleton: SkeletonSpec = SMPL,
) -> np.ndarray:
    """Joint positions (..., J, 3) from local rotations (..., J, 4), root positions (..., 3) and
    bone offsets (J, 3) or (..., J, 3)."""
    local_quats = np.asarray(local_quats, dtype=np.float64)
    root_positions = np.asarray(root_positions, dtype=np.float64)
    offsets = np.asarray(offsets, dtype=np.float64)
    if local_quats.shape[-2:] != (skeleton.num_joints, 4):
        raise ValueError(
            f"local rotations must be (..., {skeleton.num_joints}, 4), got {local_quats.shape}"
        )
    positions = np.zeros(local_quats.shape[:-1] + (3,))
    positions[..., 0, :] = root_positions
    global_rot = local_quats.copy()
    for children, parents, above in _depth_levels(skeleton):
        global_rot[..., children, :] = qmul(
            global_rot[..., above, :], local_quats[..., children, :]
        )
        positions[..., children, :] = (
            qrot(global_rot[..., children, :], offsets[..., children, :])
            + positions[..., parents, :]
        )
    return positions


def offsets_from_joints(joints: np.ndarray, skeleton: SkeletonSpec = SMPL) -> np.ndarray:
    """Target offsets (J, 3) of a skeleton measured on one frame of joints (J, 3)."""
    joints = np.asarray(joints, dtype=np.float64)
    if joints.shape != (skeleton.num_joints, 3):
        raise ValueError(
            f"one frame of joints must be ({skeleton.num_joints}, 3), got {joints.shape}"
        )
    return skeleton.rest_directions * skeleton.bone_lengths_of(joints)[:, None]


def retarget(
    joints: np.ndarray,
    skeleton: SkeletonSpec = SMPL,
    target_offsets: np.ndarray | None = None,
    compat: bool = True,
) -> np.ndarray:
    """Move a motion (T, J, 3) onto the target skeleton: IK on the source, FK with the target
    offsets, and the root trajectory scaled by the ratio of leg lengths (source frame 0).

    With swing-only IK each bone's global rotation carries its rest direction exactly onto the
    observed direction, so FK(IK) reduces to laying every observed bone direction out with the
    target length; that is what is computed (identical result, no rotations). The across
    convention (``compat``) changes only the root rotation, which cancels here.
    """
    del compat  # the result does not depend on it (see above)
    joints = np.asarray(joints, dtype=np.float64)
    if joints.ndim != 3 or joints.shape[1:] != (skeleton.num_joints, 3):
        raise ValueError(f"joints must be (T, {skeleton.num_joints}, 3), got {joints.shape}")
    target = skeleton.offsets if target_offsets is None else np.asarray(target_offsets, np.float64)
    source_lengths = skeleton.bone_lengths_of(joints[0])
    target_lengths = np.linalg.norm(target, axis=-1)
    knee, ankle = skeleton.leg_joints
    source_leg = source_lengths[knee] + source_lengths[ankle]
    if source_leg < _EPS:
        raise ValueError("the source skeleton has zero leg length")
    scale = (target_lengths[knee] + target_lengths[ankle]) / source_leg

    children, parents, _ = _chain_order(skeleton)
    bones = joints[:, children] - joints[:, parents]
    lengths = np.linalg.norm(bones, axis=-1, keepdims=True)
    if np.any(lengths < _EPS):
        frame, bone = np.argwhere(lengths[..., 0] < _EPS)[0]
        raise ValueError(
            f"zero-length bone between joints {parents[bone]} and {children[bone]} (frame {frame})"
        )
    # (T, J, 3) bone vectors of the target skeleton, indexed by child joint.
    target_bones = np.zeros_like(joints)
    target_bones[:, children] = bones / lengths * target_lengths[children, None]
    positions = np.empty_like(joints)
    positions[:, 0] = joints[:, 0] * scale
    for level_children, level_parents, _ in _depth_levels(skeleton):
        positions[:, level_children] = positions[:, level_parents] + target_bones[:, level_children]
    return positions
