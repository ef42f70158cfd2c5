"""Blender as the client: our BVH, glTF (.glb) and FBX files imported by Blender's own importers
(``bpy`` from PyPI: ``pip install -e .[blender]``; CI installs it), every bone head at every
frame compared with our joints within 1 mm.

Blender is z-up; its BVH and glTF importers turn y-up files by (x, y, z) -> (x, -z, y)
(:data:`dataset_tools.fbx.TO_BLENDER`), and so does our FBX armature. BVH is written in metres
here (the importer's scale is then 1). Blender's BVH importer starts at frame 1 and its FBX
importer puts our key at time 0 at frame 1; its glTF importer keys time 0 at frame 0.

Generated motions are the tiny model's: what the writers encode is the BVH skeleton's forward
kinematics of the joints (:func:`dataset_tools.bvh.motion_from_joints`), which Blender must show
within 1 mm always; the ``.npy`` joints agree with it only where the generated motion is rigid on
the target skeleton, checked where it is (a skip says by how much it is not).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from dataset_tools.bvh import motion_from_joints, write_bvh
from dataset_tools.fbx import BONE_NAMES, TO_BLENDER, write_fbx
from dataset_tools.gltf import write_glb
from dataset_tools.skeleton import SMPL

try:
    import bpy
except ImportError:  # the optional `blender` extra; CI installs it
    bpy = None
needs_bpy = pytest.mark.skipif(
    bpy is None, reason="Blender as a Python module is not installed (pip install -e .[blender])"
)

REFERENCE = Path(__file__).resolve().parents[1].parent / "shared" / "reference" / "humanml3d"
TOLERANCE = 1e-3  # metres
FRAMES = 60  # of the real clip: enough to turn and step, few enough to keep the test quick


def _empty_scene(fps: float = 20.0) -> None:
    bpy.ops.wm.read_factory_settings(use_empty=True)
    bpy.context.scene.render.fps = round(fps)
    bpy.context.scene.render.fps_base = 1.0


def _armature():
    armatures = [obj for obj in bpy.data.objects if obj.type == "ARMATURE"]
    assert len(armatures) == 1, [obj.name for obj in bpy.data.objects]
    return armatures[0]


def _bone_heads(names: tuple[str, ...], num_frames: int, first_frame: int) -> np.ndarray:
    """World positions (T, J, 3) of the named bones' heads at frames first_frame .. + T - 1,
    turned back into our y-up frame."""
    armature = _armature()
    scene = bpy.context.scene
    heads = np.empty((num_frames, len(names), 3))
    for frame in range(num_frames):
        scene.frame_set(first_frame + frame)
        world = np.array(armature.matrix_world)
        for index, name in enumerate(names):
            head = np.array(armature.pose.bones[name].head)
            heads[frame, index] = world[:3, :3] @ head + world[:3, 3]
    return heads @ TO_BLENDER  # row vectors: TO_BLENDER.T applied to each


def _import(path: Path) -> tuple[tuple[str, ...], int]:
    """Import a file with Blender's importer; (bone names in SMPL joint order, first frame)."""
    _empty_scene()
    suffix = path.suffix
    if suffix == ".bvh":
        bpy.ops.import_anim.bvh(
            filepath=str(path),
            global_scale=1.0,
            rotate_mode="NATIVE",
            axis_forward="-Z",
            axis_up="Y",
            use_fps_scale=False,
            update_scene_fps=False,
            update_scene_duration=True,
        )
        return SMPL.joint_names, 1
    if suffix == ".glb":
        bpy.ops.import_scene.gltf(filepath=str(path))
        return SMPL.joint_names, 0
    bpy.ops.import_scene.fbx(filepath=str(path), automatic_bone_orientation=False)
    return BONE_NAMES, 1


def _write(kind: str, joints: np.ndarray, folder: Path) -> Path:
    path = folder / f"motion.{kind}"
    if kind == "bvh":
        write_bvh(joints, path, units="m")
    elif kind == "glb":
        write_glb(joints, path)
    else:
        write_fbx(joints, path)
    return path


