"""Joint-array source: ``.npy`` files (T, >=22, 3) at a known frame rate and up axis.

Three layouts are read:
- a plain folder of ``<clip>.npy`` (fps and up axis from the command line);
- the demo-corpus folder written by ``dataset_tools synth``: ``joints/<clip>.npy``,
  ``texts/<clip>.txt`` and a ``source.json`` giving ``{"fps": ..., "up": ...}``;
- the reference pipeline's intermediate ``pose_data`` layout cut by an ``index.csv``
  (20 fps, y-up after its axis swap; see :mod:`dataset_tools.segment` for its rules).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from dataset_tools.command import UsageError
from dataset_tools.io import load_npy, read_json
from dataset_tools.rotations import to_y_up
from dataset_tools.sources import ClipError, Motion, fps_problem

logger = logging.getLogger(__name__)

SOURCE_CONFIG = "source.json"


@dataclass(frozen=True)
class JointsOptions:
    """How to read joint arrays: their frame rate and up axis."""

    fps: float = 20.0
    up: str = "y"


def read_source_config(input_dir: str | Path) -> dict:
    """The folder's ``source.json`` as a dict ({} when absent), its ``fps`` (when given) a usable
    frame rate and its ``up`` (when given) "y" or "z".

    Raises UsageError (one line naming the file) when it is malformed.
    """
    path = Path(input_dir) / SOURCE_CONFIG
    if not path.is_file():
        return {}
    config = read_json(path)
    if not isinstance(config, dict):
        raise UsageError(f"{path}: expected a JSON object")
    if "fps" in config and (problem := fps_problem(config["fps"])) is not None:
        raise UsageError(f"{path}: {problem}")
    if config.get("up", "y") not in ("y", "z"):
        raise UsageError(f"{path}: up must be 'y' or 'z', got {config['up']!r}")
    return config


def joints_folder(input_dir: str | Path) -> Path:
    """Where the clip arrays are: ``input_dir/joints`` when it exists, else ``input_dir``."""
    input_dir = Path(input_dir)
    return input_dir / "joints" if (input_dir / "joints").is_dir() else input_dir


def load_joints(path: str | Path, options: JointsOptions) -> Motion:
    """Read one (T, J>=22, 3) array and return it y-up in metres.

    52 joints (SMPL-H) are kept so that mirroring can swap the hands; other widths are cut to
    the 22 body joints. Raises ClipError for unreadable files or wrong shapes.
    """
    path = Path(path)
    try:
        joints = load_npy(path, finite=False)  # NaN frames are counted by the build
    except UsageError as error:
        raise ClipError(str(error)) from None
    if joints.ndim != 3 or joints.shape[1] < 22 or joints.shape[2] != 3:
        raise ClipError(f"joint array must be (T, >=22, 3), got {joints.shape}")
    joints_in_file = joints.shape[1]
    if joints_in_file != 52:
        joints = joints[:, :22]
    joints = to_y_up(joints.astype(np.float64), options.up)
    return Motion(
        joints=joints, fps=float(options.fps), metadata={"joints_in_file": joints_in_file}
    )
