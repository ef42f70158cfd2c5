"""The edit benchmark: ``python -m t2m.evaluate --edit MODE --dataset DIR --checkpoints DIR``.

Builds ``--items`` edits of one mode from the dataset's test split and runs each with every
``--methods`` entry (``auto``, ``optimize``, ``posterior``, ``best_of_n``:
:class:`t2m.edit.SearchSettings`),
side by side, then writes ``results.md`` and ``results.json`` into ``--out``.

The edits (seeded; sources are real test motions, "donor" captions come from test clips of one
labelled action, so the corpus' detectors can check the regenerated part):

* continue: keep 2 s of a source, 4 s from a donor's caption (regenerated: frames 40..120);
* inbetween: keep the first and last second of the donor's own clip (at least 4 s, the result
  as long as the clip, at most 9.8 s) and regenerate its middle from its caption, so that the
  kept ends are ends a motion of the caption can join; ``--no-own-ends``: keep 1 s at each end
  of an unrelated source, 4 s from the donor's caption in the middle (a caption that moves the
  body, "walks forward", "turns left", contradicts a kept end at a place and facing it cannot
  reach: no edit can follow both);
* body: keep the lower body of a walking or running source, the rest from a donor's caption of
  an upper-body action (wave, raise, punch, clap);
* path: the root path of a source (a point every second) with the source's own caption;
* keys: the source's root floor position and both wrists at three frames, its own caption;
* compose: three donors' captions, 4 s each (12 s, two joins).

Columns (per method):

* ``err mean / max``: distance (m) of the result's kept or targeted joints from their targets,
  mean over entries and items / largest; ``before keep``: the same (root mean square per item,
  averaged) of the model's own output before the hard keep; ``miss >5 / >20 cm``: fraction of
  targeted entries farther than that (keys: the wrists are soft targets);
* ``seam acc / jerk``: at each join, the largest over the 0.5 s around it (the frames within
  0.25 s, :data:`SEAM_WINDOW_SECONDS`) of the largest joint acceleration (m/s^2) and jerk
  (m/s^3) (second and third differences at 20 fps), median over joins; ``plain`` and ``real``
  give the same statistic at random frames of plain generation and of the real test motions
  (the edits' sources; compose: its donors);
* ``semantic``: fraction of regenerated parts whose donor label the corpus' detectors recover
  (body: the upper-body action, and the source's walk still detected; compose: the fraction
  of segments recognised, each judged on its own 4 s, and below the table per timeline
  position: the first segment starts from rest, the others continue the one before);
  ``plain`` gives the same for plain generation of the same captions and lengths;
* ``skate``: the foot-skating ratio (:func:`dataset_tools.physical.skating_ratio`: feet 10 and
  11; a frame skates when a foot is within 5 cm of the floor in two consecutive frames and its
  speed and its 5-frame mean speed both exceed 0.5 m/s; skating frames / (T - 1), mean over
  motions) of the results, of plain generation and of the real motions (as for the seams);
* ``R@3 / FID``: R-precision (top 3, batches of 32) and FID of the regenerated parts against
  the donors' real motions with the run's evaluator stage, beside plain generation (when the
  run has an evaluator and there are at least 32 items; else n/a);
* ``ms / edit``: median wall time of single edits (one result; ``--latency-edits`` of them,
  after a warm-up; the methods take turns on each edit), and the process' peak resident memory.
"""

from __future__ import annotations

import logging
import resource
import sys
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np
import torch

from dataset_tools import humanml3d
from dataset_tools.command import CommandParser, UsageError, command, option, parse_config
from dataset_tools.io import check_output_folder, write_json_atomic, write_text_atomic
from dataset_tools.physical import skating_ratio
from dataset_tools.synth.detectors import detect_labels
from dataset_tools.synth.matching import clip_matches, label_matches
from t2m.edit import EditRequest, SearchSettings, edit_batch
from t2m.edit.core import METHODS, EditPlan
from t2m.edit.modes import Mode

logger = logging.getLogger(__name__)

