"""The HumanML3D representation: parity with the reference files, invariances, round trips.

The reference files are float32 records of the original's float32 computation; ours runs in
float64. Bounds against them are that float32 computation's error, derived from the recorded
data (``_recorded_recovery_bound``); float64 bounds are rounding counts (``float64_bound``) at the
values' magnitude, scaled by the conditioning of the shortest-arc rotations (``_opposition``)
where directions are solved for, times ``MARGIN`` = 10 for second-order terms and counting slack.
"""

from pathlib import Path

import numpy as np
import pytest

from dataset_tools.kinematics import _chain_order, forward_kinematics, inverse_kinematics, retarget
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
from tests.tolerances import U, float64_bound, gamma

MARGIN = 10

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


def _recorded_recovery_bound(features: np.ndarray) -> float:
    """Bound on the float32 error of joints recovered from ``features`` (T, 263) as the original
    did (and recorded in new_joints), plus our cast of the float64 result to float32.

    At frame k the half-yaw is a prefix sum of k recorded steps (gamma_k times their absolute
    sum, any order) and its sine and cosine carry 4 ulp each; the root sums k rotated steps, each
    turned by its frame's angle error plus qrot's 15 roundings, and rounded as a prefix sum; the
    joints add |ric| times the angle error and 15. Worst case, linear in T: float32 prefix sums
    of a walk of several metres (observed: 2e-7, 1 ulp at 2.7 m, against 1.3e-4 for 012314).
    """
    features = features.astype(np.float64)
    frames = np.arange(len(features))
    prefix = np.array([gamma(max(int(k), 1), U) for k in frames])
    yaw = np.concatenate([[0.0], np.cumsum(np.abs(features[:-1, 0]))])
    angle_error = prefix * yaw + 8 * U
    steps = np.concatenate([[0.0], np.linalg.norm(features[:-1, 1:3], axis=-1)])
    root_error = np.cumsum(steps * (angle_error + 15 * U)) + prefix * np.cumsum(steps)
    layout = FeatureLayout(22)
    ric = np.linalg.norm(features[:, layout.ric].reshape(len(features), -1, 3), axis=-1).max(-1)
    size = np.abs(features[:, layout.ric]).max() + np.cumsum(steps).max()
    return float((root_error + ric * (angle_error + 15 * U)).max() + U * size)


def _opposition(joints: np.ndarray, skeleton=SMPL) -> float:
    """The largest 1 / (2 cos(phi / 2)) over bones and frames, phi the angle from a bone's rest
    direction to its direction in ``joints``: by how much qbetween's 15 roundings of |u||v| turn
    its rotation (tests.test_rotations)."""
    children, parents, _ = _chain_order(skeleton)
    bones = joints[:, children] - joints[:, parents]
    bones /= np.linalg.norm(bones, axis=-1, keepdims=True)
    cos_angle = np.sum(bones * skeleton.rest_directions[children], axis=-1)
    return float((1 / np.sqrt(2 * (1 + cos_angle))).max())


def _fk_of_ik_bound(joints: np.ndarray) -> float:
    """float64 bound on |FK(IK(joints)) - joints| for target-length bones: each bone's direction
    off by its shortest arc's 30 K + 32 (K = ``_opposition``) and 16 per qmul level of FK's
    recomposition (<= 5 levels: the swings above cancel exactly), times the <= 1.6 m of bones
    from the root, and a rounding per level at |x| (observed 14 roundings at 2.7 m)."""
    depth, path, size = 5, 1.6, np.abs(joints).max()
    return float64_bound(30 * _opposition(joints) + 32 + 16 * depth, path) + float64_bound(
        depth, size
    )


