"""Stage ``autoencoder``: the movement autoencoder, trained on random windows of normalised features."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
from torch import nn

from t2m.data.dataset import MotionTextData
from t2m.models.autoencoder import MovementAutoencoder, autoencoder_loss
from t2m.train.checkpoint import ModelSizes
from t2m.train.job import StageJob
from t2m.train.runtime import adam, seed_init
from t2m.train.stage import LossesOf, StageRun, check_batches, load_stage_data, validation_chunks


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
        return autoencoder_loss(
            reconstruction,
            motion,
            codes,
            self.sparsity_weight,
            self.smoothness_weight,
            self.reconstruction_loss,
        )


def train_autoencoder(job: StageJob) -> Path:
    """Train the autoencoder into its stage folder; returns that folder."""
    config, runtime = job.config, job.runtime
    section = config.autoencoder
    # 1. data: windows must fit in every clip, which load_split's min_frames guarantees
    data = load_stage_data(config, job.dataset_dir)
    check_batches(job, data)
    sizes = ModelSizes(feature_dim=data.train.feature_dim)
    # 2. model, optimizer, resume
    seed_init(config.seed)
    models = job.stage.build(config, sizes)
    autoencoder = models["autoencoder"].to(runtime.device)
    objective = AutoencoderObjective(
        autoencoder, section.sparsity_weight, section.smoothness_weight, section.reconstruction_loss
    )
    optimizer = adam(autoencoder.parameters(), lr=section.lr)
    run = StageRun(job, sizes, models, optimizer, data.normalizer, vocabulary=None)
    trainable = runtime.wrap(objective)
    trainable.train()

    # 3. the loop: one random window per clip and epoch; validation on fixed windows
    def losses_on(split: MotionTextData) -> LossesOf:
        def losses_of(items: np.ndarray, rng: np.random.Generator) -> dict[str, torch.Tensor]:
            motion = split.window_batch(items, rng, section.window_frames)["motion"]  # (B, W, D)
            return trainable(motion.to(runtime.device))

        return losses_of

    val_chunks = validation_chunks(np.arange(len(data.val)), section.batch_size)
    run.train_epochs(
        len(data.train),
        losses_on(data.train),
        list(autoencoder.parameters()),
        validate=lambda: run.validate(trainable, val_chunks, losses_on(data.val)),
    )
    return run.finish()
