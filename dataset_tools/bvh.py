"""BVH files: reading, forward kinematics and writing (the 22-joint SMPL skeleton, rotations by IK).

Reading. Rotation channels are Euler angles in degrees applied in the order they are listed
(``Zrotation Xrotation Yrotation`` means R = Rz @ Rx @ Ry acting on column vectors, i.e. intrinsic
rotations). A joint with position channels takes them as its translation from the parent
(replacing its OFFSET, as exporters write the offset there); otherwise the OFFSET is used.
End Sites are not joints. Positions are in the file's units and axes (mapping them to SMPL joints
is the BVH source's job, :mod:`dataset_tools.sources.bvh`).

Forward kinematics (:func:`forward_kinematics`, used for both reading and writing): a joint's
global rotation is its parent's times its local one, and it turns its children's translations.

Writing. A BVH joint's rotation turns *all* of its children's offsets, so unlike the swing-only,
one-rotation-per-bone IK of HumanML3D (``dataset_tools.kinematics``), every joint here needs one
full rotation that fits all its child bones and a chosen twist about its bone:

* joints with several children (pelvis, spine3) take the rotation that best aligns all their
  child offsets with the observed bones (Kabsch, per frame);
* hips take the twist that puts the knee's bend plane (or, with a straight leg, the foot) forward,
  and shoulders the twist that puts the elbow's bend plane forward, so knees and elbows become
  hinges about one local axis;
* every other joint takes the shortest-arc swing from where its parent carries its bone to the
  observed bone, i.e. no twist relative to its parent, so limbs never spin about their axis;
* end joints (feet, head, wrists) carry no information about their own rotation and keep their
  parent's (identity local rotation).

The rest pose (all rotations zero) is a T-pose with the target bone lengths of
``dataset_tools.skeleton.SMPL``: legs down, feet forward, spine and head up, arms out along +-X.
The directions of the pelvis's and spine3's children (hips, collars) are body-specific and rigid
in those joints' frames, so by default they are fitted to the motion (otherwise taken from the
HumanML3D target skeleton); with that, forward kinematics of the file reproduces any motion that
has the target bone lengths (everything HumanML3D-processed or generated from its features) to
well under a centimetre.

Conventions of the writer: world y-up, a person facing +Z has their left side at +X, positions in metres in
Python and in ``units`` in the file, 20 fps by default, Euler channels ``Zrotation Xrotation
Yrotation`` (intrinsic, R = Rz Rx Ry, as CMU and most tools write them), degrees, unwrapped in time
so curves never jump by 360.
"""

from __future__ import annotations

import logging
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from dataset_tools.io import write_text_atomic
from dataset_tools.rotations import qbetween, quat_to_matrix
from dataset_tools.skeleton import SMPL

logger = logging.getLogger(__name__)

# ----------------------------------------------------------------------------- reading

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
    if not tokens or tokens[0].upper() != "HIERARCHY":
        raise ValueError(f"{where}: not a BVH file (no HIERARCHY)")
    try:
        names, parents, offsets, channels, position = _HierarchyReader(tokens, where).read()
    except (IndexError, ValueError) as error:
        raise ValueError(
            str(error) if str(error).startswith(where) else f"{where}: {error}"
        ) from None
    motion, frame_time = _parse_motion(tokens[position:], channels, where)
    return BvhFile(
        names, parents, np.asarray(offsets, dtype=np.float64), channels, motion, frame_time
    )


