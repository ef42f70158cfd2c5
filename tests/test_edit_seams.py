"""The hard keep's seams (:func:`t2m.edit.keep.hard_keep`): a free run meets the kept frame in
value and in per-frame change, and the offset that makes it meet is eased out with zero slope at
both ends (smoothstep), not cut off or ramped linearly; the generated side's jitter next to a
seam is smoothed first (:func:`t2m.edit.keep.smooth_seams`); where compose joins two generated
windows both sides are smoothed (:func:`t2m.edit.keep.smooth_join`).

Synthetic features on a non-root joint (the root's heading and path bending are not involved):
the kept frames 0-7 of joint 5, the free run 8-63, ``blend`` 16 frames.
"""

from __future__ import annotations

import numpy as np
import pytest

from dataset_tools.representation import FeatureLayout
from t2m.edit.keep import (
    JOIN_REACH_SECONDS,
    SEAM_SMOOTH_FRAMES,
    _seam_weights,
    hard_keep,
    joint_columns,
    smooth_join,
    smooth_seams,
    trend_columns,
)
from t2m.edit.plan import EditPlan

FRAMES, KEPT, BLEND, JOINT = 64, 8, 16, 5


def _plan(source: np.ndarray) -> EditPlan:
    keep = np.zeros((FRAMES, 22), bool)
    keep[:KEPT, JOINT] = True
    target = np.full((FRAMES, 22, 3), np.nan)
    return EditPlan("a person waves", FRAMES, target, keep, source_features=source)


