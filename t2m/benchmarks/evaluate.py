"""Evaluation speed: the 20-replication protocol at demo sizes, one replication at paper size
(extrapolated to 20), batched vs one-at-a-time generation at both sizes (interleaved round by
round, see :func:`_generation_speedup`), and the evaluator's forward pass at paper sizes.

Paper size: the ``paper`` preset's models with random weights (its word vectors are the built-in
50-d ones, not 300-d: only the text encoder's first layer is smaller), on a synthetic split of
4,384 items of 40..199 frames (HumanML3D's test.txt lists 4,384 names); quick mode: 256 items and
16 x 10 MultiModality generations.

Timings do not depend on the weights, so the models are built untrained from the presets unless a
trained demo run (``checkpoints/demo``) and the demo dataset (``data/demo``) are present; the
test split is the demo corpus' when present, else a synthetic one of the same size (600 items of
40..199 frames, 15% of 2,000 clips x 2 mirrors). Everything runs on one torch thread (the number
is recorded with the load average): on a busy two-core machine two threads oversubscribe and
every small op can wait milliseconds for a descheduled thread (measured up to ten times slower,
and erratic). Times are wall seconds, with the process's CPU seconds beside the generation and
replication times (``*_cpu``): single-threaded, CPU time leaves out the time other processes held
the cores, so on a shared machine it is the figure to compare.
"""

from __future__ import annotations

import logging
import os
import statistics
import time
from pathlib import Path

import numpy as np
import torch

from dataset_tools import humanml3d
from t2m import evaluate
from t2m.data.dataset import Caption, Clip
from t2m.pipeline import TextToMotion
from t2m.train import find_stage

logger = logging.getLogger(__name__)

ROOT = Path(__file__).resolve().parents[2]
DEMO_DATASET = ROOT / "data" / "demo"
DEMO_RUN = ROOT / "checkpoints" / "demo"
SYNTHETIC_ITEMS = 600
PAPER_TEST_ITEMS = 4384
"""Names in HumanML3D's test.txt: the synthetic split of the paper-size measurements."""
WORDS = (
    "a/DET person/NOUN walk/VERB forward/ADV slowly/ADV then/ADV turn/VERB left/ADJ and/CCONJ "
    "jump/VERB wave/VERB right/ADJ hand/NOUN kick/VERB with/ADP the/DET foot/NOUN"
).split()


def _untrained_stages(preset_name: str) -> dict:
    """eval, length and t2m stages of a preset's sizes with random weights, by name."""
    from t2m.data.normalization import Normalizer
    from t2m.data.words import BUILTIN_GLOVE, load_vectorizer
    from t2m.presets import preset
    from t2m.train import ModelSizes, TrainedStage

    config = preset(preset_name)
    vectorizer = load_vectorizer(BUILTIN_GLOVE, config.data.max_text_tokens)  # timing only
    dims = ModelSizes(263, vectorizer.dim, 0, config.autoencoder.model.code_size)
    normalizer = Normalizer(np.zeros(263, np.float32), np.ones(263, np.float32))
    torch.manual_seed(0)
    stages = {}
    for stage in ("evaluator", "length", "generator"):
        models = find_stage(stage).build(config, dims)
        for module in models.values():
            module.eval()
        stages[stage] = TrainedStage(
            stage=stage,
            config=config,
            models=models,
            normalizer=normalizer,
            vectorizer=vectorizer,
            progress={},
            dims=dims,
            initial_code=(
                torch.zeros(config.autoencoder.model.code_size) if stage == "generator" else None
            ),
        )
    return stages


def _untrained_backend(preset_name: str) -> evaluate.CheckpointBackend:
    stages = _untrained_stages(preset_name)
    generator, length = stages["generator"], stages["length"]
    pipeline = TextToMotion(
        vae=generator.models["vae"],
        decoder=generator.models["decoder"],
        normalizer=generator.normalizer,
        vectorizer=generator.vectorizer,
        initial_code=generator.initial_code,
        spec=generator.spec,
        length_model=length.models["length"],
        length_vectorizer=length.vectorizer,
    )
    return evaluate.CheckpointBackend(stages["evaluator"], pipeline)


def _synthetic_clips(count: int, rng: np.random.Generator) -> list[Clip]:
    clips = []
    for index in range(count):
        frames = int(rng.integers(40, 200))
        captions = [
            Caption("synthetic", list(rng.choice(WORDS, size=int(rng.integers(4, 12)))))
            for _ in range(3)
        ]
        motion = rng.normal(size=(frames, 263)).astype(np.float32)
        clips.append(Clip(f"synthetic_{index:04d}", motion, captions))
    return clips


