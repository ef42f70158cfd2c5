from pathlib import Path

import numpy as np
import pytest

from dataset_tools.kinematics import forward_kinematics, inverse_kinematics, retarget
from dataset_tools.representation import (
    FeatureLayout,
    canonicalize,
    extract_features,
    process_motion,
    recover_from_ric,
    recover_from_rot,
    target_offsets_from_example,
)
from dataset_tools.rotations import qrot, yaw_quat
from dataset_tools.skeleton import KIT, SMPL

SHARED = Path(__file__).resolve().parents[1].parent / "shared"
REFERENCE = SHARED / "reference" / "humanml3d"
needs_reference = pytest.mark.skipif(
    not REFERENCE.is_dir(), reason="../shared/reference/humanml3d is absent (CI always has it)"
)


@pytest.fixture(scope="module")
def reference():
    return {
        "vecs": np.load(REFERENCE / "new_joint_vecs" / "012314.npy"),
        "joints": np.load(REFERENCE / "new_joints" / "012314.npy"),
        "example": np.load(REFERENCE / "skeleton_example_000021_frame0.npy"),
    }


def test_layout_sizes_and_tiling():
    assert FeatureLayout(22).dim == 263
    assert FeatureLayout(21).dim == 251
    for num_joints in (21, 22):
        layout = FeatureLayout(num_joints)
        stops = 0
        for _, part in layout.groups():
            assert part.start == stops
            stops = part.stop
        assert stops == layout.dim
        assert FeatureLayout.for_dim(layout.dim) == layout
    with pytest.raises(ValueError):
        FeatureLayout.for_dim(100)


def test_target_bone_lengths_match_reference_example(reference):
    measured = SMPL.bone_lengths_of(reference["example"][:22])
    assert np.abs(measured - SMPL.bone_lengths).max() < 6e-5


@needs_reference
def test_recover_from_ric_reproduces_reference_joints(reference):
    recovered = recover_from_ric(reference["vecs"], 22)
    assert recovered.shape == reference["joints"].shape
    assert np.abs(recovered - reference["joints"]).max() < 1e-5


@needs_reference
def test_features_match_reference(reference):
    offsets = target_offsets_from_example(reference["example"])
    features, recovered = process_motion(reference["joints"], target_offsets=offsets)
    expected = reference["vecs"][:169]
    assert features.shape == (169, 263)
    assert np.abs(features - expected).max() < 0.02
    layout = FeatureLayout(22)
    assert np.array_equal(features[:, layout.foot_contact], expected[:, layout.foot_contact])
    assert recovered.shape == (169, 22, 3)
    # The listed target bone lengths give the same features.
    default, _ = process_motion(reference["joints"])
    assert np.abs(default - expected).max() < 0.02


@needs_reference
def test_corrected_across_differs_from_compat(reference):
    compat, compat_joints = process_motion(reference["joints"])
    fixed, fixed_joints = process_motion(reference["joints"], compat=False)
    layout = FeatureLayout(22)
    # The facing frame depends on the across convention, the motion itself does not.
    assert (
        np.abs(compat[:, layout.root_rot_velocity] - fixed[:, layout.root_rot_velocity]).max()
        > 0.01
    )
    assert np.abs(compat_joints - fixed_joints).max() < 1e-6


@needs_reference
def test_recover_from_rot_matches_ric(reference):
    offsets = target_offsets_from_example(reference["example"])
    joints = recover_from_rot(reference["vecs"], SMPL, offsets)
    assert np.abs(joints - reference["joints"]).max() < 1e-3


@needs_reference
def test_invariance_to_yaw_and_translation(reference):
    joints = reference["joints"].astype(np.float64)
    base = extract_features(canonicalize(retarget(joints)))
    moved = qrot(yaw_quat(0.7), joints) + np.array([1.5, 0.0, -2.0])
    moved_features = extract_features(canonicalize(retarget(moved)))
    assert np.abs(moved_features - base).max() < 1e-6


@needs_reference
def test_fk_of_ik_reproduces_joints_on_target(reference):
    joints = retarget(reference["joints"].astype(np.float64))
    for compat in (True, False):
        local = inverse_kinematics(joints, SMPL, compat=compat)
        rebuilt = forward_kinematics(local, joints[:, 0], SMPL.offsets, SMPL)
        assert np.abs(rebuilt - joints).max() < 1e-9
    assert np.abs(SMPL.bone_lengths_of(joints) - SMPL.bone_lengths).max() < 1e-9


def test_canonical_frame():
    rng = np.random.default_rng(0)
    joints = _standing_pose(SMPL) + rng.normal(scale=0.01, size=(30, 22, 3))
    joints = qrot(yaw_quat(1.2), joints) + np.array([3.0, 0.4, 1.0])
    canonical = canonicalize(joints)
    assert abs(canonical[..., 1].min()) < 1e-12
    assert np.allclose(canonical[0, 0, [0, 2]], 0.0)
    hips = canonical[0, 2] - canonical[0, 1]
    shoulders = canonical[0, 17] - canonical[0, 16]
    forward = np.cross([0, 1.0, 0], hips + shoulders)
    assert np.allclose(forward / np.linalg.norm(forward), [0, 0, 1.0])


def _standing_pose(skeleton, frames=30):
    local = np.zeros((frames, skeleton.num_joints, 4))
    local[..., 0] = 1.0
    return forward_kinematics(local, np.tile([0, 1.0, 0], (frames, 1)), skeleton.offsets, skeleton)


def test_kit_layout_round_trip():
    joints = _standing_pose(KIT, 12)
    joints[:, :, 2] += np.linspace(0, 0.3, 12)[:, None]  # walk forward
    features, recovered = process_motion(joints, KIT)
    assert features.shape == (11, 251)
    assert np.all(np.isfinite(features))
    assert recovered.shape == (11, 21, 3)


def test_degenerate_inputs_raise_clear_errors():
    pose = _standing_pose(SMPL, 5)
    with pytest.raises(ValueError, match="at least 2 frames"):
        process_motion(pose[:1])
    bad = pose.copy()
    bad[2, 5] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        process_motion(bad)
    collapsed = pose.copy()
    collapsed[:, 4] = collapsed[:, 1]  # left knee on the left hip
    with pytest.raises(ValueError, match="zero-length bone"):
        inverse_kinematics(collapsed)
    flat = pose.copy()
    flat[:, [1, 2, 16, 17]] = flat[:, [0]]  # hips and shoulders on one point
    with pytest.raises(ValueError, match="across"):
        inverse_kinematics(flat)
    with pytest.raises(ValueError, match=r"\(T, 22, 3\)"):
        process_motion(np.zeros((10, 20, 3)))
    with pytest.raises(ValueError):
        recover_from_ric(np.zeros((10, 100)))


def test_retarget_equals_fk_of_ik_with_target_offsets():
    from t2m.benchmarks.representation import _random_motion

    source = _random_motion(np.random.default_rng(3), frames=40)  # a scaled, non-target skeleton
    local = inverse_kinematics(source, SMPL)
    lengths = SMPL.bone_lengths_of(source[0])
    scale = (SMPL.bone_lengths[5] + SMPL.bone_lengths[8]) / (lengths[5] + lengths[8])
    expected = forward_kinematics(local, source[:, 0] * scale, SMPL.offsets, SMPL)
    assert np.abs(retarget(source) - expected).max() < 1e-9
    assert np.abs(SMPL.bone_lengths_of(retarget(source)) - SMPL.bone_lengths).max() < 1e-9
