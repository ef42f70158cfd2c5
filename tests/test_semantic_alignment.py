"""Timing-free semantic checks (matching.align_segments): the labelled actions in their order,
wherever the motion performs them; wrong order and wrong counts still fail."""

from __future__ import annotations

import numpy as np
import pytest

from dataset_tools.representation import process_motion
from dataset_tools.synth.clip import synthesize_action
from dataset_tools.synth.detectors import MotionSignals, detect_labels
from dataset_tools.synth.matching import align_segments, clip_matches
from dataset_tools.synth.scoring import SemanticScorer

FPS = 20.0
WALK = {"gait": "walk", "direction": "forward", "speed": "normal", "speed_mps": 1.2}
WAVE = {"side": "right", "count": 3, "rate_hz": 1.8}


def _action(action: str, params: dict, seconds: float) -> np.ndarray:
    """(T, 22, 3) joints at 20 fps of one synthesized action."""
    return synthesize_action(action, params, seconds).joints[::3].astype(np.float64)


def _then(first: np.ndarray, second: np.ndarray) -> np.ndarray:
    """``second`` carried on from where ``first`` ends (its root moved to the end point)."""
    shift = first[-1, 0] - second[0, 0]
    shift[1] = 0.0
    return np.concatenate([first, second + shift])


def _labels(*parts: tuple[str, dict, int]) -> list[dict]:
    """Segments (action, params, start, end) from (action, params, frames)."""
    segments, start = [], 0
    for action, params, frames in parts:
        segments.append({"action": action, "params": params, "start": start, "end": start + frames})
        start += frames
    return segments


@pytest.fixture(scope="module")
def walk_then_wave() -> dict[float, np.ndarray]:
    """Walk then wave, 6 s in all, the walk taking 30% or 70% of it."""
    return {
        share: _then(_action("walk", WALK, 6 * share), _action("wave", WAVE, 6 * (1 - share)))
        for share in (0.3, 0.7)
    }


def test_order_is_found_whatever_the_timing(walk_then_wave):
    labels = _labels(("walk", WALK, 60), ("wave", WAVE, 60))  # labelled half and half
    for share, joints in walk_then_wave.items():
        found = align_segments(joints, FPS, labels)
        assert found.matches == (True, True), share
        assert found.fixed == tuple(clip_matches(joints, FPS, labels))
    # The proportional cut fails where the walk is much shorter than labelled; the alignment
    # moves the boundary towards the real one (only as far as it must).
    found = align_segments(walk_then_wave[0.3], FPS, labels)
    assert found.fixed == (False, True)
    assert 0.3 <= found.spans[0][1] / 120 < 0.5


def test_reversed_order_and_other_actions_fail(walk_then_wave):
    reversed_labels = _labels(("wave", WAVE, 60), ("walk", WALK, 60))
    for joints in walk_then_wave.values():
        assert not all(align_segments(joints, FPS, reversed_labels).matches)
    left = _labels(("walk", WALK, 60), ("wave", {**WAVE, "side": "left"}, 60))
    assert not all(align_segments(walk_then_wave[0.7], FPS, left).matches)
    backward = {**WALK, "direction": "backward", "speed_mps": 0.9}
    found = align_segments(
        walk_then_wave[0.7], FPS, _labels(("walk", backward, 60), ("wave", WAVE, 60))
    )
    assert found.matches == (False, True)  # the best segmentation still finds the wave


def test_counts_must_be_exact_and_no_event_hides_in_a_neighbour():
    jumps = _action("jump", {"mode": "in_place", "count": 2, "height_m": 0.25}, 2.5)
    joints = _then(jumps, _action("wave", WAVE, 3.0))  # a wave's label ignores jumps
    for count, right in ((1, False), (2, True), (3, False)):
        jump = {"mode": "in_place", "count": count, "height_m": 0.25}
        labels = _labels(("jump", jump, 50), ("wave", WAVE, 60))
        # With "jumps once", a window holding only the first jump exists, but the second jump
        # would fall into the wave's stretch: counted events stay in their own segment.
        found = align_segments(joints, FPS, labels)
        # The wave is right either way; the jump segment carries the count's verdict.
        assert found.matches == (right, True), count


def test_window_facts_agree_with_the_facts_of_the_cut_motion(walk_then_wave):
    joints = walk_then_wave[0.7]
    signals = MotionSignals(joints, FPS)
    assert signals.facts().complete() == detect_labels(joints, FPS)
    for a, b in ((0, 80), (90, 120), (30, 110)):
        window, cut = signals.facts(a, b), detect_labels(joints[a:b], FPS)
        for key, value in cut.items():
            if isinstance(value, float):
                assert window[key] == pytest.approx(value, rel=0.1, abs=0.1), key
            else:
                assert window[key] == value, key
    with pytest.raises(ValueError, match="window"):
        signals.facts(5, 6)


def test_scorer_reports_aligned_and_fixed_timing(walk_then_wave):
    joints = walk_then_wave[0.3]
    labels = {"fps": 20, "clips": {"clip": {"frames": 120, "segments": _labels(
        ("walk", WALK, 60), ("wave", WAVE, 60))}}}  # fmt: skip
    scores = SemanticScorer(labels, fps=FPS)(["clip"], [process_motion(joints)[0]])
    assert scores["all"] == 1.0 and scores["segments"] == 1.0
    assert scores["all_fixed_timing"] == 0.0 and scores["segments_fixed_timing"] == 0.5
    assert scores["action_walk"] == 1.0 and scores["fixed_timing_action_walk"] == 0.0
    assert scores["scored_action_walk"] == 1.0 and scores["scored_action_wave"] == 1.0


def test_a_neighbour_that_makes_such_events_cannot_absorb_or_split_one():
    # A sit dips once itself: moving the boundary into it must neither give the squats its dip
    # (a count one higher) nor take one squat (one lower).
    squat = {"count": 2, "depth_deg": 90, "period_s": 1.8}
    squats, sit = _action("squat", squat, 3.8), _action("sit", {"hold_s": 1.2, "knee_deg": 25}, 5.4)
    sitting = ("sit", {"hold_s": 1.2, "knee_deg": 25}, len(sit))
    for count in (1, 2, 3):
        squatting = ("squat", {**squat, "count": count}, len(squats))
        before = align_segments(_then(squats, sit), FPS, _labels(squatting, sitting))
        after = align_segments(_then(sit, squats), FPS, _labels(sitting, squatting))
        assert before.matches == (count == 2, True), count
        assert after.matches == (True, count == 2), count