def _target_lengths_bound(joints: np.ndarray) -> float:
    """float64 bound on |bone length - target| after retarget: the unit direction times the
    length (norm 3, division, product: 5) and the norm's 3 at <= 0.43 m, and the two sums that
    place a child and take it back off its parent at |x| (observed 2 roundings)."""
    return float64_bound(8, SMPL.bone_lengths.max()) + float64_bound(2, np.abs(joints).max())


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
    # The table lists the lengths to 4 decimals: half a unit of the last, 5e-5 (observed 4.3e-5),
    # plus the float64 norms of the example's bones; a wrong digit is off by more than 5e-5.
    bound = 0.5e-4 + MARGIN * float64_bound(5, SMPL.bone_lengths.max())
    assert np.abs(measured - SMPL.bone_lengths).max() < bound


@needs_reference
def test_recover_from_ric_reproduces_reference_joints(reference):
    recovered = recover_from_ric(reference["vecs"], 22)
    assert recovered.shape == reference["joints"].shape
    # The recorded joints carry the original's float32 error (``_recorded_recovery_bound``, 1.3e-4
    # here); an off-by-one frame or a sign is off by centimetres.
    bound = _recorded_recovery_bound(reference["vecs"])
    assert np.abs(recovered - reference["joints"]).max() < bound


@needs_reference
def test_features_match_reference(reference):
    offsets = target_offsets_from_example(reference["example"])
    features, recovered = process_motion(reference["joints"], target_offsets=offsets)
    expected = reference["vecs"][:169]
    assert features.shape == (169, 263)
    # Not rounding, a semantic threshold: the recorded features came from the raw clip, ours from
    # its recovered joints one frame shorter, and the facing is smoothed over sigma = 20 frames,
    # so frames near the end differ (0.013 at the last; under 8e-6 before frame 100). 0.02, about
    # a degree in a 6-D entry, passes that end effect and fails a wrong convention (0.1 or more).
    assert np.abs(features - expected).max() < 0.02
    layout = FeatureLayout(22)
    assert np.array_equal(features[:, layout.foot_contact], expected[:, layout.foot_contact])
    assert recovered.shape == (169, 22, 3)
    # The listed target bone lengths give the same features.
    default, _ = process_motion(reference["joints"])
    assert np.abs(default - expected).max() < 0.02  # the same threshold


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
    # float64 on both sides: the facing cancels but for its integration from the features, 169
    # prefix sums of arcsin steps (4 ulp and qmul's 8 each) turning |ric| <= 1.9 m and the root's
    # 5.5 m walk, and the root's own prefix sums; for each side, 2 * 169 * 12 roundings at 7.4 m
    # (observed 3.5 roundings at 2.7 m).
    size = np.abs(fixed_joints).max() + 5.5
    bound = 2 * MARGIN * float64_bound(2 * 169 * 12, size)
    assert np.abs(compat_joints - fixed_joints).max() < bound


@needs_reference
def test_recover_from_rot_matches_ric(reference):
    offsets = target_offsets_from_example(reference["example"])
    joints = recover_from_rot(reference["vecs"], SMPL, offsets)
    # The recorded root and joints carry the original's float32 recovery error (as in the ric
    # test); its 6-D rotations carry its float32 IK: a shortest arc (30 K + 32, K = 10 for this
    # clip's raised arms) composed with the chain's inverse (16) and stored (1), about 350
    # roundings in each bone's direction, doubled in angle and summed down <= 5 levels over
    # <= 1.6 m of bones (observed 1.4e-6 against 1.3e-4 + 3.4e-4).
    ik = 2 * 5 * (30 * _opposition(reference["joints"].astype(np.float64)) + 32 + 16 + 1)
    bound = _recorded_recovery_bound(reference["vecs"]) + 1.6 * gamma(int(ik), U)
    assert np.abs(joints - reference["joints"]).max() < bound


