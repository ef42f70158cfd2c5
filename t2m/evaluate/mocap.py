"""The real-motion-capture check: build, train, sample, detect, in one command.

``python -m t2m.evaluate.mocap`` builds the Bandai-Namco-2 captures (``../shared/mocap``: ten
contents such as "a person walks forward.", "a person waves the left hand.", in several styles)
into a HumanML3D-layout folder, trains the autoencoder and generator stages at a preset (``demo``
by default; stages already finished are reused, an interrupted one resumes), generates
``--samples`` motions for each content at the lengths of real clips of that content, and judges
real and generated motions with the same detectors (:data:`CONTENT_CHECKS`, over the facts of
:func:`dataset_tools.synth.detectors.detect_labels`). It writes ``results.json`` and
``results.md``: per content the share of real clips and of generated motions recognised, and
the mean horizontal speed of both (the walking-in-place symptom: generated walks far slower than
the real ones).
"""

from __future__ import annotations

import logging
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from dataset_tools.command import CommandParser, UsageError, command, option, parse_config
from dataset_tools.io import write_json_atomic, write_text_atomic
from dataset_tools.representation import recover_from_ric
from dataset_tools.synth.detectors import RUN_SPEED_MPS, detect_labels

logger = logging.getLogger("t2m.evaluate.mocap")

Facts = dict


def _walks(facts: Facts) -> bool:
    fast = facts["path_speed_mps"] * facts["speed_scale"] > RUN_SPEED_MPS
    return facts["forward_speed_mps"] > 0.3 and facts["airborne_count"] == 0 and not fast


def _only(action: str, side: str) -> Callable[[Facts], bool]:
    sides = {"left": (True, False), "right": (False, True), "both": (True, True)}[side]
    return lambda f: (f[f"{action}_left"], f[f"{action}_right"]) == sides


CONTENT_CHECKS: dict[str, Callable[[Facts], bool]] = {
    "a person walks forward.": lambda f: _walks(f) and abs(f["yaw_change_deg"]) < 45,
    "a person walks forward and turns left.": lambda f: _walks(f) and f["yaw_change_deg"] > 45,
    "a person walks forward and turns right.": lambda f: _walks(f) and f["yaw_change_deg"] < -45,
    "a person runs forward.": lambda f: (
        f["forward_speed_mps"] > 0.3
        and (f["path_speed_mps"] * f["speed_scale"] > RUN_SPEED_MPS or f["airborne_count"] >= 2)
    ),
    "a person waves both hands.": _only("wave", "both"),
    "a person waves the left hand.": _only("wave", "left"),
    "a person waves the right hand.": _only("wave", "right"),
    "a person raises both hands.": _only("raise", "both"),
    "a person raises the left hand.": _only("raise", "left"),
    "a person raises the right hand.": _only("raise", "right"),
}
"""The Bandai-Namco content captions (as ``dataset_tools.sources.bvh`` writes them) and what
the detectors must find in a motion of that content."""

STAGES = ("autoencoder", "generator")


@dataclass
class MocapCheckConfig:
    """``python -m t2m.evaluate.mocap``: what to build, train and check, and where."""

    mocap: Path = field(
        default=Path("../shared/mocap/bandai-namco-2/data"), metadata=option(metavar="DIR")
    )
    """the Bandai-Namco-2 BVH folder (with ../cfg/ holding its label files)"""
    dataset: Path = field(default=Path("data/bandai"), metadata=option(metavar="DIR"))
    """the dataset folder to build (reused when built)"""
    checkpoints: Path = field(default=Path("checkpoints/bandai"), metadata=option(metavar="DIR"))
    """the run folder (finished stages are reused, an interrupted one resumes)"""
    out: Path = field(default=Path("outputs/bandai_check"), metadata=option(metavar="DIR"))
    """where results.json and results.md go"""
    preset: str = "demo"
    """training preset"""
    samples: int = field(default=5, metadata=option(metavar="N"))
    """generated motions per content"""
    seed: int = 0
    """seed of the lengths and the generation"""
    workers: int = 2
    """processes for the dataset build"""

    def __post_init__(self) -> None:
        if self.samples < 1 or self.workers < 1:
            raise UsageError("--samples and --workers must be at least 1")


def _content_clips(dataset: Path) -> dict[str, list[np.ndarray]]:
    """Joints (T, 22, 3) of every clip of the dataset, by its content caption."""
    from dataset_tools.skeleton import spec_for_folder
    from t2m.data.dataset import load_split

    spec = spec_for_folder(dataset)
    by_content: dict[str, list[np.ndarray]] = {caption: [] for caption in CONTENT_CHECKS}
    for clip in load_split(dataset, "all", spec=spec):
        for caption in clip.captions:
            if caption.text in by_content:
                motion = clip.motion[: spec.max_frames]
                by_content[caption.text].append(recover_from_ric(motion, spec.num_joints))
                break
    return by_content


