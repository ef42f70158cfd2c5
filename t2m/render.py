"""``python -m t2m.render IN.npy OUT.mp4|gif|png``: render a motion file with the project's renderer.

The renderer itself is :mod:`dataset_tools.viz` (torch-free, shared with the dataset tools); this
module is only its command.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

from dataset_tools.command import (
    CommandParser,
    UsageError,
    command,
    option,
    parse_config,
)
from dataset_tools.humanml3d import read_joints
from dataset_tools.io import check_output_file
from dataset_tools.spec import spec_for_joints
from dataset_tools.viz import FORMATS, render_animation, render_keyframes

SUFFIXES = tuple(f".{name}" for name in FORMATS) + (".png",)


@dataclass
class RenderCommandConfig:
    """``python -m t2m.render``."""

    input: Path = field(metadata=option(positional=True))
    """.npy joints (T, J, 3) (metres, y-up; J = 22 SMPL or 21 KIT) or HumanML3D features
    (T, 263 or 251)"""
    output: Path = field(metadata=option(positional=True))
    """file to write: .mp4 or .gif (an animation) or .png (a strip of key frames)"""
    caption: str = ""
    """title shown above the figure"""
    fps: float | None = None
    """frames per second of the motion (and of the animation); default: the dataset's rate for
    the joint count (20 for HumanML3D's 22 joints, 12.5 for KIT-ML's 21)"""
    keyframes: int = 6
    """panels of a PNG strip"""

    def __post_init__(self) -> None:
        if self.output.suffix.lower() not in SUFFIXES:
            raise UsageError(f"output must end in {', '.join(SUFFIXES)}, got {self.output.name!r}")
        if self.fps is not None and not 0 < self.fps < math.inf:
            raise UsageError(f"--fps must be positive and finite, got {self.fps}")
        check_output_file(self.output, "output")
        if self.keyframes < 1:
            raise UsageError(f"--keyframes must be at least 1, got {self.keyframes}")


@command
def main(argv: list[str] | None = None) -> int:
    """``python -m t2m.render IN.npy OUT.mp4|gif|png [--caption TEXT]``; returns the exit code
    (2 on bad input)."""
    parser = CommandParser(
        prog="python -m t2m.render",
        description="Render joints (T, J, 3) or features (T, D) from a .npy file as an mp4 or "
        "gif stick-figure animation, or a PNG strip of key frames.",
    )
    config = parse_config(parser, RenderCommandConfig, argv)
    joints = read_joints(config.input)
    fps = config.fps or spec_for_joints(joints.shape[1]).fps
    if config.output.suffix.lower() == ".png":
        render_keyframes(joints, config.output, config.caption, config.keyframes, fps)
    else:
        render_animation(joints, config.output, config.caption, fps)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