class _HierarchyReader:
    """Reads the HIERARCHY section, token by token after its keyword, up to ``MOTION``: one
    method per keyword. ValueError for what is not a well-formed hierarchy."""

    def __init__(self, tokens: list[str], where: str):
        self.tokens, self.where, self.position = tokens, where, 1
        self.names: list[str] = []
        self.parents: list[int] = []
        self.offsets: list[list[float]] = []
        self.channels: list[list[str]] = []
        self.stack: list[int] = []  # joint index per open brace; -2 marks an End Site's brace
        self.pending: int | None = None  # the joint whose brace comes next

    def take(self) -> str:
        if self.position >= len(self.tokens):
            raise ValueError(f"{self.where}: unexpected end of file in HIERARCHY")
        self.position += 1
        return self.tokens[self.position - 1]

    def read(self) -> tuple[list[str], list[int], list[list[float]], list[list[str]], int]:
        """(names, parents, offsets, channels, index of the token after ``MOTION``)."""
        handlers = {
            "ROOT": self._joint,
            "JOINT": self._joint,
            "END": self._end_site,
            "{": self._open,
            "}": self._close,
            "OFFSET": self._offset,
            "CHANNELS": self._channel_names,
        }
        while True:
            token = self.take()
            keyword = token.upper()
            if keyword == "MOTION":
                break
            if keyword not in handlers:
                raise ValueError(f"{self.where}: unexpected token {token!r} in HIERARCHY")
            handlers[keyword](keyword)
        if self.stack or not self.names:
            raise ValueError(f"{self.where}: HIERARCHY is incomplete")
        for joint_channels in self.channels:
            for name in joint_channels:
                if name[1:] not in ("position", "rotation") or name[0].upper() not in _AXES:
                    raise ValueError(f"{self.where}: unknown channel {name!r}")
        return self.names, self.parents, self.offsets, self.channels, self.position

    def _joint(self, keyword: str) -> None:
        if keyword == "ROOT" and self.names:
            raise ValueError(f"{self.where}: more than one ROOT")
        self.names.append(self.take())
        self.parents.append(self.stack[-1] if self.stack else -1)
        self.offsets.append([0.0, 0.0, 0.0])
        self.channels.append([])
        self.pending = len(self.names) - 1

    def _end_site(self, keyword: str) -> None:
        self.take()  # "Site"
        self.pending = -2

    def _open(self, keyword: str) -> None:
        if self.pending is None:
            raise ValueError(f"{self.where}: '{{' without a joint")
        self.stack.append(self.pending)
        self.pending = None

    def _close(self, keyword: str) -> None:
        if not self.stack:
            raise ValueError(f"{self.where}: unbalanced '}}'")
        self.stack.pop()

    def _offset(self, keyword: str) -> None:
        values = [float(self.take()) for _ in range(3)]
        if self.stack and self.stack[-1] >= 0:
            self.offsets[self.stack[-1]] = values

    def _channel_names(self, keyword: str) -> None:
        count = int(self.take())
        self.channels[self.stack[-1]] = [self.take() for _ in range(count)]


def _parse_motion(
    tokens: list[str], channels: list[list[str]], where: str
) -> tuple[np.ndarray, float]:
    """The MOTION section after its keyword: "Frames: T" "Frame Time: dt" then T * C numbers
    -> (motion (T, C), frame time)."""
    header = tokens[:5]
    if len(header) < 5 or header[0].lower() != "frames:" or header[2:4] != ["Frame", "Time:"]:
        raise ValueError(f"{where}: malformed MOTION header")
    try:
        num_frames, frame_time = int(header[1]), float(header[4])
        values = np.array(tokens[5:], dtype=np.float64)
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
    return motion, frame_time


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


def local_transforms(bvh: BvhFile) -> tuple[np.ndarray, np.ndarray]:
    """Per frame and joint, the translation from the parent (T, N, 3) (the root's: its position)
    and the local rotation (T, N, 3, 3), from the file's offsets and channels."""
    num_frames = bvh.motion.shape[0]
    translations = np.zeros((num_frames, len(bvh.names), 3))
    rotations = np.zeros((num_frames, len(bvh.names), 3, 3))
    column = 0
    for joint, joint_channels in enumerate(bvh.channels):
        translations[:, joint] = bvh.offsets[joint]
        angles, order = [], ""
        for name in joint_channels:
            axis = _AXES[name[0].upper()]
            if name[1:] == "position":
                translations[:, joint, axis] = bvh.motion[:, column]
            else:
                angles.append(bvh.motion[:, column])
                order += name[0].upper()
            column += 1
        rotations[:, joint] = (
            euler_to_matrix(np.stack(angles, axis=-1), order) if order else np.eye(3)
        )
    return translations, rotations


