"""Physical-quality metrics (t2m.evaluate.physical) on constructed motions with known answers."""

from __future__ import annotations

import numpy as np
import pytest

from dataset_tools import physical
from dataset_tools.representation import process_motion

FPS = 20.0
FEET = (7, 8, 10, 11)


def standing(frames: int = 21, foot_height: float = 0.02) -> np.ndarray:
    """A still body (frames, 22, 3): foot joints at ``foot_height``, the rest 0.5 .. 1.6 m up."""
    pose = np.zeros((22, 3))
    pose[:, 1] = np.linspace(0.5, 1.6, 22)
    pose[:, 0] = np.linspace(-0.2, 0.2, 22)
    pose[list(FEET), 1] = foot_height
    return np.repeat(pose[None], frames, axis=0)


def test_a_foot_sliding_fast_skates_for_its_windowed_steps():
    joints = standing()  # 21 frames: 20 steps
    # The left toe (joint 10) slides 5 cm per frame (1 m/s) during steps 5..9, then stays.
    slide = np.zeros(21)
    slide[6:11] = 0.05
    joints[:, 10, 0] += np.cumsum(slide)
    # Each of the 5 steps moves at 1 m/s; the 5-step averages there are 0.6, 0.8, 1, 0.8, 0.6.
    assert physical.skating_ratio(joints, FPS) == pytest.approx(5 / 20)
    # At 0.6 m/s the averages are 0.36, 0.48, 0.6, 0.48, 0.36: only the middle step skates.
    slower = standing()
    slower[:, 10, 0] += np.cumsum(slide * 0.6)
    assert physical.skating_ratio(slower, FPS) == pytest.approx(1 / 20)
    # The same slide 6 cm up is a foot in the air, not on the floor.
    lifted = joints.copy()
    lifted[:, 10, 1] = 0.06
    assert physical.skating_ratio(lifted, FPS) == 0.0
    # Both feet sliding together still count each step once.
    both = joints.copy()
    both[:, 11, 0] = joints[:, 10, 0] - joints[0, 10, 0] + both[0, 11, 0]
    assert physical.skating_ratio(both, FPS) == pytest.approx(5 / 20)
    # Lifting the toe at one frame of the slide breaks the two-frame contact of two steps.
    hop = joints.copy()
    hop[8, 10, 1] = 0.08
    assert physical.skating_ratio(hop, FPS) == pytest.approx(3 / 20)


def test_a_floating_body_floats_where_contact_is_predicted():
    joints = standing(20)
    joints[..., 1] += 0.10  # lowest foot joint at 12 cm
    contacts = np.zeros((20, 4))
    contacts[:10, 1] = 1.0  # the left toe predicted on the floor in the first half
    assert physical.floating_ratio(joints, contacts) == pytest.approx(0.5)
    assert physical.penetration_mm(joints) == 0.0
    grounded = standing(20)
    assert physical.floating_ratio(grounded, contacts) == 0.0


def test_penetration_is_the_mean_depth_of_the_lowest_foot_joint_in_mm():
    joints = standing(20)
    joints[:10, 8, 1] = -0.02  # right ankle 2 cm below the floor for half the frames
    joints[:5, 11, 1] = -0.03  # and the right toe 3 cm for a quarter: the lowest one counts
    expected = (5 * 30 + 5 * 20) / 20
    assert physical.penetration_mm(joints) == pytest.approx(expected)


def test_jerk_of_a_jittered_clip():
    joints = standing(30)
    sign = (-1.0) ** np.arange(30)
    joints[:, 20, 0] += 0.001 * sign  # 1 mm alternating in x: third difference 8 mm
    joints[:, 20, 2] += 0.001 * sign  # and in z: summed over xyz, 16 mm
    joints[:, 21, 1] += 0.0015 * sign  # 12 mm on another joint: the larger one is kept
    curve = physical.jerk_curve(joints, FPS)
    assert curve.shape == (27,)
    np.testing.assert_allclose(curve, 0.016 * FPS**3)  # 128 m/s^3
    figures = physical.motion_metrics(joints, np.ones((30, 4)), FPS)
    assert figures["jerk_mean"] == pytest.approx(128.0)
    assert figures["jerk_peak"] == pytest.approx(128.0)
    still = physical.motion_metrics(standing(30), np.ones((30, 4)), FPS)
    assert still["jerk_mean"] == still["jerk_peak"] == still["skating_ratio"] == 0.0


def test_mean_curves_and_the_area_between_them():
    curves = [np.full(10, 1.0), np.full(6, 3.0), np.full(4, 5.0)]
    mean = physical.mean_curve(curves)  # indices reached by at least two of the three
    np.testing.assert_allclose(mean, [3, 3, 3, 3, 2, 2])
    # |3 - 1| over 4 frames and |2 - 1| over 2 frames, 1/20 s each.
    assert physical.curve_area(mean, np.ones(8), FPS) == pytest.approx((4 * 2 + 2 * 1) / FPS)


def test_row_figures_from_features_of_a_real_walk():
    from tests.conftest import synth_joints

    rng = np.random.default_rng(0)
    motions = [process_motion(synth_joints("walk_forward", 80, rng))[0] for _ in range(3)]
    row = physical.row_physics(motions, FPS)
    assert set(row.metrics) == set(physical.METRIC_NAMES)
    assert all(np.isfinite(v) and v >= 0 for v in row.metrics.values())
    rows = physical.rows_physics({"real": row}, row, FPS)
    assert rows["real"]["jerk_area"] == 0.0
    with pytest.raises(ValueError, match="joints must be"):
        physical.skating_ratio(np.zeros((5, 22)), FPS)
