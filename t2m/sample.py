"""Command line: prompts in, motion files out (``python -m t2m.sample --help``).

Examples::

    python -m t2m.sample --text "a person walks forward and waves"
    python -m t2m.sample --text-file prompts.txt --num-samples 3 --seconds 6 --bvh --out out/
    python -m t2m.sample --text "a person jumps" --precision int8 --render none

Writes into ``--out`` (default ``outputs/<timestamp>/``), per prompt NN and sample RR:
``sampleNN_repRR.npy`` (joints (T, 22, 3), metres, y-up, 20 fps), ``sampleNN_repRR_feats.npy``
(de-normalised features (T, 263)), ``sampleNN_repRR.mp4|gif`` unless ``--render none``,
``sampleNN_repRR.bvh`` with ``--bvh``; plus ``results.npy`` (the MDM layout: a dict with
``motion`` (N, 22, 3, T_max), ``text``, ``lengths``, ``num_samples``, ``num_repetitions``; motion
``i = rep * num_samples + prompt``, padded past its length with its last pose) and
``results.json``. Everything is written into a hidden folder beside ``--out`` and renamed at the
end, so an error leaves nothing half-written. Exit status 2 with a one-line message on bad input.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import shutil
import sys
import tempfile
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from t2m.pipeline import GeneratedMotion

logger = logging.getLogger("t2m.sample")

RENDER_CHOICES = ("mp4", "gif", "none")


@dataclass(frozen=True)
class Prompt:
    """One prompt and its requested length in frames (None: sample it)."""

    text: str
    frames: int | None = None


def read_prompt_file(path: str | Path) -> list[Prompt]:
    """Prompts, one a line; ``text#frames`` fixes that prompt's length. Blank lines are skipped."""
    path = Path(path)
    try:
        lines = path.read_text(encoding="utf-8").splitlines()
    except OSError as error:
        raise ValueError(f"cannot read --text-file {path}: {error.strerror or error}") from None
    except UnicodeDecodeError:
        raise ValueError(f"--text-file {path} is not UTF-8 text") from None
    prompts = []
    for number, line in enumerate(lines, start=1):
        if not line.strip():
            continue
        text, sep, suffix = line.rpartition("#")
        if not sep:
            prompts.append(Prompt(line.strip()))
            continue
        try:
            frames = int(suffix.strip())
        except ValueError:
            raise ValueError(f"{path.name}:{number}: after '#' give a length in frames, "
                             f"got {suffix.strip()!r}") from None  # fmt: skip
        if not text.strip():
            raise ValueError(f"{path.name}:{number}: empty prompt before '#{suffix.strip()}'")
        prompts.append(Prompt(text.strip(), frames))
    if not prompts:
        raise ValueError(f"--text-file {path} holds no prompt")
    return prompts


def stem(prompt: int, repetition: int) -> str:
    """File stem of one motion: ``sampleNN_repRR``."""
    return f"sample{prompt:02d}_rep{repetition:02d}"


def _save_npy(path: Path, array) -> None:
    with open(path, "wb") as handle:  # inside the private temp folder: renamed as a whole later
        np.save(handle, array, allow_pickle=isinstance(array, dict))


def mdm_results(motions: Sequence[Sequence[GeneratedMotion]], num_repetitions: int) -> dict:
    """The ``results.npy`` dict of the MDM layout from ``motions[prompt][rep]``."""
    flat = [motions[p][r] for r in range(num_repetitions) for p in range(len(motions))]
    max_frames = max(m.num_frames for m in flat)
    stacked = np.stack([
        np.pad(m.joints, ((0, max_frames - m.num_frames), (0, 0), (0, 0)), mode="edge")
        for m in flat
    ])  # (N, T, J, 3)  # fmt: skip
    return {
        "motion": np.ascontiguousarray(stacked.transpose(0, 2, 3, 1)),  # (N, J, 3, T)
        "text": [m.text for m in flat],
        "lengths": np.array([m.num_frames for m in flat], dtype=np.int64),
        "num_samples": len(motions),
        "num_repetitions": num_repetitions,
    }


