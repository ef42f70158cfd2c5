"""Checkpoints: atomic saves, compatibility checks on resume, and rebuilding trained stages.

A run folder (``--checkpoints DIR``) holds one folder per stage, ``ae/ length/ t2m/ eval/``, each
with ``latest.pt``, ``best.pt``, ``config.json``, ``metrics.jsonl`` and ``curves.png``.

A checkpoint is a dict::

    format_version  int
    stage           "ae" | "length" | "t2m" | "eval"
    config          the resolved Config (dict) of the run that wrote it
    dims            sizes taken from the data: feature_dim, word_dim, vocab_size, code_size
    models          name -> state_dict (see STAGE_MODELS)
    optimizer       optimizer state_dict
    progress        epoch, epoch_step, step, best, and the stage's own counters
    normalizer      {"mean", "std"} (D,) float32 arrays, the root/contact-weighted statistics
    vocabulary      WordVectors.info() (None for the autoencoder)
    extra           stage extras (t2m: the mean-pose ``initial_code`` (C,))

:func:`load_stage` rebuilds the models of a stage from the stored config, in eval mode.
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import torch
from torch import nn

from dataset_tools.io import atomic_write, write_text_atomic
from t2m.config import STAGES, Config, from_dict
from t2m.data.normalization import Normalizer
from t2m.data.words import WordVectors, vectorizer_from_info
from t2m.models.autoencoder import MovementAutoencoder, MovementDecoder
from t2m.models.evaluator import Evaluator
from t2m.models.length import LengthEstimator
from t2m.models.temporal_vae import TemporalVAE

FORMAT_VERSION = 1

# The make target that trains each stage, for "run this first" messages.
MAKE_TARGETS = {"ae": "train-ae", "length": "train-len", "t2m": "train-t2m", "eval": "train-eval"}

# Models each stage stores: "name" -> what it is.
STAGE_MODELS = {
    "ae": ("autoencoder",),
    "length": ("length",),
    "t2m": ("vae", "decoder"),
    "eval": ("evaluator",),
}


def atomic_save(obj: Any, path: Path) -> None:
    """``torch.save`` atomically (see :func:`dataset_tools.io.atomic_write`)."""
    atomic_write(path, lambda file: torch.save(obj, file))


def write_config(stage_dir: Path, config: Config) -> None:
    write_text_atomic(stage_dir / "config.json", config.to_json() + "\n")


def read_checkpoint(path: Path) -> dict[str, Any]:
    """Load a checkpoint dict on CPU; ValueError when missing or not ours."""
    if not path.is_file():
        raise ValueError(f"no checkpoint at {path}")
    try:
        checkpoint = torch.load(path, map_location="cpu", weights_only=False)
    except (RuntimeError, EOFError, OSError) as error:
        raise ValueError(f"{path}: unreadable checkpoint ({error})") from None
    if not isinstance(checkpoint, dict) or checkpoint.get("format_version") != FORMAT_VERSION:
        raise ValueError(f"{path}: not a t2m checkpoint of format {FORMAT_VERSION}")
    return checkpoint


def _differences(a: Any, b: Any, prefix: str = "") -> list[str]:
    if isinstance(a, dict) and isinstance(b, dict):
        out = []
        for key in sorted(set(a) | set(b)):
            out += _differences(a.get(key), b.get(key), f"{prefix}{key}.")
        return out
    if isinstance(a, (list, tuple)) and isinstance(b, (list, tuple)):
        a, b = list(a), list(b)
    return [] if a == b else [f"{prefix.rstrip('.')}: {a!r} vs {b!r}"]


def check_compatible(
    checkpoint: dict[str, Any],
    stage: str,
    model_config: dict[str, Any],
    dims: dict[str, int],
    vocabulary: dict[str, Any] | None,
    where: str,
) -> None:
    """Refuse (ValueError, one line) a checkpoint of another stage, size or vocabulary."""
    if checkpoint["stage"] != stage:
        raise ValueError(f"{where} is a {checkpoint['stage']!r} checkpoint, not {stage!r}")
    stored_model = checkpoint["config"][stage]["model"]
    diff = _differences(stored_model, model_config)
    if diff:
        raise ValueError(
            f"{where}: model size differs ({'; '.join(diff[:3])}); use the same preset and "
            "overrides, or another --checkpoints folder"
        )
    stored_vocab = checkpoint.get("vocabulary")
    if (stored_vocab is None) != (vocabulary is None) or (
        stored_vocab is not None
        and (stored_vocab["source"], stored_vocab["fingerprint"])
        != (vocabulary["source"], vocabulary["fingerprint"])
    ):
        stored = stored_vocab and stored_vocab["source"]
        current = vocabulary and vocabulary["source"]
        raise ValueError(f"{where}: vocabulary differs ({stored!r} vs {current!r})")
    diff = _differences(checkpoint["dims"], dims)
    if diff:
        raise ValueError(f"{where}: data sizes differ ({'; '.join(diff[:3])})")


@dataclass
class TrainedStage:
    """A trained stage rebuilt from its checkpoint.

    Attributes:
        stage: "ae", "length", "t2m" or "eval".
        config: the Config the stage was trained with.
        models: eval-mode modules, by name:
            ae     -> "autoencoder": MovementAutoencoder
            length -> "length": LengthEstimator
            t2m    -> "vae": TemporalVAE, "decoder": MovementDecoder (fine-tuned)
            eval   -> "evaluator": Evaluator (owns the frozen movement encoder)
        normalizer: mean/std (D,) used for normalised features (the root/contact-weighted ones).
        vectorizer: the vocabulary (None for "ae"); ``encode_text``/``encode_tokens`` give the
            word inputs the text encoders expect.
        initial_code: (C,) mean-pose code fed before the first snippet (t2m only).
        progress: step, epoch, best validation value ...
        dims: feature_dim, word_dim, vocab_size, code_size.
    """

    stage: str
    config: Config
    models: dict[str, nn.Module]
    normalizer: Normalizer
    vectorizer: WordVectors | None
    progress: dict[str, Any]
    dims: dict[str, int]
    initial_code: torch.Tensor | None = None
    path: Path | None = None
    extra: dict[str, Any] = field(default_factory=dict)


def build_models(stage: str, config: Config, dims: dict[str, int]) -> dict[str, nn.Module]:
    """Fresh (untrained) models of ``stage`` from a Config and the data sizes."""
    word_dim, vocab_size = dims.get("word_dim", 0), dims.get("vocab_size", 0)
    feature_dim = dims["feature_dim"]
    if stage == "ae":
        return {"autoencoder": MovementAutoencoder(feature_dim, config.ae.model)}
    if stage == "length":
        return {"length": LengthEstimator(word_dim, config.length.model, vocab_size)}
    if stage == "t2m":
        code_size = config.ae.model.code_size
        return {
            "vae": TemporalVAE(word_dim, code_size, config.t2m.model, vocab_size),
            "decoder": MovementDecoder(feature_dim, config.ae.model),
        }
    if stage == "eval":
        return {
            "evaluator": Evaluator(
                word_dim, feature_dim, config.ae.model, config.eval.model, vocab_size
            )
        }
    raise ValueError(f"unknown stage {stage!r}; choose one of {', '.join(STAGES)}")


def stage_path(run_dir: str | Path, stage: str, which: str = "best") -> Path:
    if which not in ("best", "latest"):
        raise ValueError(f"which must be 'best' or 'latest', got {which!r}")
    return Path(run_dir) / stage / f"{which}.pt"


def load_stage(
    run_dir: str | Path, stage: str, device: str | torch.device = "cpu", which: str = "best"
) -> TrainedStage:
    """Rebuild a trained stage from ``run_dir/<stage>/<which>.pt``, models in eval mode on ``device``.

    Raises ValueError (one line, naming the make target to run) when the stage is not trained.
    Example::

        t2m = load_stage("checkpoints/demo", "t2m")
        text = t2m.vectorizer.encode_text("a person walks forward")[0]
        vae, decoder = t2m.models["vae"], t2m.models["decoder"]
    """
    if stage not in STAGES:
        raise ValueError(f"unknown stage {stage!r}; choose one of {', '.join(STAGES)}")
    path = stage_path(run_dir, stage, which)
    if not path.is_file():
        raise ValueError(
            f"no trained {stage!r} stage in {Path(run_dir) / stage} (run `make {MAKE_TARGETS[stage]}` "
            "with the same PRESET/CHECKPOINTS first)"
        )
    checkpoint = read_checkpoint(path)
    if checkpoint["stage"] != stage:
        raise ValueError(f"{path} is a {checkpoint['stage']!r} checkpoint, not {stage!r}")
    config = from_dict(checkpoint["config"])
    models = build_models(stage, config, checkpoint["dims"])
    device = torch.device(device)
    for name, module in models.items():
        module.load_state_dict(checkpoint["models"][name])
        module.to(device).eval()
    vocabulary = checkpoint.get("vocabulary")
    initial_code = checkpoint.get("extra", {}).get("initial_code")
    return TrainedStage(
        stage=stage,
        config=config,
        models=models,
        normalizer=Normalizer(**checkpoint["normalizer"]),
        vectorizer=vectorizer_from_info(vocabulary) if vocabulary else None,
        progress=checkpoint["progress"],
        dims=checkpoint["dims"],
        initial_code=initial_code.to(device) if initial_code is not None else None,
        path=path,
        extra={k: v for k, v in checkpoint.get("extra", {}).items() if k != "initial_code"},
    )


def make_checkpoint(
    stage: str,
    config: Config,
    dims: dict[str, int],
    models: dict[str, nn.Module],
    optimizer: torch.optim.Optimizer,
    progress: dict[str, Any],
    normalizer: Normalizer,
    vocabulary: dict[str, Any] | None,
    extra: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """The checkpoint dict (tensors copied to CPU by torch.save's pickling as they are)."""
    return {
        "format_version": FORMAT_VERSION,
        "stage": stage,
        "config": config.to_dict(),
        "dims": dict(dims),
        "models": {name: module.state_dict() for name, module in models.items()},
        "optimizer": optimizer.state_dict(),
        "progress": dict(progress),
        "normalizer": normalizer.state(),
        "vocabulary": vocabulary,
        "extra": dict(extra or {}),
    }


def read_config_json(path: Path) -> Config:
    """A Config from a stage folder's config.json."""
    return from_dict(json.loads(path.read_text()))


def model_config_dict(config: Config, stage: str) -> dict[str, Any]:
    return dataclasses.asdict(getattr(config, stage).model)
