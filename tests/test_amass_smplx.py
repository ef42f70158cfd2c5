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
from dataset_tools.sources.amass import NUM_BETAS, NUM_JOINTS, load_amass

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
    np.testing.assert_allclose(ours.joints, reference, rtol=0, atol=1e-6)
    # the poses are far from rest: a wrong parent or rotation order could not hide in 1e-6
    assert np.abs(reference - reference[:1]).max() > 0.1
