"""Foot-contact clean-up (t2m.cleanup): planted feet stop, legs keep their lengths."""

from __future__ import annotations

import numpy as np
import pytest

from dataset_tools import cleanup, physical
from dataset_tools.representation import process_motion, recover_from_ric
from dataset_tools.skeleton import SMPL
from tests.conftest import synth_joints

LEGS = ((1, 4, 7, 10), (2, 5, 8, 11))  # hip, knee, ankle, toe


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


def test_planted_feet_stop_and_bones_keep_their_lengths():
    joints, contacts = sliding_walk()
    cleaned = cleanup.clean_joints(joints, contacts)
    np.testing.assert_allclose(lengths(cleaned), lengths(joints), atol=1e-9)
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
    np.testing.assert_allclose(lengths(joints)[:, :2], [[0.40, 0.42]] * 40)
    still = np.repeat(joints[:, [10, 11]].mean(axis=0)[None], 40, axis=0)
    cleaned = cleanup.clean_joints(joints, np.ones((40, 4)))
    # The smoothed correction (a Gaussian of 1 frame) leaves a few millimetres of the sway.
    assert np.abs(cleaned[:, [10, 11]] - still).max() < 0.005
    np.testing.assert_allclose(lengths(cleaned), lengths(joints), atol=1e-9)
    assert physical.skating_ratio(cleaned, 20.0) == 0.0
    monkeypatch.setattr(cleanup, "SMOOTH_FRAMES", 0.0)  # unsmoothed: exactly still
    cleaned = cleanup.clean_joints(joints, np.ones((40, 4)))
    np.testing.assert_allclose(cleaned[:, [10, 11]], still, atol=1e-9)


def test_no_contact_and_no_penetration_changes_nothing():
    joints, contacts = sliding_walk()
    np.testing.assert_array_equal(cleanup.clean_joints(joints, np.zeros_like(contacts)), joints)


def test_a_foot_below_the_floor_is_lifted_to_it():
    joints, contacts = sliding_walk()
    sunk = joints.copy()
    sunk[:, [7, 10], 1] -= 0.03  # the left foot 3 cm lower: shorter shin, into the floor
    cleaned = cleanup.clean_joints(sunk, np.zeros_like(contacts))
    assert cleaned[:, [7, 8, 10, 11], 1].min() >= -1e-9
    np.testing.assert_allclose(lengths(cleaned), lengths(sunk), atol=1e-9)


def test_contact_runs_close_one_frame_gaps_and_drop_short_runs():
    signal = np.array([1, 1, 0, 1, 1, 0, 0, 1, 0, 0, 1, 1, 1], dtype=bool)
    assert cleanup.contact_runs(signal) == [(0, 5), (10, 13)]


def test_cleaned_features_recover_the_cleaned_joints():
    joints, _ = sliding_walk(61)
    features, _ = process_motion(joints)
    contacts = features[:, -4:].copy()
    contacts[:] = 1.0  # every foot planted all along: the strongest correction
    features[:, -4:] = contacts
    cleaned = cleanup.clean_features(features.astype(np.float32))
    assert cleaned.shape == features.shape and cleaned.dtype == np.float32
    np.testing.assert_array_equal(cleaned[:, -4:], contacts)
    np.testing.assert_array_equal(cleaned[:, :4], features[:, :4].astype(np.float32))
    expected = cleanup.clean_joints(recover_from_ric(features, 22), contacts, SMPL)
    np.testing.assert_allclose(recover_from_ric(cleaned, 22), expected, atol=1e-5)
    with pytest.raises(ValueError, match="features must be"):
        cleanup.clean_features(features[:1])


def test_generation_is_cleaned_unless_asked_not_to(tiny_run):
    from t2m.pipeline import TextToMotion

    pipe = TextToMotion.from_checkpoints(tiny_run, device="cpu")
    kwargs = dict(num_samples=3, lengths=60, seed=1)
    raw = pipe.generate("a person walks forward", clean=False, **kwargs)[0]
    cleaned = pipe.generate("a person walks forward", **kwargs)[0]
    for before, after in zip(raw, cleaned):
        np.testing.assert_array_equal(after.features, cleanup.clean_features(before.features))
        np.testing.assert_allclose(after.joints, recover_from_ric(after.features, 22), atol=1e-6)
        assert after.joints[:, [7, 8, 10, 11], 1].min() >= -1e-6  # no foot below the floor


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