def _backend_and_clips() -> tuple[evaluate.CheckpointBackend, list[Clip], str, bool]:
    """The backend, the test items, a description, and whether they are the real demo run."""
    trained = (find_stage("evaluator").folder(DEMO_RUN) / "best.pt").is_file()
    if trained and humanml3d.split_path(DEMO_DATASET, "test").is_file():
        from t2m.data.dataset import load_split

        backend = evaluate.CheckpointBackend.from_run_dir(DEMO_RUN)
        clips = load_split(DEMO_DATASET, "test", spec=backend.spec)
        return backend, clips, "trained demo run on the demo test split", True
    backend = _untrained_backend("demo")
    clips = _synthetic_clips(SYNTHETIC_ITEMS, np.random.default_rng(0))
    source = f"untrained demo-size models, synthetic split of {SYNTHETIC_ITEMS} items"
    return backend, clips, source, False


def _generation_speedup(
    backend: evaluate.CheckpointBackend,
    clips: list[Clip],
    count: int,
    single_count: int,
    rounds: int,
    prefix: str,
) -> dict[str, float]:
    """Batched against one-at-a-time generation of test captions, interleaved round by round.

    Each round generates ``count`` drawn items batched (the evaluation's batches, as its
    generated rows do) and then a random ``single_count`` of them one at a time; the speed-up is
    the median over rounds of (seconds per generated frame one at a time) / (seconds per frame
    batched): per frame, because the subset's mean length differs from the draw's (by 11% at
    paper size with these seeds). Also: motions/s of each, the share of batched recurrent steps
    spent on padding, and bf16 batched once.
    """
    from t2m.evaluate.backend import padding_share

    draw = evaluate.draw_items(clips, count, np.random.default_rng(1))
    captions, lengths = draw.caption_list(clips), draw.lengths
    subset = np.sort(np.random.default_rng(2).choice(count, single_count, replace=False))
    single_captions, single_lengths = [captions[i] for i in subset], lengths[subset]
    batch_size = backend.batch_size
    backend.generate(captions[:4], lengths[:4], seed=0)  # warm-up
    batched, single = [], []  # (wall, CPU) seconds per motion, per round
    try:
        for _ in range(rounds):
            backend.batch_size = batch_size
            batched.append(_per_item(lambda: backend.generate(captions, lengths, seed=0), count))
            backend.batch_size = 1
            single.append(
                _per_item(
                    lambda: backend.generate(single_captions, single_lengths, seed=0), single_count
                )
            )
    finally:
        backend.batch_size = batch_size
    pipeline = backend.pipeline
    backend.pipeline = pipeline.with_precision("bf16")
    try:
        backend.generate(captions[:4], lengths[:4], seed=0)  # warm-up
        start = time.perf_counter()
        backend.generate(captions, lengths, seed=0)
        batched_bf16 = (time.perf_counter() - start) / count
    finally:
        backend.pipeline = pipeline
    out = {f"{prefix}_generate_batched_bf16_motions_per_s": round(1 / batched_bf16, 1)}
    frames_ratio = float(lengths.mean() / single_lengths.mean())  # per motion -> per frame
    for clock, suffix in ((0, ""), (1, "_cpu")):
        ratios = [s[clock] / b[clock] * frames_ratio for s, b in zip(single, batched, strict=True)]
        out |= {
            f"{prefix}_generate_batched_motions_per_s{suffix}": round(
                1 / statistics.median(b[clock] for b in batched), 1
            ),
            f"{prefix}_generate_one_at_a_time_motions_per_s{suffix}": round(
                1 / statistics.median(s[clock] for s in single), 2
            ),
            f"{prefix}_batched_generation_speedup_x{suffix}": round(statistics.median(ratios), 2),
        }
    return out | {
        f"{prefix}_batched_padding_pct": round(100 * padding_share(lengths, batch_size), 1),
        f"{prefix}_generation_items_batched_one_at_a_time_rounds": f"{count}/{single_count}/{rounds}",
    }


def _per_item(function, count: int) -> tuple[float, float]:
    """(wall, CPU) seconds of one call of ``function``, divided by ``count``."""
    wall, cpu = time.perf_counter(), time.process_time()
    function()
    return (time.perf_counter() - wall) / count, (time.process_time() - cpu) / count


