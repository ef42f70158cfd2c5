"""Write our checkpoints in the original T2M release's layout: ``python -m t2m.release.export``.

    python -m t2m.release.export --checkpoints checkpoints/paper --out exported/

writes ``exported/checkpoints/<t2m|kit>/<name>/{model/latest.tar, meta/, opt.txt}``,
``length_est_bigru/``, ``text_mot_match/`` (each stage the run has) and ``exported/glove/`` (the
vocabulary in the release's format), with the release's keys and shapes (one table,
:mod:`t2m.release.keys`), so that the original code and the evaluator wrappers of later papers
load them strictly, and :func:`t2m.release.load_release` reads them back to identical outputs.
The optimiser entries (``opt_*``) are fresh Adam states: the files serve inference and
evaluation, not resuming the original's training.

A run is exported only when the original code would run it as we do
(:func:`release_incompatibilities`); otherwise the command stops with one line naming every
setting in the way and the overrides to retrain with. The original reads 300-d GloVe words, tags
captions with its own motion-word lists (``data.motion_words=release``), flips the backward word
features (``generator.model.text.flip_backward_words=true``; its format cannot record it), has
no count clock, progress code or count-reading length model, and builds its length estimator
(hidden 512, MLP 512, 256, 128, 50 classes) and evaluator (text hidden 512, motion hidden 1024,
embedding 512) at fixed sizes. The ``paper`` preset meets all of it. Generator and autoencoder
sizes are free: the original reads them from ``opt.txt``.
"""

from __future__ import annotations

import logging
import pickle
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np
import torch

from dataset_tools.command import (
    CommandParser,
    UsageError,
    command,
    option,
    parse_config,
)
from dataset_tools.io import atomic_write, save_npy_atomic, write_text_atomic
from dataset_tools.spec import HUMANML3D, KIT_ML
from t2m.data.normalization import Normalizer
from t2m.data.words import GLOVE_FOLDER_FILES, WordVectors
from t2m.lexicon import RELEASE_MOTION_WORDS
from t2m.models.temporal_vae import sinusoidal_table
from t2m.release.keys import (
    EVALUATOR_KEYS,
    GENERATOR_KEYS,
    LENGTH_KEYS,
    TABLE_ENTRIES,
    TABLE_KEY,
    ours_to_release,
)
from t2m.release.layout import (
    EVALUATOR_FOLDER,
    FLIP_OPTION,
    GENERATOR_FILE,
    LENGTH_FOLDER,
    format_opt,
)

logger = logging.getLogger(__name__)

RELEASE_DATASETS = {
    HUMANML3D.name: ("t2m", "Comp_v6_KLD01"),
    KIT_ML.name: ("kit", "Comp_v6_KLD005"),
}
"""Our dataset spec -> (the release's dataset folder, its generator's name)."""
TABLE_ROWS = 300
"""Rows of the sinusoidal table the release stores with each recurrent block."""
ORIGINAL_WORD_DIM = 300
"""The word-vector size the original code builds every text encoder with."""
ORIGINAL_LENGTH_SIZES = {"text.hidden_size": 512, "mlp_sizes": (512, 256, 128), "num_classes": 50}
"""The length estimator the original code builds, whatever ``opt.txt`` says (hidden 512, an MLP
of 512, 256, 128, and 200 // unit_length classes)."""
ORIGINAL_EVALUATOR_SIZES = {
    "text.hidden_size": 512,
    "motion_hidden_size": 1024,
    "embedding_size": 512,
}
"""The evaluator the original's wrapper (and the later papers' copies of it) builds."""
PAPER_WORDS = "--data.word_vectors=glove/glove.6B.300d.txt"


@dataclass(frozen=True)
class Incompatibility:
    """One setting of a run that the original code would not reproduce."""

    what: str
    """the setting and why, e.g. ``generator.model.count_clock=True (the release's ...)``"""
    fix: str
    """the override to retrain with, e.g. ``--generator.model.count_clock=false``"""


def _value(value: Any) -> str:
    return ",".join(map(str, value)) if isinstance(value, tuple) else str(value).lower()


def _sizes(section: str, model: Any, fixed: dict[str, Any], who: str) -> list[Incompatibility]:
    found = []
    for key, size in fixed.items():
        ours = model
        for part in key.split("."):
            ours = getattr(ours, part)
        ours = tuple(ours) if isinstance(size, tuple) else ours
        if ours != size:
            option = f"{section}.model.{key}"
            found.append(
                Incompatibility(
                    f"{option}={_value(ours)} ({who} fixes {_value(size)})",
                    f"--{option}={_value(size)}",
                )
            )
    return found


