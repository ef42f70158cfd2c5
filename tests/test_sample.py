"""Sampling: the CLI on tiny checkpoints trained in the session, the output contract,
determinism, the error cases, and the Python API."""

from __future__ import annotations

import json
import logging
import shutil
from pathlib import Path

import numpy as np
import pytest

from dataset_tools.command import UsageError
from t2m import outputs, sample
from t2m.pipeline import TextToMotion, frames_for, frames_for_seconds
from t2m.prompts import Prompt
from t2m.request import GenerationRequest


def _run(capsys, *argv: str) -> tuple[int, str]:
    code = sample.main(list(argv))
    return code, capsys.readouterr().err


def test_cli_writes_the_output_contract(tiny_run, tmp_path, capsys):
    out = tmp_path / "out"
    code, err = _run(
        capsys,
        "--text",
        "a person walks forward",
        "--num-samples",
        "2",
        "--length",
        "44",
        "--checkpoints",
        str(tiny_run),
        "--out",
        str(out),
        "--render",
        "gif",
        "--bvh",
        "--seed",
        "3",
    )
    assert code == 0, err
    expected = {"results.npy", "results.json"}
    for rep in range(2):
        expected |= {
            f"sample00_rep{rep:02d}{suffix}" for suffix in (".npy", "_feats.npy", ".gif", ".bvh")
        }
    assert {p.name for p in out.iterdir()} == expected | {outputs.MARKER}
    assert set(json.loads((out / outputs.MARKER).read_text())["files"]) == expected
    joints = np.load(out / "sample00_rep01.npy")
    feats = np.load(out / "sample00_rep01_feats.npy")
    assert joints.shape == (44, 22, 3) and joints.dtype == np.float32
    assert feats.shape == (44, 263) and np.isfinite(feats).all()
    results = np.load(out / "results.npy", allow_pickle=True).item()
    assert results["motion"].shape == (2, 22, 3, 44)
    assert results["text"] == ["a person walks forward"] * 2
    assert list(results["lengths"]) == [44, 44]
    assert (results["num_samples"], results["num_repetitions"]) == (1, 2)
    np.testing.assert_array_equal(results["motion"][1].transpose(2, 0, 1), joints)
    summary = json.loads((out / "results.json").read_text())
    assert summary["texts"] == ["a person walks forward"]
    assert summary["lengths"] == [[44, 44]] and summary["seed"] == 3
    assert set(summary["files"]) == expected
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # no temp folder left


def test_text_file_lengths_and_mdm_order(tiny_run, tmp_path, capsys):
    prompts = tmp_path / "prompts.txt"
    prompts.write_text("a person walks forward#48\n\nsomeone jumps up and down\n")
    out = tmp_path / "out"
    code, err = _run(
        capsys,
        "--text-file",
        str(prompts),
        "--num-samples",
        "2",
        "--checkpoints",
        str(tiny_run),
        "--out",
        str(out),
        "--render",
        "none",
    )
    assert code == 0, err
    summary = json.loads((out / "results.json").read_text())
    assert summary["lengths"][0] == [48, 48]
    sampled = summary["lengths"][1]
    assert all(40 <= n <= 196 and n % 4 == 0 for n in sampled)
    results = np.load(out / "results.npy", allow_pickle=True).item()
    assert results["motion"].shape[:3] == (4, 22, 3)
    assert results["motion"].shape[3] == max(48, *sampled)
    assert (results["num_samples"], results["num_repetitions"]) == (2, 2)
    # MDM order: motion index = repetition * num_prompts + prompt; padded with the last pose.
    for rep in range(2):
        for prompt in range(2):
            index = rep * 2 + prompt
            joints = np.load(out / f"sample{prompt:02d}_rep{rep:02d}.npy")
            length = results["lengths"][index]
            assert len(joints) == length
            motion = results["motion"][index].transpose(2, 0, 1)
            np.testing.assert_array_equal(motion[:length], joints)
            np.testing.assert_array_equal(
                motion[length:], np.broadcast_to(joints[-1], motion[length:].shape)
            )
    assert results["text"] == ["a person walks forward", "someone jumps up and down"] * 2


