"""The evaluation protocol of Guo et al. (CVPR 2022), Table 2, on any :class:`Backend`.

This module owns the settings (:class:`EvalConfig`, the standard protocol and the quick mode),
drawing the test items, the replications and the metric rows (:func:`run_protocol`), and the
plug-in interface through which a dataset's own scorer (:class:`Scorer`, :func:`find_scorer`)
adds semantic accuracy to the rows. Formulas are in :mod:`t2m.evaluate.metrics`, the summary and
the table in :mod:`t2m.evaluate.report`, the trained models in :mod:`t2m.evaluate.backend`.

The protocol, per replication (each with its own seed):

1. Every test item (a clip, or a captioned sub-clip) gets one of its captions at random and a crop
   to whole 4-frame units (one unit fewer with probability 1/3) from a random start, in a random
   order; rows that do not fill a last pool of 32 are left out. Such a draw is made four times:
   the reference real motions (their embedding statistics are the FID reference), the "Real
   motions" row, and the captions of the two generated rows.
2. "Ours (ground-truth length)" generates one motion per item at the item's cropped length;
   "Ours (sampled length)" lets the text2length model draw each length.
3. Per row, on the evaluator's embeddings: R-precision top 1/2/3 (pools of 32; each caption
   ranks the pool's motions, as the original code does), FID against the reference, MM-Dist,
   Diversity (300 pairs). MultiModality (generated rows only): the first ``mm_texts`` items of
   the row's draw get ``mm_samples`` generations each (the row's own generation is the first),
   10 pairs per caption.
4. Each metric is reported as mean and 95% interval ``1.96 sigma / sqrt(replications)``.
5. Physical quality of every row's motions (foot skating, jerk, penetration, floating; see
   :mod:`dataset_tools.physical`), the jerk curve compared with the reference draw's.

Unlike the original, generation is batched. When the dataset comes with a scorer (the procedural
demo corpus does: ``dataset_tools.synth.scoring``), a row also reports semantic accuracy: how
often the corpus' own label detectors recover an item's labels.
"""

from __future__ import annotations

import dataclasses
import functools
import importlib
import time
from collections.abc import Callable, Collection, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal, Protocol

import numpy as np
from tqdm import tqdm

from dataset_tools import physical
from dataset_tools.command import UsageError, option
from dataset_tools.rigid import finish_features
from dataset_tools.spec import HUMANML3D, DatasetSpec
from t2m.config import check_seed, check_threads
from t2m.data.dataset import Caption, Clip
from t2m.evaluate import metrics
from t2m.evaluate.backend import Backend
from t2m.streams import EvalStream, GenerationStream, stream_rng, stream_seed

REAL = "Real motions"
GT_LENGTH = "Ours (ground-truth length)"
SAMPLED_LENGTH = "Ours (sampled length)"
ROWS = (REAL, GT_LENGTH, SAMPLED_LENGTH)
"""The protocol's rows; the generated ones with the evaluation's plan (``EvalConfig.plan``)."""

PLANS = ("clauses", "whole")
PLAN_NAMES = {"clauses": "clause by clause", "whole": "one pass"}
PAPER_PLAN = "whole"
"""The paper's protocol generates every caption in one pass."""


def plan_row(row: str, plan: str) -> str:
    """The name of a generated row made with the other plan: ``Ours (ground-truth length, one
    pass)``, ``Ours (sampled length, clause by clause)``."""
    return f"{row[:-1]}, {PLAN_NAMES[plan]})"


def other_plan(plan: str) -> str:
    return "whole" if plan == "clauses" else "clauses"


METRICS = (
    "r_precision_top1",
    "r_precision_top2",
    "r_precision_top3",
    "fid",
    "mm_dist",
    "diversity",
    "multimodality",
)
# Kept in results.json only: R-precision with each motion ranking the pool's captions.
EXTRA_METRICS = (
    "r_precision_motion_query_top1",
    "r_precision_motion_query_top2",
    "r_precision_motion_query_top3",
)


