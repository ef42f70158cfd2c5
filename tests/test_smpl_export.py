"""SMPL-H parameters (AMASS's layout) fitted to joints: ``dataset_tools.smplh``, ``t2m.export
IN.npy OUT.npz`` and ``--smpl`` of the sample / edit writer.

What must hold: forward kinematics of the parameters (ours, the AMASS reader's and ``smplx``'s)
gives the skeleton they were fitted to, i.e. the BVH writer's joints, which are the input joints
wherever the input is rigid on the target skeleton; ``dataset_tools build --source amass`` reads
the file back.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from dataset_tools.bvh import motion_from_joints
from dataset_tools.humanml3d import read_split
from dataset_tools.io import load_npz, save_npy_atomic
from dataset_tools.skeleton import SMPL
from dataset_tools.smplh import (
    NUM_JOINTS,
    PARENTS,
    fit_smplh,
    skeleton_body_model,
    smplh_forward,
    write_smplh,
)
from dataset_tools.sources.amass import load_amass
from dataset_tools.spec import HUMANML3D

REFERENCE = Path(__file__).resolve().parents[1].parent / "shared" / "reference" / "humanml3d"
needs_reference = pytest.mark.skipif(
    not REFERENCE.is_dir(), reason=f"reference HumanML3D clips absent ({REFERENCE})"
)
CLIP = "012314"


def _clip() -> np.ndarray:
    return np.load(REFERENCE / "new_joints" / f"{CLIP}.npy")  # (T, 22, 3), rigid, 20 fps


def _generated_like(frames: int = 40, seed: int = 0) -> np.ndarray:
    """Joints as a model gives them when they are not rigid: a reference pose whose joints
    wander by up to 3 cm (bone lengths vary) while the body turns and walks."""
    rng = np.random.default_rng(seed)
    base = _clip()[0]
    angles = np.linspace(0.0, 2.5, frames)
    turn = np.zeros((frames, 3, 3))
    turn[:, 0, 0] = turn[:, 2, 2] = np.cos(angles)
    turn[:, 0, 2], turn[:, 2, 0] = np.sin(angles), -np.sin(angles)
    turn[:, 1, 1] = 1.0
    joints = np.einsum("tij,kj->tki", turn, base - base[0]) + base[0]
    joints += rng.uniform(-0.03, 0.03, joints.shape)
    joints[..., 2] += np.linspace(0.0, 1.5, frames)[:, None]
    return joints


def _write_body_model(folder: Path, rest_joints: np.ndarray) -> Path:
    (folder / "neutral").mkdir(parents=True)
    np.savez(folder / "neutral" / "model.npz", **skeleton_body_model(rest_joints))
    return folder


@needs_reference
def test_forward_kinematics_gives_the_fitted_skeleton_and_the_rigid_input():
    joints = _clip()
    parameters = fit_smplh(joints)
    assert parameters.poses.shape == (len(joints), 3 * NUM_JOINTS)
    assert parameters.trans.shape == (len(joints), 3)
    # hands at rest; the wrists keep their forearm's rotation
    assert not parameters.poses[:, 3 * 20 :].any()
    fk = smplh_forward(parameters)
    bvh_joints = motion_from_joints(joints).joints()
    # the same rotations and offsets as the BVH file: float64 rounding only
    assert np.abs(fk[:, :22] - bvh_joints).max() < 1e-9
    # a real clip is rigid: only the fitted hips / collars differ (measured 0.13 mm)
    error = np.linalg.norm(fk[:, :22] - joints, axis=-1).max()
    assert error < 5e-4, error
    # the fingers hang rigidly off the wrists
    for joint in range(22, NUM_JOINTS):
        parent = PARENTS[joint]
        lengths = np.linalg.norm(fk[:, joint] - fk[:, parent], axis=-1)
        rest = np.linalg.norm(parameters.rest_joints[joint] - parameters.rest_joints[parent])
        assert np.allclose(lengths, rest, atol=1e-9)


@needs_reference
def test_generated_like_joints_give_the_bvh_skeletons_joints():
    joints = _generated_like()
    fk = smplh_forward(fit_smplh(joints))[:, :22]
    assert np.abs(fk - motion_from_joints(joints).joints()).max() < 1e-9
    # bone directions are kept exactly, so the fitted body is within the stretch of the input
    assert np.linalg.norm(fk - joints, axis=-1).max() < 0.15


@needs_reference
def test_amass_reader_reads_the_file_back(tmp_path):
    joints = _clip()
    parameters = fit_smplh(joints, fps=HUMANML3D.fps)
    path = write_smplh(parameters, tmp_path / "clip_poses.npz")
    stored = load_npz(path)
    assert {"poses", "trans", "betas", "gender", "mocap_framerate", "dmpls"} <= set(stored)
    assert stored["poses"].shape == (len(joints), 156) and stored["betas"].shape == (16,)
    assert str(stored["gender"]) == "neutral" and float(stored["mocap_framerate"]) == 20.0
    models = _write_body_model(tmp_path / "models", stored["rest_joints"])
    motion = load_amass(path, models)
    assert motion.fps == 20.0 and motion.joints.shape == (len(joints), NUM_JOINTS, 3)
    assert np.abs(motion.joints - smplh_forward(parameters)).max() < 1e-9
    assert np.linalg.norm(motion.joints[:, :22] - joints, axis=-1).max() < 5e-4


@needs_reference
def test_dataset_build_round_trip(tmp_path):
    """``dataset_tools build --source amass`` over an exported file (with the body model of its
    own rest skeleton) gives what building the same joints (``--source joints``) gives."""
    from dataset_tools.build import main

    joints = _clip()[:80]
    parameters = fit_smplh(joints)
    write_smplh(parameters, tmp_path / "amass" / "t2m" / "ref.npz")
    save_npy_atomic(tmp_path / "joints" / "t2m_ref.npy", joints)
    texts = tmp_path / "texts"
    texts.mkdir()
    (texts / "t2m_ref.txt").write_text("a person walks forward\n")
    models = _write_body_model(tmp_path / "models", parameters.rest_joints)
    amass = ["--source", "amass", "--input", str(tmp_path / "amass"), "--body-model", str(models)]
    joints_source = ["--source", "joints", "--fps", "20", "--input", str(tmp_path / "joints")]
    for argv, out in ((amass, "from_amass"), (joints_source, "from_joints")):
        assert main([*argv, "--texts", str(texts), "--out", str(tmp_path / out)]) == 0
    report = json.loads((tmp_path / "from_amass" / "build_report.json").read_text())
    assert report["skipped"] == []
    assert sorted(read_split(tmp_path / "from_amass", "all")) == ["Mt2m_ref", "t2m_ref"]
    for name in ("t2m_ref", "Mt2m_ref"):
        built = np.load(tmp_path / "from_amass" / "new_joints" / f"{name}.npy")
        expected = np.load(tmp_path / "from_joints" / "new_joints" / f"{name}.npy")
        assert built.shape == expected.shape == (79, 22, 3)
        # the file reproduces the clip to 0.13 mm (its fitted hips / collars)
        assert np.linalg.norm(built - expected, axis=-1).max() < 1e-3, name


def test_smplx_forward_kinematics_agrees(tmp_path):
    """``smplx``'s SMPL-H (a test dependency; no body model download: the skeleton's own
    surface-free model) gives our joints."""
    smplx = pytest.importorskip("smplx")
    torch = pytest.importorskip("torch")
    from test_amass_smplx import LANDMARKS

    from dataset_tools.rotations import z_up_to_y_up

    rng = np.random.default_rng(0)
    rest = np.zeros((SMPL.num_joints, 3))
    for joint in range(1, SMPL.num_joints):
        rest[joint] = rest[SMPL.parents[joint]] + SMPL.offsets[joint]
    joints = rest[None] + rng.normal(0.0, 0.05, (6, SMPL.num_joints, 3)) + [0.0, 0.9, 0.0]
    parameters = fit_smplh(joints)
    model = skeleton_body_model(parameters.rest_joints)
    hand = 45
    data = dict(
        model,
        posedirs=np.zeros((NUM_JOINTS, 3, 9 * (NUM_JOINTS - 1))),
        weights=np.eye(NUM_JOINTS),
        f=np.zeros((1, 3), dtype=np.int64),
        hands_componentsl=np.eye(hand),
        hands_componentsr=np.eye(hand),
        hands_meanl=np.zeros(hand),
        hands_meanr=np.zeros(hand),
    )
    body = smplx.SMPLH(
        model_path=str(tmp_path),
        data_struct=smplx.body_models.Struct(**data),
        num_betas=10,
        use_pca=False,
        flat_hand_mean=True,
        vertex_ids={name: index for index, name in enumerate(LANDMARKS)},  # not compared
        dtype=torch.float64,
    )
    poses = torch.from_numpy(parameters.poses)
    with torch.no_grad():
        output = body(
            global_orient=poses[:, :3],
            body_pose=poses[:, 3:66],
            left_hand_pose=poses[:, 66:111],
            right_hand_pose=poses[:, 111:156],
            betas=torch.zeros(len(joints), 10, dtype=torch.float64),
            transl=torch.from_numpy(parameters.trans),
        )
    reference = z_up_to_y_up(output.joints[:, :NUM_JOINTS].numpy())
    # smplx's Rodrigues adds 1e-8 to each axis-angle component (see test_amass_smplx): joints
    # move by at most depth x 1e-7 rad x 1 m; a wrong frame or order moves them by decimetres
    assert np.abs(reference - smplh_forward(parameters)).max() < 1e-5
    assert np.abs(reference[:, :22] - motion_from_joints(joints).joints()).max() < 1e-5


@needs_reference
def test_export_command_writes_and_refuses_to_overwrite(tmp_path, capsys):
    from t2m.export import main

    source = tmp_path / "clip.npy"
    np.save(source, _clip()[:30])
    out = tmp_path / "clip.npz"
    assert main([str(source), str(out), "--fps", "30"]) == 0
    stored = load_npz(out)
    assert float(stored["mocap_framerate"]) == 30.0 and stored["poses"].shape == (30, 156)
    before = out.read_bytes()
    assert main([str(source), str(out)]) == 2
    assert "exists" in capsys.readouterr().err and out.read_bytes() == before


@needs_reference
def test_smpl_option_writes_parameters_per_motion(tmp_path):
    """``--smpl`` (t2m.sample and t2m.edit write through write_motions): one
    ``sampleNN_repRR_smpl.npz`` per motion, listed in results.json, fitted to the motion."""
    from t2m.motion import GeneratedMotion
    from t2m.outputs import write_motions

    joints = [_clip()[:40].astype(np.float32), _generated_like(32, seed=1).astype(np.float32)]
    motions = [
        [GeneratedMotion("a person walks", 0, 0, joints[0], np.zeros((40, 263), np.float32))],
        [GeneratedMotion("a person turns", 1, 0, joints[1], np.zeros((32, 263), np.float32))],
    ]
    out = write_motions(
        lambda: motions, HUMANML3D, tmp_path / "out", frames=[40, 32], render="none", smpl=True
    )
    summary = json.loads((out / "results.json").read_text())
    for prompt in range(len(joints)):
        name = f"sample{prompt:02d}_rep00_smpl.npz"
        assert name in summary["files"]
        stored = load_npz(out / name)
        models = _write_body_model(tmp_path / f"models{prompt}", stored["rest_joints"])
        read = load_amass(out / name, models).joints[:, :22]
        expected = motion_from_joints(np.load(out / f"sample{prompt:02d}_rep00.npy")).joints()
        assert np.abs(read - expected).max() < 1e-6


@needs_reference
def test_sample_and_edit_commands_write_smpl_files(tiny_run, tmp_path):
    """``python -m t2m.sample --smpl`` and ``python -m t2m.edit --smpl`` on the tiny run."""
    from t2m.edit.__main__ import main as edit_main
    from t2m.sample import main as sample_main

    source = tmp_path / "walk.npy"
    np.save(source, _clip()[:60])
    common = ["--checkpoints", str(tiny_run), "--render", "none", "--smpl"]
    assert sample_main(["--text", "a person walks", "--length", "32", "--out", str(tmp_path / "s")]
                       + common) == 0  # fmt: skip
    edit = ["--source", str(source), "--text", "a person walks forward", "--mode", "continue",
            "--keep-seconds", "1", "--candidates", "2", "--steps", "2", "--out", str(tmp_path / "e")]  # fmt: skip
    assert edit_main(edit + common) == 0
    for out in (tmp_path / "s", tmp_path / "e"):
        stored = load_npz(out / "sample00_rep00_smpl.npz")
        models = _write_body_model(out.parent / f"models_{out.name}", stored["rest_joints"])
        read = load_amass(out / "sample00_rep00_smpl.npz", models).joints[:, :22]
        written = np.load(out / "sample00_rep00.npy")
        assert np.abs(read - motion_from_joints(written).joints()).max() < 1e-6, out.name
        # generated and edited motions are rigid on the model's skeleton: the body's joints are
        # the .npy joints themselves
        assert np.linalg.norm(read - written, axis=-1).max() < 1e-3, out.name
        assert "sample00_rep00_smpl.npz" in json.loads((out / "results.json").read_text())["files"]
