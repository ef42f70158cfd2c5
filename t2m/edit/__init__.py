"""Editing and composition: continue a motion, fill in between, redo a body part, follow a path
or joint targets, chain prompts on a timeline. One mechanism serves every mode
(:mod:`t2m.edit.core`); ``python -m t2m.edit`` is the command over it.

API::

    from t2m.pipeline import TextToMotion
    from t2m.edit import load_source, SearchSettings

    pipe = TextToMotion.from_checkpoints("checkpoints/demo")
    motions = pipe.edit("a person waves both hands", "body", "walk.bvh", part="lower",
                        num_samples=3, seed=0)           # == t2m.edit.edit(pipe, ...)
    motions[0].joints    # (T, 22, 3) float32, metres, y-up, at pipe.spec.fps (20)
    motions[0].features  # (T, 263) float32, de-normalised
    motions[0].kept      # (T, 22) bool: copied from the source or given as a target
    motions[0].text, motions[0].repetition, motions[0].mode

``TextToMotion.edit(text, mode, source=None, **options)`` and ``edit(pipe, text, mode, source=None,
*, num_samples=1, seed=0, settings=None, progress=False, **request)`` return
``list[EditedMotion]``, one per sample; ``edit_batch(pipe, requests, num_samples=1, seed=0,
settings=None)`` takes many :class:`EditRequest` and returns ``motions[request][sample]``.

``source``: a joints array (T, 22, 3) (y-up metres at the model's frame rate) or a file for
:func:`load_source` (``.npy`` joints (T, 22, 3), ``sampleNN_repRR.npy`` of ``t2m.sample``
included, or ``.bvh`` through the dataset importer; options ``mapping`` and ``source_fps``).
:func:`load_source(path, spec=HUMANML3D, mapping=None, fps=None) -> (T, 22, 3) float32`.

Modes and their options (:class:`EditRequest` fields, the one schema of an edit that the
command line, ``--batch`` JSON and the web API are made from; seconds):

* ``continue``: ``keep_seconds`` (default 2.0) of the source's start are kept, the rest is
  generated; ``seconds``: the result's length (default: the source's, at most 9.8 s).
* ``inbetween``: ``keep_start`` / ``keep_end`` (default 1.0 each; one frame, 0.05, for single
  key poses): the source's first and last seconds at the result's start and end, the middle
  generated; ``seconds`` (default: the source's length).
* ``body``: ``part`` in ``lower`` (root path + legs, default), ``legs``, ``upper``, ``arms``,
  ``left_arm``, ``right_arm`` is kept on every frame, the rest regenerated from the text.
* ``path``: ``path``: (K, 3) rows ``seconds, x, z`` or a CSV / JSON file; the root passes
  through each floor point at its time (the motion starts at (0, 0) facing +Z);
  ``seconds`` (default: the last point's time).
* ``keys``: ``keys``: (T, 22, 3) joint targets, NaN where free (or a ``.npy``); the root's floor
  position is met exactly, other joints as closely as the search gets.
* ``compose``: ``timeline``: lines ``text#start#end`` or ``text#seconds`` (a list, a string or
  a file); one motion as long as the timeline (any length; windows of at most 9.8 s chained,
  each continuing from the last 2 s made), each stretch following its own prompt; ``text``
  unused. With a ``source``, the result starts with the source (or its last ``keep_last``
  seconds), kept exactly, and the timeline follows it: its first line starts where the kept
  stretch ends (``text#seconds`` lines do), the first window continuing from its last 2 s.

Results are in the model's frame: the source as the dataset's representation sees it
(retargeted to the model's skeleton, on the floor, frame 0 at the origin facing +Z), so kept
frames equal :func:`t2m.edit.source.prepare_source`'s joints. ``kept`` marks what came from the
source or the targets; renderings draw it in another colour.

``settings`` (:class:`SearchSettings`): ``method`` ``auto`` (default: ``optimize`` where some
targets cannot be kept exactly, i.e. keys on joints other than the root's floor position,
``posterior`` elsewhere), ``optimize``, ``posterior`` or ``best_of_n`` (the baseline);
``candidates`` (8), ``steps`` (20), ``learning_rate``, ``noise_weight``, ``blend_frames``,
``end_draws`` (3: an inbetween draws this many times ``candidates``). Bad
requests raise :class:`dataset_tools.command.UsageError` (a ValueError) with one line.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from dataset_tools.command import UsageError
from dataset_tools.representation import recover_from_ric
from t2m.edit.core import EditPlan, PlanResult, SearchSettings, generate_plans
from t2m.edit.keep import smooth_join
from t2m.edit.modes import BODY_PARTS, MODES, ComposePlan, Segment
from t2m.edit.request import EditRequest
from t2m.edit.source import half_yaw_of, load_source, prepare_source
from t2m.motion import GeneratedMotion

logger = logging.getLogger(__name__)

COMPOSE_CONTEXT_SECONDS = 2.0
"""Compose: each window continues from this much of what was made before it."""


@dataclass(frozen=True)
class EditedMotion(GeneratedMotion):
    """A :class:`t2m.pipeline.GeneratedMotion` made by an edit.

    Attributes (besides text, prompt_index, repetition, joints (T, J, 3), features (T, D)):
        kept: (T, J) bool, True where the joint came from the source or met a given target.
        mode: the edit mode.
        constraint_error: root mean square distance in metres of the chosen candidate from the
            kept / targeted joints before the hard keep, on the frames the search can change
            (not those decoded from the kept start's codes alone): how close the model got on
            its own; NaN without constraints.
    """

    kept: np.ndarray = field(default_factory=lambda: np.zeros((0, 0), bool))
    mode: str = ""
    constraint_error: float = float("nan")


def edit(
    pipe,
    text: str,
    mode: str,
    source: str | Path | np.ndarray | None = None,
    *,
    num_samples: int = 1,
    seed: int = 0,
    settings: SearchSettings | None = None,
    **request,
) -> list[EditedMotion]:
    """One edit, ``num_samples`` results (see the module docstring)."""
    requested = EditRequest(mode=mode, text=text, source=source, **request)
    return edit_batch(pipe, [requested], num_samples, seed, settings)[0]


def edit_batch(
    pipe,
    requests: Sequence[EditRequest],
    num_samples: int = 1,
    seed: int = 0,
    settings: SearchSettings | None = None,
) -> list[list[EditedMotion]]:
    """Many edits, ``num_samples`` results each: ``motions[request][sample]``. Every request is
    checked (and its source read) before any generation; plain edits are batched together,
    compose timelines run window by window. One generator seeded by ``seed`` makes every draw."""
    settings = settings or SearchSettings()
    if num_samples < 1:
        raise UsageError(f"num_samples must be >= 1, got {num_samples}")
    plans: list[EditPlan | None] = []
    timelines: list[ComposePlan | None] = []
    for request in requests:
        if request.mode == "compose":
            plans.append(None)
            timelines.append(request.compose_plan(pipe.spec))
            continue
        plan = request.plan(pipe.spec)
        counted = _counted_continue(pipe, plan) if request.mode == "continue" else None
        plans.append(None if counted else plan)
        timelines.append(counted)
    generator = torch.Generator(pipe.device).manual_seed(seed)
    flat = [(i, r) for i, plan in enumerate(plans) if plan is not None for r in range(num_samples)]
    made = generate_plans(pipe, [plans[i] for i, _ in flat], generator, settings)
    results: dict[tuple[int, int], EditedMotion] = {}
    for (i, r), result in zip(flat, made):
        results[(i, r)] = _motion(requests[i], plans[i].text, i, r, result)
    for i, timeline in enumerate(timelines):
        if timeline is None:
            continue
        if requests[i].mode == "compose":
            text = " / ".join(segment.text for segment in timeline.segments)
        else:
            text = requests[i].text
        composed = compose(
            pipe, timeline.segments, num_samples, generator, settings, start=timeline.start
        )
        for r, result in enumerate(composed):
            results[(i, r)] = _motion(requests[i], text, i, r, result)
    return [[results[(i, r)] for r in range(num_samples)] for i in range(len(requests))]


def _motion(request: EditRequest, text: str, index: int, rep: int, result: PlanResult):
    return EditedMotion(
        text=text,
        prompt_index=index,
        repetition=rep,
        joints=result.joints,
        features=result.features,
        kept=result.kept,
        mode=request.mode,
        constraint_error=result.soft_error,
    )


def compose(
    pipe,
    timeline,
    num_samples: int,
    generator,
    settings: SearchSettings,
    start: np.ndarray | None = None,
) -> list[PlanResult]:
    """Chain the timeline's segments into one motion per sample: windows of at most the
    model's longest motion, each continuing (as ``continue`` does) from the last
    :data:`COMPOSE_CONTEXT_SECONDS` made, with the prompt of the segment it makes, the join
    smoothed on both sides (:func:`t2m.edit.keep.smooth_join`; the window's own seam
    finishing smooths the new side only, as for a kept source). A segment
    whose prompt names a count and lasts longer than the count needs is made as that count
    followed by standing still (:meth:`t2m.pipeline.TextToMotion.count_parts`; needs the length
    model, else the segment is made whole).

    ``start``: features (K, D) the result starts with, kept exactly (a source's stretch,
    :class:`t2m.edit.modes.ComposePlan`); the first window continues from them as the others
    continue from the window before, and they are marked kept."""
    spec = pipe.spec
    unit = spec.snippet_length
    context = int(round(COMPOSE_CONTEXT_SECONDS * spec.fps)) // unit * unit
    chunks = []  # (text, frames)
    for segment in timeline:
        # a counted prompt keeps the time its count needs, then stands (TextToMotion.count_parts)
        for text, frames in pipe.count_parts(segment.text, segment.stop - segment.start):
            left = frames
            while left > 0:
                first = not chunks and start is None
                room = spec.max_frames - (0 if first else context)
                size = min(left, room // unit * unit)
                chunks.append((text, size))
                left -= size
    kept = 0 if start is None else len(start)
    # per sample, what is made so far (T, D)
    features: list[np.ndarray] = [] if start is None else [start] * num_samples
    total = sum(size for _, size in chunks)
    made_frames = 0
    for index, (text, size) in enumerate(chunks):
        if len(chunks) > 1:
            logger.info(
                "compose: window %d/%d (%.1f of %.1f s made): %s",
                index + 1,
                len(chunks),
                made_frames / spec.fps,
                total / spec.fps,
                text,
            )
        made_frames += size
        have = min(context, len(features[0]) // unit * unit) if features else 0
        if not features:
            target = np.full((size, spec.num_joints, 3), np.nan)
            plans = [EditPlan(text, size, target, np.zeros(target.shape[:2], bool))] * num_samples
        else:
            # the same line's next window goes on with it; a new line starts as a caption does
            goes_on = index > 0 and chunks[index - 1][0] == text
            plans = [
                _continuation(text, made[len(made) - have :], size, spec, goes_on)
                for made in features
            ]
        results = generate_plans(pipe, plans, generator, settings)
        if not features:
            features = [result.features for result in results]
        else:
            # both sides of the join are the model's own motion (but a kept source's frames)
            features = [
                smooth_join(
                    np.concatenate([made, result.features[have:]]), len(made), spec.fps, kept
                )
                for made, result in zip(features, results)
            ]
    out = []
    for r in range(num_samples):
        whole = features[r].astype(np.float32)
        joints = recover_from_ric(whole, spec.num_joints).astype(np.float32)
        marked = np.zeros(joints.shape[:2], bool)
        marked[:kept] = True
        out.append(PlanResult(whole, joints, marked, float("nan")))
    return out


def _counted_continue(pipe, plan: EditPlan) -> ComposePlan | None:
    """A ``continue`` whose text names a count and whose regenerated part is longer than the
    count needs (:meth:`t2m.pipeline.TextToMotion.count_parts`) as a compose from its kept
    start: the count in the time it needs, then standing still, so that "jumps twice" jumps
    twice however long the rest is. None: made as planned."""
    kept = int(np.argmin(plan.keep.all(axis=1)))  # continue keeps whole leading frames
    parts = pipe.count_parts(plan.text, plan.num_frames - kept)
    if len(parts) < 2:
        return None
    segments, at = [], kept
    for text, frames in parts:
        segments.append(Segment(text, at, at + frames))
        at += frames
    return ComposePlan(segments, plan.source_features[:kept].astype(np.float32))


def _continuation(text: str, tail: np.ndarray, size: int, spec, continues: bool = True) -> EditPlan:
    """A plan that keeps ``tail`` (K, D) features whole and makes ``size`` more frames;
    ``continues``: the text goes on with what the tail does (:attr:`EditPlan.continues`)."""
    have = len(tail)
    frames = have + size
    target = np.full((frames, spec.num_joints, 3), np.nan)
    target[:have] = recover_from_ric(tail, spec.num_joints)
    keep = np.zeros((frames, spec.num_joints), bool)
    keep[:have] = True
    source = np.full((frames, tail.shape[1]), np.nan)
    source[:have] = tail
    yaw = np.full(frames, np.nan)
    yaw[:have] = half_yaw_of(tail)
    return EditPlan(text, frames, target, keep, source, yaw, continues)


__all__ = [
    "BODY_PARTS",
    "MODES",
    "EditRequest",
    "EditedMotion",
    "SearchSettings",
    "edit",
    "edit_batch",
    "load_source",
    "prepare_source",
]
