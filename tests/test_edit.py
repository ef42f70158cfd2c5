"""Editing and composition (t2m.edit) on the tiny trained run: every mode through the API and
the command, kept parts, seams, determinism, bad input."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from conftest import synth_joints

from dataset_tools.command import UsageError
from dataset_tools.representation import recover_from_ric
from t2m.edit import EditRequest, SearchSettings, edit, edit_batch, load_source, prepare_source
from t2m.edit.recover import recover_from_ric_torch

FAST = SearchSettings(candidates=3, steps=3)


@pytest.fixture(scope="module")
def pipe(tiny_run):
    from t2m.pipeline import TextToMotion

    return TextToMotion.from_checkpoints(tiny_run, need_length_model=False)


@pytest.fixture(scope="module")
def walk() -> np.ndarray:
    return synth_joints("walk_forward", 101, np.random.default_rng(3))


def _steps(joints: np.ndarray) -> np.ndarray:
    """Largest joint displacement (T-1,) between consecutive frames."""
    return np.linalg.norm(np.diff(joints, axis=0), axis=-1).max(-1)


def _assert_no_jump(joints: np.ndarray, frame: int) -> None:
    """The step from ``frame - 1`` to ``frame`` is no larger than 1.5 times the steps around it
    (plus 1 cm): a pose or position jump at a join would be."""
    steps = _steps(joints)
    around = np.concatenate([steps[max(0, frame - 6) : frame - 1], steps[frame : frame + 5]])
    assert steps[frame - 1] <= 1.5 * around.max() + 0.01, (frame, steps[frame - 1], around)


def test_torch_recovery_equals_numpy_and_has_gradients():
    features = np.random.default_rng(0).normal(size=(2, 3, 17, 263)) * 0.3
    expected = recover_from_ric(features)
    tensor = torch.from_numpy(features).requires_grad_(True)
    joints = recover_from_ric_torch(tensor)
    np.testing.assert_allclose(joints.detach().numpy(), expected, atol=1e-12)
    joints.square().sum().backward()
    assert torch.isfinite(tensor.grad).all() and tensor.grad.abs().sum() > 0


def test_continue_keeps_the_start_and_carries_on(pipe, walk):
    source = prepare_source(walk)
    motions = edit(pipe, "a person walks forward", "continue", walk, keep_seconds=1.5,
                   seconds=4.0, num_samples=2, seed=1, settings=FAST)  # fmt: skip
    kept = 30
    for motion in motions:
        assert motion.joints.shape == (80, 22, 3) and motion.features.shape == (80, 263)
        assert motion.kept[:kept].all() and not motion.kept[kept:].any()
        np.testing.assert_allclose(motion.joints[:kept], source.joints[:kept], atol=1e-4)
        _assert_no_jump(motion.joints, kept)
    assert not np.allclose(motions[0].joints, motions[1].joints)


def test_same_seed_same_result_other_seed_other(pipe, walk):
    def run(seed):
        return edit(pipe, "a person walks forward", "inbetween", walk, seed=seed,
                    settings=FAST)[0].joints  # fmt: skip

    first = run(4)
    np.testing.assert_array_equal(first, run(4))
    assert not np.array_equal(first, run(5))


def test_inbetween_keeps_both_ends_with_smooth_joins(pipe, walk):
    source = prepare_source(walk)
    motion = edit(pipe, "a person jumps up and down", "inbetween", walk, keep_start=1.0,
                  keep_end=0.5, seconds=4.0, seed=0, settings=FAST)[0]  # fmt: skip
    frames, start, end = 80, 20, 10
    assert motion.joints.shape[0] == frames
    np.testing.assert_allclose(motion.joints[:start], source.joints[:start], atol=1e-4)
    np.testing.assert_allclose(motion.joints[-end:], source.joints[-end:], atol=1e-3)
    assert motion.kept[:start].all() and motion.kept[-end:].all()
    assert not motion.kept[start:-end].any()
    _assert_no_jump(motion.joints, start)
    _assert_no_jump(motion.joints, frames - end)


def test_body_keeps_the_lower_body_on_every_frame(pipe, walk):
    source = prepare_source(walk)
    motion = edit(pipe, "a person raises the left arm", "body", walk, part="lower", seed=0,
                  settings=FAST)[0]  # fmt: skip
    lower = [0, 1, 2, 4, 5, 7, 8, 10, 11]
    frames = motion.joints.shape[0]
    assert frames == 100
    np.testing.assert_allclose(motion.joints[:, lower], source.joints[:frames, lower], atol=1e-4)
    assert motion.kept[:, lower].all() and not motion.kept[:, 20].any()
    # the regenerated arms are not the source's
    assert np.abs(motion.joints[:, 20] - source.joints[:frames, 20]).max() > 1e-3


def test_path_and_keys_meet_the_root_targets(pipe):
    points = [[1.0, 0.3, 0.8], [2.5, 0.5, 2.0]]
    motion = edit(pipe, "a person walks forward", "path", path=points, seed=0, settings=FAST)[0]
    assert motion.joints.shape[0] == 52  # up to 2.5 s, whole snippets
    for t, x, z in points:
        np.testing.assert_allclose(motion.joints[round(t * 20), 0, [0, 2]], [x, z], atol=1e-4)
    assert motion.kept[[20, 50], 0].all() and motion.kept.sum() == 2
    keys = np.full((40, 22, 3), np.nan)
    keys[30, 0, [0, 2]] = [0.2, 0.9]
    keys[30, 20] = [0.5, 1.5, 0.9]
    motion = edit(pipe, "a person raises the left arm", "keys", keys=keys, seed=0, settings=FAST)[0]
    np.testing.assert_allclose(motion.joints[30, 0, [0, 2]], [0.2, 0.9], atol=1e-4)
    assert np.isfinite(motion.constraint_error)


def test_compose_three_prompts_is_one_smooth_motion(pipe):
    timeline = ["a person walks forward#0#3", "a person jumps up and down#3#5.2",
                "a person turns to the left#5.2#12"]  # fmt: skip
    motions = edit(pipe, "", "compose", timeline=timeline, num_samples=2, seed=0, settings=FAST)
    for motion in motions:
        assert motion.joints.shape == (240, 22, 3)  # 12 s: longer than one model window
        assert motion.text.count(" / ") == 2
        for join in (60, 104, 196):  # the segments' joins and the second window's
            _assert_no_jump(motion.joints, join)


def test_batch_gives_what_single_edits_give(pipe, walk):
    requests = [
        EditRequest("continue", "a person walks forward", walk, keep_seconds=1.0),
        EditRequest("body", "a person raises the left arm", walk, part="arms"),
    ]
    batch = edit_batch(pipe, requests, num_samples=1, seed=2, settings=FAST)
    assert [len(row) for row in batch] == [1, 1]
    assert batch[0][0].mode == "continue" and batch[1][0].mode == "body"
    assert batch[1][0].kept[:, [13, 16, 18, 20]].all()


def test_pipeline_edit_delegates(pipe, walk):
    direct = edit(pipe, "a person walks forward", "continue", walk, seed=3, settings=FAST)
    method = pipe.edit("a person walks forward", "continue", walk, seed=3, settings=FAST)
    np.testing.assert_array_equal(direct[0].joints, method[0].joints)


def test_sources_npy_bvh_and_ours(tmp_path, walk):
    from dataset_tools.bvh import write_bvh

    np.save(tmp_path / "walk.npy", walk)
    assert load_source(tmp_path / "walk.npy").shape == walk.shape
    write_bvh(walk, tmp_path / "walk.bvh", fps=20.0)
    from_bvh = load_source(tmp_path / "walk.bvh")
    assert from_bvh.shape == walk.shape and np.abs(from_bvh - walk).max() < 0.02
    np.save(tmp_path / "sixty.npy", walk)
    assert load_source(tmp_path / "sixty.npy", fps=60.0).shape[0] == 34  # resampled to 20 fps


@pytest.mark.parametrize(
    ("mode", "options", "message"),
    [
        ("continue", {"keep_seconds": 9.0}, "past the source's end"),
        ("continue", {"keep_seconds": 0.0}, "keeps nothing"),
        ("continue", {"keep_seconds": 5.0}, "nothing is left to generate"),
        ("inbetween", {"keep_start": 3.0, "keep_end": 3.0}, "more than the source"),
        ("path", {"path": [[0.5, 9.0, 0.0]]}, "cannot get there in time"),
        ("keys", {"keys": np.full((20, 22, 3), np.nan)}, "constrains nothing"),
        ("compose", {"timeline": ["a#0#2", "b#2.5#4"]}, "a gap"),
        ("compose", {"timeline": ["a#0#2", "b#1.5#4"]}, "an overlap"),
        ("body", {"part": "tail"}, "unknown --part"),
    ],
)
def test_bad_requests_are_one_line_errors(pipe, walk, mode, options, message):
    source = walk if mode in ("continue", "inbetween", "body") else None
    with pytest.raises(UsageError, match=message) as error:
        edit(pipe, "a person walks forward", mode, source, settings=FAST, **options)
    assert "\n" not in str(error.value)


def test_bad_sources_are_one_line_errors(tmp_path, walk):
    np.save(tmp_path / "kit.npy", walk[:, :21])
    with pytest.raises(UsageError, match=r"must be \(T, 22, 3\)"):
        load_source(tmp_path / "kit.npy")
    broken = walk.copy()
    broken[5, 3, 1] = np.nan
    np.save(tmp_path / "nan.npy", broken)
    with pytest.raises(UsageError, match="NaN"):
        load_source(tmp_path / "nan.npy")
    with pytest.raises(UsageError, match="at least 5"):
        prepare_source(walk[:3])


def test_command_writes_what_sample_writes(tiny_run, tmp_path, walk):
    from t2m.edit.__main__ import main

    np.save(tmp_path / "walk.npy", walk)

    def argv(out):
        return ["--source", str(tmp_path / "walk.npy"), "--text", "a person walks forward",
                "--mode", "continue", "--keep-seconds", "1", "--checkpoints", str(tiny_run),
                "--out", str(out), "--num-samples", "2", "--render", "none", "--bvh",
                "--glb", "--candidates", "2", "--steps", "2"]  # fmt: skip

    out = tmp_path / "out"
    assert main(argv(out)) == 0
    names = sorted(p.name for p in out.iterdir())
    for stem in ("sample00_rep00", "sample00_rep01"):
        assert {f"{stem}.npy", f"{stem}_feats.npy", f"{stem}_kept.npy", f"{stem}.bvh"} <= set(names)
        assert (out / f"{stem}.glb").read_bytes()[:4] == b"glTF"
        kept = np.load(out / f"{stem}_kept.npy")
        assert kept.shape == (100, 22) and kept[:20].all() and not kept[20:].any()
    summary = json.loads((out / "results.json").read_text())
    assert summary["modes"] == ["continue"] and summary["lengths"] == [[100, 100]]
    results = np.load(out / "results.npy", allow_pickle=True).item()
    assert results["motion"].shape == (2, 22, 3, 100)
    # same request, same bytes
    again = tmp_path / "again"
    assert main(argv(again)) == 0
    assert (again / "sample00_rep01.npy").read_bytes() == (out / "sample00_rep01.npy").read_bytes()


def test_command_batch_of_edits(tiny_run, tmp_path, walk):
    from t2m.edit.__main__ import main

    np.save(tmp_path / "walk.npy", walk)
    edits = [
        {"mode": "continue", "text": "a person walks forward", "source": "walk.npy"},
        {"mode": "path", "text": "a person walks forward", "path": [[1.0, 0.2, 0.8]]},
        {"mode": "compose", "timeline": ["a person walks forward#0#2", "a person jumps#2#3"]},
    ]
    (tmp_path / "edits.json").write_text(json.dumps(edits))
    out = tmp_path / "out"
    argv = ["--batch", str(tmp_path / "edits.json"), "--checkpoints", str(tiny_run),
            "--out", str(out), "--render", "none", "--steps", "2"]  # fmt: skip
    assert main(argv) == 0
    summary = json.loads((out / "results.json").read_text())
    assert summary["modes"] == ["continue", "path", "compose"]
    assert summary["lengths"] == [[100], [24], [60]]  # the path: past its point at frame 20
    edits[1]["speed"] = 3
    (tmp_path / "edits.json").write_text(json.dumps(edits))
    bad = ["--batch", str(tmp_path / "edits.json"), "--checkpoints", str(tiny_run),
           "--out", str(tmp_path / "bad")]  # fmt: skip
    assert main(bad) == 2
    assert not (tmp_path / "bad").exists()


def test_command_refuses_bad_input_and_writes_nothing(tiny_run, tmp_path, walk, capsys):
    from t2m.edit.__main__ import main

    np.save(tmp_path / "walk.npy", walk)
    out = tmp_path / "out"
    common = ["--checkpoints", str(tiny_run), "--out", str(out), "--render", "none"]
    cases = [
        ["--mode", "continue", "--text", "a person walks"],  # no source
        [
            "--mode",
            "continue",
            "--text",
            "a person walks",
            "--source",
            str(tmp_path / "walk.npy"),
            "--keep-seconds",
            "20",
        ],  # fmt: skip
        ["--mode", "compose", "--timeline", "a person walks#0#2", "a person jumps#3#5"],
    ]
    for case in cases:
        assert main([*case, *common]) == 2
        assert len(capsys.readouterr().err.strip().splitlines()) == 1
        assert not out.exists()


def test_kept_parts_render_in_their_own_colour(tmp_path, walk):
    from dataset_tools.viz import RenderConfig, render_keyframes

    highlight = np.zeros(walk.shape[:2], bool)
    highlight[:, [0, 1, 4, 7, 10]] = True  # the left leg
    path = render_keyframes(walk[:20], tmp_path / "k.png", num_keyframes=2,
                            highlight=highlight[:20])  # fmt: skip
    from PIL import Image

    pixels = np.asarray(Image.open(path).convert("RGB")).reshape(-1, 3)
    green = np.array([int(RenderConfig().highlight_color[i : i + 2], 16) for i in (1, 3, 5)])
    assert (np.abs(pixels.astype(int) - green).sum(-1) < 30).sum() > 50
    from dataset_tools.viz import render_animation

    render_animation(walk[:4], tmp_path / "k.gif", highlight=highlight[:4])
    assert (tmp_path / "k.gif").stat().st_size > 0
    with pytest.raises(ValueError, match="highlight must be"):
        render_keyframes(walk[:20], tmp_path / "bad.png", highlight=highlight)


@pytest.mark.parametrize("precision", ["bf16", "int8"])
def test_reduced_precision_keeps_the_source(tiny_run, walk, precision):
    from t2m.pipeline import TextToMotion

    pipe = TextToMotion.from_checkpoints(tiny_run, precision=precision, need_length_model=False)
    source = prepare_source(walk)
    motion = edit(pipe, "a person walks forward", "inbetween", walk, seed=0, settings=FAST)[0]
    assert np.isfinite(motion.joints).all()
    np.testing.assert_allclose(motion.joints[:20], source.joints[:20], atol=1e-4)


def test_the_original_release_edits_too(walk):
    from conftest import SHARED

    from t2m.pipeline import TextToMotion

    release = SHARED / "reference" / "t2m-original"
    if not release.is_dir():
        pytest.skip("no release reference folder")
    pipe = TextToMotion.from_checkpoints(release, need_length_model=False)
    assert pipe.encoder is not None  # the release's movement encoder reads the kept start
    source = prepare_source(walk)
    motion = edit(pipe, "a person walks forward", "continue", walk, keep_seconds=1.0, seed=0,
                  settings=FAST)[0]  # fmt: skip
    np.testing.assert_allclose(motion.joints[:20], source.joints[:20], atol=1e-4)


def test_batch_entries_are_read_by_the_request_schema(tmp_path, capsys):
    from t2m.edit.__main__ import main

    cases = [
        ([{"mode": "continue", "text": "x", "keep_seconds": "two"}], "edits[0].keep_seconds"),
        ([{"mode": "body", "text": "x", "source": "a.npy", "part": "head"}], "edits[0].part"),
        ([{"text": "x"}], "edits[0].mode is required"),
        ([{"mode": "path", "text": "x", "path": [[1, 0, 0]], "speed": 3}], "unknown field"),
    ]
    for edits, message in cases:
        (tmp_path / "edits.json").write_text(json.dumps(edits))
        assert main(["--batch", str(tmp_path / "edits.json"), "--out", str(tmp_path / "o")]) == 2
        err = capsys.readouterr().err.strip()
        assert message in err and len(err.splitlines()) == 1, err
    argv = ["--batch", str(tmp_path / "edits.json"), "--text", "x", "--out", str(tmp_path / "o")]
    assert main(argv) == 2
    assert "drop --text" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


def test_an_edit_optimises_after_plain_generation_on_the_same_pipeline(tiny_run):
    """Plain generation (in inference mode) first builds the float32 rollout plan, which makes
    the model's parameters views of its stacked weights: made there, they were inference tensors
    and the next edit's noise optimisation failed ("Inference tensors cannot be saved for
    backward"), as in the edit benchmark, which generates plainly first."""
    from t2m.pipeline import TextToMotion

    fresh = TextToMotion.from_checkpoints(tiny_run, need_length_model=False)
    fresh.generate(["a person raises the left arm"], lengths=[40])
    assert not any(p.is_inference() for p in fresh.vae.parameters())
    keys = np.full((40, 22, 3), np.nan)
    keys[30, 20] = [0.5, 1.5, 0.9]
    settings = SearchSettings(method="optimize", candidates=2, steps=2)
    motion = edit(fresh, "a person raises the left arm", "keys", keys=keys, settings=settings)[0]
    assert np.isfinite(motion.constraint_error)
