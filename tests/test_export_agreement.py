"""One motion, one truth: the ``.npy`` joints, the BVH file and the ``.glb`` of a motion agree
within 1 mm at every joint and frame, for generated, edited, streamed and real motions.

Each motion is saved as ``t2m.sample`` saves it (float32 ``.npy``), written with the project's
writers (:func:`dataset_tools.bvh.write_bvh`, :func:`dataset_tools.gltf.write_glb`) from the
loaded array, and read back: the BVH with our reader (:func:`dataset_tools.bvh.read_bvh`), the
glTF by evaluating its nodes and animation with pygltflib (``tests/test_gltf.py``'s reader).
Generated motions agree because they are rigid on the writers' skeleton (``dataset_tools.rigid``):
before that, their bones stretched and the files' joints were centimetres off.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from conftest import synth_joints
from test_gltf import _read_with_pygltflib

from dataset_tools import physical
from dataset_tools.bvh import read_bvh, write_bvh
from dataset_tools.gltf import write_glb
from dataset_tools.representation import process_motion
from dataset_tools.skeleton import SMPL

TOLERANCE_M = 1e-3
"""The agreement every output must reach (1 mm)."""
SHARED = Path(__file__).resolve().parents[1].parent / "shared"
REFERENCE_JOINTS = SHARED / "reference" / "humanml3d" / "new_joints" / "012314.npy"


@pytest.fixture(scope="module")
def outputs(pipe) -> dict[str, np.ndarray]:
    """Joints (T, 22, 3) float32 of the outputs: generated (cleaned and not, two prompts),
    edits of a real clip, a live stream, and real clips."""
    from t2m.edit import SearchSettings, edit

    motions = {}
    for clean in (True, False):
        generated = pipe.generate(
            ["a person walks forward", "a person jumps up and down"],
            lengths=[60, 48],
            seed=3,
            clean=clean,
        )
        for prompt, row in enumerate(generated):
            motions[f"generated {prompt} clean={clean}"] = row[0].joints
    walk = synth_joints("walk_forward", 101, np.random.default_rng(3))
    _, real = process_motion(walk)  # the dataset builder's processing: a real clip
    motions["real (tiny corpus)"] = real.astype(np.float32)
    edited = edit(pipe, "a person jumps up and down", "continue", walk, keep_seconds=1.0,
                  seconds=3.0, seed=0, settings=SearchSettings(candidates=2, steps=0))  # fmt: skip
    motions["continue edit"] = edited[0].joints
    arms = edit(pipe, "a person waves", "body", walk, part="arms", seed=0,
                settings=SearchSettings(candidates=2, steps=0))  # fmt: skip
    motions["body edit (legs and root regenerated)"] = arms[0].joints
    stream = pipe.stream("a person walks forward", seed=2)  # the live stream, across a prompt
    for snippet in range(24):
        if snippet == 12:
            stream.prompt("a person jumps up and down")
        stream.next_snippet()
    motions["live stream"] = stream.joints()
    if REFERENCE_JOINTS.exists():
        motions["real (HumanML3D 012314)"] = np.load(REFERENCE_JOINTS)[:120]
    return motions


def _saved(joints: np.ndarray, path: Path) -> np.ndarray:
    np.save(path, joints)
    return np.load(path)


def test_generated_motions_are_rigid_on_the_writers_skeleton(outputs):
    for name, joints in outputs.items():
        if name.startswith("generated"):
            lengths = SMPL.bone_lengths_of(joints)[:, 1:]
            # float32 joints a few metres from the origin: lengths round at ~1e-7 m
            np.testing.assert_allclose(lengths, np.broadcast_to(SMPL.bone_lengths[1:], lengths.shape), atol=2e-6, err_msg=name)  # fmt: skip
            assert physical.bone_stretch(joints)["max_m"] < 2e-6, name


@pytest.mark.parametrize("units", ["cm", "m"])
def test_npy_bvh_and_glb_agree_within_a_millimetre(outputs, tmp_path, units):
    for index, (name, joints) in enumerate(outputs.items()):
        npy = _saved(joints, tmp_path / f"{index}.npy")
        write_bvh(npy, tmp_path / f"{index}.bvh", units=units)
        names, _, _, positions, fps = read_bvh(tmp_path / f"{index}.bvh")  # file order
        assert sorted(names) == sorted(SMPL.joint_names) and fps == pytest.approx(20.0)
        order = [names.index(joint) for joint in SMPL.joint_names]
        bvh_joints = positions[:, order] / (100.0 if units == "cm" else 1.0)
        bvh_error = np.linalg.norm(bvh_joints - npy, axis=-1).max()
        assert bvh_error <= TOLERANCE_M, f"{name}: BVH {bvh_error * 1000:.2f} mm from the .npy"
        if units == "m":
            continue
        write_glb(npy, tmp_path / f"{index}.glb")
        glb_joints, names, _, _ = _read_with_pygltflib(tmp_path / f"{index}.glb")
        assert names == list(SMPL.joint_names)
        glb_error = np.linalg.norm(glb_joints - npy, axis=-1).max()
        assert glb_error <= TOLERANCE_M, f"{name}: glTF {glb_error * 1000:.2f} mm from the .npy"


def test_a_stretching_motion_would_not_agree(outputs, tmp_path):
    """The control: the writers lay out a rigid skeleton, so a motion whose bones stretch (as the
    model's raw joints do, by centimetres on the demo model) cannot agree with its files; this
    fails if the writers learned to stretch bones, which would make the agreement trivial."""
    joints = outputs["real (tiny corpus)"].astype(np.float64)
    wrist, elbow = SMPL.joint("left_wrist"), SMPL.joint("left_elbow")
    stretched = joints.copy()
    stretched[::2, wrist] += 0.1 * (joints[::2, wrist] - joints[::2, elbow])  # forearm +10%
    assert physical.bone_stretch(stretched)["max_rel"] > 0.04  # half the frames: 1.1 / 1.05 - 1
    write_bvh(stretched, tmp_path / "stretched.bvh")
    names, _, _, positions, _ = read_bvh(tmp_path / "stretched.bvh")
    positions = positions[:, [names.index(joint) for joint in SMPL.joint_names]] / 100.0
    error = np.linalg.norm(positions - stretched, axis=-1)
    assert error[::2, wrist].min() > 0.02 and error[:, :wrist].max() <= TOLERANCE_M


def test_the_files_t2m_sample_writes_agree(tiny_run, tmp_path):
    """What a user gets: ``python -m t2m.sample --bvh --glb`` writes three files per motion
    that hold the same joints."""
    from t2m import sample

    out = tmp_path / "out"
    argv = ["--text", "a person walks forward", "--num-samples", "2", "--length", "48"]
    argv += ["--checkpoints", str(tiny_run), "--out", str(out), "--render", "none"]
    assert sample.main([*argv, "--bvh", "--glb", "--seed", "7"]) == 0
    for rep in range(2):
        stem = out / f"sample00_rep{rep:02d}"
        npy = np.load(stem.with_suffix(".npy"))
        names, _, _, positions, _ = read_bvh(stem.with_suffix(".bvh"))
        bvh_joints = positions[:, [names.index(j) for j in SMPL.joint_names]] / 100.0
        glb_joints = _read_with_pygltflib(stem.with_suffix(".glb"))[0]
        assert np.linalg.norm(bvh_joints - npy, axis=-1).max() <= TOLERANCE_M
        assert np.linalg.norm(glb_joints - npy, axis=-1).max() <= TOLERANCE_M
