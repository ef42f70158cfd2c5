"""``python -m t2m.export IN.npy OUT.bvh|OUT.glb|OUT.npz|OUT.fbx``: joints or features to a BVH
file, an animated glTF binary, SMPL-H body parameters or an FBX file of the SMPL skeleton.

The writers are :mod:`dataset_tools.bvh` (IK with its twist choice, the file text),
:mod:`dataset_tools.gltf` (the same skeleton motion as glTF nodes), :mod:`dataset_tools.smplh`
(the same rotations as AMASS-style SMPL-H parameters) and :mod:`dataset_tools.fbx` (the same
skeleton built in Blender and written by Blender's FBX exporter; needs ``bpy``); this module is
only their command. It refuses, before writing, what no body does: joints beyond
:data:`dataset_tools.bvh.MAX_COORDINATE` metres, a bone shorter than :data:`MIN_BONE_LENGTH`
(all-zero joints would export a rest pose), a frame rate outside
[:data:`dataset_tools.bvh.MIN_FPS`, :data:`dataset_tools.bvh.MAX_FPS`]; and an existing output
file unless ``--overwrite``.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np

from dataset_tools.bvh import MAX_COORDINATE, MAX_FPS, MIN_FPS, write_bvh
from dataset_tools.command import (
    CommandParser,
    UsageError,
    command,
    option,
    parse_config,
)
from dataset_tools.fbx import require_bpy, write_fbx
from dataset_tools.gltf import write_glb
from dataset_tools.humanml3d import read_joints
from dataset_tools.io import check_output_file
from dataset_tools.skeleton import SMPL
from dataset_tools.smplh import fit_smplh, write_smplh
from dataset_tools.spec import HUMANML3D

SUFFIXES = (".bvh", ".glb", ".npz", ".fbx")


@dataclass
class ExportCommandConfig:
    """``python -m t2m.export``."""

    input: Path = field(metadata=option(positional=True))
    """.npy joints (T, 22, 3) (metres, y-up) or HumanML3D features (T, 263)"""
    output: Path = field(metadata=option(positional=True))
    """file to write: .bvh, .glb, .npz (SMPL-H parameters, AMASS's layout) or .fbx (needs bpy:
    pip install -e .[blender])"""
    fps: float | None = None
    """frames per second of the motion (the file's frame time is 1 / fps), from 1 to 1000;
    default: HumanML3D's 20"""
    units: Literal["cm", "m"] = "cm"
    """length unit of the BVH file's offsets and root positions (glTF is always in metres)"""
    template_rest_pose: bool = False
    """use the template hips / collars instead of fitting them to the motion"""
    overwrite: bool = False
    """replace an existing output file (otherwise it is refused)"""

    def __post_init__(self) -> None:
        if self.output.is_dir():
            raise UsageError(
                f"output {self.output} is a folder; give a file path ending in "
                f"{', '.join(SUFFIXES[:-1])} or {SUFFIXES[-1]}"
            )
        if self.output.suffix.lower() not in SUFFIXES:
            raise UsageError(
                f"output must end in {', '.join(SUFFIXES[:-1])} or {SUFFIXES[-1]}, "
                f"got {self.output.name!r}"
            )
        if self.fps is not None and not MIN_FPS <= self.fps <= MAX_FPS:
            raise UsageError(
                f"--fps must be positive, from {MIN_FPS:g} to {MAX_FPS:g} frames per second, "
                f"got {self.fps:g}"
            )
        check_output_file(self.output, "output")
        if os.path.lexists(self.output) and not self.overwrite:
            raise UsageError(
                f"output {self.output} exists (choose another name or add --overwrite)"
            )
        if self.output.suffix.lower() == ".fbx":
            try:
                require_bpy()
            except ValueError as error:
                raise UsageError(str(error)) from None


MIN_BONE_LENGTH = 1e-3
"""The shortest bone (metres) a motion may have in any frame: a bone of no length has no
direction, so its rotation is made up (all-zero joints would export a rest pose)."""


def check_motion(joints: np.ndarray, path: Path) -> None:
    """Raise UsageError (one line naming ``path``) unless joints (T, 22, 3) are finite, within
    :data:`MAX_COORDINATE` metres of the origin and every bone is at least
    :data:`MIN_BONE_LENGTH` long in every frame."""
    if not np.isfinite(joints).all():  # features whose recovery overflowed
        raise UsageError(f"{path}: its joints are not finite (NaN or infinite values)")
    farthest = float(np.abs(joints).max())
    if farthest > MAX_COORDINATE:
        raise UsageError(
            f"{path}: joints {farthest:.3g} m from the origin; export takes joints in metres "
            f"within {MAX_COORDINATE:g} m"
        )
    parents = np.asarray(SMPL.parents[1:])
    bones = np.linalg.norm(joints[:, 1:] - joints[:, parents], axis=-1)  # (T, J - 1)
    frame, bone = np.unravel_index(np.argmin(bones), bones.shape)
    if bones[frame, bone] < MIN_BONE_LENGTH:
        child = bone + 1
        name = f"{SMPL.joint_names[parents[bone]]}-{SMPL.joint_names[child]}"
        raise UsageError(
            f"{path}: bone {name} has length {bones[frame, bone]:.2g} m at frame {frame} "
            f"(under {MIN_BONE_LENGTH * 1000:g} mm): not a body's motion"
        )


@command
def main(argv: list[str] | None = None) -> int:
    """``python -m t2m.export IN.npy OUT.bvh|OUT.glb|OUT.npz|OUT.fbx [--units cm|m]``; returns the
    exit code (2 on bad input)."""
    parser = CommandParser(
        prog="python -m t2m.export",
        description="Write joints (T, 22, 3) (metres, y-up) or HumanML3D features (T, 263) from "
        "a .npy file as a BVH file, an animated glTF binary (.glb), SMPL-H body parameters "
        "(.npz, AMASS's layout) or an FBX file (through Blender's exporter) of the 22-joint "
        "SMPL skeleton.",
    )
    config = parse_config(parser, ExportCommandConfig, argv)
    # features that overflow when recovered are refused by check_motion, in one line
    with np.errstate(over="ignore", invalid="ignore"):
        joints = read_joints(config.input)
    if joints.shape[1] != SMPL.num_joints:
        raise UsageError(
            f"{config.input}: export needs the {SMPL.num_joints}-joint SMPL skeleton, "
            f"got {joints.shape[1]} joints"
        )
    check_motion(joints, config.input)
    fps, fit_rest_pose = config.fps or HUMANML3D.fps, not config.template_rest_pose
    suffix = config.output.suffix.lower()
    if suffix == ".glb":
        write_glb(joints, config.output, fps=fps, fit_rest_pose=fit_rest_pose)
    elif suffix == ".npz":
        write_smplh(fit_smplh(joints, fps=fps, fit_rest_pose=fit_rest_pose), config.output)
    elif suffix == ".fbx":
        write_fbx(joints, config.output, fps=fps, fit_rest_pose=fit_rest_pose)
    else:
        write_bvh(joints, config.output, fps=fps, units=config.units, fit_rest_pose=fit_rest_pose)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