def test_same_seed_same_bytes_other_seed_other_motion(tiny_run, tmp_path, capsys):
    def run(name: str, seed: str) -> Path:
        out = tmp_path / name
        code, err = _run(
            capsys,
            "--text",
            "someone jumps up and down",
            "--checkpoints",
            str(tiny_run),
            "--out",
            str(out),
            "--seed",
            seed,
            "--num-samples",
            "2",
            "--bvh",
            "--render",
            "mp4",
            "--length",
            "40",
        )
        assert code == 0, err
        return out

    first, second, other = run("a", "7"), run("b", "7"), run("c", "8")
    assert sorted(p.name for p in first.iterdir()) == sorted(p.name for p in second.iterdir())
    for path in first.iterdir():
        assert path.read_bytes() == (second / path.name).read_bytes(), path.name
    assert not np.array_equal(
        np.load(first / "sample00_rep00.npy"), np.load(other / "sample00_rep00.npy")
    )


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--text", "   "], "empty"),
        (["--text", "qwxzv plughzz"], "no known word"),
        (["--text", "a person walks", "--num-samples", "0"], "at least 1"),
    ],
)
def test_bad_prompts_exit_2_and_write_nothing(tiny_run, tmp_path, capsys, argv, message):
    out = tmp_path / "out"
    code, err = _run(
        capsys,
        *argv,
        "--checkpoints",
        str(tiny_run),
        "--out",
        str(out),
        "--render",
        "none",
        "--length",
        "40",
    )
    assert code == 2
    assert message in err and err.count("\n") == 1
    assert not list(tmp_path.iterdir())


def test_bad_text_file_suffix(tiny_run, tmp_path, capsys):
    prompts = tmp_path / "p.txt"
    prompts.write_text("a person walks#fast\n")
    code, err = _run(
        capsys,
        "--text-file",
        str(prompts),
        "--checkpoints",
        str(tiny_run),
        "--out",
        str(tmp_path / "out"),
    )
    assert code == 2 and "p.txt:1" in err
    assert not (tmp_path / "out").exists()


def test_missing_and_mismatched_checkpoints(tiny_run, tmp_path, capsys):
    out = tmp_path / "out"
    code, err = _run(
        capsys,
        "--text",
        "a person walks",
        "--checkpoints",
        str(tmp_path / "none"),
        "--out",
        str(out),
    )
    assert code == 2 and "make train-" in err
    # A run without the text2length stage: fine with a fixed length, an error without one.
    partial = tmp_path / "partial"
    shutil.copytree(tiny_run / "generator", partial / "t2m")  # a run folder of the first releases
    code, err = _run(
        capsys,
        "--text",
        "a person walks",
        "--checkpoints",
        str(partial),
        "--out",
        str(out),
        "--render",
        "none",
    )
    assert code == 2 and "make train-len" in err
    code, err = _run(
        capsys,
        "--text",
        "a person walks",
        "--checkpoints",
        str(partial),
        "--out",
        str(out),
        "--render",
        "none",
        "--length",
        "40",
    )
    assert code == 0, err
    # A stage folder holding another stage's checkpoint.
    wrong = tmp_path / "wrong"
    shutil.copytree(tiny_run / "length", wrong / "length")
    shutil.copytree(tiny_run / "autoencoder", wrong / "generator")
    code, err = _run(
        capsys,
        "--text",
        "a person walks",
        "--checkpoints",
        str(wrong),
        "--out",
        str(tmp_path / "out2"),
    )
    assert code == 2 and "'autoencoder'" in err and "make train-t2m" in err
    assert err.count("\n") == 1
    assert not (tmp_path / "out2").exists()


