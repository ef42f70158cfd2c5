"""Reading a HumanML3D-layout folder and cutting batches from it.

:func:`load_split` reads the clips of one split of a HumanML3D folder (its layout and caption
lines are :mod:`dataset_tools.humanml3d`'s): features and tagged captions. A caption with a time
range makes its own sub-clip (as the original does); clips outside
``min_frames <= T < length_limit`` of the dataset's spec
(:class:`dataset_tools.spec.DatasetSpec`) are skipped.

:class:`MotionTextData` keeps the normalised motions and the captions as vocabulary ids, and cuts
batches for each stage. Every batch is a pure function of the item indices and a
``numpy.random.Generator``; the training loops seed that generator from (seed, epoch, step), which
is what makes resuming a killed run exact.
"""

from __future__ import annotations

import json
import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from dataset_tools import humanml3d
from dataset_tools.humanml3d import SPLITS, Caption
from dataset_tools.io import load_npy
from dataset_tools.spec import DatasetSpec, spec_for_dim, spec_for_folder
from t2m.clauses import caption_count, clause_captions, repetition_count, split_clauses
from t2m.data.normalization import Normalizer
from t2m.data.words import WordVectors, pos_onehot
from t2m.streams import Stream, stream_rng

logger = logging.getLogger(__name__)

__all__ = [
    "SPLITS",
    "Caption",
    "Clip",
    "MotionTextData",
    "epoch_batches",
    "load_split",
]


@dataclass
class Clip:
    """A motion (T, D) float32 (raw features) with the captions that describe all of it, and
    where its labelled segments start and end, as shares of the clip (a procedural corpus'
    ``labels.json``; None where not known)."""

    name: str
    motion: np.ndarray
    captions: list[Caption]
    segments: list[tuple[float, float]] | None = None


def labelled_segments(dataset_dir: Path) -> dict[str, list[tuple[float, float]]]:
    """Clip name -> its segments' (start, end) as shares of the clip, from the folder's
    ``labels.json`` (:mod:`dataset_tools.humanml3d`; written for the demo corpus), for mirrored
    clips (``M`` + name) too; {} without one."""
    path = Path(dataset_dir) / humanml3d.LABELS_FILE
    if not path.is_file():
        return {}
    try:
        clips = json.loads(path.read_text(encoding="utf-8"))["clips"]
        found = {
            name: [
                (s["start"] / clip["frames"], s["end"] / clip["frames"]) for s in clip["segments"]
            ]
            for name, clip in clips.items()
        }
    except (OSError, KeyError, TypeError, ZeroDivisionError, json.JSONDecodeError) as error:
        raise ValueError(f"{path}: unreadable segment labels ({error})") from None
    return {**found, **{f"M{name}": parts for name, parts in found.items()}}


def load_split(
    dataset_dir: str | Path,
    split: str,
    *,
    spec: DatasetSpec | None = None,
    limit: int | None = None,
) -> list[Clip]:
    """The usable clips of a split, sorted by name (deterministic), sub-clips included.

    ``spec`` (default: the folder's, from its ``Mean.npy``) gives the frame rate of the
    captions' time ranges and the frame limits. Raises ValueError when the folder or split is
    missing, a clip's features do not have the spec's dimension, or no clip is usable.
    """
    dataset_dir = humanml3d.require_dataset(dataset_dir)
    spec = spec or spec_for_folder(dataset_dir)
    fps, shortest, limit_frames = spec.fps, spec.min_frames, spec.length_limit
    names = sorted(set(humanml3d.read_split(dataset_dir, split)))
    if limit is not None:
        names = names[:limit]
    clips: list[Clip] = []
    segments = labelled_segments(dataset_dir)
    missing = 0
    for name in tqdm(names, desc=f"loading {split}", unit="clip", leave=False, mininterval=2.0):
        motion_path = humanml3d.features_path(dataset_dir, name)
        if not motion_path.is_file() or not humanml3d.texts_path(dataset_dir, name).is_file():
            missing += 1
            continue
        motion = load_npy(motion_path).astype(np.float32, copy=False)
        if motion.ndim != 2 or not np.isfinite(motion).all():
            raise ValueError(f"{motion_path}: expected finite (T, D) features")
        if motion.shape[1] != spec.feature_dim:
            raise ValueError(
                f"{motion_path}: {motion.shape[1]}-d features, {spec.name} has {spec.feature_dim}"
            )
        whole: list[Caption] = []
        for caption in humanml3d.read_texts(dataset_dir, name):
            if caption.whole_clip:
                whole.append(caption)
                continue
            start, end = caption.start, caption.end
            part = motion[int(start * fps) : int(end * fps)]
            if shortest <= len(part) < limit_frames:
                clips.append(Clip(f"{name}#{start:.1f}#{end:.1f}", part, [caption]))
        if whole and shortest <= len(motion) < limit_frames:
            clips.append(Clip(name, motion, whole, segments.get(name)))
    if missing:
        logger.warning(
            "%s: %d clips of %s.txt have no features or texts", dataset_dir, missing, split
        )
    if not clips:
        raise ValueError(f"{dataset_dir}: no usable clip in split {split!r}")
    clips.sort(key=lambda clip: clip.name)
    return clips


