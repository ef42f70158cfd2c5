"""Checkpoints: the file format, atomic saves and the compatibility checks of a resume.

A run folder (``--checkpoints DIR``) holds one folder per stage, ``autoencoder/ length/
generator/ evaluator/`` (runs of the first releases: ``ae/ length/ t2m/ eval/``, still read),
each with ``latest.pt``, ``best.pt``, ``config.json``, ``metrics.jsonl`` and ``curves.png``.

A checkpoint is a dict of tensors and plain Python types only (dict, list, str, int, float,
bool, None), so that it loads with ``torch.load(..., weights_only=True)``: loading never runs
code from the file (:func:`read_checkpoint` refuses one that would need it)::

    format_version  int (2; 1: the first releases, which stored the statistics as numpy arrays)
    stage           the stage's name (first releases: "ae" | "length" | "t2m" | "eval")
    config          the resolved Config (dict) of the run that wrote it
    dims            the ModelSizes taken from the data (dict)
    spec            the DatasetSpec of the data (dict: fps, snippet length, frame limits ...);
                    checkpoints written before it was stored read as the spec of their feature
                    dimension (263: HumanML3D)
    models          name -> state_dict (the stage's ``models``, see t2m.train.stages)
    optimizer       optimizer state_dict
    progress        epoch, epoch_step, step, best, and the stage's own counters (the curriculum)
    normalizer      {"mean", "std"} (D,) float32 tensors, the root/contact-weighted statistics
    vocabulary      WordVectors.info(), plain types (None for the autoencoder); since the
                    word tables: the words of the dataset's captions plus data.vocabulary_margin
                    words with their (N, Dw) float32 vectors, so that no vector file is needed
                    to load it (t2m.data.words.checkpoint_vocabulary); earlier checkpoints name
                    the file (read again when loaded)
    extra           stage extras (generator: the mean-pose ``initial_code`` (C,))

:func:`t2m.train.stages.load_stage` rebuilds the models of a stage from the stored config.
"""

from __future__ import annotations

import dataclasses
import pickle
import re
import struct
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from dataset_tools.command import UsageError
from dataset_tools.io import atomic_write, write_text_atomic
from dataset_tools.spec import DatasetSpec, spec_for_dim
from t2m.config import Config, from_dict
from t2m.data.normalization import Normalizer
from t2m.data.words import WordVectors

FORMAT_VERSION = 2
READABLE_VERSIONS = (1, 2)

# What format-1 checkpoints need besides tensors: numpy's reconstruction of a float32 array (the
# normalisation statistics), allowed by name. Nothing here can run code; an array's contents
# pass through the same restricted unpickler. Both module names of ``_reconstruct`` are listed
# because a file written under numpy 1 names ``numpy.core``, one written under numpy 2
# ``numpy._core``.
_RECONSTRUCT = np.empty(0, np.float32).__reduce__()[0]
_FORMAT_1_GLOBALS = [
    np.ndarray,
    np.dtype,
    type(np.dtype(np.float32)),
    (_RECONSTRUCT, "numpy.core.multiarray._reconstruct"),
    (_RECONSTRUCT, "numpy._core.multiarray._reconstruct"),
]

# The entries every checkpoint has, with their types (``spec``, absent from the earliest ones, is
# read by checkpoint_spec).
_LAYOUT: dict[str, type | tuple[type, ...]] = {
    "stage": str,
    "config": dict,
    "dims": dict,
    "models": dict,
    "optimizer": dict,
    "progress": dict,
    "normalizer": dict,
    "vocabulary": (dict, type(None)),
    "extra": dict,
}


@dataclass(frozen=True)
class ModelSizes:
    """Sizes the models take from the data rather than the config (stored as ``dims``).

    Attributes:
        feature_dim: D, motion features per frame (263 for HumanML3D).
        word_dim: word-vector size (0 for the autoencoder, which reads no text).
        vocab_size: rows of a trainable embedding (0 with fixed word vectors).
        code_size: C, snippet-code size of the autoencoder the stage builds on (0 if none).
    """

    feature_dim: int
    word_dim: int = 0
    vocab_size: int = 0
    code_size: int = 0

    @classmethod
    def from_dict(cls, values: dict[str, int]) -> ModelSizes:
        """From a checkpoint's ``dims`` (older checkpoints leave out the sizes a stage ignores)."""
        return cls(**{f.name: int(values.get(f.name, 0)) for f in dataclasses.fields(cls)})

    def to_dict(self) -> dict[str, int]:
        return dataclasses.asdict(self)