def forward_kinematics(
    parents: tuple[int, ...] | list[int], translations: np.ndarray, local_rotations: np.ndarray
) -> np.ndarray:
    """Joint positions (T, J, 3) of a BVH skeleton.

    Args:
        parents: (J,) parent index per joint, -1 for the root; parents precede children.
        translations: (T, J, 3) or (J, 3) translation of each joint from its parent, in the
            parent's frame (the root's: its position).
        local_rotations: (T, J, 3, 3) rotation of each joint relative to its parent.
    """
    num_frames, num_joints = local_rotations.shape[:2]
    translations = np.broadcast_to(translations, (num_frames, num_joints, 3))
    positions = np.zeros((num_frames, num_joints, 3))
    global_rot = np.zeros((num_frames, num_joints, 3, 3))
    for joint, parent in enumerate(parents):
        if parent < 0:
            positions[:, joint] = translations[:, joint]
            global_rot[:, joint] = local_rotations[:, joint]
            continue
        positions[:, joint] = positions[:, parent] + np.einsum(
            "tij,tj->ti", global_rot[:, parent], translations[:, joint]
        )
        global_rot[:, joint] = global_rot[:, parent] @ local_rotations[:, joint]
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
    positions = forward_kinematics(bvh.parents, *local_transforms(bvh))
    return bvh.names, bvh.parents, bvh.offsets, positions, bvh.fps


# ----------------------------------------------------------------------------- writing

UNITS = {"m": 1.0, "cm": 100.0}
MIN_FPS, MAX_FPS = 1.0, 1000.0
"""The frame rates the writers take (BVH and glTF): a BVH frame time has 8 decimals and glTF key
times are float32 seconds, so far faster rates lose the timing (1e9 fps prints a frame time of
0); under one frame a second is no motion clip."""
MAX_COORDINATE = 1e4
"""The largest |coordinate| (metres) of a joint the writers take: 10 km from the origin is beyond
any captured or generated clip, and the inverse kinematics' squared lengths stay finite."""
EULER_ORDER = "ZXY"
_EPS = 1e-9

# T-pose directions of the bone ending at each joint (the rest pose of the BVH file).
_TPOSE = np.array([
    [0, 0, 0],                                  # pelvis (root)
    [1, 0, 0], [-1, 0, 0], [0, 1, 0],           # hips, spine1 (pelvis's children, see below)
    [0, -1, 0], [0, -1, 0], [0, 1, 0],          # knees, spine2
    [0, -1, 0], [0, -1, 0], [0, 1, 0],          # ankles, spine3
    [0, 0, 1], [0, 0, 1], [0, 1, 0],            # feet, neck (spine3's child)
    [1, 0, 0], [-1, 0, 0], [0, 1, 0],           # collars (spine3's children), head
    [1, 0, 0], [-1, 0, 0], [1, 0, 0], [-1, 0, 0], [1, 0, 0], [-1, 0, 0],  # shoulders..wrists
], dtype=np.float64)  # fmt: skip

# Directions of the pelvis's and spine3's children in their parent's frame (x from the right to
# the left twin, y along the middle child), measured on the HumanML3D target skeleton (clip
# 000021, frame 0) and made left/right symmetric. Used when the rest pose is not fitted.
_BRANCH_TEMPLATE = {
    1: (0.557, -0.737, -0.380), 2: (-0.557, -0.737, -0.380), 3: (0.0, 1.0, 0.0),
    12: (0.0, 1.0, 0.0), 13: (0.549, 0.835, -0.021), 14: (-0.549, 0.835, -0.021),
}  # fmt: skip
_SIDES = ("left", "right")
# Branch joint -> (left child, right child, middle child).
_BRANCHES = {
    SMPL.joint("pelvis"): (SMPL.joint("left_hip"), SMPL.joint("right_hip"), SMPL.joint("spine1")),
    SMPL.joint("spine3"): (
        SMPL.joint("left_collar"),
        SMPL.joint("right_collar"),
        SMPL.joint("neck"),
    ),
}
# Hip -> (knee, ankle, foot) and shoulder -> (elbow, wrist): the joints that give their twist.
_LEGS = {
    SMPL.joint(f"{side}_hip"): tuple(SMPL.joint(f"{side}_{j}") for j in ("knee", "ankle", "foot"))
    for side in _SIDES
}
_ARMS = {
    SMPL.joint(f"{side}_shoulder"): (SMPL.joint(f"{side}_elbow"), SMPL.joint(f"{side}_wrist"))
    for side in _SIDES
}
# Lengths (metres) of the End Site of each end joint, along its bone's rest direction.
_END_SITES = {10: 0.05, 11: 0.05, 15: 0.10, 20: 0.08, 21: 0.08}
_FORWARD = np.array([0.0, 0.0, 1.0])
# A bend smaller than this angle hands the twist over (smoothly) to the next cue.
_BEND_FULL_DEGREES = 20.0