def _blender_joints(kind: str, joints: np.ndarray, folder: Path) -> np.ndarray:
    names, first = _import(_write(kind, joints, folder))
    return _bone_heads(names, len(joints), first)


def _error(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.linalg.norm(a - b, axis=-1).max())


@pytest.fixture(scope="module")
def real_clip() -> np.ndarray:
    if not REFERENCE.is_dir():
        pytest.skip(f"reference HumanML3D clips absent ({REFERENCE})")
    return np.load(REFERENCE / "new_joints" / "012314.npy")[:FRAMES].astype(np.float64)


@needs_bpy
@pytest.mark.parametrize("kind", ["bvh", "glb", "fbx"])
def test_real_clip_in_blender_is_our_joints(kind, real_clip, tmp_path):
    shown = _blender_joints(kind, real_clip, tmp_path)
    # a real clip is rigid on the target skeleton: Blender shows the .npy joints themselves
    assert _error(shown, real_clip) < TOLERANCE, kind
    assert _error(shown, motion_from_joints(real_clip).joints()) < TOLERANCE, kind
    # and the clip moves: a wrong frame offset or axis could not hide under 1 mm
    assert _error(real_clip[1:], real_clip[:-1]) > 0.01


@needs_bpy
def test_fbx_skeleton_names_and_orientation(real_clip, tmp_path):
    """The FBX armature as Blender reads it: Mixamo bone names and hierarchy, bones along +Y
    towards their child, +Z to the body's front in the rest pose, the body facing -Y (Blender's
    front view) and standing on z = 0 in the T-pose."""
    _import(_write("fbx", real_clip, tmp_path))
    armature = _armature()
    bones = armature.data.bones
    assert sorted(bone.name for bone in bones) == sorted(BONE_NAMES)
    for joint, parent in enumerate(SMPL.parents):
        bone = bones[BONE_NAMES[joint]]
        assert (bone.parent.name if bone.parent else None) == (
            BONE_NAMES[parent] if parent >= 0 else None
        )
    rest = {name: np.array(bones[name].matrix_local) for name in BONE_NAMES}
    # the left arm goes out along +X, the shin down, the foot forward (-Y in Blender)
    assert rest["LeftArm"][:3, 1] @ np.array([1.0, 0.0, 0.0]) > 0.99
    assert rest["LeftLeg"][:3, 1] @ np.array([0.0, 0.0, -1.0]) > 0.99
    assert rest["LeftFoot"][:3, 1] @ np.array([0.0, -1.0, 0.0]) > 0.9
    assert rest["Spine"][:3, 2] @ np.array([0.0, -1.0, 0.0]) > 0.99  # +Z to the front
    assert rest["LeftToeBase"][:3, 2] @ np.array([0.0, 0.0, 1.0]) > 0.99  # a foot's +Z is up


@pytest.fixture(scope="module")
def generated(pipe) -> list[np.ndarray]:
    """Joints of two motions of the tiny model (generated, not captured)."""
    motions = pipe.generate(["a person walks forward", "a person jumps"], lengths=[40, 32], seed=0)
    return [row[0].joints.astype(np.float64) for row in motions]


@needs_bpy
@pytest.mark.parametrize("kind", ["bvh", "glb", "fbx"])
def test_generated_motion_in_blender_is_what_the_writer_encodes(kind, generated, tmp_path):
    for index, joints in enumerate(generated):
        folder = tmp_path / str(index)
        folder.mkdir()
        shown = _blender_joints(kind, joints, folder)
        assert _error(shown, motion_from_joints(joints).joints()) < TOLERANCE, (kind, index)


