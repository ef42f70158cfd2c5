"""glTF export: read back with pygltflib (an independent reader) and our own node forward
kinematics of its animation, the GLB container, the command line and its errors."""

from __future__ import annotations

import json
import struct
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from dataset_tools.bvh import motion_from_joints
from dataset_tools.gltf import write_glb
from dataset_tools.skeleton import SMPL
from t2m import export

SHARED = Path(__file__).resolve().parents[1].parent / "shared"
REFERENCE_JOINTS = SHARED / "reference" / "humanml3d" / "new_joints" / "012314.npy"


def _reference_joints() -> np.ndarray:
    if not REFERENCE_JOINTS.exists():
        pytest.skip(f"real reference clip not found at {REFERENCE_JOINTS} (../shared is absent)")
    return np.load(REFERENCE_JOINTS).astype(np.float64)


U = 2.0**-24  # float32's unit roundoff: the file's keys, vertices and times


def _float32_bound(root_positions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """How far the file's float32 values can move each joint from the writer's forward
    kinematics: (T, 22) metres and (22,) radians of turn. The root's translation rounds by at
    most U |root|; a quaternion key rounds each component by at most U of itself, which turns its
    (renormalised) rotation by at most 2U; turns add along the chain and move a bone by its
    length times the angle. Node offsets are JSON float64 (exact); 1e-12 m: the float64 FK."""
    moved, turned = np.zeros((len(root_positions), 22)), np.zeros(22)
    for joint, parent in enumerate(SMPL.parents):
        if parent < 0:
            moved[:, joint], turned[joint] = U * np.linalg.norm(root_positions, axis=-1), 2 * U
        else:
            moved[:, joint] = moved[:, parent] + turned[parent] * SMPL.bone_lengths[joint]
            turned[joint] = turned[parent] + 2 * U
    return moved + 1e-12, turned


def _accessor(gltf, index: int) -> np.ndarray:
    """An accessor's values as a (count, width) array, read through pygltflib's objects."""
    accessor = gltf.accessors[index]
    view = gltf.bufferViews[accessor.bufferView]
    data = gltf.binary_blob()
    dtype = {5126: "<f4", 5123: "<u2", 5121: "u1"}[accessor.componentType]
    width = {"SCALAR": 1, "VEC3": 3, "VEC4": 4, "MAT4": 16}[accessor.type]
    start = (view.byteOffset or 0) + (accessor.byteOffset or 0)
    values = np.frombuffer(data, dtype, accessor.count * width, start)
    return values.reshape(accessor.count, width).astype(np.float64)


def _read_with_pygltflib(path: Path, with_rotations: bool = False) -> tuple:
    """Joint positions (T, 22, 3) in SMPL order computed from the file's nodes and animation
    (translation, rotation per node; global = parent global * T * R), the joint names, the key
    times, the pygltflib document and, ``with_rotations``, the global rotations (T, 22, 3, 3)."""
    pygltflib = pytest.importorskip("pygltflib", reason="pygltflib is in the test extra")
    gltf = pygltflib.GLTF2().load(str(path))
    skin = gltf.skins[0]
    joint_nodes = list(skin.joints)
    parent_of = {child: n for n, node in enumerate(gltf.nodes) for child in node.children or []}
    animation = gltf.animations[0]
    times = _accessor(gltf, animation.samplers[0].input)[:, 0]
    num_frames = len(times)
    local_t = {
        n: np.tile(gltf.nodes[n].translation or [0, 0, 0], (num_frames, 1)) for n in joint_nodes
    }
    local_r = {
        n: np.tile(gltf.nodes[n].rotation or [0, 0, 0, 1], (num_frames, 1)) for n in joint_nodes
    }
    for channel in animation.channels:
        sampler = animation.samplers[channel.sampler]
        assert sampler.interpolation == "LINEAR"
        values = _accessor(gltf, sampler.output)
        target = {"translation": local_t, "rotation": local_r}[channel.target.path]
        target[channel.target.node] = values
    positions, rotations = {}, {}
    order = []  # parents before children
    pending = [n for n in joint_nodes if n not in parent_of]
    while pending:
        node = pending.pop(0)
        order.append(node)
        pending += list(gltf.nodes[node].children or [])
    for node in order:
        local = Rotation.from_quat(local_r[node]).as_matrix()
        if node not in parent_of:
            positions[node], rotations[node] = local_t[node], local
        else:
            parent = parent_of[node]
            positions[node] = positions[parent] + np.einsum(
                "tij,tj->ti", rotations[parent], local_t[node]
            )
            rotations[node] = rotations[parent] @ local
    names = [gltf.nodes[n].name for n in joint_nodes]
    joints = np.stack([positions[n] for n in joint_nodes], axis=1)
    if with_rotations:
        return joints, names, times, gltf, np.stack([rotations[n] for n in joint_nodes], axis=1)
    return joints, names, times, gltf


def test_independent_reader_reproduces_the_joints(tmp_path):
    joints = _reference_joints()[:80]
    path = tmp_path / "clip.glb"
    write_glb(joints, path, fps=20.0)
    positions, names, times, gltf = _read_with_pygltflib(path)
    assert names == list(SMPL.joint_names)
    assert positions.shape == joints.shape
    # float32 key times: within U of themselves (observed 0.76 U); a wrong fps is off by 5%.
    exact_times = np.arange(80) / 20.0
    assert (np.abs(times - exact_times) <= U * exact_times).all()
    # The writer's FK (which test_export holds to the input) to float32 rounding: observed
    # 5.3e-8 m against bounds of 5e-8 (root) to 7.7e-7 m; a wrong key order or axis is off by cm.
    solved = motion_from_joints(joints)
    moved, _ = _float32_bound(solved.root_positions)
    assert (np.linalg.norm(positions - solved.joints(), axis=-1) <= moved).all()
    assert gltf.animations[0].extras["fps"] == 20.0
    # every rotation key is a unit quaternion, and consecutive keys are on the near side
    for channel in gltf.animations[0].channels:
        if channel.target.path == "rotation":
            values = _accessor(gltf, gltf.animations[0].samplers[channel.sampler].output)
            # Rounding each component by <= U of itself moves the norm by <= U, plus float64's
            # ~2e-16 (observed 0.68 U); a key that is not a rotation is off by far more.
            np.testing.assert_allclose(np.linalg.norm(values, axis=-1), 1.0, rtol=0, atol=U + 1e-15)
            assert (np.sum(values[1:] * values[:-1], axis=-1) >= 0).all()


def test_skinned_mesh_follows_the_skeleton(tmp_path):
    """The stick-figure mesh, skinned by the specification's formula (v' = G_j IBM_j v with the
    reader's global joint transforms), puts each bone's box centre half-way along its bone."""
    joints = _reference_joints()[:5]
    path = tmp_path / "clip.glb"
    write_glb(joints, path)
    positions, _, _, gltf, rotations = _read_with_pygltflib(path, with_rotations=True)
    primitive = gltf.meshes[0].primitives[0]
    vertices = _accessor(gltf, primitive.attributes.POSITION)
    bound = _accessor(gltf, primitive.attributes.JOINTS_0)[:, 0].astype(int)
    weights = _accessor(gltf, primitive.attributes.WEIGHTS_0)
    np.testing.assert_array_equal(weights.sum(axis=1), 1.0)  # (1, 0, 0, 0): exact
    inverse_bind = _accessor(gltf, gltf.skins[0].inverseBindMatrices).reshape(-1, 4, 4)
    inverse_bind = np.swapaxes(inverse_bind, 1, 2)  # column-major in the file
    frame = 3
    bind = np.einsum("vij,vj->vi", inverse_bind[bound, :3, :3], vertices)
    bind += inverse_bind[bound, :3, 3]
    skinned = np.einsum("vij,vj->vi", rotations[frame, bound], bind) + positions[frame, bound]
    centres = skinned.reshape(-1, 8, 3).mean(axis=1)
    children = [j for j, p in enumerate(SMPL.parents) if p >= 0]
    assert len(centres) == len(children) == 21
    # Midpoints of the writer's FK: the parent's float32 bound, its turn times the half bone,
    # and the float32 vertices and inverse binds (|.| <= 1 m: 2 sqrt(3) U m). Observed 4.8e-8 m
    # against >= 2.6e-7 m; a box bound to the wrong joint or a wrong bind is off by decimetres.
    solved = motion_from_joints(joints)
    fk, parents = solved.joints()[frame], [SMPL.parents[j] for j in children]
    expected = (fk[children] + fk[parents]) / 2
    moved, turned = _float32_bound(solved.root_positions[frame : frame + 1])
    bound = moved[0, parents] + turned[parents] * SMPL.bone_lengths[children] / 2
    bound += 2 * np.sqrt(3) * U
    assert (np.linalg.norm(centres - expected, axis=-1) <= bound).all()


def test_glb_container_layout(tmp_path):
    joints = _reference_joints()[:10]
    path = tmp_path / "clip.glb"
    write_glb(joints, path)
    data = path.read_bytes()
    magic, version, length = struct.unpack_from("<III", data)
    assert (magic, version, length) == (0x46546C67, 2, len(data))
    json_length, json_type = struct.unpack_from("<II", data, 12)
    assert json_type == 0x4E4F534A and json_length % 4 == 0
    document = json.loads(data[20 : 20 + json_length])
    bin_length, bin_type = struct.unpack_from("<II", data, 20 + json_length)
    assert bin_type == 0x004E4942 and bin_length % 4 == 0
    assert document["buffers"][0]["byteLength"] <= bin_length
    assert all(view["byteOffset"] % 4 == 0 for view in document["bufferViews"])
    position = document["meshes"][0]["primitives"][0]["attributes"]["POSITION"]
    assert "min" in document["accessors"][position] and "max" in document["accessors"][position]


def test_export_command_writes_glb_and_refuses_bad_input(tmp_path, capsys):
    joints = _reference_joints()[:30].astype(np.float32)
    source = tmp_path / "in.npy"
    np.save(source, joints)
    assert export.main([str(source), str(tmp_path / "out.glb"), "--fps", "10"]) == 0
    positions, _, times, _ = _read_with_pygltflib(tmp_path / "out.glb")
    assert abs(times[1] - 0.1) <= U * 0.1  # one float32 rounding
    solved = motion_from_joints(joints)  # what the command solves from the float32 file
    moved, _ = _float32_bound(solved.root_positions)
    assert (np.linalg.norm(positions - solved.joints(), axis=-1) <= moved).all()
    capsys.readouterr()
    assert export.main([str(source), str(tmp_path / "out.obj")]) == 2
    assert ".glb" in capsys.readouterr().err
    np.save(source, np.zeros((5, 21, 3), np.float32))
    assert export.main([str(source), str(tmp_path / "kit.glb")]) == 2
    assert "22-joint" in capsys.readouterr().err
    assert not (tmp_path / "kit.glb").exists()


def test_sample_glb_option_writes_a_glb_per_motion(tiny_run, tmp_path):
    from t2m import sample

    out = tmp_path / "out"
    argv = ["--text", "a person walks forward", "--num-samples", "2", "--length", "40"]
    argv += ["--checkpoints", str(tiny_run), "--out", str(out), "--render", "none", "--glb"]
    assert sample.main(argv) == 0
    for rep in range(2):
        # The tiny model's bone lengths drift from the target skeleton's; the file holds the
        # skeleton motion the BVH writer solves (target bone lengths, the same rotations).
        # The .npy holds the very array the .glb was written from: float32 rounding only.
        solved = motion_from_joints(np.load(out / f"sample00_rep{rep:02d}.npy"))
        positions, _, _, _ = _read_with_pygltflib(out / f"sample00_rep{rep:02d}.glb")
        moved, _ = _float32_bound(solved.root_positions)
        assert (np.linalg.norm(positions - solved.joints(), axis=-1) <= moved).all()
    assert "sample00_rep01.glb" in json.loads((out / "results.json").read_text())["files"]
