"""``python -m dataset_tools features|recover``: one motion file in, one out."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np

from dataset_tools.command import (
    CommandParser,
    UsageError,
    command,
    option,
    parse_config,
)
from dataset_tools.io import check_output_file, load_npy, save_npy_atomic
from dataset_tools.representation import (
    FeatureLayout,
    process_motion,
    recover_from_ric,
    recover_from_rot,
    target_offsets_from_example,
)
from dataset_tools.skeleton import skeleton_for


@dataclass
class FeaturesConfig:
    """``python -m dataset_tools features``."""

    input: Path = field(metadata=option(positional=True))
    """joints .npy, shape (T, J, 3)"""
    output: Path = field(metadata=option(positional=True))
    """features .npy to write, shape (T-1, 263 or 251)"""
    target_skeleton: Path | None = field(default=None, metadata=option(metavar="NPY"))
    """one frame (>= J, 3) whose bone lengths define the target skeleton (default: the HumanML3D
    target lengths)"""
    fixed_across: bool = False
    """use the corrected across vector in inverse kinematics instead of HumanML3D's"""
    joints_out: Path | None = field(default=None, metadata=option(metavar="NPY"))
    """also write the recovered joints"""


@dataclass
class RecoverConfig:
    """``python -m dataset_tools recover``."""

    input: Path = field(metadata=option(positional=True))
    """features .npy, shape (T, 263) or (T, 251)"""
    output: Path = field(metadata=option(positional=True))
    """joints .npy to write, shape (T, J, 3)"""
    method: Literal["ric", "rot"] = "ric"
    """ric: from joint positions (as HumanML3D); rot: forward kinematics of the 6-D rotations on
    the target skeleton"""


def check_outputs(inputs: list[Path | None], outputs: list[tuple[str, Path | None]]) -> None:
    """Before any work: every output can be written, and none is an input or another output
    (an output written over an input would destroy the user's file). UsageError otherwise."""
    seen: dict[Path, str] = {}
    for path in inputs:
        if path is not None:
            seen[path.resolve()] = f"the input {path}"
    for what, path in outputs:
        if path is None:
            continue
        check_output_file(path, what)
        if path.resolve() in seen:
            raise UsageError(f"{what} {path} is {seen[path.resolve()]}; give another file name")
        seen[path.resolve()] = f"the {what}"


def finite_float32(array: np.ndarray, source: Path) -> np.ndarray:
    """``array`` as float32 for writing; UsageError naming ``source`` when a value is not finite
    in float32 (NaN, or beyond its range), so no command writes an array that would poison
    every later step."""
    with np.errstate(over="ignore", invalid="ignore"):
        result = np.asarray(array).astype(np.float32)
    if not np.isfinite(result).all():
        raise UsageError(f"{source}: the result is not finite in float32 (values out of range?)")
    return result


@command
def features_main(argv: list[str] | None = None) -> int:
    parser = CommandParser(
        prog="python -m dataset_tools features",
        description="Joints (T, J, 3), y-up metres at 20 fps (J = 22 SMPL or 21 KIT), to HumanML3D "
        "features (T-1, D): retarget to the target skeleton, canonicalise, extract.",
    )
    config = parse_config(parser, FeaturesConfig, argv)
    check_outputs(
        [config.input, config.target_skeleton],
        [("output", config.output), ("--joints-out", config.joints_out)],
    )
    joints = load_npy(config.input)
    if joints.ndim != 3 or joints.shape[-1] != 3 or joints.shape[1] not in (21, 22):
        raise UsageError(f"{config.input}: expected joints (T, 22 or 21, 3), got {joints.shape}")
    if len(joints) < 2:
        raise UsageError(f"{config.input}: need at least 2 frames, got {len(joints)}")
    skeleton = skeleton_for(joints.shape[1])
    offsets = None
    if config.target_skeleton is not None:
        example = load_npy(config.target_skeleton)
        if example.ndim != 2 or example.shape[0] < skeleton.num_joints or example.shape[1] != 3:
            raise UsageError(
                f"{config.target_skeleton}: expected one frame (>= {skeleton.num_joints}, 3), "
                f"got {example.shape}"
            )
        offsets = target_offsets_from_example(example, skeleton)
    try:
        features, recovered = process_motion(
            joints, skeleton, offsets, compat=not config.fixed_across
        )
    except ValueError as error:  # degenerate input (a documented refusal of process_motion)
        raise UsageError(f"{config.input}: {error}") from None
    features = finite_float32(features, config.input)
    recovered = finite_float32(recovered, config.input)
    save_npy_atomic(config.output, features)
    if config.joints_out is not None:
        save_npy_atomic(config.joints_out, recovered)
    return 0


@command
def recover_main(argv: list[str] | None = None) -> int:
    parser = CommandParser(
        prog="python -m dataset_tools recover",
        description="HumanML3D features (T, 263 or 251) back to joints (T, J, 3), y-up metres.",
    )
    config = parse_config(parser, RecoverConfig, argv)
    check_outputs([config.input], [("output", config.output)])
    features = load_npy(config.input)
    dims = {FeatureLayout(joints).dim: joints for joints in (22, 21)}
    if features.ndim != 2 or features.shape[1] not in dims:
        raise UsageError(
            f"{config.input}: expected features (T, 263 or 251), got shape {features.shape}"
        )
    num_joints = dims[features.shape[1]]
    if config.method == "ric":
        joints = recover_from_ric(features, num_joints)
    else:
        joints = recover_from_rot(features, skeleton_for(num_joints))
    save_npy_atomic(config.output, finite_float32(joints, config.input))
    return 0
