"""Joint positions to BVH: the 22-joint SMPL skeleton, Y-up, with rotations solved by IK.

A BVH joint's rotation turns *all* of its children's offsets, so unlike the swing-only,
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

Conventions: world y-up, a person facing +Z has their left side at +X, positions in metres in
Python and in ``units`` in the file, 20 fps by default, Euler channels ``Zrotation Xrotation
Yrotation`` (intrinsic, R = Rz Rx Ry, as CMU and most tools write them), degrees, unwrapped in time
so curves never jump by 360.
"""

from __future__ import annotations

import logging
import os
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from dataset_tools.io import write_text_atomic
from dataset_tools.rotations import qbetween, quat_to_matrix
from dataset_tools.skeleton import SMPL

logger = logging.getLogger(__name__)

UNITS = {"m": 1.0, "cm": 100.0}
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
# Branch joint -> (left child, right child, middle child).
_BRANCHES = {0: (1, 2, 3), 9: (13, 14, 12)}
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
        return forward_kinematics(self.offsets, self.parents, self.root_positions,
                                  self.local_rotations)  # fmt: skip

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
                lines.extend([f"{pad}\tEnd Site", f"{pad}\t{{", f"{pad}\t\tOFFSET {vec(end)}",
                              f"{pad}\t}}"])  # fmt: skip
            lines.append(f"{pad}}}")

        emit(0, 0)
        euler = self.euler_degrees()
        lines += ["MOTION", f"Frames: {self.num_frames}", f"Frame Time: {1.0 / self.fps:.8f}"]
        root = self.root_positions * scale
        for frame in range(self.num_frames):
            values = np.concatenate([root[frame], euler[frame, file_order].reshape(-1)])
            lines.append(vec(values))
        return "\n".join(lines) + "\n"


def forward_kinematics(
    offsets: np.ndarray,
    parents: tuple[int, ...],
    root_positions: np.ndarray,
    local_rotations: np.ndarray,
) -> np.ndarray:
    """BVH forward kinematics: joints (T, J, 3) from offsets (J, 3), root positions (T, 3) and
    local rotations (T, J, 3, 3). A joint's global rotation turns its children's offsets
    (parents must precede children)."""
    num_frames, num_joints = local_rotations.shape[:2]
    positions = np.zeros((num_frames, num_joints, 3))
    global_rot = np.zeros_like(local_rotations)
    for joint, parent in enumerate(parents):
        if parent < 0:
            positions[:, joint] = root_positions
            global_rot[:, joint] = local_rotations[:, joint]
            continue
        positions[:, joint] = positions[:, parent] + global_rot[:, parent] @ offsets[joint]
        global_rot[:, joint] = global_rot[:, parent] @ local_rotations[:, joint]
    return positions


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
    if joint in (1, 2):  # hips: the knee bends backwards, so "forward" is minus the shin's bend
        knee, ankle, foot = joint + 3, joint + 6, joint + 9
        thigh, _ = _unit(joints[:, knee] - joints[:, joint])
        shin, _ = _unit(joints[:, ankle] - joints[:, knee])
        bend, sin_bend = _unit(-_perp(shin, thigh))
        cues.append((bend, np.clip(sin_bend / full, 0.0, 1.0)))
        toe, toe_norm = _unit(_perp(joints[:, foot] - joints[:, ankle], thigh))
        _, foot_len = _unit(joints[:, foot] - joints[:, ankle])
        cues.append((toe, np.clip(toe_norm / np.maximum(foot_len, _EPS) / full, 0.0, 1.0)))
    elif joint in (16, 17):  # shoulders: the elbow bends the forearm forwards in the T-pose
        elbow, wrist = joint + 2, joint + 4
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
    and the rotations. Raises ValueError on a wrong shape, non-finite values or fps <= 0.
    """
    joints = np.asarray(joints, dtype=np.float64)
    if joints.ndim != 3 or joints.shape[1:] != (SMPL.num_joints, 3) or len(joints) < 1:
        raise ValueError(f"BVH export needs joints (T, 22, 3) with T >= 1, got {joints.shape}")
    if not np.isfinite(joints).all():
        raise ValueError("joints contain NaN or infinite values")
    if not fps > 0:
        raise ValueError(f"fps must be positive, got {fps}")
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


def main(argv: list[str] | None = None) -> int:
    """``python -m t2m.export IN.npy OUT.bvh``: joints (T, 22, 3) or features (T, 263) to BVH."""
    import argparse
    import sys

    from t2m.render import _load_joints

    parser = argparse.ArgumentParser(
        prog="python -m t2m.export",
        description="Write joints (T, 22, 3) (metres, y-up) or HumanML3D features (T, 263) from "
        "a .npy file as a BVH file of the 22-joint SMPL skeleton.",
    )
    parser.add_argument("input", help=".npy joints (T, 22, 3) or features (T, 263)")
    parser.add_argument("output", help="output .bvh file")
    parser.add_argument("--fps", type=float, default=20.0, help="frames per second (default 20)")
    parser.add_argument("--units", choices=sorted(UNITS), default="cm", help="default cm")
    parser.add_argument("--template-rest-pose", action="store_true",
                        help="use the template hips / collars instead of fitting them")  # fmt: skip
    args = parser.parse_args(sys.argv[1:] if argv is None else argv)
    try:
        write_bvh(_load_joints(args.input), args.output, fps=args.fps, units=args.units,
                  fit_rest_pose=not args.template_rest_pose)  # fmt: skip
    except ValueError as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
