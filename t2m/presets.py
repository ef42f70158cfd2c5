"""Named presets: ``paper`` (the published sizes), ``demo`` (small models for the demo corpus
on two CPU cores) and ``tiny`` (seconds, for tests). Each is a function returning a full
:class:`t2m.config.Config`, kept in :data:`PRESETS` with notes on how it was chosen (printed by
``python -m t2m.train --print-config``); :func:`preset` builds one by name.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from dataset_tools.command import UsageError
from t2m.config import (
    AutoencoderConfig,
    AutoencoderStageConfig,
    Config,
    EvaluatorConfig,
    EvaluatorStageConfig,
    GeneratorStageConfig,
    LengthModelConfig,
    LengthStageConfig,
    TemporalVAEConfig,
    TextEncoderConfig,
)


@dataclass(frozen=True)
class Preset:
    """A named Config with notes on how it was chosen and what it gave (``--print-config``)."""

    name: str
    build: Callable[[], Config]
    notes: str


def paper() -> Config:
    """The sizes and optimisation settings of Guo et al. (CVPR 2022)."""
    cfg = Config(preset="paper")
    # The release's training scripts divide the same std array by feat_bias = 5 once per
    # dataset they build (train and validation): its models saw root and contact std / 25.
    cfg.data.feature_bias = 25.0
    # What the original code needs to run an export of this run as we do
    # (python -m t2m.release.export): its networks take 300-d GloVe words, tag captions with its
    # own motion-word lists and flip the backward word features.
    cfg.data.word_vectors = PAPER_WORD_VECTORS
    cfg.data.motion_words = "release"
    cfg.generator.model.text.flip_backward_words = True
    return cfg


PAPER_WORD_VECTORS = "glove/glove.6B.300d.txt"
"""The paper preset's word vectors: GloVe 6B 300-d, looked for under ``glove/`` of the working
folder (``--data.word_vectors=PATH`` elsewhere; a missing file stops training at once)."""


PAPER_NOTES = """Sizes and optimisation settings of Guo et al. (CVPR 2022), for HumanML3D or KIT-ML
on a GPU, with GloVe 6B 300-d word vectors (glove/glove.6B.300d.txt, or --data.word_vectors=PATH;
from nlp.stanford.edu/projects/glove), the release's motion-word lists and the release's flip of
the backward word features, so that python -m t2m.release.export writes a release the original
code runs as we do (docs/release.md). Epoch counts are ours: an autoencoder epoch is one random 24-frame window per clip,
and the generator's curriculum advances on validation patience, so step counts differ from the
original scripts'. Normalisation as the release trained: root and foot-contact std divided by
25 (data.feature_bias), as in the release's meta/std.npy."""


def demo() -> Config:
    """Small models that train all four stages on the demo corpus (``make demo``; its time per
    CPU class: docs/performance.md)."""
    # One thread: these sizes are dominated by per-op overhead, where a second thread gains
    # little and loses a lot whenever another process wants the core (--num_threads=2 to try).
    cfg = Config(preset="demo", num_threads=1)
    # Sized in optimiser steps (epoch_steps: one pass over the demo corpus' 3,200 training clips),
    # so that another dataset trains as many steps: 420 Bandai-Namco captures (672 training
    # clips) trained a fifth of them when epochs were passes, and the generator walked in place.
    cfg.sized_for_clips = 3200
    # The longest demo captions have 30 words; at 20, 5.8% of them lost their last words
    # (count words among them).
    cfg.data.max_text_tokens = 28
    cfg.autoencoder = AutoencoderStageConfig(
        model=AutoencoderConfig(hidden_size=192, code_size=128, dropout=0.1),
        batch_size=64,
        lr=1e-3,
        reconstruction_loss="smooth_l1",
        epochs=40,
        epoch_steps=50,  # 40 x 50 = 2,000 steps
        checkpoint_every=500,
    )
    cfg.length = LengthStageConfig(
        model=LengthModelConfig(
            text=TextEncoderConfig(hidden_size=64), mlp_sizes=(128, 64), plan_inputs=True
        ),
        clause_examples=0.5,
        batch_size=64,
        lr=1e-3,
        epochs=25,
        epoch_steps=50,  # 1,250 steps
    )
    cfg.generator = GeneratorStageConfig(
        model=TemporalVAEConfig(
            text=TextEncoderConfig(hidden_size=96),
            hidden_size=256,
            latent_size=32,
            attention_size=128,
            # "claps five times": a clock that turns five times between a 0.6 s wind-up and
            # wind-down (3 snippets at 20 fps); see DEMO_NOTES.
            count_clock=True,
            count_clock_margin=3,
        ),
        batch_size=32,
        lr=1e-3,
        decoder_lr=1e-4,
        start_snippets=10,
        end_snippets=49,
        curriculum_step=13,
        # A fixed schedule: 2 epochs per length, 19 at the last; no patience ends it (3 stopped the
        # generator on the 420 Bandai-Namco captures after 15 of 25 epochs: the real-mocap check
        # read 0.63 with it, 0.78 without; on the demo corpus it never fired).
        patience=1_000,
        max_stage_epochs=2,
        final_epochs=17,
        # The last 8 epochs' learning rates fall to a tenth (half cosine): at a constant rate
        # the speed a caption gets swung by 10-50% between checkpoints 200 steps apart (runs
        # read as too slow or too fast by the detectors); see DEMO_NOTES.
        anneal_epochs=8,
        anneal_to=0.1,
        whole_clips=True,
        epoch_steps=100,  # 25 epochs x 100 = 2,500 steps
        checkpoint_every=100,
    )
    cfg.evaluator = EvaluatorStageConfig(
        model=EvaluatorConfig(
            text=TextEncoderConfig(hidden_size=64), motion_hidden_size=128, embedding_size=128
        ),
        batch_size=32,
        lr=1e-3,
        epochs=8,
        epoch_steps=100,  # 800 steps
    )
    return cfg