def _paper_replication(items: int, quick: bool) -> dict:
    """One replication of the protocol with paper-size untrained models on a synthetic split of
    ``items`` items (HumanML3D's test.txt lists 4,384): seconds, and the 20-replication
    estimate."""
    backend = _untrained_backend("paper")
    clips = _synthetic_clips(items, np.random.default_rng(3))
    config = evaluate.EvalConfig(replications=1)
    if quick:
        config = evaluate.EvalConfig(replications=1, mm_texts=16, mm_samples=10)
    start, cpu = time.perf_counter(), time.process_time()
    result = evaluate.run_protocol(clips, backend, config)
    elapsed, cpu = time.perf_counter() - start, time.process_time() - cpu
    out = {
        "evaluate.paper_protocol_items": result.num_items,
        "evaluate.paper_protocol_mm": f"{config.mm_texts}x{config.mm_samples}",
        "evaluate.paper_replication_s": round(elapsed, 1),
        "evaluate.paper_replication_s_cpu": round(cpu, 1),
        "evaluate.paper_20_replications_s_estimated_from_1": round(20 * elapsed),
    }
    for part in ("generate_s", "embed_s", "metrics_s", "physical_s"):
        out[f"evaluate.paper_{part.removesuffix('_s')}_share_pct"] = round(
            100 * result.timings_s[part] / elapsed, 1
        )
    return out


def _paper_evaluator_forward(repeats: int) -> float:
    """Seconds for the paper-size evaluator to embed 32 captions and 32 motions of 196 frames."""
    eval_stage = _untrained_stages("paper")["evaluator"]
    evaluator = eval_stage.models["evaluator"]
    words = torch.randn(32, 22, eval_stage.dims.word_dim)
    pos = torch.zeros(32, 22, 15)
    text_lengths = torch.full((32,), 12, dtype=torch.long)
    motion = torch.randn(32, 196, 263)
    motion_lengths = torch.full((32,), 196, dtype=torch.long)
    with torch.no_grad():
        evaluator(words, pos, text_lengths, motion, motion_lengths)  # warm-up
        start = time.perf_counter()
        for _ in range(repeats):
            evaluator(words, pos, text_lengths, motion, motion_lengths)
    return (time.perf_counter() - start) / repeats


def run(quick: bool = False) -> dict:
    """Every evaluation measurement, on one torch thread (see the module docstring)."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        return _measure(quick)
    finally:
        torch.set_num_threads(threads)


def _measure(quick: bool) -> dict:
    logging.getLogger("t2m").setLevel(logging.WARNING)
    backend, clips, source, real_demo = _backend_and_clips()
    results: dict = {
        "evaluate.setup": source,
        "evaluate.test_items": len(clips),
        "evaluate.torch_threads": torch.get_num_threads(),
        "evaluate.batch_size": backend.batch_size,
        "evaluate.load_average_1min_at_start": round(os.getloadavg()[0], 2),
    }
    # (count, single_count, rounds) of _generation_speedup
    demo_sizes = (128, 32, 1) if quick else (512, 128, 3)
    results.update(_generation_speedup(backend, clips, *demo_sizes, "evaluate.demo"))
    paper_clips = _synthetic_clips(PAPER_TEST_ITEMS, np.random.default_rng(0))
    paper_sizes = (256, 8, 1) if quick else (1024, 32, 3)
    paper_backend = _untrained_backend("paper")
    results.update(_generation_speedup(paper_backend, paper_clips, *paper_sizes, "evaluate.paper"))
    results["evaluate.paper_evaluator_forward_batch32_s"] = round(
        _paper_evaluator_forward(2 if quick else 5), 3
    )
    replications = 2 if quick else 20
    config = evaluate.EvalConfig(replications=replications)
    semantic = evaluate.find_scorer(DEMO_DATASET) if real_demo else None
    start, cpu = time.perf_counter(), time.process_time()
    result = evaluate.run_protocol(clips, backend, config, semantic=semantic)
    elapsed, cpu = time.perf_counter() - start, time.process_time() - cpu
    per_replication = elapsed / replications
    results["evaluate.protocol_items"] = result.num_items
    results["evaluate.replication_s"] = round(per_replication, 2)
    results["evaluate.replication_s_cpu"] = round(cpu / replications, 2)
    key = "evaluate.20_replications_s" + ("_estimated_from_2" if quick else "")
    results[key] = round(per_replication * 20, 1)
    for part in ("generate_s", "embed_s", "metrics_s", "semantic_s"):
        results[f"evaluate.{part.removesuffix('_s')}_share_pct"] = round(
            100 * result.timings_s[part] / elapsed, 1
        )
    results.update(_paper_replication(256 if quick else PAPER_TEST_ITEMS, quick))
    return results
