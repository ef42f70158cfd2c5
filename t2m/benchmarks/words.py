"""Word vectors: converting a GloVe text file once, loading it from the cache, and loading
checkpoints that carry their own word table against ones that name the file.

Paper size: a synthetic GloVe file of 400,000 words x 300 (the size of glove.6B.300d.txt; quick
mode 40,000) is converted into a private cache (``T2M_CACHE_DIR`` in a temporary folder); a
paper-config generator checkpoint with random weights and a one-step Adam state is saved twice,
its vocabulary once as earlier versions stored it (the file's name: loading reads the file through
the cache) and once as a word table (4,199 caption words, the size of the original release's
HumanML3D subset, plus ``data.vocabulary_margin`` frequent words). Demo: the trained demo run's
generator and length checkpoints (``checkpoints/demo``, when present) as they are (they name the
built-in 50-d vectors) and rewritten with the table of the demo dataset's caption words. Loads are
timed in one process, the two forms alternating, with the per-process vocabulary cache cleared
before each; the medians are reported.
"""

from __future__ import annotations

import os
import shutil
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

import t2m.data.words as words_module
from t2m.data.words import CACHE_ENV, checkpoint_vocabulary, load_vectorizer

ROOT = Path(__file__).resolve().parents[2]
DEMO_RUN = ROOT / "checkpoints" / "demo"
DEMO_DATASET = ROOT / "data" / "demo"
CAPTION_WORDS = 4199
"""Words of the synthetic dataset's captions: the original release's HumanML3D subset size."""


def _write_glove(path: Path, count: int, dim: int, seed: int = 0) -> None:
    """A GloVe text file of ``count`` distinct words (``sos``/``eos``/``unk`` among them)."""
    rng = np.random.default_rng(seed)
    with open(path, "w", encoding="utf-8") as handle:
        for start in range(0, count, 10000):
            block = rng.normal(size=(min(10000, count - start), dim)).astype(np.float32)
            lines = []
            for offset, row in enumerate(block):
                index = start + offset
                word = ("sos", "eos", "unk")[index] if index < 3 else f"w{index}"
                lines.append(word + " " + " ".join(f"{x:.5f}" for x in row))
            handle.write("\n".join(lines) + "\n")


def _load_seconds(load) -> float:
    words_module._CACHE.clear()  # the per-process cache would make every load after the first free
    start = time.perf_counter()
    load()
    return time.perf_counter() - start


def _alternate(loads: dict[str, object], rounds: int) -> dict[str, float]:
    """Median seconds of each load, the loads alternating round by round."""
    times: dict[str, list[float]] = {name: [] for name in loads}
    for _ in range(rounds):
        for name, load in loads.items():
            times[name].append(_load_seconds(load))
    return {name: statistics.median(values) for name, values in times.items()}


def _paper_checkpoints(folder: Path, glove: Path) -> tuple[dict[str, Path], int]:
    """Run folders ``file`` and ``table`` with one paper-size generator checkpoint each, and
    the size of the table."""
    from dataset_tools.spec import HUMANML3D
    from t2m.config import apply_overrides
    from t2m.data.normalization import Normalizer
    from t2m.presets import preset
    from t2m.train import ModelSizes, find_stage
    from t2m.train.checkpoint import atomic_save, make_checkpoint

    config = apply_overrides(preset("paper"), {"data.word_vectors": str(glove)})
    whole = load_vectorizer(str(glove), config.data.max_text_tokens)
    rng = np.random.default_rng(1)
    caption_words = [whole.words[i] for i in rng.choice(whole.size, CAPTION_WORDS, replace=False)]
    table = whole.subset(caption_words, config.data.vocabulary_margin)
    sizes = ModelSizes(263, whole.dim, 0, config.autoencoder.model.code_size)
    models = find_stage("generator").build(config, sizes)
    optimizer = torch.optim.Adam([p for m in models.values() for p in m.parameters()])
    for module in models.values():
        for parameter in module.parameters():
            parameter.grad = torch.zeros_like(parameter)
    optimizer.step()  # the Adam state a saved run carries
    normalizer = Normalizer(np.zeros(263, np.float32), np.ones(263, np.float32))
    extra = {"initial_code": torch.zeros(config.autoencoder.model.code_size)}
    runs = {}
    for name, vocabulary in (("file", whole.info()), ("table", table.info())):
        checkpoint = make_checkpoint(
            "generator",
            config,
            sizes,
            HUMANML3D,
            models,
            optimizer,
            {},
            normalizer,
            vocabulary,
            extra,
        )
        path = folder / name / "generator" / "best.pt"
        path.parent.mkdir(parents=True)
        atomic_save(checkpoint, path)
        runs[name] = folder / name
    return runs, table.size