@dataclass(frozen=True)
class BvhMotion:
    """A motion on the BVH skeleton.

    Attributes:
        joint_names: one name per joint (the SMPL joint names).
        parents: parent index per joint, -1 for the root.
        offsets: (J, 3) rest offsets in metres (the root's is zero).
        root_positions: (T, 3) root (pelvis) positions in metres.
        local_rotations: (T, J, 3, 3) rotation of each joint relative to its parent.
        fps: frames per second.
    """

    joint_names: tuple[str, ...]
    parents: tuple[int, ...]
    offsets: np.ndarray
    root_positions: np.ndarray
    local_rotations: np.ndarray
    fps: float

    @property
    def num_frames(self) -> int:
        return len(self.root_positions)

    def joints(self) -> np.ndarray:
        """Forward kinematics: joint positions (T, J, 3) in metres."""
        translations = np.repeat(self.offsets[None], self.num_frames, axis=0)
        translations[:, self.parents.index(-1)] = self.root_positions
        return forward_kinematics(self.parents, translations, self.local_rotations)

    def euler_degrees(self) -> np.ndarray:
        """(T, J, 3) Euler angles in degrees in channel order (Z, X, Y), continuous in time.

        Every rotation has two Euler triples, (z, x, y) and (z + 180, 180 - x, y + 180), each up
        to whole turns; per frame the one nearest the previous frame's is kept, so a knee bending
        past 90 degrees stays (0, x, 0) rather than flipping to (180, 180 - x, 180).
        """
        num_frames, num_joints = self.local_rotations.shape[:2]
        flat = self.local_rotations.reshape(-1, 3, 3)
        primary = Rotation.from_matrix(flat).as_euler(EULER_ORDER, degrees=True)
        primary = primary.reshape(num_frames, num_joints, 3)
        alternative = primary * (1.0, -1.0, 1.0) + (180.0, 180.0, 180.0)
        angles = np.empty_like(primary)
        angles[0] = primary[0]
        for frame in range(1, num_frames):
            previous = angles[frame - 1]
            candidates = np.stack([primary[frame], alternative[frame]])  # (2, J, 3)
            candidates -= 360.0 * np.round((candidates - previous) / 360.0)
            distance = np.abs(candidates - previous).sum(axis=-1)  # (2, J)
            angles[frame] = np.where((distance[0] <= distance[1])[:, None], *candidates)
        return angles

    def to_text(self, units: str = "cm", decimals: int = 6) -> str:
        """The BVH file's text."""
        if units not in UNITS:
            raise ValueError(f"unknown BVH units {units!r}; use one of {sorted(UNITS)}")
        scale = UNITS[units]
        fmt = f"{{:.{decimals}f}}"

        def vec(v: np.ndarray) -> str:
            # Round first so tiny negatives print as 0.0, not -0.000000.
            return " ".join(fmt.format(x) for x in np.round(v, decimals) + 0.0)

        children: dict[int, list[int]] = {j: [] for j in range(len(self.parents))}
        for joint, parent in enumerate(self.parents):
            if parent >= 0:
                children[parent].append(joint)
        lines = ["HIERARCHY"]
        file_order: list[int] = []  # depth first, the order of the channels in every frame line

        def emit(joint: int, depth: int) -> None:
            file_order.append(joint)
            pad = "\t" * depth
            kind = "ROOT" if self.parents[joint] < 0 else "JOINT"
            lines.append(f"{pad}{kind} {self.joint_names[joint]}")
            lines.append(f"{pad}{{")
            lines.append(f"{pad}\tOFFSET {vec(self.offsets[joint] * scale)}")
            rotations = "Zrotation Xrotation Yrotation"
            if kind == "ROOT":
                lines.append(f"{pad}\tCHANNELS 6 Xposition Yposition Zposition {rotations}")
            else:
                lines.append(f"{pad}\tCHANNELS 3 {rotations}")
            for child in children[joint]:
                emit(child, depth + 1)
            if not children[joint]:
                end = _TPOSE[joint] * _END_SITES.get(joint, 0.05) * scale
                lines.extend(
                    [f"{pad}\tEnd Site", f"{pad}\t{{", f"{pad}\t\tOFFSET {vec(end)}", f"{pad}\t}}"]
                )
            lines.append(f"{pad}}}")

        emit(0, 0)
        euler = self.euler_degrees()
        lines += ["MOTION", f"Frames: {self.num_frames}", f"Frame Time: {1.0 / self.fps:.8f}"]
        root = self.root_positions * scale
        for frame in range(self.num_frames):
            values = np.concatenate([root[frame], euler[frame, file_order].reshape(-1)])
            lines.append(vec(values))
        return "\n".join(lines) + "\n"