@dataclass
class EvalConfig:
    """Settings of one evaluation; the defaults are the standard protocol.

    Each field's docstring is its ``python -m t2m.evaluate`` help; impossible values raise
    :class:`~dataset_tools.command.UsageError` (a ``ValueError``) naming the option.
    """

    split: str = "test"
    """split file of the dataset to evaluate on (<split>.txt)"""
    replications: int = field(default=20, metadata=option(metavar="N"))
    """independent repetitions, each regenerating everything with its own seed (default 20; 3
    with --quick)"""
    mm_texts: int = field(default=100, metadata=option(metavar="N"))
    """captions used for MultiModality (default 100; 16 with --quick)"""
    mm_samples: int = field(default=30, metadata=option(metavar="N"))
    """generations per MultiModality caption, at least 2 (default 30; 10 with --quick)"""
    pool_size: int = field(default=metrics.R_PRECISION_BATCH_SIZE, metadata=option(metavar="N"))
    """R-precision pool: each caption ranks its motion among this many motions"""
    diversity_pairs: int = field(default=metrics.DIVERSITY_PAIRS, metadata=option(metavar="N"))
    """random pairs of motions whose mean distance is the Diversity"""
    mm_pairs: int = field(default=metrics.MULTIMODALITY_PAIRS, metadata=option(metavar="N"))
    """random pairs of generations per caption whose mean distance is the MultiModality"""
    max_items: int | None = field(default=None, metadata=option(metavar="N"))
    """evaluate at most this many items of the split (default: all of it; 224 with --quick)"""
    batch_size: int = field(default=128, metadata=option(metavar="N"))
    """items per generation / embedding forward pass (speed only; raise it on a GPU)"""
    num_threads: int = field(default=0, metadata=option("--threads", metavar="N"))
    """torch CPU threads (0: torch's choice; on a small shared CPU, 1 is often fastest)"""
    seed: int = 0
    """seed of replication 0; each replication derives its own from it"""
    device: str = "auto"
    """device of the evaluator and the generator: auto, cpu, cuda or cuda:N (auto: CUDA when
    present, the CPU for int8)"""
    which: Literal["best", "latest"] = "best"
    """checkpoint of each stage"""
    precision: Literal["fp32", "bf16", "int8"] = "fp32"
    """generator precision (bf16 and int8 are marked as deviations; int8 runs on the CPU); the
    evaluator always runs in float32"""
    quick: bool = False
    """development run: few replications on a subset, marked as such in every output"""
    plan: Literal["clauses", "whole"] = "clauses"
    """how a caption is generated: clauses (a caption of several clauses clause by clause, as
    t2m.sample and the web app do; t2m.clauses) or whole (one pass, as the paper evaluates)"""
    both_plans: bool = True
    """also table the row generated with the other plan at ground-truth lengths, named (Ours
    (ground-truth length, one pass)), where it differs on the split's captions (some caption
    reads as several clauses): the same items, captions, lengths and seeds, without
    MultiModality"""
    min_segments: int = field(default=30, metadata=option(metavar="N"))
    """when a replication evaluates a subset of the split (--max-items), draw it so that every
    action the dataset's labels name has at least N segments in it (the demo corpus; 0: a
    uniform draw); the subset grows by whole R-precision pools where --max-items is too few"""
    clean: bool = False
    """finish generated motions as t2m.sample does by default (rigid on the model's skeleton,
    dataset_tools.rigid, then the foot-contact clean-up, dataset_tools.cleanup) before they are
    embedded and scored; the standard protocol judges the raw model output"""

    def __post_init__(self) -> None:
        at_least = {
            "replications": 1,
            "mm_texts": 1,
            "mm_samples": 2,  # MultiModality compares generations of one caption
            "pool_size": 3,  # R-precision reports the top 3
            "diversity_pairs": 1,
            "mm_pairs": 1,
            "max_items": 1,
            "batch_size": 1,
            "num_threads": 0,
            "min_segments": 0,
        }
        for key, least in at_least.items():
            value = getattr(self, key)
            if value is not None and value < least:
                name = "threads" if key == "num_threads" else key.replace("_", "-")
                raise UsageError(f"--{name} must be >= {least}, got {value}")
        check_seed(self.seed)
        check_threads(self.num_threads)


