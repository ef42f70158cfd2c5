"""Evaluation: the protocol of Guo et al. (CVPR 2022), Table 2, on the trained stages.

``python -m t2m.evaluate --dataset DIR --checkpoints DIR`` writes ``results.md`` (the table) and
``results.json`` (every number, every replication, the settings and any deviation from the
standard protocol). The library entry point is :func:`evaluate`; the protocol itself,
:func:`run_protocol`, works on any :class:`Backend` (text / motion embedder plus generator).

The protocol, per replication (each with its own seed):

1. Every test item (a clip, or a captioned sub-clip) gets one of its captions at random and a crop
   to whole 4-frame units (one unit fewer with probability 1/3) from a random start, in a random
   order; rows that do not fill a last pool of 32 are left out. Such a draw is made four times:
   the reference real motions (their embedding statistics are the FID reference), the "Real
   motions" row, and the captions of the two generated rows.
2. "Ours (ground-truth length)" generates one motion per item at the item's cropped length;
   "Ours (sampled length)" lets the text2length model draw each length.
3. Per row, on the evaluator's embeddings: R-precision top 1/2/3 (pools of 32; each caption
   ranks the pool's motions, as the original code does), FID against the reference, MM-Dist, Diversity (300 pairs). MultiModality (generated rows only): the first
   ``mm_texts`` items of the row's draw get ``mm_samples`` generations each (the row's own
   generation is the first), 10 pairs per caption.
4. Each metric is reported as mean and 95% interval ``1.96 sigma / sqrt(replications)``.

Unlike the original, generation is batched. On the procedural demo corpus, a row can also report
semantic accuracy: how often the corpus' own label detectors recover an item's labels.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import logging
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

import numpy as np
import torch
from tqdm import tqdm

from dataset_tools.io import write_json_atomic, write_text_atomic
from t2m import metrics
from t2m.data.dataset import Caption, Clip, load_split

logger = logging.getLogger(__name__)

REAL = "Real motions"
GT_LENGTH = "Ours (ground-truth length)"
SAMPLED_LENGTH = "Ours (sampled length)"
ROWS = (REAL, GT_LENGTH, SAMPLED_LENGTH)

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
COLUMN_TITLES = {
    "r_precision_top1": "R-precision top 1 ↑",
    "r_precision_top2": "R-precision top 2 ↑",
    "r_precision_top3": "R-precision top 3 ↑",
    "fid": "FID ↓",
    "mm_dist": "MM-Dist ↓",
    "diversity": "Diversity →",
    "multimodality": "MultiModality ↑",
    "semantic_accuracy": "Semantic accuracy ↑",
}


@dataclass
class EvalConfig:
    """Settings of one evaluation; the defaults are the standard protocol."""

    split: str = "test"
    """Which split file of the dataset to evaluate on."""
    replications: int = 20
    """Independent repetitions (each regenerates everything with its own seed)."""
    mm_texts: int = 100
    """Captions used for MultiModality."""
    mm_samples: int = 30
    """Generations per MultiModality caption."""
    pool_size: int = metrics.R_PRECISION_BATCH_SIZE
    """R-precision pool: each motion against its caption and pool_size - 1 others."""
    diversity_pairs: int = metrics.DIVERSITY_PAIRS
    mm_pairs: int = metrics.MULTIMODALITY_PAIRS
    max_items: int | None = None
    """Evaluate on at most this many items of the split (None: all of it)."""
    batch_size: int = 128
    """Items per generation / embedding forward pass (speed only; raise it on a GPU)."""
    num_threads: int = 0
    """torch intra-op threads (0: torch's default). On a small shared CPU, 1 is often fastest."""
    seed: int = 0
    device: str = "cpu"
    which: str = "best"
    """Checkpoint of each stage: best or latest."""
    precision: str = "fp32"
    """Generator precision (fp32, bf16, int8); the evaluator always runs in float32."""
    quick: bool = False
    """A development run (few replications on a subset); marked in every output."""


STANDARD = EvalConfig()

# What --quick changes; explicit command-line values win.
QUICK_SETTINGS = {"replications": 3, "max_items": 128, "mm_texts": 16, "mm_samples": 10}


def quick_config(config: EvalConfig) -> EvalConfig:
    """The config with the quick-mode reductions applied (never raising a value)."""
    changes: dict[str, Any] = {"quick": True}
    for key, value in QUICK_SETTINGS.items():
        current = getattr(config, key)
        changes[key] = value if current is None else min(current, value)
    return dataclasses.replace(config, **changes)


def deviations(config: EvalConfig, num_items: int) -> list[str]:
    """Human-readable differences between the effective settings and the standard protocol."""
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
    ):
        value, standard = getattr(config, key), getattr(STANDARD, key)
        if value != standard:
            notes.append(f"{key} = {value} (standard: {standard})")
    if config.max_items is not None:
        notes.append(
            f"only {num_items} items of the split evaluated (max_items = {config.max_items})"
        )
    pairs = min(config.diversity_pairs, num_items)
    if pairs != STANDARD.diversity_pairs:
        notes.append(f"diversity over {pairs} pairs (standard: {STANDARD.diversity_pairs})")
    return notes


