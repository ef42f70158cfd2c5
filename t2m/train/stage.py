"""What every stage loop shares: its data, and :class:`StageRun`, the loop skeleton.

A stage loop (``t2m/train/autoencoder.py`` ...) is given a :class:`~t2m.train.job.StageJob`,
reads its data, builds its models and optimizer, then opens a :class:`StageRun`, which restores
them from ``latest.pt`` on resume (after refusing a checkpoint of another stage, size or
vocabulary), writes ``config.json``, and runs the epochs: :meth:`StageRun.train_epoch` (seeded
batches, optimiser steps, records, periodic ``latest.pt``), :meth:`StageRun.validate` (fixed
validation batches) and :meth:`StageRun.end_epoch` (record, ``best.pt``).
:meth:`StageRun.train_epochs` is the whole loop of a stage trained for a number of epochs.
"""

from __future__ import annotations

import dataclasses
import logging
import math
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn
from tqdm import tqdm

from dataset_tools.command import UsageError
from dataset_tools.io import write_json_atomic
from dataset_tools.spec import DatasetSpec, spec_for_dim, spec_for_folder
from t2m.config import Config, StageConfig, from_dict, validate_for_spec
from t2m.data.dataset import MotionTextData, epoch_batches, load_split
from t2m.data.normalization import Normalizer
from t2m.data.words import (
    TRAINABLE,
    WordVectors,
    build_trainable_vocabulary,
    checkpoint_vocabulary,
    load_vectorizer,
)
from t2m.models.autoencoder import check_snippet_length
from t2m.streams import Stream, stream_rng
from t2m.train.checkpoint import (
    ModelSizes,
    TrainedStage,
    atomic_save,
    check_compatible,
    content_error,
    make_checkpoint,
    read_checkpoint,
    write_config,
)
from t2m.train.job import StageJob
from t2m.train.logbook import Logbook
from t2m.train.runtime import clip_gradients, seed_step, unwrap

logger = logging.getLogger(__name__)

# Written into the stage folder when its loop ends normally.
FINISHED = "finished.json"

# A stage's step: (batch item indices, the batch's random generator) -> named losses, "loss"
# the one optimised.
LossesOf = Callable[[np.ndarray, np.random.Generator], dict[str, torch.Tensor]]


@dataclass
class StageData:
    """Train and validation data of one stage, and the spec of their dataset."""

    train: MotionTextData
    val: MotionTextData
    vectorizer: WordVectors
    normalizer: Normalizer
    spec: DatasetSpec
    vocabulary: dict[str, Any] = field(default_factory=dict)
    """What the stage's checkpoints store of the vocabulary (:func:`checkpoint_vocabulary`:
    the words of the dataset's captions and the configured margin, with their vectors)."""

    def sizes(self, code_size: int = 0) -> ModelSizes:
        """The model sizes these data give (``code_size``: of the autoencoder built upon)."""
        vectorizer = self.vectorizer
        return ModelSizes(
            feature_dim=self.train.feature_dim,
            word_dim=vectorizer.dim,
            vocab_size=vectorizer.size if vectorizer.trainable else 0,
            code_size=code_size,
        )


def vocabulary_for(config: Config, dataset_dir: Path) -> WordVectors:
    """The configured word vectors, or a trainable vocabulary of the training captions."""
    data = config.data
    if data.word_vectors == TRAINABLE:
        clips = load_split(dataset_dir, "train")
        return build_trainable_vocabulary(
            (c.tokens for clip in clips for c in clip.captions),
            data.trainable_word_dim,
            data.max_text_tokens,
        )
    return load_vectorizer(data.word_vectors, data.max_text_tokens, data.motion_words)


