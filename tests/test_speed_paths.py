"""The performance work's contracts: gradient clipping as the original, int8 / bf16 pipelines
without a deep copy, the GloVe binary cache."""

from __future__ import annotations

import pytest

from t2m.presets import PRESETS, preset


@pytest.mark.parametrize("name", sorted(PRESETS))
def test_clipping_follows_the_original(name):
    # The original clips 0.5 in its length, temporal-VAE and evaluator trainers, not the
    # autoencoder's.
    config = preset(name)
    assert config.length.grad_clip == 0.5
    assert config.generator.grad_clip == 0.5
    assert config.evaluator.grad_clip == 0.5
    assert config.autoencoder.grad_clip == 0.0


@pytest.mark.parametrize("precision", ["int8", "bf16"])
def test_reduced_precision_converts_in_place_only_when_asked(tiny_run, precision):
    import torch

    from t2m.hardware import native_bf16
    from t2m.pipeline import TextToMotion

    fp32 = TextToMotion.from_checkpoints(tiny_run)
    expected = fp32.generate("a person walks forward", lengths=40, seed=3)[0][0].joints
    vae, decoder = fp32.vae, fp32.decoder
    copied = fp32.with_precision(precision)  # copies: the fp32 pipeline keeps working
    assert copied.vae is not vae
    assert type(vae.generator.input) is torch.nn.Linear
    assert vae.generator.input.weight.dtype == torch.float32
    again = fp32.generate("a person walks forward", lengths=40, seed=3)[0][0].joints
    assert (again == expected).all()
    # from_checkpoints owns what it loads: converted in place, no second copy of the weights
    loaded = TextToMotion.from_checkpoints(tiny_run, precision=precision)
    low = loaded.generate("a person walks forward", lengths=40, seed=3)[0][0].joints
    # Not float32 rounding: int8 weights (steps of max|W| / 127, 0.8%) or bfloat16 (2^-8, 0.4%)
    # per product, carried through 10 generation steps, the decoder and forward kinematics. 5% of
    # the largest coordinate plus 5 cm bounds that; > 0 checks the conversion happened at all.
    assert 0 < abs(low - expected).max() < 0.05 * abs(expected).max() + 0.05
    owned = TextToMotion(
        vae,
        decoder,
        fp32.normalizer,
        fp32.vectorizer,
        fp32.initial_code,
        precision=precision,
        training_words=fp32.training_words,
        copy_models=False,
    )
    assert owned.vae is vae and owned.decoder is decoder
    # int8's decoder runs in bfloat16 only where the CPU computes it natively (t2m.pipeline)
    assert owned.decoder.out.weight.dtype == owned.decoder_dtype
    assert owned.decoder_dtype == (torch.bfloat16 if precision == "bf16" else torch.float32) or (
        precision == "int8" and native_bf16("cpu")
    )


def _write_glove(path, words, dim, seed):
    import numpy as np

    vectors = np.random.default_rng(seed).normal(size=(len(words), dim)).astype(np.float32)
    lines = [" ".join([w, *(f"{v:.6f}" for v in row)]) for w, row in zip(words, vectors)]
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return np.array([[float(f"{v:.6f}") for v in row] for row in vectors], np.float32)


def test_glove_text_is_converted_once_to_a_cache(tmp_path, monkeypatch):
    import numpy as np

    from t2m.data import words as words_module

    monkeypatch.setenv(words_module.CACHE_ENV, str(tmp_path / "cache"))
    glove = tmp_path / "glove.txt"
    names = ["sos", "eos", "unk", "walk", "wave", "café"]
    expected = _write_glove(glove, names, 7, seed=0)
    words, vectors = words_module.load_glove_file(glove)
    assert words == names and np.array_equal(vectors, expected)
    cached = sorted(p.suffix for p in (tmp_path / "cache" / "glove").iterdir())
    assert cached == [".npy", ".sha256", ".words"]
    # later loads read the cache: the text is not parsed again, and no file is rewritten
    stamps = {p: p.stat().st_mtime_ns for p in (tmp_path / "cache" / "glove").iterdir()}

    def refuse(path):
        raise AssertionError("parsed the text again")

    monkeypatch.setattr(words_module, "_load_glove_text", refuse)
    words, vectors = words_module.load_glove_file(glove)
    assert words == names and np.array_equal(vectors, expected)
    assert isinstance(vectors, np.memmap)
    assert {p: p.stat().st_mtime_ns for p in stamps} == stamps
    vectorizer = words_module.WordVectors(words, vectors, str(glove))
    assert vectorizer.encode_tokens(["walk/VERB"]).words[1].tolist() == expected[3].tolist()