@needs_reference
def test_invariance_to_yaw_and_translation(reference):
    joints = reference["joints"].astype(np.float64)
    base = extract_features(canonicalize(retarget(joints)))
    moved = qrot(yaw_quat(0.7), joints) + np.array([1.5, 0.0, -2.0])
    moved_features = extract_features(canonicalize(retarget(moved)))
    # float64: the yaw and shift move joints by 15 + 15 roundings at |x| <= 3.9 m (retargeting
    # and canonicalising add as many again), which turns bone directions by twice that over the
    # shortest bone (0.057 m); a shortest arc turns by K times a turn of its input and rounds 30 K
    # + 32 (K = 10 for this clip), doubled in angle, for a bone and its parent: the rotations are
    # the largest feature error (observed 284 roundings of unit 6-D entries).
    opposition = _opposition(joints)
    moved_error = 2 * float64_bound(15 + 15, np.abs(moved).max())
    directions = 2 * moved_error / SMPL.bone_lengths[1:].min()
    rotations = 4 * (directions * opposition + float64_bound(30 * opposition + 32))
    bound = MARGIN * (rotations + moved_error)
    assert np.abs(moved_features - base).max() < bound


@needs_reference
def test_fk_of_ik_reproduces_joints_on_target(reference):
    joints = retarget(reference["joints"].astype(np.float64))
    for compat in (True, False):
        local = inverse_kinematics(joints, SMPL, compat=compat)
        rebuilt = forward_kinematics(local, joints[:, 0], SMPL.offsets, SMPL)
        assert np.abs(rebuilt - joints).max() < MARGIN * _fk_of_ik_bound(joints)
    lengths_error = np.abs(SMPL.bone_lengths_of(joints) - SMPL.bone_lengths).max()
    assert lengths_error < MARGIN * _target_lengths_bound(joints)


def test_canonical_frame():
    rng = np.random.default_rng(0)
    joints = _standing_pose(SMPL) + rng.normal(scale=0.01, size=(30, 22, 3))
    joints = qrot(yaw_quat(1.2), joints) + np.array([3.0, 0.4, 1.0])
    canonical = canonicalize(joints)
    # The floor is subtracted (x - x is exactly 0) and the yaw quaternion's x and z parts are
    # exact zeros (a cross product with (0, 1, 0)), so heights pass qrot unrounded: exact. Frame
    # 0's root x and z are subtracted from themselves, a zero vector rotates to zero: exact.
    assert canonical[..., 1].min() == 0.0
    np.testing.assert_array_equal(canonical[0, 0, [0, 2]], 0.0)
    hips = canonical[0, 2] - canonical[0, 1]
    shoulders = canonical[0, 17] - canonical[0, 16]
    forward = np.cross([0, 1.0, 0], hips + shoulders)
    # float64: the shortest arc from frame 0's facing onto +Z (30 K + 32, K = 1 / (2 cos(phi / 2))
    # for its angle phi) doubled in the rotation; qrot's 15 at |x| <= 1.5 m in 4 joints over
    # |across| = 0.51 m (118); the normalisation's 5 (observed 0.5 rounding).
    across = joints[0, 2] - joints[0, 1] + joints[0, 17] - joints[0, 16]
    facing = np.cross([0, 1.0, 0], across)
    opposition = 1 / np.sqrt(2 * (1 + facing[2] / np.linalg.norm(facing)))
    size = np.abs(canonical).max() / np.linalg.norm(hips + shoulders)
    roundings = 2 * (30 * opposition + 32) + 4 * 15 * size + 5
    np.testing.assert_allclose(
        forward / np.linalg.norm(forward),
        [0, 0, 1.0],
        rtol=0,
        atol=MARGIN * float64_bound(roundings),
    )


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
    # Bounds as in the FK-of-IK test, with the source's directions (K = 0.76 here).
    assert np.abs(retarget(source) - expected).max() < MARGIN * _fk_of_ik_bound(expected)
    lengths_error = np.abs(SMPL.bone_lengths_of(retarget(source)) - SMPL.bone_lengths).max()
    assert lengths_error < MARGIN * _target_lengths_bound(expected)
