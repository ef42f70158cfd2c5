"""Stage 3: text encoder + temporal VAE, with the autoencoder's decoder fine-tuned.

Curriculum: training starts on crops of ``start_snippets`` snippets (40 frames) and grows by
``curriculum_step`` snippets per curriculum stage up to ``end_snippets`` (196 frames), moving on
when the validation reconstruction has not improved for ``patience`` epochs or after
``max_stage_epochs`` epochs; only clips long enough for the current length are used. Scheduled
sampling: per batch, with probability ``teacher_forcing`` the ground-truth previous codes are fed,
otherwise the model's own (detached) predictions.
"""

from __future__ import annotations

import logging
import math
from pathlib import Path

import numpy as np
import torch
from torch import nn

from t2m.config import Config
from t2m.data.dataset import MotionTextData, epoch_batches
from t2m.models.autoencoder import CONTACT_DIMS, MovementDecoder, MovementEncoder
from t2m.models.temporal_vae import TemporalVAE, temporal_vae_loss
from t2m.train.checkpoint import build_models
from t2m.train.runtime import Runtime, seed_init
from t2m.train.stage import (
    StageRun,
    mean_records,
    start_on_autoencoder,
    to_device,
)

logger = logging.getLogger(__name__)


class TextToMotionObjective(nn.Module):
    """The trainable module: captions + motion crops -> the temporal-VAE loss parts.

    The movement encoder is frozen (it defines the target codes); the decoder is fine-tuned.
    """

    def __init__(
        self,
        vae: TemporalVAE,
        encoder: MovementEncoder,
        decoder: MovementDecoder,
        initial_code: torch.Tensor,
        config: Config,
    ):
        super().__init__()
        self.vae = vae
        self.encoder = encoder.requires_grad_(False)
        self.decoder = decoder
        self.register_buffer("initial_code", initial_code)
        stage = config.t2m
        self.weights = {"kl_weight": stage.kl_weight, "code_weight": stage.code_weight,
                        "feature_weight": stage.feature_weight}  # fmt: skip

    def train(self, mode: bool = True) -> TextToMotionObjective:
        super().train(mode)
        self.encoder.eval()
        return self

    def forward(
        self,
        batch: dict[str, torch.Tensor],
        teacher_forcing: bool,
        noise: torch.Tensor | None = None,
    ) -> dict[str, torch.Tensor]:
        motion = batch["motion"]  # (B, 4S, D) normalised
        with torch.no_grad():
            target_codes = self.encoder(motion[..., :-CONTACT_DIMS])  # (B, S, C)
        word_features, sentence, word_mask = self.vae.encode_text(
            batch["words"], batch["pos"], batch["text_lengths"]
        )
        outputs = self.vae(word_features, sentence, word_mask, target_codes, self.initial_code,
                           teacher_forcing, noise)  # fmt: skip
        decoded = self.decoder(outputs["codes"])
        losses = temporal_vae_loss(outputs, target_codes, decoded, motion, **self.weights)
        losses["reconstruction"] = losses["features"] + losses["codes"]
        return losses


@torch.no_grad()
def mean_pose_code(
    encoder: MovementEncoder, feature_dim: int, device: torch.device
) -> torch.Tensor:
    """(C,) code of 4 frames of zero normalised features, i.e. the mean pose."""
    encoder.eval()
    return encoder(torch.zeros(1, 4, feature_dim - CONTACT_DIMS, device=device))[0, 0]