def release_incompatibilities(stages: dict[str, Any]) -> list[Incompatibility]:
    """Every setting of ``stages`` (stage name -> :class:`~t2m.train.TrainedStage`) that the
    original code would not reproduce: settings whose weights it cannot load, and settings whose
    weights it loads but computes with differently (which it would do silently)."""
    found: list[Incompatibility] = []
    vocabularies = [stage.vectorizer for stage in stages.values()]
    first = vocabularies[0]
    if first is None or first.trainable:
        found.append(
            Incompatibility(
                "data.word_vectors=trainable (the original reads pre-trained word vectors)",
                PAPER_WORDS,
            )
        )
    else:
        if first.dim != ORIGINAL_WORD_DIM:
            found.append(
                Incompatibility(
                    f"{first.dim}-d word vectors {Path(first.source).name} (the original's "
                    f"networks take {ORIGINAL_WORD_DIM}-d GloVe)",
                    PAPER_WORDS,
                )
            )
        if first.motion_words is not RELEASE_MOTION_WORDS:
            found.append(
                Incompatibility(
                    "data.motion_words=ours (the original tags captions with its own, shorter "
                    "motion-word lists)",
                    "--data.motion_words=release",
                )
            )
        if any(other is None or not first.compatible(other) for other in vocabularies[1:]):
            found.append(
                Incompatibility(
                    f"stages {', '.join(stages)} read different word vectors (the release "
                    "holds one glove/ for all)",
                    "one --data.word_vectors for every stage",
                )
            )
    if "generator" in stages:
        model = stages["generator"].config.generator.model
        if not model.text.flip_backward_words:
            found.append(
                Incompatibility(
                    "generator.model.text.flip_backward_words=false (the original flips the "
                    "backward word features; its format cannot say otherwise)",
                    "--generator.model.text.flip_backward_words=true",
                )
            )
        if model.count_clock:
            found.append(
                Incompatibility(
                    "generator.model.count_clock=true (the release's temporal VAE reads the "
                    "time to arrival only, no count clock)",
                    "--generator.model.count_clock=false",
                )
            )
        if model.progress_frequencies:
            found.append(
                Incompatibility(
                    f"generator.model.progress_frequencies={model.progress_frequencies} (the "
                    "release's temporal VAE reads the time to arrival only)",
                    "--generator.model.progress_frequencies=0",
                )
            )
    if "length" in stages:
        model = stages["length"].config.length.model
        if model.plan_inputs:
            found.append(
                Incompatibility(
                    "length.model.plan_inputs=true (the release's length estimator reads the "
                    "text only, not the caption's count)",
                    "--length.model.plan_inputs=false",
                )
            )
        found += _sizes("length", model, ORIGINAL_LENGTH_SIZES, "the original")
    if "evaluator" in stages:
        model = stages["evaluator"].config.evaluator.model
        found += _sizes("evaluator", model, ORIGINAL_EVALUATOR_SIZES, "the original's wrapper")
    return found


@dataclass
class ExportConfig:
    """``python -m t2m.release.export``: a run folder -> the T2M release layout."""

    checkpoints: Path = field(metadata=option(metavar="DIR"))
    """our run folder (its generator, length and evaluator stages, those it has)"""
    out: Path = field(metadata=option(metavar="DIR"))
    """folder to write checkpoints/ and glove/ into (must not hold a checkpoints/ already)"""
    name: str | None = None
    """the generator's folder name (default: Comp_v6_KLD01 for HumanML3D, Comp_v6_KLD005 for
    KIT-ML, as the release names them)"""
    which: Literal["best", "latest"] = "best"
    """which checkpoint of each stage"""


def _adam_state(num_parameters: int) -> dict[str, Any]:
    """A fresh Adam state for a module of ``num_parameters`` tensors (what ``opt_*`` hold)."""
    parameters = [torch.zeros(1, requires_grad=True) for _ in range(num_parameters)]
    return torch.optim.Adam(parameters, lr=1e-4).state_dict()


def _with_optimisers(
    entries: dict[str, dict[str, torch.Tensor]], optimised: dict[str, str]
) -> dict[str, Any]:
    """Release entries + ``opt_<name>`` for each optimised entry (``optimised``: opt name ->
    entry)."""
    out: dict[str, Any] = dict(entries)
    for opt_name, entry in optimised.items():
        count = sum(1 for key in entries[entry] if key != TABLE_KEY)
        out[opt_name] = _adam_state(count)
    return out


def _save(path: Path, checkpoint: dict[str, Any]) -> None:
    atomic_write(path, lambda handle: torch.save(checkpoint, handle))


def _state(module: torch.nn.Module) -> dict[str, torch.Tensor]:
    return {key: value.detach().cpu().float() for key, value in module.state_dict().items()}