UPPER_ACTIONS = ("wave", "raise", "punch", "clap")
LOWER_ACTIONS = ("walk", "run")
SECONDS = {"part": 4.0, "keep": 2.0, "end": 1.0, "segment": 4.0}
MAX_SECONDS = 9.8
"""The longest single edit (HumanML3D's 196 frames at 20 fps): an ``--own-ends`` clip longer
than this is cut to it."""


@dataclass
class EditBenchConfig:
    """``python -m t2m.evaluate --edit MODE``: the edit benchmark."""

    edit: Mode = field(metadata=option(metavar="MODE"))
    """the edit mode to measure"""
    dataset: Path = field(metadata=option(metavar="DIR"))
    """HumanML3D-layout dataset folder (its test split; the demo corpus for semantic scores)"""
    checkpoints: Path = field(metadata=option(metavar="DIR"))
    """run folder (or the original release's folder)"""
    out: Path | None = field(default=None, metadata=option(metavar="DIR"))
    """output folder (default <checkpoints>/edit_results/<mode>)"""
    items: int = field(default=300, metadata=option(metavar="N"))
    """edits per method (at 64 the semantic accuracy moves by about 0.05 between seeds)"""
    methods: tuple[str, ...] = ("auto", "optimize", "posterior", "best_of_n")
    """search methods to compare (t2m.edit.SearchSettings.method)"""
    candidates: int = field(default=8, metadata=option(metavar="N"))
    """noise draws per edit"""
    steps: int = field(default=20, metadata=option(metavar="N"))
    """optimisation steps of the optimize method"""
    noise_weight: float = field(default=SearchSettings.noise_weight, metadata=option(metavar="W"))
    """weight of mean(eps^2) in the optimize method's loss"""
    latency_edits: int = field(default=5, metadata=option(metavar="N"))
    """single edits timed per method"""
    paper_latency: bool = False
    """also time single edits of the same requests with paper-sized random-weight models"""
    seed: int = 0
    """seeds the choice of items and the edits"""
    threads: int = field(default=1, metadata=option(metavar="N"))
    """torch CPU threads"""
    device: str = "cpu"
    """cpu, cuda or auto"""
    precision: Literal["fp32", "bf16", "int8"] = "fp32"
    """inference precision"""
    own_ends: bool | None = None
    """inbetween only: keep the ends of the caption's own clip (its first and last second, the
    result as long as the clip), so that the kept ends fit the text (the default), or with
    --no-own-ends an unrelated source's, whose place and facing a moving caption may not
    reach"""

    def __post_init__(self) -> None:
        if self.items < 1 or self.candidates < 1 or self.steps < 0 or self.latency_edits < 0:
            raise UsageError(
                "--items and --candidates must be >= 1, --steps and --latency-edits >= 0"
            )
        if self.own_ends is not None and self.edit != "inbetween":
            flag = "--own-ends" if self.own_ends else "--no-own-ends"
            raise UsageError(f"{flag} is an inbetween option (--edit inbetween)")
        if self.own_ends is None:
            self.own_ends = self.edit == "inbetween"
        for method in self.methods:
            if method not in METHODS:
                raise UsageError(f"unknown method {method!r}; use {', '.join(METHODS)}")


@dataclass
class Item:
    """One benchmark edit: the request, what it regenerates and how it is judged."""

    request: EditRequest
    part: tuple[int, int] | None  # regenerated frames to judge [a, b), None: the whole motion
    labels: list[dict]  # the donor's (or source's) segment labels the part should show
    texts: list[humanml3d.Caption]  # caption(s) of the regenerated part(s)
    donors: list[str]  # clips whose real motions the parts are compared with
    source: str | None = None  # the clip the edit starts from (or whose path it follows)
    seams: list[int] = field(default_factory=list)
    source_labels: list[dict] | None = None  # body: the source's labels, still expected
    plan: EditPlan | None = None  # the request's plan (not for compose)


# ---------------------------------------------------------------------------- items


def _whole_captions(dataset: Path, name: str) -> list[humanml3d.Caption]:
    return [c for c in humanml3d.read_texts(dataset, name) if c.whole_clip and c.tokens]


