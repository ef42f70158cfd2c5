"""The generation queue of the web app: one thread owns the models, requests wait in a queue, and
requests waiting together are generated in one batch.

Batching keeps every request's motions what it would get alone: each request has its own
``torch.Generator`` seeded by its seed, from which :meth:`t2m.pipeline.TextToMotion.plan` draws
its lengths (text2length) and then its latent noise, as :meth:`~t2m.pipeline.TextToMotion.generate`
does for a request of at most ``batch_size`` motions; the rows of several requests are then
stacked (noise padded with zeros past each row's end, which the recurrence never reads) and
generated in one pass. So a seed gives
the motions ``python -m t2m.sample --seed`` gives for the same prompts and lengths, up to float
rounding of the batched matrix products.
"""

from __future__ import annotations

import logging
import queue
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field

import torch

from t2m.motion import GeneratedMotion
from t2m.pipeline import PreparedText, TextToMotion

logger = logging.getLogger(__name__)


@dataclass
class GenerationJob:
    """One request for the worker: prompts (with lengths in frames, None: drawn), samples, seed,
    precision. ``result`` (motions[prompt][sample], the prepared prompts) or ``error`` is set
    before ``done``."""

    texts: list[str]
    frames: list[int | None]
    num_samples: int
    seed: int
    precision: str
    done: threading.Event = field(default_factory=threading.Event)
    result: tuple[list[list[GeneratedMotion]], list[PreparedText]] | None = None
    error: BaseException | None = None
    queued_at: float = field(default_factory=time.perf_counter)

    @property
    def num_motions(self) -> int:
        return len(self.texts) * self.num_samples


@dataclass
class ModelCall:
    """Other model work for the worker thread (an edit): ``function(pipe)`` runs alone, never
    batched; its return value is ``result``, or its exception ``error``, before ``done``."""

    function: Callable[[TextToMotion], object]
    precision: str
    done: threading.Event = field(default_factory=threading.Event)
    result: object = None
    error: BaseException | None = None
    num_motions: int = 0


@dataclass
class _Rows:
    """A prepared job: its motions in the pipeline's generation order and their noise."""

    job: GenerationJob
    prepared: list[PreparedText]
    items: list[tuple[int, int]]  # (prompt, sample), longest first
    frames: list[int]
    noise: torch.Tensor  # (len(items), max snippets of the job, Z)
    fixed: list[bool]  # each item's length given (not drawn): its counted clauses settle


LENGTH_BATCH = 256
"""Prompts whose lengths the text2length model reads at a time (at least)."""


def _prepare_job(pipe: TextToMotion, job: GenerationJob) -> _Rows:
    """Words, lengths and noise of one job (:meth:`TextToMotion.plan`), drawn from its own
    generator, the noise as one tensor for all its motions."""
    generator = torch.Generator(pipe.device).manual_seed(job.seed)
    planned = pipe.plan(
        job.texts,
        job.num_samples,
        job.frames,
        generator,
        batch_size=max(LENGTH_BATCH, job.num_motions),
    )
    (noise,) = planned.noise
    return _Rows(job, planned.prepared, planned.items, planned.frames, noise, planned.fixed)