def _prepare_out(out: Path, overwrite: bool) -> Path:
    """Check ``out`` can be written and create the hidden temp folder beside it."""
    if out.exists() and not out.is_dir():
        raise ValueError(f"--out {out} exists and is not a folder")
    if out.is_dir() and any(out.iterdir()):
        if not overwrite:
            raise ValueError(f"--out {out} exists and is not empty (choose another or add "
                             "--overwrite)")  # fmt: skip
        # --overwrite deletes the folder: only ever one that an earlier run wrote.
        if not (out / "results.json").is_file():
            raise ValueError(f"--overwrite refuses to replace {out}: it holds no results.json, so "
                             "it is not an earlier sampling output")  # fmt: skip
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        return Path(tempfile.mkdtemp(prefix=f".{out.name}.", suffix=".tmp", dir=out.parent))
    except OSError as error:
        raise ValueError(f"cannot write to --out {out}: {error.strerror or error}") from None


def _publish(tmp: Path, out: Path) -> None:
    """Move the finished temp folder to ``out`` (replacing an empty or --overwrite'n one)."""
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(tmp, 0o777 & ~umask)  # mkdtemp makes 0700 folders
    old = None
    if out.exists():
        old = out.parent / f".{out.name}.old-{os.getpid()}"
        os.replace(out, old)
    os.replace(tmp, out)
    if old is not None:
        shutil.rmtree(old)


def sample_to_folder(
    pipe,
    prompts: Sequence[Prompt],
    out: str | Path,
    num_samples: int = 1,
    seed: int = 0,
    batch_size: int = 32,
    render: str = "mp4",
    bvh: bool = False,
    overwrite: bool = False,
    extra_info: dict | None = None,
) -> Path:
    """Generate motions for ``prompts`` with a :class:`t2m.pipeline.TextToMotion` and write every
    file of the output contract into ``out``; returns ``out``. Nothing is left in ``out`` on error.
    """
    from t2m.export import write_bvh
    from t2m.pipeline import FPS
    from t2m.render import render_animation

    if render not in RENDER_CHOICES:
        raise ValueError(f"--render must be one of {', '.join(RENDER_CHOICES)}, got {render!r}")
    out = Path(out).resolve()  # "." has no name to put a temp folder beside
    # 1. where to write (fails early, before any model work)
    tmp = _prepare_out(out, overwrite)
    try:
        # 2. generate
        texts = [p.text for p in prompts]
        motions = pipe.generate(texts, num_samples=num_samples, lengths=[p.frames for p in prompts],
                                seed=seed, batch_size=batch_size, progress=True)  # fmt: skip
        if bvh and motions[0][0].joints.shape[1] != 22:
            raise ValueError("--bvh needs the 22-joint SMPL skeleton (HumanML3D checkpoints)")
        # 3. per-motion files
        files: list[str] = []
        flat = [m for row in motions for m in row]
        from tqdm import tqdm

        for motion in tqdm(flat, desc="writing", unit="motion", disable=len(flat) < 2):
            name = stem(motion.prompt_index, motion.repetition)
            _save_npy(tmp / f"{name}.npy", motion.joints)
            _save_npy(tmp / f"{name}_feats.npy", motion.features)
            files += [f"{name}.npy", f"{name}_feats.npy"]
            if render != "none":
                render_animation(motion.joints, tmp / f"{name}.{render}", caption=motion.text)
                files.append(f"{name}.{render}")
            if bvh:
                write_bvh(motion.joints, tmp / f"{name}.bvh")
                files.append(f"{name}.bvh")
        # 4. the summaries
        _save_npy(tmp / "results.npy", mdm_results(motions, num_samples))
        summary = {
            "texts": texts,
            "lengths": [[m.num_frames for m in row] for row in motions],
            "seed": seed,
            "num_samples": num_samples,
            "fps": FPS,
            "files": files + ["results.npy", "results.json"],
            **(extra_info or {}),
        }
        (tmp / "results.json").write_text(json.dumps(summary, indent=2) + "\n")
        # 5. publish in one rename
        _publish(tmp, out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return out


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="python -m t2m.sample",
        description="Generate 3D human motions from text with trained T2M checkpoints.",
    )
    source = parser.add_mutually_exclusive_group(required=True)
    source.add_argument("--text", help='one prompt, e.g. "a person walks forward and waves"')
    source.add_argument(
        "--text-file", metavar="FILE", help="prompts one a line; 'prompt#FRAMES' fixes a length"
    )
    parser.add_argument(
        "--num-samples", type=int, metavar="N", default=1, help="motions per prompt (default 1)"
    )
    length = parser.add_mutually_exclusive_group()
    length.add_argument("--length", type=int, metavar="FRAMES", help="frames at 20 fps (rounded to 4, 40..196); "
                        "default: drawn from the text2length model")  # fmt: skip
    length.add_argument(
        "--seconds", type=float, metavar="S", help="length in seconds instead of frames"
    )
    parser.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    parser.add_argument("--checkpoints", default="checkpoints/demo", metavar="DIR",
                        help="run folder with the length/ and generator/ stages (default checkpoints/demo)")  # fmt: skip
    parser.add_argument("--out", metavar="DIR", help="output folder (default outputs/<timestamp>/)")
    parser.add_argument("--overwrite", action="store_true", help="replace a non-empty --out")
    parser.add_argument("--render", choices=RENDER_CHOICES, default="mp4",
                        help="animation format, or none (default mp4)")  # fmt: skip
    parser.add_argument("--bvh", action="store_true", help="also write a BVH file per motion")
    parser.add_argument("--device", default="auto",
                        help="auto, cpu, cuda or cuda:N (default auto: CUDA when present)")  # fmt: skip
    parser.add_argument(
        "--batch-size", type=int, default=32, metavar="N", help="motions per batch (default 32)"
    )
    parser.add_argument("--precision", choices=("fp32", "bf16", "int8"), default="fp32",
                        help="inference precision (default fp32; int8 is CPU only)")  # fmt: skip
    parser.add_argument("--threads", type=int, default=0, metavar="N",
                        help="torch CPU threads (default 0: torch's choice; 1 is fastest on a "
                        "busy machine)")  # fmt: skip
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    return parser