class _Clips:
    """The test split's clips that have whole-clip captions, as (name, labels, captions), in
    the pools the edits draw from, and seeded draws from them."""

    def __init__(self, dataset: Path, seed: int, fps: float):
        from dataset_tools.synth.scoring import scorer_for

        scorer = scorer_for(dataset)
        names = humanml3d.read_split(dataset, "test")
        self.rng = np.random.default_rng(seed)
        self.dataset = dataset
        self.joints: dict[str, np.ndarray] = {}
        self.all = []
        for name in names:
            segments = scorer.segments_for(name) if scorer else None
            captions = _whole_captions(dataset, name)
            if not captions:
                continue
            self.all.append((name, segments, captions))
        clips = self.all
        self.single = [c for c in clips if c[1] is not None and len(c[1]) == 1]
        self.upper = [c for c in self.single if c[1][0]["action"] in UPPER_ACTIONS]
        self.walkers = [
            c for c in clips if c[1] is not None and all(s["action"] in LOWER_ACTIONS for s in c[1])
        ]
        if scorer is None:  # not the demo corpus: captions only, no labels
            self.single = self.upper = self.walkers = clips
        self.shortest = int(
            2.5 * fps
        )  # every source: at least 2.5 s (2 s kept + some, or both ends)

    def load(self, name: str) -> np.ndarray:
        if name not in self.joints:
            self.joints[name] = humanml3d.read_joints(humanml3d.joints_path(self.dataset, name))
        return self.joints[name]

    def pick(self, pool: list, source: bool = False) -> tuple:
        """A clip of ``pool``; a ``source`` at least ``shortest`` frames long."""
        while True:
            clip = pool[int(self.rng.integers(len(pool)))]
            if not source or len(self.load(clip[0])) >= self.shortest:
                return clip

    def at_least(self, pool: list, frames: int) -> list:
        """The clips of ``pool`` at least ``frames`` long."""
        return [clip for clip in pool if len(self.load(clip[0])) >= frames]

    def caption(self, clip: tuple) -> humanml3d.Caption:
        return clip[2][int(self.rng.integers(len(clip[2])))]


def _kept_ends_item(mode: str, clips: _Clips, fps: float) -> Item:
    """continue (keep the source's first seconds) or inbetween (keep both ends): a donor's
    caption for the regenerated part."""
    source, donor = clips.pick(clips.all, True), clips.pick(clips.single)
    text = clips.caption(donor)
    part = int(SECONDS["part"] * fps)
    if mode == "continue":
        keep = int(SECONDS["keep"] * fps)
        timing = dict(keep_seconds=SECONDS["keep"], seconds=SECONDS["keep"] + SECONDS["part"])
        judged, seams = (keep, keep + part), [keep]
    else:
        end = int(SECONDS["end"] * fps)
        timing = dict(
            keep_start=SECONDS["end"],
            keep_end=SECONDS["end"],
            seconds=2 * SECONDS["end"] + SECONDS["part"],
        )
        judged, seams = (end, end + part), [end, end + part]
    request = EditRequest(mode, text.text, clips.load(source[0]), **timing)
    return Item(request, judged, donor[1] or [], [text], [donor[0]], source[0], seams)


def _own_ends_item(mode: str, clips: _Clips, fps: float) -> Item:
    """inbetween with the ends of the caption's own clip: its first and last second kept, its
    middle regenerated from its caption (the clip at least four times the kept end long), so
    that the kept ends fit what the caption does."""
    end = int(SECONDS["end"] * fps)
    pool = clips.at_least(clips.single, 4 * end)
    if not pool:
        raise UsageError(f"--own-ends: no test clip of one action lasts {4 * end / fps:g} s")
    donor = clips.pick(pool)
    joints = clips.load(donor[0])
    text = clips.caption(donor)
    unit = 4  # the result is whole snippets of the model's 4 frames, as plan_inbetween makes it
    frames = min(len(joints), int(MAX_SECONDS * fps)) // unit * unit
    timing = dict(keep_start=SECONDS["end"], keep_end=SECONDS["end"], seconds=frames / fps)
    request = EditRequest(mode, text.text, joints[:frames], **timing)
    judged, seams = (end, frames - end), [end, frames - end]
    return Item(request, judged, donor[1] or [], [text], [donor[0]], donor[0], seams)


