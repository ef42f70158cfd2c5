"""FBX export of a motion on the 22-joint SMPL skeleton, through Blender's own FBX exporter.

Needs ``bpy`` (Blender as a Python module: ``pip install -e .[blender]``); everything else in
this package works without it. :func:`build_armature` builds the skeleton in Blender directly
from the BVH writer's solved motion (:func:`dataset_tools.bvh.motion_from_joints`: the same rest
pose, rotations and twist choice as the BVH and glTF files), :func:`write_fbx` exports it.

The skeleton's convention (what retargeting tools and game engines expect):

* bone names are Mixamo's (:data:`MIXAMO_NAMES`: ``Hips``, ``Spine``, ``Spine1``, ``Spine2``,
  ``Neck``, ``Head``, ``LeftUpLeg``, ``LeftLeg``, ``LeftFoot``, ``LeftToeBase``,
  ``LeftShoulder``, ``LeftArm``, ``LeftForeArm``, ``LeftHand`` and the right twins), without
  the ``mixamorig:`` prefix, so Mixamo-style retargeting maps and humanoid auto-mapping take them;
* one bone per joint, its head at the joint and its tail at its child (the pelvis's at spine1,
  spine3's at the neck; the end joints' along their rest direction), in a T-pose facing +Z
  (y-up, metres) in the file; the armature object is called ``Armature``;
* in Blender (z-up) the body faces -Y; Blender's exporter writes the FBX y-up with the body facing
  +Z (``axis_up="Y"``, ``axis_forward="-Z"``, its defaults); bones point along their local +Y
  (``primary_bone_axis="Y"``), their local +Z points to the body's front in the rest pose (for
  the feet, which point forwards: up), no leaf bones are added;
* a stick-figure mesh (``Body``: the glTF file's, one thin box per bone) is skinned to it, so
  the file has a bind pose (the T-pose), which importers take as the rest pose;
* the animation is one action keyed at every frame, at times ``frame / fps`` from 0 (frames
  0 .. T - 1 of the scene it is built in; Blender's FBX importer puts them at 1 .. T), root translation on ``Hips``, rotations on every bone, baked without simplification.
"""

from __future__ import annotations

import contextlib
import io
import logging
import os
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from dataset_tools.bvh import _END_SITES, BvhMotion, motion_from_joints
from dataset_tools.gltf import _bone_boxes
from dataset_tools.io import atomic_output
from dataset_tools.skeleton import SMPL

logger = logging.getLogger(__name__)

BLENDER_EXTRA = "pip install -e .[blender]"
MIXAMO_NAMES: dict[str, str] = {
    "pelvis": "Hips",
    "left_hip": "LeftUpLeg",
    "right_hip": "RightUpLeg",
    "spine1": "Spine",
    "left_knee": "LeftLeg",
    "right_knee": "RightLeg",
    "spine2": "Spine1",
    "left_ankle": "LeftFoot",
    "right_ankle": "RightFoot",
    "spine3": "Spine2",
    "left_foot": "LeftToeBase",
    "right_foot": "RightToeBase",
    "neck": "Neck",
    "left_collar": "LeftShoulder",
    "right_collar": "RightShoulder",
    "head": "Head",
    "left_shoulder": "LeftArm",
    "right_shoulder": "RightArm",
    "left_elbow": "LeftForeArm",
    "right_elbow": "RightForeArm",
    "left_wrist": "LeftHand",
    "right_wrist": "RightHand",
}
"""SMPL joint name -> bone name (Mixamo's, without its ``mixamorig:`` prefix)."""
BONE_NAMES: tuple[str, ...] = tuple(MIXAMO_NAMES[name] for name in SMPL.joint_names)

# Our y-up frame (body facing +Z) -> Blender's z-up frame (body facing -Y), on column vectors:
# (x, y, z) -> (x, -z, y), as Blender's BVH and glTF importers turn y-up files.
TO_BLENDER = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
_BODY_FRONT = np.array([0.0, 0.0, 1.0])  # ours
_UP = np.array([0.0, 1.0, 0.0])  # ours


def require_bpy():
    """``bpy``, or a one-line ValueError naming the extra that installs it."""
    try:
        import bpy
    except ImportError:
        raise ValueError(
            f"FBX export needs Blender as a Python module (bpy): {BLENDER_EXTRA}"
        ) from None
    return bpy


def _children(parents: tuple[int, ...]) -> dict[int, list[int]]:
    children: dict[int, list[int]] = {joint: [] for joint in range(len(parents))}
    for joint, parent in enumerate(parents):
        if parent >= 0:
            children[parent].append(joint)
    return children


