"""Build a HumanML3D-layout dataset from AMASS, joint arrays or BVH files.

``python -m dataset_tools build --source amass|joints|bvh --input DIR --out DIR ...`` or
:func:`build_dataset`. Per clip: load -> resample to 20 fps -> segment (index) or crop (10 s,
seeded) -> mirror -> retarget, canonicalise, features (:func:`process_motion`) -> write
``new_joint_vecs/`` and ``new_joints/``; captions are tagged with spaCy in batches and written
last, so a clip whose ``texts/`` files exist is finished and a re-run skips it. Then Mean/Std,
splits and ``build_report.json`` (file names: :mod:`dataset_tools.humanml3d`). A clip whose data
is unusable (:class:`~dataset_tools.sources.ClipError`, or an unreadable file) is reported with its
reason and skipped; any other error stops the build.

What keeps a dataset folder safe: every option, input and output path is checked before any
work (:meth:`BuildConfig.validate`); the folder's options record, its lock and the refusal of
clip names that would collide live in :mod:`dataset_tools.build_safety`; temporary files that a
killed build left are removed when the next one starts; a worker process that dies (the
out-of-memory killer) stops the build with one line, the clips finished so far stay and a
re-run resumes.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import platform
import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Literal

import numpy as np
from tqdm import tqdm

from dataset_tools import humanml3d, segment, texts
from dataset_tools.build_safety import claim_output, exclusive, refuse_unsafe_names
from dataset_tools.command import (
    CommandParser,
    UsageError,
    add_config_options,
    command,
    config_from_args,
    configure_logging,
    option,
)
from dataset_tools.humanml3d import Caption, mirror_name
from dataset_tools.io import (
    check_output_folder,
    load_npy,
    remove_partial_files,
    save_npy_atomic,
    write_bytes_atomic,
    write_json_atomic,
)
from dataset_tools.mirror import mirror_caption, mirror_joints
from dataset_tools.parallel import imap_unordered
from dataset_tools.representation import FeatureLayout, process_motion, target_offsets_from_example
from dataset_tools.skeleton import SMPL
from dataset_tools.sources import ClipError, ClipTask, Motion, fps_problem
from dataset_tools.spec import HUMANML3D
from dataset_tools.stats import FeatureStats, mean_and_pooled_std

logger = logging.getLogger(__name__)

SOURCES = ("amass", "joints", "bvh")
DATASET_FPS = HUMANML3D.fps
SPLIT_FRACTIONS = (0.80, 0.05, 0.15)
# Captions are tagged and written in chunks of this many clips: one spaCy pass per chunk is
# fast, and a crash loses at most one chunk of finished motions' texts (re-done on resume).
CAPTION_CHUNK = 512


@dataclass
class BuildConfig:
    """Everything a build needs; each field is an option of ``python -m dataset_tools build``."""

    source: str = field(metadata=option(choices=SOURCES))
    """kind of input files"""
    input_dir: Path = field(metadata=option("--input", metavar="DIR"))
    """folder of source files (searched recursively for .npz / .bvh; for joints, the folder itself
    or its joints/ subfolder, or the index's paths relative to it)"""
    out_dir: Path = field(metadata=option("--out", metavar="DIR"))
    """dataset folder to write"""
    texts_dir: Path | None = field(default=None, metadata=option("--texts", metavar="DIR"))
    """caption files <clip name>.txt, one caption a line, optionally caption#start#end in seconds
    (default: INPUT/texts when it exists)"""
    index: Path | None = field(default=None, metadata=option(metavar="CSV"))
    """HumanML3D's index.csv segmenting the sources (the reference pipeline's rules apply)"""
    body_model_dir: Path | None = field(
        default=None, metadata=option("--body-model", metavar="DIR")
    )
    """SMPL-H body models (male|female|neutral/model.npz), for AMASS"""
    mapping: str | None = field(default=None, metadata=option(metavar="NAME|FILE"))
    """BVH joint mapping: a built-in name (bandai, cmu_cc, smpl) or a JSON file (default: detected
    from the joint names)"""
    fps: float | None = None
    """frame rate of joint arrays (default: source.json, else 20 with --index)"""
    up: Literal["y", "z"] | None = None
    """up axis of joint arrays and BVH files (default: source.json, else y)"""
    bvh_scale: float | None = field(default=None, metadata=option(metavar="S"))
    """metres per BVH unit (default: detected from the body size)"""
    drop_first_frame: bool | None = field(
        default=None, metadata=option(negative="--keep-first-frame")
    )
    """drop a leading BVH T-pose frame (default: per mapping)"""
    target_skeleton: Path | None = field(default=None, metadata=option(metavar="NPY"))
    """a (>=22, 3) frame whose bone lengths define the target skeleton (default: HumanML3D's)"""
    splits_dir: Path | None = field(default=None, metadata=option("--splits", metavar="DIR"))
    """reuse train/val/test.txt from this folder (default: seeded 80/5/15 by source file)"""
    max_seconds: float = 10.0
    """crop longer clips (seeded) unless an index segments them"""
    workers: int = 1
    """parallel processes (the output does not depend on it; the command's default: the CPU
    cores, at most 8)"""
    force: bool = False
    """rebuild clips already finished"""
    seed: int = 0
    """seed for crops and splits"""
    spacy_pos: bool = False
    """tag captions with spaCy 3's own POS (possessives such as his/their PRON) instead of the
    published HumanML3D texts' (DET)"""

    def validate(self) -> None:
        """Raise UsageError, naming the option, for a configuration that cannot work (cheap:
        values, the named files and the output folder; what depends on the source, such as a
        missing --fps or --body-model, is checked when the build reads its source options)."""
        if self.source not in SOURCES:
            raise UsageError(f"unknown --source {self.source!r} (choose from {', '.join(SOURCES)})")
        most_workers = 4 * (os.cpu_count() or 1)
        if not 1 <= self.workers <= most_workers:
            raise UsageError(
                f"--workers must be between 1 and {most_workers} (4 per CPU core), "
                f"got {self.workers}"
            )
        if self.seed < 0:
            raise UsageError(f"--seed must be 0 or more, got {self.seed}")
        shortest = 2 / DATASET_FPS  # two frames, the fewest a clip has features for
        if not (np.isfinite(self.max_seconds) and self.max_seconds >= shortest):
            raise UsageError(
                f"--max-seconds must be a number of seconds >= {shortest:g}, got {self.max_seconds}"
            )
        if self.bvh_scale is not None and not (np.isfinite(self.bvh_scale) and self.bvh_scale > 0):
            raise UsageError(f"--bvh-scale must be a positive number, got {self.bvh_scale}")
        if self.fps is not None and (problem := fps_problem(self.fps)) is not None:
            raise UsageError(f"--fps: {problem}")
        if not self.input_dir.is_dir():
            raise UsageError(f"input folder {self.input_dir} does not exist")
        for name, folder in (("--texts", self.texts_dir), ("--splits", self.splits_dir)):
            if folder is not None and not folder.is_dir():
                raise UsageError(f"{name} folder {folder} does not exist")
        for name, file in (("--index", self.index), ("--target-skeleton", self.target_skeleton)):
            if file is not None and not file.is_file():
                raise UsageError(f"{name} file {file} not found")
        if self.target_skeleton is not None:
            frame = load_npy(self.target_skeleton)
            if frame.ndim != 2 or frame.shape[0] < SMPL.num_joints or frame.shape[1] != 3:
                raise UsageError(
                    f"--target-skeleton {self.target_skeleton}: expected one frame "
                    f"(>= {SMPL.num_joints}, 3), got {frame.shape}"
                )
        if self.splits_dir is not None:
            for split in ("train", "val", "test"):
                if not humanml3d.split_path(self.splits_dir, split).is_file():
                    raise UsageError(f"--splits folder {self.splits_dir} has no {split}.txt")
        self._validate_output()

    def content_options(self, reading: dict) -> dict:
        """The options that decide what a clip's files hold (JSON values), for
        ``build_options.json`` (:func:`~dataset_tools.build_safety.claim_output`).

        The source kind, the resolved reading options ``reading`` (frame rate, up axis, BVH
        mapping, scale and first frame), crop length and seed, and the content (SHA-256) of the
        small files that shape clips: index, target skeleton, mapping file. Where files live is
        not part of it (the same sources moved elsewhere give the same clips); neither are the
        worker count, the splits (rewritten by every run) or the caption files (a changed caption
        needs ``--force``).
        """
        mapping_file = Path(self.mapping) if self.mapping and Path(self.mapping).is_file() else None
        record = {
            "source": self.source,
            "reading": {key: value for key, value in reading.items() if key != "body_model_dir"},
            "max_seconds": self.max_seconds,
            "seed": self.seed,
            "index_sha256": _sha256(self.index),
            "target_skeleton_sha256": _sha256(self.target_skeleton),
            "mapping_sha256": _sha256(mapping_file),
        }
        return json.loads(json.dumps(record))  # tuples as lists, as they read back

    def _validate_output(self) -> None:
        """The output folder can be written and is none of the folders the build reads (it
        rewrites ``texts/`` and the split files, and would read its own outputs as sources)."""
        check_output_folder(self.out_dir, "--out folder")
        out = self.out_dir.resolve()
        if out == self.input_dir.resolve():
            raise UsageError(f"--out {self.out_dir} must not be the --input folder")
        if self.texts_dir is not None and self.texts_dir.resolve() == out / humanml3d.TEXTS_DIR:
            raise UsageError(
                f"--texts {self.texts_dir} is the texts/ folder the build writes; "
                "copy the caption files elsewhere"
            )
        if self.splits_dir is not None and self.splits_dir.resolve() == out:
            raise UsageError(
                f"--splits {self.splits_dir} is the folder whose split files the build writes; "
                "copy them elsewhere"
            )


def _sha256(path: Path | None) -> str | None:
    return None if path is None else hashlib.sha256(path.read_bytes()).hexdigest()


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
class _WorkerContext:
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


def _cut(task: ClipTask, joints: np.ndarray, context: _WorkerContext) -> tuple[np.ndarray, float]:
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


def process_task(task: ClipTask, context: _WorkerContext) -> ClipResult:
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


def _process_star(arguments: tuple[ClipTask, _WorkerContext]) -> ClipResult:
    # Looked up at call time (not bound), so a test can replace process_task in workers too.
    return process_task(*arguments)


# ----------------------------------------------------------------------------- captions


def write_captions(out_dir: Path, results: Sequence[ClipResult], spacy_pos: bool = False) -> None:
    """Tag the captions of finished clips (and their mirrors) in one spaCy pass and write texts/
    (``spacy_pos``: see :func:`dataset_tools.texts.tag_captions`)."""
    jobs: list[tuple[str, list[Caption]]] = []
    for result in results:
        jobs.append((result.name, result.captions))
        mirrored = [replace(c, text=mirror_caption(c.text)) for c in result.captions]
        jobs.append((mirror_name(result.name), mirrored))
    tagged = texts.tag_captions(
        [caption.text for _, captions in jobs for caption in captions], spacy_pos=spacy_pos
    )
    position = 0
    for name, captions in jobs:
        lines = []
        for caption in captions:
            lines.append(humanml3d.format_caption_line(caption, tagged[position]))
            position += 1
        humanml3d.write_texts(out_dir, name, lines)


# ----------------------------------------------------------------------------- splits


def make_splits(
    groups: dict[str, list[str]], seed: int, splits_dir: Path | None = None
) -> tuple[dict[str, list[str]], list[str]]:
    """Split clip names into train/val/test; returns (splits, clips missing from given splits).

    ``groups`` maps a source file to its clip names (no mirrors). Without ``splits_dir`` whole
    groups are shuffled with ``seed`` and cut 80/5/15, so segments of one capture never straddle
    splits; every clip's mirror follows it.
    """
    splits: dict[str, list[str]] = {"train": [], "val": [], "test": []}
    unassigned: list[str] = []
    if splits_dir is not None:
        assigned: dict[str, str] = {}
        for split in splits:
            try:
                listed = humanml3d.read_split(splits_dir, split)
            except (OSError, ValueError) as error:  # missing, or not UTF-8
                raise UsageError(
                    f"--splits {splits_dir}: cannot read {split}.txt ({error})"
                ) from None
            for name in listed:
                assigned.setdefault(name, split)
        for names in groups.values():
            for name in names:
                split = assigned.get(name)
                if split is None:
                    unassigned.append(name)
                else:
                    splits[split] += [name, mirror_name(name)]
    else:
        keys = sorted(groups)
        order = np.random.default_rng(seed).permutation(len(keys))
        cut_train = int(round(SPLIT_FRACTIONS[0] * len(keys)))
        cut_val = int(round((SPLIT_FRACTIONS[0] + SPLIT_FRACTIONS[1]) * len(keys)))
        for position, key_index in enumerate(order):
            split = "train" if position < cut_train else "val" if position < cut_val else "test"
            for name in groups[keys[key_index]]:
                splits[split] += [name, mirror_name(name)]
    return {split: sorted(names) for split, names in splits.items()}, sorted(unassigned)


# ----------------------------------------------------------------------------- the build


def _versions() -> dict[str, str]:
    import scipy
    import spacy

    import dataset_tools

    versions = {
        "python": platform.python_version(),
        "numpy": np.__version__,
        "scipy": scipy.__version__,
        "spacy": spacy.__version__,
        "dataset_tools": getattr(dataset_tools, "__version__", "0.1.0"),
    }
    try:
        versions["spacy_model"] = texts.spacy_model_version()
    except RuntimeError:
        versions["spacy_model"] = "none"
    return versions


def _source_options(config: BuildConfig) -> dict:
    """Per-source reading options, resolved from flags and ``source.json``; UsageError (one
    line) for options or shared files (source.json, mapping, body models) that cannot work."""
    options: dict = {
        "body_model_dir": str(config.body_model_dir) if config.body_model_dir else None,
        # Joint arrays met by another source (HumanAct12 rows of an AMASS index) are in the
        # reference pose_data layout: 20 fps, y-up.
        "fps": DATASET_FPS,
        "up": "y",
    }
    if config.source == "joints":
        from dataset_tools.sources.joints import read_source_config

        source_config = read_source_config(config.input_dir)
        fps = config.fps or source_config.get("fps") or (DATASET_FPS if config.index else None)
        if fps is None:
            raise UsageError("--fps is required for joint arrays without a source.json or --index")
        options["fps"] = float(fps)
        options["up"] = config.up or source_config.get("up", "y")
    if config.source == "amass":
        _check_body_models(config.body_model_dir)
    if config.source == "bvh":
        from dataset_tools.sources.bvh import load_mapping

        if config.mapping is not None:
            try:
                load_mapping(config.mapping)
            except ValueError as error:
                raise UsageError(f"--mapping: {error}") from None
        options["bvh"] = {
            "mapping": config.mapping,
            "scale": config.bvh_scale,
            "up": config.up or "y",
            "drop_first_frame": config.drop_first_frame,
        }
    return options


def _check_body_models(folder: Path | None) -> None:
    """Load every body model under ``folder`` once (cached: forked workers inherit them), so a
    broken one is one line now rather than a failure in every clip."""
    from dataset_tools.sources.amass import GENDERS, NUM_JOINTS, load_body_model

    if folder is None or not folder.is_dir():
        raise UsageError(
            "--body-model DIR (with male|female|neutral/model.npz) is required for AMASS"
        )
    paths = [folder / gender / "model.npz" for gender in GENDERS]
    if not any(path.is_file() for path in paths):
        raise UsageError(f"--body-model {folder} has no male|female|neutral/model.npz")
    for path in paths:
        if path.is_file():
            try:
                model = load_body_model(str(path))
            except ValueError as error:
                raise UsageError(f"--body-model: {error}") from None
            if len(model.parents) != NUM_JOINTS:
                raise UsageError(
                    f"--body-model: {path} has {len(model.parents)} joints, SMPL-H has {NUM_JOINTS}"
                )


def _read_clip_features(out_dir: Path, name: str) -> np.ndarray:
    """``new_joint_vecs/<name>.npy`` of a built clip; UsageError naming the file when it cannot
    be read (damaged after it was written: the build's own writes are atomic)."""
    try:
        return load_npy(humanml3d.features_path(out_dir, name), finite=False)
    except UsageError as error:
        raise UsageError(f"{error}; delete it and run the build again to rebuild it") from None


def compute_stats(out_dir: Path, names: Sequence[str]) -> tuple[np.ndarray, np.ndarray, dict]:
    """Mean/Std over the features of ``names`` (their files in ``new_joint_vecs``); the info
    dict counts their frames (``frames_out``) and the frames the statistics used (``frames``)."""
    layout = FeatureLayout(SMPL.num_joints)
    stats = FeatureStats(layout.dim)
    skipped = []
    frames_out = 0
    for name in tqdm(names, desc="stats", unit="clip", leave=False, disable=len(names) < 1000):
        features = _read_clip_features(out_dir, name)
        frames_out += len(features) if features.ndim else 0
        try:
            stats.add(features)
        except ValueError as error:
            skipped.append({"name": name, "reason": str(error)})
    if stats.count == 0:
        raise UsageError(f"no clip in {out_dir} has finite features; cannot compute Mean/Std")
    mean, std, constant = mean_and_pooled_std(stats, layout.groups())
    info = {"frames": stats.count, "skipped": skipped, "constant_groups": constant}
    return mean, std, info | {"frames_out": frames_out}


def build_dataset(config: BuildConfig) -> dict:
    """Build (or resume) the dataset described by ``config``; returns the build report.

    Raises UsageError for unusable configuration (missing input, unknown source, other options
    than the folder was built with, ...) and ChildProcessError when a worker process dies;
    clip-level problems (refused names included) are reported in ``report["skipped"]``.
    """
    started = time.perf_counter()
    timings: dict[str, float] = {}
    # 1. Check the configuration and list the clips, before touching the output folder.
    config.validate()
    options = _source_options(config)
    texts.load_nlp()  # fail now, not after the motion work, when no English model is installed
    target_offsets = None
    if config.target_skeleton is not None:
        target_offsets = target_offsets_from_example(load_npy(config.target_skeleton))
    record = config.content_options(options)
    clock = time.perf_counter()
    all_tasks = list_tasks(config)
    tasks, skipped = refuse_unsafe_names(all_tasks)
    timings["list_s"] = time.perf_counter() - clock

    with exclusive(config.out_dir) as lock:
        # 2. Claim the folder: clean up after a killed run, refuse other options.
        partial = [
            str(path)
            for folder in _folders(config.out_dir)
            for path in remove_partial_files(folder)
        ]
        if partial:
            logger.info("removed %d temporary file(s) of an interrupted build", len(partial))
        claim_output(config.out_dir, record, [task.name for task in tasks], config.force)
        humanml3d.make_folders(config.out_dir)
        todo = [task for task in tasks if not is_finished(config.out_dir, task.name)]
        logger.info("%d clips listed, %d to build", len(tasks), len(todo))
        context = _WorkerContext(
            out_dir=config.out_dir,
            options=options,
            target_offsets=target_offsets,
            max_frames=int(round(config.max_seconds * DATASET_FPS)),
            seed=config.seed,
        )
        built, clip_skips = _build_clips(todo, context, config, lock, timings)
        skipped += clip_skips
        report = _finish(config, all_tasks, tasks, built, skipped, timings, started)
        report["partial_files_removed"] = len(partial)
        _write_report(config.out_dir, report)
    return report


def _folders(out_dir: Path) -> list[Path]:
    """The dataset folder and its per-clip folders (where atomic writes leave temporaries)."""
    subfolders = (humanml3d.FEATURES_DIR, humanml3d.JOINTS_DIR, humanml3d.TEXTS_DIR)
    return [out_dir, *(out_dir / sub for sub in subfolders)]


def _build_clips(
    todo: Sequence[ClipTask],
    context: _WorkerContext,
    config: BuildConfig,
    lock: int,
    timings: dict[str, float],
) -> tuple[list[ClipResult], list[dict]]:
    """Motions in worker processes; captions tagged and written by chunk as clips finish (and
    for every finished clip when the build stops early). Returns (built, skipped entries)."""
    skipped: list[dict] = []
    built: list[ClipResult] = []
    pending: list[ClipResult] = []
    worker_seconds: dict[str, float] = {"load": 0.0, "features": 0.0, "write": 0.0}
    timings["captions_s"] = 0.0
    clock = time.perf_counter()

    def flush() -> None:
        caption_clock = time.perf_counter()
        write_captions(config.out_dir, pending, config.spacy_pos)
        timings["captions_s"] += time.perf_counter() - caption_clock
        pending.clear()

    progress = tqdm(total=len(todo), desc="build", unit="clip", disable=None)
    results = imap_unordered(
        _process_star,
        ((task, context) for task in todo),
        min(config.workers, len(todo)),
        initializer=os.close,  # the worker's copy of the folder lock (see exclusive)
        initargs=(lock,),
    )
    try:
        for result in results:
            progress.update()
            for step, seconds in result.seconds.items():
                worker_seconds[step] += seconds
            if result.error is not None:
                skipped.append({"name": result.name, "path": result.path, "reason": result.error})
                continue
            built.append(result)
            pending.append(result)
            if len(pending) >= CAPTION_CHUNK:
                flush()
    finally:
        # Clips whose motions are on disk get their texts (which mark them finished), also when
        # a worker died or the user interrupted: a re-run then resumes after them.
        if pending:
            flush()
        progress.close()
    timings["clips_s"] = time.perf_counter() - clock
    for step, seconds in worker_seconds.items():
        timings[f"worker_{step}_s"] = seconds
    return built, skipped


def _finish(
    config: BuildConfig,
    all_tasks: Sequence[ClipTask],
    tasks: Sequence[ClipTask],
    built: Sequence[ClipResult],
    skipped: list[dict],
    timings: dict[str, float],
    started: float,
) -> dict:
    """Statistics and splits over every finished clip (this run's and earlier runs'); the report."""
    clock = time.perf_counter()
    skipped_names = {entry["name"] for entry in skipped}
    finished = [
        t for t in tasks if t.name not in skipped_names and is_finished(config.out_dir, t.name)
    ]
    if not finished:
        return _report(config, all_tasks, built, skipped, [], timings, started, {})
    all_names = sorted(name for task in finished for name in (task.name, mirror_name(task.name)))
    mean, std, stats_info = compute_stats(config.out_dir, all_names)
    humanml3d.write_mean_std(config.out_dir, mean, std)
    timings["stats_s"] = time.perf_counter() - clock

    clock = time.perf_counter()
    stats_skipped = {entry["name"] for entry in stats_info["skipped"]}
    groups: dict[str, list[str]] = {}
    for task in finished:
        if task.name not in stats_skipped and mirror_name(task.name) not in stats_skipped:
            groups.setdefault(task.path, []).append(task.name)
    splits, unassigned = make_splits(groups, config.seed, config.splits_dir)
    split_names = sorted(
        name for names in groups.values() for n in names for name in (n, mirror_name(n))
    )
    humanml3d.write_splits(config.out_dir, splits, split_names)
    timings["splits_s"] = time.perf_counter() - clock

    stats_info["unassigned_to_splits"] = unassigned
    labels = config.input_dir / humanml3d.LABELS_FILE
    if labels.is_file():
        # Ground-truth labels of a procedural corpus travel with the dataset, for evaluation.
        write_bytes_atomic(config.out_dir / humanml3d.LABELS_FILE, labels.read_bytes())
    report = _report(config, all_tasks, built, skipped, finished, timings, started, stats_info)
    report["splits"] = {split: len(names) for split, names in splits.items()}
    return report


def _report(
    config: BuildConfig,
    tasks: Sequence[ClipTask],
    built: Sequence[ClipResult],
    skipped: list[dict],
    finished: Sequence[ClipTask],
    timings: dict[str, float],
    started: float,
    stats_info: dict,
) -> dict:
    """The content of ``build_report.json``."""
    frames = stats_info.pop("frames_out", 0)
    seconds_in = sum(r.source_frames / r.source_fps for r in built if r.source_fps > 0)
    timings["total_s"] = time.perf_counter() - started
    config_dict = {
        key: (str(value) if isinstance(value, Path) else value)
        for key, value in asdict(config).items()
    }
    return {
        "config": config_dict,
        "clips_in": len(tasks),
        "clips_built_this_run": len(built),
        "clips_resumed": len(finished) - len(built) if finished else 0,
        "clips_out": 2 * len(finished),
        "source_hours_read_this_run": seconds_in / 3600.0,
        "frames_out": frames,
        "hours_out": frames / DATASET_FPS / 3600.0,
        "skipped": skipped,
        "stats": stats_info,
        "timings": {key: round(value, 4) for key, value in timings.items()},
        "versions": _versions(),
    }


def _write_report(out_dir: Path, report: dict) -> None:
    write_json_atomic(out_dir / humanml3d.REPORT_FILE, report)


# ----------------------------------------------------------------------------- command line


@command
def main(argv: Sequence[str] | None = None) -> int:
    """``python -m dataset_tools build ...``: 0 on success, 1 when no clip was built, 2 on bad input."""
    parser = CommandParser(
        prog="python -m dataset_tools build",
        description="Build a HumanML3D-layout dataset (new_joint_vecs/, new_joints/, texts/, "
        "Mean.npy, Std.npy, split files, build_report.json) from motion sources.",
    )
    add_config_options(parser, BuildConfig, defaults={"workers": min(os.cpu_count() or 1, 8)})
    parser.add_argument("-v", "--verbose", action="store_true", help="log debug details")
    arguments = parser.parse_args(argv)
    configure_logging(arguments.verbose)
    config = config_from_args(BuildConfig, arguments)
    config.validate()
    try:
        texts.load_nlp()  # the English spaCy model is an install step: say which, before any work
    except RuntimeError as error:
        raise UsageError(str(error)) from None
    report = build_dataset(config)
    for entry in report["skipped"]:
        logger.warning("skipped %s: %s", entry["name"], entry["reason"])
    print(
        f"{report['clips_out']} clips ({report['hours_out']:.2f} h) in {config.out_dir}; "
        f"{len(report['skipped'])} skipped (see build_report.json)"
    )
    return 0 if report["clips_out"] else 1
