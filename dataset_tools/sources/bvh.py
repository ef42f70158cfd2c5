"""BVH source: our own parser and forward kinematics, plus joint mappings to the 22 SMPL joints.

Conventions. Rotation channels are Euler angles in degrees applied in the order they are listed
(``Zrotation Xrotation Yrotation`` means R = Rz @ Rx @ Ry acting on column vectors, i.e. intrinsic
rotations). A joint with position channels takes them as its translation from the parent
(replacing its OFFSET, as exporters write the offset there); otherwise the OFFSET is used.
End Sites are not joints. Output positions are in the file's units and axes; :func:`load_bvh_motion`
maps them to SMPL joints in metres, y-up.

A mapping names, for each SMPL joint, a BVH joint or a point between two (``["Spine", "Chest",
0.5]``), which is how skeletons with fewer spine joints get the third one.
"""

from __future__ import annotations

import json
import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from dataset_tools.skeleton import SMPL_JOINT_NAMES
from dataset_tools.sources import Motion, to_y_up

logger = logging.getLogger(__name__)

_AXES = {"X": 0, "Y": 1, "Z": 2}


@dataclass
class BvhFile:
    """A parsed BVH file.

    Attributes:
        names: (N,) joint names in file order (End Sites excluded).
        parents: (N,) parent index, -1 for the root; parents precede children.
        offsets: (N, 3) offsets from the parent, file units.
        channels: per joint, its channel names in order (e.g. "Xposition", "Zrotation").
        motion: (T, C) channel values, C = total channel count.
        frame_time: seconds per frame.
    """

    names: list[str]
    parents: list[int]
    offsets: np.ndarray
    channels: list[list[str]]
    motion: np.ndarray
    frame_time: float

    @property
    def fps(self) -> float:
        return 1.0 / self.frame_time


def parse_bvh(text: str, where: str = "BVH") -> BvhFile:
    """Parse BVH text. Raises ValueError with the problem for malformed or truncated files."""
    tokens = text.split()
    position = 0
    names: list[str] = []
    parents: list[int] = []
    offsets: list[list[float]] = []
    channels: list[list[str]] = []
    stack: list[int] = []  # joint index per open brace; -2 marks an End Site's brace

    def take() -> str:
        nonlocal position
        if position >= len(tokens):
            raise ValueError(f"{where}: unexpected end of file in HIERARCHY")
        position += 1
        return tokens[position - 1]

    if not tokens or tokens[0].upper() != "HIERARCHY":
        raise ValueError(f"{where}: not a BVH file (no HIERARCHY)")
    position = 1
    pending: int | None = None  # the joint whose brace comes next
    try:
        while True:
            token = take()
            keyword = token.upper()
            if keyword in ("ROOT", "JOINT"):
                if keyword == "ROOT" and names:
                    raise ValueError(f"{where}: more than one ROOT")
                names.append(take())
                parents.append(stack[-1] if stack else -1)
                offsets.append([0.0, 0.0, 0.0])
                channels.append([])
                pending = len(names) - 1
            elif keyword == "END":
                take()  # "Site"
                pending = -2
            elif token == "{":
                if pending is None:
                    raise ValueError(f"{where}: '{{' without a joint")
                stack.append(pending)
                pending = None
            elif token == "}":
                if not stack:
                    raise ValueError(f"{where}: unbalanced '}}'")
                stack.pop()
            elif keyword == "OFFSET":
                values = [float(take()) for _ in range(3)]
                if stack and stack[-1] >= 0:
                    offsets[stack[-1]] = values
            elif keyword == "CHANNELS":
                count = int(take())
                channels[stack[-1]] = [take() for _ in range(count)]
            elif keyword == "MOTION":
                break
            else:
                raise ValueError(f"{where}: unexpected token {token!r} in HIERARCHY")
    except (IndexError, ValueError) as error:
        raise ValueError(
            str(error) if str(error).startswith(where) else f"{where}: {error}"
        ) from None
    if stack or not names:
        raise ValueError(f"{where}: HIERARCHY is incomplete")
    for joint_channels in channels:
        for name in joint_channels:
            if name[1:] not in ("position", "rotation") or name[0].upper() not in _AXES:
                raise ValueError(f"{where}: unknown channel {name!r}")

    # MOTION: "Frames: T" "Frame Time: dt" then T * C numbers.
    header = tokens[position : position + 5]
    if len(header) < 5 or header[0].lower() != "frames:" or header[2:4] != ["Frame", "Time:"]:
        raise ValueError(f"{where}: malformed MOTION header")
    try:
        num_frames, frame_time = int(header[1]), float(header[4])
        values = np.array(tokens[position + 5 :], dtype=np.float64)
    except ValueError:
        raise ValueError(f"{where}: non-numeric value in MOTION") from None
    if not (np.isfinite(frame_time) and frame_time > 0):
        raise ValueError(f"{where}: frame time must be positive, got {frame_time}")
    num_channels = sum(len(c) for c in channels)
    if num_frames < 1 or values.size < num_frames * num_channels:
        raise ValueError(
            f"{where}: truncated MOTION: {values.size} values for {num_frames} frames of "
            f"{num_channels} channels"
        )
    motion = values[: num_frames * num_channels].reshape(num_frames, num_channels)
    return BvhFile(
        names, parents, np.asarray(offsets, dtype=np.float64), channels, motion, frame_time
    )


