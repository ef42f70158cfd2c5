"""SMPL-H body parameters in AMASS's layout, fitted to joints (T, 22, 3).

What is written (an ``.npz`` that :func:`dataset_tools.sources.amass.load_amass`, i.e.
``dataset_tools build --source amass``, reads back):

* ``poses`` (T, 156): one axis-angle rotation (radians) per SMPL-H joint relative to its parent,
  in SMPL-H's order (22 body joints, then 15 left-hand and 15 right-hand joints); the hands stay
  at rest (zeros), the wrists keep their forearm's rotation (zero), since 22 joints say nothing
  about either;
* ``trans`` (T, 3): the body's translation, so that the pelvis is at ``rest_joints[0] + trans``;
* ``betas`` (16,) zeros, ``gender`` "neutral", ``mocap_framerate`` (the motion's frame rate) and
  ``dmpls`` (T, 8) zeros, as in AMASS;
* ``rest_joints`` (52, 3): the rest (T-) pose the rotations are relative to, in the body model's
  frame (not an AMASS key; readers of AMASS ignore it), and ``skeleton`` = "t2m-smplh-fit".

Frames. The body model's own frame is y-up with the body facing +Z and its left side at +X, the
frame of our BVH skeleton's rest pose; AMASS's world is z-up (:func:`y_up_to_z_up` of ours), so
the root's rotation carries the body from its frame into the z-up world, as in every AMASS file.

Rotations come from :func:`dataset_tools.bvh.motion_from_joints` (the BVH writer's inverse
kinematics and twist choice): the body joints' rotations are the BVH file's, and forward
kinematics of the parameters over ``rest_joints`` (:func:`dataset_tools.sources.amass.smplh_joints`)
gives the BVH skeleton's joints, which are the input joints wherever the input is rigid on the
target skeleton. The rest pose is the BVH skeleton's T-pose (target bone lengths of
``dataset_tools.skeleton.SMPL``, hips and collars fitted to the motion), with the pelvis at
:data:`REST_PELVIS`, near the SMPL templates' pelvis at ``betas`` 0, so that ``trans`` places a
real body near the motion too (shifted by the difference of its own rest pelvis). A real SMPL-H body's own
rest pose bends its bones a few degrees away from this T-pose, so on such a body the pose is the
same up to those degrees; exact reproduction needs the rest joints, which
:func:`skeleton_body_model` turns into a body model file the AMASS reader takes.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from dataset_tools.bvh import BvhMotion, motion_from_joints
from dataset_tools.io import atomic_write
from dataset_tools.rotations import y_up_to_z_up, z_up_to_y_up
from dataset_tools.skeleton import SMPL

NUM_JOINTS = 52
NUM_BETAS = 16
SKELETON_TAG = "t2m-smplh-fit"
_FINGERS = ("index", "middle", "pinky", "ring", "thumb")
JOINT_NAMES: tuple[str, ...] = SMPL.joint_names + tuple(
    f"{side}_{finger}{segment}"
    for side in ("left", "right")
    for finger in _FINGERS
    for segment in (1, 2, 3)
)
"""SMPL-H's 52 joints: the 22 of SMPL's body, then each hand's 15 (5 fingers of 3 joints)."""
PARENTS: tuple[int, ...] = SMPL.parents + tuple(
    wrist if segment == 1 else 22 + 15 * hand + 3 * finger + segment - 2
    for hand, wrist in enumerate((SMPL.joint("left_wrist"), SMPL.joint("right_wrist")))
    for finger in range(5)
    for segment in (1, 2, 3)
)
REST_PELVIS = np.array([0.0, -0.223, 0.028])
"""Rest position (metres, body model frame) of the pelvis, chosen near the SMPL templates' pelvis
at ``betas`` 0 (not checked against a model file: none is in this repository)."""

# A plausible hand at rest (not SMPL-H's own): offsets (metres) of each finger's first joint from
# the left wrist and the direction of its segments, palm down, thumb forward (+Z); the right hand
# is its mirror image in x.
_FINGER_BASES = {
    "index": (0.085, 0.0, 0.025),
    "middle": (0.09, 0.0, 0.005),
    "pinky": (0.075, 0.0, -0.035),
    "ring": (0.085, 0.0, -0.015),
    "thumb": (0.025, -0.01, 0.03),
}
_SEGMENT = {finger: (0.03, 0.0, 0.0) for finger in _FINGERS} | {"thumb": (0.022, 0.0, 0.022)}

# y-up -> z-up as a matrix acting on column vectors (the inverse of z_up_to_y_up).
_TO_Z_UP = y_up_to_z_up(np.eye(3)).T


@dataclass(frozen=True)
class SmplhParameters:
    """An AMASS-style SMPL-H motion.

    Attributes:
        poses: (T, 156) axis-angle rotations (radians) of the 52 joints relative to their parents.
        trans: (T, 3) translation (metres, z-up world): the pelvis is at rest_joints[0] + trans.
        betas: (16,) shape coefficients (zeros: the shape is in rest_joints).
        gender: "neutral".
        fps: frames per second (``mocap_framerate``).
        rest_joints: (52, 3) rest joints (metres, the body model's y-up frame).
    """

    poses: np.ndarray
    trans: np.ndarray
    betas: np.ndarray
    gender: str
    fps: float
    rest_joints: np.ndarray

    @property
    def num_frames(self) -> int:
        return len(self.poses)

    def arrays(self) -> dict[str, np.ndarray]:
        """The .npz members (AMASS's keys, then ``rest_joints`` and ``skeleton``)."""
        return {
            "poses": self.poses,
            "trans": self.trans,
            "betas": self.betas,
            "gender": np.array(self.gender),
            "mocap_framerate": np.array(self.fps),
            "dmpls": np.zeros((self.num_frames, 8)),
            "rest_joints": self.rest_joints,
            "skeleton": np.array(SKELETON_TAG),
        }


