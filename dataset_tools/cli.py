"""``python -m dataset_tools features|recover``: one motion file in, one out."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from dataset_tools.io import save_npy_atomic
from dataset_tools.representation import (
    FeatureLayout,
    process_motion,
    recover_from_ric,
    recover_from_rot,
    target_offsets_from_example,
)
from dataset_tools.skeleton import skeleton_for


class _CliError(Exception):
    """A bad input, reported as one line with exit code 2."""


def _load(path: str) -> np.ndarray:
    file = Path(path)
    if not file.is_file():
        raise _CliError(f"no such file: {file}")
    try:
        array = np.load(file, allow_pickle=False)
    except (OSError, ValueError) as error:
        raise _CliError(f"cannot read {file} as a .npy array ({error})") from error
    if not np.all(np.isfinite(array)):
        raise _CliError(f"{file} contains NaN or infinite values")
    return array


def _run(function, argv: list[str]) -> int:
    try:
        function(argv)
    except (_CliError, ValueError) as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    return 0


def _features(argv: list[str]) -> None:
    parser = argparse.ArgumentParser(
        prog="python -m dataset_tools features",
        description="Joints (T, J, 3), y-up metres at 20 fps (J = 22 SMPL or 21 KIT), to HumanML3D "
        "features (T-1, D): retarget to the target skeleton, canonicalise, extract.",
    )
    parser.add_argument("input", help="joints .npy, shape (T, J, 3)")
    parser.add_argument("output", help="features .npy to write, shape (T-1, 263 or 251)")
    parser.add_argument(
        "--target-skeleton",
        metavar="NPY",
        help="one frame (>= J, 3) whose bone lengths define the target skeleton "
        "(default: the HumanML3D target lengths)",
    )
    parser.add_argument(
        "--fixed-across",
        action="store_true",
        help="use the corrected across vector in inverse kinematics instead of HumanML3D's",
    )
    parser.add_argument("--joints-out", metavar="NPY", help="also write the recovered joints")
    args = parser.parse_args(argv)
    joints = _load(args.input)
    if joints.ndim != 3 or joints.shape[-1] != 3 or joints.shape[1] not in (21, 22):
        raise _CliError(f"{args.input}: expected joints (T, 22 or 21, 3), got {joints.shape}")
    skeleton = skeleton_for(joints.shape[1])
    offsets = None
    if args.target_skeleton:
        offsets = target_offsets_from_example(_load(args.target_skeleton), skeleton)
    features, recovered = process_motion(joints, skeleton, offsets, compat=not args.fixed_across)
    save_npy_atomic(args.output, features.astype(np.float32))
    if args.joints_out:
        save_npy_atomic(args.joints_out, recovered.astype(np.float32))


def _recover(argv: list[str]) -> None:
    parser = argparse.ArgumentParser(
        prog="python -m dataset_tools recover",
        description="HumanML3D features (T, 263 or 251) back to joints (T, J, 3), y-up metres.",
    )
    parser.add_argument("input", help="features .npy, shape (T, 263) or (T, 251)")
    parser.add_argument("output", help="joints .npy to write, shape (T, J, 3)")
    parser.add_argument(
        "--method",
        choices=("ric", "rot"),
        default="ric",
        help="ric: from joint positions (default, as HumanML3D); rot: forward kinematics of the "
        "6-D rotations on the target skeleton",
    )
    args = parser.parse_args(argv)
    features = _load(args.input)
    if features.ndim != 2:
        raise _CliError(f"{args.input}: expected features (T, D), got shape {features.shape}")
    layout = FeatureLayout.for_dim(features.shape[1])
    if args.method == "ric":
        joints = recover_from_ric(features, layout.num_joints)
    else:
        joints = recover_from_rot(features, skeleton_for(layout.num_joints))
    save_npy_atomic(args.output, joints.astype(np.float32))


def features_main(argv: list[str]) -> int:
    return _run(_features, argv)


def recover_main(argv: list[str]) -> int:
    return _run(_recover, argv)