def generator_checkpoint(stage, encoder: torch.nn.Module) -> dict[str, Any]:
    """The release's ``model/latest.tar`` of a generator stage (+ the autoencoder's encoder)."""
    models = {
        "vae": _state(stage.models["vae"]),
        "decoder": _state(stage.models["decoder"]),
        "encoder": _state(encoder),
    }
    entries = ours_to_release(models, GENERATOR_KEYS)
    hidden = stage.models["vae"].config.hidden_size
    for entry in TABLE_ENTRIES:
        entries[entry][TABLE_KEY] = sinusoidal_table(TABLE_ROWS, hidden)
    progress = stage.progress
    checkpoint = _with_optimisers(
        entries,
        {
            "opt_mov_dec": "mov_dec",
            "opt_text_enc": "text_enc",
            "opt_seq_pri": "seq_pri",
            "opt_att_layer": "att_layer",
            "opt_seq_post": "seq_post",
            "opt_seq_dec": "seq_dec",
        },
    )
    checkpoint.update(
        ep=int(progress.get("epoch", 0)),
        total_it=int(progress.get("step", 0)),
        sub_ep=0,
        sl_len=int(stage.config.generator.end_snippets),
    )
    return checkpoint


def length_checkpoint(stage) -> dict[str, Any]:
    """The release's ``length_est_bigru/model/latest.tar`` of a length stage."""
    entries = ours_to_release({"length": _state(stage.models["length"])}, LENGTH_KEYS)
    checkpoint = _with_optimisers(entries, {"opt_estimator": "estimator"})
    checkpoint.update(
        epoch=int(stage.progress.get("epoch", 0)), niter=int(stage.progress.get("step", 0))
    )
    return checkpoint


def evaluator_checkpoint(stage) -> dict[str, Any]:
    """The release's ``text_mot_match/model/finest.tar`` of an evaluator stage."""
    entries = ours_to_release({"evaluator": _state(stage.models["evaluator"])}, EVALUATOR_KEYS)
    checkpoint = _with_optimisers(
        entries, {"opt_text_encoder": "text_encoder", "opt_motion_encoder": "motion_encoder"}
    )
    checkpoint.update(
        epoch=int(stage.progress.get("epoch", 0)), iter=int(stage.progress.get("step", 0))
    )
    return checkpoint


def release_options(stages: dict[str, Any], name: str, dataset: str) -> dict[str, Any]:
    """The ``opt.txt`` entries the original's option reader and model builders use."""
    config = next(iter(stages.values())).config
    dims = next(iter(stages.values())).dims
    generator, evaluator = config.generator.model, config.evaluator.model
    return {
        "checkpoints_dir": "./checkpoints",
        "dataset_name": dataset,
        "name": name,
        "text_enc_mod": "bigru",
        "dim_word": dims.word_dim,
        "dim_pos_ohot": 15,
        "dim_text_hidden": generator.text.hidden_size,
        "dim_att_vec": generator.attention_size,
        "dim_z": generator.latent_size,
        "dim_pri_hidden": generator.hidden_size,
        "dim_pos_hidden": generator.hidden_size,
        "dim_dec_hidden": generator.hidden_size,
        "dim_movement_enc_hidden": config.autoencoder.model.hidden_size,
        "dim_movement_dec_hidden": config.autoencoder.model.hidden_size,
        "dim_movement_latent": config.autoencoder.model.code_size,
        "dim_pose": dims.feature_dim,
        "unit_length": 4,
        "max_text_len": config.data.max_text_tokens,
        "n_layers_pri": 1,
        "n_layers_pos": 1,
        "n_layers_dec": 1,
        "feat_bias": config.data.feature_bias,
        "dim_coemb_hidden": evaluator.embedding_size,
        "dim_motion_hidden": evaluator.motion_hidden_size,
        "dim_len_hidden": config.length.model.text.hidden_size,
        "num_classes": config.length.model.num_classes,
        "lambda_kld": config.generator.kl_weight,
        FLIP_OPTION: generator.text.flip_backward_words,
    }


def write_vocabulary(vectorizer: WordVectors, folder: Path) -> None:
    """The vocabulary as the release's GloVe folder: vectors (N, Dw), the words, word -> row."""
    data, words_file, index_file = (folder / name for name in GLOVE_FOLDER_FILES)
    save_npy_atomic(data, np.asarray(vectorizer.vectors, dtype=np.float32))
    words = list(vectorizer.words)
    atomic_write(words_file, lambda handle: pickle.dump(words, handle, protocol=4))
    index = {word: row for row, word in enumerate(words)}
    atomic_write(index_file, lambda handle: pickle.dump(index, handle, protocol=4))


