"""Physical-quality metrics (dataset_tools.physical) on constructed motions with known answers.

Ratios are counts over 20 frames or steps, divided once on both sides (k / 20, the same float64
quotient), so they compare exactly: the constructed speeds and heights clear their thresholds by
2 cm/s and 1 cm or more, far beyond any rounding. Sums of float64 values have bounds from their
rounding counts (``tests.tolerances.float64_bound``) times ``MARGIN`` = 10.
"""

from __future__ import annotations

import numpy as np
import pytest

from dataset_tools import physical
from dataset_tools.representation import process_motion
from tests.tolerances import float64_bound

FPS = 20.0
MARGIN = 10
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
    assert physical.skating_ratio(joints, FPS) == 5 / 20
    # At 0.6 m/s the averages are 0.36, 0.48, 0.6, 0.48, 0.36: only the middle step skates.
    slower = standing()
    slower[:, 10, 0] += np.cumsum(slide * 0.6)
    assert physical.skating_ratio(slower, FPS) == 1 / 20
    # The same slide 6 cm up is a foot in the air, not on the floor.
    lifted = joints.copy()
    lifted[:, 10, 1] = 0.06
    assert physical.skating_ratio(lifted, FPS) == 0.0
    # Both feet sliding together still count each step once.
    both = joints.copy()
    both[:, 11, 0] = joints[:, 10, 0] - joints[0, 10, 0] + both[0, 11, 0]
    assert physical.skating_ratio(both, FPS) == 5 / 20
    # Lifting the toe at one frame of the slide breaks the two-frame contact of two steps.
    hop = joints.copy()
    hop[8, 10, 1] = 0.08
    assert physical.skating_ratio(hop, FPS) == 3 / 20


def test_a_floating_body_floats_where_contact_is_predicted():
    joints = standing(20)
    joints[..., 1] += 0.10  # lowest foot joint at 12 cm
    contacts = np.zeros((20, 4))
    contacts[:10, 1] = 1.0  # the left toe predicted on the floor in the first half
    assert physical.floating_ratio(joints, contacts) == 0.5
    assert physical.penetration_mm(joints) == 0.0
    grounded = standing(20)
    assert physical.floating_ratio(grounded, contacts) == 0.0


def test_penetration_is_the_mean_depth_of_the_lowest_foot_joint_in_mm():
    joints = standing(20)
    joints[:10, 8, 1] = -0.02  # right ankle 2 cm below the floor for half the frames
    joints[:5, 11, 1] = -0.03  # and the right toe 3 cm for a quarter: the lowest one counts
    expected = (5 * 30 + 5 * 20) / 20
    # Positive terms, so relative: the heights' literals (1), the mean's 19 sums and division,
    # the product by 1000 (1): 22 roundings; a missed frame is off by 1 mm or more.
    bound = MARGIN * float64_bound(22)
    assert physical.penetration_mm(joints) == pytest.approx(expected, rel=bound, abs=0)


def test_jerk_of_a_jittered_clip():
    joints = standing(30)
    sign = (-1.0) ** np.arange(30)
    joints[:, 20, 0] += 0.001 * sign  # 1 mm alternating in x: third difference 8 mm
    joints[:, 20, 2] += 0.001 * sign  # and in z: summed over xyz, 16 mm
    joints[:, 21, 1] += 0.0015 * sign  # 12 mm on another joint: the larger one is kept
    curve = physical.jerk_curve(joints, FPS)
    assert curve.shape == (27,)
    # Adding the jitter rounds each x once at <= 0.2 m, which the third difference weighs by
    # 1 + 3 + 3 + 1 = 8 and fps^3 by 8000; its own 2 roundings at 8 mm, the product's, the xyz
    # sum's 2 at 128, and the expected 0.016 * 8000's 2 (a lost jitter is off by 32).
    jerk = float64_bound(8, 0.2 * FPS**3) + float64_bound(2 * 0.008 * FPS**3 + 1 + 2 + 2, 128.0)
    np.testing.assert_allclose(curve, 0.016 * FPS**3, rtol=0, atol=MARGIN * jerk)  # 128 m/s^3
    figures = physical.motion_metrics(joints, np.ones((30, 4)), FPS)
    # The mean adds its 27 sums and division at 128; the peak is one of the curve's values.
    mean_bound = MARGIN * (jerk + float64_bound(27, 128.0))
    assert figures["jerk_mean"] == pytest.approx(128.0, rel=0, abs=mean_bound)
    assert figures["jerk_peak"] == pytest.approx(128.0, rel=0, abs=MARGIN * jerk)
    still = physical.motion_metrics(standing(30), np.ones((30, 4)), FPS)
    assert still["jerk_mean"] == still["jerk_peak"] == still["skating_ratio"] == 0.0


def test_mean_curves_and_the_area_between_them():
    curves = [np.full(10, 1.0), np.full(6, 3.0), np.full(4, 5.0)]
    mean = physical.mean_curve(curves)  # indices reached by at least two of the three
    # Small integers: (1 + 3 + 5) / 3 and (1 + 3) / 2 are exact.
    np.testing.assert_array_equal(mean, [3, 3, 3, 3, 2, 2])
    # |3 - 1| over 4 frames and |2 - 1| over 2 frames, 1/20 s each: the sum 10 and 10 / 20 exact.
    assert physical.curve_area(mean, np.ones(8), FPS) == (4 * 2 + 2 * 1) / FPS


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