def atomic_save(obj: Any, path: Path) -> None:
    """``torch.save`` atomically (see :func:`dataset_tools.io.atomic_write`)."""
    atomic_write(path, lambda file: torch.save(obj, file))


def write_config(stage_dir: Path, config: Config) -> None:
    write_text_atomic(stage_dir / "config.json", config.to_json() + "\n")


def read_checkpoint(path: Path) -> dict[str, Any]:
    """Load a checkpoint dict on CPU without running any code from the file.

    ``torch.load(..., weights_only=True)``: only tensors and plain types (and, for format 1,
    float32 numpy arrays) are unpickled. Raises UsageError (a ValueError, one line naming the
    file) when it is missing, unreadable, would need arbitrary unpickling (a pickle payload is
    refused before it can run), or is not a t2m checkpoint of a readable format.
    """
    if not path.is_file():
        raise UsageError(f"no checkpoint at {path}")
    try:
        with torch.serialization.safe_globals(_FORMAT_1_GLOBALS), warnings.catch_warnings():
            # garbage read as a pickle stream makes torch warn of odd protocols: it is refused
            warnings.filterwarnings("ignore", "Detected pickle protocol")
            checkpoint = torch.load(path, map_location="cpu", weights_only=True)
    except pickle.UnpicklingError as error:
        asked = _asked_for(error)
        if asked is None:  # not a payload: a broken pickle stream
            raise UsageError(f"{path}: unreadable checkpoint ({_reason(error)})") from None
        raise UsageError(
            f"{path}: refused without running it: it needs arbitrary unpickling ({asked}); "
            "load only checkpoints written by t2m"
        ) from None
    except (
        RuntimeError,
        EOFError,
        OSError,
        ValueError,
        LookupError,
        TypeError,
        struct.error,
    ) as error:
        raise UsageError(f"{path}: unreadable checkpoint ({_reason(error)})") from None
    _check_layout(checkpoint, path)
    return checkpoint


def _asked_for(error: pickle.UnpicklingError) -> str | None:
    """What a file refused by torch's weights-only unpickler asked for (a global, a call, an
    object), or None when the refusal is of malformed data rather than of code."""
    found = re.search(r"GLOBAL (\S+)", str(error))
    if found:
        return f"it asks for {found.group(1)}"
    reason = _reason(error)
    code = ("call reduce for", "Can only build", "Can only create new object", "blocked")
    return reason if any(words in reason for words in code) else None


def _reason(error: BaseException) -> str:
    """The line of ``error`` that says what is wrong (torch wraps it in advice)."""
    text = str(error).rsplit("WeightsUnpickler error:", 1)[-1]
    lines = [line.strip() for line in text.splitlines() if line.strip()]
    return lines[0] if lines else type(error).__name__


def content_error(path: Path, problem: str, error: Exception) -> UsageError:
    """The one-line UsageError for a checkpoint whose content does not fit what reads it
    (``problem``: e.g. "unusable generator checkpoint"), from the error that showed it."""
    reason = f"missing {error}" if isinstance(error, KeyError) else " ".join(str(error).split())
    return UsageError(f"{path}: {problem} ({reason[:300]})")


def _check_layout(checkpoint: Any, path: Path) -> None:
    """UsageError (one line) unless ``checkpoint`` has the entries and types of our format."""
    if not isinstance(checkpoint, dict) or "format_version" not in checkpoint:
        raise UsageError(f"{path}: not a t2m checkpoint")
    version = checkpoint["format_version"]
    if version not in READABLE_VERSIONS:
        raise UsageError(
            f"{path}: checkpoint format {version!r}; this version of t2m reads formats "
            f"{', '.join(map(str, READABLE_VERSIONS))}"
        )
    for key, kind in _LAYOUT.items():
        if not isinstance(checkpoint.get(key), kind):
            raise UsageError(f"{path}: malformed t2m checkpoint ({key!r} is missing or mistyped)")
    normalizer = checkpoint["normalizer"]
    if set(normalizer) != {"mean", "std"}:
        raise UsageError(f"{path}: malformed t2m checkpoint (normalizer {sorted(normalizer)})")
    if not all(isinstance(weights, dict) for weights in checkpoint["models"].values()):
        raise UsageError(f"{path}: malformed t2m checkpoint (models are not state dicts)")


