"""Stage ``evaluator``: the contrastive text / motion evaluator on the frozen autoencoder's codes."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
from torch import nn

from t2m.data.dataset import MotionTextData
from t2m.models.evaluator import Evaluator, contrastive_loss
from t2m.train.job import StageJob
from t2m.train.runtime import adam, seed_init
from t2m.train.stage import LossesOf, StageRun, start_on_autoencoder, to_device


class EvaluatorObjective(nn.Module):
    """The trainable module: a caption + motion batch and a shift -> contrastive loss parts."""

    def __init__(self, evaluator: Evaluator, margin: float, negative_weight: float):
        super().__init__()
        self.evaluator = evaluator
        self.margin = margin
        self.negative_weight = negative_weight

    def forward(self, batch: dict[str, torch.Tensor], shift: int) -> dict[str, torch.Tensor]:
        text, motion = self.evaluator(
            batch["words"],
            batch["pos"],
            batch["text_lengths"],
            batch["motion"],
            batch["motion_lengths"],
        )
        losses = contrastive_loss(text, motion, shift, self.margin, self.negative_weight)
        # In-batch retrieval: how often a caption's nearest motion is its own (a cheap R@1).
        nearest = torch.cdist(text.float(), motion.float()).argmin(dim=1)
        losses["top1"] = (nearest == torch.arange(len(text), device=text.device)).float().mean()
        return losses


def draw_shift(rng: np.random.Generator, batch_size: int) -> int:
    """A negative-pair shift in 1 .. B-1 (never 0, which would pair items with themselves)."""
    return int(rng.integers(1, batch_size))


def train_evaluator(job: StageJob) -> Path:
    """Train the evaluator into its stage folder (needs the autoencoder); returns that folder."""
    # 1. the frozen autoencoder and its statistics, then the data
    start = start_on_autoencoder(job)
    job, data, sizes = start.job, start.data, start.sizes
    config, runtime = job.config, job.runtime
    section = config.evaluator
    # 2. model (frozen encoder copied in), optimizer, resume
    seed_init(config.seed)
    models = job.stage.build(config, sizes)
    evaluator = models["evaluator"].to(runtime.device)
    evaluator.movement_encoder.load_state_dict(
        start.autoencoder.models["autoencoder"].encoder.state_dict()
    )
    trainable_parameters = [p for p in evaluator.parameters() if p.requires_grad]
    optimizer = adam(trainable_parameters, lr=section.lr)
    run = StageRun(job, sizes, models, optimizer, data.normalizer, data.vocabulary)
    trainable = runtime.wrap(EvaluatorObjective(evaluator, section.margin, section.negative_weight))
    trainable.train()

    # 3. the loop: captions against unit-cropped motions, negatives by a random shift;
    # validation on fixed batches of at least two items (a shift needs another item)
    def losses_on(split: MotionTextData) -> LossesOf:
        def losses_of(items: np.ndarray, rng: np.random.Generator) -> dict[str, torch.Tensor]:
            batch = to_device(split.unit_crop_batch(items, rng), runtime.device)
            return trainable(batch, draw_shift(rng, len(items)))

        return losses_of

    size, count = section.batch_size, len(data.val)
    val_chunks = [
        np.arange(i * size, min(count, (i + 1) * size)) for i in range(max(1, count // size))
    ]
    run.train_epochs(
        len(data.train),
        losses_on(data.train),
        trainable_parameters,
        validate=lambda: run.validate(
            trainable, [c for c in val_chunks if len(c) >= 2], losses_on(data.val)
        ),
    )
    return run.finish()
