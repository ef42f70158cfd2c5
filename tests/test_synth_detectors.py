"""Detectors agree with the generated labels, mirroring swaps sides, plausibility stays in bounds."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from dataset_tools.mirror import mirror_joints
from dataset_tools.synth.clip import synthesize_action, synthesize_clip
from dataset_tools.synth.detectors import detect_labels, plausibility
from dataset_tools.synth.matching import clip_matches, label_matches, mirror_label
from dataset_tools.synth.motions import ACTIONS

SHARED = Path(__file__).resolve().parents[1].parent / "shared"


def _twenty_fps(joints: np.ndarray) -> np.ndarray:
    return joints[::3].astype(np.float64)


def _sample(action: str, seed: int, **fixed) -> tuple[dict, float]:
    rng = np.random.default_rng(seed)
    for _ in range(200):
        params, seconds = ACTIONS[action].sample(rng)
        if all(params.get(k) == v for k, v in fixed.items()):
            return params, seconds
    raise AssertionError(f"no {action} with {fixed}")


def test_walking_forward_moves_along_the_facing():
    params = {"gait": "walk", "direction": "forward", "speed": "normal", "speed_mps": 1.2}
    facts = detect_labels(_twenty_fps(synthesize_action("walk", params, 4.0).joints), 20.0)
    assert facts["forward_speed_mps"] > 1.0 and abs(facts["left_speed_mps"]) < 0.1
    assert label_matches(facts, {"action": "walk", "params": params})
    backward = {**params, "direction": "backward", "speed_mps": 0.9}
    assert not label_matches(facts, {"action": "walk", "params": backward})


def test_turning_left_turns_counterclockwise_and_mirrors_to_right():
    joints = _twenty_fps(synthesize_action("turn", {"direction": "left", "angle": 90}, 2.0).joints)
    facts = detect_labels(joints, 20.0)
    assert 60 < facts["yaw_change_deg"] < 120
    mirrored = detect_labels(mirror_joints(joints), 20.0)
    assert -120 < mirrored["yaw_change_deg"] < -60


def test_wave_right_keeps_the_right_wrist_up_and_swinging():
    joints = _twenty_fps(
        synthesize_action("wave", {"side": "right", "count": 3, "rate_hz": 1.8}, 3.0).joints
    )
    facts = detect_labels(joints, 20.0)
    assert facts["wave_right"] and not facts["wave_left"]
    middle = joints[len(joints) // 3 : 2 * len(joints) // 3]
    assert np.all(middle[:, 21, 1] > middle[:, 17, 1])  # right wrist above right shoulder


def test_jump_lifts_both_feet_and_sitting_lowers_the_pelvis():
    params = {"mode": "in_place", "count": 2, "height_m": 0.25}
    jump = detect_labels(_twenty_fps(synthesize_action("jump", params, 3.0).joints), 20.0)
    assert jump["airborne_count"] == 2 and jump["max_airborne_height_m"] > 0.15
    sit = detect_labels(
        _twenty_fps(synthesize_action("sit", {"hold_s": 1.0, "knee_deg": 30}, 5.0).joints), 20.0
    )
    assert sit["sit"] and sit["pelvis_min_ratio"] < 0.4
    stand = detect_labels(_twenty_fps(synthesize_action("stand", {}, 2.0).joints), 20.0)
    assert not stand["sit"] and stand["airborne_count"] == 0


@pytest.mark.parametrize("action", sorted(ACTIONS))
def test_every_action_is_recognised_and_mirrors_correctly(action):
    for seed in range(4):
        params, seconds = _sample(action, seed)
        label = {"action": action, "params": params}
        joints = _twenty_fps(synthesize_action(action, params, seconds, seed=seed).joints)
        assert label_matches(detect_labels(joints, 20.0), label), params
        mirrored = detect_labels(mirror_joints(joints), 20.0)
        assert label_matches(mirrored, mirror_label(label)), params
        if mirror_label(label) != label:
            # Left and right are never confused: the mirror does not match the original label.
            assert not label_matches(mirrored, label), params


def test_labels_hold_on_a_random_corpus_and_its_mirror():
    matched = mirrored = total = 0
    for index in range(80):
        clip = synthesize_clip(21, index)
        segments = [s.label() for s in clip.segments]
        joints = _twenty_fps(clip.joints)
        matched += sum(clip_matches(joints, 20.0, segments, len(clip.joints)))
        swapped = [mirror_label(s) for s in segments]
        mirrored += sum(clip_matches(mirror_joints(joints), 20.0, swapped, len(clip.joints)))
        total += len(segments)
    assert matched / total >= 0.95
    assert mirrored / total >= 0.95


# Per action: foot skating (m/s) and 95th-percentile root jerk (m/s^3) at 20 fps.
_LIMITS = {
    "walk": (0.1, 250),
    "run": (0.1, 600),
    "turn": (0.25, 150),
    "jump": (0.1, 450),
    "hop": (0.15, 300),
    "kick": (0.15, 250),
    "punch": (0.05, 50),
    "squat": (0.1, 200),
    "sit": (0.1, 100),
    "bow": (0.05, 50),
    "clap": (0.05, 50),
    "wave": (0.05, 50),
    "raise": (0.05, 50),
    "stand": (0.02, 20),
}


@pytest.mark.parametrize("action", sorted(ACTIONS))
def test_plausibility_within_thresholds(action):
    skate, jerk = _LIMITS[action]
    for seed in range(3):
        params, seconds = _sample(action, 100 + seed)
        figures = plausibility(
            _twenty_fps(synthesize_action(action, params, seconds, seed=seed).joints), 20.0
        )
        assert figures["foot_skate_mps"] < skate, (params, figures)
        assert figures["penetration_m"] < 0.002
        assert figures["bone_length_cv"] < 1e-5
        assert figures["knee_flexion_min_deg"] > -1.0  # knees never bend backwards
        assert figures["knee_flexion_max_deg"] < 150
        assert figures["elbow_flexion_max_deg"] < 150
        assert figures["root_jerk_mps3"] < jerk, (params, figures)


def test_plausibility_flags_broken_motion():
    params = {"gait": "walk", "direction": "forward", "speed": "normal", "speed_mps": 1.2}
    joints = _twenty_fps(synthesize_action("walk", params, 3.0).joints)
    sunk = joints.copy()
    sunk[..., 1] -= 0.05
    assert plausibility(sunk, 20.0)["penetration_m"] == pytest.approx(0.05, abs=3e-3)
    stretched = joints.copy()
    stretched[::2, 20] += 0.1
    assert plausibility(stretched, 20.0)["bone_length_cv"] > 0.05
    skating = joints.copy()
    skating[:, [7, 8, 10, 11], 2] += np.arange(len(joints))[:, None] * 0.05
    assert plausibility(skating, 20.0)["foot_skate_mps"] > 0.5
    backwards_knee = joints.copy()
    hip, ankle = backwards_knee[:, 1], backwards_knee[:, 7]
    backwards_knee[:, 4] = (
        hip + (ankle - hip) * 0.5 + np.array([0.0, 0.0, -0.15])
    )  # knee pushed back
    assert plausibility(backwards_knee, 20.0)["knee_flexion_min_deg"] < -10


def test_detectors_reject_bad_input():
    with pytest.raises(ValueError, match="shape"):
        detect_labels(np.zeros((10, 21, 3)), 20.0)
    joints = np.zeros((10, 22, 3))
    joints[3, 4, 1] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        plausibility(joints, 20.0)
    with pytest.raises(ValueError, match="2 frames"):
        detect_labels(np.zeros((1, 22, 3)), 20.0)


@pytest.mark.skipif(not (SHARED / "reference").exists(), reason="../shared/reference is absent")
def test_detectors_run_on_a_real_humanml3d_clip():
    joints = np.load(SHARED / "reference" / "humanml3d" / "new_joints" / "012314.npy")
    facts = detect_labels(joints, 20.0)
    assert all(np.isfinite(v) for v in facts.values() if isinstance(v, float))
    figures = plausibility(joints, 20.0)
    assert figures["bone_length_cv"] < 1e-4 and figures["penetration_m"] < 0.01
    assert figures["foot_skate_mps"] < 0.1 and figures["knee_flexion_min_deg"] > -5


def test_detectors_tell_actions_apart():
    """A clip of one action does not satisfy the labels of clearly different actions."""
    confusions = []
    names = sorted(ACTIONS)
    for action in names:
        params, seconds = _sample(action, 7)
        facts = detect_labels(
            _twenty_fps(synthesize_action(action, params, seconds, seed=3).joints), 20.0
        )
        for other in names:
            if other == action:
                continue
            other_params, _ = _sample(other, 8)
            if label_matches(facts, {"action": other, "params": other_params}):
                confusions.append((action, other))
    assert not confusions
