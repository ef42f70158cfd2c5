"""BVH source: BVH files (read by :mod:`dataset_tools.bvh`) as the 22 SMPL joints, metres, y-up.

:func:`load_bvh_motion` reads a file's joint positions, maps them to SMPL joints, detects the
unit (cm, m, inches or mm) and turns a z-up file y-up.

A mapping names, for each SMPL joint, a BVH joint or a point between two (``["Spine", "Chest",
0.5]``), which is how skeletons with fewer spine joints get the third one.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from dataset_tools.bvh import read_bvh
from dataset_tools.io import read_json
from dataset_tools.rotations import to_y_up
from dataset_tools.skeleton import SMPL, SMPL_JOINT_NAMES
from dataset_tools.sources import ClipError, Motion

logger = logging.getLogger(__name__)

# ----------------------------------------------------------------------------- mappings


@dataclass(frozen=True)
class JointMapping:
    """SMPL joint name -> BVH joint name or (joint a, joint b, t) for a point a + t (b - a)."""

    name: str
    joints: dict
    drop_first_frame: bool = False


def _sided(left: str, right: str, pairs: dict[str, str]) -> dict[str, str]:
    mapping = {}
    for smpl, bvh in pairs.items():
        mapping[f"left_{smpl}"] = bvh.format(side=left)
        mapping[f"right_{smpl}"] = bvh.format(side=right)
    return mapping


# Bandai-Namco Research Motion Dataset: Hips - Spine - Chest - Neck; SMPL's middle spine joint is
# put halfway between Spine and Chest.
BANDAI = JointMapping(
    name="bandai",
    joints={
        "pelvis": "Hips",
        "spine1": "Spine",
        "spine2": ["Spine", "Chest", 0.5],
        "spine3": "Chest",
        "neck": "Neck",
        "head": "Head",
        **_sided(
            "L",
            "R",
            {
                "hip": "UpperLeg_{side}",
                "knee": "LowerLeg_{side}",
                "ankle": "Foot_{side}",
                "foot": "Toes_{side}",
                "collar": "Shoulder_{side}",
                "shoulder": "UpperArm_{side}",
                "elbow": "LowerArm_{side}",
                "wrist": "Hand_{side}",
            },
        ),
    },
)

# Reallusion Character Creator rig (CMU conversions): frame 0 is a T-pose added by the converter.
CMU_CC = JointMapping(
    name="cmu_cc",
    joints={
        "pelvis": "CC_Base_Hip",
        "spine1": "CC_Base_Waist",
        "spine2": "CC_Base_Spine01",
        "spine3": "CC_Base_Spine02",
        "neck": "CC_Base_NeckTwist01",
        "head": "CC_Base_Head",
        **_sided(
            "L",
            "R",
            {
                "hip": "CC_Base_{side}_Thigh",
                "knee": "CC_Base_{side}_Calf",
                "ankle": "CC_Base_{side}_Foot",
                "foot": "CC_Base_{side}_ToeBase",
                "collar": "CC_Base_{side}_Clavicle",
                "shoulder": "CC_Base_{side}_Upperarm",
                "elbow": "CC_Base_{side}_Forearm",
                "wrist": "CC_Base_{side}_Hand",
            },
        ),
    },
    drop_first_frame=True,
)

# Our own exports (dataset_tools.bvh.write_bvh) and any BVH whose joints carry the SMPL names.
SMPL_NAMES = JointMapping(name="smpl", joints={name: name for name in SMPL_JOINT_NAMES})

MAPPINGS: dict[str, JointMapping] = {
    mapping.name: mapping for mapping in (BANDAI, CMU_CC, SMPL_NAMES)
}


def _check_mapping(mapping: JointMapping, where: str) -> JointMapping:
    missing = [name for name in SMPL_JOINT_NAMES if name not in mapping.joints]
    unknown = [name for name in mapping.joints if name not in SMPL_JOINT_NAMES]
    if missing or unknown:
        raise ValueError(f"{where}: mapping lacks SMPL joints {missing} / has unknown {unknown}")
    for smpl, target in mapping.joints.items():
        ok = isinstance(target, str) or (
            isinstance(target, (list, tuple))
            and len(target) == 3
            and all(isinstance(part, str) for part in target[:2])
            and isinstance(target[2], (int, float))
            and np.isfinite(target[2])
        )
        if not ok:
            raise ValueError(f"{where}: {smpl} must map to a joint name or [joint, joint, t]")
    return mapping


def load_mapping(spec: str | Path) -> JointMapping:
    """A built-in mapping by name ("bandai", "cmu_cc", "smpl") or a JSON file.

    The file holds ``{smpl_joint_name: bvh_joint_name | [bvh_a, bvh_b, t], ...}`` for all 22 SMPL
    joints, or ``{"joints": {...}, "drop_first_frame": true}``.
    """
    if str(spec) in MAPPINGS:
        return MAPPINGS[str(spec)]
    path = Path(spec)
    if not path.is_file():
        raise ValueError(
            f"unknown mapping {str(spec)!r} (built-in: {', '.join(MAPPINGS)}, or a JSON file)"
        )
    content = read_json(path, "the mapping")  # a UsageError, which is a ValueError
    if not isinstance(content, dict):
        raise ValueError(f"{path.name}: mapping must be a JSON object")
    joints = content.get("joints", content)
    if not isinstance(joints, dict):
        raise ValueError(f"{path.name}: mapping's joints must be a JSON object")
    return _check_mapping(
        JointMapping(path.stem, dict(joints), bool(content.get("drop_first_frame", False))),
        path.name,
    )


def detect_mapping(names: list[str]) -> JointMapping:
    """The built-in mapping whose joints all exist in ``names``; ValueError if none fits."""
    available = set(names)
    for mapping in MAPPINGS.values():
        needed = {part for target in mapping.joints.values() for part in _parts(target)}
        if needed <= available:
            return mapping
    raise ClipError("no built-in mapping fits this skeleton; pass --mapping FILE.json")


def _parts(target) -> list[str]:
    return [target] if isinstance(target, str) else list(target[:2])


def apply_mapping(positions: np.ndarray, names: list[str], mapping: JointMapping) -> np.ndarray:
    """SMPL joints (T, 22, 3) from BVH joint positions (T, N, 3). ClipError on unknown joints."""
    index = {name: i for i, name in enumerate(names)}
    unknown = sorted(
        {part for target in mapping.joints.values() for part in _parts(target)} - set(index)
    )
    if unknown:
        raise ClipError(f"mapping {mapping.name!r} names BVH joint(s) not in the file: {unknown}")
    joints = np.empty(positions.shape[:1] + (len(SMPL_JOINT_NAMES), 3))
    for smpl_index, smpl_name in enumerate(SMPL_JOINT_NAMES):
        target = mapping.joints[smpl_name]
        if isinstance(target, str):
            joints[:, smpl_index] = positions[:, index[target]]
        else:
            start, end, t = (
                positions[:, index[target[0]]],
                positions[:, index[target[1]]],
                target[2],
            )
            joints[:, smpl_index] = start + float(t) * (end - start)
    return joints


# ----------------------------------------------------------------------------- loading


@dataclass(frozen=True)
class BvhOptions:
    """How to read BVH files into SMPL joints.

    Attributes:
        mapping: built-in mapping name or JSON path; None detects a built-in one.
        scale: metres per file unit; None detects it from the rest-pose size (cm, m or inches).
        up: up axis of the file's world, "y" or "z".
        drop_first_frame: drop frame 0 (a T-pose); None follows the mapping's default.
    """

    mapping: str | None = None
    scale: float | None = None
    up: str = "y"
    drop_first_frame: bool | None = None


# Ankle -> knee -> hip -> pelvis -> spine -> neck -> head: about 1.58 m on the SMPL target body,
# whatever the pose, so its length in file units tells the unit.
_HEIGHT_CHAIN = tuple(
    SMPL.joint(name)
    for name in (
        "right_ankle",
        "right_knee",
        "right_hip",
        "pelvis",
        "spine1",
        "spine2",
        "spine3",
        "neck",
        "head",
    )
)


def detect_scale(smpl_joints: np.ndarray) -> float:
    """Metres per file unit from mapped SMPL joints (T, 22, 3): cm, m, inches or mm.

    Raises ClipError when the body's size fits no unit (then the user passes ``--bvh-scale``).
    """
    chain = np.asarray(smpl_joints[0])[list(_HEIGHT_CHAIN)]
    length = float(np.linalg.norm(np.diff(chain, axis=0), axis=-1).sum())
    for metres_per_unit in (1.0, 0.01, 0.0254, 0.001):
        if 0.8 <= length * metres_per_unit <= 2.6:
            return metres_per_unit
    raise ClipError(f"cannot tell the unit of a body {length:g} units tall; pass --bvh-scale")


def load_bvh_motion(path: str | Path, options: BvhOptions = BvhOptions()) -> Motion:
    """Read a BVH file as SMPL joints (T, 22, 3), y-up metres, at the file's frame rate.

    Raises ClipError for a malformed file, a skeleton the mapping does not fit, an unknown unit
    or no frames; ValueError for a mapping that does not exist or is malformed.
    """
    try:
        names, _, _, positions, fps = read_bvh(path)
    except ValueError as error:  # the parser's message names the file and the problem
        raise ClipError(str(error)) from error
    mapping = load_mapping(options.mapping) if options.mapping else detect_mapping(names)
    drop = (
        mapping.drop_first_frame if options.drop_first_frame is None else options.drop_first_frame
    )
    if drop:
        positions = positions[1:]
    if len(positions) == 0:
        raise ClipError("no frames left after dropping the first frame")
    joints = apply_mapping(positions, names, mapping)
    scale = options.scale if options.scale is not None else detect_scale(joints)
    joints = to_y_up(joints * scale, options.up)
    metadata = {"mapping": mapping.name, "scale": scale, "dropped_first_frame": bool(drop)}
    return Motion(joints=joints, fps=fps, metadata=metadata)


# ----------------------------------------------------------------------------- label captions

# Bandai-Namco content labels -> what a person does; styles -> how.
_BANDAI_ACTIONS = {
    "walk": "walks forward",
    "walk-turn-left": "walks forward and turns left",
    "walk-turn-right": "walks forward and turns right",
    "run": "runs forward",
    "wave-both-hands": "waves both hands",
    "wave-left-hand": "waves the left hand",
    "wave-right-hand": "waves the right hand",
    "raise-up-both-hands": "raises both hands",
    "raise-up-left-hand": "raises the left hand",
    "raise-up-right-hand": "raises the right hand",
}


def _label_lines(path: Path) -> list[str]:
    return [line.strip() for line in path.read_text(encoding="utf-8").splitlines() if line.strip()]


def label_captions(path: str | Path) -> list[str] | None:
    """Captions made from a Bandai-Namco clip's labels (``<clip>.json`` + ``cfg/*_label.txt``).

    Returns None when the clip has no such labels. Two captions: the action, and the action
    with its style ("a person walks forward in an elderly way.").
    """
    path = Path(path)
    labels, cfg = path.with_suffix(".json"), path.parent.parent / "cfg"
    if not (labels.is_file() and (cfg / "content_label.txt").is_file()):
        return None
    try:
        indices = read_json(labels)  # UsageError (a ValueError) when malformed
        content = _label_lines(cfg / "content_label.txt")[int(indices["content"])]
        style = _label_lines(cfg / "style_label.txt")[int(indices["style"])]
    except (OSError, ValueError, KeyError, IndexError, TypeError, UnicodeDecodeError):
        return None
    content, style = content.split("_", 1)[-1], style.split("_", 1)[-1]
    action = _BANDAI_ACTIONS.get(content, content.replace("-", " "))
    captions = [f"a person {action}."]
    if style != "normal":
        article = "an" if style[0] in "aeiou" else "a"
        captions.append(f"a person {action} in {article} {style} way.")
    return captions
