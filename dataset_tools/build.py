"""Build a HumanML3D-layout dataset from AMASS, joint arrays or BVH files.

``python -m dataset_tools build --source amass|joints|bvh --input DIR --out DIR ...`` or
:func:`build_dataset`. Per clip, in worker processes (:mod:`dataset_tools.build_clips`): load
-> resample to 20 fps -> segment (index) or crop (10 s, seeded) -> mirror -> retarget,
canonicalise, features (:func:`process_motion`) -> write ``new_joint_vecs/`` and
``new_joints/``; captions are tagged with spaCy in batches and written last, so a clip whose
``texts/`` files exist is finished and a re-run skips it. Then Mean/Std, splits and
``build_report.json`` (file names: :mod:`dataset_tools.humanml3d`). A clip whose data
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

import json
import logging
import os
import platform
import time
from collections.abc import Sequence
from dataclasses import asdict, replace
from pathlib import Path

import numpy as np
from tqdm import tqdm

from dataset_tools import humanml3d, texts
from dataset_tools.build_clips import (
    DATASET_FPS,
    ClipResult,
    WorkerContext,
    is_finished,
    list_tasks,
    process_star,
)
from dataset_tools.build_config import BuildConfig
from dataset_tools.build_safety import claim_output, exclusive, refuse_unsafe_names
from dataset_tools.command import (
    CommandParser,
    UsageError,
    add_config_options,
    command,
    config_from_args,
    configure_logging,
)
from dataset_tools.humanml3d import Caption, mirror_name
from dataset_tools.io import (
    load_npy,
    remove_partial_files,
    write_bytes_atomic,
    write_json_atomic,
)
from dataset_tools.mirror import mirror_caption
from dataset_tools.parallel import imap_unordered
from dataset_tools.representation import FeatureLayout, target_offsets_from_example
from dataset_tools.skeleton import SMPL
from dataset_tools.sources import ClipTask
from dataset_tools.stats import FeatureStats, mean_and_pooled_std

logger = logging.getLogger(__name__)

SPLIT_FRACTIONS = (0.80, 0.05, 0.15)
# Captions are tagged and written in chunks of this many clips: one spaCy pass per chunk is
# fast, and a crash loses at most one chunk of finished motions' texts (re-done on resume).
CAPTION_CHUNK = 512


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

_FIXED_SPLITS = frozenset({"train", "val", "test", "train_val", "all"})


def pinned_splits(input_dir: Path, names: list[str]) -> dict[str, str]:
    """Clips of ``names`` whose label in the source's ``labels.json`` names a split of their
    own (``"split": "test_paraphrase"``, the demo corpus's held-out phrasings): clip -> split.
    Such clips (and their mirrors) go to that split file only, never to train/val/test."""
    path = Path(input_dir) / humanml3d.LABELS_FILE
    if not path.is_file():
        return {}
    clips = json.loads(path.read_text(encoding="utf-8")).get("clips", {})
    pinned = {}
    for name in names:
        split = clips.get(name, {}).get("split") if isinstance(clips.get(name), dict) else None
        if split is None:
            continue
        if not (isinstance(split, str) and split.isidentifier() and split not in _FIXED_SPLITS):
            raise UsageError(f"{path}: clip {name} names split {split!r}, not a new split name")
        pinned[name] = split
    return pinned


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
        context = WorkerContext(
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
    context: WorkerContext,
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
        process_star,
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
    # clips pinned to a split of their own (a held-out test) stay out of the statistics too, so
    # that adding them changes nothing the stages train on
    pinned = pinned_splits(config.input_dir, [task.name for task in finished])
    held = {name for clip in pinned for name in (clip, mirror_name(clip))}
    mean, std, stats_info = compute_stats(config.out_dir, [n for n in all_names if n not in held])
    humanml3d.write_mean_std(config.out_dir, mean, std)
    timings["stats_s"] = time.perf_counter() - clock

    clock = time.perf_counter()
    stats_skipped = {entry["name"] for entry in stats_info["skipped"]}
    groups: dict[str, list[str]] = {}
    for task in finished:
        if task.name not in stats_skipped and mirror_name(task.name) not in stats_skipped:
            groups.setdefault(task.path, []).append(task.name)
    split_names = sorted(
        name for names in groups.values() for n in names for name in (n, mirror_name(n))
    )
    groups = {path: [n for n in names if n not in pinned] for path, names in groups.items()}
    splits, unassigned = make_splits(
        {path: names for path, names in groups.items() if names}, config.seed, config.splits_dir
    )
    humanml3d.write_splits(config.out_dir, splits, split_names)
    for split in sorted(set(pinned.values())):
        splits[split] = sorted(
            name for n, s in pinned.items() if s == split for name in (n, mirror_name(n))
        )
        humanml3d.write_split(config.out_dir, split, splits[split])
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