# ----------------------------------------------------------------------------------------------
# what the protocol needs from the models


class Backend(Protocol):
    """Embedders and generator behind the protocol (see :class:`CheckpointBackend`)."""

    def embed_texts(self, captions: Sequence[Caption]) -> np.ndarray:
        """Captions -> (N, E) embeddings."""
        ...

    def embed_motions(self, motions: Sequence[np.ndarray]) -> np.ndarray:
        """Raw features, each (T_i, D) with T_i a multiple of 4 -> (N, E) embeddings."""
        ...

    def generate(
        self, captions: Sequence[Caption], lengths: np.ndarray | None, seed: int
    ) -> list[np.ndarray]:
        """One motion per caption as raw features (T_i, D); ``lengths`` in frames (multiples
        of 4), or None to let the length model draw them. Deterministic for a seed."""
        ...


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
    unit_length: int = 4,
    max_frames: int = 196,
    candidates: np.ndarray | None = None,
) -> Draw:
    """Draw ``num_rows`` distinct items in random order, a caption and a unit crop for each.

    Items come from ``candidates`` (indices into ``clips``; default: all clips). The crop keeps
    ``min(T, max_frames) // unit`` units, one fewer with probability 1/3 (the original
    evaluation loader's rule), from a uniformly random start.
    """
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


# ----------------------------------------------------------------------------------------------
# the protocol


SemanticScore = Callable[[Sequence[str], Sequence[np.ndarray]], dict[str, float]]
"""(clip names, raw features (T_i, D)) -> label accuracies (``"all"`` is the one tabled)."""


@dataclass
class ProtocolResult:
    """Per row, per metric, the value of each replication; plus timings and settings."""

    values: dict[str, dict[str, list[float]]]
    semantic: dict[str, dict[str, list[float]]]
    num_items: int
    num_available: int
    config: EvalConfig
    timings_s: dict[str, float] = field(default_factory=dict)


class _Timer:
    """Accumulates wall time per kind of work: ``timer("embed_s", fn, *args)`` calls ``fn``."""

    def __init__(self, *keys: str):
        self.seconds = dict.fromkeys(keys, 0.0)

    def __call__(self, key: str, fn: Callable[..., Any], *args: Any) -> Any:
        start = time.perf_counter()
        out = fn(*args)
        self.seconds[key] += time.perf_counter() - start
        return out


def _seed(*keys: int) -> int:
    """A 63-bit seed derived from integer keys (stable across platforms)."""
    return int(np.random.default_rng(list(keys)).integers(2**63 - 1))


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


