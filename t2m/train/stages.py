"""The training stages, in one table: what each trains, stores and needs; train one; load one.

=============  ===============  ==================  ===========  =============================
stage          ``make`` target  models stored       needs        old names (still accepted)
=============  ===============  ==================  ===========  =============================
autoencoder    train-ae         autoencoder         -            ae
length         train-len        length              -            len, text2length
generator      train-t2m        vae, decoder        autoencoder  t2m
evaluator      train-eval       evaluator           autoencoder  eval
=============  ===============  ==================  ===========  =============================

A stage's name is also its config section (``--generator.batch_size=16``) and its folder in the
run folder (``checkpoints/demo/generator/``). Runs written before the renaming keep their
folders (``ae/ t2m/ eval/``): a stage is read from, and resumed in, the folder that exists.

Adding a stage is one :class:`~t2m.train.job.Stage` in :data:`STAGES`, its config section in
``t2m.config`` and its loop module.
"""

from __future__ import annotations

import logging
import os
from pathlib import Path

import torch
from torch import nn

from dataset_tools.command import UsageError
from t2m.accel import accelerate
from t2m.config import Config, from_dict
from t2m.data.normalization import Normalizer
from t2m.data.words import vectorizer_from_info
from t2m.models.autoencoder import MovementAutoencoder, MovementDecoder
from t2m.models.evaluator import Evaluator
from t2m.models.length import LengthEstimator
from t2m.models.temporal_vae import TemporalVAE
from t2m.train import runtime as runtime_module
from t2m.train.autoencoder import train_autoencoder
from t2m.train.checkpoint import (
    ModelSizes,
    TrainedStage,
    checkpoint_spec,
    content_error,
    read_checkpoint,
)
from t2m.train.evaluator import train_evaluator
from t2m.train.generator import train_generator
from t2m.train.job import Stage, StageJob
from t2m.train.length import train_length
from t2m.train.runtime import Runtime
from t2m.train.stage import FINISHED

logger = logging.getLogger(__name__)


def _accelerated(models: dict[str, nn.Module]) -> dict[str, nn.Module]:
    """``models`` with :func:`t2m.accel.accelerate` applied (float32, torch)."""
    return {name: accelerate(module) for name, module in models.items()}


STAGES: tuple[Stage, ...] = (
    Stage(
        name="autoencoder",
        make_target="train-ae",
        models=("autoencoder",),
        build=lambda config, sizes: _accelerated(
            {"autoencoder": MovementAutoencoder(sizes.feature_dim, config.autoencoder.model)}
        ),
        train=train_autoencoder,
        old_names=("ae",),
    ),
    Stage(
        name="length",
        make_target="train-len",
        models=("length",),
        build=lambda config, sizes: _accelerated(
            {"length": LengthEstimator(sizes.word_dim, config.length.model, sizes.vocab_size)}
        ),
        train=train_length,
        old_names=("len", "text2length"),
    ),
    Stage(
        name="generator",
        make_target="train-t2m",
        models=("vae", "decoder"),
        build=lambda config, sizes: _accelerated(
            {
                "vae": TemporalVAE(
                    sizes.word_dim, sizes.code_size, config.generator.model, sizes.vocab_size
                ),
                "decoder": MovementDecoder(sizes.feature_dim, config.autoencoder.model),
            }
        ),
        train=train_generator,
        needs=("autoencoder",),
        old_names=("t2m",),
    ),
    Stage(
        name="evaluator",
        make_target="train-eval",
        models=("evaluator",),
        build=lambda config, sizes: _accelerated(
            {
                "evaluator": Evaluator(
                    sizes.word_dim,
                    sizes.feature_dim,
                    config.autoencoder.model,
                    config.evaluator.model,
                    sizes.vocab_size,
                )
            }
        ),
        train=train_evaluator,
        needs=("autoencoder",),
        old_names=("eval",),
    ),
)

STAGE_NAMES: tuple[str, ...] = tuple(stage.name for stage in STAGES)


def find_stage(name: str) -> Stage:
    """The stage called ``name`` (or one of its old names); UsageError naming the choices."""
    for stage in STAGES:
        if name == stage.name or name in stage.old_names:
            return stage
    raise UsageError(f"unknown stage {name!r}; choose one of {', '.join(STAGE_NAMES)}")


def load_stage(
    run_dir: str | Path, stage: str, device: str | torch.device = "cpu", which: str = "best"
) -> TrainedStage:
    """Rebuild a trained stage from its ``<which>.pt``, models in eval mode on ``device``.

    ``stage``: a stage name or an old one (``"ae"`` is the autoencoder). Raises UsageError (a
    ValueError: one line) naming the make target to run when the stage is not trained, or naming
    the file when its checkpoint is refused (:func:`~t2m.train.checkpoint.read_checkpoint`
    never runs code from it) or does not fit its stored config. Example::

        generator = load_stage("checkpoints/demo", "generator")
        text = generator.vectorizer.encode_text("a person walks forward")[0]
        vae, decoder = generator.models["vae"], generator.models["decoder"]
    """
    record = find_stage(stage)
    if which not in ("best", "latest"):
        raise ValueError(f"which must be 'best' or 'latest', got {which!r}")
    path = record.folder(run_dir) / f"{which}.pt"
    if not path.is_file():
        raise record.not_trained(run_dir)
    checkpoint = read_checkpoint(path)
    if checkpoint["stage"] not in (record.name, *record.old_names):
        raise UsageError(f"{path} is a {checkpoint['stage']!r} checkpoint, not {record.name!r}")
    try:
        return _rebuild(record, checkpoint, path, torch.device(device))
    except torch.OutOfMemoryError:
        raise
    except (ValueError, TypeError, KeyError, RuntimeError) as error:
        # read_checkpoint checked the layout; this is content that does not fit it
        raise content_error(path, f"unusable {record.name} checkpoint", error) from None