@needs_bpy
def test_generated_motion_in_blender_is_the_npy_joints(generated, tmp_path):
    """The .npy joints themselves, where the generated motion is rigid on the target skeleton."""
    parents = np.asarray(SMPL.parents[1:])
    stretch = max(
        float(
            np.abs(
                np.linalg.norm(joints[:, 1:] - joints[:, parents], axis=-1) - SMPL.bone_lengths[1:]
            ).max()
        )
        for joints in generated
    )
    if stretch > 1e-4:
        pytest.skip(
            f"the generated joints are not rigid on the target skeleton (bones off by up to "
            f"{stretch * 1000:.0f} mm), so no file can show them within 1 mm"
        )
    for kind in ("bvh", "glb", "fbx"):
        for index, joints in enumerate(generated):
            folder = tmp_path / f"{kind}{index}"
            folder.mkdir()
            assert _error(_blender_joints(kind, joints, folder), joints) < TOLERANCE, kind


def _docs_recipe() -> str:
    """The Python block of docs/export.md's "On an SMPL body in Blender"."""
    page = (Path(__file__).resolve().parents[1] / "docs" / "export.md").read_text()
    section = page.split("### On an SMPL body in Blender", 1)[1]
    return section.split("```python\n", 1)[1].split("```", 1)[0]


@needs_bpy
def test_docs_recipe_puts_the_smplh_parameters_on_an_armature(real_clip, tmp_path):
    """The page's recipe, run on a stand-in SMPL-H armature (bones at a file's rest joints,
    arbitrary rolls, upright in Blender), gives the file's forward kinematics."""
    from dataset_tools.rotations import y_up_to_z_up
    from dataset_tools.smplh import JOINT_NAMES, PARENTS, fit_smplh, smplh_forward, write_smplh

    joints = real_clip[:12]
    parameters = fit_smplh(joints)
    path = write_smplh(parameters, tmp_path / "clip_smpl.npz")
    _empty_scene()
    data = bpy.data.armatures.new("SMPLH")
    armature = bpy.data.objects.new("SMPLH", data)
    bpy.context.scene.collection.objects.link(armature)
    bpy.context.view_layer.objects.active = armature
    bpy.ops.object.mode_set(mode="EDIT")
    heads = parameters.rest_joints @ TO_BLENDER.T  # the body upright in Blender
    rng = np.random.default_rng(0)
    bones = []
    for joint, parent in enumerate(PARENTS):
        bone = data.edit_bones.new(JOINT_NAMES[joint])
        bone.head = heads[joint].tolist()
        bone.tail = (heads[joint] + rng.normal(0.0, 1.0, 3) * 0.05 + [0, 0, 0.02]).tolist()
        bone.roll = float(rng.uniform(-np.pi, np.pi))
        if parent >= 0:
            bone.parent = bones[parent]
        bones.append(bone)
    bpy.ops.object.mode_set(mode="OBJECT")
    recipe = _docs_recipe().replace("/path/to/sample00_rep00_smpl.npz", str(path))
    exec(compile(recipe, "docs/export.md", "exec"), {"__name__": "recipe"})
    shown = _bone_heads(JOINT_NAMES, len(joints), 1) @ TO_BLENDER.T  # Blender's world
    # Blender's world is AMASS's z-up world
    expected = y_up_to_z_up(smplh_forward(parameters))
    assert _error(shown, expected) < TOLERANCE
    assert _error(expected[1:], expected[:-1]) > 0.005  # it moves


def test_fbx_without_bpy_is_one_line_naming_the_extra(tmp_path, capsys, monkeypatch):
    """Without bpy, ``t2m.export OUT.fbx`` stops before reading anything, in one line."""
    from t2m.export import main

    monkeypatch.setitem(sys.modules, "bpy", None)  # import bpy now raises ImportError
    source = tmp_path / "clip.npy"
    np.save(source, np.zeros((3, 22, 3)))
    assert main([str(source), str(tmp_path / "clip.fbx")]) == 2
    assert capsys.readouterr().err == (
        "error: FBX export needs Blender as a Python module (bpy): pip install -e .[blender]\n"
    )
    assert not (tmp_path / "clip.fbx").exists()