def generate_jobs(pipe: TextToMotion, jobs: list[GenerationJob]) -> None:
    """Generate every job's motions in one batch (all jobs share ``pipe``'s precision); sets each
    job's ``result``, or its ``error`` when its prompts are refused (the others still run)."""
    prepared_jobs: list[_Rows] = []
    for job in jobs:
        try:
            prepared_jobs.append(_prepare_job(pipe, job))
        except ValueError as error:  # UsageError: empty prompt, no known word, ...
            job.error = error
    if not prepared_jobs:
        return
    steps = max(rows.noise.shape[1] for rows in prepared_jobs)
    encoded, clauses, frames, noise, fixed = [], [], [], [], []
    for rows in prepared_jobs:
        encoded += [rows.prepared[p].encoded for p, _ in rows.items]
        clauses += [rows.prepared[p].clauses for p, _ in rows.items]  # clause by clause
        frames += rows.frames
        fixed += rows.fixed  # as TextToMotion.generate: counts settle at given lengths
        noise.append(torch.nn.functional.pad(rows.noise, (0, 0, 0, steps - rows.noise.shape[1])))
    features = pipe.generate_features(
        encoded, frames, generator=None, noise=torch.cat(noise), clauses=clauses, settle=fixed
    )
    start = 0
    for rows in prepared_jobs:
        job = rows.job
        motions: dict[tuple[int, int], GeneratedMotion] = {}
        for (p, r), feats in zip(rows.items, features[start : start + len(rows.items)]):
            joints, feats = pipe.finish(feats)  # cleaned, as t2m.sample and generate() do
            motions[(p, r)] = GeneratedMotion(job.texts[p], p, r, joints, feats)
        start += len(rows.items)
        grid = [[motions[(p, r)] for r in range(job.num_samples)] for p in range(len(job.texts))]
        job.result = (grid, rows.prepared)


class GenerationWorker:
    """A thread that owns the models and runs queued jobs, batching those that wait together.

    Args:
        pipe: the loaded float32 pipeline; other precisions are made from it on first use.
        max_batch_motions: at most this many motions in one batch (1: no batching across
            requests; a request larger than this still runs, alone).
        max_queue: jobs waiting at most; :meth:`submit` refuses more (the server answers 503).
    """

    def __init__(self, pipe: TextToMotion, max_batch_motions: int = 32, max_queue: int = 16):
        self.pipes = {pipe.precision: pipe}
        self.max_batch_motions = max_batch_motions
        self.jobs: queue.Queue[GenerationJob] = queue.Queue(maxsize=max_queue)
        self._held: GenerationJob | None = None  # taken from the queue, left for the next batch
        self.batches: deque[int] = deque(maxlen=1000)  # jobs per batch, the latest (measure.py)
        self._thread = threading.Thread(target=self._run, name="t2m-generation", daemon=True)
        self._stop = threading.Event()
        self._thread.start()

    def pipe_for(self, precision: str) -> TextToMotion:
        if precision not in self.pipes:
            self.pipes[precision] = self.pipes["fp32"].with_precision(precision)
        return self.pipes[precision]

    def submit(self, job: GenerationJob | ModelCall) -> None:
        """Queue ``job``; raises queue.Full when too many wait."""
        self.jobs.put_nowait(job)

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=10)

    def _next_batch(self) -> list[GenerationJob | ModelCall]:
        """The first waiting job and those queued behind it with its precision, up to
        ``max_batch_motions`` motions (a job that does not fit waits for the next batch); a
        :class:`ModelCall` runs alone."""
        first = self._held or self.jobs.get(timeout=0.2)
        self._held = None
        batch, motions = [first], first.num_motions
        while not isinstance(first, ModelCall):
            try:
                job = self.jobs.get_nowait()
            except queue.Empty:
                break
            if (
                isinstance(job, ModelCall)
                or job.precision != first.precision
                or motions + job.num_motions > self.max_batch_motions
            ):
                self._held = job
                break
            batch.append(job)
            motions += job.num_motions
        return batch

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                batch = self._next_batch()
            except queue.Empty:
                continue
            self.batches.append(len(batch))
            try:
                pipe = self.pipe_for(batch[0].precision)
                if isinstance(batch[0], ModelCall):  # may need gradients (an edit's search)
                    try:
                        batch[0].result = batch[0].function(pipe)
                    except ValueError as error:  # UsageError: a bad request
                        batch[0].error = error
                else:
                    with torch.inference_mode():
                        generate_jobs(pipe, batch)
            except Exception as error:  # a model failure: every job of the batch hears it
                logger.exception("generation failed")
                for job in batch:
                    job.error = job.error or error
            for job in batch:
                job.done.set()
