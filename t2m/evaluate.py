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
3. Per row, on the evaluator's embeddings: R-precision top 1/2/3 (pools of 32), FID against the
   reference, MM-Dist, Diversity (300 pairs). MultiModality (generated rows only): the first
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
import os
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

import numpy as np
import torch
from tqdm import tqdm

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
    batch_size: int = 256
    """Items per generation / embedding forward pass (speed only)."""
    seed: int = 0
    device: str = "cpu"
    which: str = "best"
    """Checkpoint of each stage: best or latest."""
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
    for key in ("split", "replications", "mm_texts", "mm_samples", "pool_size", "mm_pairs"):
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
) -> Draw:
    """Draw ``num_rows`` distinct items in random order, a caption and a unit crop for each.

    The crop keeps ``min(T, max_frames) // unit`` units, one fewer with probability 1/3 (the
    original evaluation loader's rule), from a uniformly random start.
    """
    if num_rows > len(clips):
        raise ValueError(f"cannot draw {num_rows} items from {len(clips)} clips")
    items = rng.permutation(len(clips))[:num_rows]
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


SemanticScorer = Callable[[Sequence[str], Sequence[np.ndarray]], dict[str, float]]
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
    top = metrics.r_precision(text, motion, top_k=3, batch_size=config.pool_size)
    motion_stats = metrics.gaussian_statistics(motion)
    return {
        "r_precision_top1": float(top[0]),
        "r_precision_top2": float(top[1]),
        "r_precision_top3": float(top[2]),
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
) -> float:
    """MultiModality of the first ``mm_texts`` rows: their own generation plus
    ``mm_samples - 1`` more each, generated in one batched call."""
    num_texts = min(config.mm_texts, len(captions))
    extra = config.mm_samples - 1
    repeated = [captions[k] for k in range(num_texts) for _ in range(extra)]
    repeated_lengths = None if lengths is None else np.repeat(lengths[:num_texts], extra)
    more = backend.embed_motions(backend.generate(repeated, repeated_lengths, seed))
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
    semantic: SemanticScorer | None = None,
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
        row: {name: [] for name in METRICS if row != REAL or name != "multimodality"}
        for row in ROWS
    }
    semantic_values: dict[str, dict[str, list[float]]] = {row: {} for row in ROWS}
    timings = {"generate_s": 0.0, "embed_s": 0.0, "metrics_s": 0.0, "semantic_s": 0.0}

    def timed(key: str, fn: Callable[..., Any], *args: Any) -> Any:
        start = time.perf_counter()
        out = fn(*args)
        timings[key] += time.perf_counter() - start
        return out

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

        def new_draw() -> Draw:
            return draw_items(clips, num_items, rng, unit_length, max_frames)  # noqa: B023

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
            start = time.perf_counter()
            row["multimodality"] = _multimodality(
                backend,
                captions,
                lengths,
                motion,
                config,
                _seed(config.seed, rep, variant, 1),
                metric_rng,
            )
            # The extra generations dominate this call's time.
            timings["generate_s"] += time.perf_counter() - start
            for name, value in row.items():
                values[row_name][name].append(value)
            add_semantic(row_name, draw, generated)
    timings["total_s"] = time.perf_counter() - total_start
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
        "R-precision: each motion ranks its caption among a pool of "
        f"{settings['pool_size']} captions by embedding distance. FID: against real motions "
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
    timings = summary.get("timings_s", {})
    if "total_s" in timings:
        lines += ["", f"Wall time: {timings['total_s']:.1f} s."]
    return "\n".join(lines) + "\n"