def main(argv: list[str] | None = None) -> int:
    from t2m.pipeline import TextToMotion, frames_for, frames_for_seconds

    parser = build_parser()
    args = parser.parse_args(sys.argv[1:] if argv is None else argv)
    logging.basicConfig(level=logging.DEBUG if args.verbose else logging.INFO,
                        format="%(levelname)s %(name)s: %(message)s")  # fmt: skip
    try:
        if args.num_samples < 1 or args.batch_size < 1:
            raise ValueError("--num-samples and --batch-size must be at least 1")
        if args.threads < 0:
            raise ValueError(f"--threads must be >= 0, got {args.threads}")
        if args.threads:
            import torch

            torch.set_num_threads(args.threads)
        if args.text is not None:
            if not args.text.strip():
                raise ValueError("empty --text: give a sentence describing the motion")
            prompts = [Prompt(args.text.strip())]
        else:
            prompts = read_prompt_file(args.text_file)
        if args.length is not None:
            default_frames = frames_for(args.length)
        elif args.seconds is not None:
            default_frames = frames_for_seconds(args.seconds)
        else:
            default_frames = None
        prompts = [Prompt(p.text, p.frames if p.frames is not None else default_frames)
                   for p in prompts]  # fmt: skip
        out = Path(args.out or Path("outputs") / time.strftime("%Y-%m-%d_%H-%M-%S"))
        # Check the output folder before spending time on loading models.
        _prepare_out(out.resolve(), args.overwrite).rmdir()
        need_length = any(p.frames is None for p in prompts)
        # int8 kernels exist on the CPU only: "auto" means the CPU there.
        device = "cpu" if args.precision == "int8" and args.device == "auto" else args.device
        pipe = TextToMotion.from_checkpoints(args.checkpoints, device=device,
                                             precision=args.precision,
                                             need_length_model=need_length)  # fmt: skip
        sample_to_folder(
            pipe, prompts, out, num_samples=args.num_samples, seed=args.seed,
            batch_size=args.batch_size, render=args.render, bvh=args.bvh,
            overwrite=args.overwrite,
            extra_info={"checkpoints": str(args.checkpoints), "precision": args.precision,
                        "batch_size": args.batch_size},
        )  # fmt: skip
    except ValueError as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    except OSError as error:  # e.g. a full disk while writing: nothing was published
        print(f"error: {error}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("interrupted; nothing was written", file=sys.stderr)
        return 130
    logger.info("wrote %s", out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
