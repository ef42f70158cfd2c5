"""Stage ``generator``: text encoder + temporal VAE, with the autoencoder's decoder fine-tuned.

Curriculum: training starts on crops of ``start_snippets`` snippets (40 frames) and grows by
``curriculum_step`` snippets per curriculum stage up to ``end_snippets`` (196 frames), moving on
when the validation reconstruction has not improved for ``patience`` epochs or after
``max_stage_epochs`` epochs (:class:`Curriculum`); only clips long enough for the current length
are used. Scheduled
sampling: per batch, with probability ``teacher_forcing`` the ground-truth previous codes are fed,
otherwise the model's own (detached) predictions. With ``anneal_epochs`` the learning rates fall
over the last epochs of the last length (:func:`anneal_scale`), so the weights settle.

With ``whole_clips`` (the ``demo`` preset) every training clip takes part at every curriculum
length: one shorter than the length is trained whole, with the caption that describes all of it,
instead of being left out; batches hold clips of similar length (:func:`length_buckets`), each
cropped to its shortest. Without it (the original), a caption such as "jumps three times, then
waves" is mostly trained against crops that show one jump, and the longest lengths see only the
few clips that long.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from torch import nn

from t2m.accel.packed import linear
from t2m.config import Config, GeneratorStageConfig
from t2m.data.dataset import MotionTextData
from t2m.models.autoencoder import CONTACT_DIMS, MovementDecoder, MovementEncoder
from t2m.models.temporal_vae import TemporalVAE, temporal_vae_loss
from t2m.streams import Stream, stream_rng
from t2m.train.job import StageJob
from t2m.train.runtime import adam, seed_init
from t2m.train.stage import LossesOf, StageRun, start_on_autoencoder, to_device, validation_chunks

logger = logging.getLogger(__name__)


class GeneratorObjective(nn.Module):
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
        section = config.generator
        self.weights = {
            "kl_weight": section.kl_weight,
            "code_weight": section.code_weight,
            "feature_weight": section.feature_weight,
        }

    def train(self, mode: bool = True) -> GeneratorObjective:
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
        outputs = self.vae(
            word_features,
            sentence,
            word_mask,
            target_codes,
            self.initial_code,
            teacher_forcing,
            noise,
            counts=batch.get("counts"),
            done=batch.get("done"),
            clause_snippets=batch.get("clause_snippets"),
        )
        decoded = decode(self.decoder, outputs["codes"])
        losses = temporal_vae_loss(outputs, target_codes, decoded, motion, **self.weights)
        losses["reconstruction"] = losses["features"] + losses["codes"]
        return losses


def decode(decoder: MovementDecoder, codes: torch.Tensor) -> torch.Tensor:
    """``decoder(codes)`` (B, S, C) -> (B, 4S, D), its output Linear through
    :func:`t2m.accel.packed.linear` (oneDNN): 1.3-1.4x faster for the fine-tuned
    decoder's forward and backward at demo size on one CPU thread."""
    hidden = decoder.net(codes.transpose(1, 2)).transpose(1, 2)
    return linear(hidden, decoder.out.weight, decoder.out.bias)


@torch.no_grad()
def mean_pose_code(
    encoder: MovementEncoder, feature_dim: int, device: torch.device
) -> torch.Tensor:
    """(C,) code of 4 frames of zero normalised features, i.e. the mean pose."""
    encoder.eval()
    return encoder(torch.zeros(1, 4, feature_dim - CONTACT_DIMS, device=device))[0, 0]


@dataclass
class Curriculum:
    """Where the generator is along its curriculum (stored with the checkpoint's progress)."""

    snippets: int
    """The crop length trained now, in snippets."""
    stage_epochs: int = 0
    """Epochs trained at this length."""
    bad_epochs: int = 0
    """Epochs at this length since the validation value last improved."""
    stage_best: float = math.inf
    """Best validation value at this length."""
    done: bool = False

    def record(self, value: float, section: GeneratorStageConfig) -> bool:
        """Record an epoch's validation value; move to the next length when the stage is over.
        True when ``value`` is the best at the current length."""
        improved = value < self.stage_best
        if improved:
            self.stage_best, self.bad_epochs = value, 0
        else:
            self.bad_epochs += 1
        self.stage_epochs += 1
        last = self.snippets >= section.end_snippets
        limit = section.max_stage_epochs + (section.final_epochs if last else 0)
        if self.bad_epochs >= section.patience or self.stage_epochs >= limit:
            if last:
                self.done = True
            else:
                self.snippets = min(section.end_snippets, self.snippets + section.curriculum_step)
                self.stage_epochs, self.bad_epochs, self.stage_best = 0, 0, math.inf
                logger.info("generator: curriculum moves to %d snippets", self.snippets)
        return improved


