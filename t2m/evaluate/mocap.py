"""The real-motion-capture check: build, train, sample, detect, in one command.

``python -m t2m.evaluate.mocap`` builds the Bandai-Namco-2 captures (``../shared/mocap``: ten
contents such as "a person walks forward.", "a person waves the left hand.", in several styles)
into a HumanML3D-layout folder, trains the autoencoder and generator stages at a preset (``demo``
by default; stages already finished are reused, an interrupted one resumes), generates
``--samples`` motions for each content of :data:`CONTENT_CHECKS` the dataset holds, at the
lengths of real clips of that content, and judges real and generated motions with the same
detectors (:data:`CONTENT_CHECKS`, over the facts of :func:`mocap_facts`, thresholds calibrated
on the real clips; Bandai-Namco-1's contents are judged by ``t2m.evaluate.mocap_bench``, which
reads that dataset's labels). It writes ``results.json`` and ``results.md``: per content the
share of real clips and of generated motions recognised, and the mean horizontal speed of both
(the walking-in-place symptom: generated walks far slower than the real ones).
"""

from __future__ import annotations

import logging
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.ndimage import gaussian_filter1d

from dataset_tools.command import CommandParser, UsageError, command, option, parse_config
from dataset_tools.io import write_json_atomic, write_text_atomic
from dataset_tools.representation import recover_from_ric
from dataset_tools.skeleton import SMPL
from dataset_tools.synth.detectors import RUN_SPEED_MPS, MotionSignals, count_dips, swing

logger = logging.getLogger("t2m.evaluate.mocap")

Facts = dict

# Thresholds of the content checks, calibrated on the real Bandai-Namco-2 clips (all styles and
# their mirrors; numbers from the clips of /work/shared/mocap at 20 fps):
RAISED_BELOW_SHOULDER_M = 0.15
"""An arm is up while its wrist is above shoulder height less this: raised and waving arms
spend 46-96% of a clip there (the elderly and feminine styles wave and raise at shoulder height,
below the corpus detectors' "above the shoulder/head"), idle arms 0% (wrist 0.23 m or more
below the shoulder)."""
ARM_UP_SHARE = 0.25
"""An arm counts as raised (or waving) when up for at least this share of the clip."""
SWING_SPEED_MPS = 0.1
"""Sideways wrist movement slower than this is no swing (the slow waves of the exhausted and
feminine styles move at 0.1-0.6 m/s, under the corpus detectors' 0.6)."""
WAVE_SWINGS = 5
"""A raised arm waves with at least this many sideways reversals: real waves make 5-23, real
raised arms 0-4."""
IN_PLACE_SPEED_MPS = 0.3
"""The arm contents are performed in place (real clips move 0.01-0.08 m/s; walks and runs 0.5
m/s or faster, and the active style's walks swing the arms up to shoulder height)."""
RUN_CADENCE_HZ = 2.4
RUN_CADENCE_MIN_SPEED_MPS = 1.6
"""A run without flight: steps at least this often (real runs 2.2-3.1 steps/s, walks 1.5-2.5)
at this speed or faster (real walks reach 1.5 m/s)."""

# Thresholds of the Bandai-Namco-1 content checks, calibrated on its real clips (all 15 styles
# and their mirrors, at 20 fps); Bandai-Namco-2's clips in brackets:
SIDEWAYS_ANGLE_DEG = 15.0
"""Walking to one side: the mean root velocity points at least this far from the facing towards
that side (real walk-left and walk-right clips 17-55 degrees, their mirrors the same to the
other side; real forward walks 0-10 [0-13 for walks and turns])."""
BACKWARD_ANGLE_DEG = 150.0
"""Walking backward: the mean root velocity points at least this far from the facing (real
walk-back clips 175-180 degrees)."""
MOVING_SPEED_MPS = 0.3
"""A motion that goes somewhere moves its root at least this fast (real walks of every
direction 0.42-1.94 m/s [0.50-1.49]; the in-place contents 0.01-0.20 [0.01-0.09])."""
DASH_SPEED_MPS = 2.4
"""A dash is a run at least this fast (real dashes 2.5-4.4 m/s; real runs 1.6-3.4 [1.2-3.7])."""
BOW_DEPTH_DEG = 18.0
"""A bow pitches the trunk forward at least this far beyond its lean at the start and at the end
of the motion (real bows 21-70 degrees; real walks 1-15, runs and dashes 0-8, waves goodbye 0-15,
guiding gestures 0-38)."""