def rest_bones(motion: BvhMotion) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The rest pose in Blender's frame: heads (J, 3), tails (J, 3) and rest rotations
    (J, 3, 3) of the bones (columns: the bone's local x, y = along the bone, z = the front)."""
    parents = motion.parents
    children = _children(parents)
    heads = np.zeros((len(parents), 3))
    for joint, parent in enumerate(parents):
        if parent >= 0:
            heads[joint] = heads[parent] + motion.offsets[joint]
    tails = np.empty_like(heads)
    rotations = np.empty((len(parents), 3, 3))
    middle = {SMPL.joint("pelvis"): SMPL.joint("spine1"), SMPL.joint("spine3"): SMPL.joint("neck")}
    for joint in range(len(parents)):
        kids = children[joint]
        if kids:
            tails[joint] = heads[middle.get(joint, kids[0])]
        else:  # an end joint: its bone goes on along the bone that ends there
            direction = motion.offsets[joint] / np.linalg.norm(motion.offsets[joint])
            tails[joint] = heads[joint] + direction * _END_SITES.get(joint, 0.05)
        along = tails[joint] - heads[joint]
        along /= np.linalg.norm(along)
        front = _BODY_FRONT if abs(along @ _BODY_FRONT) < 0.9 else _UP
        front = front - (front @ along) * along
        front /= np.linalg.norm(front)
        rotations[joint] = np.stack([np.cross(along, front), along, front], axis=-1)
    to_blender = lambda points: points @ TO_BLENDER.T  # noqa: E731
    return to_blender(heads), to_blender(tails), TO_BLENDER @ rotations


def pose_channels(motion: BvhMotion) -> tuple[np.ndarray, np.ndarray]:
    """Per frame and bone, Blender's pose channels relative to the rest pose: locations (T, J, 3)
    and unit quaternions (T, J, 4) (w, x, y, z), sign-continuous in time."""
    heads, _, rest = rest_bones(motion)
    parents = motion.parents
    num_frames, num_joints = motion.num_frames, len(parents)
    global_rotations = np.empty((num_frames, num_joints, 3, 3))
    for joint, parent in enumerate(parents):
        local = motion.local_rotations[:, joint]
        global_rotations[:, joint] = local if parent < 0 else global_rotations[:, parent] @ local
    positions = motion.joints() @ TO_BLENDER.T  # (T, J, 3)
    # Each bone's posed armature-space matrix: rotation (world rotation of the joint, in
    # Blender's frame) @ its rest rotation, at the joint's position.
    posed = np.zeros((num_frames, num_joints, 4, 4))
    posed[..., :3, :3] = TO_BLENDER @ global_rotations @ TO_BLENDER.T @ rest
    posed[..., :3, 3] = positions
    posed[..., 3, 3] = 1.0
    rest_matrix = np.zeros((num_joints, 4, 4))
    rest_matrix[:, :3, :3] = rest
    rest_matrix[:, :3, 3] = heads
    rest_matrix[:, 3, 3] = 1.0
    # Blender: posed = parent_posed @ parent_rest^-1 @ rest @ basis, so
    # basis = rest^-1 @ parent_rest @ parent_posed^-1 @ posed (the root: rest^-1 @ posed).
    basis = np.empty_like(posed)
    for joint, parent in enumerate(parents):
        relative = posed[:, joint]
        if parent >= 0:
            relative = rest_matrix[parent] @ np.linalg.inv(posed[:, parent]) @ relative
        basis[:, joint] = np.linalg.inv(rest_matrix[joint]) @ relative
    quaternions = Rotation.from_matrix(basis[..., :3, :3].reshape(-1, 3, 3)).as_quat()
    quaternions = quaternions.reshape(num_frames, num_joints, 4)[..., [3, 0, 1, 2]]
    flips = np.cumsum(np.sum(quaternions[1:] * quaternions[:-1], axis=-1) < 0, axis=0) % 2
    quaternions[1:] *= np.where(flips == 1, -1.0, 1.0)[..., None]
    return basis[..., :3, 3], quaternions


def build_armature(motion: BvhMotion, name: str = "Armature"):
    """Build the motion as an animated armature object in Blender's current (emptied) scene;
    returns the object. Needs ``bpy``."""
    bpy = require_bpy()
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    scene.render.fps = max(1, round(motion.fps))
    scene.render.fps_base = scene.render.fps / motion.fps
    scene.frame_start, scene.frame_end = 0, motion.num_frames - 1
    heads, tails, rest = rest_bones(motion)
    data = bpy.data.armatures.new(name)
    armature = bpy.data.objects.new(name, data)
    scene.collection.objects.link(armature)
    bpy.context.view_layer.objects.active = armature
    bpy.ops.object.mode_set(mode="EDIT")
    bones = []
    for joint, parent in enumerate(motion.parents):
        bone = data.edit_bones.new(BONE_NAMES[joint])
        bone.head, bone.tail = heads[joint].tolist(), tails[joint].tolist()
        bone.align_roll(rest[joint][:, 2].tolist())  # local +Z to the body's front
        if parent >= 0:
            bone.parent = bones[parent]
            bone.use_connect = False
        bones.append(bone)
    bpy.ops.object.mode_set(mode="OBJECT")
    locations, quaternions = pose_channels(motion)
    action = bpy.data.actions.new(f"{name}Action")
    armature.animation_data_create().action = action
    # FBX key times frame / fps from 0 (Blender's importer puts them at frames 1 .. T)
    frames = np.arange(motion.num_frames, dtype=np.float64)
    for joint, bone_name in enumerate(BONE_NAMES):
        armature.pose.bones[bone_name].rotation_mode = "QUATERNION"
        path = f'pose.bones["{bone_name}"]'
        channels = [("rotation_quaternion", quaternions[:, joint])]
        if motion.parents[joint] < 0:
            channels.append(("location", locations[:, joint]))
        for prop, values in channels:
            for index in range(values.shape[1]):
                curve = action.fcurves.new(f"{path}.{prop}", index=index, action_group=bone_name)
                curve.keyframe_points.add(motion.num_frames)
                keys = np.stack([frames, values[:, index]], axis=-1).reshape(-1)
                curve.keyframe_points.foreach_set("co", keys)
                curve.keyframe_points.foreach_set(
                    "interpolation", [1] * motion.num_frames
                )  # LINEAR
                curve.update()
    return armature


def add_stick_figure(armature, motion: BvhMotion, name: str = "Body"):
    """Skin the glTF writer's stick figure (one thin box per bone, bound rigidly to the bone's
    parent) to the armature; returns the mesh object. A skinned mesh gives the FBX file its bind
    pose, which importers take as the skeleton's rest pose (without one they take the pose of
    the frame the file was written at)."""
    bpy = require_bpy()
    heads, _, _ = rest_bones(motion)
    positions, joints, _, triangles = _bone_boxes(heads @ TO_BLENDER, motion.parents)
    positions = positions.astype(np.float64) @ TO_BLENDER.T
    mesh = bpy.data.meshes.new(name)
    mesh.from_pydata(positions.tolist(), [], triangles.reshape(-1, 3).tolist())
    body = bpy.data.objects.new(name, mesh)
    bpy.context.scene.collection.objects.link(body)
    body.parent = armature
    for joint, bone_name in enumerate(BONE_NAMES):
        vertices = np.flatnonzero(joints[:, 0] == joint).tolist()
        if vertices:
            body.vertex_groups.new(name=bone_name).add(vertices, 1.0, "REPLACE")
    body.modifiers.new("Armature", "ARMATURE").object = armature
    return body


def write_fbx(
    joints: np.ndarray,
    path: str | os.PathLike,
    fps: float = 20.0,
    fit_rest_pose: bool = True,
) -> BvhMotion:
    """Write joints (T, 22, 3) (metres, y-up) as an FBX file (atomically) through Blender's FBX
    exporter; returns the solved motion. Blender's session is reset to an empty scene first
    (bpy has one session per process). ValueError without ``bpy`` (naming the extra) and for
    what :func:`dataset_tools.bvh.motion_from_joints` refuses."""
    bpy = require_bpy()
    motion = motion_from_joints(joints, fps=fps, fit_rest_pose=fit_rest_pose)
    armature = build_armature(motion)
    body = add_stick_figure(armature, motion)
    armature.select_set(True)
    body.select_set(True)
    # the exporter prints its progress: kept for the debug log, out of the command's output
    with atomic_output(Path(path)) as temp, contextlib.redirect_stdout(io.StringIO()) as said:
        result = bpy.ops.export_scene.fbx(
            filepath=str(temp),
            use_selection=True,
            object_types={"ARMATURE", "MESH"},
            add_leaf_bones=False,
            primary_bone_axis="Y",
            secondary_bone_axis="X",
            axis_forward="-Z",
            axis_up="Y",
            bake_anim=True,
            bake_anim_use_all_bones=True,
            bake_anim_use_nla_strips=False,
            bake_anim_use_all_actions=False,
            bake_anim_force_startend_keying=True,
            bake_anim_step=1.0,
            bake_anim_simplify_factor=0.0,
        )
        if "FINISHED" not in result:
            raise ValueError(f"Blender's FBX exporter did not finish ({result})")
    logger.debug("Blender's FBX exporter: %s", said.getvalue().strip())
    return motion