def euler_to_matrix(angles_deg: np.ndarray, order: str) -> np.ndarray:
    """Rotation matrices (..., 3, 3) of Euler angles (..., 3) in degrees applied in ``order``.

    ``order`` like "ZXY": R = Rz(a0) @ Rx(a1) @ Ry(a2) (intrinsic, column vectors).
    """
    angles = np.deg2rad(np.asarray(angles_deg, dtype=np.float64))
    result = np.broadcast_to(np.eye(3), angles.shape[:-1] + (3, 3)).copy()
    for k, axis in enumerate(order.upper()):
        cos, sin = np.cos(angles[..., k]), np.sin(angles[..., k])
        matrix = np.zeros(angles.shape[:-1] + (3, 3))
        # Rotation about axis a acts on the (b, c) plane, (a, b, c) a cyclic order of (x, y, z).
        a = _AXES[axis]
        b, c = (a + 1) % 3, (a + 2) % 3
        matrix[..., a, a] = 1.0
        matrix[..., b, b] = cos
        matrix[..., c, c] = cos
        matrix[..., b, c] = -sin
        matrix[..., c, b] = sin
        result = result @ matrix
    return result


def forward_kinematics(bvh: BvhFile) -> np.ndarray:
    """Joint positions (T, N, 3) in file units and axes."""
    num_frames = bvh.motion.shape[0]
    positions = np.zeros((num_frames, len(bvh.names), 3))
    rotations = np.zeros((num_frames, len(bvh.names), 3, 3))
    column = 0
    for joint, joint_channels in enumerate(bvh.channels):
        translation = np.broadcast_to(bvh.offsets[joint], (num_frames, 3)).copy()
        angles, order = [], ""
        for name in joint_channels:
            axis = _AXES[name[0].upper()]
            if name[1:] == "position":
                translation[:, axis] = bvh.motion[:, column]
            else:
                angles.append(bvh.motion[:, column])
                order += name[0].upper()
            column += 1
        local = (
            euler_to_matrix(np.stack(angles, axis=-1), order)
            if order
            else np.broadcast_to(np.eye(3), (num_frames, 3, 3))
        )
        parent = bvh.parents[joint]
        if parent < 0:
            positions[:, joint] = translation
            rotations[:, joint] = local
        else:
            positions[:, joint] = positions[:, parent] + np.einsum(
                "tij,tj->ti", rotations[:, parent], translation
            )
            rotations[:, joint] = rotations[:, parent] @ local
    return positions