def mocap_facts(joints: np.ndarray, fps: float) -> Facts:
    """The facts of :func:`~dataset_tools.synth.detectors.detect_labels` plus those the content
    checks add: per side ``arm_up_<side>`` (share of frames with the wrist above shoulder height
    less :data:`RAISED_BELOW_SHOULDER_M`) and ``arm_swings_<side>`` (sideways reversals of the
    wrist while up), ``cadence_hz`` (steps per second), ``heading_change_deg`` (net change
    of facing, in (-180, 180]), ``travel_angle_deg`` (direction of the mean horizontal root
    velocity from the facing, in (-180, 180]: 0 ahead, +90 to the left, -90 to the right) and
    ``bow_depth_deg`` (the largest forward lean of the trunk less the larger of its mean leans
    over the first and the last tenth of the motion: how far it pitched forward and came
    back)."""
    signals = MotionSignals(joints, fps)
    facts = signals.facts().complete()
    for side in ("left", "right"):
        arm = signals.side[side]
        up = arm["above_shoulder"] > -RAISED_BELOW_SHOULDER_M
        facts[f"arm_up_{side}"] = float(up.mean())
        swings = swing(arm["lateral"][up], fps, SWING_SPEED_MPS)[1] if up.sum() > 2 else 0
        facts[f"arm_swings_{side}"] = swings
    # Steps: the ankles pass each other along the facing (5 cm hysteresis).
    ankles = joints[:, SMPL.joint("left_ankle")] - joints[:, SMPL.joint("right_ankle")]
    apart = gaussian_filter1d(np.sum(ankles * signals.forward, axis=1), max(0.05 * fps, 0.5))
    steps = count_dips(apart, -0.05, 0.05) + count_dips(-apart, -0.05, 0.05)
    facts["cadence_hz"] = steps / facts["duration_s"]
    facts["heading_change_deg"] = float((facts["yaw_change_deg"] + 180.0) % 360.0 - 180.0)
    facts["travel_angle_deg"] = float(
        np.degrees(np.arctan2(facts["left_speed_mps"], facts["forward_speed_mps"]))
    )
    lean = signals.lean_deg
    tenth = max(1, len(lean) // 10)
    ends = max(lean[:tenth].mean(), lean[-tenth:].mean())
    facts["bow_depth_deg"] = float(lean.max() - ends)
    return facts


def _walks(facts: Facts) -> bool:
    fast = facts["path_speed_mps"] * facts["speed_scale"] > RUN_SPEED_MPS
    return facts["forward_speed_mps"] > 0.3 and facts["airborne_count"] == 0 and not fast


def _runs(facts: Facts) -> bool:
    speed = facts["path_speed_mps"] * facts["speed_scale"]
    return facts["forward_speed_mps"] > 0.3 and (
        speed > RUN_SPEED_MPS
        or facts["airborne_count"] >= 2
        or (facts["cadence_hz"] >= RUN_CADENCE_HZ and speed >= RUN_CADENCE_MIN_SPEED_MPS)
    )


def _arms(action: str, side: str) -> Callable[[Facts], bool]:
    """Waving or raising exactly the ``side`` arm(s) ("left", "right", "both"), in place."""
    wanted = {"left": ("left",), "right": ("right",), "both": ("left", "right")}[side]

    def check(facts: Facts) -> bool:
        if facts["path_speed_mps"] * facts["speed_scale"] >= IN_PLACE_SPEED_MPS:
            return False
        for arm in ("left", "right"):
            up = facts[f"arm_up_{arm}"] >= ARM_UP_SHARE
            waving = facts[f"arm_swings_{arm}"] >= WAVE_SWINGS
            if (arm in wanted) != up or (arm in wanted and waving != (action == "wave")):
                return False
        return True

    return check


def _moves(facts: Facts, lowest_deg: float, highest_deg: float) -> bool:
    """Walking (no flight, below running speed) in a direction between the two angles from the
    facing (:func:`mocap_facts`' ``travel_angle_deg``)."""
    speed = facts["path_speed_mps"] * facts["speed_scale"]
    return (
        MOVING_SPEED_MPS <= speed <= RUN_SPEED_MPS
        and facts["airborne_count"] == 0
        and lowest_deg <= facts["travel_angle_deg"] <= highest_deg
    )


def _dashes(facts: Facts) -> bool:
    return _runs(facts) and facts["path_speed_mps"] * facts["speed_scale"] >= DASH_SPEED_MPS


def _bows(facts: Facts) -> bool:
    in_place = facts["path_speed_mps"] * facts["speed_scale"] < IN_PLACE_SPEED_MPS
    return in_place and facts["bow_depth_deg"] >= BOW_DEPTH_DEG


CONTENT_CHECKS: dict[str, Callable[[Facts], bool]] = {
    "a person walks forward.": lambda f: (
        _walks(f)
        and abs(f["heading_change_deg"]) < 45
        and abs(f["travel_angle_deg"]) < SIDEWAYS_ANGLE_DEG
    ),
    "a person walks forward and turns left.": lambda f: _walks(f) and f["heading_change_deg"] > 45,
    "a person walks forward and turns right.": lambda f: (
        _walks(f) and f["heading_change_deg"] < -45
    ),
    "a person runs forward.": _runs,
    "a person waves both hands.": _arms("wave", "both"),
    "a person waves the left hand.": _arms("wave", "left"),
    "a person waves the right hand.": _arms("wave", "right"),
    "a person raises both hands.": _arms("raise", "both"),
    "a person raises the left hand.": _arms("raise", "left"),
    "a person raises the right hand.": _arms("raise", "right"),
    "a person walks backward.": lambda f: (
        _moves(f, BACKWARD_ANGLE_DEG, 180.0) or _moves(f, -180.0, -BACKWARD_ANGLE_DEG)
    ),
    "a person walks to the left.": lambda f: _moves(f, SIDEWAYS_ANGLE_DEG, BACKWARD_ANGLE_DEG),
    "a person walks to the right.": lambda f: _moves(f, -BACKWARD_ANGLE_DEG, -SIDEWAYS_ANGLE_DEG),
    "a person dashes forward.": _dashes,
    "a person bows.": _bows,
}
"""The Bandai-Namco content captions (Bandai-Namco-2's as ``dataset_tools.sources.bvh`` writes
them) and what :func:`mocap_facts` must show in a motion of that content."""

CONTENT_LABELS = {
    "walk": "a person walks forward.",
    "walk-turn-left": "a person walks forward and turns left.",
    "walk-turn-right": "a person walks forward and turns right.",
    "run": "a person runs forward.",
    "wave-both-hands": "a person waves both hands.",
    "wave-left-hand": "a person waves the left hand.",
    "wave-right-hand": "a person waves the right hand.",
    "raise-up-both-hands": "a person raises both hands.",
    "raise-up-left-hand": "a person raises the left hand.",
    "raise-up-right-hand": "a person raises the right hand.",
    "walk-back": "a person walks backward.",
    "walk-left": "a person walks to the left.",
    "walk-right": "a person walks to the right.",
    "dash": "a person dashes forward.",
    "bow": "a person bows.",
}
"""The judged content labels of Bandai-Namco-2 (all ten) and Bandai-Namco-1
(``cfg/content_label.txt`` without its prefix; ``walk`` and ``run`` are in both) and their
captions in :data:`CONTENT_CHECKS`."""

NOT_JUDGED = {
    "bye": "a goodbye wave of one hand, often below the shoulder: the one-hand wave checks "
    "pass 73% of the real clips",
    "byebye": "a goodbye wave of both hands: the both-hands wave check passes 68% of the real "
    "clips",
    "guide": "showing the way: no fact measures where a hand points",
    "call": "calling someone over: two real clips, no fact for it",
    "respond": "an answering gesture: one real clip, no fact for it",
    "slash": "a sword stroke: two real clips, no fact for it",
    "punch": "the punch detector finds punches in half of the real clips (two clips)",
    "kick": "one real clip: too few to calibrate a check on",
    "dance-short": "a dance: one real clip, no fact for it",
    "dance-long": "a dance: one real clip, no fact for it",
}
"""Bandai-Namco-1 contents without a content check, and why: their motions are excluded from
content accuracy (neither passing nor failing)."""

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
    final_epochs: int = field(default=0, metadata=option(metavar="N"))
    """generator epochs at the full length in place of the preset's (0: the preset's own; the
    demo preset is sized in optimiser steps, so these captures train as many as the demo
    corpus)"""
    samples: int = field(default=5, metadata=option(metavar="N"))
    """generated motions per content"""
    seed: int = 0
    """seed of the lengths and the generation"""
    workers: int = 2
    """processes for the dataset build"""

    def __post_init__(self) -> None:
        if self.samples < 1 or self.workers < 1:
            raise UsageError("--samples and --workers must be at least 1")
        if self.final_epochs < 0:
            raise UsageError("--final-epochs must be 0 (the preset's) or more")


def _content_clips(dataset: Path) -> dict[str, list[np.ndarray]]:
    """Joints (T, 22, 3) of every clip of the dataset, by its content caption."""
    from dataset_tools.spec import spec_for_folder
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
    facts = [mocap_facts(joints, fps) for joints in motions]
    return {
        "motions": len(motions),
        "recognised": float(np.mean([CONTENT_CHECKS[caption](f) for f in facts])),
        "speed_mps": float(np.mean([f["path_speed_mps"] for f in facts])),
        "displacement_m": float(np.mean([f["displacement_m"] for f in facts])),
    }


def run_check(config: MocapCheckConfig) -> dict:
    """Build, train, sample, detect; returns (and writes) the results."""
    from dataset_tools.build import BuildConfig, build_dataset
    from t2m.config import apply_overrides
    from t2m.pipeline import TextToMotion
    from t2m.presets import preset
    from t2m.train.stage import FINISHED
    from t2m.train.stages import find_stage, train_stage

    start = time.perf_counter()
    timings = {}
    training = preset(config.preset)
    if config.final_epochs:
        training = apply_overrides(training, {"generator.final_epochs": str(config.final_epochs)})
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
            train_stage(name, training, config.dataset, config.checkpoints, resume=resume)
            timings[f"{name}_s"] = time.perf_counter() - stage_start
    # 3. real clips by content, generated motions at real lengths
    pipe = TextToMotion.from_checkpoints(config.checkpoints, need_length_model=False)
    fps = pipe.spec.fps
    real = {caption: clips for caption, clips in _content_clips(config.dataset).items() if clips}
    if not real:
        raise UsageError(
            f"--dataset {config.dataset}: no clip captioned as a content of CONTENT_CHECKS"
        )
    rng = np.random.default_rng(config.seed)
    texts, lengths = [], []
    for caption, clips in real.items():
        for k in rng.integers(len(clips), size=config.samples):
            texts.append(caption)
            lengths.append(len(clips[k]))
    generated = pipe.generate(texts, lengths=lengths, seed=config.seed, clean=False)
    by_content: dict[str, list[np.ndarray]] = {caption: [] for caption in real}
    for caption, motions in zip(texts, generated, strict=True):
        by_content[caption].append(motions[0].joints)
    # 4. detect
    rows = {
        caption: {
            "real": _judge(caption, real[caption], fps),
            "generated": _judge(caption, by_content[caption], fps),
        }
        for caption in real
    }
    overall = {
        side: float(np.mean([row[side]["recognised"] for row in rows.values()]))
        for side in ("real", "generated")
    }
    timings["total_s"] = time.perf_counter() - start
    results = {
        "dataset": str(config.dataset),
        "checkpoints": str(config.checkpoints),
        "preset": config.preset,
        "final_epochs": config.final_epochs,
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
    epochs = results.get("final_epochs") or "the preset's"
    lines = [
        "# Real motion capture check",
        "",
        f"Dataset `{results['dataset']}`, run `{results['checkpoints']}` (preset "
        f"{results['preset']}, generator final epochs {epochs}), "
        f"{results['samples']} generated motions per content at the "
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
        "Recognised: the facts of `t2m.evaluate.mocap.mocap_facts` (the demo corpus' detectors "
        "plus arm, step-rate and heading facts) pass the content's check "
        "(`t2m.evaluate.mocap.CONTENT_CHECKS`, calibrated on the real clips). Speed: mean "
        "horizontal root speed.",
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
