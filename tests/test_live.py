"""Live generation (t2m/live.py) on the tiny run: stitching, prompts at snippet boundaries,
rewinds and replays that give the same frames, bad prompts that change nothing, bounded memory,
and a shortened long run that does not drift."""

from __future__ import annotations

import logging

import numpy as np
import pytest

from dataset_tools.command import UsageError
from dataset_tools.representation import recover_from_ric
from t2m.live import SETTLE_TEXT, LiveStream, drift_report, replay, settle_text

WALK, JUMP, BACK = "a person walks forward", "a person jumps up and down", "a person walks backward"


@pytest.fixture(autouse=True)
def _quiet():
    logging.getLogger("t2m.edit").setLevel(logging.WARNING)


def _pull(stream: LiveStream, snippets: int) -> list:
    return [stream.next_snippet() for _ in range(snippets)]


def test_snippets_stitch_into_one_motion(pipe):
    """Raw snippets placed in the world equal the whole stream's features recovered at once
    (world heading and position carried across snippets and segments, float64)."""
    stream = pipe.stream(WALK, seed=1, finish=False)
    snippets = _pull(stream, 30)
    stream.prompt(JUMP)
    snippets += _pull(stream, 30)
    assert [s.start for s in snippets] == list(range(0, 240, 4))
    assert all(s.joints.shape == (4, 22, 3) and s.features.shape == (4, 263) for s in snippets)
    whole = recover_from_ric(stream.features(raw=True))
    np.testing.assert_allclose(stream.joints(), whole, atol=1e-4)
    np.testing.assert_array_equal(np.concatenate([s.joints for s in snippets]), stream.joints())


def test_prompt_takes_over_at_the_next_boundary(pipe):
    stream = pipe.stream(WALK, seed=2)
    _pull(stream, 10)
    assert stream.boundary(41) == 44 and stream.boundary(40) == 40
    assert stream.prompt(JUMP) == 40
    first = stream.next_snippet()
    assert (first.start, first.text, first.prompt) == (40, JUMP, 1)
    # a prompt for a later frame waits for it
    assert stream.prompt(BACK, at=61) == 64
    texts = {s.start: s.text for s in _pull(stream, 8)}
    assert texts[60] == JUMP and texts[64] == BACK
    assert stream.timeline() == [f"{WALK}#0#2", f"{JUMP}#2#3.2", f"{BACK}#3.2#3.8"]


def test_rewind_and_replay_give_the_same_frames(pipe):
    """A prompt given at an earlier frame than the last pulled (a page's read-ahead) makes what a
    stream that got it in time makes, and the timeline replays both, bit for bit."""
    direct = pipe.stream(WALK, seed=5)
    _pull(direct, 15)
    direct.prompt(JUMP)
    _pull(direct, 25)
    ahead = pipe.stream(WALK, seed=5)
    _pull(ahead, 22)
    revised = ahead.prompt(JUMP, at=57)  # the boundary after frame 57: 60
    first = ahead.next_snippet()
    assert revised == 60 and first.start == 60 and ahead.frame == 64
    while ahead.frame < direct.frame:
        ahead.next_snippet()
    np.testing.assert_array_equal(ahead.joints(), direct.joints())
    assert ahead.timeline() == direct.timeline()
    again = replay(pipe, direct.timeline(), seed=5)
    np.testing.assert_array_equal(again.joints(), direct.joints())
    other = replay(pipe, direct.timeline(), seed=6)
    assert not np.allclose(other.joints(), direct.joints())
    with pytest.raises(UsageError, match="at most"):
        ahead.prompt(BACK, at=0)