def _body_item(mode: str, clips: _Clips, fps: float) -> Item:
    """body: a walker's legs kept, an upper-body action's caption for the rest."""
    source, donor = clips.pick(clips.walkers, True), clips.pick(clips.upper)
    text = clips.caption(donor)
    motion = clips.load(source[0])[: 196 + 1]
    request = EditRequest(mode, text.text, motion, part="lower")
    labels = donor[1] or []
    return Item(request, None, labels, [text], [donor[0]], source[0], source_labels=source[1])


def _targets_item(mode: str, clips: _Clips, fps: float) -> Item:
    """path (the source's root path, one point a second) or keys (its root and hands at three
    frames), with the source's own caption."""
    from t2m.edit.source import prepare_source

    source = clips.pick(clips.all, True)
    text = clips.caption(source)
    prepared = prepare_source(clips.load(source[0])[: 196 + 1])
    frames = prepared.num_frames // 4 * 4
    if mode == "path":
        rows = np.arange(int(fps), frames, int(fps))
        points = np.stack([rows / fps, *prepared.joints[rows, 0][:, [0, 2]].T], axis=-1)
        request = EditRequest(mode, text.text, path=points, seconds=frames / fps)
    else:
        keys = np.full((frames, 22, 3), np.nan)
        for row in (frames // 4, frames // 2, frames - 1):
            keys[row, 0, [0, 2]] = prepared.joints[row, 0, [0, 2]]
            keys[row, [20, 21]] = prepared.joints[row, [20, 21]]
        request = EditRequest(mode, text.text, keys=keys)
    return Item(request, None, source[1] or [], [text], [source[0]], source[0])


def _compose_item(mode: str, clips: _Clips, fps: float) -> Item:
    """compose: three single-action captions on a timeline."""
    donors = [clips.pick(clips.single) for _ in range(3)]
    texts = [clips.caption(d) for d in donors]
    length = SECONDS["segment"]
    timeline = [f"{t.text}#{i * length:g}#{(i + 1) * length:g}" for i, t in enumerate(texts)]
    request = EditRequest(mode, timeline=timeline)
    labels = [d[1][0] if d[1] else None for d in donors]
    part = int(SECONDS["part"] * fps)
    return Item(request, None, labels, texts, [d[0] for d in donors], seams=[part, 2 * part])


_ITEM_MAKERS = {
    "continue": _kept_ends_item,
    "inbetween": _kept_ends_item,
    "body": _body_item,
    "path": _targets_item,
    "keys": _targets_item,
    "compose": _compose_item,
}


def build_items(config: EditBenchConfig, fps: float) -> list[Item]:
    """Seeded edits of ``config.edit`` from the test split (see the module docstring)."""
    clips = _Clips(config.dataset, config.seed, fps)
    make = _ITEM_MAKERS.get(config.edit, _compose_item)
    if config.own_ends:
        make = _own_ends_item
    return [make(config.edit, clips, fps) for _ in range(config.items)]


# ---------------------------------------------------------------------------- statistics


SEAM_WINDOW_SECONDS = 0.5
"""The stretch around a join (or a random frame) whose acceleration and jerk are measured."""


def seam_statistics(joints: np.ndarray, frame: int, fps: float) -> tuple[float, float]:
    """(acceleration m/s^2, jerk m/s^3): the largest joint's, largest over the differences of the
    frames within ``SEAM_WINDOW_SECONDS / 2`` of ``frame`` (a window that would leave the motion
    is moved inside it)."""
    half = max(int(round(SEAM_WINDOW_SECONDS * fps / 2)), 2)
    size = min(2 * half + 3, len(joints))  # second differences centred on frame - half.. + half
    lo = min(max(frame - half - 1, 0), len(joints) - size)
    window = joints[lo : lo + size]
    acc = np.linalg.norm(np.diff(window, 2, axis=0), axis=-1).max() * fps**2
    jerk = np.linalg.norm(np.diff(window, 3, axis=0), axis=-1).max() * fps**3
    return float(acc), float(jerk)


def _labels_found(joints: np.ndarray, labels: list[dict], fps: float) -> bool | None:
    if not labels:
        return None
    facts = detect_labels(joints, fps)
    return all(label_matches(facts, label) for label in labels)


def judge(item: Item, motion, fps: float) -> dict:
    """Every per-edit number of one result."""
    request = item.request
    out: dict = {}
    # targets of the result: what was kept or given
    if item.plan is not None:
        target = item.plan.target
        given = np.isfinite(target)  # (T, J, 3): a path gives x and z only
        if request.mode not in ("path", "keys"):  # kept joints; "legs" etc. have no targets
            given &= item.plan.keep[..., None]
        finite = given.any(-1)
    else:
        target, finite = None, None
    if target is not None and finite.any():
        difference = np.where(given, motion.joints - np.nan_to_num(target), 0.0)
        distance = np.linalg.norm(difference, axis=-1)[finite]
        out.update(
            err_mean=float(distance.mean()),
            err_max=float(distance.max()),
            miss_5=float((distance > 0.05).mean()),
            miss_20=float((distance > 0.2).mean()),
        )
    out["before_keep"] = motion.constraint_error
    out["seams"] = [seam_statistics(motion.joints, s, fps) for s in item.seams]
    out["skate"] = skating_ratio(motion.joints, fps)
    # semantic
    if request.mode == "compose":
        step = len(motion.joints) // 3
        segments = [
            None
            if label is None
            else _labels_found(motion.joints[index * step : (index + 1) * step], [label], fps)
            for index, label in enumerate(item.labels)
        ]
        found = [f for f in segments if f is not None]
        out["semantic"] = float(np.mean(found)) if found else None  # per segment, as plain
        out["segments"] = segments
    else:
        a, b = item.part or (0, len(motion.joints))
        part = motion.joints[a:b]
        if request.mode in ("path", "keys") and item.labels:
            out["semantic"] = all(clip_matches(part, fps, item.labels))
        else:
            out["semantic"] = _labels_found(part, item.labels, fps)
        if item.source_labels:
            out["semantic"] = out["semantic"] and all(
                clip_matches(motion.joints, fps, item.source_labels)
            )
    return out


# ---------------------------------------------------------------------------- the run


def _plans(items: list[Item], spec) -> None:
    for item in items:
        if item.request.mode != "compose":
            item.plan = item.request.plan(spec)


def _parts(item: Item, motion) -> list[np.ndarray]:
    """The regenerated features the evaluator embeds (whole snippets)."""
    if item.request.mode == "compose":
        step = len(motion.features) // 3
        return [motion.features[i * step : (i + 1) * step] for i in range(3)]
    a, b = item.part or (0, len(motion.features) // 4 * 4)
    return [motion.features[a:b]]


def _real_row(dataset: Path, sources: list[str], fps: float, rng: np.random.Generator) -> dict:
    """Seam (at a random frame) and skating figures of the real source clips."""
    real_seams, real_skate = [], []
    for name in sources:
        joints = humanml3d.read_joints(humanml3d.joints_path(dataset, name))
        real_skate.append(skating_ratio(joints, fps))
        if len(joints) > 8:
            real_seams.append(seam_statistics(joints, int(rng.integers(3, len(joints) - 4)), fps))
    return {
        "seam_acc": float(np.median([s[0] for s in real_seams])),
        "seam_jerk": float(np.median([s[1] for s in real_seams])),
        "skate": float(np.mean(real_skate)),
    }


def _plain_row(
    pipe, items: list[Item], config: EditBenchConfig, fps: float, rng: np.random.Generator
) -> tuple[dict, list]:
    """Plain generation of every item's captions at its parts' lengths: its figures (seams at a
    random frame, labels found, skating) and the motions."""
    plain_texts, plain_frames, plain_labels = [], [], []
    for item in items:
        frames = _part_frames(item, fps)
        for caption, label in zip(item.texts, _label_rows(item)):
            plain_texts.append(caption.text)
            plain_frames.append(frames)
            plain_labels.append(label)
    plain = pipe.generate(plain_texts, lengths=plain_frames, seed=config.seed)
    plain_motions = [row[0] for row in plain]
    if config.edit in ("path", "keys"):  # the source's own caption and labels (segments)
        found = [
            all(clip_matches(m.joints, fps, lab)) if lab else None
            for m, lab in zip(plain_motions, plain_labels)
        ]
    else:
        found = [_labels_found(m.joints, lab, fps) for m, lab in zip(plain_motions, plain_labels)]
    segments = None
    if config.edit == "compose":  # each timeline position's captions (three per item)
        segments = [_mean_found(found[index::3]) for index in range(3)]
    found = [f for f in found if f is not None]
    plain_seams = [
        seam_statistics(m.joints, int(rng.integers(3, len(m.joints) - 4)), fps)
        for m in plain_motions
    ]
    row = {
        "seam_acc": float(np.median([s[0] for s in plain_seams])),
        "seam_jerk": float(np.median([s[1] for s in plain_seams])),
        "semantic": float(np.mean(found)) if found else None,
        "skate": float(np.mean([skating_ratio(m.joints, fps) for m in plain_motions])),
    }
    if segments is not None:
        row["semantic_segments"] = segments
    return row, plain_motions


def _mean_found(found: list) -> float | None:
    """The share of True among the judged (not None) entries; None where none was judged."""
    judged = [f for f in found if f is not None]
    return float(np.mean(judged)) if judged else None


def run_benchmark(config: EditBenchConfig) -> dict:
    from t2m.pipeline import TextToMotion
    from t2m.train.runtime import inference_device

    torch.set_num_threads(config.threads)
    device = inference_device(config.device, config.precision)
    pipe = TextToMotion.from_checkpoints(
        config.checkpoints, device=device, precision=config.precision, need_length_model=False
    )
    fps = pipe.spec.fps
    items = build_items(config, fps)
    _plans(items, pipe.spec)
    requests = [item.request for item in items]
    logger.info("%d %s edits", len(items), config.edit)
    # the evaluator (optional)
    backend = None
    try:
        from t2m.evaluate.backend import CheckpointBackend, Embedder

        backend = CheckpointBackend(Embedder.load(config.checkpoints, device), pipe)
    except (ValueError, OSError) as error:
        logger.warning("no evaluator (%s): R-precision and FID are n/a", error)
    results: dict = {"mode": config.edit, "items": len(items), "config": _jsonable(asdict(config))}
    # real reference, then plain generation of the same captions and lengths (one draw order)
    rng = np.random.default_rng(config.seed + 1)
    sources = [item.source or item.donors[0] for item in items]
    results["real"] = _real_row(config.dataset, sources, fps, rng)
    results["plain"], plain_motions = _plain_row(pipe, items, config, fps, rng)
    captions = [c for item in items for c in item.texts]
    real_features = [
        _real_features(config.dataset, donor) for item in items for donor in item.donors
    ]
    if backend is not None:
        results["plain"].update(
            _rprec_fid(backend, captions, [m.features for m in plain_motions], real_features)
        )
        results["real"].update(_rprec_fid(backend, captions, real_features, real_features))
    # the methods
    results["methods"] = {}
    all_settings = {
        method: SearchSettings(
            method=method,
            candidates=config.candidates,
            steps=config.steps,
            noise_weight=config.noise_weight,
        )
        for method in config.methods
    }
    for method, settings in all_settings.items():
        start = time.perf_counter()
        motions = [row[0] for row in edit_batch(pipe, requests, 1, config.seed, settings)]
        batch_seconds = time.perf_counter() - start
        judged = [judge(item, motion, fps) for item, motion in zip(items, motions)]
        row = _summarise(judged)
        row["batch_s"] = batch_seconds
        if backend is not None:
            parts = [p for item, m in zip(items, motions) for p in _parts(item, m)]
            row.update(_rprec_fid(backend, captions, parts, real_features))
        results["methods"][method] = row
        logger.info("%s: %s", method, {k: v for k, v in row.items() if not isinstance(v, list)})
    latency = _latency(pipe, requests[: config.latency_edits], all_settings, config.seed)
    for method, milliseconds in latency.items():
        results["methods"][method]["ms_per_edit"] = milliseconds
    if config.paper_latency and config.latency_edits:
        paper = _latency(
            _paper_pipeline(), requests[: config.latency_edits], all_settings, config.seed
        )
        results["paper_ms_per_edit"] = paper
    results["peak_rss_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    return results


def _jsonable(value):
    if isinstance(value, dict):
        return {k: _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    return str(value) if isinstance(value, Path) else value


def _part_frames(item: Item, fps: float) -> int:
    if item.part is not None:
        return item.part[1] - item.part[0]
    if item.request.mode == "compose":
        return int(SECONDS["segment"] * fps)
    return item.plan.num_frames


def _label_rows(item: Item) -> list[list[dict]]:
    if item.request.mode == "compose":
        return [[label] if label else [] for label in item.labels]
    return [item.labels]


def _real_features(dataset: Path, name: str) -> np.ndarray:
    from dataset_tools.io import load_npy

    features = load_npy(humanml3d.features_path(dataset, name)).astype(np.float32)
    return features[: len(features) // 4 * 4][:196]


def _rprec_fid(backend, captions, motions, reference) -> dict:
    from t2m.evaluate.metrics import fid, r_precision

    if len(captions) < 32:
        return {}
    texts = backend.embed_texts(captions)
    embedded = backend.embed_motions([m[: len(m) // 4 * 4] for m in motions])
    real = backend.embed_motions(reference)
    return {"r_precision_3": float(r_precision(texts, embedded)[2]), "fid": fid(real, embedded)}


def _paper_pipeline():
    """The random-weight pipeline of :func:`~t2m.evaluate.paper_sized.paper_sized_pipeline`
    (what ``t2m.benchmarks.sample`` times) with a movement encoder: for latency only."""
    from t2m.evaluate.paper_sized import paper_sized_pipeline
    from t2m.models.autoencoder import CONTACT_DIMS, MovementEncoder
    from t2m.pipeline import TextToMotion
    from t2m.presets import paper

    pipe, (vae, decoder, initial_code) = paper_sized_pipeline("fp32")
    torch.manual_seed(0)
    encoder = MovementEncoder(pipe.spec.feature_dim - CONTACT_DIMS, paper().autoencoder.model)
    return TextToMotion(
        vae, decoder, pipe.normalizer, pipe.vectorizer, initial_code, encoder=encoder.eval()
    )


def _latency(pipe, requests, methods: dict[str, SearchSettings], seed: int) -> dict:
    """Median milliseconds of a single edit per method; the methods take turns on each edit
    (interleaved, so that load from other processes falls on all of them alike)."""
    if not requests:
        return {}
    for settings in methods.values():  # warm-up (spaCy, first allocations)
        edit_batch(pipe, requests[:1], 1, seed, settings)
    times: dict[str, list[float]] = {method: [] for method in methods}
    for request in requests:
        for method, settings in methods.items():
            start = time.perf_counter()
            edit_batch(pipe, [request], 1, seed, settings)
            times[method].append(time.perf_counter() - start)
    return {method: 1000 * float(np.median(values)) for method, values in times.items()}


def _summarise(judged: list[dict]) -> dict:
    def mean(key):
        values = [j[key] for j in judged if key in j and j[key] is not None and np.isfinite(j[key])]
        return float(np.mean(values)) if values else None

    row = {key: mean(key) for key in ("err_mean", "miss_5", "miss_20", "before_keep", "skate")}
    maxima = [j["err_max"] for j in judged if "err_max" in j]
    row["err_max"] = float(np.max(maxima)) if maxima else None
    seams = [s for j in judged for s in j["seams"]]
    row["seam_acc"] = float(np.median([s[0] for s in seams])) if seams else None
    row["seam_jerk"] = float(np.median([s[1] for s in seams])) if seams else None
    semantic = [j["semantic"] for j in judged if j["semantic"] is not None]
    row["semantic"] = float(np.mean(semantic)) if semantic else None
    if judged and "segments" in judged[0]:  # compose: per timeline position
        row["semantic_segments"] = [
            _mean_found([j["segments"][index] for j in judged]) for index in range(3)
        ]
    return row


# ---------------------------------------------------------------------------- the report


def format_table(results: dict) -> str:
    def f(value, digits=3):
        return "n/a" if value is None else f"{value:.{digits}f}"

    real, plain = results["real"], results["plain"]
    lines = [
        f"# Edit benchmark: {results['mode']} ({results['items']} edits per method)",
        "",
        "| method | err mean (m) | err max (m) | before keep (m) | miss >5 cm | miss >20 cm | "
        "seam acc (m/s²) | seam jerk (m/s³) | semantic | skate | R@3 | FID | ms / edit |",
        "| --- | " + " | ".join(["---"] * 12) + " |",
    ]
    for method, row in results["methods"].items():
        lines.append(
            f"| {method} | {f(row['err_mean'], 4)} | {f(row['err_max'], 4)} | "
            f"{f(row['before_keep'])} | {f(row['miss_5'])} | {f(row['miss_20'])} | "
            f"{f(row['seam_acc'], 1)} | {f(row['seam_jerk'], 0)} | {f(row['semantic'], 2)} | "
            f"{f(row['skate'])} | {f(row.get('r_precision_3'))} | {f(row.get('fid'), 2)} | "
            f"{f(row.get('ms_per_edit'), 0)} |"
        )
    lines.append(
        f"| plain generation | | | | | | {f(plain['seam_acc'], 1)} | {f(plain['seam_jerk'], 0)} | "
        f"{f(plain['semantic'], 2)} | {f(plain['skate'])} | "
        f"{f(plain.get('r_precision_3'))} | {f(plain.get('fid'), 2)} | |"
    )
    lines.append(
        f"| real motions | | | | | | {f(real['seam_acc'], 1)} | {f(real['seam_jerk'], 0)} | | "
        f"{f(real['skate'])} | {f(real.get('r_precision_3'))} | {f(real.get('fid'), 2)} | |"
    )
    if "semantic_segments" in plain:
        lines.append("")
        for name, row in [*results["methods"].items(), ("plain generation", plain)]:
            shares = " / ".join(f(v, 2) for v in row.get("semantic_segments", []))
            lines.append(f"Semantic per segment (first / second / third), {name}: {shares}.")
    lines += ["", f"Peak resident memory of the process: {results['peak_rss_mb']:.0f} MB."]
    if "paper_ms_per_edit" in results:
        timed = ", ".join(f"{m} {v:.0f}" for m, v in results["paper_ms_per_edit"].items())
        lines.append(f"Paper-size models (random weights), ms per edit: {timed}.")
    return "\n".join(lines) + "\n"


@command
def main(argv: list[str] | None = None) -> int:
    parser = CommandParser(
        prog="python -m t2m.evaluate --edit MODE",
        description="Measure one edit mode: constraint errors, seams, semantics, skating, "
        "R-precision/FID, latency; methods side by side.",
    )
    config = parse_config(parser, EditBenchConfig, argv)
    humanml3d.require_dataset(config.dataset)
    out = check_output_folder(
        config.out or config.checkpoints / "edit_results" / config.edit, "--out"
    )
    results = run_benchmark(config)
    out.mkdir(parents=True, exist_ok=True)
    table = format_table(results)
    write_text_atomic(out / "results.md", table)
    write_json_atomic(out / "results.json", results)
    print(table)
    print(f"wrote {out / 'results.md'} and {out / 'results.json'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
