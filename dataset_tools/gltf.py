"""glTF 2.0 binary (``.glb``) export of a motion on the 22-joint SMPL skeleton.

Written by the glTF 2.0 specification (Khronos), with numpy only:

* the skeleton is a node hierarchy, one node per SMPL joint (named as in
  ``dataset_tools.skeleton.SMPL``), each with its rest translation from its parent (the BVH
  writer's offsets, the target bone lengths) and its local rotation;
* one animation, "motion", with a rotation channel per joint and a translation channel for the
  root (pelvis), LINEAR, keyed once per frame at ``frame / fps`` seconds (glTF has no frame rate;
  it is also stored in the animation's ``extras.fps``);
* a skin over those joints and a small stick-figure mesh (one thin box per bone, bound rigidly to
  the bone's parent joint) so that viewers that draw only meshes show the figure too.

Rotations are the BVH writer's (:func:`dataset_tools.bvh.motion_from_joints`: inverse
kinematics with its twist choice), so node forward kinematics reproduces the joints exactly where
their bone lengths are the target's (every HumanML3D-processed or generated motion, to well under
a centimetre). Quaternions are unit, x-y-z-w (glTF's order) and sign-continuous in time, so the
spherical interpolation between keys takes the short way.

Axes and units are glTF's and ours alike: metres, +Y up, a body facing +Z has its left side at
+X (right-handed). The file is written atomically.
"""

from __future__ import annotations

import json
import os
import struct
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from dataset_tools.bvh import BvhMotion, motion_from_joints
from dataset_tools.io import write_bytes_atomic

GLB_MAGIC = 0x46546C67  # "glTF"
CHUNK_JSON = 0x4E4F534A  # "JSON"
CHUNK_BIN = 0x004E4942  # "BIN\0"
# Accessor component types and buffer-view targets of the specification.
FLOAT, UNSIGNED_SHORT = 5126, 5123
ARRAY_BUFFER, ELEMENT_ARRAY_BUFFER = 34962, 34963
BONE_HALF_WIDTH = 0.015  # metres: half the side of each bone's box in the stick-figure mesh


def continuous_quaternions(quaternions: np.ndarray) -> np.ndarray:
    """Flip the sign of quaternions (T, ..., 4) where needed so each is in the same hemisphere
    as the previous frame's (q and -q are one rotation; interpolation needs the near one)."""
    result = np.array(quaternions, dtype=np.float64)
    for frame in range(1, len(result)):
        flip = np.sum(result[frame] * result[frame - 1], axis=-1) < 0
        result[frame][flip] *= -1
    return result


