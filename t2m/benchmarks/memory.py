"""Peak memory of a generation process at ``paper`` sizes, per inference precision.

A run folder of paper-size random-weight ``generator`` and ``length`` checkpoints is written
once (with Adam state, as training writes them), then one fresh process per precision loads it
with :meth:`t2m.pipeline.TextToMotion.from_checkpoints`, generates one 196-frame motion and
reports its peak resident set (:func:`peak_rss_mb`): what a user's ``python -m t2m.sample`` costs,
torch and spaCy included. Word vectors: the built-in 50-d GloVe (memory-mapped).

``python -m t2m.benchmarks.memory [--quick]``; ``--child RUN PRECISION`` is the measured process.
"""

from __future__ import annotations

import json
import resource
import subprocess
import sys
import tempfile
from pathlib import Path

import torch

PROMPT = "a person walks forward and waves with the right hand"
FRAMES = 196


def write_paper_run(run_dir: Path) -> None:
    """Paper-size ``generator`` and ``length`` checkpoints of random weights in ``run_dir``."""
    import numpy as np

    from dataset_tools.spec import HUMANML3D
    from t2m.data.normalization import Normalizer
    from t2m.data.words import BUILTIN_GLOVE, load_vectorizer
    from t2m.presets import paper
    from t2m.train.checkpoint import ModelSizes, atomic_save, make_checkpoint
    from t2m.train.stages import find_stage

    config = paper()
    config.data.word_vectors = BUILTIN_GLOVE
    vectorizer = load_vectorizer(BUILTIN_GLOVE, config.data.max_text_tokens)
    sizes = ModelSizes(
        feature_dim=HUMANML3D.feature_dim,
        word_dim=vectorizer.dim,
        code_size=config.autoencoder.model.code_size,
    )
    normalizer = Normalizer(np.zeros(263, np.float32), np.ones(263, np.float32))
    torch.manual_seed(0)
    for name in ("generator", "length"):
        stage = find_stage(name)
        models = stage.build(config, sizes)
        parameters = [p for m in models.values() for p in m.parameters()]
        optimizer = torch.optim.Adam(parameters)
        for parameter in parameters:  # one step so the checkpoint holds Adam's state
            parameter.grad = torch.zeros_like(parameter)
        optimizer.step()
        extra = {"initial_code": torch.zeros(sizes.code_size)} if name == "generator" else {}
        checkpoint = make_checkpoint(
            name,
            config,
            sizes,
            HUMANML3D,
            models,
            optimizer,
            {"step": 1, "epoch": 0},
            normalizer,
            vectorizer.info(),
            extra,
        )
        folder = stage.folder(run_dir)
        folder.mkdir(parents=True, exist_ok=True)
        atomic_save(checkpoint, folder / "best.pt")


def peak_rss_mb() -> float:
    """This process's peak resident set in MB: ``VmHWM`` of ``/proc/self/status`` where there is
    one (Linux). Not ``getrusage``'s ``ru_maxrss``: Linux carries it across ``execve`` from the
    process that started this one, so a child of a 3.4 GB benchmark process reported 3.4 GB
    whatever it did itself."""
    try:
        with open("/proc/self/status", encoding="ascii") as status:
            for line in status:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) / 1024
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # kB on Linux


def child(run_dir: str, precision: str) -> dict:
    """Load ``run_dir`` at ``precision``, generate one motion; peak resident set in MB."""
    from t2m.pipeline import TextToMotion

    torch.set_num_threads(1)
    pipe = TextToMotion.from_checkpoints(run_dir, precision=precision)
    after_load = peak_rss_mb()
    pipe.generate(PROMPT, lengths=FRAMES, clean=False, seed=0)
    peak = peak_rss_mb()
    return {"peak_mb": round(peak, 1), "peak_after_load_mb": round(after_load, 1)}


def measure(run_dir: Path, precision: str) -> dict:
    out = subprocess.run(
        [sys.executable, "-m", "t2m.benchmarks.memory", "--child", str(run_dir), precision],
        check=True,
        capture_output=True,
        text=True,
    ).stdout
    return json.loads(out.strip().splitlines()[-1])


def run(quick: bool = False) -> dict:
    from t2m.pipeline import PRECISIONS

    results: dict = {}
    with tempfile.TemporaryDirectory() as tmp:
        write_paper_run(Path(tmp))
        for precision in PRECISIONS:
            measured = measure(Path(tmp), precision)
            results[f"memory.{precision}_generation_peak_mb"] = measured["peak_mb"]
            results[f"memory.{precision}_after_load_peak_mb"] = measured["peak_after_load_mb"]
    return results


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] == ["--child"]:
        print(json.dumps(child(argv[1], argv[2])))
        return 0
    print(json.dumps(run(quick="--quick" in argv), indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
