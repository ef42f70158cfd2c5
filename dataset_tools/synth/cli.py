"""Command lines: ``python -m dataset_tools synth`` and ``python -m dataset_tools contact-sheet``."""

from __future__ import annotations

import argparse
import json
import logging
import sys
from pathlib import Path

import numpy as np


def _parser_synth() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="python -m dataset_tools synth",
        description="Write the procedural demo corpus (joints z-up 60 fps, captions, labels) that "
        "`python -m dataset_tools build --source joints` reads.",
    )
    parser.add_argument("--out", required=True, help="output folder")
    parser.add_argument("--clips", type=int, default=2000, help="number of clips (default 2000)")
    parser.add_argument("--seed", type=int, default=0, help="corpus seed (default 0)")
    parser.add_argument(
        "--heldout-phrasings",
        action="store_true",
        help="caption with the held-out templates only (to test generalisation to new wording)",
    )
    parser.add_argument("--workers", type=int, default=1, help="worker processes (default 1)")
    parser.add_argument("--force", action="store_true", help="replace an existing corpus in --out")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")
    return parser


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``synth``; returns the exit code (2 on bad input)."""
    from dataset_tools.synth.corpus import write_corpus

    args = _parser_synth().parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    try:
        write_corpus(
            args.out,
            args.clips,
            seed=args.seed,
            heldout_phrasings=args.heldout_phrasings,
            workers=args.workers,
            force=args.force,
            progress=not args.quiet,
        )
    except (ValueError, OSError) as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    return 0


def _parser_sheet() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="python -m dataset_tools contact-sheet",
        description="Render a grid of stick-figure key frames of N random clips of a synth corpus "
        "(or of any folder of y-up 20 fps HumanML3D new_joints/ with texts/) to PNG.",
    )
    parser.add_argument("--input", required=True, help="synth corpus folder or HumanML3D folder")
    parser.add_argument("--out", required=True, help="PNG to write")
    parser.add_argument("--clips", type=int, default=8, help="clips to show (default 8)")
    parser.add_argument("--seed", type=int, default=0, help="which clips (default 0)")
    parser.add_argument("--frames", type=int, default=6, help="key frames per clip (default 6)")
    parser.add_argument("--azimuth", type=float, default=30.0, help="camera azimuth in degrees")
    return parser


def _load_for_sheet(
    folder: Path, count: int, seed: int
) -> tuple[list[tuple[np.ndarray, str]], float]:
    """(joints y-up, caption) of ``count`` random clips, and their fps."""
    rng = np.random.default_rng(seed)
    if (folder / "source.json").exists() and (folder / "joints").is_dir():
        from dataset_tools.synth.corpus import z_up_to_y_up

        source = json.loads((folder / "source.json").read_text(encoding="utf-8"))
        if source.get("up", "y") not in ("y", "z"):
            raise ValueError(f"{folder}/source.json: up must be 'y' or 'z'")
        files, fps = sorted((folder / "joints").glob("*.npy")), float(source.get("fps", 60))
        convert = z_up_to_y_up if source.get("up") == "z" else np.asarray
    elif (folder / "new_joints").is_dir():
        files, fps, convert = sorted((folder / "new_joints").glob("*.npy")), 20.0, np.asarray
    else:
        raise ValueError(f"{folder} has neither joints/ with source.json nor new_joints/")
    if not files:
        raise ValueError(f"no clips in {folder}")
    picks = rng.choice(len(files), size=min(count, len(files)), replace=False)
    clips = []
    for i in sorted(picks):
        path = files[i]
        joints = convert(np.load(path))
        text_path = folder / "texts" / f"{path.stem}.txt"
        caption = path.stem
        if text_path.exists():
            lines = text_path.read_text(encoding="utf-8").splitlines()
            if lines:
                caption = f"{path.stem}: {lines[0].split('#')[0]}"
        clips.append((joints, caption))
    return clips, fps


def contact_sheet_main(argv: list[str] | None = None) -> int:
    """Entry point of ``contact-sheet``; returns the exit code (2 on bad input)."""
    from dataset_tools.synth.contact_sheet import render_contact_sheet

    args = _parser_sheet().parse_args(argv)
    try:
        if args.clips < 1 or args.frames < 1:
            raise ValueError("--clips and --frames must be at least 1")
        clips, fps = _load_for_sheet(Path(args.input), args.clips, args.seed)
        render_contact_sheet(
            clips, args.out, frames_per_clip=args.frames, azimuth_deg=args.azimuth, fps=fps
        )
    except (ValueError, OSError) as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    return 0
