"""The bookkeeping every stage loop shares: data, vocabulary, resume, checkpoints, records.

A stage loop (``t2m/train/ae.py`` ...) builds its models and optimizer, then opens a
:class:`StageRun`, which restores them from ``latest.pt`` on ``--resume`` (after refusing a
checkpoint of another stage, size or vocabulary), writes ``config.json``, keeps the progress
counters, saves ``latest.pt`` / ``best.pt`` atomically and writes the metrics.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn
from tqdm import tqdm

from dataset_tools.io import write_json_atomic
from t2m.config import Config
from t2m.data.dataset import MotionTextData, batch_rng, load_split
from t2m.data.normalization import Normalizer
from t2m.data.words import TRAINABLE, WordVectors, build_trainable_vocabulary, load_vectorizer
from t2m.train.checkpoint import (
    MAKE_TARGETS,
    atomic_save,
    check_compatible,
    load_stage,
    make_checkpoint,
    model_config_dict,
    read_checkpoint,
    stage_path,
    write_config,
)
from t2m.train.logbook import Logbook
from t2m.train.runtime import Runtime, clip_gradients, seed_step, unwrap

logger = logging.getLogger(__name__)

# Written into the stage folder when its loop ends normally.
FINISHED = "finished.json"


@dataclass
class StageData:
    """Train and validation data of one stage."""

    train: MotionTextData
    val: MotionTextData
    vectorizer: WordVectors
    normalizer: Normalizer


def vocabulary_for(config: Config, dataset_dir: Path) -> WordVectors:
    """The configured word vectors, or a trainable vocabulary of the training captions."""
    data = config.data
    if data.word_vectors == TRAINABLE:
        clips = load_split(dataset_dir, "train", data)
        return build_trainable_vocabulary(
            (c.tokens for clip in clips for c in clip.captions),
            data.trainable_word_dim,
            data.max_text_tokens,
        )
    return load_vectorizer(data.word_vectors, data.max_text_tokens)


def load_stage_data(
    config: Config, dataset_dir: str | Path, normalizer: Normalizer | None = None
) -> StageData:
    """Train/val splits of a HumanML3D-layout folder, normalised, with their vocabulary.

    ``normalizer`` defaults to the dataset's Mean/Std with the root/contact weighting.
    The validation split falls back to ``test`` when ``val.txt`` is missing or empty of clips.
    """
    dataset_dir = Path(dataset_dir)
    if not dataset_dir.is_dir():
        raise ValueError(f"dataset folder {dataset_dir} does not exist (run `make dataset` first)")
    if normalizer is None:
        normalizer = Normalizer.from_dataset(dataset_dir, config.data.feature_bias)
    vectorizer = vocabulary_for(config, dataset_dir)
    train = MotionTextData(
        load_split(dataset_dir, "train", config.data), normalizer, vectorizer, config.data
    )
    try:
        val_clips = load_split(dataset_dir, "val", config.data)
    except ValueError:
        logger.warning("%s: no usable val split, validating on test", dataset_dir)
        val_clips = load_split(dataset_dir, "test", config.data)
    val = MotionTextData(val_clips, normalizer, vectorizer, config.data)
    return StageData(train, val, vectorizer, normalizer)


def require_stage(run_dir: Path, stage: str, device: torch.device) -> Any:
    """A prerequisite stage (best checkpoint); ValueError naming the make target when missing."""
    if not stage_path(run_dir, stage, "best").is_file():
        raise ValueError(
            f"stage needs a trained {stage!r} in {run_dir / stage}: run `make {MAKE_TARGETS[stage]}` first"
        )
    return load_stage(run_dir, stage, device=device, which="best")


@dataclass
class OnAutoencoder:
    """What the stages trained on top of the autoencoder (t2m, eval) start from."""

    ae: Any
    config: Config
    data: StageData
    dims: dict[str, int]


def start_on_autoencoder(config: Config, dataset_dir: str | Path, run_dir: Path,
                         device: torch.device) -> OnAutoencoder:  # fmt: skip
    """Load the trained ``ae`` stage, adopt its model config (on a copy: the caller's config stays),
    read the data with its statistics, and derive the model sizes; refuse a dataset whose feature
    dimension differs from the autoencoder's."""
    from t2m.config import from_dict

    ae = require_stage(run_dir, "ae", device)
    config = from_dict(config.to_dict())
    config.ae.model = ae.config.ae.model
    data = load_stage_data(config, dataset_dir, normalizer=ae.normalizer)
    vectorizer = data.vectorizer
    dims = {
        "feature_dim": data.train.feature_dim,
        "word_dim": vectorizer.dim,
        "vocab_size": vectorizer.size if vectorizer.trainable else 0,
        "code_size": config.ae.model.code_size,
    }
    if ae.dims["feature_dim"] != dims["feature_dim"]:
        raise ValueError(
            f"the autoencoder was trained on {ae.dims['feature_dim']}-d features, "
            f"the dataset has {dims['feature_dim']}"
        )
    return OnAutoencoder(ae, config, data, dims)


class StageRun:
    """Resume, checkpoints and records of one stage in ``run_dir/<stage>``.

    Args:
        stage, config, run_dir: what and where.
        runtime: device and process rank.
        dims: sizes from the data (stored; checked on resume).
        models: name -> module (unwrapped) saved in the checkpoint.
        optimizer: saved and restored with them.
        normalizer, vocabulary: stored for later stages and sampling.
        resume: continue from ``latest.pt``.
        extra: stage extras stored in the checkpoint.
    """

    def __init__(
        self,
        stage: str,
        config: Config,
        run_dir: str | Path,
        runtime: Runtime,
        dims: dict[str, int],
        models: dict[str, nn.Module],
        optimizer: torch.optim.Optimizer,
        normalizer: Normalizer,
        vocabulary: dict[str, Any] | None,
        resume: bool = False,
        extra: dict[str, Any] | None = None,
    ):
        self.stage = stage
        self.config = config
        self.dir = Path(run_dir) / stage
        self.runtime = runtime
        self.dims = dims
        self.models = models
        self.optimizer = optimizer
        self.normalizer = normalizer
        self.vocabulary = vocabulary
        self.extra = dict(extra or {})
        self.progress: dict[str, Any] = {"epoch": 0, "epoch_step": 0, "step": 0, "best": math.inf}
        latest = stage_path(self.dir.parent, stage, "latest")
        if resume:
            checkpoint = read_checkpoint(latest)
            check_compatible(
                checkpoint, stage, model_config_dict(config, stage), dims, vocabulary, str(latest)
            )
            for name, module in models.items():
                module.load_state_dict(checkpoint["models"][name])
            optimizer.load_state_dict(checkpoint["optimizer"])
            self.progress.update(checkpoint["progress"])
            logger.info(
                "%s: resumed at step %d (epoch %d)",
                stage,
                self.progress["step"],
                self.progress["epoch"],
            )
        elif latest.is_file() and runtime.is_main:
            logger.warning("%s: starting afresh over the existing run in %s", stage, self.dir)
        if runtime.is_main:
            self.dir.mkdir(parents=True, exist_ok=True)
            (self.dir / FINISHED).unlink(missing_ok=True)
            write_config(self.dir, config)
        self.logbook = Logbook(
            self.dir,
            stage,
            enabled=runtime.is_main,
            resume_step=self.progress["step"] if resume else None,
        )

    @property
    def step(self) -> int:
        return int(self.progress["step"])

    def reached_max_steps(self, max_steps: int) -> bool:
        return max_steps > 0 and self.step >= max_steps

    def save(self, best: bool = False) -> None:
        """Write latest.pt (and best.pt) from the main process; every process waits for it."""
        if self.runtime.is_main:
            checkpoint = make_checkpoint(
                self.stage, self.config, self.dims,
                {name: unwrap(module) for name, module in self.models.items()},
                self.optimizer, self.progress, self.normalizer, self.vocabulary, self.extra,
            )  # fmt: skip
            atomic_save(checkpoint, self.dir / "latest.pt")
            if best:
                atomic_save(checkpoint, self.dir / "best.pt")
        self.runtime.barrier()

    def steps(
        self, epoch: int, num_batches: int, description: str, max_steps: int
    ) -> Iterator[tuple[int, np.random.Generator]]:
        """The batches of one epoch still to run, from where a resumed run stopped: yields
        (batch index, the batch's random generator) after seeding torch for that step, and
        keeps the epoch's progress bar; stops early at ``max_steps``."""
        self.bar = tqdm(total=num_batches, initial=self.progress["epoch_step"], desc=description,
                        disable=not self.runtime.is_main, leave=False)  # fmt: skip
        for index in range(self.progress["epoch_step"], num_batches):
            if self.reached_max_steps(max_steps):
                break
            seed_step(self.config.seed, epoch, index, self.runtime.rank)
            yield index, batch_rng(self.config.seed, epoch, index, self.runtime.rank)

    def optimize(
        self,
        losses: dict[str, torch.Tensor],
        parameters: Any,
        grad_clip: float,
        log_every: int,
        checkpoint_every: int,
        extra: dict[str, Any] | None = None,
    ) -> None:
        """One optimizer step on ``losses["loss"]`` and the bookkeeping every stage shares:
        counters, progress bar, a train record every ``log_every`` steps, ``latest.pt`` every
        ``checkpoint_every`` steps."""
        self.optimizer.zero_grad(set_to_none=True)
        losses["loss"].backward()
        clip_gradients(parameters, grad_clip)
        self.optimizer.step()
        self.progress["step"] += 1
        self.progress["epoch_step"] += 1
        self.bar.update()
        if self.step % log_every == 0:
            self.log("train", {**losses, **(extra or {})})
            self.bar.set_postfix(loss=f"{float(losses['loss'].detach()):.4g}")
        if self.step % checkpoint_every == 0:
            self.save()

    def close_epoch(self, num_batches: int, max_steps: int) -> bool:
        """End an epoch's batches. True when ``max_steps`` cut the epoch short (latest.pt is
        saved so a resume continues mid-epoch); otherwise the counters move to the next epoch."""
        self.bar.close()
        if self.reached_max_steps(max_steps) and self.progress["epoch_step"] < num_batches:
            self.save()
            return True
        self.progress["epoch"] += 1
        self.progress["epoch_step"] = 0
        return False

    def improved(self, value: float) -> bool:
        """Record a validation value (rank 0's); True (and best updated) when it is the best yet."""
        value = self.runtime.broadcast_float(value)
        if value < self.progress["best"]:
            self.progress["best"] = value
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
            raise ValueError(
                f"{self.stage}: {split} loss is {loss} at step {self.step}; lower the learning "
                "rate or resume from the last good checkpoint"
            )
        self.logbook.write(split, self.step, int(self.progress["epoch"]), plain)
        if split == "val":
            self.logbook.draw(force=False)

    def finish(self) -> None:
        """Draw the curves; make sure best.pt exists (a run too short to validate saves latest);
        mark the stage finished (``finished.json``), so a driver such as ``make demo`` can tell a
        completed stage from an interrupted one."""
        if self.runtime.is_main and not (self.dir / "best.pt").is_file():
            self.save(best=True)  # waits at the barrier itself
        else:
            self.runtime.barrier()
        if self.runtime.is_main:
            self.logbook.draw()
            write_json_atomic(self.dir / FINISHED, dict(self.progress))


def mean_records(records: list[dict[str, torch.Tensor]]) -> dict[str, float]:
    """Average of per-batch metric dicts (validation), reading tensors once at the end."""
    if not records:
        return {}
    keys = records[0].keys()
    return {k: float(torch.stack([r[k].detach().float() for r in records]).mean()) for k in keys}


def to_device(batch: dict[str, torch.Tensor], device: torch.device) -> dict[str, torch.Tensor]:
    """Every tensor of a batch on ``device``."""
    return {key: value.to(device, non_blocking=True) for key, value in batch.items()}
