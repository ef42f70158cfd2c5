"""The rigid skeleton fit (dataset_tools.rigid) and the bone-stretch measure
(dataset_tools.physical.bone_stretch): exact lengths, kept directions, idempotence, the BVH
writer's forward kinematics, held joints, features that recover the fitted joints, bad input."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import synth_joints

from dataset_tools import physical, rigid
from dataset_tools.bvh import motion_from_joints
from dataset_tools.representation import extract_features, process_motion, recover_from_ric
from dataset_tools.skeleton import KIT, SMPL


@pytest.fixture(scope="module")
def real() -> np.ndarray:
    """A rigid motion on the target skeleton: the dataset builder's processing of a walk."""
    _, joints = process_motion(synth_joints("walk_forward", 81, np.random.default_rng(0)))
    return joints


def _stretched(joints: np.ndarray, seed: int = 1, scale: float = 0.02) -> np.ndarray:
    """Joints moved independently by Gaussian noise (bones grow, shrink and turn)."""
    return joints + np.random.default_rng(seed).normal(0.0, scale, joints.shape)


def _bone_directions(joints: np.ndarray) -> np.ndarray:
    bones = joints[:, 1:] - joints[:, list(SMPL.parents[1:])]
    return bones / np.linalg.norm(bones, axis=-1, keepdims=True)


def test_a_rigid_motion_on_the_target_skeleton_is_left_as_it_is(real):
    assert physical.bone_stretch(real)["max_m"] < 1e-6
    np.testing.assert_allclose(rigid.rigid_joints(real), real, rtol=0, atol=1e-6)


def test_the_fit_has_the_target_lengths_keeps_directions_and_is_idempotent(real):
    noisy = _stretched(real)
    assert physical.bone_stretch(noisy)["max_m"] > 0.02
    fitted = rigid.rigid_joints(noisy)
    lengths = SMPL.bone_lengths_of(fitted)
    np.testing.assert_allclose(
        lengths, np.broadcast_to(SMPL.bone_lengths, lengths.shape), atol=1e-12
    )
    assert physical.bone_stretch(fitted)["max_m"] < 1e-12
    np.testing.assert_array_equal(fitted[:, 0], noisy[:, 0])  # the root stays
    # bones from a joint with one child keep their observed direction exactly
    single = [j for j in range(1, 22) if sum(p == SMPL.parents[j] for p in SMPL.parents) == 1]
    cosine = np.sum(_bone_directions(fitted) * _bone_directions(noisy), axis=-1)
    np.testing.assert_allclose(cosine[:, [j - 1 for j in single]], 1.0, atol=1e-12)
    np.testing.assert_allclose(rigid.rigid_joints(fitted), fitted, rtol=0, atol=1e-12)


def test_the_bvh_writer_reproduces_the_fit_exactly(real):
    fitted = rigid.rigid_joints(_stretched(real, seed=2))
    np.testing.assert_allclose(motion_from_joints(fitted).joints(), fitted, rtol=0, atol=1e-12)


def test_held_joints_stay_and_a_part_hanging_from_a_fitted_joint_follows_it(real):
    noisy = _stretched(real, seed=3)
    held = np.zeros(real.shape[:2], bool)
    held[:30] = True  # a kept start: every joint, root included
    held[:, [1, 4, 7, 10]] = True  # a left leg kept on every frame, under a kept root only
    mixed = noisy.copy()
    mixed[held] = real[held]
    fitted = rigid.rigid_joints(mixed, held=held)
    np.testing.assert_array_equal(fitted[:30], real[:30])
    after = slice(30, None)
    np.testing.assert_allclose(SMPL.bone_lengths_of(fitted[after]), np.broadcast_to(SMPL.bone_lengths, (len(real) - 30, 22)), atol=1e-12)  # fmt: skip
    # The leg hangs from the regenerated root after frame 30: it keeps its pose, not its place.
    cosine = np.sum(_bone_directions(fitted[after]) * _bone_directions(mixed[after]), axis=-1)
    np.testing.assert_allclose(cosine[:, [3, 6, 9]], 1.0, atol=1e-12)  # knee, ankle, foot bones
    # One rigid piece throughout (the kept start's shape): the writer reproduces all of it.
    np.testing.assert_allclose(motion_from_joints(fitted).joints(), fitted, rtol=0, atol=1e-6)


