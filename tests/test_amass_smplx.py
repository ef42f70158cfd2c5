"""AMASS forward kinematics (our numpy SMPL-H) against ``smplx``, the reference implementation.

``smplx`` is a test-only dependency (``pip install -e .[test]``); its SMPL-H runs on the small
synthetic body model of ``test_sources`` (60 vertices, 52 joints) with zero pose blend shapes
and, since the model has no real hand PCA or surface landmarks, an identity hand basis and extra
"vertex joints" on its first vertices (they are outputs after the 52 joints, not compared).
"""

from __future__ import annotations

import numpy as np
import pytest
from test_sources import make_amass_npz, make_body_model

from dataset_tools.rotations import z_up_to_y_up
from dataset_tools.sources.amass import NUM_BETAS, NUM_JOINTS, load_amass, load_body_model

smplx = pytest.importorskip("smplx")
torch = pytest.importorskip("torch")

# smplx adds joints at named vertices (nose, toes, finger tips ...) after the 52 of the skeleton.
LANDMARKS = (
    "nose reye leye rear lear LBigToe LSmallToe LHeel RBigToe RSmallToe RHeel "
    "lthumb lindex lmiddle lring lpinky rthumb rindex rmiddle rring rpinky"
).split()


def smplx_body(model_file) -> smplx.SMPLH:
    """smplx's SMPL-H (float64, hand poses as axis-angle) over one of our model.npz files."""
    with np.load(model_file) as stored:
        data = dict(stored)
    num_vertices = data["v_template"].shape[0]
    hand_dims = 3 * 15
    data.update(
        posedirs=np.zeros((num_vertices, 3, 9 * (NUM_JOINTS - 1))),  # joints never use them
        hands_componentsl=np.eye(hand_dims),
        hands_componentsr=np.eye(hand_dims),
        hands_meanl=np.zeros(hand_dims),
        hands_meanr=np.zeros(hand_dims),
    )
    return smplx.SMPLH(
        model_path=str(model_file),
        data_struct=smplx.body_models.Struct(**data),
        num_betas=NUM_BETAS,
        use_pca=False,
        flat_hand_mean=True,
        vertex_ids={name: index for index, name in enumerate(LANDMARKS)},
        dtype=torch.float64,
    )


@pytest.mark.parametrize("gender", ["male", "female"])
def test_amass_joints_match_smplx(gender, tmp_path):
    models = make_body_model(tmp_path / "models", seed=3, genders=("male", "female"))
    rng = np.random.default_rng({"male": 1, "female": 2}[gender])
    frames = 7
    poses = rng.normal(0.0, 0.8, (frames, 3 * NUM_JOINTS))
    trans = rng.normal(0.0, 1.0, (frames, 3))
    betas = rng.normal(0.0, 1.5, 16)
    clip = make_amass_npz(
        tmp_path / "clip.npz",
        num_frames=frames,
        poses=poses,
        trans=trans,
        betas=betas,
        gender=np.array(gender),
    )

    ours = load_amass(clip, models)
    assert ours.metadata["body_model"] == str(models / gender / "model.npz")

    body = smplx_body(models / gender / "model.npz")
    as_tensor = lambda array: torch.from_numpy(np.ascontiguousarray(array))  # noqa: E731
    with torch.no_grad():
        output = body(
            global_orient=as_tensor(poses[:, :3]),
            body_pose=as_tensor(poses[:, 3:66]),
            left_hand_pose=as_tensor(poses[:, 66:111]),
            right_hand_pose=as_tensor(poses[:, 111:156]),
            betas=as_tensor(np.tile(betas[:NUM_BETAS], (frames, 1))),
            transl=as_tensor(trans),
        )
    reference = z_up_to_y_up(output.joints[:, :NUM_JOINTS].numpy())
    assert ours.joints.shape == reference.shape == (frames, NUM_JOINTS, 3)
    # Both sides are float64 (rounding ~1e-15 m), but smplx's batch_rodrigues takes the angle as
    # |r + 1e-8| (1e-8 added to each axis-angle component) and the axis as r / that angle: each
    # joint's rotation is off by at most |angle error| + 2 |axis length error| <= sqrt(3) 1e-8
    # (1 + 2 / |r|) rad, and a joint's position by the sum over its ancestors of that times the
    # lever arm: at most (chain depth) x (largest rotation error) x (largest extent of the body).
    # Observed 1.2e-7 m against bounds of 5.7e-6 and 9.3e-6 (the smallest angles, about 0.1 rad,
    # dominate); a wrong parent or rotation order moves joints by centimetres (the poses are far
    # from rest, checked below).
    depth = np.zeros(NUM_JOINTS, np.int64)
    parents = load_body_model(str(models / gender / "model.npz")).parents
    for joint, parent in enumerate(parents):
        depth[joint] = 0 if parent < 0 else depth[parent] + 1
    angles = np.linalg.norm(poses.reshape(frames, NUM_JOINTS, 3), axis=-1)
    rotation_error = np.sqrt(3) * 1e-8 * (1 + 2 / angles.min())
    extent = np.ptp(reference, axis=1).max() * np.sqrt(3)
    bound = depth.max() * rotation_error * extent + 1e-12
    error = np.abs(ours.joints - reference).max()
    assert error <= bound, f"joints {error:.3g} m from smplx's, bound {bound:.3g}"
    # the poses are far from rest: a wrong parent or rotation order could not hide in 1e-6
    assert np.abs(reference - reference[:1]).max() > 0.1
