"""Compose from a source (t2m.edit, ``--mode compose --source``) on the tiny trained run: the
kept stretch is the source's exactly, the timeline's segments follow it with an eased seam,
the same seed gives the same bytes, and bad requests are one line, in the command, the
``--batch`` JSON and the web API alike."""

from __future__ import annotations

import base64
import io
import json

import numpy as np
import pytest
from conftest import synth_joints
from test_serve import call

from dataset_tools.command import UsageError
from dataset_tools.representation import recover_from_ric
from t2m.edit import SearchSettings, edit, prepare_source

FAST = SearchSettings(candidates=2, steps=2)


@pytest.fixture(scope="module")
def walk() -> np.ndarray:
    return synth_joints("walk_forward", 101, np.random.default_rng(3))  # 100 feature frames


def _largest_steps(joints: np.ndarray) -> np.ndarray:
    """Largest joint displacement (T-1,) between consecutive frames."""
    return np.linalg.norm(np.diff(joints, axis=0), axis=-1).max(-1)


def _assert_no_jump(joints: np.ndarray, frame: int) -> None:
    """The step into ``frame`` is no larger than 1.5 times the steps around it (plus 1 cm)."""
    steps = _largest_steps(joints)
    around = np.concatenate([steps[max(0, frame - 6) : frame - 1], steps[frame : frame + 5]])
    assert steps[frame - 1] <= 1.5 * around.max() + 0.01, (frame, steps[frame - 1], around)


def test_the_whole_source_is_kept_and_the_segments_follow(pipe, walk):
    source = prepare_source(walk)
    timeline = ["a person jumps up and down#2", "a person walks forward#9"]  # after the source
    motions = edit(pipe, "", "compose", walk, timeline=timeline, num_samples=2, seed=0,
                   settings=FAST)  # fmt: skip
    kept = source.num_frames
    for motion in motions:
        assert motion.joints.shape == (kept + 40 + 180, 22, 3)  # two windows after the source
        assert motion.text == "a person jumps up and down / a person walks forward"
        np.testing.assert_array_equal(motion.features[:kept], source.features)
        np.testing.assert_allclose(motion.joints[:kept], source.joints, atol=1e-4)
        assert motion.kept[:kept].all() and not motion.kept[kept:].any()
        for join in (kept, kept + 40):  # the source's seam and the segments' join
            _assert_no_jump(motion.joints, join)
        assert np.abs(motion.joints[kept:, 0, [0, 2]]).max() < 50  # the root carries on
    assert not np.allclose(motions[0].joints[kept:], motions[1].joints[kept:])


def test_same_seed_same_bytes(pipe, walk):
    def run(seed):
        return edit(pipe, "", "compose", walk, timeline=["a person walks forward#3"],
                    keep_last=1.0, seed=seed, settings=FAST)[0].joints  # fmt: skip

    first = run(4)
    np.testing.assert_array_equal(first, run(4))
    assert not np.array_equal(first, run(5))
    np.testing.assert_array_equal(first[:20], run(5)[:20])  # the kept stretch never changes


def test_the_last_seconds_start_the_result_in_the_model_frame(pipe, walk):
    source = prepare_source(walk)
    timeline = ["a person jumps up and down#1#3"]  # on the result's timeline: after 1 s kept
    motion = edit(pipe, "", "compose", walk, timeline=timeline, keep_last=1.0, seed=0,
                  settings=FAST)[0]  # fmt: skip
    assert motion.joints.shape[0] == 60 and motion.kept[:20].all() and not motion.kept[20:].any()
    tail = source.features[-20:]
    np.testing.assert_array_equal(motion.features[:20], tail)
    np.testing.assert_allclose(motion.joints[:20], recover_from_ric(tail), atol=1e-5)
    # the source's last second moved rigidly: frame 0 at the origin, the body as it was
    np.testing.assert_allclose(motion.joints[0, 0, [0, 2]], [0.0, 0.0], atol=1e-6)
    pairs = np.linalg.norm(motion.joints[:20, :, None] - motion.joints[:20, None], axis=-1)
    original = np.linalg.norm(source.joints[-20:, :, None] - source.joints[-20:, None], axis=-1)
    np.testing.assert_allclose(pairs, original, atol=1e-4)
    _assert_no_jump(motion.joints, 20)


def test_a_source_of_any_length_is_kept_whole(pipe):
    odd = synth_joints(
        "walk_forward", 47, np.random.default_rng(5)
    )  # 46 frames: not whole snippets
    source = prepare_source(odd)
    motion = edit(pipe, "", "compose", odd, timeline=["a person walks forward#1.2"], seed=0,
                  settings=FAST)[0]  # fmt: skip
    assert motion.joints.shape[0] == 46 + 24
    np.testing.assert_array_equal(motion.features[:46], source.features)
    _assert_no_jump(motion.joints, 46)


