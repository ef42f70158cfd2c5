"""Foot-contact clean-up (dataset_tools.cleanup): planted feet stop, legs keep their lengths.

The clean-up runs in float64; bounds are rounding counts (``tests.tolerances.float64_bound``) at
the values' magnitude, times ``MARGIN`` = 10, with the two-bone IK's conditioning taken from the
data (``_bending_amplification``); the float32 features carry exactly one rounding of 2^-24 per
value written. Thresholds on behaviour (millimetres of sway) say so.
"""

from __future__ import annotations

import numpy as np
import pytest

from dataset_tools import cleanup, physical
from dataset_tools.kinematics import forward_kinematics
from dataset_tools.representation import FeatureLayout, process_motion, recover_from_ric
from dataset_tools.rotations import axis_angle_to_quat
from dataset_tools.skeleton import SMPL
from tests.conftest import synth_joints
from tests.tolerances import U, float64_bound

LEGS = ((1, 4, 7, 10), (2, 5, 8, 11))  # hip, knee, ankle, toe
MARGIN = 10


def sliding_walk(frames: int = 80) -> tuple[np.ndarray, np.ndarray]:
    """A walk whose root glides at constant speed while the legs swing (so planted feet slide),
    and its contacts (T, 4): each foot planted while its toe is the lower one."""
    joints = synth_joints("walk_forward", frames, np.random.default_rng(3)).astype(np.float64)
    joints[..., 1] -= joints[..., 1].min()  # on the floor
    left_lower = joints[:, 10, 1] <= joints[:, 11, 1]
    contacts = np.stack([left_lower, left_lower, ~left_lower, ~left_lower], axis=1)
    return joints, contacts.astype(np.float64)


def lengths(joints: np.ndarray) -> np.ndarray:
    return np.stack(
        [np.linalg.norm(joints[:, a] - joints[:, b], axis=-1) for leg in LEGS
         for a, b in zip(leg[:-1], leg[1:])],
        axis=1,
    )  # fmt: skip


def _off_line(vectors: np.ndarray, along: np.ndarray) -> np.ndarray:
    """|the part of vectors (T, 3) off the unit directions along (T, 3)|."""
    parallel = np.sum(vectors * along, axis=-1, keepdims=True) * along
    return np.linalg.norm(vectors - parallel, axis=-1)


def _bending_amplification(joints: np.ndarray, contacts: np.ndarray) -> float:
    """The largest r |p| / |p_perp| (metres) over the frames the clean-up moves: the two-bone IK
    bends the new knee (r off the hip-target line) towards the generated one (p = knee - hip),
    whose part off that line, p_perp, is computed with ~5 roundings of |p|; so the new knee's
    bending direction leans towards the line by 5 u |p| / |p_perp| and the thigh's length moves
    by r times that. Nearly straight generated legs make it large (1.7e6 m for a sunk foot)."""
    largest = 0.0
    for side, (hip, knee, ankle, toe) in enumerate(LEGS):
        contact = (contacts[:, 2 * side] > 0.5) | (contacts[:, 2 * side + 1] > 0.5)
        offsets = cleanup.foot_offsets(joints[:, ankle], joints[:, toe], contact)
        moved = np.any(offsets, axis=1)
        if not moved.any():
            continue
        target = joints[:, ankle] + offsets
        new_knee, _ = cleanup.two_bone_knee(
            joints[:, hip], joints[:, knee], joints[:, ankle], target
        )
        along = target - joints[:, hip]
        along /= np.linalg.norm(along, axis=-1, keepdims=True)
        generated = joints[:, knee] - joints[:, hip]
        bend = _off_line(new_knee - joints[:, hip], along)
        ratio = bend * np.linalg.norm(generated, axis=-1) / _off_line(generated, along)
        largest = max(largest, float(ratio[moved].max()))
    return largest