def epoch_batches(
    num_items: int, batch_size: int, seed: int, epoch: int, rank: int = 0, world_size: int = 1
) -> list[np.ndarray]:
    """Shuffled item indices for one epoch of one process, cut into full batches.

    Every process draws the same permutation and takes every ``world_size``-th item, so the
    processes of a DDP run see disjoint data and the same number of batches.
    """
    order = stream_rng(Stream.EPOCH_ORDER, seed, epoch).permutation(num_items)
    per_rank = num_items // world_size
    mine = order[rank::world_size][:per_rank]
    count = per_rank // batch_size
    return [mine[i * batch_size : (i + 1) * batch_size] for i in range(count)]


class MotionTextData:
    """Normalised motions with their captions as vocabulary ids, and the batch makers.

    Args:
        clips: from :func:`load_split` (raw features).
        normalizer: mean/std used for every motion.
        vectorizer: the vocabulary.
        spec: the dataset's spec (snippet length, longest motion); default: the one of the
            statistics' feature dimension.
    """

    def __init__(
        self,
        clips: list[Clip],
        normalizer: Normalizer,
        vectorizer: WordVectors,
        spec: DatasetSpec | None = None,
    ):
        if clips and clips[0].motion.shape[1] != normalizer.dim:
            raise ValueError(
                f"features have {clips[0].motion.shape[1]} dimensions but the statistics "
                f"have {normalizer.dim}"
            )
        self.spec = spec or spec_for_dim(normalizer.dim)
        if self.spec.feature_dim != normalizer.dim:
            raise ValueError(
                f"{self.spec.name} has {self.spec.feature_dim}-d features, the statistics "
                f"{normalizer.dim}"
            )
        self.normalizer = normalizer
        self.vectorizer = vectorizer
        self.names = [clip.name for clip in clips]
        self.motions = [normalizer.normalize(clip.motion) for clip in clips]
        self.lengths = np.array([len(m) for m in self.motions], dtype=np.int64)
        self.captions = [[c.text for c in clip.captions] for clip in clips]
        # Per clip and caption, its count clocks: (starts, ends, counts) of its clauses
        self.clocks = [
            [count_clocks(c.tokens, clip.segments) for c in clip.captions] for clip in clips
        ]
        # Per clip and caption, the repetitions it names as one clause (0: none, or several)
        self.caption_counts = [[caption_count(c.tokens) for c in clip.captions] for clip in clips]
        # Per clip and caption, its clauses paired with labelled segments, as length examples
        self.clause_examples = [
            [clause_examples(c.tokens, clip.segments, vectorizer) for c in clip.captions]
            for clip in clips
        ]
        # Per clip, the encoded captions: rows (C, L), POS indices (C, L), lengths (C,).
        self.tokens: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
        for clip in clips:
            encoded = [vectorizer.token_ids(c.tokens) for c in clip.captions]
            self.tokens.append(
                (
                    np.stack([e[0] for e in encoded]),
                    np.stack([e[1] for e in encoded]),
                    np.array([e[2] for e in encoded], dtype=np.int64),
                )
            )

    def __len__(self) -> int:
        return len(self.motions)

    @property
    def feature_dim(self) -> int:
        return self.normalizer.dim

    def indices_at_least(self, frames: int) -> np.ndarray:
        """Indices of the clips with at least ``frames`` frames."""
        return np.flatnonzero(self.lengths >= frames)

    # -- text ---------------------------------------------------------------------------------

    def text_batch(self, indices: np.ndarray, rng: np.random.Generator) -> dict[str, torch.Tensor]:
        """One random caption per item: ``words`` (B, L, Dw) or (B, L) ids, ``pos`` (B, L, 15),
        ``text_lengths`` (B,)."""
        return self._text_rows(indices, rng)[0]

    def _text_rows(
        self, indices: np.ndarray, rng: np.random.Generator
    ) -> tuple[dict[str, torch.Tensor], list[int]]:
        """:meth:`text_batch` and the caption chosen for each item."""
        rows, cats, lengths, choices = [], [], [], []
        for index in indices:
            clip_rows, clip_cats, clip_lengths = self.tokens[index]
            choice = int(rng.integers(len(clip_lengths)))
            rows.append(clip_rows[choice])
            cats.append(clip_cats[choice])
            lengths.append(clip_lengths[choice])
            choices.append(choice)
        batch = {
            "words": torch.from_numpy(self.vectorizer.lookup(np.stack(rows))),
            "pos": torch.from_numpy(pos_onehot(np.stack(cats))),
            "text_lengths": torch.tensor(lengths, dtype=torch.long),
        }
        return batch, choices

    # -- motion -------------------------------------------------------------------------------

    def window_batch(
        self, indices: np.ndarray, rng: np.random.Generator, frames: int
    ) -> dict[str, torch.Tensor]:
        """A random ``frames``-long window of each item: ``motion`` (B, frames, D), and where
        each snippet of it starts as a share of its clip (``done`` (B, frames // snippet
        length): (window start + snippet start) / clip frames)."""
        windows, done = [], []
        unit = self.spec.snippet_length
        offsets = np.arange(frames // unit) * unit
        for index in indices:
            motion = self.motions[index]
            start = rng.integers(0, len(motion) - frames + 1)
            windows.append(motion[start : start + frames])
            done.append((start + offsets) / len(motion))
        return {
            "motion": torch.from_numpy(np.stack(windows)),
            "done": torch.from_numpy(np.stack(done).astype(np.float32)),
        }

    def unit_crop_batch(
        self, indices: np.ndarray, rng: np.random.Generator
    ) -> dict[str, torch.Tensor]:
        """Caption + motion cropped to whole units (the original's evaluation crop), padded.

        Each motion keeps ``T // unit`` units, or one unit fewer with probability 1/3, from a
        random start, clipped to ``max_frames``; zero-padded to ``max_frames``.
        Returns the text batch plus ``motion`` (B, max_frames, D) and ``motion_lengths`` (B,).
        """
        unit, max_frames = self.spec.snippet_length, self.spec.max_frames
        batch = self.text_batch(indices, rng)
        padded = np.zeros((len(indices), max_frames, self.feature_dim), dtype=np.float32)
        lengths = np.empty(len(indices), dtype=np.int64)
        for row, index in enumerate(indices):
            motion = self.motions[index]
            units = min(len(motion), max_frames) // unit
            if units > 1 and rng.random() < 1 / 3:
                units -= 1
            frames = units * unit
            start = rng.integers(0, len(motion) - frames + 1)
            padded[row, :frames] = motion[start : start + frames]
            lengths[row] = frames
        batch["motion"] = torch.from_numpy(padded)
        batch["motion_lengths"] = torch.from_numpy(lengths)
        return batch

    def length_batch(
        self, indices: np.ndarray, rng: np.random.Generator, clause_examples: float = 0.0
    ) -> dict[str, torch.Tensor]:
        """Caption + length class (snippets: frames // snippet_length, frames capped at
        ``max_frames``): ``length_class`` (B,), ``counts`` (B,) the repetitions each caption
        names (:func:`t2m.clauses.caption_count`, as ``EncodedText.count``) and ``clause`` (B,)
        whether it is a clause of its clip. With ``clause_examples`` > 0, that share of the
        captions whose clauses pair with labelled segments is replaced by one of those clauses
        (drawn at random) and its segment's length (``LengthStageConfig.clause_examples``; no
        extra draws at 0)."""
        batch, choices = self._text_rows(indices, rng)
        frames = np.minimum(self.lengths[indices], self.spec.max_frames)
        counts = [self.caption_counts[i][c] for i, c in zip(indices, choices)]
        clause = np.zeros(len(indices), dtype=bool)
        if clause_examples > 0:
            rows = [self.tokens[i][0][c] for i, c in zip(indices, choices)]
            cats = [self.tokens[i][1][c] for i, c in zip(indices, choices)]
            lengths = batch["text_lengths"].numpy().copy()
            for row, (index, choice) in enumerate(zip(indices, choices)):
                examples = self.clause_examples[index][choice]
                if examples and rng.uniform() < clause_examples:
                    clause_rows, clause_cats, length, count, share = examples[
                        int(rng.integers(len(examples)))
                    ]
                    rows[row], cats[row] = clause_rows, clause_cats
                    lengths[row], counts[row], clause[row] = length, count, True
                    frames[row] = min(round(share * self.lengths[index]), self.spec.max_frames)
            batch["words"] = torch.from_numpy(self.vectorizer.lookup(np.stack(rows)))
            batch["pos"] = torch.from_numpy(pos_onehot(np.stack(cats)))
            batch["text_lengths"] = torch.from_numpy(lengths)
        batch["length_class"] = torch.from_numpy(frames // self.spec.snippet_length)
        batch["counts"] = torch.tensor(counts, dtype=torch.long)
        batch["clause"] = torch.from_numpy(clause)
        return batch

    def fixed_crop_batch(
        self, indices: np.ndarray, rng: np.random.Generator, frames: int
    ) -> dict[str, torch.Tensor]:
        """Caption + a random ``frames``-long crop of each item (all items must be long enough),
        with each snippet's count clock: ``counts`` (B, S) the repetitions its clause names
        (:func:`count_clocks`, 0: none), ``done`` (B, S) the share of that clause done and
        ``clause_snippets`` (B, S) the clause's length in snippets."""
        batch, choices = self._text_rows(indices, rng)
        batch.update(self.window_batch(indices, rng, frames))
        batch["motion_lengths"] = torch.full((len(indices),), frames, dtype=torch.long)
        where = batch["done"].numpy()  # (B, S) shares of the clips
        counts = np.zeros(where.shape, dtype=np.int64)
        done = np.zeros(where.shape, dtype=np.float32)
        clause = np.zeros(where.shape, dtype=np.float32)
        for row, (index, choice) in enumerate(zip(indices, choices)):
            starts, ends, named = self.clocks[index][choice]
            part = np.clip(np.searchsorted(ends, where[row], side="right"), 0, len(ends) - 1)
            counts[row] = named[part]
            done[row] = (where[row] - starts[part]) / (ends[part] - starts[part])
            clause[row] = (
                (ends[part] - starts[part]) * self.lengths[index] / self.spec.snippet_length
            )
        batch["counts"], batch["done"] = torch.from_numpy(counts), torch.from_numpy(done)
        batch["clause_snippets"] = torch.from_numpy(clause)
        return batch


ClauseExample = tuple[np.ndarray, np.ndarray, int, int, float]
"""A clause as a caption of its own: token rows (L,), POS indices (L,), its length, the count it
names (:func:`t2m.clauses.caption_count`) and its segment's share of the clip."""


def clause_examples(
    tokens: list[str], segments: list[tuple[float, float]] | None, vectorizer: WordVectors
) -> list[ClauseExample]:
    """A caption's clauses as standalone captions (:func:`t2m.clauses.clause_captions`, as the
    clause plan encodes them) with their labelled segments' shares of the clip, when the caption
    has two or more clauses and as many as the clip has segments; else none."""
    clauses = clause_captions(tokens)
    if len(clauses) < 2 or segments is None or len(segments) != len(clauses):
        return []
    out = []
    for clause, (start, end) in zip(clauses, segments, strict=True):
        if end <= start:
            return []
        rows, cats, length = vectorizer.token_ids(clause)
        out.append((rows, cats, int(length), caption_count(clause), float(end - start)))
    return out


def count_clocks(
    tokens: list[str], segments: list[tuple[float, float]] | None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The count clocks of a caption: its clauses' (starts, ends) as shares of the clip and the
    repetitions each names (:func:`t2m.clauses.repetition_count`; 0: none), as generation gives
    them clause by clause (:meth:`t2m.pipeline.TextToMotion.generate_features`). A caption of one
    clause spans the clip; one of several spans the clip's labelled segments in order when it
    has as many clauses as the clip has segments, else it gets no clock (one span, count 0)."""
    clauses = split_clauses(tokens)
    if len(clauses) == 1:
        spans = [(0.0, 1.0, repetition_count(tokens))]
    elif segments is not None and len(segments) == len(clauses) and all(e > s for s, e in segments):
        counts = [repetition_count([tokens[i] for i in clause]) for clause in clauses]
        spans = [(s, e, n) for (s, e), n in zip(segments, counts)]
        spans[0] = (0.0, spans[0][1], spans[0][2])  # the clauses cover the whole clip
        spans[-1] = (spans[-1][0], 1.0, spans[-1][2])
    else:
        spans = [(0.0, 1.0, 0)]
    starts, ends, counts = (np.array(values) for values in zip(*spans))
    return starts.astype(np.float64), ends.astype(np.float64), counts.astype(np.int64)
