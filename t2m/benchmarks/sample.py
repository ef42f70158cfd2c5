"""Generation speed at ``paper`` sizes (random weights): batch-1 latency and batch-32 throughput
per inference precision, plus rendering and BVH export costs.

Latency is "text in, joints out": spaCy tagging and word vectors, the text encoder, the temporal
VAE's 49 prior / generator steps (196 frames, the longest motion), the decoder, de-normalisation
and joint recovery; model loading, rendering and the foot-contact clean-up (``clean=False``: the
original has none; it costs 8-9 ms per 196-frame motion) are excluded. Targets from the issue: <= 60 ms
at batch 1 and >= 100 motions/s at batch 32 on the 2-core CPU (the original: 275 ms, 27 /s).
The output difference against fp32 is measured on the same random-weight models and seeds; its
effect on the metrics of trained checkpoints is measured with ``python -m t2m.evaluate
--precision int8``.

Timings are single-threaded (see :func:`run`); ``*_cpu_ms`` / ``*_per_cpu_s`` use the process's
CPU time, which leaves out the time other processes held the shared cores.
"""

from __future__ import annotations

import statistics
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

from dataset_tools import humanml3d
from t2m.accel import onnx as onnx_backend
from t2m.evaluate.paper_sized import paper_sized_pipeline
from t2m.pipeline import PRECISIONS

PROMPT = "a person walks forward and waves with the right hand"
FRAMES = 196
BATCH = 32


def _best_of(repeats: int, function) -> tuple[float, object]:
    times, result = [], None
    for _ in range(repeats):
        start = time.perf_counter()
        result = function()
        times.append(time.perf_counter() - start)
    return min(times), result


def _timed(function) -> tuple[float, float]:
    """(wall seconds, CPU seconds of this process) of one call. Single-threaded, CPU time is
    what the call costs without the time other processes held the cores."""
    wall, cpu = time.perf_counter(), time.process_time()
    function()
    return time.perf_counter() - wall, time.process_time() - cpu


def run(quick: bool = False) -> dict:
    """Single-threaded measurements for every precision, then int8 at torch's default threads.

    One thread is the main setting: on a shared 2-core machine, two OpenMP threads per process
    wait on each other at every one of the ~2000 small ops of a generation, which made 2-thread
    timings up to 10x slower whenever other processes were busy.
    """
    default_threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        results = _measure(quick)
        if default_threads != 1:
            torch.set_num_threads(default_threads)
            pipe, _ = paper_sized_pipeline("int8")
            pipe.generate(PROMPT, lengths=FRAMES, clean=False, seed=0)
            seconds, _ = _best_of(
                3, lambda: pipe.generate(PROMPT, lengths=FRAMES, clean=False, seed=1)
            )
            results[f"sample.int8_batch1_best_ms_{default_threads}_threads"] = round(
                seconds * 1e3, 1
            )
            seconds, _ = _best_of(
                1,
                lambda: pipe.generate(
                    [PROMPT] * BATCH, lengths=FRAMES, clean=False, seed=0, batch_size=BATCH
                ),
            )
            results[f"sample.int8_batch32_motions_per_s_{default_threads}_threads"] = round(
                BATCH / seconds, 1
            )
    finally:
        torch.set_num_threads(default_threads)
    return results


def _measure(quick: bool) -> dict:
    results: dict[str, float | str] = {
        "sample.frames": FRAMES,
        "sample.torch_threads": torch.get_num_threads(),
    }
    repeats = 3 if quick else 7
    modules = None
    reference = None
    sides = [(precision, "torch") for precision in PRECISIONS]
    if onnx_backend.available():  # the optional ONNX Runtime backend: keys onnx_fp32, onnx_int8
        sides += [(precision, "onnx") for precision in onnx_backend.ONNX_PRECISIONS]
    for precision, backend in sides:
        pipe, modules = paper_sized_pipeline(precision, modules, backend)
        if backend != "torch":
            precision = f"{backend}_{precision}"
        pipe.generate(
            PROMPT, lengths=FRAMES, clean=False, seed=0
        )  # warm-up (spaCy, word vectors, kernels)
        latencies = [
            _timed(
                lambda seed=seed, pipe=pipe: pipe.generate(
                    PROMPT, lengths=FRAMES, clean=False, seed=seed
                )
            )
            for seed in range(repeats)
        ]
        wall, cpu = zip(*latencies)
        results[f"sample.{precision}_batch1_median_ms"] = round(statistics.median(wall) * 1e3, 1)
        results[f"sample.{precision}_batch1_best_ms"] = round(min(wall) * 1e3, 1)
        results[f"sample.{precision}_batch1_cpu_ms"] = round(statistics.median(cpu) * 1e3, 1)
        batches = [
            _timed(
                lambda pipe=pipe: pipe.generate(
                    [PROMPT] * BATCH, lengths=FRAMES, clean=False, seed=0, batch_size=BATCH
                )
            )
            for _ in range(1 if quick else 2)
        ]
        wall, cpu = zip(*batches)
        results[f"sample.{precision}_batch32_motions_per_s"] = round(BATCH / min(wall), 1)
        results[f"sample.{precision}_batch32_motions_per_cpu_s"] = round(BATCH / min(cpu), 1)
        final = pipe.generate(PROMPT, lengths=FRAMES, clean=False, seed=123)[0][0].joints
        if reference is None:
            reference = final
            # For scale: how far two samples (seeds) of the same prompt are from each other.
            other = pipe.generate(PROMPT, lengths=FRAMES, clean=False, seed=124)[0][0].joints
            spread = np.linalg.norm(other - reference, axis=-1)
            results["sample.fp32_seed_to_seed_random_weights_mean_mm"] = round(
                float(spread.mean()) * 1e3, 2
            )
        else:
            difference = np.linalg.norm(final - reference, axis=-1)
            results[f"sample.{precision}_vs_fp32_random_weights_mean_mm"] = round(
                float(difference.mean()) * 1e3, 2
            )
    # Files: rendering and BVH export of one 196-frame motion.
    from dataset_tools.bvh import write_bvh
    from dataset_tools.viz import RenderConfig, render_animation

    with tempfile.TemporaryDirectory() as tmp:
        joints = _walking_joints()
        seconds, _ = _best_of(1 if quick else 3, lambda: write_bvh(joints, Path(tmp) / "a.bvh"))
        results["sample.bvh_export_ms_per_motion"] = round(seconds * 1e3, 1)
        frames = 40 if quick else FRAMES
        seconds, _ = _best_of(
            1,
            lambda: render_animation(
                joints[:frames], Path(tmp) / "a.mp4", "a caption", config=RenderConfig()
            ),
        )
        results["sample.render_mp4_ms_per_frame"] = round(seconds * 1e3 / frames, 2)
    return results


def _walking_joints() -> np.ndarray:
    """The real reference clip when ../shared is present, else a procedural stand-in."""
    shared = Path(__file__).resolve().parents[2].parent / "shared"
    clip = humanml3d.joints_path(shared / "reference" / "humanml3d", "012314")
    if clip.exists():
        joints = np.load(clip, allow_pickle=False)
        return np.concatenate([joints, joints[::-1]])[:FRAMES]
    from dataset_tools.skeleton import SMPL

    pose = np.zeros((22, 3))
    for joint in range(1, 22):
        pose[joint] = pose[SMPL.parents[joint]] + SMPL.offsets[joint]
    pose[:, 1] -= pose[:, 1].min()
    walk = np.linspace(0, 3, FRAMES)[:, None, None] * np.array([0.0, 0.0, 1.0])
    return pose[None] + walk
