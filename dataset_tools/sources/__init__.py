"""Motion sources: each turns files into joints (T, 22 or 52, 3), y-up, metres, plus fps.

A source module exposes a loader returning a :class:`Motion`. ``build`` enumerates
:class:`ClipTask` items (one per output clip) so that the work can be split across processes; a
task names a file and, optionally, the slice of it that makes the clip.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass
class Motion:
    """Joint positions read from one source file.

    Attributes:
        joints: (T, J, 3) float array, J = 22 (SMPL body) or 52 (SMPL-H), y-up, metres.
        fps: frame rate of ``joints``.
        metadata: free-form facts about the file (gender, skeleton name, dropped frames, ...).
    """

    joints: np.ndarray
    fps: float
    metadata: dict = field(default_factory=dict)


@dataclass(frozen=True)
class ClipTask:
    """One output clip: which file, which part of it, and the per-clip rules.

    Attributes:
        name: output clip name (no extension); its mirror is ``"M" + name``.
        path: source file.
        segmented: the clip is cut by an index (``start_frame``/``end_frame`` at 20 fps after
            ``trim_seconds``, end exclusive, ``None`` = to the end); otherwise it is the whole
            motion, cropped when too long.
        trim_seconds: seconds dropped from the start before segmenting (reference-pipeline rule).
        negate_x: negate x before mirroring (reference-pipeline rule for its intermediate layout).
        caption_path: the clip's caption file, or ``None`` when it has none.
    """

    name: str
    path: str
    segmented: bool = False
    start_frame: int = 0
    end_frame: int | None = None
    trim_seconds: float = 0.0
    negate_x: bool = False
    caption_path: str | None = None


def z_up_to_y_up(joints: np.ndarray) -> np.ndarray:
    """Rotate (..., 3) points from a z-up to a y-up right-handed frame: (x, y, z) -> (x, z, -y).

    A proper rotation (-90 degrees about x), so left and right are kept.
    """
    joints = np.asarray(joints)
    return np.stack([joints[..., 0], joints[..., 2], -joints[..., 1]], axis=-1)


def to_y_up(joints: np.ndarray, up: str) -> np.ndarray:
    """Convert (..., 3) points whose up axis is ``up`` ("y" or "z") to y-up."""
    if up == "y":
        return np.asarray(joints)
    if up == "z":
        return z_up_to_y_up(joints)
    raise ValueError(f"up axis must be 'y' or 'z', got {up!r}")