def _judge(caption: str, motions: list[np.ndarray], fps: float) -> dict:
    facts = [detect_labels(joints, fps) for joints in motions]
    return {
        "motions": len(motions),
        "recognised": float(np.mean([CONTENT_CHECKS[caption](f) for f in facts])),
        "speed_mps": float(np.mean([f["path_speed_mps"] for f in facts])),
        "displacement_m": float(np.mean([f["displacement_m"] for f in facts])),
    }


def run_check(config: MocapCheckConfig) -> dict:
    """Build, train, sample, detect; returns (and writes) the results."""
    from dataset_tools.build import BuildConfig, build_dataset
    from t2m.config import preset
    from t2m.pipeline import TextToMotion
    from t2m.train.stage import FINISHED
    from t2m.train.stages import find_stage, train_stage

    start = time.perf_counter()
    timings = {}
    # 1. the dataset
    if not (config.dataset / "Mean.npy").is_file():
        build_dataset(
            BuildConfig("bvh", config.mocap, config.dataset, workers=config.workers, seed=0)
        )
    timings["build_s"] = time.perf_counter() - start
    # 2. the stages it needs (lengths come from real clips)
    for name in STAGES:
        folder = find_stage(name).folder(config.checkpoints)
        if not (folder / FINISHED).is_file():
            stage_start = time.perf_counter()
            resume = (folder / "latest.pt").is_file()
            logger.info("training %s (%s) ...", name, "resuming" if resume else "from scratch")
            train_stage(
                name, preset(config.preset), config.dataset, config.checkpoints, resume=resume
            )
            timings[f"{name}_s"] = time.perf_counter() - stage_start
    # 3. real clips by content, generated motions at real lengths
    pipe = TextToMotion.from_checkpoints(config.checkpoints, need_length_model=False)
    fps = pipe.spec.fps
    real = _content_clips(config.dataset)
    rng = np.random.default_rng(config.seed)
    texts, lengths = [], []
    for caption, clips in real.items():
        if not clips:
            raise UsageError(f"--dataset {config.dataset}: no clip captioned {caption!r}")
        for k in rng.integers(len(clips), size=config.samples):
            texts.append(caption)
            lengths.append(len(clips[k]))
    generated = pipe.generate(texts, lengths=lengths, seed=config.seed, clean=False)
    by_content: dict[str, list[np.ndarray]] = {caption: [] for caption in CONTENT_CHECKS}
    for caption, motions in zip(texts, generated, strict=True):
        by_content[caption].append(motions[0].joints)
    # 4. detect
    rows = {
        caption: {"real": _judge(caption, real[caption], fps),
                  "generated": _judge(caption, by_content[caption], fps)}
        for caption in CONTENT_CHECKS
    }  # fmt: skip
    overall = {
        side: float(np.mean([row[side]["recognised"] for row in rows.values()]))
        for side in ("real", "generated")
    }
    timings["total_s"] = time.perf_counter() - start
    results = {
        "dataset": str(config.dataset),
        "checkpoints": str(config.checkpoints),
        "preset": config.preset,
        "samples": config.samples,
        "seed": config.seed,
        "overall": overall,
        "contents": rows,
        "timings_s": timings,
    }
    config.out.mkdir(parents=True, exist_ok=True)
    write_json_atomic(config.out / "results.json", results)
    write_text_atomic(config.out / "results.md", format_results(results))
    return results


def format_results(results: dict) -> str:
    """The results as a markdown table."""
    lines = [
        "# Real motion capture check",
        "",
        f"Dataset `{results['dataset']}`, run `{results['checkpoints']}` (preset "
        f"{results['preset']}), {results['samples']} generated motions per content at the "
        f"lengths of real clips, seed {results['seed']}.",
        "",
        "| content | real recognised | generated recognised | real speed, m/s | "
        "generated speed, m/s |",
        "|---|---|---|---|---|",
    ]
    for caption, row in results["contents"].items():
        real, generated = row["real"], row["generated"]
        lines.append(
            f"| {caption} | {real['recognised']:.2f} ({real['motions']}) | "
            f"{generated['recognised']:.2f} ({generated['motions']}) | "
            f"{real['speed_mps']:.2f} | {generated['speed_mps']:.2f} |"
        )
    overall = results["overall"]
    lines += [
        f"| **overall** | {overall['real']:.2f} | {overall['generated']:.2f} | | |",
        "",
        "Recognised: the detectors of `dataset_tools.synth.detectors` find the content "
        "(`t2m.evaluate.mocap.CONTENT_CHECKS`). Speed: mean horizontal root speed.",
    ]
    return "\n".join(lines) + "\n"


@command(interrupted="interrupted; run it again to continue where it stopped")
def main(argv: list[str] | None = None) -> int:
    """``python -m t2m.evaluate.mocap``; exit status 0, or 2 with a one-line reason."""
    parser = CommandParser(
        prog="python -m t2m.evaluate.mocap",
        description="Real motion capture check: build the Bandai-Namco-2 captures, train the "
        "autoencoder and generator, generate every content and judge real and generated "
        "motions with the same detectors.",
    )
    config = parse_config(parser, MocapCheckConfig, argv)
    results = run_check(config)
    print(format_results(results))
    return 0


if __name__ == "__main__":
    sys.exit(main())