def test_the_seam_offset_eases_out_with_zero_slope_at_both_ends():
    columns = joint_columns(22)[JOINT]
    source = np.zeros((FRAMES, 263))
    generated = np.zeros((FRAMES, 263))
    generated[:, columns] = 1.0  # the free run sits 1 away from the kept value
    out = hard_keep(generated, _plan(source), blend=BLEND)
    weight = -(out[:, columns] - generated[:, columns])[:, 0]  # share of the offset applied
    assert np.all(out[:KEPT, columns] == 0.0)  # kept exactly
    assert weight[KEPT - 1 + BLEND :] == pytest.approx(0.0, abs=1e-12)  # gone after blend frames
    assert np.all(np.diff(weight[KEPT - 1 : KEPT + BLEND]) <= 0)  # fades monotonically
    # zero slope where it starts and where it ends: the first and the last step of the fade
    # are 3/b^2 - 2/b^3 = 0.011 of the offset for smoothstep (a linear ramp: 1/b = 0.0625)
    first_step = weight[KEPT - 1] - weight[KEPT]
    last_step = weight[KEPT + BLEND - 2] - weight[KEPT + BLEND - 1]
    assert first_step < 0.02 and last_step < 0.02, (first_step, last_step)
    assert weight[KEPT - 1 + BLEND // 2] == pytest.approx(0.5)  # symmetric about the middle
    # a hard cut (no easing) would apply the whole offset up to a frame and none after it
    assert np.max(-np.diff(weight)) < 0.1


def test_the_free_run_meets_the_kept_frame_in_its_rate_of_change():
    columns = joint_columns(22)[JOINT]
    trend = trend_columns(FeatureLayout(22))[columns]
    assert trend.sum() == 9 and (~trend).sum() == 3  # position + 6-D rotation; local velocity
    source = np.zeros((FRAMES, 263))
    source[:, columns] = 0.1 * np.arange(FRAMES)[:, None]  # the kept side moves 0.1 a frame
    generated = np.zeros((FRAMES, 263))  # the generated side stands still
    out = hard_keep(generated, _plan(source), blend=BLEND)
    kept_step = source[KEPT - 1, columns] - source[KEPT - 2, columns]
    seam_step = out[KEPT, columns] - out[KEPT - 1, columns]
    # positions and rotations: smoothstep keeps 0.989 of offset + change, the step across the
    # seam is 0.091 for 0.1 (a linear ramp: 0.050; meeting the value alone: -0.008)
    assert seam_step[trend] == pytest.approx(kept_step[trend], abs=0.015)
    # velocities meet the kept value only (their rate of change is an acceleration, not carried)
    offset = source[KEPT - 1, columns] - generated[KEPT - 1, columns]
    weights, _ = _seam_weights(KEPT, FRAMES, FRAMES, BLEND)
    np.testing.assert_allclose(out[KEPT:, columns][:, ~trend], weights[:, None] * offset[~trend])
    # and it returns to the generated motion once the blend is over
    assert np.all(out[KEPT - 1 + BLEND :, columns] == pytest.approx(0.0, abs=1e-12))


def test_the_generated_side_of_a_seam_is_smoothed():
    columns = joint_columns(22)[JOINT]
    source = np.zeros((FRAMES, 263))
    generated = np.zeros((FRAMES, 263))
    # the model's jitter where it takes over from the kept start: +-1 cm a frame
    generated[:, columns] = 0.01 * (-1.0) ** np.arange(FRAMES)[:, None]
    out = hard_keep(generated, _plan(source), blend=BLEND)
    jerk = np.abs(np.diff(out[:, columns[0]], 3))  # jerk[t]: frames t..t+3
    raw_jerk = np.abs(np.diff(generated[:, columns[0]], 3))  # 0.08 everywhere
    # across the seam and over the first three free frames a small share of the jitter is left
    # (observed <= 0.008 of 0.08: the Gaussian of 2.5 frames, fading out over 9 frames; without
    # the smoothing the seam's offset leaves the jitter whole)
    seam = jerk[KEPT - 3 : KEPT + 1]
    assert seam.max() < 0.25 * raw_jerk.max(), seam
    # the smoothing fades out: once the seam's blend is over the generated values are back
    later = KEPT + SEAM_SMOOTH_FRAMES + BLEND
    np.testing.assert_allclose(out[later:, columns], generated[later:, columns], atol=1e-12)
    # the foot's contact flag is not smoothed (the foot's other columns are)
    foot = joint_columns(22)[10]
    generated[:, foot] = (np.arange(FRAMES) % 2).astype(float)[:, None]
    keep = np.zeros((FRAMES, 22), bool)
    keep[:KEPT, 10] = True
    smoothed = smooth_seams(generated, keep)
    np.testing.assert_array_equal(smoothed[:, foot[-1]], generated[:, foot[-1]])
    assert np.abs(smoothed[KEPT, foot[:-1]] - generated[KEPT, foot[:-1]]).min() > 0.3


def test_a_join_of_two_generated_stretches_is_smoothed_on_both_sides():
    """smooth_join: the jitter within the seam's half second is damped on both sides (a light
    Gaussian: sigma 0.6 frames), fades back to the features after it, and never touches a kept
    source's frames or the foot contacts."""
    fps, join, fixed = 20.0, 32, 8
    reach = int(round(JOIN_REACH_SECONDS * fps))
    features = np.zeros((FRAMES, 263))
    features[:] = 0.01 * (-1.0) ** np.arange(FRAMES)[:, None]  # +-1 cm a frame everywhere
    out = smooth_join(features, join, fps, fixed)
    jerk = np.abs(np.diff(out[:, 70], 3))  # a ric column; jerk[t]: frames t..t+3
    raw = np.abs(np.diff(features[:, 70], 3)).max()  # 0.08
    # within the judged half second: under half the jitter's jerk on either side
    assert jerk[join - reach : join + reach - 3].max() < 0.5 * raw
    assert (
        jerk[join - reach : join].max() < 0.5 * raw
        and jerk[join : join + reach - 3].max() < 0.5 * raw
    )
    far = reach + SEAM_SMOOTH_FRAMES + 1
    np.testing.assert_array_equal(out[join + far :], features[join + far :])
    np.testing.assert_array_equal(out[: join - far], features[: join - far])
    contacts = FeatureLayout(22).foot_contact
    np.testing.assert_array_equal(out[:, contacts], features[:, contacts])
    # a kept source's frames stay as they are, even within reach
    near = smooth_join(features, fixed + 2, fps, fixed)
    np.testing.assert_array_equal(near[:fixed], features[:fixed])
    assert not np.allclose(near[fixed : fixed + 4], features[fixed : fixed + 4])


def test_compose_smooths_every_window_join(pipe, monkeypatch):
    """compose smooths each join of its windows (segments' and a long segment's windows) on
    both sides, once, on what was made so far."""
    import torch

    import t2m.edit
    from t2m.edit import SearchSettings
    from t2m.edit.modes import Segment

    seen = []
    original = t2m.edit.smooth_join

    def recording(features, join, fps, fixed=0, **options):
        seen.append((len(features), join, fixed))
        return original(features, join, fps, fixed, **options)

    monkeypatch.setattr(t2m.edit, "smooth_join", recording)
    timeline = [Segment("a person walks forward", 0, 60), Segment("a person jumps", 60, 300)]
    settings = SearchSettings(candidates=1)
    (result,) = t2m.edit.compose(pipe, timeline, 1, torch.Generator().manual_seed(0), settings)
    # windows: 60 from rest, then 156 (7.8 s after 2 s of context), then the remaining 84
    assert seen == [(216, 60, 0), (300, 216, 0)]
    assert len(result.features) == 300


def test_the_benchmark_measures_the_half_second_around_a_seam():
    from t2m.evaluate.edit_bench import seam_statistics

    joints = np.zeros((60, 22, 3))
    joints[35, 3, 0] = 0.01  # a 1 cm blip 5 frames after a join at 30
    acc, jerk = seam_statistics(joints, 30, 20.0)
    assert acc == pytest.approx(2 * 0.01 * 400) and jerk == pytest.approx(3 * 0.01 * 8000)
    assert seam_statistics(joints, 25, 20.0) == (0.0, 0.0)  # 10 frames away: outside
    assert seam_statistics(joints, 58, 20.0) == (0.0, 0.0)  # near the end: the window moves in


def test_edit_benchmark_own_ends_keep_the_captions_own_clip(tiny_dataset, tmp_path):
    """An inbetween item keeps the first and last second of its caption's own clip (so the
    kept ends fit the text; the default, ``--own-ends``), judges the middle;
    ``--no-own-ends`` keeps an unrelated source's ends around a 4 s middle; the option is
    inbetween's only."""
    from dataset_tools import humanml3d
    from dataset_tools.command import UsageError
    from t2m.evaluate.edit_bench import EditBenchConfig, build_items, main

    config = EditBenchConfig("inbetween", tiny_dataset, tmp_path, items=4)
    assert config.own_ends is True
    for item in build_items(config, 20.0):
        clip = humanml3d.read_joints(humanml3d.joints_path(tiny_dataset, item.donors[0]))
        frames = len(item.request.source)
        assert item.source == item.donors[0] and frames == min(len(clip), 196) // 4 * 4
        np.testing.assert_array_equal(item.request.source, clip[:frames])
        assert item.part == (20, frames - 20) and item.seams == [20, frames - 20]
        assert item.request.keep_start == item.request.keep_end == 1.0
    unrelated = EditBenchConfig("inbetween", tiny_dataset, tmp_path, items=4, own_ends=False)
    for item in build_items(unrelated, 20.0):
        assert item.part == (20, 100) and item.seams == [20, 100]
        assert item.request.seconds == 6.0  # 1 s + a 4 s middle + 1 s, whatever the clips
    with pytest.raises(UsageError, match="--own-ends is an inbetween option"):
        EditBenchConfig("continue", tiny_dataset, tmp_path, own_ends=True)
    assert EditBenchConfig("continue", tiny_dataset, tmp_path).own_ends is False
    arguments = ["--edit", "continue", "--dataset", str(tiny_dataset), "--checkpoints", "x"]
    assert main([*arguments, "--no-own-ends"]) == 2  # refused in one line
