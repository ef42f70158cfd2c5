"""Benchmark of the dataset builder: joint arrays -> HumanML3D layout, end to end.

Clips are 200 frames at 20 fps (y-up) with 3 captions each; every clip is also mirrored, so a
source clip gives two dataset clips. ``clips_per_s`` counts source clips per wall-clock second of
the whole build (listing, motions, caption tagging, statistics, splits, report).
"""

from __future__ import annotations

import json
import os
import tempfile
import time
from pathlib import Path

import numpy as np

from dataset_tools.build import BuildConfig, build_dataset
from dataset_tools.skeleton import SMPL
from dataset_tools.spec import HUMANML3D
from dataset_tools.texts import load_nlp

CAPTIONS = (
    "a person walks forward and turns {side} at the end.",
    "someone takes {n} steps, then raises the {side} hand over the head.",
    "the figure walks in a circle clockwise while swinging both arms.",
)


def _walk(num_frames: int, rng: np.random.Generator) -> np.ndarray:
    """(T, 22, 3) y-up: the target skeleton translated forward with bobbing, swinging legs."""
    rest = np.zeros((22, 3))
    for joint in range(1, 22):
        rest[joint] = rest[SMPL.parents[joint]] + SMPL.offsets[joint]
    rest[:, 1] -= rest[:, 1].min()
    time_s = np.arange(num_frames) / HUMANML3D.fps
    joints = np.broadcast_to(rest, (num_frames, 22, 3)).copy()
    swing = 0.25 * np.sin(2 * np.pi * (time_s + rng.uniform()))[:, None]
    for leg, sign in (((4, 7, 10), 1.0), ((5, 8, 11), -1.0)):
        joints[:, list(leg), 2] += sign * swing * np.array([0.5, 1.0, 1.0])
    joints[..., 2] += rng.uniform(0.8, 1.4) * time_s[:, None]
    joints[..., 1] += 0.02 * np.sin(4 * np.pi * time_s)[:, None]
    return joints + rng.normal(0, 0.003, joints.shape)


def write_source(folder: Path, num_clips: int, num_frames: int = 200, seed: int = 0) -> None:
    """A joint-array source folder (``joints/``, ``texts/``, ``source.json``)."""
    rng = np.random.default_rng(seed)
    (folder / "joints").mkdir(parents=True)
    (folder / "texts").mkdir()
    for index in range(num_clips):
        np.save(folder / "joints" / f"{index:06d}.npy", _walk(num_frames, rng).astype(np.float32))
        side = ("left", "right")[index % 2]
        lines = [caption.format(side=side, n=3 + index % 5) for caption in CAPTIONS]
        (folder / "texts" / f"{index:06d}.txt").write_text("\n".join(lines) + "\n")
    (folder / "source.json").write_text(json.dumps({"fps": HUMANML3D.fps, "up": "y"}))


def run(quick: bool = False) -> dict:
    """Build the same source with 1 and with 2 workers; clips/s and time per step."""
    num_clips = 60 if quick else 400
    results: dict = {
        "num_source_clips": num_clips,
        "frames_per_clip": 200,
        "cpu_count": os.cpu_count(),
    }
    # The spaCy model loads once per process (about 0.5 s); timed apart from the throughput.
    clock = time.perf_counter()
    load_nlp()
    results["spacy_load_s"] = time.perf_counter() - clock
    with tempfile.TemporaryDirectory() as temp:
        source = Path(temp) / "src"
        write_source(source, num_clips)
        for workers in (1, 2):
            out = Path(temp) / f"out{workers}"
            clock = time.perf_counter()
            report = build_dataset(BuildConfig("joints", source, out, workers=workers))
            seconds = time.perf_counter() - clock
            if report["clips_out"] != 2 * num_clips:
                raise RuntimeError(f"benchmark build lost clips: {report['skipped'][:3]}")
            results[f"workers{workers}_clips_per_s"] = num_clips / seconds
            results[f"workers{workers}_dataset_clips_per_s"] = 2 * num_clips / seconds
            if workers == 1:
                timings = report["timings"]
                for step in (
                    "worker_load_s",
                    "worker_features_s",
                    "worker_write_s",
                    "captions_s",
                    "stats_s",
                    "splits_s",
                ):
                    results[f"ms_per_clip_{step[:-2]}"] = 1000 * timings.get(step, 0.0) / num_clips
        # Resuming a finished build only checks files.
        clock = time.perf_counter()
        build_dataset(BuildConfig("joints", source, Path(temp) / "out1"))
        results["resume_noop_s"] = time.perf_counter() - clock
    results["clips_per_s"] = max(results["workers1_clips_per_s"], results["workers2_clips_per_s"])
    return {
        key: round(value, 3) if isinstance(value, float) else value
        for key, value in results.items()
    }


if __name__ == "__main__":
    print(json.dumps(run(quick="--quick" in __import__("sys").argv), indent=2))