@torch.no_grad()
def validate(
    objective: nn.Module, data: MotionTextData, config: Config, runtime: Runtime, snippets: int
) -> dict[str, float]:
    """Free-running losses on fixed crops of the validation clips long enough for ``snippets``."""
    frames = snippets * config.data.unit_length
    indices = data.indices_at_least(frames)
    if len(indices) == 0:
        return {}
    objective.eval()
    records = []
    batch_size = config.t2m.batch_size
    for index, chunk in enumerate(np.array_split(indices, max(1, len(indices) // batch_size))):
        rng = np.random.default_rng([config.seed, index, 99])
        batch = to_device(data.fixed_crop_batch(chunk, rng, frames), runtime.device)
        generator = torch.Generator().manual_seed(config.seed * 7919 + index)
        noise = torch.randn(len(chunk), snippets, config.t2m.model.latent_size, generator=generator)
        with runtime.autocast():
            records.append(objective(batch, False, noise.to(runtime.device)))
    objective.train()
    return mean_records(records)


def train_text_to_motion(
    config: Config,
    dataset_dir: str | Path,
    run_dir: str | Path,
    runtime: Runtime,
    resume: bool = False,
) -> Path:
    """Train stage 3 into ``run_dir/t2m`` (needs ``run_dir/ae``); returns that folder."""
    unit = config.data.unit_length
    # 1. the trained autoencoder (frozen encoder, decoder to fine-tune) and the data
    start = start_on_autoencoder(config, dataset_dir, Path(run_dir), runtime.device)
    ae, config, data, dims = start.ae, start.config, start.data, start.dims
    vectorizer = data.vectorizer
    stage = config.t2m
    autoencoder = ae.models["autoencoder"]
    # 2. models, optimizer (decoder at its own rate), resume
    seed_init(config.seed)
    models = build_models("t2m", config, dims)
    vae = models["vae"].to(runtime.device)
    decoder = models["decoder"].to(runtime.device)
    decoder.load_state_dict(autoencoder.decoder.state_dict())
    initial_code = mean_pose_code(autoencoder.encoder, dims["feature_dim"], runtime.device)
    objective = TextToMotionObjective(vae, autoencoder.encoder, decoder, initial_code, config)
    optimizer = torch.optim.Adam([
        {"params": vae.parameters(), "lr": stage.lr},
        {"params": decoder.parameters(), "lr": stage.decoder_lr},
    ])  # fmt: skip
    run = StageRun("t2m", config, run_dir, runtime, dims, models, optimizer, data.normalizer,
                   vectorizer.info(), resume, extra={"initial_code": initial_code.cpu()})  # fmt: skip
    progress = run.progress
    progress.setdefault("snippets", stage.start_snippets)
    progress.setdefault("stage_epochs", 0)
    progress.setdefault("bad_epochs", 0)
    progress.setdefault("stage_best", math.inf)
    progress.setdefault("done", False)
    trainable = runtime.wrap(objective)
    trainable.train()
    trainable_parameters = [p for p in objective.parameters() if p.requires_grad]
    # 3. the loop: epochs at the current curriculum length
    while not progress["done"] and not run.reached_max_steps(stage.max_steps):
        epoch, snippets = progress["epoch"], progress["snippets"]
        frames = snippets * unit
        items = data.train.indices_at_least(frames)
        batches = [items[b] for b in epoch_batches(len(items), stage.batch_size, config.seed, epoch,
                                                     runtime.rank, runtime.world_size)]  # fmt: skip
        if not batches:
            logger.warning(
                "t2m: fewer than %d training clips of %d frames; curriculum ends",
                stage.batch_size,
                frames,
            )
            progress["done"] = True
            break
        description = f"t2m epoch {epoch + 1} ({frames} frames)"
        for index, rng in run.steps(epoch, len(batches), description, stage.max_steps):
            batch = to_device(
                data.train.fixed_crop_batch(batches[index], rng, frames), runtime.device
            )
            teacher_forcing = bool(rng.random() < stage.teacher_forcing)
            with runtime.autocast():
                losses = trainable(batch, teacher_forcing)
            run.optimize(
                losses,
                trainable_parameters,
                stage.grad_clip,
                stage.log_every,
                stage.checkpoint_every,
                extra={"snippets": snippets},
            )
        if run.close_epoch(len(batches), stage.max_steps):
            break
        # 4. end of epoch: validate, then move along the curriculum
        metrics = validate(trainable, data.val, config, runtime, snippets)
        value = runtime.broadcast_float(metrics.get("reconstruction", math.inf))
        improved = value < progress["stage_best"]
        if improved:
            progress["stage_best"], progress["bad_epochs"] = value, 0
        else:
            progress["bad_epochs"] += 1
        progress["stage_epochs"] += 1
        run.log("val", {**metrics, "snippets": snippets})
        limit = stage.max_stage_epochs + (
            stage.final_epochs if snippets >= stage.end_snippets else 0
        )
        if progress["bad_epochs"] >= stage.patience or progress["stage_epochs"] >= limit:
            if snippets >= stage.end_snippets:
                progress["done"] = True
            else:
                progress["snippets"] = min(stage.end_snippets, snippets + stage.curriculum_step)
                progress["stage_epochs"], progress["bad_epochs"] = 0, 0
                progress["stage_best"] = math.inf
                logger.info("t2m: curriculum moves to %d snippets", progress["snippets"])
        # best = the best model at the longest length reached so far
        run.save(best=improved)
        logger.info(
            "t2m epoch %d (%d snippets): val reconstruction %.4f", epoch + 1, snippets, value
        )
    run.finish()
    return run.dir