def _atomic_write_text(path: Path, text: str) -> None:
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", dir=path.parent)
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as handle:
            handle.write(text)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def write_results(summary: dict[str, Any], out_dir: str | Path) -> tuple[Path, Path]:
    """Write ``results.json`` and ``results.md`` into ``out_dir`` (atomically)."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    json_path, md_path = out_dir / "results.json", out_dir / "results.md"
    _atomic_write_text(json_path, json.dumps(summary, indent=2) + "\n")
    _atomic_write_text(md_path, format_markdown(summary))
    return json_path, md_path


# ----------------------------------------------------------------------------------------------
# the trained stages as a backend


def _chunks(count: int, size: int) -> list[slice]:
    return [slice(start, min(start + size, count)) for start in range(0, count, size)]


class CheckpointBackend:
    """The evaluator, text2length and temporal VAE of a run, batched.

    Build one with :meth:`from_run_dir`, or from :class:`~t2m.train.checkpoint.TrainedStage`
    objects (the benchmark builds untrained ones of a preset's sizes).

    Args:
        eval_stage, length_stage, t2m_stage: the trained stages (models in eval mode).
        device: where the models are.
        batch_size: items per forward pass.
    """

    def __init__(
        self,
        eval_stage: Any,
        length_stage: Any,
        t2m_stage: Any,
        device: str | torch.device = "cpu",
        batch_size: int = 256,
    ):
        if batch_size < 1:
            raise ValueError(f"batch_size must be >= 1, got {batch_size}")
        self.device = torch.device(device)
        self.batch_size = batch_size
        self.eval_stage = eval_stage
        self.length_stage = length_stage
        self.t2m_stage = t2m_stage
        self.evaluator = eval_stage.models["evaluator"]
        self.length_model = length_stage.models["length"]
        self.vae = t2m_stage.models["vae"]
        self.decoder = t2m_stage.models["decoder"]
        self.data_config = eval_stage.config.data
        if eval_stage.dims["feature_dim"] != t2m_stage.dims["feature_dim"]:
            raise ValueError("the eval and t2m stages disagree on the feature size")
        self._encoded: dict[tuple[int, tuple[str, ...]], tuple[np.ndarray, np.ndarray, int]] = {}

    @classmethod
    def from_run_dir(
        cls,
        run_dir: str | Path,
        device: str = "cpu",
        which: str = "best",
        batch_size: int = 256,
    ) -> CheckpointBackend:
        """Load ``eval/ length/ t2m/`` of a run folder (a one-line ValueError names the make
        target of a missing stage)."""
        from t2m.train.checkpoint import load_stage  # torch-heavy; only when models are used

        stages = [load_stage(run_dir, stage, device, which) for stage in ("eval", "length", "t2m")]
        return cls(*stages, device=device, batch_size=batch_size)

    @property
    def unit_length(self) -> int:
        return self.data_config.unit_length

    @property
    def max_frames(self) -> int:
        return self.data_config.max_frames

    def _text_inputs(self, stage: Any, captions: Sequence[Caption]) -> tuple[torch.Tensor, ...]:
        """Captions -> words (B, L, Dw) or ids, POS one-hot (B, L, 15), lengths (B,) for the
        vocabulary of ``stage``; encodings are cached since replications reuse captions."""
        vectorizer = stage.vectorizer
        rows, pos, lengths = [], [], []
        for caption in captions:
            key = (id(vectorizer), tuple(caption.tokens))
            if key not in self._encoded:
                encoded = vectorizer.encode_tokens(caption.tokens)
                self._encoded[key] = (encoded.words, encoded.pos_onehot, encoded.length)
            words, onehot, length = self._encoded[key]
            rows.append(words)
            pos.append(onehot)
            lengths.append(length)
        return (
            torch.from_numpy(np.stack(rows)).to(self.device),
            torch.from_numpy(np.stack(pos)).to(self.device),
            torch.tensor(lengths, dtype=torch.long, device=self.device),
        )

    @torch.no_grad()
    def embed_texts(self, captions: Sequence[Caption]) -> np.ndarray:
        out = []
        for chunk in _chunks(len(captions), self.batch_size):
            words, pos, lengths = self._text_inputs(self.eval_stage, captions[chunk])
            out.append(self.evaluator.embed_text(words, pos, lengths).float().cpu().numpy())
        return np.concatenate(out)

    @torch.no_grad()
    def embed_motions(self, motions: Sequence[np.ndarray]) -> np.ndarray:
        normalizer = self.eval_stage.normalizer
        lengths = np.array([len(m) for m in motions], dtype=np.int64)
        if np.any(lengths % self.unit_length) or np.any(lengths < self.unit_length):
            raise ValueError(f"motion lengths must be positive multiples of {self.unit_length}")
        out = []
        for chunk in _chunks(len(motions), self.batch_size):
            batch = motions[chunk]
            padded = np.zeros((len(batch), int(lengths[chunk].max()), normalizer.dim), np.float32)
            for row, motion in enumerate(batch):
                padded[row, : len(motion)] = normalizer.normalize(np.asarray(motion, np.float32))
            embeddings = self.evaluator.embed_motion(
                torch.from_numpy(padded).to(self.device),
                torch.from_numpy(lengths[chunk]).to(self.device),
            )
            out.append(embeddings.float().cpu().numpy())
        return np.concatenate(out)

    @torch.no_grad()
    def sample_lengths(self, captions: Sequence[Caption], generator: torch.Generator) -> np.ndarray:
        """Frames per caption drawn from text2length (multiples of the unit, <= max_frames)."""
        from t2m.models.length import sample_lengths

        units = []
        for chunk in _chunks(len(captions), self.batch_size):
            words, pos, lengths = self._text_inputs(self.length_stage, captions[chunk])
            logits = self.length_model(words, pos, lengths)
            units.append(sample_lengths(logits, generator).cpu().numpy())
        frames = np.concatenate(units).astype(np.int64) * self.unit_length
        return np.minimum(frames, (self.max_frames // self.unit_length) * self.unit_length)

    @torch.no_grad()
    def generate(
        self, captions: Sequence[Caption], lengths: np.ndarray | None, seed: int
    ) -> list[np.ndarray]:
        generator = torch.Generator(self.device).manual_seed(seed)
        if lengths is None:
            lengths = self.sample_lengths(captions, generator)
        lengths = np.asarray(lengths, dtype=np.int64)
        if len(lengths) != len(captions):
            raise ValueError(f"{len(lengths)} lengths for {len(captions)} captions")
        # Batches of similar length waste fewer recurrent steps on padding.
        order = np.argsort(-lengths, kind="stable")
        t2m_normalizer = self.t2m_stage.normalizer
        out: list[np.ndarray | None] = [None] * len(captions)
        for chunk in _chunks(len(order), self.batch_size):
            index = order[chunk]
            words, pos, text_lengths = self._text_inputs(
                self.t2m_stage, [captions[i] for i in index]
            )
            word_features, sentence, mask = self.vae.encode_text(words, pos, text_lengths)
            snippets = torch.from_numpy(lengths[index] // self.unit_length).to(self.device)
            codes = self.vae.generate(
                word_features, sentence, mask, snippets, self.t2m_stage.initial_code, generator
            )
            features = t2m_normalizer.denormalize(self.decoder(codes).float().cpu().numpy())
            for row, item in enumerate(index):
                out[item] = features[row, : lengths[item]]
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
    if backend is None:
        backend = CheckpointBackend.from_run_dir(
            checkpoints_dir, config.device, config.which, config.batch_size
        )
    data_config = getattr(backend, "data_config", None)
    if data_config is None:
        from t2m.config import DataConfig

        data_config = DataConfig()
    # 2. data
    clips = load_split(dataset_dir, config.split, data_config)
    semantic = semantic_scorer(dataset_dir)
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


def semantic_scorer(dataset_dir: str | Path) -> SemanticScorer | None:
    """Label detectors for a demo-corpus dataset, or None when the dataset carries no labels."""
    return None


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="python -m t2m.evaluate",
        description="Evaluate trained stages with the protocol of Guo et al. 2022 (Table 2): "
        "R-precision, FID, MM-Dist, Diversity, MultiModality, mean ±95%% interval over "
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
        help="items per forward pass (speed only)",
    )
    parser.add_argument("--seed", type=int, default=STANDARD.seed)
    parser.add_argument(
        "--which", choices=("best", "latest"), default="best", help="checkpoint of each stage"
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
        if not Path(args.dataset).is_dir():
            raise ValueError(f"--dataset {args.dataset}: no such folder")
        if not Path(args.checkpoints).is_dir():
            raise ValueError(f"--checkpoints {args.checkpoints}: no such folder")
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