def test_bad_prompts_change_nothing(pipe):
    clean = pipe.stream(WALK, seed=3)
    _pull(clean, 12)
    stream = pipe.stream(WALK, seed=3)
    _pull(stream, 6)
    for bad, message in (("", "empty"), ("   ", "empty"), ("zzqx qqvv", "no known word")):
        with pytest.raises(UsageError, match=message):
            stream.prompt(bad)
    with pytest.raises(UsageError, match="characters"):
        stream.prompt("walk " * 200)
    _pull(stream, 6)
    np.testing.assert_array_equal(stream.joints(), clean.joints())
    with pytest.raises(UsageError, match="no known word"):
        LiveStream(pipe, "zzqx")


def test_settle_commands_and_fixed_lengths(pipe):
    assert settle_text("Stop!") == SETTLE_TEXT and settle_text(" stand   still. ") == SETTLE_TEXT
    assert settle_text("a person stops and waves") == "a person stops and waves"
    stream = pipe.stream(WALK, seed=0, seconds=2.4)
    _pull(stream, 30)  # 120 frames: segments of 48 frames, the prompt going on
    assert [s.start for s in stream._segments] == [0, 48, 96]
    stream.prompt("Stop!", seconds=3)
    _pull(stream, 2)
    assert stream.prompts[-1].text == SETTLE_TEXT and stream.prompts[-1].typed == "Stop!"
    assert stream.prompts[-1].frames == 60


def test_trim_bounds_memory(pipe):
    stream = pipe.stream(WALK, seed=0, finish=False)
    _pull(stream, 100)
    before = stream.joints()[-40:]
    stream.trim(6.0)
    assert stream.first_frame > 0 and len(stream.joints()) == 400 - stream.first_frame
    np.testing.assert_array_equal(stream.joints()[-40:], before)
    assert stream.first_frame + len(stream.joints()) == stream.frame
    assert len(stream.features()) == len(stream.features(raw=True)) == 144  # 5 s + 2 s + 1
    stream.prompt(JUMP, at=stream.frame - 100)  # a rewind as far back as allowed still works
    _pull(stream, 4)  # goes on from what it kept
    assert len(stream.joints()) == 316 - stream.first_frame


def test_a_long_stream_does_not_drift(pipe):
    """90 s of prompts alternating every 3 s: on the floor, upright, bounded speed, no growth of
    jerk from the first half to the second (the 10-minute run is in docs/live.md)."""
    stream = pipe.stream(WALK, seed=0)
    prompts = (WALK, JUMP, BACK, "a person raises the left arm")
    for index in range(30):
        stream.prompt(prompts[index % len(prompts)])
        _pull(stream, 15)
    joints = stream.joints()
    assert joints.shape == (1800, 22, 3) and np.isfinite(joints).all()
    report = drift_report(joints, pipe.spec.fps, window_seconds=45)
    assert len(report) == 2
    for window in report:
        assert abs(window["floor_m"]) < 0.15, report
        assert window["upright_deg"] < 30, report
        assert window["speed_p95_mps"] < 4.0, report
    assert report[1]["jerk_mean"] < 1.5 * report[0]["jerk_mean"], report


def test_without_a_length_model_segments_have_a_fixed_length(pipe, monkeypatch):
    monkeypatch.setattr(pipe, "length_model", None)
    stream = pipe.stream(WALK, seed=0)
    _pull(stream, 45)
    assert [s.start for s in stream._segments] == [0, 80, 160]


def test_the_replay_command_writes_the_streams_motion(pipe, tiny_run, tmp_path):
    from t2m.replay import main

    stream = pipe.stream(WALK, seed=4)
    _pull(stream, 12)
    stream.prompt("Stop!")
    _pull(stream, 12)
    timeline = tmp_path / "live_seed4.txt"
    timeline.write_text("\n".join(stream.timeline()) + "\n")
    out = tmp_path / "out"
    argv = ["--timeline", str(timeline), "--seed", "4", "--checkpoints", str(tiny_run)]
    assert main([*argv, "--out", str(out), "--device", "cpu"]) == 0
    np.testing.assert_array_equal(np.load(out / "sample00_rep00.npy"), stream.joints())
    assert main(["--checkpoints", str(tiny_run)]) == 2  # no timeline: one line, no traceback