def load_stage_data(
    config: Config, dataset_dir: str | Path, normalizer: Normalizer | None = None
) -> StageData:
    """Train/val splits of a HumanML3D-layout folder, normalised, with their vocabulary.

    ``normalizer`` defaults to the dataset's Mean/Std with the root/contact weighting.
    The dataset's spec (from its ``Mean.npy``) decides the frame limits; the config is checked
    against it. The validation split falls back to ``test`` when ``val.txt`` is missing or empty
    of clips. What is wrong with the folder (missing, no Mean/Std, no usable clip, features of
    another size than the statistics, a config that does not fit the dataset) is a one-line
    :class:`UsageError`.
    """
    dataset_dir = Path(dataset_dir)
    if not dataset_dir.is_dir():
        raise UsageError(f"dataset folder {dataset_dir} does not exist (run `make dataset` first)")
    try:
        spec = spec_for_folder(dataset_dir)
        check_snippet_length(spec.snippet_length)
        validate_for_spec(config, spec)
        if normalizer is None:
            normalizer = Normalizer.from_dataset(dataset_dir, config.data.feature_bias)
        vectorizer = vocabulary_for(config, dataset_dir)
        train_clips = load_split(dataset_dir, "train", spec=spec)
        try:
            val_clips = load_split(dataset_dir, "val", spec=spec)
        except ValueError:
            logger.warning("%s: no usable val split, validating on test", dataset_dir)
            val_clips = load_split(dataset_dir, "test", spec=spec)
        train = MotionTextData(train_clips, normalizer, vectorizer, spec)
        val = MotionTextData(val_clips, normalizer, vectorizer, spec)
    except ValueError as error:  # the folder's content, or the configured word vectors
        raise UsageError(str(error)) from None
    vocabulary = checkpoint_vocabulary(vectorizer, dataset_dir, config.data.vocabulary_margin)
    return StageData(train, val, vectorizer, normalizer, spec, vocabulary)


@dataclass
class OnAutoencoder:
    """What the stages trained on top of the autoencoder (generator, evaluator) start from."""

    job: StageJob
    """The job, its config adopting the trained autoencoder's model settings."""
    autoencoder: TrainedStage
    data: StageData
    sizes: ModelSizes


def start_on_autoencoder(job: StageJob) -> OnAutoencoder:
    """Adopt the trained autoencoder's model config (on a copy: the caller's config stays), read
    the data with its statistics, and derive the model sizes; refuse a dataset whose feature
    dimension differs from the autoencoder's."""
    autoencoder = job.prerequisites["autoencoder"]
    config = from_dict(job.config.to_dict())
    config.autoencoder.model = autoencoder.config.autoencoder.model
    data = load_stage_data(config, job.dataset_dir, normalizer=autoencoder.normalizer)
    sizes = data.sizes(code_size=config.autoencoder.model.code_size)
    if autoencoder.dims.feature_dim != sizes.feature_dim:
        raise UsageError(
            f"the autoencoder was trained on {autoencoder.dims.feature_dim}-d features, "
            f"the dataset has {sizes.feature_dim}"
        )
    if job.stage.name == "generator":  # its curriculum starts on crops of start_snippets
        check_batches(job, data, frames=config.generator.start_snippets * data.spec.snippet_length)
    else:  # the evaluator's negatives pair each validation item with another
        check_batches(job, data, val_items=2)
    return OnAutoencoder(dataclasses.replace(job, config=config), autoencoder, data, sizes)


@dataclass
class Progress:
    """Where a stage is: stored in every checkpoint, so a resume continues mid-epoch."""

    epoch: int = 0
    epoch_step: int = 0
    """Batches of the current epoch already trained."""
    step: int = 0
    """Optimiser steps in total."""
    best: float = math.inf
    """Best validation value so far (what ``best.pt`` holds)."""