def _check_exportable(stages: dict, name: str | None) -> tuple[str, str]:
    """Refuse (UsageError, one line) a run the release layout cannot hold or the original code
    would not run as we do (naming every such setting and the overrides to retrain with);
    returns the dataset's folder and the generator's folder name."""
    first = next(iter(stages.values()))
    if first.spec.name not in RELEASE_DATASETS:
        raise UsageError(f"the release layout holds HumanML3D or KIT-ML, not {first.spec.name}")
    dataset, default_name = RELEASE_DATASETS[first.spec.name]
    name = name or default_name
    if name in (LENGTH_FOLDER, EVALUATOR_FOLDER) or not name or "/" in name:
        raise UsageError(f"--name {name!r} is not a generator folder name")
    found = release_incompatibilities(stages)
    if found:
        fixes = " ".join(dict.fromkeys(item.fix for item in found))
        raise UsageError(
            "the original code would not run this export as we do: "
            + "; ".join(item.what for item in found)
            + f" (retrain with {fixes}, or start from --preset paper)"
        )
    return dataset, name


def export_release(
    run_dir: str | Path, out: str | Path, name: str | None = None, which: str = "best"
) -> Path:
    """Write the run's generator, length and evaluator stages (those it has), ``meta/`` and the
    vocabulary in the release layout under ``out``; returns the dataset folder
    (``out/checkpoints/<t2m|kit>``). UsageError (one line) for what the layout cannot hold."""
    from t2m.train.stages import load_stage

    run_dir, out = Path(run_dir), Path(out)
    if (out / "checkpoints").exists() or (out / "glove").exists():
        raise UsageError(f"{out} already holds checkpoints/ or glove/: choose an empty --out")
    # 1. the stages this run has
    stages = {}
    for stage in ("generator", "length", "evaluator"):
        try:
            stages[stage] = load_stage(run_dir, stage, "cpu", which)
        except UsageError:
            logger.info("no %s stage in %s: not exported", stage, run_dir)
    if not stages:
        raise UsageError(f"{run_dir}: no generator, length or evaluator stage to export")
    dataset, name = _check_exportable(stages, name)
    first = next(iter(stages.values()))
    vectorizer = first.vectorizer
    # 2. the checkpoints, each beside its opt.txt
    dataset_dir = out / "checkpoints" / dataset
    options = release_options(stages, name, dataset)
    generator_dir = dataset_dir / name
    files: dict[Path, dict[str, Any]] = {}
    if "generator" in stages:
        autoencoder = load_stage(run_dir, "autoencoder", "cpu", which).models["autoencoder"]
        files[generator_dir / GENERATOR_FILE] = generator_checkpoint(
            stages["generator"], autoencoder.encoder
        )
    if "length" in stages:
        files[dataset_dir / LENGTH_FOLDER / "model" / "latest.tar"] = length_checkpoint(
            stages["length"]
        )
    if "evaluator" in stages:
        files[dataset_dir / EVALUATOR_FOLDER / "model" / "finest.tar"] = evaluator_checkpoint(
            stages["evaluator"]
        )
    for path, checkpoint in files.items():
        path.parent.mkdir(parents=True, exist_ok=True)
        _save(path, checkpoint)
        folder = path.parent.parent
        write_text_atomic(folder / "opt.txt", format_opt({**options, "name": folder.name}))
    # 3. the normalisation every model of the release reads (meta/ of the generator's folder)
    normalizer: Normalizer = first.normalizer
    (generator_dir / "meta").mkdir(parents=True, exist_ok=True)
    save_npy_atomic(generator_dir / "meta" / "mean.npy", normalizer.mean.astype(np.float64))
    save_npy_atomic(generator_dir / "meta" / "std.npy", normalizer.std.astype(np.float64))
    if not (generator_dir / "opt.txt").is_file():
        write_text_atomic(generator_dir / "opt.txt", format_opt(options))
    # 4. the vocabulary
    (out / "glove").mkdir(parents=True, exist_ok=True)
    write_vocabulary(vectorizer, out / "glove")
    logger.info("wrote %s (%s) and %s", dataset_dir, ", ".join(stages), out / "glove")
    return dataset_dir


@command
def main(argv: list[str] | None = None) -> int:
    parser = CommandParser(
        prog="python -m t2m.release.export",
        description="Write a run's generator, length estimator, evaluator, normalisation and "
        "vocabulary in the original T2M release's layout.",
    )
    config = parse_config(parser, ExportConfig, argv)
    export_release(config.checkpoints, config.out, config.name, config.which)
    return 0


if __name__ == "__main__":
    sys.exit(main())