def test_unwritable_or_occupied_out(tiny_run, tmp_path, capsys):
    blocker = tmp_path / "file.txt"
    blocker.write_text("x")
    code, err = _run(
        capsys,
        "--text",
        "a person walks",
        "--checkpoints",
        str(tiny_run),
        "--out",
        str(blocker / "sub"),
    )
    assert code == 2 and "is a file, not a folder" in err
    occupied = tmp_path / "occupied"
    occupied.mkdir()
    (occupied / "keep.txt").write_text("mine")
    argv = [
        "--text",
        "a person walks",
        "--checkpoints",
        str(tiny_run),
        "--out",
        str(occupied),
        "--render",
        "none",
        "--length",
        "40",
    ]
    code, err = _run(capsys, *argv)
    assert code == 2 and "not empty" in err
    # --overwrite replaces only an earlier output (it deletes the folder), never other files.
    code, err = _run(capsys, *argv, "--overwrite")
    assert code == 2 and outputs.MARKER in err
    assert (occupied / "keep.txt").read_text() == "mine"
    (occupied / "keep.txt").unlink()
    code, err = _run(capsys, *argv)
    assert code == 0, err
    first = (occupied / "results.npy").read_bytes()
    code, err = _run(capsys, *argv[:-2], "--length", "48", "--overwrite")
    assert code == 0, err
    assert (occupied / "results.npy").read_bytes() != first
    assert sorted(p.name for p in tmp_path.iterdir()) == ["file.txt", "occupied"]


def test_one_request_schema_for_the_command_line_and_python(pipe, tmp_path):
    # the command's config is the request plus the output options: one declaration
    assert issubclass(sample.SampleConfig, GenerationRequest)
    # --text is taken as typed; prompt lines (a file, or a list from Python or JSON) read '#N'
    assert GenerationRequest(text="a person walks#40").read_prompts() == [
        Prompt("a person walks#40")
    ]
    lines = GenerationRequest(prompts=["a person walks#48", " ", "someone jumps"], seconds=3.0)
    expected = [Prompt("a person walks", 48), Prompt("someone jumps", 60)]
    assert lines.prompts_for(pipe.spec) == expected
    file = tmp_path / "prompts.txt"
    file.write_text("a person walks#48\n\nsomeone jumps\n")
    assert GenerationRequest(prompts=str(file), seconds=3.0).prompts_for(pipe.spec) == expected
    with pytest.raises(UsageError, match="^prompt 2: after '#' give a length in frames"):
        GenerationRequest(prompts=("a person walks", "someone jumps#x")).read_prompts()
    for bad, message in [
        ({}, "give one of --text and --text-file"),
        ({"text": "x", "prompts": ("y",)}, "give one of --text and --text-file"),
        ({"prompts": ("", " ")}, "empty prompts"),
        ({"text": "x", "num_samples": 0}, "at least 1"),
        ({"text": "x", "length": 40, "seconds": 2.0}, "give one of --length and --seconds"),
    ]:
        with pytest.raises(UsageError, match=message):
            GenerationRequest(**bad)
    # the Python API takes the request's parts: the motions pipe.generate gives for them
    request = GenerationRequest(prompts=("a person walks forward#40",), num_samples=2, seed=3)
    prompts = request.prompts_for(pipe.spec)
    motions = pipe.generate(
        [p.text for p in prompts], lengths=[p.frames for p in prompts], **request.generate_options()
    )
    alone = pipe.generate("a person walks forward", 2, 40, seed=3)
    for got, want in zip(motions[0], alone[0]):
        np.testing.assert_array_equal(got.joints, want.joints)


def test_lengths_are_rounded_and_clamped_with_a_warning(caplog):
    with caplog.at_level(logging.WARNING, logger="t2m.pipeline"):
        assert frames_for(1000) == 196
        assert frames_for(10) == 40
    assert len(caplog.records) == 2
    assert frames_for(61) == 60 and frames_for(63) == 64
    assert frames_for(42) == 44 and frames_for(46) == 48  # halves round up, not to even
    assert frames_for_seconds(3.0) == 60
    with pytest.raises(ValueError):
        frames_for(float("nan"))
    with pytest.raises(ValueError):
        frames_for_seconds(-1.0)