def test_kit_keeps_its_own_median_lengths():
    rng = np.random.default_rng(4)
    rest = np.zeros((KIT.num_joints, 3))
    for joint, parent in enumerate(KIT.parents):
        if parent >= 0:
            rest[joint] = rest[parent] + KIT.rest_directions[joint] * 1.3 * KIT.bone_lengths[joint]
    joints = rest + np.array([0.0, 1.0, 0.0]) + rng.normal(0, 0.005, (40, KIT.num_joints, 3))
    fitted = rigid.rigid_joints(joints, KIT)
    median = np.median(KIT.bone_lengths_of(joints), axis=0)
    np.testing.assert_allclose(KIT.bone_lengths_of(fitted), np.broadcast_to(median, (40, 21)), atol=1e-12)  # fmt: skip


def test_features_with_joints_recover_the_joints(real):
    features = extract_features(real)  # (T - 1, D)
    moved = _stretched(real[:-1], seed=5, scale=0.01)
    moved[:, 0] = real[:-1, 0]  # the root is the features' own
    fitted = rigid.rigid_joints(moved)
    rebuilt = rigid.features_with_joints(features, fitted)
    assert rebuilt.dtype == np.float32 and rebuilt.shape == features.shape
    np.testing.assert_allclose(recover_from_ric(rebuilt), fitted, rtol=0, atol=1e-5)
    np.testing.assert_array_equal(rebuilt[:, :4], features[:, :4].astype(np.float32))  # the root


def test_finished_features_are_rigid_and_on_the_floor(real):
    features = extract_features(real)
    layout_ric = slice(4, 4 + 21 * 3)
    noisy = features.copy()
    noisy[:, layout_ric] += np.random.default_rng(6).normal(0, 0.02, (len(features), 63))
    noisy[:, layout_ric][:, 1::3] -= 0.03  # sink the body: the clean-up lifts planted feet
    for clean in (False, True):
        joints = recover_from_ric(rigid.finish_features(noisy, clean=clean))
        assert physical.bone_stretch(joints)["max_m"] < 1e-5
        np.testing.assert_allclose(SMPL.bone_lengths_of(joints)[:, 1:], np.broadcast_to(SMPL.bone_lengths[1:], (len(joints), 21)), atol=1e-5)  # fmt: skip
    assert physical.penetration_mm(joints) == pytest.approx(0.0, abs=1e-3)


def test_bone_stretch_of_a_known_stretch(real):
    joints = real.copy()
    wrist, elbow = SMPL.joint("left_wrist"), SMPL.joint("left_elbow")
    joints[:20, wrist] += 0.5 * (real[:20, wrist] - real[:20, elbow])  # forearm x1.5, 20 frames
    stretch = physical.bone_stretch(joints)
    forearm = SMPL.bone_lengths[wrist]
    assert stretch["max_m"] == pytest.approx(0.5 * forearm, abs=1e-5)
    assert stretch["max_rel"] == pytest.approx(0.5, abs=1e-4)
    assert stretch["mean_m"] == pytest.approx(0.5 * forearm * 20 / (len(real) * 21), abs=1e-5)


@pytest.mark.parametrize(
    "arguments, message",
    [
        ((np.zeros((5, 21, 3)), SMPL), "joints must be"),
        ((np.full((5, 22, 3), np.nan),), "NaN"),
        ((np.zeros((5, 22, 3)), None, np.ones(3)), "lengths must be"),
        ((np.zeros((5, 22, 3)), None, None, np.ones((4, 22), bool)), "held must be"),
    ],
)
def test_bad_input_is_a_clear_error(arguments, message):
    with pytest.raises(ValueError, match=message):
        rigid.rigid_joints(*arguments)


def test_held_joints_stay_through_the_clean_up(real):
    """finish_features with held joints and the clean-up: the held ones stay exactly where they
    were given (the fit and the clean-up both hold them), the free feet may move."""
    rng = np.random.default_rng(5)
    features = extract_features(real + rng.normal(0, 0.01, real.shape))
    joints = recover_from_ric(features.astype(np.float64), 22)
    held = np.zeros((len(features), 22), bool)
    held[:20] = True  # a kept start, as continue keeps it
    finished = rigid.finish_features(features, clean=True, held=held)
    after = recover_from_ric(finished, 22)
    np.testing.assert_allclose(after[held], joints[held], rtol=0, atol=1e-5)  # float32 features
    assert np.abs(after[~held] - joints[~held]).max() > 1e-3