def rest_joints_from_offsets(offsets: np.ndarray) -> np.ndarray:
    """The 52 SMPL-H rest joints (52, 3) (body model frame, metres) of a 22-joint skeleton whose
    rest offsets (22, 3) are ``offsets`` (a :class:`BvhMotion`'s), pelvis at :data:`REST_PELVIS`,
    with the plausible hands of this module."""
    offsets = np.asarray(offsets, dtype=np.float64)
    if offsets.shape != (SMPL.num_joints, 3):
        raise ValueError(f"offsets must be ({SMPL.num_joints}, 3), got {offsets.shape}")
    joints = np.zeros((NUM_JOINTS, 3))
    joints[0] = REST_PELVIS
    for joint in range(1, SMPL.num_joints):
        joints[joint] = joints[PARENTS[joint]] + offsets[joint]
    for joint in range(SMPL.num_joints, NUM_JOINTS):
        side, finger_segment = JOINT_NAMES[joint].split("_")
        finger, segment = finger_segment[:-1], finger_segment[-1]
        step = np.array(_FINGER_BASES[finger] if segment == "1" else _SEGMENT[finger])
        if side == "right":
            step[0] = -step[0]
        joints[joint] = joints[PARENTS[joint]] + step
    return joints


def parameters_from_motion(motion: BvhMotion) -> SmplhParameters:
    """The SMPL-H parameters of a solved BVH motion (its rotations, its offsets as the rest pose)."""
    num_frames = motion.num_frames
    local = np.broadcast_to(np.eye(3), (num_frames, NUM_JOINTS, 3, 3)).copy()
    local[:, : SMPL.num_joints] = motion.local_rotations
    local[:, 0] = _TO_Z_UP @ motion.local_rotations[:, 0]  # into AMASS's z-up world
    poses = Rotation.from_matrix(local.reshape(-1, 3, 3)).as_rotvec()
    rest = rest_joints_from_offsets(motion.offsets)
    trans = y_up_to_z_up(motion.root_positions) - rest[0]
    return SmplhParameters(
        poses=poses.reshape(num_frames, 3 * NUM_JOINTS),
        trans=trans,
        betas=np.zeros(NUM_BETAS),
        gender="neutral",
        fps=float(motion.fps),
        rest_joints=rest,
    )


def fit_smplh(joints: np.ndarray, fps: float = 20.0, fit_rest_pose: bool = True) -> SmplhParameters:
    """SMPL-H parameters of joints (T, 22, 3) (metres, y-up) at ``fps``: the BVH writer's inverse
    kinematics (see the module docstring). Raises ValueError as
    :func:`dataset_tools.bvh.motion_from_joints` does."""
    return parameters_from_motion(motion_from_joints(joints, fps=fps, fit_rest_pose=fit_rest_pose))


def smplh_forward(parameters: SmplhParameters) -> np.ndarray:
    """Joints (T, 52, 3) of the parameters over their own rest joints, y-up metres (what the
    AMASS reader gives for the file with :func:`skeleton_body_model`)."""
    from dataset_tools.sources.amass import smplh_joints

    positions = smplh_joints(
        parameters.poses, parameters.trans, parameters.rest_joints, np.asarray(PARENTS)
    )
    return z_up_to_y_up(positions)


def write_smplh(parameters: SmplhParameters, path: str | os.PathLike) -> Path:
    """Write the parameters as an uncompressed .npz file, atomically."""
    return atomic_write(path, lambda file: np.savez(file, **parameters.arrays()))


def skeleton_body_model(rest_joints: np.ndarray) -> dict[str, np.ndarray]:
    """The members of an SMPL-H-style ``model.npz`` whose rest joints are ``rest_joints`` (52, 3)
    (body model frame) and which has no surface: 52 vertices at the joints, an identity joint
    regressor, no shape directions. Saved as ``DIR/neutral/model.npz``, it makes
    ``dataset_tools build --source amass --body-model DIR`` reproduce the fitted skeleton."""
    rest_joints = np.asarray(rest_joints, dtype=np.float64)
    if rest_joints.shape != (NUM_JOINTS, 3):
        raise ValueError(f"rest joints must be ({NUM_JOINTS}, 3), got {rest_joints.shape}")
    kintree = np.stack([np.asarray(PARENTS), np.arange(NUM_JOINTS)]).astype(np.int64)
    kintree[0, 0] = 2**32 - 1  # the released files' root marker
    return {
        "v_template": rest_joints,
        "shapedirs": np.zeros((NUM_JOINTS, 3, NUM_BETAS)),
        "J_regressor": np.eye(NUM_JOINTS),
        "kintree_table": kintree,
    }
