"""Stage ``length``: text to length, a classifier over motion lengths in units of 4 frames."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
from torch import nn

from t2m.data.dataset import MotionTextData
from t2m.models.length import LengthEstimator, length_loss
from t2m.train.job import StageJob
from t2m.train.runtime import adam, seed_init
from t2m.train.stage import (
    LossesOf,
    StageRun,
    check_batches,
    load_stage_data,
    to_device,
    validation_chunks,
)


class LengthObjective(nn.Module):
    """The trainable module: a caption batch -> cross-entropy and accuracy."""

    def __init__(self, estimator: LengthEstimator):
        super().__init__()
        self.estimator = estimator

    def forward(self, batch: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
        logits = self.estimator(
            batch["words"],
            batch["pos"],
            batch["text_lengths"],
            batch.get("counts"),
            batch.get("clause", False),
        )
        return length_loss(logits, batch["length_class"])


def train_length(job: StageJob) -> Path:
    """Train the length classifier into its stage folder; returns that folder."""
    config, runtime = job.config, job.runtime
    section = config.length
    # 1. data and vocabulary
    data = load_stage_data(config, job.dataset_dir)
    check_batches(job, data)
    sizes = data.sizes()
    # 2. model, optimizer, resume
    seed_init(config.seed)
    models = job.stage.build(config, sizes)
    estimator = models["length"].to(runtime.device)
    optimizer = adam(estimator.parameters(), lr=section.lr)
    run = StageRun(job, sizes, models, optimizer, data.normalizer, data.vocabulary)
    trainable = runtime.wrap(LengthObjective(estimator))
    trainable.train()

    # 3. the loop: one random caption per clip and epoch; validation on fixed captions
    def losses_on(split: MotionTextData, clause_examples: float = 0.0) -> LossesOf:
        def losses_of(items: np.ndarray, rng: np.random.Generator) -> dict[str, torch.Tensor]:
            batch = split.length_batch(items, rng, clause_examples)
            return trainable(to_device(batch, runtime.device))

        return losses_of

    # validation on whole captions, comparable across settings
    val_chunks = validation_chunks(np.arange(len(data.val)), section.batch_size)
    run.train_epochs(
        len(data.train),
        losses_on(data.train, section.clause_examples),
        list(estimator.parameters()),
        validate=lambda: run.validate(trainable, val_chunks, losses_on(data.val)),
    )
    return run.finish()
