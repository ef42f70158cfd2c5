"""Trained models and what they need, read from a run folder (its ``generator``, ``length`` and
``autoencoder`` stages) or from the original T2M release (:func:`t2m.release.load_release`):
:func:`load_models`, what :meth:`t2m.pipeline.TextToMotion.from_checkpoints` builds a pipeline
from."""

from __future__ import annotations

from collections.abc import Collection
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

import torch

from dataset_tools.command import UsageError
from dataset_tools.spec import DatasetSpec
from t2m.data.normalization import Normalizer
from t2m.data.words import WordVectors
from t2m.models.autoencoder import MovementDecoder, MovementEncoder
from t2m.models.length import LengthEstimator
from t2m.models.temporal_vae import TemporalVAE


@dataclass
class LoadedModels:
    """What a :class:`~t2m.pipeline.TextToMotion` is made of (its arguments of the same names;
    :meth:`arguments`)."""

    vae: TemporalVAE
    decoder: MovementDecoder
    normalizer: Normalizer
    vectorizer: WordVectors
    initial_code: torch.Tensor
    spec: DatasetSpec
    length_model: LengthEstimator | None
    device: torch.device
    length_vectorizer: WordVectors | None = None
    training_words: Collection[str] | None = None
    encoder: MovementEncoder | None = None

    def arguments(self) -> dict[str, Any]:
        """The fields by name (not copied)."""
        return {field.name: getattr(self, field.name) for field in fields(self)}


def load_models(
    run_dir: str | Path,
    device: str = "cpu",
    need_length_model: bool = True,
    which: str = "best",
    glove_dir: str | Path | None = None,
) -> LoadedModels:
    """The ``generator`` (and ``length``) stages of a run folder with the autoencoder's encoder
    where trained, or the original T2M release's models from any folder of its layout
    (``glove_dir``: its GloVe subset, default ``glove/`` beside its ``checkpoints/``).

    Raises ValueError, one line naming the make target that trains a missing stage, when a
    stage is missing, unreadable or does not belong with the other.
    """
    from t2m.release import is_release_folder, load_release
    from t2m.train.runtime import resolve_device
    from t2m.train.stages import find_stage, load_stage

    run_dir = Path(run_dir)
    resolved = resolve_device(device)
    if is_release_folder(run_dir):
        release = load_release(run_dir, glove_dir, resolved, need_length_model)
        return LoadedModels(
            vae=release.vae,
            decoder=release.decoder,
            normalizer=release.normalizer,
            vectorizer=release.vectorizer,
            initial_code=release.initial_code,
            spec=release.spec,
            length_model=release.length_model,
            device=resolved,
            encoder=release.encoder,
        )
    if not run_dir.is_dir():
        raise ValueError(
            f"no checkpoint folder {run_dir} (train one with `make train-ae train-len "
            "train-t2m`, or pass --checkpoints DIR)"
        )
    retrain = {name: f"`make {find_stage(name).make_target}`" for name in ("generator", "length")}

    def load(stage: str):
        try:
            return load_stage(run_dir, stage, resolved, which)
        except ValueError as error:
            if "make " in str(error):  # it already says what to run
                raise
            raise UsageError(f"{error} (train it with {retrain[stage]})") from None

    t2m = load("generator")
    length = load("length") if need_length_model else None
    if t2m.vectorizer is None or t2m.initial_code is None:
        raise ValueError(
            f"{t2m.path}: incomplete generator checkpoint (retrain with {retrain['generator']})"
        )
    if length is not None:
        if length.vectorizer is None or not length.vectorizer.compatible(t2m.vectorizer):
            raise ValueError(
                f"{length.path} was trained with other word vectors than {t2m.path} "
                f"(retrain with {retrain['length']} on the same dataset)"
            )
        if length.spec != t2m.spec:
            raise ValueError(
                f"{length.path} was trained on {length.spec.name}, {t2m.path} "
                f"on {t2m.spec.name} (retrain with {retrain['length']})"
            )
    try:  # the frozen encoder of the autoencoder stage: only edits use it
        encoder = load_stage(run_dir, "autoencoder", resolved, which).models["autoencoder"]
        encoder = encoder.encoder
    except ValueError:
        encoder = None
    return LoadedModels(
        vae=t2m.models["vae"],
        decoder=t2m.models["decoder"],
        normalizer=t2m.normalizer,
        vectorizer=t2m.vectorizer,
        initial_code=t2m.initial_code,
        spec=t2m.spec,
        length_model=length.models["length"] if length else None,
        device=resolved,
        length_vectorizer=length.vectorizer if length else None,
        training_words=t2m.extra.get("training_words"),
        encoder=encoder,
    )