STANDARD = EvalConfig()

# What --quick changes; explicit command-line values win. 224 items (7 R-precision pools): a draw
# of the demo corpus' test split with at least 30 segments of every action (min_segments) needs
# 194-197 (stratified_subset).
QUICK_SETTINGS = {"replications": 3, "max_items": 224, "mm_texts": 16, "mm_samples": 10}


def quick_config(config: EvalConfig, keep: Collection[str] = ()) -> EvalConfig:
    """The config with the quick-mode reductions applied (never raising a value) to the
    :data:`QUICK_SETTINGS` not named in ``keep`` (those the user chose)."""
    changes: dict[str, Any] = {"quick": True}
    for key, value in QUICK_SETTINGS.items():
        current = getattr(config, key)
        if key not in keep:
            changes[key] = value if current is None else min(current, value)
    return dataclasses.replace(config, **changes)


def deviations(
    config: EvalConfig, num_items: int, plans_differ: bool = True, stratified: bool = False
) -> list[str]:
    """Human-readable differences between the effective settings and the standard protocol
    (the paper's). ``plans_differ``: the clause plan generates some caption of the split
    otherwise than one pass; ``stratified``: the subset was drawn per action
    (``min_segments``)."""
    notes = []
    if config.quick:
        notes.append(
            "QUICK MODE: development run on a subset, not comparable with published numbers"
        )
    for key in (
        "split",
        "replications",
        "mm_texts",
        "mm_samples",
        "pool_size",
        "mm_pairs",
        "precision",
        "clean",
    ):
        value, standard = getattr(config, key), getattr(STANDARD, key)
        if value != standard:
            notes.append(f"{key} = {value} (standard: {standard})")
    if config.plan != PAPER_PLAN and plans_differ:
        paper_rows = (
            f"; the paper's generation is the '{PLAN_NAMES[PAPER_PLAN]}' row"
            if config.both_plans
            else ""
        )
        notes.append(
            f"plan = {config.plan}: captions of several clauses generated "
            f"{PLAN_NAMES[config.plan]}, as t2m.sample does (the paper: {PAPER_PLAN}){paper_rows}"
        )
    if config.max_items is not None:
        how = (
            f", drawn so that every action has at least {config.min_segments} segments"
            if stratified
            else ""
        )
        notes.append(
            f"only {num_items} items of the split evaluated (max_items = {config.max_items}{how})"
        )
    pairs = min(config.diversity_pairs, num_items)
    if pairs != STANDARD.diversity_pairs:
        notes.append(f"diversity over {pairs} pairs (standard: {STANDARD.diversity_pairs})")
    return notes


# ----------------------------------------------------------------------------------------------
# drawing the test items


@dataclass(frozen=True)
class Draw:
    """One pass over the test items: which item, caption and crop each row uses.

    Attributes (all (N,) int64): ``items`` indices into the clips, ``captions`` index of the
    caption within the clip, ``starts`` first frame, ``lengths`` frames (multiples of the unit).
    """

    items: np.ndarray
    captions: np.ndarray
    starts: np.ndarray
    lengths: np.ndarray

    def caption_list(self, clips: Sequence[Clip]) -> list[Caption]:
        return [clips[i].captions[c] for i, c in zip(self.items, self.captions, strict=True)]

    def motion_list(self, clips: Sequence[Clip]) -> list[np.ndarray]:
        """The cropped raw features, (lengths[k], D) each."""
        return [
            clips[i].motion[s : s + n]
            for i, s, n in zip(self.items, self.starts, self.lengths, strict=True)
        ]


