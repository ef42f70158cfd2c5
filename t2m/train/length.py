"""Stage 2: text2length, a classifier over motion lengths in units of 4 frames."""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import torch
from torch import nn

from t2m.config import Config
from t2m.data.dataset import MotionTextData, epoch_batches
from t2m.models.length import LengthEstimator, length_loss
from t2m.train.checkpoint import build_models
from t2m.train.runtime import Runtime, seed_init
from t2m.train.stage import StageRun, load_stage_data, mean_records, to_device

logger = logging.getLogger(__name__)


class LengthObjective(nn.Module):
    """The trainable module: a caption batch -> cross-entropy and accuracy."""

    def __init__(self, estimator: LengthEstimator):
        super().__init__()
        self.estimator = estimator

    def forward(self, batch: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
        logits = self.estimator(batch["words"], batch["pos"], batch["text_lengths"])
        return length_loss(logits, batch["length_class"])


@torch.no_grad()
def validate(
    objective: nn.Module, data: MotionTextData, config: Config, runtime: Runtime
) -> dict[str, float]:
    """Mean loss and accuracy over the validation captions (fixed caption choice)."""
    objective.eval()
    records = []
    chunks = np.array_split(np.arange(len(data)), max(1, len(data) // config.length.batch_size))
    for index, indices in enumerate(chunks):
        batch = to_device(
            data.length_batch(indices, np.random.default_rng([config.seed, index, 99])),
            runtime.device,
        )
        with runtime.autocast():
            records.append(objective(batch))
    objective.train()
    return mean_records(records)


def train_length(
    config: Config,
    dataset_dir: str | Path,
    run_dir: str | Path,
    runtime: Runtime,
    resume: bool = False,
) -> Path:
    """Train stage 2 into ``run_dir/length``; returns that folder."""
    stage = config.length
    # 1. data and vocabulary
    data = load_stage_data(config, dataset_dir)
    vectorizer = data.vectorizer
    dims = {
        "feature_dim": data.train.feature_dim,
        "word_dim": vectorizer.dim,
        "vocab_size": vectorizer.size if vectorizer.trainable else 0,
    }
    # 2. model, optimizer, resume
    seed_init(config.seed)
    models = build_models("length", config, dims)
    estimator = models["length"].to(runtime.device)
    optimizer = torch.optim.Adam(estimator.parameters(), lr=stage.lr)
    run = StageRun("length", config, run_dir, runtime, dims, models, optimizer, data.normalizer,
                   vectorizer.info(), resume)  # fmt: skip
    trainable = runtime.wrap(LengthObjective(estimator))
    trainable.train()
    # 3. the loop
    progress = run.progress
    for epoch in range(progress["epoch"], stage.epochs):
        batches = epoch_batches(
            len(data.train), stage.batch_size, config.seed, epoch, runtime.rank, runtime.world_size
        )
        description = f"length epoch {epoch + 1}/{stage.epochs}"
        for index, rng in run.steps(epoch, len(batches), description, stage.max_steps):
            batch = to_device(data.train.length_batch(batches[index], rng), runtime.device)
            with runtime.autocast():
                losses = trainable(batch)
            run.optimize(
                losses,
                estimator.parameters(),
                stage.grad_clip,
                stage.log_every,
                stage.checkpoint_every,
            )
        if run.close_epoch(len(batches), stage.max_steps):
            break
        metrics = validate(trainable, data.val, config, runtime)
        run.log("val", metrics)
        run.save(best=run.improved(metrics["loss"]))
        logger.info(
            "length epoch %d: val loss %.3f, accuracy %.3f",
            epoch + 1,
            metrics["loss"],
            metrics["accuracy"],
        )
    run.finish()
    return run.dir