def anneal_scale(curriculum: Curriculum, section: GeneratorStageConfig) -> float:
    """The share of the learning rates for the epoch about to train: 1, except over the last
    ``anneal_epochs`` epochs of the last curriculum length (all of its epochs if it has fewer),
    where it falls along a half cosine to ``anneal_to`` at the last one (epoch k of n:
    ``to + (1 - to) * (1 + cos(pi (k + 1) / n)) / 2``)."""
    if not section.anneal_epochs or curriculum.snippets < section.end_snippets:
        return 1.0
    limit = section.max_stage_epochs + section.final_epochs
    epochs = min(section.anneal_epochs, limit)
    index = curriculum.stage_epochs - (limit - epochs)
    if index < 0:
        return 1.0
    fall = 0.5 * (1.0 + math.cos(math.pi * min(index + 1, epochs) / epochs))
    return section.anneal_to + (1.0 - section.anneal_to) * fall


def curriculum_lengths(section: GeneratorStageConfig) -> list[int]:
    """The crop lengths (snippets) the curriculum trains, in order: ``start_snippets`` up by
    ``curriculum_step`` to ``end_snippets``."""
    lengths = [section.start_snippets]
    while lengths[-1] < section.end_snippets:
        lengths.append(min(section.end_snippets, lengths[-1] + section.curriculum_step))
    return lengths


def announce_curriculum(run: StageRun, data: MotionTextData, spec_min_frames: int) -> None:
    """Log the steps the curriculum will take at most (every length its ``max_stage_epochs``,
    the last its ``final_epochs`` more; patience may end a length sooner)."""
    section, unit = run.config.generator, run.spec.snippet_length
    lengths = curriculum_lengths(section)

    def items_at(snippets: int) -> int:
        frames = spec_min_frames if section.whole_clips else snippets * unit
        return len(data.indices_at_least(frames))

    def steps_at(snippets: int) -> int:
        if section.epoch_steps:
            return section.epoch_steps
        return items_at(snippets) // run.runtime.world_size // section.batch_size

    epochs = len(lengths) * section.max_stage_epochs + section.final_epochs
    steps = sum(steps_at(n) for n in lengths) * section.max_stage_epochs
    steps += steps_at(lengths[-1]) * section.final_epochs
    detail = (
        f"{len(lengths)} curriculum lengths of {', '.join(map(str, lengths))} snippets, "
        f"{section.max_stage_epochs} each and {section.final_epochs} more at the last"
    )
    if section.patience < section.max_stage_epochs + section.final_epochs:
        detail += f"; at most: {section.patience} epochs without progress end a length"
    if section.anneal_epochs:
        detail += (
            f"; over the last {section.anneal_epochs} the learning rates fall to "
            f"{section.anneal_to:g} of their value"
        )
    run.announce(epochs, steps, items_at(lengths[0]), detail)


def length_buckets(
    batches: list[np.ndarray], lengths: np.ndarray, rng: np.random.Generator
) -> list[np.ndarray]:
    """The items of ``batches`` re-cut into batches of similar length, in random batch order.

    Items are sorted by ``lengths[item]`` (ties keep the batches' random order) and cut into
    batches of the first batch's size (the same count as given); ``rng`` shuffles the batches.
    """
    if not batches:
        return []
    items = np.concatenate(batches)
    order = items[np.argsort(lengths[items], kind="stable")]
    size = len(batches[0])
    cut = [order[k * size : (k + 1) * size] for k in range(len(batches))]
    return [cut[k] for k in rng.permutation(len(cut))]


