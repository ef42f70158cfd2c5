"""Command lines: ``python -m dataset_tools synth`` and ``python -m dataset_tools contact-sheet``."""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from dataset_tools import humanml3d
from dataset_tools.command import (
    CommandParser,
    UsageError,
    command,
    parse_config,
)
from dataset_tools.io import check_output_file, load_npy
from dataset_tools.rotations import to_y_up


@dataclass
class SynthConfig:
    """``python -m dataset_tools synth``: what :func:`dataset_tools.synth.corpus.write_corpus` writes."""

    out: Path
    """output folder"""
    clips: int = 2000
    """number of clips"""
    seed: int = 0
    """corpus seed"""
    heldout_phrasings: bool = False
    """caption with the held-out templates only (to test generalisation to new wording)"""
    workers: int = 1
    """worker processes"""
    force: bool = False
    """replace an existing corpus in --out"""
    quiet: bool = False
    """no progress bar"""


MAX_SHEET_CLIPS = 64
MAX_SHEET_FRAMES = 32


@dataclass
class ContactSheetConfig:
    """``python -m dataset_tools contact-sheet``."""

    input: Path
    """synth corpus folder or HumanML3D folder"""
    out: Path
    """PNG to write"""
    clips: int = 8
    """clips to show"""
    seed: int = 0
    """which clips"""
    frames: int = 6
    """key frames per clip"""
    azimuth: float = 30.0
    """camera azimuth in degrees"""

    def __post_init__(self) -> None:
        # The sheet is one image of clips x frames figures: bounded so that it fits in memory.
        if not (1 <= self.clips <= MAX_SHEET_CLIPS and 1 <= self.frames <= MAX_SHEET_FRAMES):
            raise UsageError(
                f"--clips must be between 1 and {MAX_SHEET_CLIPS} and --frames between 1 and "
                f"{MAX_SHEET_FRAMES}, got {self.clips} and {self.frames}"
            )
        if not math.isfinite(self.azimuth):
            raise UsageError(f"--azimuth must be a number of degrees, got {self.azimuth}")
        if self.seed < 0:
            raise UsageError(f"--seed must be 0 or more, got {self.seed}")


@command
def main(argv: list[str] | None = None) -> int:
    """Entry point of ``synth``; returns the exit code (2 on bad input)."""
    from dataset_tools.synth.corpus import write_corpus

    parser = CommandParser(
        prog="python -m dataset_tools synth",
        description="Write the procedural demo corpus (joints z-up 60 fps, captions, labels) that "
        "`python -m dataset_tools build --source joints` reads.",
    )
    config = parse_config(parser, SynthConfig, argv)
    # write_corpus checks its arguments (UsageError) before writing anything.
    write_corpus(
        config.out,
        config.clips,
        seed=config.seed,
        heldout_phrasings=config.heldout_phrasings,
        workers=config.workers,
        force=config.force,
        progress=not config.quiet,
    )
    return 0


def _load_for_sheet(
    folder: Path, count: int, seed: int
) -> tuple[list[tuple[np.ndarray, str]], float]:
    """(joints y-up, caption) of ``count`` random clips of a synth corpus (``joints/``, any up
    axis and fps, per its ``source.json``) or a HumanML3D folder (``new_joints/``, y-up, 20 fps),
    and their fps."""
    from dataset_tools.sources.joints import read_source_config

    rng = np.random.default_rng(seed)
    if (folder / "source.json").exists() and (folder / "joints").is_dir():
        source = read_source_config(folder)  # checks fps and up
        up = source.get("up", "y")
        files, fps = sorted((folder / "joints").glob("*.npy")), float(source.get("fps", 60))
    elif (folder / humanml3d.JOINTS_DIR).is_dir():
        files, fps, up = sorted((folder / humanml3d.JOINTS_DIR).glob("*.npy")), 20.0, "y"
    else:
        raise UsageError(
            f"{folder} has neither joints/ with source.json nor {humanml3d.JOINTS_DIR}/"
        )
    if not files:
        raise UsageError(f"no clips in {folder}")
    picks = rng.choice(len(files), size=min(count, len(files)), replace=False)
    clips = []
    for i in sorted(picks):
        path = files[i]
        caption = path.stem
        # Corpus captions are plain lines, HumanML3D's tagged ones; the first line is shown.
        text_path = humanml3d.texts_path(folder, path.stem)
        try:
            lines = text_path.read_text(encoding="utf-8").splitlines() if text_path.exists() else []
            if lines and lines[0].strip():
                text = humanml3d.parse_caption_line(lines[0], str(text_path)).text
                caption = f"{path.stem}: {text}"
        except (OSError, ValueError) as error:  # not UTF-8, or a malformed line
            raise UsageError(f"cannot read {text_path}: {error}") from None
        joints = load_npy(path)
        if joints.ndim != 3 or joints.shape[1] < 22 or joints.shape[2] != 3 or len(joints) < 1:
            raise UsageError(f"{path}: expected joints (T, >=22, 3), got {joints.shape}")
        clips.append((to_y_up(joints[:, :22], up), caption))
    return clips, fps


@command
def contact_sheet_main(argv: list[str] | None = None) -> int:
    """Entry point of ``contact-sheet``; returns the exit code (2 on bad input)."""
    from dataset_tools.synth.contact_sheet import render_contact_sheet

    parser = CommandParser(
        prog="python -m dataset_tools contact-sheet",
        description="Render a grid of stick-figure key frames of N random clips of a synth corpus "
        "(or of any folder of y-up 20 fps HumanML3D new_joints/ with texts/) to PNG.",
    )
    config = parse_config(parser, ContactSheetConfig, argv)
    check_output_file(config.out, "--out")
    if not config.input.is_dir():
        raise UsageError(f"--input folder {config.input} does not exist")
    clips, fps = _load_for_sheet(config.input, config.clips, config.seed)
    render_contact_sheet(
        clips, config.out, frames_per_clip=config.frames, azimuth_deg=config.azimuth, fps=fps
    )
    return 0