def checkpoint_spec(checkpoint: dict[str, Any]) -> DatasetSpec:
    """The dataset spec a checkpoint was trained with; for one written before specs were
    stored, the spec of its feature dimension (ValueError, one line, when none fits)."""
    stored = checkpoint.get("spec")
    if stored is not None:
        return DatasetSpec.from_dict(stored)
    return spec_for_dim(ModelSizes.from_dict(checkpoint["dims"]).feature_dim)


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
    stage_names: tuple[str, ...],
    config: Config,
    sizes: ModelSizes,
    vocabulary: dict[str, Any] | None,
    where: str,
) -> None:
    """Refuse (UsageError, one line) a checkpoint of another stage, size or vocabulary.

    ``stage_names``: the stage's name first, then the old names its checkpoints may carry.
    """
    name = stage_names[0]
    if checkpoint["stage"] not in stage_names:
        raise UsageError(f"{where} is a {checkpoint['stage']!r} checkpoint, not {name!r}")
    stored_model = dataclasses.asdict(getattr(from_dict(checkpoint["config"]), name).model)
    diff = _differences(stored_model, dataclasses.asdict(getattr(config, name).model))
    if diff:
        raise UsageError(
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
        raise UsageError(f"{where}: vocabulary differs ({stored!r} vs {current!r})")
    diff = _differences(ModelSizes.from_dict(checkpoint["dims"]).to_dict(), sizes.to_dict())
    if diff:
        raise UsageError(f"{where}: data sizes differ ({'; '.join(diff[:3])})")


def make_checkpoint(
    stage: str,
    config: Config,
    sizes: ModelSizes,
    spec: DatasetSpec,
    models: dict[str, nn.Module],
    optimizer: torch.optim.Optimizer,
    progress: dict[str, Any],
    normalizer: Normalizer,
    vocabulary: dict[str, Any] | None,
    extra: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """The checkpoint dict: tensors and plain types only (tensors are copied to CPU by
    torch.save's pickling as they are)."""
    if spec.feature_dim != sizes.feature_dim:
        raise ValueError(
            f"{spec.name} has {spec.feature_dim}-d features, the models {sizes.feature_dim}"
        )
    return {
        "format_version": FORMAT_VERSION,
        "stage": stage,
        "config": config.to_dict(),
        "dims": sizes.to_dict(),
        "spec": spec.to_dict(),
        "models": {name: module.state_dict() for name, module in models.items()},
        "optimizer": optimizer.state_dict(),
        "progress": dict(progress),
        "normalizer": normalizer.state(),
        "vocabulary": vocabulary,
        "extra": dict(extra or {}),
    }


@dataclass
class TrainedStage:
    """A trained stage rebuilt from its checkpoint (see :func:`t2m.train.stages.load_stage`).

    Attributes:
        stage: "autoencoder", "length", "generator" or "evaluator".
        config: the Config the stage was trained with.
        models: eval-mode modules, by name:
            autoencoder -> "autoencoder": MovementAutoencoder
            length      -> "length": LengthEstimator
            generator   -> "vae": TemporalVAE, "decoder": MovementDecoder (fine-tuned)
            evaluator   -> "evaluator": Evaluator (owns the frozen movement encoder)
        normalizer: mean/std (D,) used for normalised features (the root/contact-weighted ones).
        vectorizer: the vocabulary (None for the autoencoder); ``encode_text``/``encode_tokens``
            give the word inputs the text encoders expect.
        progress: the stored counters: step, epoch, best validation value ...
        dims: the sizes taken from the data.
        spec: the dataset spec of the data (frame rate, snippet length, frame limits, body);
            default: the one of ``dims.feature_dim`` (for stages built without a checkpoint).
        initial_code: (C,) mean-pose code fed before the first snippet (generator only).
    """

    stage: str
    config: Config
    models: dict[str, nn.Module]
    normalizer: Normalizer
    vectorizer: WordVectors | None
    progress: dict[str, Any]
    dims: ModelSizes
    initial_code: torch.Tensor | None = None
    path: Path | None = None
    extra: dict[str, Any] = field(default_factory=dict)
    spec: DatasetSpec = None  # type: ignore[assignment]  # filled in by __post_init__

    def __post_init__(self) -> None:
        if self.spec is None:
            self.spec = spec_for_dim(self.dims.feature_dim)
