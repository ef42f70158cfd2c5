"""Contact sheet: a grid of stick-figure key frames of clips with their captions, to PNG.

Each clip gets one row: key frames evenly spaced in time, seen from the front-left and slightly
above, after turning the clip so that its first frame faces +Z. Left limbs are blue, right limbs
red, the nose is a short line from the head along the facing; the grey line on the ground is the
root's path over the whole clip and the dot marks where the root is at that key frame.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from dataset_tools.skeleton import SMPL

_LEFT = {1, 4, 7, 10, 13, 16, 18, 20}
_RIGHT = {2, 5, 8, 11, 14, 17, 19, 21}


def _facing_yaw(frame: np.ndarray) -> float:
    across = (frame[2] - frame[1]) + (frame[17] - frame[16])
    forward = np.cross([0.0, 1.0, 0.0], across)
    return float(np.arctan2(forward[0], forward[2]))


def _project(points: np.ndarray, azimuth: float, elevation: float) -> np.ndarray:
    """Orthographic screen coordinates (..., 2) of y-up points (..., 3); camera on the +Z side
    turned by ``azimuth`` towards -X (the subject's right when it faces +Z), looking down by
    ``elevation`` (radians)."""
    ca, sa = np.cos(azimuth), np.sin(azimuth)
    x = ca * points[..., 0] - sa * points[..., 2]
    depth = sa * points[..., 0] + ca * points[..., 2]
    y = np.cos(elevation) * points[..., 1] - np.sin(elevation) * depth
    # Seen from +Z, +X (the left of a subject facing the camera) is on the screen's right.
    return np.stack([x, y], axis=-1)


def render_contact_sheet(
    clips: list[tuple[np.ndarray, str]],
    out_path: str | os.PathLike,
    frames_per_clip: int = 6,
    azimuth_deg: float = 35.0,
    elevation_deg: float = 12.0,
    fps: float = 60.0,
) -> Path:
    """Draw clips (joints (T, 22, 3) y-up metres, caption) as rows of key frames; write a PNG."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    if not clips:
        raise ValueError("no clips to draw")
    azimuth, elevation = np.radians(azimuth_deg), np.radians(elevation_deg)
    rows = len(clips)
    fig, axes = plt.subplots(
        rows, frames_per_clip, figsize=(1.9 * frames_per_clip, 2.5 * rows), squeeze=False
    )
    parents = SMPL.parents
    for row, (joints, caption) in enumerate(clips):
        joints = np.asarray(joints, dtype=np.float64)
        yaw = _facing_yaw(joints[0])
        c, s = np.cos(-yaw), np.sin(-yaw)
        turn = np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])
        joints = (joints - joints[0, 0] * np.array([1, 0, 1])) @ turn.T
        path = joints[:, 0] * np.array([1, 0, 1])
        picks = np.linspace(0, len(joints) - 1, frames_per_clip).round().astype(int)
        for col, t in enumerate(picks):
            ax = axes[row, col]
            centre = joints[t, 0] * np.array([1, 0, 1])
            frame = joints[t] - centre
            screen = _project(frame, azimuth, elevation)
            ground = _project(path - centre, azimuth, elevation)
            ax.plot(ground[:, 0], ground[:, 1], color="0.75", lw=1)
            ax.plot(*_project(np.zeros(3), azimuth, elevation), "o", color="0.5", ms=3)
            for j in range(1, SMPL.num_joints):
                p = parents[j]
                color = "tab:blue" if j in _LEFT else "tab:red" if j in _RIGHT else "k"
                ax.plot(screen[[p, j], 0], screen[[p, j], 1], color=color, lw=2)
            face = _facing_yaw(joints[t])
            nose = frame[15] + 0.15 * np.array([np.sin(face), 0.0, np.cos(face)])
            tip = _project(np.stack([frame[15], nose]), azimuth, elevation)
            ax.plot(tip[:, 0], tip[:, 1], color="green", lw=2)
            ax.set_xlim(-1.1, 1.1)
            ax.set_ylim(-0.5, 2.1)
            ax.set_aspect("equal")
            ax.set_xticks([])
            ax.set_yticks([])
            ax.set_title(f"t={t / fps:.1f}s", fontsize=7)
        axes[row, 0].set_ylabel(
            "\n".join(_wrap(caption, 28)), fontsize=7, rotation=0, ha="right", va="center"
        )
    fig.suptitle("blue = left, red = right, green = nose (facing)", fontsize=9)
    fig.tight_layout()
    out_path = Path(out_path)
    out_path.parent.mkdir(parents=True, exist_ok=True)
    temp = out_path.with_name(f".{out_path.name}.tmp.png")
    fig.savefig(temp, dpi=80)
    plt.close(fig)
    os.replace(temp, out_path)
    return out_path


def _wrap(text: str, width: int) -> list[str]:
    lines, line = [], ""
    for word in text.split():
        if line and len(line) + 1 + len(word) > width:
            lines.append(line)
            line = word
        else:
            line = f"{line} {word}".strip()
    return lines + ([line] if line else [])