@pytest.mark.parametrize(
    ("options", "message"),
    [
        ({"timeline": ["a person walks#0#3"]}, "follows the kept source, which ends at 5.00 s"),
        ({"timeline": ["a person walks#5#8"], "keep_last": 2.0}, "ends at 2.00 s"),
        ({"timeline": ["a person walks#3"], "keep_last": 9.0}, "more than the source"),
        ({"timeline": ["a person walks#3"], "keep_last": 0.1}, "at least one snippet"),
        ({"timeline": ["a person walks#3"], "keep_last": -1.0}, "from 0 to 3600"),
        ({"timeline": ["a person walks#5#8", "a person jumps#9#10"]}, "a gap"),
    ],
)
def test_bad_compose_sources_are_one_line_errors(pipe, walk, options, message):
    with pytest.raises(UsageError, match=message) as error:
        edit(pipe, "", "compose", walk, settings=FAST, **options)
    assert "\n" not in str(error.value)


def test_keep_last_belongs_to_compose_with_a_source(pipe, walk):
    for mode, source, options in (
        ("compose", None, {"timeline": ["a person walks#3"]}),
        ("continue", walk, {}),
    ):
        with pytest.raises(UsageError, match="--keep-last is for --mode compose with a --source"):
            edit(pipe, "a person walks", mode, source, keep_last=1.0, **options)


def test_command_and_batch(tiny_run, tmp_path, walk, capsys):
    from t2m.edit.__main__ import main

    np.save(tmp_path / "walk.npy", walk)
    out = tmp_path / "out"
    argv = ["--checkpoints", str(tiny_run), "--mode", "compose", "--source",
            str(tmp_path / "walk.npy"), "--keep-last", "2", "--timeline",
            "a person jumps up and down#2", "--candidates", "2", "--render", "none",
            "--out", str(out)]  # fmt: skip
    assert main(argv) == 0
    joints, kept = np.load(out / "sample00_rep00.npy"), np.load(out / "sample00_rep00_kept.npy")
    assert joints.shape == (80, 22, 3) and kept[:40].all() and not kept[40:].any()
    # a timeline that starts inside the source: one line, exit 2, nothing written
    bad = [*argv[:-1], str(tmp_path / "bad")]
    bad[bad.index("a person jumps up and down#2")] = "a person jumps up and down#0#2"
    assert main(bad) == 2
    message = capsys.readouterr().err.strip()
    assert "follows the kept source" in message and "\n" not in message
    assert not (tmp_path / "bad").exists() or not any((tmp_path / "bad").iterdir())
    # --batch: the same fields as JSON keys, refusals in those keys
    batch = [{"mode": "compose", "source": "walk.npy", "keep_last": 1,
              "timeline": ["a person walks forward#2"]},
             {"mode": "continue", "text": "a person walks", "source": "walk.npy",
              "keep_last": 1}]  # fmt: skip
    (tmp_path / "edits.json").write_text(json.dumps(batch))
    batch_argv = ["--checkpoints", str(tiny_run), "--batch", str(tmp_path / "edits.json"),
                  "--render", "none", "--out", str(tmp_path / "batch")]  # fmt: skip
    assert main(batch_argv) == 2
    message = capsys.readouterr().err.strip()
    assert "edits[1]: keep_last is for mode compose with a source" in message, message
    (tmp_path / "edits.json").write_text(json.dumps(batch[:1]))
    assert main(batch_argv) == 0
    assert np.load(tmp_path / "batch" / "sample00_rep00.npy").shape == (60, 22, 3)


def _upload(name: str, array: np.ndarray) -> dict:
    buffer = io.BytesIO()
    np.save(buffer, array)
    return {"upload": {"name": name, "base64": base64.b64encode(buffer.getvalue()).decode()}}


def test_web_composes_from_an_upload_as_the_library_does(server, pipe, walk):
    body = {"mode": "compose", "timeline": ["a person jumps up and down#2"], "keep_last": 2.0,
            "source": _upload("walk.npy", walk), "seed": 3}  # fmt: skip
    status, answer, _ = call(server, "POST", "/api/edit", body)
    assert status == 200, answer
    assert answer["edit"] == {"mode": "compose", "source": "walk.npy"}
    expected = edit(pipe, "", "compose", walk, timeline=["a person jumps up and down#2"],
                    keep_last=2.0, seed=3)[0]  # fmt: skip
    motion = answer["motions"][0]
    assert motion["frames"] == 80
    kept = np.array([[c == "1" for c in row] for row in motion["kept"]])
    assert kept[:40].all() and not kept[40:].any()
    joints = np.asarray(motion["joints"]).reshape(80, 22, 3)
    np.testing.assert_allclose(joints, expected.joints, atol=2e-4)
    # without a source compose is as before; a bad start is refused in the request's words
    plain = {"mode": "compose", "timeline": ["a person walks forward#0#2"]}
    assert call(server, "POST", "/api/edit", plain)[0] == 200
    status, answer, _ = call(server, "POST", "/api/edit", {**body, "timeline": ["a#0#2"]})
    assert status == 400 and "follows the kept source" in answer["error"], answer
    status, answer, _ = call(server, "POST", "/api/edit", {**plain, "keep_last": 1})
    assert status == 400, answer
    assert answer["error"] == "keep_last is for mode compose with a source", answer
    assert not [p for p in server.app.store.root.iterdir() if p.name.startswith(".upload")]