class StageRun:
    """Resume, the epoch skeleton, checkpoints and records of one stage in its folder.

    Args:
        job: the stage, config, folders, runtime and resume flag.
        sizes: sizes from the data (stored; checked on resume). The dataset spec stored with
            them is the one of their feature dimension.
        models: name -> module (unwrapped) saved in the checkpoint.
        optimizer: saved and restored with them.
        normalizer, vocabulary: stored for later stages and sampling.
        extra: stage extras stored in the checkpoint.
        counters: the stage's own progress counters (a dataclass, e.g. the generator's
            curriculum), stored with the progress and restored on resume.
    """

    def __init__(
        self,
        job: StageJob,
        sizes: ModelSizes,
        models: dict[str, nn.Module],
        optimizer: torch.optim.Optimizer,
        normalizer: Normalizer,
        vocabulary: dict[str, Any] | None,
        extra: dict[str, Any] | None = None,
        counters: Any = None,
    ):
        self.name = job.stage.name
        self.config = job.config
        self.section: StageConfig = getattr(job.config, self.name)
        self.dir = job.stage.folder(job.run_dir)
        self.runtime = runtime = job.runtime
        self.sizes = sizes
        self.spec = spec_for_dim(sizes.feature_dim)
        self.models = models
        self.optimizer = optimizer
        self.normalizer = normalizer
        self.vocabulary = vocabulary
        self.extra = dict(extra or {})
        self.progress = Progress()
        self.counters = counters
        latest = self.dir / "latest.pt"
        if job.resume:
            checkpoint = read_checkpoint(latest)  # never runs code from the file
            names = (self.name, *job.stage.old_names)
            try:
                check_compatible(checkpoint, names, self.config, sizes, vocabulary, str(latest))
                for name, module in models.items():
                    module.load_state_dict(checkpoint["models"][name])
                optimizer.load_state_dict(checkpoint["optimizer"])
                self._restore(checkpoint["progress"])
            except UsageError:
                raise
            except (ValueError, TypeError, KeyError, RuntimeError) as error:
                raise content_error(latest, "cannot resume from it", error) from None
            logger.info(
                "%s: resumed at step %d (epoch %d)", self.name, self.step, self.progress.epoch
            )
        elif latest.is_file() and runtime.is_main:
            logger.warning("%s: starting afresh over the existing run in %s", self.name, self.dir)
        if runtime.is_main:
            self.dir.mkdir(parents=True, exist_ok=True)
            (self.dir / FINISHED).unlink(missing_ok=True)
            write_config(self.dir, self.config)
        self.logbook = Logbook(
            self.dir,
            self.name,
            enabled=runtime.is_main,
            resume_step=self.step if job.resume else None,
            resume_epoch=self.progress.epoch,
        )

    def _stored_progress(self) -> dict[str, Any]:
        counters = dataclasses.asdict(self.counters) if self.counters is not None else {}
        return {**dataclasses.asdict(self.progress), **counters}

    def _restore(self, stored: dict[str, Any]) -> None:
        def known(record: Any) -> dict[str, Any]:
            return {f.name: stored[f.name] for f in dataclasses.fields(record) if f.name in stored}

        self.progress = dataclasses.replace(self.progress, **known(self.progress))
        if self.counters is not None:
            self.counters = dataclasses.replace(self.counters, **known(self.counters))

    @property
    def step(self) -> int:
        return self.progress.step

    def reached_max_steps(self) -> bool:
        return 0 < self.section.max_steps <= self.step

    def save(self, best: bool = False) -> None:
        """Write latest.pt (and best.pt) from the main process; every process waits for it."""
        if self.runtime.is_main:
            checkpoint = make_checkpoint(
                self.name,
                self.config,
                self.sizes,
                self.spec,
                {name: unwrap(module) for name, module in self.models.items()},
                self.optimizer,
                self._stored_progress(),
                self.normalizer,
                self.vocabulary,
                self.extra,
            )
            atomic_save(checkpoint, self.dir / "latest.pt")
            if best:
                atomic_save(checkpoint, self.dir / "best.pt")
        self.runtime.barrier()

    # -- the epoch skeleton -------------------------------------------------------------------

    def epoch_batches(self, num_items: int) -> list[np.ndarray]:
        """This process's shuffled batches of the current epoch (indices into ``num_items``):
        :func:`step_sized_batches` with the section's ``epoch_steps``."""
        runtime, section = self.runtime, self.section
        return step_sized_batches(
            num_items,
            section.batch_size,
            self.config.seed,
            self.progress.epoch,
            section.epoch_steps,
            runtime.rank,
            runtime.world_size,
        )

    def announce(self, epochs: int, steps: int, num_items: int, detail: str = "") -> int:
        """Log how many optimiser steps the stage will take (``steps`` over ``epochs``, capped by
        ``max_steps``; ``detail`` says more of the epochs) and how often that passes over its
        ``num_items`` training items; warn when they are under a quarter of the split the preset
        was sized on (``Config.sized_for_clips``). Returns the steps."""
        section, name = self.section, self.name
        if section.max_steps:
            steps = min(steps, section.max_steps)
        batch = section.batch_size * self.runtime.world_size
        passes = steps * batch / max(num_items, 1)
        per_epoch = (
            f"{section.epoch_steps} steps an epoch" if section.epoch_steps else "one pass an epoch"
        )
        logger.info(
            "%s will take %d optimiser steps: %d epochs%s, %s, batches of %d from %d training "
            "items (%.1f passes over them)",
            name,
            steps,
            epochs,
            f" ({detail})" if detail else "",
            per_epoch,
            batch,
            num_items,
            passes,
        )
        sized_for = self.config.sized_for_clips
        if sized_for and num_items * 4 < sized_for:
            logger.warning(
                "%s: %d training items are under a quarter of the %d the %s preset was sized "
                "on: each is seen %.1f times (%.1f there), and models of this size may learn "
                "them by heart; check that the validation loss still falls at the end (%s)",
                name,
                num_items,
                sized_for,
                self.config.preset,
                passes,
                steps * batch / sized_for,
                self.dir / "curves.png",
            )
        return steps

    def train_epoch(
        self,
        batches: list[np.ndarray],
        description: str,
        losses_of: LossesOf,
        parameters: list[nn.Parameter],
        log_extra: dict[str, Any] | None = None,
    ) -> bool:
        """Train the batches of the current epoch still to run (all of them, or the rest of an
        interrupted epoch); True when the epoch completed (the counters move to the next one),
        False when ``max_steps`` cut it short (latest.pt is saved so a resume continues here).

        Each batch: torch seeded from its coordinates (dropout, latent noise), its generator of
        the BATCH stream, ``losses_of`` under autocast, one optimiser step on ``losses["loss"]``,
        a record every ``log_every`` steps and ``latest.pt`` every ``checkpoint_every``.
        """
        section, runtime, progress = self.section, self.runtime, self.progress
        runtime.before_epoch()
        seed, epoch = self.config.seed, progress.epoch
        bar = tqdm(
            total=len(batches),
            initial=progress.epoch_step,
            desc=description,
            disable=not runtime.is_main,
            leave=False,
        )
        for index in range(progress.epoch_step, len(batches)):
            if self.reached_max_steps():
                break
            seed_step(seed, epoch, index, runtime.rank)
            rng = stream_rng(Stream.BATCH, seed, epoch, index, runtime.rank)
            with runtime.autocast():
                losses = losses_of(batches[index], rng)
            self.optimizer.zero_grad(set_to_none=True)
            losses["loss"].backward()
            clip_gradients(parameters, section.grad_clip)
            self.optimizer.step()
            progress.step += 1
            progress.epoch_step += 1
            bar.update()
            if self.step % section.log_every == 0:
                self.log("train", {**losses, **(log_extra or {})})
                bar.set_postfix(loss=f"{float(losses['loss'].detach()):.4g}")
            if self.step % section.checkpoint_every == 0:
                self.save()
        bar.close()
        if self.reached_max_steps() and progress.epoch_step < len(batches):
            self.save()
            return False
        progress.epoch += 1
        progress.epoch_step = 0
        return True

    @torch.no_grad()
    def validate(
        self, trainable: nn.Module, chunks: Iterable[np.ndarray], losses_of: LossesOf
    ) -> dict[str, float]:
        """Mean losses over validation batches (``chunks`` of item indices), each drawing from
        its own generator of the VALIDATION stream, so every epoch sees the same batches."""
        trainable.eval()
        records = []
        for index, chunk in enumerate(chunks):
            rng = stream_rng(Stream.VALIDATION, self.config.seed, index)
            with self.runtime.autocast():
                records.append(losses_of(chunk, rng))
        trainable.train()
        return mean_records(records)

    def end_epoch(self, metrics: dict[str, Any], improved: bool) -> None:
        """Record the validation metrics, save latest.pt (and best.pt when ``improved``), log."""
        self.log("val", metrics)
        self.save(best=improved)
        shown = ", ".join(f"{key} {value:.4g}" for key, value in metrics.items())
        logger.info("%s epoch %d: val %s", self.name, self.progress.epoch, shown)

    def train_epochs(
        self,
        num_items: int,
        losses_of: LossesOf,
        parameters: list[nn.Parameter],
        validate: Callable[[], dict[str, float]],
    ) -> None:
        """The loop of a stage trained for ``epochs``: shuffled batches of ``num_items`` training
        items, then validation; best.pt holds the lowest validation loss."""
        epochs = self.section.epochs
        self.announce(epochs, epochs * len(self.epoch_batches(num_items)), num_items)
        while self.progress.epoch < epochs:
            description = f"{self.name} epoch {self.progress.epoch + 1}/{epochs}"
            batches = self.epoch_batches(num_items)
            if not self.train_epoch(batches, description, losses_of, parameters):
                break
            metrics = validate()
            self.end_epoch(metrics, self.improved(metrics["loss"]))

    # -- records ------------------------------------------------------------------------------

    def improved(self, value: float) -> bool:
        """Record a validation value (rank 0's); True (and best updated) when it is the best yet."""
        value = self.runtime.broadcast_float(value)
        if value < self.progress.best:
            self.progress.best = value
            return True
        return False

    def log(self, split: str, values: dict[str, Any]) -> None:
        """Write one record; tensors are read here (the only host sync of the loop).

        Validation records also refresh curves.png (at most once a minute).
        """
        plain = {
            k: (v.detach().float().item() if isinstance(v, torch.Tensor) else v)
            for k, v in values.items()
        }
        loss = plain.get("loss")
        if isinstance(loss, float) and not math.isfinite(loss):
            raise UsageError(
                f"{self.name}: {split} loss is {loss} at step {self.step}; lower the learning "
                "rate or resume from the last good checkpoint"
            )
        self.logbook.write(split, self.step, self.progress.epoch, plain)
        if split == "val":
            self.logbook.draw(force=False)

    def finish(self) -> Path:
        """Draw the curves; make sure best.pt exists (a run too short to validate saves latest);
        mark the stage finished (``finished.json``), so a driver such as ``make demo`` can tell a
        completed stage from an interrupted one. Returns the stage folder."""
        if self.runtime.is_main and not (self.dir / "best.pt").is_file():
            self.save(best=True)  # waits at the barrier itself
        else:
            self.runtime.barrier()
        if self.runtime.is_main:
            self.logbook.draw()
            write_json_atomic(self.dir / FINISHED, json_safe(self._stored_progress()))
        return self.dir