def _bone_boxes(rest_positions: np.ndarray, parents: tuple[int, ...]) -> tuple[np.ndarray, ...]:
    """The stick-figure mesh in the bind pose: one box of 8 corners per bone from each joint's
    parent to the joint, bound to the parent. Returns positions (V, 3) float32, joint indices
    (V, 4) uint16, weights (V, 4) float32 and triangle indices (3 * F,) uint16."""
    # 12 triangles of a box whose corners are (end, u sign, v sign) in binary order.
    faces = np.array([
        [0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
        [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3],
    ])  # fmt: skip
    positions, joints, indices = [], [], []
    for joint, parent in enumerate(parents):
        if parent < 0:
            continue
        start, end = rest_positions[parent], rest_positions[joint]
        axis = end - start
        helper = np.array([1.0, 0.0, 0.0]) if abs(axis[0]) < 0.9 * np.linalg.norm(axis) else None
        helper = np.array([0.0, 1.0, 0.0]) if helper is None else helper
        u = np.cross(axis, helper)
        u *= BONE_HALF_WIDTH / max(np.linalg.norm(u), 1e-12)
        v = np.cross(axis, u)
        v *= BONE_HALF_WIDTH / max(np.linalg.norm(v), 1e-12)
        base = len(positions)
        for corner in range(8):
            point = end if corner & 4 else start
            positions.append(point + (u if corner & 2 else -u) + (v if corner & 1 else -v))
            joints.append(parent)
        indices.extend((faces + base).reshape(-1))
    count = len(positions)
    joint_indices = np.zeros((count, 4), np.uint16)
    joint_indices[:, 0] = joints
    weights = np.zeros((count, 4), np.float32)
    weights[:, 0] = 1.0
    return (
        np.asarray(positions, np.float32),
        joint_indices,
        weights,
        np.asarray(indices, np.uint16),
    )


class _BinaryBuilder:
    """The BIN chunk and the bufferViews and accessors that point into it."""

    def __init__(self) -> None:
        self.data = bytearray()
        self.views: list[dict] = []
        self.accessors: list[dict] = []

    def add(
        self,
        array: np.ndarray,
        kind: str,
        target: int | None = None,
        bounds: bool = False,
    ) -> int:
        """Append ``array`` (little-endian, 4-byte aligned) as one bufferView and accessor of
        ``kind`` (SCALAR, VEC3, VEC4, MAT4); returns the accessor index."""
        component = {np.float32: FLOAT, np.uint16: UNSIGNED_SHORT}[array.dtype.type]
        width = {"SCALAR": 1, "VEC3": 3, "VEC4": 4, "MAT4": 16}[kind]
        flat = np.ascontiguousarray(array).reshape(-1, width)
        self.data.extend(b"\0" * (-len(self.data) % 4))
        view = {"buffer": 0, "byteOffset": len(self.data), "byteLength": flat.nbytes}
        if target is not None:
            view["target"] = target
        self.data.extend(flat.astype(flat.dtype.newbyteorder("<")).tobytes())
        self.views.append(view)
        accessor = {
            "bufferView": len(self.views) - 1,
            "componentType": component,
            "count": len(flat),
            "type": kind,
        }
        if bounds:
            accessor["min"] = [float(x) for x in flat.min(axis=0)]
            accessor["max"] = [float(x) for x in flat.max(axis=0)]
        self.accessors.append(accessor)
        return len(self.accessors) - 1


def gltf_document(motion: BvhMotion, name: str = "motion") -> tuple[dict, bytes]:
    """The glTF JSON document and its binary buffer for a solved skeleton motion."""
    num_joints = len(motion.parents)
    quaternions = Rotation.from_matrix(motion.local_rotations.reshape(-1, 3, 3)).as_quat()
    quaternions = continuous_quaternions(quaternions.reshape(motion.num_frames, num_joints, 4))
    binary = _BinaryBuilder()
    # 1. the skeleton: nodes 0..J-1 are the joints, in SMPL order; then the mesh's node
    nodes = _joint_nodes(motion, quaternions[0])
    root = motion.parents.index(-1)
    # 2. the stick-figure mesh bound to the skeleton
    mesh, skin = _skinned_mesh(motion, root, binary)
    nodes.append({"name": "stick_figure", "mesh": 0, "skin": 0})
    # 3. the animation: one rotation channel per joint and the root's translation
    animation = _animation(motion, quaternions, root, name, binary)
    document = {
        "asset": {"version": "2.0", "generator": "t2m-toolkit dataset_tools.gltf"},
        "scene": 0,
        "scenes": [{"name": name, "nodes": [root, num_joints]}],
        "nodes": nodes,
        "meshes": [mesh],
        "skins": [skin],
        "animations": [animation],
        "accessors": binary.accessors,
        "bufferViews": binary.views,
        "buffers": [{"byteLength": len(binary.data)}],
    }
    return document, bytes(binary.data)


def _joint_nodes(motion: BvhMotion, first_rotations: np.ndarray) -> list[dict]:
    """One node per joint, posed as the first frame (rotations (J, 4) x, y, z, w)."""
    parents = motion.parents
    nodes = []
    for joint in range(len(parents)):
        node = {
            "name": motion.joint_names[joint],
            "rotation": [float(x) for x in first_rotations[joint]],
            "translation": [
                float(x)
                for x in (motion.root_positions[0] if parents[joint] < 0 else motion.offsets[joint])
            ],
        }
        children = [child for child, parent in enumerate(parents) if parent == joint]
        if children:
            node["children"] = children
        nodes.append(node)
    return nodes


def _skinned_mesh(motion: BvhMotion, root: int, binary: _BinaryBuilder) -> tuple[dict, dict]:
    """The stick-figure mesh and its skin. Bind pose: every rotation zero, root at the origin,
    so each inverse bind matrix is a translation."""
    parents = motion.parents
    num_joints = len(parents)
    rest = np.zeros((num_joints, 3))
    for joint, parent in enumerate(parents):
        if parent >= 0:
            rest[joint] = rest[parent] + motion.offsets[joint]
    positions, joint_indices, weights, indices = _bone_boxes(rest, parents)
    inverse_bind = np.repeat(np.eye(4, dtype=np.float32)[None], num_joints, axis=0)
    inverse_bind[:, 3, :3] = -rest  # column-major storage: the translation is the last column
    mesh = {
        "name": "stick_figure",
        "primitives": [
            {
                "attributes": {
                    "POSITION": binary.add(positions, "VEC3", ARRAY_BUFFER, bounds=True),
                    "JOINTS_0": binary.add(joint_indices, "VEC4", ARRAY_BUFFER),
                    "WEIGHTS_0": binary.add(weights, "VEC4", ARRAY_BUFFER),
                },
                "indices": binary.add(indices, "SCALAR", ELEMENT_ARRAY_BUFFER),
            }
        ],
    }
    skin = {
        "name": "smpl",
        "joints": list(range(num_joints)),
        "skeleton": root,
        "inverseBindMatrices": binary.add(inverse_bind, "MAT4"),
    }
    return mesh, skin


def _animation(
    motion: BvhMotion, quaternions: np.ndarray, root: int, name: str, binary: _BinaryBuilder
) -> dict:
    """Linear samplers over the frame times: the root's translation, then every joint's
    rotation (quaternions (T, J, 4))."""
    times = (np.arange(motion.num_frames) / motion.fps).astype(np.float32)
    time_accessor = binary.add(times, "SCALAR", bounds=True)
    samplers, channels = [], []

    def channel(node: int, path: str, values: np.ndarray, kind: str) -> None:
        samplers.append(
            {
                "input": time_accessor,
                "output": binary.add(values.astype(np.float32), kind),
                "interpolation": "LINEAR",
            }
        )
        channels.append({"sampler": len(samplers) - 1, "target": {"node": node, "path": path}})

    channel(root, "translation", motion.root_positions, "VEC3")
    for joint in range(len(motion.parents)):
        channel(joint, "rotation", quaternions[:, joint], "VEC4")
    return {
        "name": name,
        "channels": channels,
        "samplers": samplers,
        "extras": {"fps": motion.fps, "frames": motion.num_frames},
    }


def glb_bytes(document: dict, binary: bytes) -> bytes:
    """The GLB container: a 12-byte header, the JSON chunk (padded with spaces) and the BIN
    chunk (padded with zeros), each 4-byte aligned."""
    text = json.dumps(document, separators=(",", ":")).encode("utf-8")
    text += b" " * (-len(text) % 4)
    binary += b"\0" * (-len(binary) % 4)
    total = 12 + 8 + len(text) + 8 + len(binary)
    return b"".join(
        [
            struct.pack("<III", GLB_MAGIC, 2, total),
            struct.pack("<II", len(text), CHUNK_JSON),
            text,
            struct.pack("<II", len(binary), CHUNK_BIN),
            binary,
        ]
    )


def write_glb(
    joints: np.ndarray,
    path: str | os.PathLike,
    fps: float = 20.0,
    fit_rest_pose: bool = True,
    name: str = "motion",
) -> BvhMotion:
    """Write joints (T, 22, 3) (metres, y-up) as an animated glTF binary, atomically; returns the
    solved skeleton motion (its ``joints()`` are what the file's node animation reproduces).

    Raises ValueError on a wrong shape, non-finite or farther values, or an fps out of range
    (:func:`dataset_tools.bvh.motion_from_joints`).
    """
    motion = motion_from_joints(joints, fps=fps, fit_rest_pose=fit_rest_pose)
    document, binary = gltf_document(motion, name)
    write_bytes_atomic(Path(path), glb_bytes(document, binary))
    return motion