def test_glove_cache_follows_the_content_and_repairs_itself(tmp_path, monkeypatch):
    import os

    import numpy as np

    from t2m.data import words as words_module

    monkeypatch.setenv(words_module.CACHE_ENV, str(tmp_path / "cache"))
    glove = tmp_path / "glove.txt"
    _write_glove(glove, ["sos", "eos", "unk", "a"], 3, seed=0)
    words_module.load_glove_file(glove)
    # new content: a new key (the remembered hash is per path, size and mtime)
    expected = _write_glove(glove, ["sos", "eos", "unk", "b"], 3, seed=1)
    stat = glove.stat()
    os.utime(glove, ns=(stat.st_atime_ns, stat.st_mtime_ns + 1))
    words, vectors = words_module.load_glove_file(glove)
    assert words[-1] == "b" and np.array_equal(vectors, expected)
    # a damaged entry (words without their vectors' rows) is rebuilt, not trusted
    for words_file in (tmp_path / "cache" / "glove").glob("*.words"):
        words_file.write_text("sos\neos", encoding="utf-8")
    words, vectors = words_module.load_glove_file(glove)
    assert words[-1] == "b" and np.array_equal(vectors, expected)


def _results(cpu, **values):
    return {
        "environment": {"cpu": cpu, "cpu_count": 2, "torch_threads": 2, "torch": "2", "date": "d"},
        "quick": False,
        "parts": {"sample": {"status": "ok", "results": values}},
    }


def test_bench_compare_prints_ratios_of_shared_numbers():
    from t2m.bench import compare

    now = _results("X", fp32_ms=150.0, int8_ms=30, frames=196, note="a", new_only=1.0)
    table = compare(now, _results("X", fp32_ms=300.0, int8_ms=40, frames=196, note="a"))
    assert "| sample | fp32_ms | 300.0 | 150.0 | 0.500 |" in table
    assert "| sample | int8_ms | 40 | 30 | 0.750 |" in table
    assert "note" not in table and "new_only" not in table
    assert "NOT the same setting" not in table
    assert "NOT the same setting: cpu 'Y' -> 'X'" in compare(now, _results("Y", fp32_ms=1.0))


def test_bench_compare_refuses_a_file_that_is_no_results(tmp_path):
    from dataset_tools.command import UsageError
    from t2m.bench import read_results

    bad = tmp_path / "results.json"
    bad.write_text("[1, 2]")
    with pytest.raises(UsageError, match="not a results.json"):
        read_results(bad)
    with pytest.raises(UsageError, match="cannot read"):
        read_results(tmp_path / "missing.json")


def test_make_bench_runs_every_part_but_the_side_by_side():
    from t2m.bench import available

    parts = available()
    assert {"representation", "train", "sample", "memory"} <= set(parts)
    assert "versus_original" not in parts


def test_side_by_side_ratios_are_medians_of_per_round_ratios():
    from t2m.benchmarks.versus_original import interleave, summarise, to_markdown

    calls = []
    sides = {
        "original": lambda: calls.append("o") or (2.0, 1.0),
        "ours_fp32": lambda: calls.append("a") or (1.0, 1.0),
    }
    times = interleave(sides, rounds=3)
    assert calls == ["o", "a", "o", "a", "a", "o", "o", "a"]  # warm-up, then rotated rounds
    (row,) = summarise("generation_b1", times)
    assert row["measure"] == "generation_b1 fp32"
    assert (row["ratio"], row["cpu_ratio"], row["rounds"]) == (0.5, 1.0, 3)
    table = to_markdown(
        {
            "environment": {
                "date": "d",
                "cpu": "c",
                "cores": 2,
                "threads": 1,
                "load_average_at_end": (1.0, 1.0, 1.0),
                "torch": "t",
                "python": "p",
                "rounds": 3,
            },
            "rows": [row],
        }
    )
    assert "| generation_b1 fp32 | 2.0 s | 1.0 s | 0.5 (0.5-0.5) | 1.0 |" in table


def test_sentence_alone_is_the_forward_sentence():
    import torch

    from t2m.config import TextEncoderConfig
    from t2m.models.text_encoder import TextEncoder

    torch.manual_seed(0)
    encoder = TextEncoder(6, TextEncoderConfig(hidden_size=5)).train()
    words, pos = torch.randn(3, 7, 6), torch.eye(15)[torch.randint(0, 15, (3, 7))]
    lengths = torch.tensor([7, 2, 4])
    _, expected = encoder(words, pos, lengths)
    sentence = encoder.sentence(words, pos, lengths)
    assert torch.equal(sentence, expected)
    sentence.sum().backward()
    fast = [p.grad.clone() for p in encoder.parameters()]
    encoder.zero_grad()
    encoder(words, pos, lengths)[1].sum().backward()
    for a, p in zip(fast, encoder.parameters()):
        torch.testing.assert_close(a, p.grad)
