"""``python -m t2m.export IN.npy OUT.bvh|OUT.glb``: joints or features to a BVH file or an
animated glTF binary of the SMPL skeleton.

The writers are :mod:`dataset_tools.bvh` (IK with its twist choice, the file text) and
:mod:`dataset_tools.gltf` (the same skeleton motion as glTF nodes); this module is only their
command.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

from dataset_tools.bvh import write_bvh
from dataset_tools.command import (
    CommandParser,
    UsageError,
    command,
    option,
    parse_config,
)
from dataset_tools.gltf import write_glb
from dataset_tools.humanml3d import read_joints
from dataset_tools.io import check_output_file
from dataset_tools.skeleton import SMPL
from dataset_tools.spec import HUMANML3D


@dataclass
class ExportCommandConfig:
    """``python -m t2m.export``."""

    input: Path = field(metadata=option(positional=True))
    """.npy joints (T, 22, 3) (metres, y-up) or HumanML3D features (T, 263)"""
    output: Path = field(metadata=option(positional=True))
    """.bvh or .glb file to write"""
    fps: float | None = None
    """frames per second of the motion (the file's frame time is 1 / fps); default: HumanML3D's
    20"""
    units: Literal["cm", "m"] = "cm"
    """length unit of the BVH file's offsets and root positions (glTF is always in metres)"""
    template_rest_pose: bool = False
    """use the template hips / collars instead of fitting them to the motion"""

    def __post_init__(self) -> None:
        if self.output.suffix.lower() not in (".bvh", ".glb"):
            raise UsageError(f"output must end in .bvh or .glb, got {self.output.name!r}")
        if self.fps is not None and not 0 < self.fps < math.inf:
            raise UsageError(f"--fps must be positive and finite, got {self.fps}")
        check_output_file(self.output, "output")


@command
def main(argv: list[str] | None = None) -> int:
    """``python -m t2m.export IN.npy OUT.bvh|OUT.glb [--units cm|m]``; returns the exit code (2 on
    bad input)."""
    parser = CommandParser(
        prog="python -m t2m.export",
        description="Write joints (T, 22, 3) (metres, y-up) or HumanML3D features (T, 263) from "
        "a .npy file as a BVH file or an animated glTF binary (.glb) of the 22-joint SMPL "
        "skeleton.",
    )
    config = parse_config(parser, ExportCommandConfig, argv)
    joints = read_joints(config.input)
    if joints.shape[1] != SMPL.num_joints:
        raise UsageError(
            f"{config.input}: export needs the {SMPL.num_joints}-joint SMPL skeleton, "
            f"got {joints.shape[1]} joints"
        )
    if config.output.suffix.lower() == ".glb":
        write_glb(
            joints,
            config.output,
            fps=config.fps or HUMANML3D.fps,
            fit_rest_pose=not config.template_rest_pose,
        )
        return 0
    write_bvh(
        joints,
        config.output,
        fps=config.fps or HUMANML3D.fps,
        units=config.units,
        fit_rest_pose=not config.template_rest_pose,
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
