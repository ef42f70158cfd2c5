"""Stage 4: the contrastive text / motion evaluator on the frozen autoencoder's codes."""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import torch
from torch import nn

from t2m.config import Config
from t2m.data.dataset import MotionTextData, epoch_batches
from t2m.models.evaluator import Evaluator, contrastive_loss
from t2m.train.checkpoint import build_models
from t2m.train.runtime import Runtime, seed_init
from t2m.train.stage import (
    StageRun,
    mean_records,
    start_on_autoencoder,
    to_device,
)

logger = logging.getLogger(__name__)


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


@torch.no_grad()
def validate(
    objective: nn.Module, data: MotionTextData, config: Config, runtime: Runtime
) -> dict[str, float]:
    """Mean losses and in-batch R@1 over fixed validation batches."""
    objective.eval()
    records = []
    batch_size = config.eval.batch_size
    for index in range(max(1, len(data) // batch_size)):
        indices = np.arange(index * batch_size, min(len(data), (index + 1) * batch_size))
        if len(indices) < 2:
            break
        rng = np.random.default_rng([config.seed, index, 99])
        batch = to_device(data.unit_crop_batch(indices, rng), runtime.device)
        with runtime.autocast():
            records.append(objective(batch, draw_shift(rng, len(indices))))
    objective.train()
    return mean_records(records)


def train_evaluator(
    config: Config,
    dataset_dir: str | Path,
    run_dir: str | Path,
    runtime: Runtime,
    resume: bool = False,
) -> Path:
    """Train stage 4 into ``run_dir/eval`` (needs ``run_dir/ae``); returns that folder."""
    # 1. the frozen autoencoder and its statistics, then the data
    start = start_on_autoencoder(config, dataset_dir, Path(run_dir), runtime.device)
    ae, config, data, dims = start.ae, start.config, start.data, start.dims
    vectorizer = data.vectorizer
    stage = config.eval
    # 2. model (frozen encoder copied in), optimizer, resume
    seed_init(config.seed)
    models = build_models("eval", config, dims)
    evaluator = models["evaluator"].to(runtime.device)
    evaluator.movement_encoder.load_state_dict(ae.models["autoencoder"].encoder.state_dict())
    optimizer = torch.optim.Adam(
        [p for p in evaluator.parameters() if p.requires_grad], lr=stage.lr
    )
    run = StageRun("eval", config, run_dir, runtime, dims, models, optimizer, data.normalizer,
                   vectorizer.info(), resume)  # fmt: skip
    trainable = runtime.wrap(EvaluatorObjective(evaluator, stage.margin, stage.negative_weight))
    trainable.train()
    # 3. the loop
    progress = run.progress
    for epoch in range(progress["epoch"], stage.epochs):
        batches = epoch_batches(
            len(data.train), stage.batch_size, config.seed, epoch, runtime.rank, runtime.world_size
        )
        description = f"eval epoch {epoch + 1}/{stage.epochs}"
        for index, rng in run.steps(epoch, len(batches), description, stage.max_steps):
            batch = to_device(data.train.unit_crop_batch(batches[index], rng), runtime.device)
            with runtime.autocast():
                losses = trainable(batch, draw_shift(rng, len(batches[index])))
            run.optimize(
                losses,
                [p for p in evaluator.parameters() if p.requires_grad],
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
            "eval epoch %d: val loss %.3f, in-batch R@1 %.3f",
            epoch + 1,
            metrics["loss"],
            metrics["top1"],
        )
    run.finish()
    return run.dir