def _lengths_bound(joints: np.ndarray, contacts: np.ndarray) -> float:
    """float64 bound on the change of the legs' bone lengths by ``clean_joints``: the bending
    direction's lean (5 roundings of ``_bending_amplification``); the law of cosines, the unit
    hip-target direction and the root, ~30 roundings of the leg (t^2 + s^2 + d^2) / s <= 3 leg
    lengths; the new knee, ankle and toe (two sums each) and both sides' differences at |x|."""
    leg = float(SMPL.bone_lengths[[4, 7]].sum())
    return (
        float64_bound(5, _bending_amplification(joints, contacts))
        + float64_bound(30, 3 * leg)
        + float64_bound(8, np.abs(joints).max())
    )


def test_planted_feet_stop_and_bones_keep_their_lengths():
    joints, contacts = sliding_walk()
    cleaned = cleanup.clean_joints(joints, contacts)
    # 3.1e-12 (nearly straight synthetic legs: amplification 5.4e2 m); observed 8.2e-14.
    bound = MARGIN * _lengths_bound(joints, contacts)
    np.testing.assert_allclose(lengths(cleaned), lengths(joints), rtol=0, atol=bound)
    legs = [j for leg in LEGS for j in leg[1:]]
    others = [j for j in range(22) if j not in legs]
    np.testing.assert_array_equal(cleaned[:, others], joints[:, others])
    before = physical.skating_ratio(joints, 20.0)
    after = physical.skating_ratio(cleaned, 20.0)
    assert before > 0.3 and after < 0.6 * before  # 0.34 -> 0.18: many locks are out of reach
    assert physical.penetration_mm(cleaned) == 0.0


def bent_pose() -> np.ndarray:
    """A standing pose (22, 3) with both knees bent: thigh 0.40, shin 0.42, hip to ankle 0.76."""
    thigh, shin, reach = 0.40, 0.42, 0.76
    down = (thigh**2 - shin**2 + reach**2) / (2 * reach)  # knee below the hip (law of cosines)
    forward = np.sqrt(thigh**2 - down**2)
    pose = np.zeros((22, 3))
    pose[:, 1] = np.linspace(0.9, 1.7, 22)  # everything else stacked above the pelvis
    for side, (hip, knee, ankle, toe) in zip((1.0, -1.0), LEGS):
        pose[hip] = [0.1 * side, 0.85, 0.0]
        pose[knee] = [0.1 * side, 0.85 - down, forward]
        pose[ankle] = [0.1 * side, 0.85 - reach, 0.0]
        pose[toe] = [0.1 * side, 0.02, 0.12]
    return pose


def test_a_swaying_body_keeps_its_planted_toes_still(monkeypatch):
    joints = np.repeat(bent_pose()[None], 40, axis=0)
    joints[..., 0] += 0.04 * np.sin(np.linspace(0, 4 * np.pi, 40))[:, None]  # sways 4 cm
    # The law of cosines and the sway, a few roundings at <= 0.85 m (observed exact).
    construction = MARGIN * float64_bound(10, 0.85)
    np.testing.assert_allclose(
        lengths(joints)[:, :2], [[0.40, 0.42]] * 40, rtol=0, atol=construction
    )
    still = np.repeat(joints[:, [10, 11]].mean(axis=0)[None], 40, axis=0)
    contacts = np.ones((40, 4))
    cleaned = cleanup.clean_joints(joints, contacts)
    # A behavioural threshold, not rounding: the smoothed correction (a Gaussian of 1 frame)
    # leaves a few millimetres of the 4 cm sway (observed 4.5 mm); unlocked toes move 4 cm.
    assert np.abs(cleaned[:, [10, 11]] - still).max() < 0.005
    bound = MARGIN * _lengths_bound(joints, contacts)  # bent knees: amplification 0.4 m
    np.testing.assert_allclose(lengths(cleaned), lengths(joints), rtol=0, atol=bound)
    assert physical.skating_ratio(cleaned, 20.0) == 0.0
    monkeypatch.setattr(cleanup, "SMOOTH_FRAMES", 0.0)  # unsmoothed: exactly still
    cleaned = cleanup.clean_joints(joints, np.ones((40, 4)))
    # The run's mean of 40 toe positions on both sides (any order) at <= 0.2 m; the target, the
    # IK's hip + unit direction times distance (~8 at <= 1 m) and the toe following the ankle
    # (2): observed 0.75 roundings.
    bound = MARGIN * (float64_bound(2 * 40, 0.2) + float64_bound(10, 1.0))
    np.testing.assert_allclose(cleaned[:, [10, 11]], still, rtol=0, atol=bound)