def draw_items(
    clips: Sequence[Clip],
    num_rows: int,
    rng: np.random.Generator,
    spec: DatasetSpec = HUMANML3D,
    candidates: np.ndarray | None = None,
) -> Draw:
    """Draw ``num_rows`` distinct items in random order, a caption and a unit crop for each.

    Items come from ``candidates`` (indices into ``clips``; default: all clips). The crop keeps
    ``min(T, max_frames) // unit`` units (snippets of the dataset ``spec``), one fewer with
    probability 1/3 (the original evaluation loader's rule), from a uniformly random start.
    """
    unit_length, max_frames = spec.snippet_length, spec.max_frames
    candidates = np.arange(len(clips)) if candidates is None else np.asarray(candidates)
    if num_rows > len(candidates):
        raise ValueError(f"cannot draw {num_rows} items from {len(candidates)} clips")
    items = candidates[rng.permutation(len(candidates))[:num_rows]]
    captions = np.empty(num_rows, dtype=np.int64)
    starts = np.empty(num_rows, dtype=np.int64)
    lengths = np.empty(num_rows, dtype=np.int64)
    for row, index in enumerate(items):
        clip = clips[index]
        captions[row] = rng.integers(len(clip.captions))
        units = min(len(clip.motion), max_frames) // unit_length
        if units > 1 and rng.random() < 1 / 3:
            units -= 1
        if units < 1:
            raise ValueError(f"clip {clip.name} is shorter than one {unit_length}-frame unit")
        lengths[row] = units * unit_length
        starts[row] = rng.integers(0, len(clip.motion) - lengths[row] + 1)
    return Draw(items.astype(np.int64), captions, starts, lengths)