def read_bvh(path: str | Path) -> tuple[list[str], list[int], np.ndarray, np.ndarray, float]:
    """Read a BVH file: (joint names, parents, offsets (N, 3), positions (T, N, 3), fps).

    Positions and offsets are in the file's units and axes. Raises ValueError for bad files.
    """
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8", errors="strict")
    except UnicodeDecodeError:
        raise ValueError(f"{path.name}: not a text BVH file") from None
    bvh = parse_bvh(text, path.name)
    return bvh.names, bvh.parents, bvh.offsets, forward_kinematics(bvh), bvh.fps


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
        **_sided("L", "R", {
            "hip": "UpperLeg_{side}", "knee": "LowerLeg_{side}", "ankle": "Foot_{side}",
            "foot": "Toes_{side}", "collar": "Shoulder_{side}", "shoulder": "UpperArm_{side}",
            "elbow": "LowerArm_{side}", "wrist": "Hand_{side}",
        }),
    },
)  # fmt: skip

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
        **_sided("L", "R", {
            "hip": "CC_Base_{side}_Thigh", "knee": "CC_Base_{side}_Calf",
            "ankle": "CC_Base_{side}_Foot", "foot": "CC_Base_{side}_ToeBase",
            "collar": "CC_Base_{side}_Clavicle", "shoulder": "CC_Base_{side}_Upperarm",
            "elbow": "CC_Base_{side}_Forearm", "wrist": "CC_Base_{side}_Hand",
        }),
    },
    drop_first_frame=True,
)  # fmt: skip

# Our own exports (t2m.export) and any BVH whose joints carry the SMPL names.
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
    try:
        content = json.loads(path.read_text(encoding="utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as error:
        raise ValueError(f"{path.name}: mapping is not valid JSON ({error})") from None
    if not isinstance(content, dict):
        raise ValueError(f"{path.name}: mapping must be a JSON object")
    joints = content.get("joints", content)
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
    raise ValueError("no built-in mapping fits this skeleton; pass --mapping FILE.json")


def _parts(target) -> list[str]:
    return [target] if isinstance(target, str) else list(target[:2])


def apply_mapping(positions: np.ndarray, names: list[str], mapping: JointMapping) -> np.ndarray:
    """SMPL joints (T, 22, 3) from BVH joint positions (T, N, 3). ValueError on unknown joints."""
    index = {name: i for i, name in enumerate(names)}
    unknown = sorted(
        {part for target in mapping.joints.values() for part in _parts(target)} - set(index)
    )
    if unknown:
        raise ValueError(f"mapping {mapping.name!r} names BVH joint(s) not in the file: {unknown}")
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
_HEIGHT_CHAIN = (8, 5, 2, 0, 3, 6, 9, 12, 15)


def detect_scale(smpl_joints: np.ndarray) -> float:
    """Metres per file unit from mapped SMPL joints (T, 22, 3): cm, m, inches or mm.

    Raises ValueError when the body's size fits no unit (then the user passes ``--bvh-scale``).
    """
    chain = np.asarray(smpl_joints[0])[list(_HEIGHT_CHAIN)]
    length = float(np.linalg.norm(np.diff(chain, axis=0), axis=-1).sum())
    for metres_per_unit in (1.0, 0.01, 0.0254, 0.001):
        if 0.8 <= length * metres_per_unit <= 2.6:
            return metres_per_unit
    raise ValueError(f"cannot tell the unit of a body {length:g} units tall; pass --bvh-scale")


def load_bvh_motion(path: str | Path, options: BvhOptions = BvhOptions()) -> Motion:
    """Read a BVH file as SMPL joints (T, 22, 3), y-up metres, at the file's frame rate."""
    names, parents, offsets, positions, fps = read_bvh(path)
    mapping = load_mapping(options.mapping) if options.mapping else detect_mapping(names)
    drop = (
        mapping.drop_first_frame if options.drop_first_frame is None else options.drop_first_frame
    )
    if drop:
        positions = positions[1:]
    if len(positions) == 0:
        raise ValueError("no frames left after dropping the first frame")
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
        indices = json.loads(labels.read_text(encoding="utf-8"))
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