def step_sized_batches(
    num_items: int,
    batch_size: int,
    seed: int,
    epoch: int,
    epoch_steps: int = 0,
    rank: int = 0,
    world_size: int = 1,
) -> list[np.ndarray]:
    """One process's batches of epoch ``epoch``: one pass over the items
    (:func:`~t2m.data.dataset.epoch_batches` of the epoch), or with ``epoch_steps`` that many
    batches: numbers ``epoch x epoch_steps`` on of the sequence of passes 0, 1, 2, ..., each
    batch within one pass. Where a pass holds exactly ``epoch_steps`` batches, epoch k is pass
    k, the same batches as without it; empty when the items fill no batch."""

    def one_pass(index: int) -> list[np.ndarray]:
        return epoch_batches(num_items, batch_size, seed, index, rank, world_size)

    if not epoch_steps:
        return one_pass(epoch)
    per_pass = (num_items // world_size) // batch_size
    if per_pass == 0:
        return []
    first = epoch * epoch_steps
    passes: dict[int, list[np.ndarray]] = {}
    batches = []
    for index in range(first, first + epoch_steps):
        number, position = divmod(index, per_pass)
        if number not in passes:
            passes[number] = one_pass(number)
        batches.append(passes[number][position])
    return batches


def json_safe(record: dict[str, Any]) -> dict[str, Any]:
    """``record`` with non-finite floats (a best value never set is infinity) as None, so the
    JSON file is standard JSON (``json.dumps`` would write ``Infinity``)."""
    return {
        key: None if isinstance(value, float) and not math.isfinite(value) else value
        for key, value in record.items()
    }


def check_batches(job: StageJob, data: StageData, frames: int = 0, val_items: int = 1) -> None:
    """UsageError, before any model is built, when an epoch of the stage would train nothing:
    fewer training clips of at least ``frames`` frames per process than one batch, or fewer
    than ``val_items`` validation clips of that length."""
    name, runtime = job.stage.name, job.runtime
    batch_size = getattr(job.config, name).batch_size
    at_least = f" of at least {frames} frames" if frames else ""
    train = len(data.train.indices_at_least(frames))
    if train // runtime.world_size < batch_size:
        processes = f" over {runtime.world_size} processes" if runtime.world_size > 1 else ""
        raise UsageError(
            f"{name}: the train split has {train} usable clips{at_least}, fewer than one batch "
            f"of {name}.batch_size={batch_size}{processes}; lower --{name}.batch_size or use "
            "a larger dataset"
        )
    val = len(data.val.indices_at_least(frames))
    if val < val_items:
        raise UsageError(
            f"{name}: the validation split has {val} usable clips{at_least}; validation needs "
            f"at least {val_items}"
        )


def validation_chunks(indices: np.ndarray, batch_size: int) -> list[np.ndarray]:
    """``indices`` cut into about ``len / batch_size`` batches of ``batch_size`` or more items."""
    return np.array_split(indices, max(1, len(indices) // batch_size))


def mean_records(records: list[dict[str, torch.Tensor]]) -> dict[str, float]:
    """Average of per-batch metric dicts (validation), reading tensors once at the end."""
    if not records:
        return {}
    keys = records[0].keys()
    return {k: float(torch.stack([r[k].detach().float() for r in records]).mean()) for k in keys}


def to_device(batch: dict[str, torch.Tensor], device: torch.device) -> dict[str, torch.Tensor]:
    """Every tensor of a batch on ``device``."""
    return {key: value.to(device, non_blocking=True) for key, value in batch.items()}