def _demo_runs(folder: Path) -> tuple[dict[str, Path], int]:
    """Copies of the demo run's length and generator stages: as trained, and with the table."""
    from t2m.train.checkpoint import atomic_save, read_checkpoint

    runs = {"file": folder / "demo_file", "table": folder / "demo_table"}
    size = 0
    for stage in ("length", "generator"):
        for name, run in runs.items():
            (run / stage).mkdir(parents=True)
            if name == "file":
                shutil.copy(DEMO_RUN / stage / "best.pt", run / stage / "best.pt")
                continue
            checkpoint = read_checkpoint(DEMO_RUN / stage / "best.pt")
            whole = load_vectorizer(checkpoint["vocabulary"]["source"])
            margin = checkpoint["config"]["data"].get("vocabulary_margin", 10000)
            checkpoint["vocabulary"] = checkpoint_vocabulary(whole, DEMO_DATASET, margin)
            size = checkpoint["vocabulary"]["size"]
            atomic_save(checkpoint, run / stage / "best.pt")
    return runs, size


def _sizes_mb(runs: dict[str, Path]) -> dict[str, float]:
    return {
        name: sum(p.stat().st_size for p in run.rglob("*.pt")) / 1e6 for name, run in runs.items()
    }


def run(quick: bool = False) -> dict:
    from t2m.pipeline import TextToMotion
    from t2m.train.stages import load_stage

    results: dict = {}
    count = 40000 if quick else 400000
    rounds = 3 if quick else 5
    saved_cache = os.environ.get(CACHE_ENV)
    with tempfile.TemporaryDirectory(prefix="t2m_words_bench_") as temporary:
        folder = Path(temporary)
        os.environ[CACHE_ENV] = str(folder / "cache")
        try:
            glove = folder / "glove.synthetic.300d.txt"
            _write_glove(glove, count, 300)
            results["words.glove_file_words"] = count
            results["words.glove_file_mb"] = round(glove.stat().st_size / 1e6, 1)
            words_module._CACHE.clear()
            results["words.glove_first_conversion_s"] = round(
                _load_seconds(lambda: load_vectorizer(str(glove))), 2
            )
            results["words.glove_cached_load_s"] = round(
                _alternate({"cached": lambda: load_vectorizer(str(glove))}, rounds)["cached"], 3
            )
            runs, table_words = _paper_checkpoints(folder, glove)
            sizes = _sizes_mb(runs)
            loads = _alternate(
                {
                    name: (lambda run=run: load_stage(run, "generator"))
                    for name, run in runs.items()
                },
                rounds,
            )
            results["words.paper_table_words"] = table_words
            for name in ("file", "table"):
                results[f"words.paper_generator_checkpoint_{name}_mb"] = round(sizes[name], 1)
                results[f"words.paper_generator_load_{name}_s"] = round(loads[name], 3)
            if (DEMO_RUN / "generator" / "best.pt").is_file() and DEMO_DATASET.is_dir():
                runs, table_words = _demo_runs(folder)
                sizes = _sizes_mb(runs)
                loads = _alternate(
                    {
                        name: (lambda run=run: TextToMotion.from_checkpoints(run))
                        for name, run in runs.items()
                    },
                    rounds,
                )
                results["words.demo_table_words"] = table_words
                for name in ("file", "table"):
                    results[f"words.demo_length_generator_checkpoints_{name}_mb"] = round(
                        sizes[name], 2
                    )
                    results[f"words.demo_pipeline_load_{name}_s"] = round(loads[name], 3)
        finally:
            words_module._CACHE.clear()
            if saved_cache is None:
                os.environ.pop(CACHE_ENV, None)
            else:
                os.environ[CACHE_ENV] = saved_cache
    return results