def run_protocol(
    clips: Sequence[Clip],
    backend: Backend,
    config: EvalConfig,
    unit_length: int = 4,
    max_frames: int = 196,
    semantic: SemanticScore | None = None,
) -> ProtocolResult:
    """Run ``config.replications`` replications of the protocol on ``clips`` (raw features).

    Returns the per-replication values; :func:`summarize` turns them into means and intervals.
    """
    if config.replications < 1:
        raise ValueError(f"replications must be >= 1, got {config.replications}")
    if config.mm_samples < 2 or config.mm_texts < 1:
        raise ValueError("MultiModality needs mm_texts >= 1 and mm_samples >= 2")
    available = len(clips) if config.max_items is None else min(len(clips), config.max_items)
    num_items = (available // config.pool_size) * config.pool_size
    if num_items == 0:
        raise ValueError(
            f"the {config.split} split has {len(clips)} usable items; R-precision needs at least "
            f"one pool of {config.pool_size}"
        )
    values = {
        row: {
            name: [] for name in METRICS + EXTRA_METRICS if row != REAL or name != "multimodality"
        }
        for row in ROWS
    }
    semantic_values: dict[str, dict[str, list[float]]] = {row: {} for row in ROWS}
    timed = _Timer("generate_s", "embed_s", "metrics_s", "semantic_s")

    def add_semantic(row: str, draw: Draw, motions: Sequence[np.ndarray]) -> None:
        if semantic is None:
            return
        names = [clips[i].name for i in draw.items]
        scores = timed("semantic_s", semantic, names, motions)
        for key, value in scores.items():
            semantic_values[row].setdefault(key, []).append(float(value))

    total_start = time.perf_counter()
    for rep in tqdm(range(config.replications), desc="replications", unit="rep"):
        rng = np.random.default_rng([config.seed, rep, 1])
        metric_rng = np.random.default_rng([config.seed, rep, 2])

        # A subset (max_items) is drawn once per replication, so that the reference, the real
        # row and the generated rows all describe the same clips.
        candidates = None if available == len(clips) else rng.permutation(len(clips))[:available]

        def new_draw() -> Draw:
            return draw_items(clips, num_items, rng, unit_length, max_frames, candidates)  # noqa: B023

        reference_draw = new_draw()
        reference = metrics.gaussian_statistics(
            timed("embed_s", backend.embed_motions, reference_draw.motion_list(clips))
        )

        real_draw = new_draw()
        real_motions = real_draw.motion_list(clips)
        text = timed("embed_s", backend.embed_texts, real_draw.caption_list(clips))
        motion = timed("embed_s", backend.embed_motions, real_motions)
        row = timed("metrics_s", _row_metrics, text, motion, reference, config, metric_rng)
        for name, value in row.items():
            values[REAL][name].append(value)
        add_semantic(REAL, real_draw, real_motions)

        for variant, row_name in enumerate((GT_LENGTH, SAMPLED_LENGTH)):
            draw = new_draw()
            captions = draw.caption_list(clips)
            lengths = draw.lengths if row_name == GT_LENGTH else None
            generated = timed(
                "generate_s",
                backend.generate,
                captions,
                lengths,
                _seed(config.seed, rep, variant, 0),
            )
            text = timed("embed_s", backend.embed_texts, captions)
            motion = timed("embed_s", backend.embed_motions, generated)
            row = timed("metrics_s", _row_metrics, text, motion, reference, config, metric_rng)
            row["multimodality"] = _multimodality(
                backend,
                captions,
                lengths,
                motion,
                config,
                _seed(config.seed, rep, variant, 1),
                metric_rng,
                timed,
            )
            for name, value in row.items():
                values[row_name][name].append(value)
            add_semantic(row_name, draw, generated)
    timings = dict(timed.seconds, total_s=time.perf_counter() - total_start)
    return ProtocolResult(
        values=values,
        semantic=semantic_values,
        num_items=num_items,
        num_available=len(clips),
        config=config,
        timings_s=timings,
    )


# ----------------------------------------------------------------------------------------------
# reporting


def summarize(result: ProtocolResult) -> dict[str, Any]:
    """The results.json content: settings, deviations, and per row/metric mean, interval, values."""
    rows: dict[str, dict[str, Any]] = {}
    for row in ROWS:
        rows[row] = {}
        for name, series in result.values[row].items():
            mean, interval = metrics.confidence_interval(series)
            rows[row][name] = {"mean": mean, "interval": interval, "values": series}
        for name, series in result.semantic[row].items():
            mean, interval = metrics.confidence_interval(series)
            key = "semantic_accuracy" if name == "all" else f"semantic_accuracy_{name}"
            rows[row][key] = {"mean": mean, "interval": interval, "values": series}
    return {
        "quick": result.config.quick,
        "standard_protocol": not deviations(result.config, result.num_items),
        "deviations": deviations(result.config, result.num_items),
        "settings": dataclasses.asdict(result.config),
        "num_items": result.num_items,
        "num_items_available": result.num_available,
        "rows": rows,
        "timings_s": result.timings_s,
    }


def _cell(entry: dict[str, float] | None, digits: int = 3) -> str:
    if entry is None:
        return "-"
    return f"{entry['mean']:.{digits}f} ±{entry['interval']:.{digits}f}"


def _semantic_breakdown(summary: dict[str, Any]) -> list[str]:
    """Per-action semantic accuracy (segments of that action recovered), one column per row."""
    prefix = "semantic_accuracy_action_"
    actions = sorted(
        {
            key[len(prefix) :]
            for row in ROWS
            for key in summary["rows"][row]
            if key.startswith(prefix)
        }
    )
    if not actions:
        return []
    lines = [
        "Segments recovered, per action:",
        "",
        "| Action | " + " | ".join(ROWS) + " |",
        "|---|" + "---|" * len(ROWS),
    ]
    for action in actions:
        cells = [_cell(summary["rows"][row].get(prefix + action)) for row in ROWS]
        lines.append(f"| {action} | " + " | ".join(cells) + " |")
    return lines


def format_markdown(summary: dict[str, Any], title: str = "Text-to-motion evaluation") -> str:
    """The results table (like Table 2 of Guo et al.) with a header that cannot be misread."""
    lines = [f"# {title}", ""]
    if summary["quick"]:
        lines += [
            "> **QUICK MODE — development numbers on a subset with few replications; do not "
            "compare them with published results.**",
            "",
        ]
    settings = summary["settings"]
    lines.append(
        f"Split `{settings['split']}`: {summary['num_items']} items evaluated "
        f"(of {summary['num_items_available']} usable), {settings['replications']} replications, "
        f"seed {settings['seed']}. Each cell is mean ±95% interval (1.96 σ / √replications)."
    )
    lines.append("")
    if summary["deviations"]:
        lines.append("Deviations from the standard protocol:")
        lines += [f"- {note}" for note in summary["deviations"]]
    else:
        lines.append("Standard protocol (Guo et al. 2022).")
    lines.append("")
    columns = list(METRICS)
    if any("semantic_accuracy" in summary["rows"][row] for row in ROWS):
        columns.append("semantic_accuracy")
    lines.append("| Method | " + " | ".join(COLUMN_TITLES[c] for c in columns) + " |")
    lines.append("|---|" + "---|" * len(columns))
    for row in ROWS:
        cells = [_cell(summary["rows"][row].get(c)) for c in columns]
        lines.append(f"| {row} | " + " | ".join(cells) + " |")
    lines += [
        "",
        f"R-precision: each caption ranks the {settings['pool_size']} motions of its pool by "
        "embedding distance (the original evaluation code's orientation; each motion ranking the "
        "captions is in results.json as r_precision_motion_query_*). FID: against real motions "
        "re-drawn every replication. MM-Dist: distance between a motion and its caption. "
        "Diversity: mean distance of random pairs of motions (closer to the real row is better). "
        f"MultiModality: {settings['mm_texts']} captions x {settings['mm_samples']} generations, "
        f"{settings['mm_pairs']} pairs each.",
    ]
    if "semantic_accuracy" in columns:
        lines.append(
            "Semantic accuracy: fraction of motions whose ground-truth labels (action, side, "
            "direction) the demo corpus' detectors recover from the joints."
        )
        lines += ["", *_semantic_breakdown(summary)]
    timings = summary.get("timings_s", {})
    if "total_s" in timings:
        lines += ["", f"Wall time: {timings['total_s']:.1f} s."]
    return "\n".join(lines) + "\n"


def write_results(summary: dict[str, Any], out_dir: str | Path) -> tuple[Path, Path]:
    """Write ``results.json`` and ``results.md`` into ``out_dir`` (atomically)."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    json_path, md_path = out_dir / "results.json", out_dir / "results.md"
    write_json_atomic(json_path, summary)
    write_text_atomic(md_path, format_markdown(summary))
    return json_path, md_path


# ----------------------------------------------------------------------------------------------
# the trained stages as a backend


def _chunks(count: int, size: int) -> list[slice]:
    return [slice(start, min(start + size, count)) for start in range(0, count, size)]


class CheckpointBackend:
    """The trained evaluator (embeddings) and the shared text-to-motion pipeline (generation).

    Build one with :meth:`from_run_dir`, or from an evaluator stage
    (:class:`~t2m.train.checkpoint.TrainedStage`) and a :class:`~t2m.pipeline.TextToMotion`
    (the benchmark builds untrained ones of a preset's sizes).

    Args:
        eval_stage: the trained ``eval`` stage (its evaluator, statistics and vocabulary).
        pipeline: generation (text2length + temporal VAE + decoder), batched.
        batch_size: items per forward pass.
    """

    def __init__(self, eval_stage: Any, pipeline: Any, batch_size: int = 128):
        if batch_size < 1:
            raise ValueError(f"batch_size must be >= 1, got {batch_size}")
        self.eval_stage = eval_stage
        self.pipeline = pipeline
        self.batch_size = batch_size
        self.evaluator = eval_stage.models["evaluator"]
        self.device = next(self.evaluator.parameters()).device
        self.data_config = eval_stage.config.data
        if eval_stage.normalizer.dim != pipeline.normalizer.dim:
            raise ValueError(
                f"the evaluator reads {eval_stage.normalizer.dim}-d features but the generator "
                f"writes {pipeline.normalizer.dim}-d ones"
            )
        # Replications reuse captions: encode each once per vocabulary.
        self._encoded: dict[tuple[str, tuple[str, ...]], Any] = {}

    @classmethod
    def from_run_dir(
        cls,
        run_dir: str | Path,
        device: str = "cpu",
        which: str = "best",
        batch_size: int = 128,
        precision: str = "fp32",
    ) -> CheckpointBackend:
        """Load ``eval/ length/ t2m/`` of a run folder (a one-line ValueError names the make
        target of a missing stage)."""
        from t2m.pipeline import TextToMotion
        from t2m.train.checkpoint import load_stage
        from t2m.train.runtime import resolve_device

        resolved = resolve_device(device)
        eval_stage = load_stage(run_dir, "eval", resolved, which)
        pipeline = TextToMotion.from_checkpoints(run_dir, str(resolved), precision, which=which)
        return cls(eval_stage, pipeline, batch_size)

    def _encode(self, vectorizer: Any, captions: Sequence[Caption]) -> list[Any]:
        """Dataset tokens (``word/POS``) -> EncodedText, as the models were trained on them."""
        fingerprint = vectorizer.fingerprint()
        out = []
        for caption in captions:
            key = (fingerprint, tuple(caption.tokens))
            if key not in self._encoded:
                self._encoded[key] = vectorizer.encode_tokens(caption.tokens)
            out.append(self._encoded[key])
        return out

    @torch.no_grad()
    def embed_texts(self, captions: Sequence[Caption]) -> np.ndarray:
        encoded = self._encode(self.eval_stage.vectorizer, captions)
        out = []
        for chunk in _chunks(len(encoded), self.batch_size):
            items = encoded[chunk]
            words = torch.from_numpy(np.stack([e.words for e in items])).to(self.device)
            pos = torch.from_numpy(np.stack([e.pos_onehot for e in items])).to(self.device)
            lengths = torch.tensor([e.length for e in items], dtype=torch.long, device=self.device)
            out.append(self.evaluator.embed_text(words, pos, lengths).float().cpu().numpy())
        return np.concatenate(out)

    @torch.no_grad()
    def embed_motions(self, motions: Sequence[np.ndarray]) -> np.ndarray:
        normalizer = self.eval_stage.normalizer
        unit = self.data_config.unit_length
        lengths = np.array([len(m) for m in motions], dtype=np.int64)
        if np.any(lengths % unit) or np.any(lengths < unit):
            raise ValueError(f"motion lengths must be positive multiples of {unit}")
        # Every motion is zero-padded to max_frames, as the original evaluator's loader did and
        # as the evaluator is trained: the second encoder convolution sees the padding's
        # activations, so a shorter padding would shift the last snippets' codes and make an
        # embedding depend on the batch it happens to be in.
        frames = max(self.data_config.max_frames, int(lengths.max()))
        out = []
        for chunk in _chunks(len(motions), self.batch_size):
            batch = motions[chunk]
            padded = np.zeros((len(batch), frames, normalizer.dim), np.float32)
            for row, motion in enumerate(batch):
                padded[row, : len(motion)] = normalizer.normalize(np.asarray(motion, np.float32))
            embeddings = self.evaluator.embed_motion(
                torch.from_numpy(padded).to(self.device),
                torch.from_numpy(lengths[chunk]).to(self.device),
            )
            out.append(embeddings.float().cpu().numpy())
        return np.concatenate(out)

    def generate(
        self, captions: Sequence[Caption], lengths: np.ndarray | None, seed: int
    ) -> list[np.ndarray]:
        from t2m.pipeline import PreparedText

        pipeline = self.pipeline
        generator = torch.Generator(pipeline.device).manual_seed(seed)
        encoded = self._encode(pipeline.vectorizer, captions)
        if lengths is None:
            prepared = [
                PreparedText(c.text, e, (), ()) for c, e in zip(captions, encoded, strict=True)
            ]
            frames = np.concatenate(
                [
                    pipeline.sample_lengths(prepared[chunk], generator)
                    for chunk in _chunks(len(prepared), self.batch_size)
                ]
            ).astype(np.int64)
        else:
            frames = np.asarray(lengths, dtype=np.int64)
            if len(frames) != len(captions):
                raise ValueError(f"{len(frames)} lengths for {len(captions)} captions")
        # Batches of similar length waste fewer recurrent steps on padding.
        order = np.argsort(-frames, kind="stable")
        out: list[np.ndarray | None] = [None] * len(captions)
        for chunk in _chunks(len(order), self.batch_size):
            index = order[chunk]
            features = pipeline.generate_features(
                [encoded[i] for i in index], [int(frames[i]) for i in index], generator
            )
            for item, feats in zip(index, features, strict=True):
                out[item] = feats
        return out  # type: ignore[return-value]


# ----------------------------------------------------------------------------------------------
# entry points


def evaluate(
    dataset_dir: str | Path,
    checkpoints_dir: str | Path,
    out_dir: str | Path | None,
    config: EvalConfig,
    backend: Backend | None = None,
) -> dict[str, Any]:
    """Evaluate the run in ``checkpoints_dir`` on ``dataset_dir``; write results into ``out_dir``.

    Steps: 1. load the stages, 2. read the split, 3. run the protocol, 4. summarise and write.
    Returns the summary (the content of results.json).
    """
    # 1. models
    if config.num_threads > 0:
        torch.set_num_threads(config.num_threads)
    if backend is None:
        backend = CheckpointBackend.from_run_dir(
            checkpoints_dir, config.device, config.which, config.batch_size, config.precision
        )
    data_config = getattr(backend, "data_config", None)
    if data_config is None:
        from t2m.config import DataConfig

        data_config = DataConfig()
    # 2. data
    clips = load_split(dataset_dir, config.split, data_config)
    semantic = SemanticScorer.for_dataset(dataset_dir)
    # 3. protocol
    result = run_protocol(
        clips,
        backend,
        config,
        unit_length=data_config.unit_length,
        max_frames=data_config.max_frames,
        semantic=semantic,
    )
    # 4. report
    summary = summarize(result)
    summary["dataset"] = str(dataset_dir)
    summary["checkpoints"] = str(checkpoints_dir)
    if out_dir is not None:
        write_results(summary, out_dir)
    return summary


def find_corpus_labels(dataset_dir: str | Path) -> Path | None:
    """The demo corpus' ``labels.json`` behind a built dataset, or None.

    Looked for in the dataset folder itself, then in the source folder its ``build_report.json``
    names, which must be a corpus written by ``dataset_tools.synth`` (its ``source.json`` says so).
    """
    dataset_dir = Path(dataset_dir)
    if (dataset_dir / "labels.json").is_file():
        return dataset_dir / "labels.json"
    report_path = dataset_dir / "build_report.json"
    if not report_path.is_file():
        return None
    try:
        report = json.loads(report_path.read_text(encoding="utf-8"))
        source_dir = Path(report["config"]["input_dir"])
        source = json.loads((source_dir / "source.json").read_text(encoding="utf-8"))
    except (OSError, KeyError, TypeError, json.JSONDecodeError):
        return None
    labels = source_dir / "labels.json"
    if source.get("generator") != "dataset_tools.synth" or not labels.is_file():
        return None
    return labels


class SemanticScorer:
    """Semantic accuracy on the demo corpus: do the corpus' own detectors find an item's labels?

    An item counts as right when every labelled segment of its source clip is recovered from the
    joints (the motion is cut in proportion to the segments' frames, see
    ``dataset_tools.synth.detectors.clip_matches``); mirrored clips (``M`` prefix) are checked
    against the mirrored labels. Sub-clips with their own time range are not scored.

    Args:
        labels: the content of ``labels.json`` (``{"fps", "clips": {name: {"frames",
            "segments"}}}``).
        fps: frame rate of the dataset's motions.
    """

    def __init__(self, labels: dict[str, Any], fps: float = 20.0):
        self.clips = labels["clips"]
        self.fps = fps

    @classmethod
    def for_dataset(cls, dataset_dir: str | Path) -> SemanticScorer | None:
        """A scorer when the dataset was built from the demo corpus, else None."""
        path = find_corpus_labels(dataset_dir)
        if path is None:
            return None
        logger.info("semantic accuracy from the corpus labels in %s", path)
        return cls(json.loads(path.read_text(encoding="utf-8")))

    def segments_for(self, name: str) -> list[dict] | None:
        """The ground-truth segments of a dataset clip name, or None when it has none."""
        from dataset_tools.synth.detectors import mirror_label

        if "#" in name:  # a captioned sub-clip: its labels are not known
            return None
        if name in self.clips:
            return self.clips[name]["segments"]
        if name.startswith("M") and name[1:] in self.clips:
            return [mirror_label(segment) for segment in self.clips[name[1:]]["segments"]]
        return None

    def __call__(self, names: Sequence[str], motions: Sequence[np.ndarray]) -> dict[str, float]:
        """Raw features (T_i, D) of the named items -> ``all`` (items fully right),
        ``segments`` (segments right) and ``action_<name>`` (segments of that action right)."""
        from dataset_tools.representation import FeatureLayout, recover_from_ric
        from dataset_tools.synth.detectors import clip_matches

        items_right, items, per_action = 0, 0, {}
        for name, motion in zip(names, motions, strict=True):
            segments = self.segments_for(name)
            if segments is None:
                continue
            base = name[1:] if name not in self.clips else name
            joints = recover_from_ric(motion, FeatureLayout.for_dim(motion.shape[-1]).num_joints)
            matched = clip_matches(joints, self.fps, segments, self.clips[base]["frames"])
            items += 1
            items_right += all(matched)
            for segment, ok in zip(segments, matched, strict=True):
                tally = per_action.setdefault(segment["action"], [0, 0])
                tally[0] += ok
                tally[1] += 1
        if items == 0:
            return {}
        scores = {"all": items_right / items}
        scores["segments"] = sum(t[0] for t in per_action.values()) / sum(
            t[1] for t in per_action.values()
        )
        for action, (right, total) in sorted(per_action.items()):
            scores[f"action_{action}"] = right / total
        return scores


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="python -m t2m.evaluate",
        description="Evaluate trained stages with the protocol of Guo et al. 2022 (Table 2): "
        "R-precision, FID, MM-Dist, Diversity, MultiModality, mean ±95% interval over "
        "replications. Writes results.md and results.json into --out.",
    )
    parser.add_argument("--dataset", required=True, help="HumanML3D-layout dataset folder")
    parser.add_argument("--checkpoints", required=True, help="run folder with eval/ length/ t2m/")
    parser.add_argument(
        "--split", default=STANDARD.split, help="split file to evaluate (default: test)"
    )
    parser.add_argument(
        "--replications", type=int, default=None, help="default 20 (3 with --quick)"
    )
    parser.add_argument(
        "--mm-texts", type=int, default=None, help="MultiModality captions (default 100)"
    )
    parser.add_argument(
        "--mm-samples", type=int, default=None, help="generations per caption (default 30)"
    )
    parser.add_argument(
        "--max-items", type=int, default=None, help="evaluate at most this many items"
    )
    parser.add_argument(
        "--quick",
        action="store_true",
        help="development run: 3 replications on a subset, marked as such",
    )
    parser.add_argument(
        "--out", default=None, help="output folder (default: <checkpoints>/eval_results[_quick])"
    )
    parser.add_argument("--device", default="cpu", help="torch device (default cpu)")
    parser.add_argument(
        "--batch-size",
        type=int,
        default=STANDARD.batch_size,
        help="items per forward pass (speed only; default 128, raise it on a GPU)",
    )
    parser.add_argument(
        "--seed", type=int, default=STANDARD.seed, help="seed of replication 0 (default 0)"
    )
    parser.add_argument(
        "--threads", type=int, default=0, help="torch CPU threads (default: torch's choice)"
    )
    parser.add_argument(
        "--which", choices=("best", "latest"), default="best", help="checkpoint of each stage"
    )
    parser.add_argument(
        "--precision",
        choices=("fp32", "bf16", "int8"),
        default="fp32",
        help="generator precision (default fp32; others are marked as deviations)",
    )
    return parser


def config_from_args(args: argparse.Namespace) -> EvalConfig:
    """An EvalConfig from parsed arguments (None means: the default, or the quick value)."""
    explicit = {
        key: getattr(args, key)
        for key in ("replications", "mm_texts", "mm_samples", "max_items")
        if getattr(args, key) is not None
    }
    for key, value in explicit.items():
        if value < 1:
            raise ValueError(f"--{key.replace('_', '-')} must be >= 1, got {value}")
    config = EvalConfig(
        split=args.split,
        batch_size=args.batch_size,
        seed=args.seed,
        device=args.device,
        which=args.which,
        precision=args.precision,
        num_threads=args.threads,
    )
    if args.quick:
        config = quick_config(config)
    return dataclasses.replace(config, **explicit)


def main(argv: list[str] | None = None) -> int:
    """``python -m t2m.evaluate``; exit code 0 on success, 2 with a one-line reason on bad input."""
    args = _parser().parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    try:
        config = config_from_args(args)
        if config.batch_size < 1:
            raise ValueError(f"--batch-size must be >= 1, got {config.batch_size}")
        if config.num_threads < 0:
            raise ValueError(f"--threads must be >= 0, got {config.num_threads}")
        if not Path(args.dataset).is_dir():
            raise ValueError(f"--dataset {args.dataset}: no such folder")
        if not Path(args.checkpoints).is_dir():
            raise ValueError(f"--checkpoints {args.checkpoints}: no such folder")
        if not (Path(args.dataset) / f"{config.split}.txt").is_file():
            raise ValueError(f"--dataset {args.dataset}: no split file {config.split}.txt")
        out = args.out or str(
            Path(args.checkpoints) / ("eval_results_quick" if config.quick else "eval_results")
        )
        summary = evaluate(args.dataset, args.checkpoints, out, config)
    except ValueError as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    print(format_markdown(summary))
    print(f"wrote {Path(out) / 'results.md'} and {Path(out) / 'results.json'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