def stratified_subset(
    labels: Sequence[Sequence[str]],
    size: int,
    min_count: int,
    rng: np.random.Generator,
    multiple: int = 1,
) -> np.ndarray:
    """Indices of a random subset of the items in which every label occurs at least
    ``min_count`` times (or as often as all the items hold it), filled up at random to ``size``
    items, or to the next multiple of ``multiple`` above what the labels need.

    ``labels[i]``: the labels of item i, one per occurrence (an item of two walks and a wave:
    ``["walk", "wave", "walk"]``). Labels are served from the rarest up, each by the items that
    hold it, first those that also hold the most labels still short (so fewer items serve them
    all: 194-197 of the demo corpus' 600 test items for 30 segments of each of its 14 actions,
    250-262 taking the items in random order), ties in random order; the result's order is
    random.
    """
    order = rng.permutation(len(labels))
    totals: dict[str, int] = {}
    for item_labels in labels:
        for label in item_labels:
            totals[label] = totals.get(label, 0) + 1
    target = {label: min(min_count, total) for label, total in totals.items()}
    counts = dict.fromkeys(totals, 0)
    chosen: list[int] = []
    taken = np.zeros(len(labels), dtype=bool)
    for label in sorted(totals, key=lambda name: (totals[name], name)):
        while counts[label] < target[label]:
            best, best_short = -1, -1
            for index in order:
                if taken[index] or label not in labels[index]:
                    continue
                short = sum(counts[held] < target[held] for held in set(labels[index]))
                if short > best_short:
                    best, best_short = int(index), short
            taken[best] = True
            chosen.append(best)
            for held in labels[best]:
                counts[held] += 1
    needed = -(-len(chosen) // multiple) * multiple
    size = min(len(labels), max(size, needed))
    chosen += [int(index) for index in order if not taken[index]][: max(0, size - len(chosen))]
    return np.asarray(chosen, dtype=np.int64)[rng.permutation(len(chosen))]


# ----------------------------------------------------------------------------------------------
# scorers: what a dataset itself can tell about the motions of a row


class Scorer(Protocol):
    """Scores motions against what the dataset knows of its items (e.g. the demo corpus' labels).

    A scorer that also has ``segments_for(name) -> list[dict] | None`` (an item's labelled
    segments, each with its ``"action"``; None for an item it does not know) lets the
    evaluation draw a subset with enough segments of every action (``EvalConfig.min_segments``,
    :func:`item_actions`)."""

    def __call__(self, names: Sequence[str], motions: Sequence[np.ndarray]) -> dict[str, float]:
        """Item names and their motions as raw features (T_i, D) -> accuracies by name: ``all``
        is tabled as semantic accuracy, ``action_<name>`` listed per action, others kept in
        results.json. Empty when none of the items can be scored."""
        ...


SCORER_PLUGINS = ("dataset_tools.synth.scoring",)
"""Modules that define ``scorer_for(dataset_dir: Path) -> Scorer | None``, asked in this order."""


def item_actions(scorer: Scorer | None, names: Sequence[str]) -> list[list[str]] | None:
    """The action of every labelled segment of each named item (the scorer's
    ``segments_for``), or None when the scorer knows no item's segments."""
    segments_for = getattr(scorer, "segments_for", None)
    if segments_for is None:
        return None
    actions = []
    for name in names:
        segments = segments_for(name) or []
        actions.append([str(segment["action"]) for segment in segments])
    return actions if any(actions) else None


def find_scorer(dataset_dir: str | Path) -> Scorer | None:
    """The scorer of the first plug-in that knows the dataset in ``dataset_dir``, else None."""
    for module in SCORER_PLUGINS:
        scorer = importlib.import_module(module).scorer_for(Path(dataset_dir))
        if scorer is not None:
            return scorer
    return None


# ----------------------------------------------------------------------------------------------
# the protocol


@dataclass
class ProtocolResult:
    """Per row, per metric, the value of each replication; plus timings and settings."""

    values: dict[str, dict[str, list[float]]]
    semantic: dict[str, dict[str, list[float]]]
    num_items: int
    num_available: int
    config: EvalConfig
    timings_s: dict[str, float] = field(default_factory=dict)
    physical: dict[str, dict[str, list[float]]] = field(default_factory=dict)
    """Per row, per figure of :mod:`dataset_tools.physical`, the value of each replication."""
    rows: tuple[str, ...] = ROWS
    """The rows, in table order: :data:`ROWS`, then the other plan's with ground-truth lengths
    (:func:`plan_row`)."""
    plans_differ: bool = False
    """Whether the clause plan generates some caption of the split otherwise than one pass."""
    stratified: bool = False
    """Whether each replication's subset was drawn per action (``min_segments``)."""


class _Timer:
    """Accumulates wall time per kind of work: ``timer("embed_s", fn, *args)`` calls ``fn``."""

    def __init__(self, *keys: str):
        self.seconds = dict.fromkeys(keys, 0.0)

    def __call__(self, key: str, fn: Callable[..., Any], *args: Any) -> Any:
        start = time.perf_counter()
        out = fn(*args)
        self.seconds[key] += time.perf_counter() - start
        return out


def _row_metrics(
    text: np.ndarray,
    motion: np.ndarray,
    reference: metrics.GaussianStats,
    config: EvalConfig,
    rng: np.random.Generator,
) -> dict[str, float]:
    top = metrics.r_precision(text, motion, 3, config.pool_size, query="text")
    by_motion = metrics.r_precision(text, motion, 3, config.pool_size, query="motion")
    motion_stats = metrics.gaussian_statistics(motion)
    return {
        "r_precision_top1": float(top[0]),
        "r_precision_top2": float(top[1]),
        "r_precision_top3": float(top[2]),
        "r_precision_motion_query_top1": float(by_motion[0]),
        "r_precision_motion_query_top2": float(by_motion[1]),
        "r_precision_motion_query_top3": float(by_motion[2]),
        "fid": metrics.frechet_distance(
            motion_stats.mean, motion_stats.covariance, reference.mean, reference.covariance
        ),
        "mm_dist": metrics.multimodal_distance(text, motion),
        "diversity": metrics.diversity(
            motion, num_pairs=min(config.diversity_pairs, len(motion)), rng=rng
        ),
    }


def _multimodality(
    backend: Backend,
    captions: list[Caption],
    lengths: np.ndarray | None,
    first_generation: np.ndarray,
    config: EvalConfig,
    seed: int,
    rng: np.random.Generator,
    timer: _Timer,
) -> float:
    """MultiModality of the first ``mm_texts`` rows: their own generation plus
    ``mm_samples - 1`` more each, generated in one batched call."""
    num_texts = min(config.mm_texts, len(captions))
    extra = config.mm_samples - 1
    repeated = [captions[k] for k in range(num_texts) for _ in range(extra)]
    repeated_lengths = None if lengths is None else np.repeat(lengths[:num_texts], extra)
    generated = timer("generate_s", backend.generate, repeated, repeated_lengths, seed)
    more = timer("embed_s", backend.embed_motions, generated)
    more = more.reshape(num_texts, extra, -1)  # (C, S - 1, E)
    samples = np.concatenate([first_generation[:num_texts, None], more], axis=1)  # (C, S, E)
    return metrics.multimodality(
        samples, num_pairs=min(config.mm_pairs, config.mm_samples), rng=rng
    )


class CleanedBackend:
    """A :class:`Backend` whose generated motions (raw features) are finished as ``t2m.sample``
    finishes them (:func:`dataset_tools.rigid.finish_features`: rigid on the model's skeleton,
    then the foot-contact clean-up)."""

    def __init__(self, backend: Backend):
        self.backend = backend

    def embed_texts(self, captions: Sequence[Caption]) -> np.ndarray:
        return self.backend.embed_texts(captions)

    def embed_motions(self, motions: Sequence[np.ndarray]) -> np.ndarray:
        return self.backend.embed_motions(motions)

    def generate(
        self, captions: Sequence[Caption], lengths: np.ndarray | None, seed: int
    ) -> list[np.ndarray]:
        return [finish_features(f) for f in self.backend.generate(captions, lengths, seed)]


def check_memory(num_items: int, config: EvalConfig, spec: DatasetSpec) -> None:
    """Refuse, before the first replication, settings whose generations cannot fit in memory:
    a generated row (``num_items`` motions) and the MultiModality generations
    (``mm_texts x (mm_samples - 1)`` motions, made in one call) are held as features of up to
    the dataset's longest motion. UsageError naming the options to lower."""
    from t2m.train.runtime import available_memory

    available = available_memory()
    mm_motions = min(config.mm_texts, num_items) * (config.mm_samples - 1)
    motions = max(num_items, mm_motions)
    needed = 2 * 4 * motions * spec.max_frames * spec.feature_dim  # features, and a copy
    if available is not None and needed > available:
        raise UsageError(
            f"{motions} generations at once need about {needed / 2**30:.1f} GiB of memory, "
            f"{available / 2**30:.1f} GiB is available; lower --mm-texts or --mm-samples "
            "(or --max-items)"
        )


def _item_counts(num_clips: int, config: EvalConfig) -> tuple[int, int]:
    """(clips a replication draws from: all or ``max_items``, items a row draws: whole
    R-precision pools of them); UsageError when that is not one pool."""
    available = num_clips if config.max_items is None else min(num_clips, config.max_items)
    num_items = (available // config.pool_size) * config.pool_size
    if num_items == 0:
        if available < num_clips:  # the split would do: the user asked for too few
            raise UsageError(
                f"--max-items {config.max_items} is fewer than one R-precision pool of "
                f"{config.pool_size} items (raise --max-items or lower --pool-size)"
            )
        raise UsageError(
            f"the {config.split} split has {num_clips} usable items; R-precision needs at least "
            f"one pool of {config.pool_size} (lower --pool-size or evaluate a larger split)"
        )
    return available, num_items


def _generated_row(
    backend: Backend,
    captions: list[Caption],
    lengths: np.ndarray | None,
    reference: metrics.GaussianStats,
    config: EvalConfig,
    stream: tuple[int, int],
    metric_rng: np.random.Generator,
    timed: _Timer,
    multimodality: bool = True,
) -> tuple[dict[str, float], list]:
    """One generated row of a replication: motions for ``captions`` (at ``lengths``, or at
    lengths the model draws), their metrics against ``reference`` and (with ``multimodality``)
    their multimodality; ``stream`` is (replication, row) of their generation seeds. Returns
    the row's values and the motions."""
    rep, variant = stream
    generated = timed(
        "generate_s",
        backend.generate,
        captions,
        lengths,
        stream_seed(GenerationStream.MOTIONS, config.seed, rep, variant),
    )
    text = timed("embed_s", backend.embed_texts, captions)
    motion = timed("embed_s", backend.embed_motions, generated)
    row = timed("metrics_s", _row_metrics, text, motion, reference, config, metric_rng)
    if not multimodality:
        return row, generated
    row["multimodality"] = _multimodality(
        backend,
        captions,
        lengths,
        motion,
        config,
        stream_seed(GenerationStream.MULTIMODALITY, config.seed, rep, variant),
        metric_rng,
        timed,
    )
    return row, generated


def _stratified_subsets(
    clips: Sequence[Clip],
    num_items: int,
    available: int,
    config: EvalConfig,
    semantic: Scorer | None,
) -> list[np.ndarray] | None:
    """Each replication's subset of the clips drawn with at least ``min_segments`` segments of
    every action (:func:`stratified_subset`), all of one size (whole pools), or None: the whole
    split is evaluated, ``min_segments`` is 0, or the scorer knows no segments."""
    if not config.min_segments or available == len(clips):
        return None
    actions = item_actions(semantic, [clip.name for clip in clips])
    if actions is None:
        return None

    def draw(size: int) -> list[np.ndarray]:
        return [
            stratified_subset(
                actions,
                size,
                config.min_segments,
                stream_rng(EvalStream.ITEMS, config.seed, rep),
                config.pool_size,
            )
            for rep in range(config.replications)
        ]

    subsets = draw(num_items)
    largest = max(len(subset) for subset in subsets)
    if largest > num_items:  # some draw needed more: every replication takes as many
        subsets = draw(largest)
    size = (min(len(subset) for subset in subsets) // config.pool_size) * config.pool_size
    return [subset[:size] for subset in subsets]


def run_protocol(
    clips: Sequence[Clip],
    backend: Backend,
    config: EvalConfig,
    spec: DatasetSpec = HUMANML3D,
    semantic: Scorer | None = None,
) -> ProtocolResult:
    """Run ``config.replications`` replications of the protocol on ``clips`` (raw features of the
    dataset ``spec``: its snippet length and longest motion decide the crops).

    ``semantic`` (see :func:`find_scorer`) adds its scores of every row's motions. Returns the
    per-replication values; :func:`~t2m.evaluate.report.summarize` turns them into means and
    intervals.
    """
    available, num_items = _item_counts(len(clips), config)
    subsets = _stratified_subsets(clips, num_items, available, config, semantic)
    if subsets is not None:
        available = num_items = len(subsets[0])
    check_memory(num_items, config, spec)
    # the other plan's rows, where it generates some caption otherwise
    other = None
    with_plan = getattr(backend, "with_plan", None)
    if config.both_plans and with_plan is not None:
        captions = [caption for clip in clips for caption in clip.captions]
        if backend.plans_differ(captions):  # type: ignore[attr-defined]
            other = with_plan(other_plan(config.plan))
    if config.clean:
        backend = CleanedBackend(backend)
        other = None if other is None else CleanedBackend(other)
    # with ground-truth lengths only: the plans then differ in generation alone, and the
    # evaluation stays within make demo's time (each generated row is about a fifth of it)
    other_rows = {}
    if other is not None:
        other_rows = {GT_LENGTH: plan_row(GT_LENGTH, other_plan(config.plan))}
    rows = ROWS + tuple(other_rows.values())
    values = {
        row: {
            name: []
            for name in METRICS + EXTRA_METRICS
            if row in (GT_LENGTH, SAMPLED_LENGTH) or name != "multimodality"
        }
        for row in rows
    }
    semantic_values: dict[str, dict[str, list[float]]] = {row: {} for row in rows}
    timed = _Timer("generate_s", "embed_s", "metrics_s", "semantic_s", "physical_s")
    physical_values: dict[str, dict[str, list[float]]] = {row: {} for row in rows}
    # Physical figures need joints: only motions that are the spec's features have them.
    measure_physics = clips[0].motion.shape[-1] == spec.feature_dim

    def row_physics(motions: Sequence[np.ndarray]) -> physical.RowPhysics | None:
        if not measure_physics:
            return None
        return timed("physical_s", physical.row_physics, motions, spec.fps)

    def add_semantic(row: str, draw: Draw, motions: Sequence[np.ndarray]) -> None:
        if semantic is None:
            return
        names = [clips[i].name for i in draw.items]
        scores = timed("semantic_s", semantic, names, motions)
        for key, value in scores.items():
            semantic_values[row].setdefault(key, []).append(float(value))

    total_start = time.perf_counter()
    for rep in tqdm(range(config.replications), desc="replications", unit="rep"):
        rng = stream_rng(EvalStream.ITEMS, config.seed, rep)
        metric_rng = stream_rng(EvalStream.METRICS, config.seed, rep)
        # the other plan's rows draw their pairs apart, so that they leave the plan's as they are
        other_metric_rng = stream_rng(EvalStream.METRICS, config.seed, rep, 1)

        # A subset (max_items) is drawn once per replication, so that the reference, the real
        # row and the generated rows all describe the same clips.
        if subsets is not None:
            candidates = subsets[rep]
            rng = stream_rng(EvalStream.ITEMS, config.seed, rep, 1)  # the crops, after the subset
        elif available == len(clips):
            candidates = None
        else:
            candidates = rng.permutation(len(clips))[:available]
        new_draw = functools.partial(draw_items, clips, num_items, rng, spec, candidates)

        reference_draw = new_draw()
        reference_motions = reference_draw.motion_list(clips)
        reference = metrics.gaussian_statistics(
            timed("embed_s", backend.embed_motions, reference_motions)
        )
        physics: dict[str, Any] = {}  # row -> physical.RowPhysics of this replication
        reference_physics = row_physics(reference_motions)

        real_draw = new_draw()
        real_motions = real_draw.motion_list(clips)
        text = timed("embed_s", backend.embed_texts, real_draw.caption_list(clips))
        motion = timed("embed_s", backend.embed_motions, real_motions)
        row = timed("metrics_s", _row_metrics, text, motion, reference, config, metric_rng)
        for name, value in row.items():
            values[REAL][name].append(value)
        add_semantic(REAL, real_draw, real_motions)
        physics[REAL] = row_physics(real_motions)

        for variant, row_name in enumerate((GT_LENGTH, SAMPLED_LENGTH)):
            draw = new_draw()
            row, generated = _generated_row(
                backend,
                draw.caption_list(clips),
                draw.lengths if row_name == GT_LENGTH else None,
                reference,
                config,
                (rep, variant),
                metric_rng,
                timed,
            )
            for name, value in row.items():
                values[row_name][name].append(value)
            add_semantic(row_name, draw, generated)
            physics[row_name] = row_physics(generated)
            if row_name in other_rows:  # the same items, captions, lengths and seed; other plan
                other_name = other_rows[row_name]
                row, generated = _generated_row(
                    other,
                    draw.caption_list(clips),
                    draw.lengths,
                    reference,
                    config,
                    (rep, variant),
                    other_metric_rng,
                    timed,
                    multimodality=False,
                )
                for name, value in row.items():
                    values[other_name][name].append(value)
                add_semantic(other_name, draw, generated)
                physics[other_name] = row_physics(generated)
        if reference_physics is not None:
            figures = physical.rows_physics(physics, reference_physics, spec.fps)
            for row_name, row_figures in figures.items():
                for key, value in row_figures.items():
                    physical_values[row_name].setdefault(key, []).append(value)
    timings = dict(timed.seconds, total_s=time.perf_counter() - total_start)
    return ProtocolResult(
        values=values,
        semantic=semantic_values,
        num_items=num_items,
        num_available=len(clips),
        config=config,
        timings_s=timings,
        physical=physical_values,
        rows=rows,
        plans_differ=other is not None,
        stratified=subsets is not None,
    )
