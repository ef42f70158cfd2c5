"""Measure the peak memory of an edit's search against ``t2m.edit``'s estimate.

``python -m t2m.edit`` refuses, before generating, a search whose results x candidates x frames
x :data:`t2m.edit.__main__.SEARCH_BYTES_PER_FRAME` exceed the free memory. This script runs one
keys edit (or path edit) of the model's longest motion at several candidate counts, each in a
fresh process, and reports how much the process's peak resident memory grew during the edit
(``resource.getrusage``'s ``ru_maxrss`` after the edit minus the resident memory before it;
``tracemalloc`` does not see PyTorch's allocations), per candidate frame, and the slope
between the smallest and largest counts (what one more candidate frame costs, fixed costs
removed)::

    python tools/measure_edit_memory.py --checkpoints checkpoints/demo --mode keys
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
from pathlib import Path

import numpy as np


def _resident_bytes() -> int:
    with open("/proc/self/statm") as statm:
        return int(statm.read().split()[1]) * resource.getpagesize()


def _paper_sized(checkpoints: Path):
    """The run's pipeline with its generator, decoder and encoder replaced by randomly
    initialised ones of the ``paper`` preset's sizes (memory depends on sizes, not weights)."""
    import torch

    from t2m.inference.loading import load_models
    from t2m.models.autoencoder import MovementAutoencoder
    from t2m.models.temporal_vae import TemporalVAE
    from t2m.pipeline import TextToMotion
    from t2m.presets import paper
    from t2m.release.load import initial_code

    loaded = load_models(checkpoints, "cpu", need_length_model=False)
    config = paper()
    torch.manual_seed(0)
    autoencoder = MovementAutoencoder(loaded.spec.feature_dim, config.autoencoder.model).eval()
    embedding = loaded.vae.text_encoder.embedding
    vae = TemporalVAE(
        loaded.vectorizer.dim,
        config.autoencoder.model.code_size,
        config.generator.model,
        embedding.num_embeddings if embedding is not None else 0,
    ).eval()
    arguments = {**loaded.arguments(), "vae": vae, "decoder": autoencoder.decoder}
    arguments.update(encoder=autoencoder.encoder, initial_code=initial_code(autoencoder.encoder))
    return TextToMotion(**arguments, copy_models=False)


def measure(
    checkpoints: Path, mode: str, candidates: int, steps: int, paper_sized: bool = False
) -> dict:
    """One edit in this process: its frames and the growth of peak resident memory."""
    import torch

    from t2m.edit import SearchSettings, edit
    from t2m.pipeline import TextToMotion

    torch.set_num_threads(1)
    pipe = TextToMotion.from_checkpoints(checkpoints, device="cpu", need_length_model=False)
    if paper_sized:
        pipe = _paper_sized(checkpoints)
    spec = pipe.spec
    frames = spec.max_frames // spec.snippet_length * spec.snippet_length
    request: dict = {}
    if mode == "keys":  # the root's floor position at three frames, the right wrist at one
        keys = np.full((frames, spec.num_joints, 3), np.nan)
        for row, x in ((frames // 4, 0.3), (frames // 2, 0.8), (frames - 1, 1.5)):
            keys[row, 0, [0, 2]] = [0.0, x]
        keys[frames // 2, 21] = [0.3, 1.5, 1.0]
        request["keys"] = keys
    else:
        seconds = (frames - 1) / spec.fps
        request["path"] = [[seconds / 2, 0.0, 1.0], [seconds, 0.5, 2.0]]
    settings = SearchSettings(method="optimize", candidates=candidates, steps=steps)
    before = _resident_bytes()
    edit(pipe, "a person walks forward", mode, settings=settings, **request)
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024  # KiB on Linux
    hidden = pipe.vae.config.hidden_size
    return {"candidates": candidates, "frames": frames, "growth": peak - before, "hidden": hidden}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--checkpoints", type=Path, required=True)
    parser.add_argument("--mode", choices=("keys", "path"), default="keys")
    parser.add_argument("--candidates", type=int, nargs="+", default=[1, 8, 32, 64])
    parser.add_argument("--steps", type=int, default=20)
    parser.add_argument(
        "--paper-sized",
        action="store_true",
        help="replace the run's generator and autoencoder by random ones of the paper's sizes",
    )
    parser.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        count = args.candidates[0]
        print(json.dumps(measure(args.checkpoints, args.mode, count, args.steps, args.paper_sized)))
        return
    from t2m.edit.__main__ import (
        SEARCH_BYTES_PER_FRAME,
        SEARCH_BYTES_PER_HIDDEN,
        SEARCH_FIXED_BYTES,
    )

    rows = []
    for count in args.candidates:
        command = [sys.executable, __file__, "--child", "--checkpoints", str(args.checkpoints),
                   "--mode", args.mode, "--candidates", str(count), "--steps", str(args.steps),
                   *(["--paper-sized"] if args.paper_sized else [])]  # fmt: skip
        done = subprocess.run(command, capture_output=True, text=True, check=True)
        rows.append(json.loads(done.stdout.strip().splitlines()[-1]))
    sizes = " (paper-sized models)" if args.paper_sized else ""
    print(
        f"{args.mode} edit, {rows[0]['frames']} frames, {args.steps} steps, {args.checkpoints}{sizes}"
    )
    print("candidates  peak growth MiB  KiB per candidate frame  t2m.edit's estimate MiB")
    for row in rows:
        per = row["growth"] / (row["candidates"] * row["frames"]) / 1024
        per_frame = SEARCH_BYTES_PER_FRAME + SEARCH_BYTES_PER_HIDDEN * row["hidden"]
        estimate = SEARCH_FIXED_BYTES + row["candidates"] * row["frames"] * per_frame
        print(f"{row['candidates']:>10}  {row['growth'] / 2**20:>15.1f}  {per:>23.1f}  "
              f"{estimate / 2**20:>23.1f}")  # fmt: skip
    first, last = rows[0], rows[-1]
    if last["candidates"] > first["candidates"]:
        slope = (last["growth"] - first["growth"]) / (
            (last["candidates"] - first["candidates"]) * first["frames"]
        )
        print(f"slope: {slope / 1024:.1f} KiB per candidate frame")


if __name__ == "__main__":
    main()