def test_api_batches_prompts_and_samples(pipe):
    texts = ["a person walks forward", "someone jumps up and down", "a person turns to the left"]
    motions = pipe.generate(texts, num_samples=2, lengths=[40, None, 52], seed=0, batch_size=4)
    assert [len(row) for row in motions] == [2, 2, 2]
    for prompt, row in enumerate(motions):
        for rep, motion in enumerate(row):
            assert (motion.prompt_index, motion.repetition, motion.text) == (
                prompt,
                rep,
                texts[prompt],
            )
            assert motion.joints.shape == (motion.num_frames, 22, 3)
            assert motion.features.shape == (motion.num_frames, 263)
    assert [m.num_frames for m in motions[0]] == [40, 40]
    assert [m.num_frames for m in motions[2]] == [52, 52]
    # The same call gives the same motions; the two samples of a prompt differ.
    again = pipe.generate(texts, num_samples=2, lengths=[40, None, 52], seed=0, batch_size=4)
    for row, row_again in zip(motions, again):
        for a, b in zip(row, row_again):
            np.testing.assert_array_equal(a.joints, b.joints)
    assert not np.array_equal(motions[0][0].features, motions[0][1].features)


@pytest.mark.parametrize("precision", ["bf16", "int8"])
def test_reduced_precision_stays_close_to_fp32(tiny_run, pipe, precision):
    reduced = TextToMotion.from_checkpoints(tiny_run, device="cpu", precision=precision)
    kwargs = dict(num_samples=2, lengths=48, seed=5)
    reference = pipe.generate(["a person walks forward"], **kwargs)[0]
    result = reduced.generate(["a person walks forward"], **kwargs)[0]
    again = reduced.generate(["a person walks forward"], **kwargs)[0]
    for a, b, c in zip(reference, result, again):
        np.testing.assert_array_equal(b.joints, c.joints)  # deterministic too
        assert np.isfinite(b.joints).all()
        # Tiny models: the outputs must agree to well within a centimetre.
        assert np.abs(a.joints - b.joints).max() < 0.01


def test_bad_precision_is_a_value_error(tiny_run):
    with pytest.raises(ValueError, match="precision"):
        TextToMotion.from_checkpoints(tiny_run, precision="fp16")


def test_batched_decoding_gives_what_each_motion_decoded_alone_gives(pipe, monkeypatch):
    import torch

    prepared = pipe.prepare(["a person walks forward", "a person jumps", "a person walks back"])
    frames = [48, 80, 64]
    unit = pipe.spec.snippet_length
    codes = torch.randn(3, max(frames) // unit, pipe.initial_code.shape[-1])
    for row, length in enumerate(frames):
        codes[row, length // unit :] = 0.0  # as generate leaves the rows past an item's end
    monkeypatch.setattr(pipe.vae, "generate", lambda *args, **kwargs: codes)
    batched = pipe.generate_features([p.encoded for p in prepared], frames, torch.Generator())
    for row, length in enumerate(frames):
        with torch.no_grad():
            alone = pipe.decoder(codes[row : row + 1, : length // unit]).float()
        expected = pipe.normalizer.denormalize(alone).numpy()[0]
        assert batched[row].shape == (length, pipe.normalizer.dim)
        np.testing.assert_allclose(batched[row], expected, rtol=1e-5, atol=1e-5)


def test_with_precision_keeps_models_vocabulary_and_settings(pipe):
    import torch

    reduced = pipe.with_precision("bf16")
    assert reduced.precision == "bf16" and reduced.dtype == torch.bfloat16
    assert reduced.training_words == pipe.training_words and reduced.spec == pipe.spec
    assert reduced.vectorizer is pipe.vectorizer and reduced.spacy_pos == pipe.spacy_pos
    with pytest.raises(ValueError, match="needs a fp32 pipeline"):
        reduced.with_precision("fp32")
