"""Contact sheet of demo-corpus clips: each clip turned to face +Z, drawn by the renderer.

One row per clip (:func:`dataset_tools.viz.render_contact_sheet`): key frames evenly spaced in
time, left limbs blue, right limbs red, the root's path on the ground grid. Every clip is first
turned about the vertical so that its first frame faces +Z and moved so that its root starts
above the origin, so rows are comparable at a glance.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from dataset_tools import viz
from dataset_tools.kinematics import across_vector
from dataset_tools.skeleton import SMPL


def face_forward(joints: np.ndarray) -> np.ndarray:
    """Joints (T, 22, 3) y-up turned about y so that frame 0 faces +Z, root starting over the
    origin (its height kept). A clip whose first frame has no facing is only moved."""
    joints = np.asarray(joints, dtype=np.float64)
    forward = np.cross([0.0, 1.0, 0.0], across_vector(joints[0], SMPL, compat=False))
    yaw = float(np.arctan2(forward[0], forward[2]))
    cos, sin = np.cos(-yaw), np.sin(-yaw)
    turn = np.array([[cos, 0.0, sin], [0.0, 1.0, 0.0], [-sin, 0.0, cos]])
    return (joints - joints[0, 0] * np.array([1.0, 0.0, 1.0])) @ turn.T


def render_contact_sheet(
    clips: Sequence[tuple[np.ndarray, str]],
    out_path: str | os.PathLike,
    frames_per_clip: int = 6,
    azimuth_deg: float = 35.0,
    elevation_deg: float = 12.0,
    fps: float = 60.0,
) -> Path:
    """Draw clips (joints (T, 22, 3) y-up metres, caption) as rows of key frames; write a PNG.

    The camera looks at the (turned) clips from the front, ``azimuth_deg`` to the subject's
    left, ``elevation_deg`` above the ground.
    """
    config = viz.RenderConfig(azimuth=-90.0 + azimuth_deg, elevation=elevation_deg)
    turned = [(face_forward(joints), caption) for joints, caption in clips]
    return viz.render_contact_sheet(turned, out_path, frames_per_clip, fps, SMPL, config)