def _rebuild(record: Stage, checkpoint: dict, path: Path, device: torch.device) -> TrainedStage:
    """The stage's models and data of a checkpoint read by :func:`read_checkpoint`."""
    config = from_dict(checkpoint["config"])
    sizes = ModelSizes.from_dict(checkpoint["dims"])
    models = record.build(config, sizes)
    for name, module in models.items():
        module.load_state_dict(checkpoint["models"][name])
        module.to(device).eval()
    vocabulary = checkpoint["vocabulary"]
    extra = checkpoint["extra"]
    initial_code = extra.get("initial_code")
    if initial_code is not None and not isinstance(initial_code, torch.Tensor):
        raise ValueError(f"initial_code is a {type(initial_code).__name__}, not a tensor")
    return TrainedStage(
        stage=record.name,
        config=config,
        models=models,
        normalizer=Normalizer(**checkpoint["normalizer"]),
        vectorizer=vectorizer_from_info(vocabulary) if vocabulary else None,
        progress=checkpoint["progress"],
        dims=sizes,
        spec=checkpoint_spec(checkpoint),
        initial_code=initial_code.to(device) if initial_code is not None else None,
        path=path,
        extra={k: v for k, v in extra.items() if k != "initial_code"},
    )


# What a stage's run writes into its folder (see t2m.train.checkpoint and t2m.train.stage).
RUN_FILES = ("best.pt", "latest.pt", FINISHED, "config.json", "metrics.jsonl", "curves.png")
PREVIOUS = "previous"


def set_aside(stage_dir: Path) -> Path:
    """Move a stage folder's run files (:data:`RUN_FILES`) into its ``previous/`` subfolder
    (replacing the run set aside there before) and return that folder. ``--force`` does this
    before it retrains, so that a retrain stopped before its first validation leaves no
    ``best.pt`` behind for sampling or export to take for the new model; the old run stays
    recoverable. Files the run did not write are left where they are."""
    previous = stage_dir / PREVIOUS
    if previous.is_dir():
        for name in RUN_FILES:
            (previous / name).unlink(missing_ok=True)
    previous.mkdir(exist_ok=True)
    for name in RUN_FILES:
        if (stage_dir / name).is_file():
            os.replace(stage_dir / name, previous / name)
    logger.info("the earlier %s run is set aside in %s", stage_dir.name, previous)
    return previous


def train_stage(
    stage: str,
    config: Config,
    dataset_dir: str | Path,
    run_dir: str | Path,
    runtime: Runtime | None = None,
    resume: bool = False,
    force: bool = False,
) -> Path:
    """Train ``stage`` with ``config`` into its folder of ``run_dir``; returns that folder.

    A stage folder that already holds a run (a checkpoint or ``finished.json``) is continued
    with ``resume``, started afresh with ``force`` (the earlier run's files moved into
    ``previous/`` first: :func:`set_aside`), and otherwise refused (UsageError), so that a
    trained ``best.pt`` is never replaced by mistake. The stages it needs are loaded from ``run_dir`` (best checkpoints; a one-line UsageError
    names the make target of a missing one). Opens (and closes) the runtime when not given one.
    Example::

        train_stage("autoencoder", tiny(), "data/demo", "checkpoints/tiny")
    """
    record = find_stage(stage)
    run_dir = Path(run_dir)
    if resume and force:
        raise UsageError("give one of --resume (continue the run) and --force (start afresh)")
    stage_dir = record.folder(run_dir)
    earlier = [name for name in ("best.pt", "latest.pt", FINISHED) if (stage_dir / name).is_file()]
    if earlier and not (resume or force):
        state = "finished" if FINISHED in earlier else "unfinished"
        raise UsageError(
            f"{stage_dir} holds a {state} {record.name} run; use --resume to continue or "
            "--force to retrain"
        )
    own_runtime = runtime is None
    if runtime is None:
        runtime = runtime_module.start(config.device, config.bf16, config.num_threads)
    try:
        prerequisites = {}
        for name in record.needs:
            needed = find_stage(name)
            if not (needed.folder(run_dir) / "best.pt").is_file():
                raise UsageError(
                    f"{record.name} needs a trained {name!r} in {needed.folder(run_dir)}: "
                    f"run `make {needed.make_target}` first"
                )
            prerequisites[name] = load_stage(run_dir, name, runtime.device)
        if earlier and force:  # only once the stages it needs are there
            set_aside(stage_dir)
        job = StageJob(record, config, Path(dataset_dir), run_dir, runtime, resume, prerequisites)
        return record.train(job)
    finally:
        if own_runtime:
            runtime_module.finish(runtime)
