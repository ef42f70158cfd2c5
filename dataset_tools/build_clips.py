"""The build's work on one clip: which clips an input gives (:func:`list_tasks`) and turning
one into its files (:func:`process_task`, run in worker processes by
:func:`dataset_tools.build.build_dataset`).

Per clip: read its captions and its source file -> resample to 20 fps -> segment (index) or crop
(seeded) -> mirror -> retarget, canonicalise, features (:func:`process_motion`) -> write
``new_joint_vecs/`` and ``new_joints/``. The captions come back in the :class:`ClipResult`; the
build tags and writes them, last, so a clip whose ``texts/`` files exist is finished
(:func:`is_finished`).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from dataset_tools import humanml3d, segment, texts
from dataset_tools.humanml3d import Caption, mirror_name
from dataset_tools.io import save_npy_atomic
from dataset_tools.mirror import mirror_joints
from dataset_tools.representation import process_motion
from dataset_tools.skeleton import SMPL
from dataset_tools.sources import ClipError, ClipTask, Motion, fps_problem
from dataset_tools.spec import HUMANML3D

if TYPE_CHECKING:
    from dataset_tools.build_config import BuildConfig

DATASET_FPS = HUMANML3D.fps
"""The rate every built dataset is written at (HumanML3D's)."""


@dataclass
class ClipResult:
    """What a worker reports for one task."""

    name: str
    path: str
    error: str | None = None
    frames: int = 0
    source_frames: int = 0
    source_fps: float = 0.0
    captions: list[Caption] = field(default_factory=list)
    seconds: dict[str, float] = field(default_factory=dict)


@dataclass(frozen=True)
class WorkerContext:
    """What every worker needs besides its task (picklable)."""

    out_dir: Path
    options: dict
    target_offsets: np.ndarray | None
    max_frames: int
    seed: int


# ----------------------------------------------------------------------------- file writing


def output_paths(out_dir: Path, name: str) -> list[Path]:
    """Every file a finished clip has (texts last: they are written after the motions)."""
    return [
        path for clip in (name, mirror_name(name)) for path in humanml3d.clip_files(out_dir, clip)
    ]


def is_finished(out_dir: Path, name: str) -> bool:
    return all(path.is_file() for path in output_paths(out_dir, name))


# ----------------------------------------------------------------------------- task listing


def _caption_path(config: BuildConfig, name: str) -> str | None:
    texts_dir = config.texts_dir
    if texts_dir is None and (config.input_dir / "texts").is_dir():
        texts_dir = config.input_dir / "texts"
    return str(texts_dir / f"{name}.txt") if texts_dir is not None else None


def _name_from_relative(relative: Path) -> str:
    """Clip name from a path under the input folder: ``KIT/3/walk_poses.npz`` -> ``KIT_3_walk_poses``."""
    return "_".join(relative.with_suffix("").parts)


def _resolve_index_path(input_dir: Path, source_path: str, suffix: str) -> Path:
    """Find an index row's file under ``input_dir`` (with or without the ``pose_data/`` prefix)."""
    relative = Path(source_path)
    parts = [part for part in relative.parts if part not in (".", "")]
    candidates = [Path(*parts)]
    if parts and parts[0] == "pose_data":
        candidates.append(Path(*parts[1:]))
    for candidate in candidates:
        for path in (input_dir / candidate, input_dir / candidate.with_suffix(suffix)):
            if path.is_file():
                return path
    return input_dir / candidates[-1].with_suffix(suffix)


def list_tasks(config: BuildConfig) -> list[ClipTask]:
    """One task per output clip, in a stable order. Raises ValueError for an unusable input."""
    input_dir = config.input_dir
    suffix = {"amass": ".npz", "joints": ".npy", "bvh": ".bvh"}[config.source]
    if config.index is not None:
        tasks = []
        for row in segment.read_index(config.index):
            path = _resolve_index_path(input_dir, row.source_path, suffix)
            # Only the reference joint layout (its pose_data, reflected by an axis swap) needs the
            # x negation; our AMASS reader already returns a proper right-handed y-up frame.
            negate = config.source == "joints" and not row.is_humanact12
            tasks.append(
                ClipTask(
                    name=row.new_name,
                    path=str(path),
                    start_frame=0 if row.is_humanact12 else row.start_frame,
                    end_frame=None if row.is_humanact12 else row.end_frame,
                    trim_seconds=0.0
                    if row.is_humanact12
                    else segment.trim_seconds_for(row.source_path),
                    negate_x=negate,
                    caption_path=_caption_path(config, row.new_name),
                    segmented=not row.is_humanact12,
                )
            )
        return tasks
    folder = input_dir
    if config.source == "joints":
        from dataset_tools.sources.joints import joints_folder

        folder = joints_folder(input_dir)
    files = (
        sorted(folder.rglob(f"*{suffix}"))
        if config.source != "joints"
        else sorted(folder.glob(f"*{suffix}"))
    )
    tasks = []
    for path in files:
        name = _name_from_relative(path.relative_to(folder))
        tasks.append(ClipTask(name=name, path=str(path), caption_path=_caption_path(config, name)))
    return tasks


# ----------------------------------------------------------------------------- per-clip work

_LOADED: dict[str, Motion] = {}  # the last file read by this process (index rows share files)


def load_motion(path: str, options: dict) -> Motion:
    """Read one source file with the loader its suffix names; y-up metres, any fps."""
    if path in _LOADED:
        return _LOADED[path]
    if not Path(path).is_file():
        raise ClipError("source file not found")
    suffix = Path(path).suffix.lower()
    if suffix == ".npz":
        from dataset_tools.sources.amass import load_amass

        motion = load_amass(path, options["body_model_dir"])
    elif suffix == ".npy":
        from dataset_tools.sources.joints import JointsOptions, load_joints

        motion = load_joints(path, JointsOptions(fps=options["fps"], up=options["up"]))
    elif suffix == ".bvh":
        from dataset_tools.sources.bvh import BvhOptions, load_bvh_motion

        motion = load_bvh_motion(path, BvhOptions(**options["bvh"]))
    else:
        raise ValueError(f"no reader for {suffix!r} files")
    _LOADED.clear()
    _LOADED[path] = motion
    return motion


def _cut(task: ClipTask, joints: np.ndarray, context: WorkerContext) -> tuple[np.ndarray, float]:
    """Segment by the task's index rules, or crop to ``max_frames``.

    Returns (joints, seconds to shift caption times by): 0 for index segments, whose captions
    are already timed within the segment (as HumanML3D's are), the crop start otherwise.
    """
    if task.segmented:
        cut = segment.cut_segment(
            joints, task.start_frame, task.end_frame, task.trim_seconds, task.negate_x, DATASET_FPS
        )
        return cut, 0.0
    if task.negate_x:
        joints = segment.cut_segment(joints, 0, None, negate_x=True)
    cropped, start = segment.random_crop(
        joints, context.max_frames, segment.clip_rng(task.name, context.seed)
    )
    return cropped, start / DATASET_FPS


def read_captions(task: ClipTask) -> list[Caption]:
    """The task's caption file, else captions from the source's own labels (Bandai-Namco BVH).

    Raises ClipError when there is neither or the caption file is unusable.
    """
    if task.caption_path is not None and Path(task.caption_path).is_file():
        try:
            return texts.read_caption_file(task.caption_path)
        except ValueError as error:  # not UTF-8, empty, or a malformed line
            raise ClipError(str(error)) from error
    if Path(task.path).suffix.lower() == ".bvh":
        from dataset_tools.sources.bvh import label_captions

        labelled = label_captions(task.path)
        if labelled:
            return [Caption(text) for text in labelled]
    raise ClipError("no caption file")


def process_task(task: ClipTask, context: WorkerContext) -> ClipResult:
    """Turn one task into its two clips (plain and mirrored) on disk; captions are returned.

    A clip whose data is unusable (ClipError) or whose file cannot be read (OSError) comes back
    with ``error`` set; anything else is a bug and propagates.
    """
    result = ClipResult(name=task.name, path=task.path)
    clock = time.perf_counter()
    try:
        captions = read_captions(task)
        motion = load_motion(task.path, context.options)
        result.source_frames, result.source_fps = len(motion.joints), motion.fps
        if not np.isfinite(motion.joints).all():
            bad = int((~np.isfinite(motion.joints)).any(axis=(1, 2)).sum())
            raise ClipError(f"{bad} frame(s) contain NaN or inf")
        if (problem := fps_problem(motion.fps)) is not None:
            raise ClipError(problem)
        joints = segment.resample(motion.joints, motion.fps, DATASET_FPS)
        result.seconds["load"] = time.perf_counter() - clock

        clock = time.perf_counter()
        joints, offset = _cut(task, joints, context)
        if len(joints) < 2:
            raise ClipError(f"only {len(joints)} frame(s) at {DATASET_FPS:g} fps; need at least 2")
        captions = texts.shift_captions(captions, offset, (len(joints) - 1) / DATASET_FPS)
        if not captions:
            raise ClipError("no caption falls inside the clip")
        mirrored = mirror_joints(joints)[:, :22]
        outputs = {}
        for name, clip in ((task.name, joints[:, :22]), (mirror_name(task.name), mirrored)):
            try:
                features, recovered = process_motion(clip, SMPL, context.target_offsets)
            except ValueError as error:  # degenerate motion, refused by process_motion
                raise ClipError(str(error)) from None
            with np.errstate(over="ignore", invalid="ignore"):
                features, recovered = features.astype(np.float32), recovered.astype(np.float32)
            if not (np.isfinite(features).all() and np.isfinite(recovered).all()):
                raise ClipError("features came out non-finite (coordinates too large?)")
            outputs[name] = (features, recovered)
        result.seconds["features"] = time.perf_counter() - clock

        clock = time.perf_counter()
        for name, (features, recovered) in outputs.items():
            save_npy_atomic(humanml3d.features_path(context.out_dir, name), features)
            save_npy_atomic(humanml3d.joints_path(context.out_dir, name), recovered)
        result.seconds["write"] = time.perf_counter() - clock
        result.frames = len(outputs[task.name][0])
        result.captions = captions
    except (ClipError, OSError) as error:
        result.error = str(error) or type(error).__name__
    return result


def process_star(arguments: tuple[ClipTask, WorkerContext]) -> ClipResult:
    # Looked up at call time (not bound), so a test can replace process_task in workers too.
    return process_task(*arguments)