def train_generator(job: StageJob) -> Path:
    """Train the generator into its stage folder (needs the autoencoder); returns that folder."""
    # 1. the trained autoencoder (frozen encoder, decoder to fine-tune) and the data
    start = start_on_autoencoder(job)
    job, data, sizes = start.job, start.data, start.sizes
    config, runtime = job.config, job.runtime
    section, unit = config.generator, data.spec.snippet_length
    autoencoder = start.autoencoder.models["autoencoder"]
    # 2. models, optimizer (decoder at its own rate), resume
    seed_init(config.seed)
    models = job.stage.build(config, sizes)
    vae = models["vae"].to(runtime.device)
    decoder = models["decoder"].to(runtime.device)
    decoder.load_state_dict(autoencoder.decoder.state_dict())
    initial_code = mean_pose_code(autoencoder.encoder, sizes.feature_dim, runtime.device)
    objective = GeneratorObjective(vae, autoencoder.encoder, decoder, initial_code, config)
    optimizer = adam(
        [
            {"params": vae.parameters(), "lr": section.lr},
            {"params": decoder.parameters(), "lr": section.decoder_lr},
        ]
    )
    run = StageRun(
        job,
        sizes,
        models,
        optimizer,
        data.normalizer,
        data.vocabulary,
        extra={
            "initial_code": initial_code.cpu(),
            # the words the model sees (prompts are checked against them): a list of str
            "training_words": data.vectorizer.words_of_rows(
                rows for rows, _, _ in data.train.tokens
            ),
        },
        counters=Curriculum(section.start_snippets),
    )
    curriculum: Curriculum = run.counters
    trainable = runtime.wrap(objective)
    trainable.train()
    trainable_parameters = [p for p in objective.parameters() if p.requires_grad]

    def losses_on(split: MotionTextData, snippets: int, teacher: bool) -> LossesOf:
        """Losses of crops of ``snippets``; with ``teacher``, ground-truth codes fed back with
        probability ``teacher_forcing`` per batch, else free-running with noise drawn from the
        batch's generator (validation: the same noise every epoch)."""

        def losses_of(items: np.ndarray, rng: np.random.Generator) -> dict[str, torch.Tensor]:
            # crops of `snippets`, or of the batch's shortest clip when that is shorter
            steps = min(snippets, int(split.lengths[items].min()) // unit)
            batch = to_device(split.fixed_crop_batch(items, rng, steps * unit), runtime.device)
            if teacher:
                return trainable(batch, bool(rng.random() < section.teacher_forcing))
            shape = (len(items), steps, section.model.latent_size)
            noise = torch.from_numpy(rng.standard_normal(shape, dtype=np.float32))
            return trainable(batch, False, noise.to(runtime.device))

        return losses_of

    announce_curriculum(run, data.train, data.spec.min_frames)
    # 3. the loop: epochs at the current curriculum length
    while not curriculum.done and not run.reached_max_steps():
        snippets = curriculum.snippets
        frames = snippets * unit
        if section.whole_clips:  # every clip; the shorter ones whole
            items = data.train.indices_at_least(data.spec.min_frames)
        else:
            items = data.train.indices_at_least(frames)
        batches = [items[b] for b in run.epoch_batches(len(items))]
        if section.whole_clips:
            crops = np.minimum(data.train.lengths, frames) // unit
            rng = stream_rng(Stream.EPOCH_ORDER, config.seed, run.progress.epoch, 1)
            batches = length_buckets(batches, crops, rng)
        if not batches:
            logger.warning(
                "generator: fewer than %d training clips of %d frames; curriculum ends",
                section.batch_size,
                frames,
            )
            curriculum.done = True
            break
        # the learning rates of this epoch (set each epoch, so a resume sets them too)
        scale = anneal_scale(curriculum, section)
        for group, rate in zip(
            optimizer.param_groups, (section.lr, section.decoder_lr), strict=True
        ):
            group["lr"] = rate * scale
        description = f"generator epoch {run.progress.epoch + 1} ({frames} frames)"
        if not run.train_epoch(
            batches,
            description,
            losses_on(data.train, snippets, True),
            trainable_parameters,
            log_extra={"snippets": snippets, "lr_scale": scale},
        ):
            break
        # 4. end of epoch: validate on the clips long enough, then move along the curriculum;
        # best.pt = the best model at the longest length reached so far
        if section.whole_clips:  # every clip, in chunks of similar length
            val_items = data.val.indices_at_least(data.spec.min_frames)
            val_items = val_items[np.argsort(data.val.lengths[val_items], kind="stable")]
        else:
            val_items = data.val.indices_at_least(frames)
        val_chunks = validation_chunks(val_items, section.batch_size)
        metrics = run.validate(trainable, val_chunks, losses_on(data.val, snippets, False))
        value = runtime.broadcast_float(metrics.get("reconstruction", math.inf))
        improved = curriculum.record(value, section)
        run.end_epoch({**metrics, "snippets": snippets}, improved)
    return run.finish()
