"""The body's height near an edit's seams (:func:`t2m.edit.keep.keep_floor`, called by
:func:`t2m.edit.keep.finish_plan`): where the model stands on the floor, the finished result
stands on it too; a body the seam carried into the floor is lifted out of it; frames with a kept
joint are never moved.

Synthetic features: a source that stands and, over its last kept frames, pushes off the floor
(the whole body rising 1 cm a frame, 5 cm up at the seam), and a generated motion that stands
on the floor in the same pose. The seam carries the source's height and its rate of rise into
the generated side: without the floor the body hangs up to 9 cm over it for most of a second.
"""

from __future__ import annotations

import numpy as np
import pytest

import t2m.edit.keep as keep_module
from dataset_tools.kinematics import forward_kinematics
from dataset_tools.representation import FeatureLayout, process_motion, recover_from_ric
from dataset_tools.rotations import axis_angle_to_quat
from dataset_tools.skeleton import SMPL
from t2m.edit.keep import finish_plan, keep_floor
from t2m.edit.plan import EditPlan
from t2m.edit.source import half_yaw_of

FRAMES, KEPT = 64, 20
FEET = [7, 8, 10, 11]


def crouch_features(bend: np.ndarray, lift: np.ndarray) -> np.ndarray:
    """Features (len(bend) - 1, 263) of a stance with knees bent by ``bend`` (radians, per
    frame), the lowest foot joint ``lift`` (metres, per frame) over the floor."""
    axis_angles = np.zeros((len(bend), 22, 3))
    axis_angles[:, [1, 2], 0] = -0.5 * bend[:, None]  # hips and ankles against the knees
    axis_angles[:, [7, 8], 0] = -0.5 * bend[:, None]
    axis_angles[:, [4, 5], 0] = bend[:, None]
    joints = forward_kinematics(
        axis_angle_to_quat(axis_angles), np.zeros((len(bend), 3)), SMPL.offsets, SMPL
    )
    joints[..., 1] += lift[:, None] - joints[:, FEET, 1].min(axis=1)[:, None]
    features, _ = process_motion(joints)
    features[:, FeatureLayout(22).foot_contact] = 1.0
    return features


@pytest.fixture(scope="module")
def rising() -> tuple[np.ndarray, EditPlan]:
    bend = np.full(FRAMES + 1, 0.4)
    push = 0.01 * np.clip(np.arange(FRAMES + 1) - (KEPT - 6), 0, None)  # 5 cm at the seam
    source = crouch_features(bend, push)
    generated = crouch_features(bend, np.zeros(FRAMES + 1))  # the model stands on the floor
    keep = np.zeros((FRAMES, 22), bool)
    keep[:KEPT] = True
    target = np.full((FRAMES, 22, 3), np.nan)
    target[keep] = recover_from_ric(source, 22)[keep]
    kept_source = np.where(keep.any(axis=1)[:, None], source, np.nan)
    plan = EditPlan("a person stands", FRAMES, target, keep, kept_source, half_yaw_of(source))
    return generated, plan


def lowest_foot(features: np.ndarray) -> np.ndarray:
    return recover_from_ric(features.astype(np.float64), 22)[:, FEET, 1].min(axis=1)


def test_the_finished_edit_stands_where_the_model_stands(rising, monkeypatch):
    generated, plan = rising
    finished = finish_plan(generated, plan, clean=False)
    # on the floor once the smoothed shift has settled (two frames after the seam)
    assert lowest_foot(finished)[KEPT + 2 :].max() < 0.005
    joints = recover_from_ric(finished.astype(np.float64), 22)
    np.testing.assert_allclose(joints[:KEPT], plan.target[:KEPT], atol=1e-5)  # kept exactly
    # without the floor, the seam's rising pelvis lifts the whole body off the ground
    monkeypatch.setattr(keep_module, "keep_floor", lambda features, *args, **kwargs: features)
    floating = finish_plan(generated, plan, clean=False)
    assert lowest_foot(floating)[KEPT:].max() > 0.05


def test_a_body_carried_into_the_floor_is_lifted_out_of_it_and_kept_frames_stay(rising):
    generated, plan = rising
    layout = FeatureLayout(22)
    airborne = generated.copy()
    airborne[:, layout.ric.start + 1 : layout.ric.stop : 3] += 0.3  # the model's body in the air
    airborne[:, layout.root_height] += 0.3
    sunk = generated.copy()
    sunk[:, layout.ric.start + 1 : layout.ric.stop : 3] -= 0.1  # made 10 cm into the floor
    sunk[:, layout.root_height] -= 0.1
    out = keep_floor(sunk, airborne, plan.keep, sigma=0.0)
    assert lowest_foot(out)[KEPT:] == pytest.approx(0.0, abs=1e-6)  # on the floor, not at 0.3
    kept_joints = recover_from_ric(out.astype(np.float64), 22)[:KEPT]
    np.testing.assert_array_equal(kept_joints, recover_from_ric(sunk.astype(np.float64), 22)[:KEPT])
    # a body in the air where the model is in the air stays where it is
    lifted = generated.copy()
    lifted[:, layout.ric.start + 1 : layout.ric.stop : 3] += 0.2
    lifted[:, layout.root_height] += 0.2
    np.testing.assert_array_equal(keep_floor(lifted, airborne, plan.keep), lifted)
    # before a kept end the body is only lifted out of the floor, not put down on it: there the
    # path is bent toward the kept end's, and feet put down slide
    ends = plan.keep.copy()
    ends[-KEPT:] = True
    floating = keep_floor(lifted, generated, ends, sigma=0.0)
    height = lowest_foot(floating)
    middle = (KEPT + FRAMES - KEPT) // 2
    assert height[KEPT:middle] == pytest.approx(0.0, abs=1e-6)  # after the kept start: down
    assert height[middle + 1 : FRAMES - KEPT] == pytest.approx(0.2, abs=1e-6)  # before the end
    sunk_ends = keep_floor(sunk, generated, ends, sigma=0.0)
    assert lowest_foot(sunk_ends)[KEPT : FRAMES - KEPT] == pytest.approx(0.0, abs=1e-6)
    # every frame with a kept joint (a body edit) is left alone
    legs = np.zeros_like(plan.keep)
    legs[:, [0, 1, 2, 4, 5, 7, 8, 10, 11]] = True
    np.testing.assert_array_equal(keep_floor(sunk, generated, legs), sunk)
