"""Joints from features in torch, differentiable: the twin of
:func:`dataset_tools.representation.recover_from_ric` (same formulas, tested equal to it).

The root's yaw is integrated from the per-frame half-angle steps (feature 0), its horizontal
position from the facing-frame velocities (features 1..2) rotated back to the world, its height is
feature 3; the other joints are the ``ric`` slice (positions relative to the root's floor point in
the facing frame) rotated back by the yaw and moved onto the root.
"""

from __future__ import annotations

import torch

from dataset_tools.representation import FeatureLayout


def yaw_rotate(vectors: torch.Tensor, angle: torch.Tensor) -> torch.Tensor:
    """Rotate vectors (..., 3) about +Y by ``angle`` (...,) radians (right-handed: +Z -> +X)."""
    cos, sin = torch.cos(angle), torch.sin(angle)
    x, y, z = vectors.unbind(-1)
    return torch.stack([cos * x + sin * z, y, cos * z - sin * x], dim=-1)


def recover_root_torch(features: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Half-angles of the world -> facing yaw (..., T) and root positions (..., T, 3) from
    features (..., T, D), as :func:`dataset_tools.representation.recover_root`."""
    steps = features[..., :-1, 0]
    half_yaw = torch.cat([torch.zeros_like(features[..., :1, 0]), torch.cumsum(steps, -1)], -1)
    velocity = torch.zeros(features.shape[:-1] + (3,), dtype=features.dtype, device=features.device)
    velocity[..., 1:, 0] = features[..., :-1, 1]
    velocity[..., 1:, 2] = features[..., :-1, 2]
    # facing -> world is the inverse yaw: a rotation by -2 * half_yaw
    root = torch.cumsum(yaw_rotate(velocity, -2.0 * half_yaw), dim=-2)
    root = torch.cat([root[..., :1], features[..., 3:4], root[..., 2:]], dim=-1)
    return half_yaw, root


def recover_from_ric_torch(features: torch.Tensor, num_joints: int = 22) -> torch.Tensor:
    """Joints (..., T, J, 3) from features (..., T, D) (de-normalised), differentiably."""
    layout = FeatureLayout(num_joints)
    if features.shape[-1] != layout.dim:
        raise ValueError(f"features must be (..., T, {layout.dim}), got {tuple(features.shape)}")
    half_yaw, root = recover_root_torch(features)
    ric = features[..., layout.ric].reshape(features.shape[:-1] + (num_joints - 1, 3))
    positions = yaw_rotate(ric, -2.0 * half_yaw[..., None])
    offset = torch.stack(
        [root[..., 0], torch.zeros_like(root[..., 1]), root[..., 2]], dim=-1
    )  # (..., T, 3)
    return torch.cat([root[..., None, :], positions + offset[..., None, :]], dim=-2)