def _unit(v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit vectors (..., 3) and norms (...,); zero vectors stay zero (callers check the norm)."""
    norm = np.linalg.norm(v, axis=-1)
    return v / np.maximum(norm, _EPS)[..., None], norm


def _perp(v: np.ndarray, axis: np.ndarray) -> np.ndarray:
    """Part of v (..., 3) perpendicular to unit vectors axis (..., 3)."""
    return v - np.sum(v * axis, axis=-1, keepdims=True) * axis


def _basis(primary: np.ndarray, secondary: np.ndarray) -> np.ndarray:
    """Orthonormal frames (..., 3, 3) with columns (primary, secondary made perpendicular, cross)."""
    e1, _ = _unit(primary)
    e2, _ = _unit(_perp(secondary, e1))
    return np.stack([e1, e2, np.cross(e1, e2)], axis=-1)


def _branch_frames(joints: np.ndarray, joint: int) -> np.ndarray:
    """(T, 3, 3) frames of a branch joint: x from its right to its left child, y towards its
    middle child (made perpendicular), z = x cross y."""
    left, right, middle = _BRANCHES[joint]
    x, _ = _unit(joints[:, left] - joints[:, right])
    y, _ = _unit(_perp(joints[:, middle] - joints[:, joint], x))
    return np.stack([x, y, np.cross(x, y)], axis=-1)


def rest_directions(joints: np.ndarray | None = None) -> np.ndarray:
    """(J, 3) unit rest directions of the BVH skeleton's bones.

    With joints (T, 22, 3), the directions of the pelvis's and spine3's children are fitted to the
    motion (their mean direction in the branch joint's frame); otherwise the template is used.
    """
    directions = _TPOSE.copy()
    for child, direction in _BRANCH_TEMPLATE.items():
        directions[child] = _unit(np.asarray(direction))[0]
    if joints is None:
        return directions
    for joint, kids in _BRANCHES.items():
        frames = _branch_frames(joints, joint)  # (T, 3, 3)
        for child in kids:
            bone, _ = _unit(joints[:, child] - joints[:, joint])
            local = np.einsum("tji,tj->ti", frames, bone)  # frames^T @ bone
            mean, norm = _unit(local.mean(axis=0))
            if norm > 0.5:  # a consistent direction; otherwise keep the template
                directions[child] = mean
    return directions


def _kabsch(rest: np.ndarray, observed: np.ndarray) -> np.ndarray:
    """Rotations (T, 3, 3) best carrying rest directions (K, 3) onto observed (T, K, 3)."""
    covariance = np.einsum("tki,kj->tij", observed, rest)  # sum_k observed_k rest_k^T
    u, _, vt = np.linalg.svd(covariance)
    det = np.linalg.det(u @ vt)
    fix = np.ones((len(det), 3))
    fix[:, 2] = np.sign(det + (det == 0))  # a proper rotation, never a reflection
    return (u * fix[:, None, :]) @ vt


def _twist_cues(joints: np.ndarray, joint: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """Twist cues for a single-child joint: (direction (T, 3), confidence (T,)) pairs, best first.

    Each direction is where the rest pose's +Z (perpendicular to the bone) should point.
    """
    cues: list[tuple[np.ndarray, np.ndarray]] = []
    full = np.sin(np.radians(_BEND_FULL_DEGREES))
    if joint in _LEGS:  # hips: the knee bends backwards, so "forward" is minus the shin's bend
        knee, ankle, foot = _LEGS[joint]
        thigh, _ = _unit(joints[:, knee] - joints[:, joint])
        shin, _ = _unit(joints[:, ankle] - joints[:, knee])
        bend, sin_bend = _unit(-_perp(shin, thigh))
        cues.append((bend, np.clip(sin_bend / full, 0.0, 1.0)))
        toe, toe_norm = _unit(_perp(joints[:, foot] - joints[:, ankle], thigh))
        _, foot_len = _unit(joints[:, foot] - joints[:, ankle])
        cues.append((toe, np.clip(toe_norm / np.maximum(foot_len, _EPS) / full, 0.0, 1.0)))
    elif joint in _ARMS:  # shoulders: the elbow bends the forearm forwards in the T-pose
        elbow, wrist = _ARMS[joint]
        upper, _ = _unit(joints[:, elbow] - joints[:, joint])
        fore, _ = _unit(joints[:, wrist] - joints[:, elbow])
        bend, sin_bend = _unit(_perp(fore, upper))
        cues.append((bend, np.clip(sin_bend / full, 0.0, 1.0)))
    return cues


def solve_rotations(joints: np.ndarray, directions: np.ndarray) -> np.ndarray:
    """Local rotations (T, J, 3, 3) of the BVH skeleton that lay its bones along joints (T, J, 3).

    ``directions`` (J, 3) are the unit rest directions of the bones. See the module docstring for
    how twists are chosen.
    """
    num_frames, num_joints = joints.shape[:2]
    parents = SMPL.parents
    children: dict[int, list[int]] = {j: [] for j in range(num_joints)}
    for joint, parent in enumerate(parents):
        if parent >= 0:
            children[parent].append(joint)
    identity = np.broadcast_to(np.eye(3), (num_frames, 3, 3))
    global_rot = np.zeros((num_frames, num_joints, 3, 3))
    local_rot = np.zeros((num_frames, num_joints, 3, 3))
    for joint in range(num_joints):  # parents precede children
        parent_rot = identity if parents[joint] < 0 else global_rot[:, parents[joint]]
        kids = children[joint]
        if not kids:
            rotation = parent_rot
        elif len(kids) > 1:
            observed, _ = _unit(joints[:, kids] - joints[:, joint : joint + 1])
            rotation = _kabsch(directions[kids], observed)
        else:
            rotation = _single_child_rotation(joints, joint, kids[0], directions, parent_rot)
        global_rot[:, joint] = rotation
        local_rot[:, joint] = np.swapaxes(parent_rot, -1, -2) @ rotation
    return local_rot


def _single_child_rotation(
    joints: np.ndarray,
    joint: int,
    child: int,
    directions: np.ndarray,
    parent_rot: np.ndarray,
) -> np.ndarray:
    """Global rotations (T, 3, 3) of a joint with one child: its bone exactly along the observed
    bone, twisted by the joint's cues, falling back smoothly to no twist relative to the parent."""
    rest = directions[child]
    bone, length = _unit(joints[:, child] - joints[:, joint])
    carried = parent_rot @ rest  # (T, 3): where the parent's rotation alone puts the bone
    # A zero-length bone has no direction: keep the parent's.
    bone = np.where((length > _EPS)[:, None], bone, carried)
    swing = quat_to_matrix(qbetween(carried, bone)) @ parent_rot  # (T, 3, 3)
    cues = _twist_cues(joints, joint)
    if not cues:
        return swing
    reference_rest = _FORWARD  # perpendicular to the hips' and shoulders' rest bones
    # Blend the cues in priority order; whatever confidence is left goes to the previous frame's
    # twist, carried along with the bone (frame 0: no twist relative to the parent).
    cue = np.zeros_like(bone)
    remaining = np.ones(len(bone))
    for direction, confidence in cues:
        weight = remaining * confidence
        cue += weight[:, None] * direction
        remaining = remaining - weight
    references = _propagate_twist(bone, cue, remaining, swing @ reference_rest)
    return _basis(bone, references) @ _basis(rest, reference_rest).T


def _propagate_twist(
    bone: np.ndarray, cue: np.ndarray, remaining: np.ndarray, no_twist: np.ndarray
) -> np.ndarray:
    """Twist references (T, 3) perpendicular to unit bones (T, 3): ``cue`` (already weighted)
    plus ``remaining`` (T,) times the previous frame's reference, turned by the shortest arc from
    the previous bone to this one, so a limb whose cues fade keeps its twist instead of snapping
    to another one. ``no_twist`` (T, 3) stands in where nothing else is defined."""
    fallback = _perp(no_twist, bone)  # used where the cues cancel out
    if not remaining[1:].any():  # the cues decide every frame: no sequential pass needed
        target = _perp(cue + remaining[:, None] * no_twist, bone)
        weak = np.linalg.norm(target, axis=-1) < 1e-6
        target[weak] = fallback[weak]
        return _unit(target)[0]
    arcs = quat_to_matrix(qbetween(bone[:-1], bone[1:]))  # (T - 1, 3, 3) frame-to-frame turns
    references = np.empty_like(bone)
    previous = no_twist[0]
    for frame in range(len(bone)):
        if frame > 0:
            previous = arcs[frame - 1] @ references[frame - 1]
        target = _perp(cue[frame] + remaining[frame] * previous, bone[frame])
        norm = np.linalg.norm(target)
        if norm < 1e-6:
            target, norm = fallback[frame], 1.0
        references[frame] = target / norm
    return references


def motion_from_joints(
    joints: np.ndarray, fps: float = 20.0, fit_rest_pose: bool = True
) -> BvhMotion:
    """Solve the BVH motion of joints (T, 22, 3) (metres, y-up).

    Offsets have the target bone lengths of ``SMPL``; see the module docstring for the rest pose
    and the rotations. Raises ValueError on a wrong shape, non-finite values or values beyond
    :data:`MAX_COORDINATE`, or fps outside [:data:`MIN_FPS`, :data:`MAX_FPS`].
    """
    joints = np.asarray(joints, dtype=np.float64)
    if joints.ndim != 3 or joints.shape[1:] != (SMPL.num_joints, 3) or len(joints) < 1:
        raise ValueError(f"BVH export needs joints (T, 22, 3) with T >= 1, got {joints.shape}")
    if not np.isfinite(joints).all():
        raise ValueError("joints contain NaN or infinite values")
    if not np.abs(joints).max() <= MAX_COORDINATE:
        raise ValueError(f"joints lie beyond {MAX_COORDINATE:g} m of the origin (not metres?)")
    if not MIN_FPS <= fps <= MAX_FPS:
        raise ValueError(f"fps must be positive, from {MIN_FPS:g} to {MAX_FPS:g}, got {fps}")
    directions = rest_directions(joints if fit_rest_pose else None)
    offsets = directions * SMPL.bone_lengths[:, None]
    return BvhMotion(
        joint_names=SMPL.joint_names,
        parents=SMPL.parents,
        offsets=offsets,
        root_positions=joints[:, 0].copy(),
        local_rotations=solve_rotations(joints, directions),
        fps=float(fps),
    )


def write_bvh(
    joints: np.ndarray,
    path: str | os.PathLike,
    fps: float = 20.0,
    units: str = "cm",
    fit_rest_pose: bool = True,
) -> BvhMotion:
    """Write joints (T, 22, 3) (metres, y-up) as a BVH file, atomically; returns the solved motion.

    ``units`` is the length unit inside the file ("cm", the usual one for BVH, or "m").
    The largest distance between the input joints and the file's forward kinematics is logged.
    """
    if units not in UNITS:
        raise ValueError(f"unknown BVH units {units!r}; use one of {sorted(UNITS)}")
    motion = motion_from_joints(joints, fps=fps, fit_rest_pose=fit_rest_pose)
    # Bone directions are reproduced exactly; positions differ only where the input's bone
    # lengths differ from the target skeleton's (generated motions vary a little).
    error = float(np.linalg.norm(motion.joints() - np.asarray(joints), axis=-1).max())
    logger.debug("BVH %s reproduces the joints to %.1f mm", path, error * 1000)
    text = motion.to_text(units=units)
    write_text_atomic(path, text)
    return motion
