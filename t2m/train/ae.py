"""Stage 1: the movement autoencoder, trained on random windows of normalised features."""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import torch
from torch import nn

from t2m.config import Config
from t2m.data.dataset import MotionTextData, epoch_batches
from t2m.models.autoencoder import MovementAutoencoder, autoencoder_loss
from t2m.train.checkpoint import build_models
from t2m.train.runtime import Runtime, seed_init
from t2m.train.stage import StageRun, load_stage_data, mean_records

logger = logging.getLogger(__name__)


class AutoencoderObjective(nn.Module):
    """The trainable module: a batch of windows -> the loss parts (what DDP wraps)."""

    def __init__(
        self,
        autoencoder: MovementAutoencoder,
        sparsity_weight: float,
        smoothness_weight: float,
        reconstruction_loss: str = "l1",
    ):
        super().__init__()
        self.autoencoder = autoencoder
        self.sparsity_weight = sparsity_weight
        self.smoothness_weight = smoothness_weight
        self.reconstruction_loss = reconstruction_loss

    def forward(self, motion: torch.Tensor) -> dict[str, torch.Tensor]:
        reconstruction, codes = self.autoencoder(motion)
        return autoencoder_loss(reconstruction, motion, codes, self.sparsity_weight,
                                self.smoothness_weight, self.reconstruction_loss)  # fmt: skip


@torch.no_grad()
def validate(
    objective: nn.Module, data: MotionTextData, config: Config, runtime: Runtime
) -> dict[str, float]:
    """Mean losses on fixed windows of the validation clips (same windows every time)."""
    stage = config.ae
    objective.eval()
    records = []
    for index, batch_indices in enumerate(
        np.array_split(np.arange(len(data)), max(1, len(data) // stage.batch_size))
    ):
        batch = data.window_batch(
            batch_indices, np.random.default_rng([config.seed, index, 99]), stage.window_frames
        )
        with runtime.autocast():
            records.append(objective(batch["motion"].to(runtime.device)))
    objective.train()
    return mean_records(records)


def train_autoencoder(
    config: Config,
    dataset_dir: str | Path,
    run_dir: str | Path,
    runtime: Runtime,
    resume: bool = False,
) -> Path:
    """Train stage 1 into ``run_dir/ae``; returns that folder."""
    stage = config.ae
    # 1. data: windows must fit in every clip, which load_split's min_frames guarantees
    data = load_stage_data(config, dataset_dir)
    dims = {"feature_dim": data.train.feature_dim}
    # 2. model, optimizer, resume
    seed_init(config.seed)
    models = build_models("ae", config, dims)
    autoencoder = models["autoencoder"].to(runtime.device)
    objective = AutoencoderObjective(autoencoder, stage.sparsity_weight, stage.smoothness_weight,
                                     stage.reconstruction_loss)  # fmt: skip
    optimizer = torch.optim.Adam(autoencoder.parameters(), lr=stage.lr)
    run = StageRun(
        "ae", config, run_dir, runtime, dims, models, optimizer, data.normalizer, None, resume
    )
    trainable = runtime.wrap(objective)
    trainable.train()
    # 3. the loop
    progress = run.progress
    for epoch in range(progress["epoch"], stage.epochs):
        batches = epoch_batches(
            len(data.train), stage.batch_size, config.seed, epoch, runtime.rank, runtime.world_size
        )
        description = f"ae epoch {epoch + 1}/{stage.epochs}"
        for index, rng in run.steps(epoch, len(batches), description, stage.max_steps):
            motion = data.train.window_batch(batches[index], rng, stage.window_frames)["motion"].to(
                runtime.device
            )
            with runtime.autocast():
                losses = trainable(motion)
            run.optimize(
                losses,
                autoencoder.parameters(),
                stage.grad_clip,
                stage.log_every,
                stage.checkpoint_every,
            )
        if run.close_epoch(len(batches), stage.max_steps):
            break
        metrics = validate(trainable, data.val, config, runtime)
        run.log("val", metrics)
        run.save(best=run.improved(metrics["loss"]))
        logger.info("ae epoch %d: val reconstruction %.4f", epoch + 1, metrics["reconstruction"])
    run.finish()
    return run.dir