DEMO_NOTES = """Small models that train all four stages on the procedural demo corpus on two CPU
cores (make demo). The autoencoder uses smooth L1 (the original's L1 loses one-handed waves at
this size); the generator trains whole clips over four curriculum lengths (10, 23, 36, 49
snippets: 2 epochs each, 19 at the last, no patience; the last 8 at learning rates falling to a
tenth, without which what a caption says of speed had not settled: runs read as too slow or too
fast by the detectors, run 0.66 in one make demo; with it 0.90 and 0.93 over two generator
seeds) with a count clock ("claps five times" turns a clock five times between a 0.6 s
wind-up and wind-down); the length model reads a
caption's count and whether it is a clause. Sized in optimiser steps, not passes (epoch_steps:
one pass over the demo corpus' 3,200 training clips): autoencoder 2,000, length 1,250,
generator 2,500, evaluator 800 on any dataset; a training split under 800 clips logs a
warning. make demo from a fresh clone: 9.9 min after the install on a 2-core Intel Xeon
(AVX-512), 2026-12-02; 19.8 min on a 2-core AMD EPYC Zen 3 (AVX2), 2026-12-03 (time make
demo). Its quick evaluation as it was then (python -m t2m.evaluate --quick --plan clauses, 128
uniform items): semantic accuracy 0.878 +- 0.018 and 0.870 +- 0.018. docs/results.md,
docs/performance.md."""


def tiny() -> Config:
    """Minute models and a few steps per stage: seconds, for tests."""
    # One thread: these models are far too small to gain from more, and idle worker threads
    # spinning on a busy machine make each small op milliseconds slower.
    cfg = Config(preset="tiny", num_threads=1)
    cfg.autoencoder = AutoencoderStageConfig(
        model=AutoencoderConfig(hidden_size=32, code_size=16, dropout=0.1),
        batch_size=16,
        lr=1e-3,
        epochs=2,
        checkpoint_every=5,
        log_every=2,
    )
    cfg.length = LengthStageConfig(
        model=LengthModelConfig(
            text=TextEncoderConfig(hidden_size=16), mlp_sizes=(32, 16), plan_inputs=True
        ),
        clause_examples=0.5,
        batch_size=16,
        lr=1e-3,
        epochs=2,
        checkpoint_every=5,
        log_every=2,
    )
    cfg.generator = GeneratorStageConfig(
        model=TemporalVAEConfig(
            text=TextEncoderConfig(hidden_size=16),
            hidden_size=32,
            latent_size=8,
            attention_size=16,
            count_clock=True,  # as the demo preset: the tests train and sample through it
            count_clock_margin=3,
        ),
        batch_size=8,
        lr=1e-3,
        decoder_lr=1e-4,
        start_snippets=10,
        end_snippets=12,
        patience=1,
        max_stage_epochs=1,
        checkpoint_every=5,
        log_every=2,
    )
    cfg.evaluator = EvaluatorStageConfig(
        model=EvaluatorConfig(
            text=TextEncoderConfig(hidden_size=16), motion_hidden_size=32, embedding_size=16
        ),
        batch_size=8,
        lr=1e-3,
        epochs=2,
        checkpoint_every=5,
        log_every=2,
    )
    return cfg


PRESETS = {
    preset.name: preset
    for preset in (
        Preset("paper", paper, PAPER_NOTES),
        Preset("demo", demo, DEMO_NOTES),
        Preset("tiny", tiny, "Minute models and a few steps per stage: seconds, for tests."),
    )
}


def preset(name: str) -> Config:
    """The Config of a named preset; UsageError (a ValueError) for an unknown name."""
    if name not in PRESETS:
        raise UsageError(f"unknown preset {name!r}; choose one of {', '.join(PRESETS)}")
    return PRESETS[name].build()
