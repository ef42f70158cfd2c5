"""Joints -> features throughput on one core (200-frame clips), against the issue's target."""

from __future__ import annotations

import time

import numpy as np

from dataset_tools.kinematics import forward_kinematics, retarget
from dataset_tools.representation import canonicalize, extract_features, process_motion
from dataset_tools.rotations import axis_angle_to_quat
from dataset_tools.skeleton import SMPL


def _random_motion(rng: np.random.Generator, frames: int = 200) -> np.ndarray:
    """A smooth random motion on a scaled SMPL skeleton (joint rotations as slow sinusoids)."""
    t = np.arange(frames)[:, None, None] / 20.0
    amplitude = rng.uniform(0.05, 0.5, size=(1, SMPL.num_joints, 3))
    frequency = rng.uniform(0.2, 1.5, size=(1, SMPL.num_joints, 3))
    local = axis_angle_to_quat(amplitude * np.sin(2 * np.pi * frequency * t))
    root = np.stack([0.5 * t[:, 0, 0], np.full(frames, 0.95), 0.2 * t[:, 0, 0]], axis=-1)
    return forward_kinematics(local, root, SMPL.offsets * rng.uniform(0.9, 1.1), SMPL)


def run(quick: bool = False) -> dict:
    rng = np.random.default_rng(0)
    clips = [_random_motion(rng) for _ in range(10 if quick else 50)]
    process_motion(clips[0])  # warm-up
    start = time.perf_counter()
    for clip in clips:
        process_motion(clip)
    full = (time.perf_counter() - start) / len(clips)
    prepared = [canonicalize(retarget(clip)) for clip in clips]
    start = time.perf_counter()
    for clip in prepared:
        extract_features(clip)
    extract = (time.perf_counter() - start) / len(prepared)
    return {
        "representation.process_motion_ms_per_clip": round(full * 1e3, 3),
        "representation.process_motion_clips_per_s": round(1.0 / full, 1),
        "representation.extract_features_ms_per_clip": round(extract * 1e3, 3),
        "representation.clip_frames": 200,
    }
