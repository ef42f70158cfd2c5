"""Named random streams: every random choice of a run is drawn from one of these.

A stream's generator is seeded from the run's seed, the coordinates of the draw (epoch, step,
rank, batch index ...) and the stream's number, so two streams never share draws, and a resumed
run draws exactly what the uninterrupted run drew at the same coordinates. Training draws from
:class:`Stream`; evaluation from :class:`EvalStream` and :class:`GenerationStream`.
"""

from __future__ import annotations

from enum import IntEnum

import numpy as np


class Stream(IntEnum):
    """The random streams of training (the numbers are part of what a seed reproduces)."""

    EPOCH_ORDER = 7
    """The shuffle of one epoch (``t2m.data.dataset.epoch_batches`` draws it)."""
    BATCH = 11
    """One training batch's choices: captions, crops, teacher forcing, negative shifts."""
    VALIDATION = 99
    """One validation batch's choices: captions, crops, latent noise (the same every epoch)."""


class EvalStream(IntEnum):
    """The random streams of one evaluation replication (coordinate: the replication)."""

    ITEMS = 1
    """The items, captions and crops the replication draws."""
    METRICS = 2
    """The pairs Diversity and MultiModality draw."""


class GenerationStream(IntEnum):
    """The seeds of an evaluation's generated rows (coordinates: replication, row)."""

    MOTIONS = 0
    """The row's motions, one per item."""
    MULTIMODALITY = 1
    """The row's extra motions for MultiModality."""


def stream_rng(stream: IntEnum, seed: int, *coordinates: int) -> np.random.Generator:
    """The generator of ``stream`` at ``coordinates`` (e.g. epoch, step, rank) of run ``seed``."""
    return np.random.default_rng([seed, *coordinates, int(stream)])


def stream_seed(stream: IntEnum, seed: int, *coordinates: int) -> int:
    """A 63-bit integer seed drawn from ``stream`` at ``coordinates`` (for code seeded with an
    integer, such as a torch generator); stable across platforms."""
    return int(stream_rng(stream, seed, *coordinates).integers(2**63 - 1))