def test_no_contact_and_no_penetration_changes_nothing():
    joints, contacts = sliding_walk()
    np.testing.assert_array_equal(cleanup.clean_joints(joints, np.zeros_like(contacts)), joints)


def test_a_foot_below_the_floor_is_lifted_to_it():
    joints, contacts = sliding_walk()
    sunk = joints.copy()
    sunk[:, [7, 10], 1] -= 0.03  # the left foot 3 cm lower: shorter shin, into the floor
    cleaned = cleanup.clean_joints(sunk, np.zeros_like(contacts))
    # Lifted onto the floor up to the lift's own rounding and the IK's reconstruction of the
    # target height (~10 roundings at <= 1 m) and the toe following (2) (observed exactly 0).
    assert cleaned[:, [7, 8, 10, 11], 1].min() >= -MARGIN * float64_bound(12, 1.0)
    # 9.2e-9 (amplification 1.7e6 m: sinking straight legs puts generated knees within 1e-7 of
    # the hip-target line); observed 5.4e-13. A wrong knee formula is off by millimetres.
    bound = MARGIN * _lengths_bound(sunk, np.zeros_like(contacts))
    np.testing.assert_allclose(lengths(cleaned), lengths(sunk), rtol=0, atol=bound)


def _hovering_step(height_in_run: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One foot standing still at ``height_in_run`` (its toe) over frames 10-19, the contact run,
    with 5 cm of air on either side, ankle 6 cm above the toe: (ankle, toe, contact)."""
    toe = np.zeros((30, 3))
    toe[:, 1] = 0.05
    toe[10:20, 1] = height_in_run
    ankle = toe + np.array([0.0, 0.06, -0.1])
    contact = np.zeros(30, dtype=bool)
    contact[10:20] = True
    return ankle, toe, contact


def test_a_lowered_foot_leaves_the_floor_as_generated():
    ankle, toe, contact = _hovering_step(0.04)  # hovering 4 cm: lowered to 2 cm in the run
    offsets = cleanup.foot_offsets(ankle, toe, contact)
    assert np.allclose(offsets[14:16, 1], cleanup.PLANT_HEIGHT_M - 0.04, atol=1e-6)
    # Out of the run only the Gaussian's tail of the 2 cm step (2.5 sigma and more: under
    # 0.13 mm); a lowering carried on over BLEND_FRAMES held the foot 4.7 mm lower 3 frames out.
    outside = np.r_[0:8, 22:30]
    assert np.abs(offsets[outside, 1]).max() < 2e-4


def test_a_lift_out_of_the_floor_fades_out():
    ankle, toe, contact = _hovering_step(-0.02)  # sunk 2 cm: lifted onto the floor in the run
    offsets = cleanup.foot_offsets(ankle, toe, contact)
    assert np.allclose(offsets[14:16, 1], 0.02, atol=1e-6)
    # Two frames after the run half the lift is left (smoothstep over BLEND_FRAMES + 1 = 4),
    # rounded by the Gaussian: the foot does not drop back at once.
    assert 0.006 < offsets[21, 1] < 0.014 and 0.006 < offsets[8, 1] < 0.014


def test_contact_runs_close_one_frame_gaps_and_drop_short_runs():
    signal = np.array([1, 1, 0, 1, 1, 0, 0, 1, 0, 0, 1, 1, 1], dtype=bool)
    assert cleanup.contact_runs(signal) == [(0, 5), (10, 13)]


def test_cleaned_features_recover_the_cleaned_joints():
    joints, _ = sliding_walk(61)
    features, _ = process_motion(joints)
    contacts = features[:, -4:].copy()
    contacts[:] = 1.0  # every foot planted all along: the strongest correction
    features[:, -4:] = contacts
    given = features.astype(np.float32)
    cleaned = cleanup.clean_features(given)
    assert cleaned.shape == features.shape and cleaned.dtype == np.float32
    np.testing.assert_array_equal(cleaned[:, -4:], contacts)
    np.testing.assert_array_equal(cleaned[:, :4], given[:, :4])
    # The clean-up of the joints recovered from the same float32 features: the root channels
    # are kept, so the root is recovered identically; the ric written to float32 round once
    # (2^-24 of |ric| after the facing turn, which keeps norms) and the recovered joints once
    # more at |x| (observed 1.2e-7 against 3.3e-7). (Against float64 features the IK's bending
    # direction would amplify their float32 rounding: ``_bending_amplification``.)
    layout = FeatureLayout(22)
    expected = cleanup.clean_joints(recover_from_ric(given.astype(np.float64), 22), contacts, SMPL)
    ric = np.linalg.norm(cleaned[:, layout.ric].reshape(len(cleaned), -1, 3), axis=-1).max()
    bound = U * (ric + np.abs(expected).max()) + MARGIN * float64_bound(40, np.abs(expected).max())
    np.testing.assert_allclose(recover_from_ric(cleaned, 22), expected, rtol=0, atol=bound)
    with pytest.raises(ValueError, match="features must be"):
        cleanup.clean_features(features[:1])


def test_generation_is_cleaned_unless_asked_not_to(tiny_run):
    from t2m.pipeline import TextToMotion

    pipe = TextToMotion.from_checkpoints(tiny_run, device="cpu")
    kwargs = dict(num_samples=3, lengths=60, seed=1)
    raw = pipe.generate("a person walks forward", clean=False, **kwargs)[0]
    cleaned = pipe.generate("a person walks forward", **kwargs)[0]
    for before, after in zip(raw, cleaned):
        # clean=False is the rigid motion (dataset_tools.rigid), rounded to float32 before this
        # clean-up and not before the pipeline's
        np.testing.assert_allclose(
            after.features, cleanup.clean_features(before.features), rtol=0, atol=1e-5
        )
        # The pipeline's joints are this very recovery of these features: exact.
        np.testing.assert_array_equal(after.joints, recover_from_ric(after.features, 22))
        # No foot below the floor: heights pass the facing turns (quaternions about y) exactly,
        # so the float64 clean-up's lift (12 roundings at |x|, as above) only rounds to float32.
        floor = MARGIN * float64_bound(12, np.abs(after.joints).max())
        assert after.joints[:, [7, 8, 10, 11], 1].min() >= -floor


def test_evaluation_of_cleaned_motions(tiny_run, tiny_dataset, tmp_path):
    import json

    from t2m.evaluate import main

    out = tmp_path / "results"
    args = ["--dataset", str(tiny_dataset), "--checkpoints", str(tiny_run), "--split", "all"]
    args += ["--replications", "1", "--mm-texts", "2", "--mm-samples", "2", "--out", str(out)]
    assert main([*args, "--clean"]) == 0
    summary = json.loads((out / "results.json").read_text())
    assert "clean = True (standard: False)" in summary["deviations"]
    for row in ("Ours (ground-truth length)", "Ours (sampled length)"):
        assert summary["rows"][row]["physical_penetration_mm"]["mean"] == 0.0
    # finished as t2m.sample finishes them: rigid, as the real motions are
    for row in ("Real motions", "Ours (ground-truth length)", "Ours (sampled length)"):
        assert summary["rows"][row]["physical_bone_stretch_max_m"]["mean"] < 1e-5


def test_a_large_correction_keeps_the_knee_bending_forward():
    """The knee bends as the generated knee bends off the generated leg's own hip-ankle line: a
    foot lock that moves the ankle far ahead swings the hip-target line past a forward-bent
    knee, and measured off that line the knee bent backward (164 of 62,096 leg-frames of 300
    demo-model motions bent 3 cm or more backward after the clean-up, none before it)."""
    hip = np.zeros((1, 3))
    ankle = np.array([[0.0, -0.8, 0.0]])
    knee = np.array([[0.0, -0.4, 0.1]])  # bent forward (+z), as knees bend
    target = np.array([[0.0, -0.7, 0.35]])  # the ankle moved 35 cm ahead and 10 cm up
    new_knee, new_ankle = cleanup.two_bone_knee(hip, knee, ankle, target)
    axis = (new_ankle - hip) / np.linalg.norm(new_ankle - hip)
    bend = new_knee - hip - np.sum((new_knee - hip) * axis) * axis
    assert bend[0, 2] > 0.05  # still ahead of the new hip-ankle line, not behind it
    np.testing.assert_allclose(np.linalg.norm(new_knee - hip), np.linalg.norm(knee - hip))


def _front(
    joints: np.ndarray, hip: int, ankle: int, right_hip: int = 2, left_hip: int = 1
) -> np.ndarray:
    """(T, 3) unit front of a leg: square to its hip-ankle line and to the hips' left-right
    axis (SMPL's hips by default)."""
    line = joints[:, ankle] - joints[:, hip]
    line /= np.linalg.norm(line, axis=-1, keepdims=True)
    front = np.cross(joints[:, right_hip] - joints[:, left_hip], line)
    return front / np.linalg.norm(front, axis=-1, keepdims=True)


def _ahead(joints: np.ndarray, hip: int, knee: int, ankle: int) -> np.ndarray:
    """(T,) how far the knee sits in front of its hip-ankle line (m; negative: behind)."""
    return np.sum((joints[:, knee] - joints[:, hip]) * _front(joints, hip, ankle), axis=-1)


def test_a_knee_bent_behind_the_leg_is_mirrored_to_the_front():
    """front_knees mirrors a knee that bends behind its hip-ankle line to the front and moves
    nothing else: the thigh and shin keep their lengths, forward knees and held knees stay."""
    # a crouch that sways and turns, knees bent forward as knees bend
    t = np.arange(40) / 20.0
    axis_angles = np.zeros((40, 22, 3))
    axis_angles[:, 0, 1] = 0.6 * t  # turning
    bend = 0.45 + 0.15 * np.sin(2 * np.pi * t)[:, None]
    axis_angles[:, [4, 5], 0] = -bend  # thighs forward (each joint's rotation turns its bone)
    axis_angles[:, [7, 8], 0] = 2 * bend  # shins back
    root = np.stack([0.1 * np.sin(2 * np.pi * t), np.ones(40), 0.3 * t], axis=1)
    joints = forward_kinematics(axis_angle_to_quat(axis_angles), root, SMPL.offsets, SMPL)
    hip, knee, ankle = 1, 4, 7
    assert (_ahead(joints, hip, knee, ankle) > 0.03).all()
    behind = joints.copy()
    ahead = _ahead(joints, hip, knee, ankle)
    front = _front(joints, hip, ankle)
    frames = np.arange(10, 25)  # the left knee mirrored behind the line on these frames
    behind[frames, knee] -= 2 * ahead[frames, None] * front[frames]
    assert (_ahead(behind, hip, knee, ankle)[frames] < -0.03).all()
    fronted = cleanup.front_knees(behind)
    # back where the walk had it, to the rounding of two mirrors (each a unit line, a cross
    # product, its norm, a dot product and a subtraction: under 16 roundings at 1 m), x MARGIN
    bound = float64_bound(32, 1.0) * MARGIN
    np.testing.assert_allclose(fronted, joints, rtol=0, atol=bound)
    np.testing.assert_array_equal(np.delete(fronted, knee, axis=1), np.delete(behind, knee, 1))
    np.testing.assert_allclose(lengths(fronted), lengths(behind), rtol=0, atol=bound)
    # a knee held on a frame stays behind there
    free = np.ones(joints.shape[:2], bool)
    free[frames[:3], knee] = False
    held = cleanup.front_knees(behind, free=free)
    np.testing.assert_array_equal(held[frames[:3]], behind[frames[:3]])
    np.testing.assert_allclose(held[frames[3:]], joints[frames[3:]], rtol=0, atol=bound)


def test_front_knees_finds_the_knees_of_a_kit_skeleton():
    """On KIT-ML's 21 joints the knees are the joints after the hips (face_joints) along the
    leg chains, not the parents of the contact joints (the foot's, below the ankle there)."""
    from dataset_tools.skeleton import KIT

    axis_angles = np.zeros((4, 21, 3))
    right_hip, left_hip = KIT.face_joints[:2]
    legs = []
    for hip in (left_hip, right_hip):
        chain = next(c for c in KIT.chains if hip in c)
        legs.append(chain[chain.index(hip) : chain.index(hip) + 3])  # hip, knee, ankle
    # the body's front is up x (face_joints[0] - face_joints[1]), as process_motion faces it:
    # -z for this rest pose, so the thighs turn toward -z and the shins back
    for _, knee, ankle in legs:
        axis_angles[:, knee, 0] = 0.5  # each joint's rotation turns its bone
        axis_angles[:, ankle, 0] = -1.0
    joints = forward_kinematics(axis_angle_to_quat(axis_angles), np.ones((4, 3)), KIT.offsets, KIT)
    front = []
    for hip, knee, ankle in legs:
        ahead = _front(joints, hip, ankle, right_hip, left_hip)
        front.append(ahead)
        bend = np.sum((joints[:, knee] - joints[:, hip]) * ahead, axis=-1)
        assert (bend > 0.05).all()  # bent forward, as the dataset's facing has it
    behind = joints.copy()
    for (hip, knee, _), ahead in zip(legs, front):
        bend = np.sum((joints[:, knee] - joints[:, hip]) * ahead, axis=-1)
        behind[:, knee] -= 2 * bend[:, None] * ahead
    bound = float64_bound(32, 2.0) * MARGIN  # as above, at the skeleton's 2 m
    np.testing.assert_allclose(cleanup.front_knees(behind, KIT), joints, rtol=0, atol=bound)
    np.testing.assert_array_equal(cleanup.front_knees(joints, KIT), joints)


def test_a_kit_legs_clean_up_bends_the_knee():
    """On KIT-ML's 21 joints the contact joints lie below the ankle: the clean-up takes hip,
    knee and ankle from the leg chain (cleanup.leg_of), so a locked foot bends the knee and the
    whole foot moves with the ankle (read as the contact joint's parent and grandparent, the
    ankle bent as a knee and the knee stayed where it was)."""
    from dataset_tools.skeleton import KIT

    frames = 60
    t = np.arange(frames) / 20.0
    axis_angles = np.zeros((frames, 21, 3))
    for knee, ankle, phase in ((12, 13, 0.0), (17, 18, np.pi)):  # each rotation turns its bone
        axis_angles[:, knee, 0] = -(0.4 * np.sin(2 * np.pi * t + phase) + 0.3)
        axis_angles[:, ankle, 0] = 0.6
    root = np.stack([np.zeros(frames), np.ones(frames), 0.3 * t], axis=1)  # gliding forward
    joints = forward_kinematics(axis_angle_to_quat(axis_angles), root, KIT.offsets, KIT)
    joints[..., 1] -= joints[..., 1].min()
    contacts = np.zeros((frames, 4))
    contacts[20:40] = 1.0  # both feet planted for a second while the body glides 30 cm
    assert [cleanup.leg_of(KIT, foot) for foot, _ in (KIT.feet_left, KIT.feet_right)] == [
        (16, 17, 18),
        (11, 12, 13),
    ]
    cleaned = cleanup.clean_joints(joints, contacts, KIT)
    moved = np.abs(cleaned - joints).max(axis=(0, 2))
    assert moved[12] > 0.05 and moved[17] > 0.05  # the knees bend
    bound = float64_bound(64, 2.0) * MARGIN  # the IK's few dozen roundings at 2 m, x MARGIN
    for a, b in ((11, 12), (12, 13), (13, 14), (14, 15), (16, 17), (17, 18), (18, 19), (19, 20)):
        np.testing.assert_allclose(
            np.linalg.norm(cleaned[:, a] - cleaned[:, b], axis=-1),
            np.linalg.norm(joints[:, a] - joints[:, b], axis=-1),
            rtol=0,
            atol=bound,
        )
    step = np.linalg.norm(np.diff(cleaned[20:40, [13, 18]], axis=0), axis=-1).max()
    glide = np.linalg.norm(np.diff(joints[20:40, [13, 18]], axis=0), axis=-1).max()
    assert step < 0.5 * glide  # the planted ankles held back
