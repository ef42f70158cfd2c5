"""The options of a dataset build (:class:`BuildConfig`, one field per option of ``python -m
dataset_tools build``) and their checks, which run before any work: read by the build
(:mod:`dataset_tools.build`) and by each clip's work (:mod:`dataset_tools.build_clips`)."""

from __future__ import annotations

import hashlib
import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np

from dataset_tools import humanml3d
from dataset_tools.command import UsageError, option
from dataset_tools.io import check_output_folder, load_npy
from dataset_tools.skeleton import SMPL
from dataset_tools.sources import fps_problem
from dataset_tools.spec import HUMANML3D

SOURCES = ("amass", "joints", "bvh")


def _sha256(path: Path | None) -> str | None:
    return None if path is None else hashlib.sha256(path.read_bytes()).hexdigest()


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
        self._validate_values()
        self._validate_inputs()
        self._validate_output()

    def _validate_values(self) -> None:
        """The options that are plain values: source kind, workers, seed, lengths, scale, fps."""
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
        shortest = 2 / HUMANML3D.fps  # two frames, the fewest a clip has features for
        if not (np.isfinite(self.max_seconds) and self.max_seconds >= shortest):
            raise UsageError(
                f"--max-seconds must be a number of seconds >= {shortest:g}, got {self.max_seconds}"
            )
        if self.bvh_scale is not None and not (np.isfinite(self.bvh_scale) and self.bvh_scale > 0):
            raise UsageError(f"--bvh-scale must be a positive number, got {self.bvh_scale}")
        if self.fps is not None and (problem := fps_problem(self.fps)) is not None:
            raise UsageError(f"--fps: {problem}")

    def _validate_inputs(self) -> None:
        """The folders and files the build reads exist and hold what it needs."""
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
