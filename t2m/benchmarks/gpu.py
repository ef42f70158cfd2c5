"""The GPU check of issue 18, one short script: ``python -m t2m.benchmarks.gpu [--out FILE]``.

On the first CUDA device, paper-size models with random weights (timings do not depend on the
weights), 196-frame motions (49 recurrent steps), the same prompt as ``t2m.benchmarks.sample``,
tagged here and looked up in a table of random 50-d word vectors (the built-in GloVe's size), so
that the check needs torch and numpy alone (no spaCy model or GloVe table on the GPU machine):

* generation latency at batch 1 and throughput at batch 32, fp32 and bf16, text in, features out
  (``TextToMotion.generate_features``: text encoder, the temporal VAE's prior / generator loop,
  decoder), each timing closed by ``torch.cuda.synchronize``;
* the recurrent loop alone (the generation plan over 49 steps, batch 1, fp32) eagerly and replayed
  from a CUDA graph, when the graph can be captured (else the reason is recorded);
* the training steps of every stage at paper size, the temporal VAE's under bf16 autocast too
  (:func:`t2m.benchmarks.train.run` on the device);
* a two-process DDP step of the temporal VAE (NCCL) when more than one device is present.

Writes a JSON (default ``bench/gpu.json``) with the devices and versions, and prints it.
Without CUDA it stops at once with one line (exit status 2). Not part of ``make bench``.
"""

from __future__ import annotations

import json
import os
import platform
import statistics
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from dataset_tools.command import CommandParser, UsageError, command, option, parse_config
from dataset_tools.io import write_json_atomic

PROMPT = "a person walks forward and waves with the right hand"
PROMPT_TOKENS = (
    "a/DET person/NOUN walk/VERB forward/ADV and/CCONJ wave/NOUN with/ADP the/DET right/ADJ "
    "hand/NOUN"
).split()
"""``PROMPT`` as prompts are tagged (:func:`dataset_tools.texts.tag_prompts`, ``word/POS``)."""
WORD_DIM = 50
"""The built-in GloVe's size, which ``t2m.benchmarks.sample`` runs with."""
FRAMES = 196
BATCH = 32


@dataclass
class GpuConfig:
    """``python -m t2m.benchmarks.gpu``."""

    out: Path = field(default=Path("bench/gpu.json"), metadata=option(metavar="FILE"))
    """where the results go (JSON)"""
    repeats: int = field(default=10, metadata=option(metavar="N"))
    """timed runs per measurement (the median is reported)"""
    device: str = "cuda"
    """the CUDA device (cuda or cuda:N)"""


def versions() -> dict:
    """The device, driver and library versions the numbers were measured with."""
    return {
        "date": time.strftime("%Y-%m-%d %H:%M:%S %Z"),
        "devices": [torch.cuda.get_device_name(i) for i in range(torch.cuda.device_count())],
        "capability": ".".join(map(str, torch.cuda.get_device_capability(0))),
        "torch": torch.__version__,
        "cuda": torch.version.cuda,
        "cudnn": torch.backends.cudnn.version(),
        "python": platform.python_version(),
        "numpy": np.__version__,
        "platform": platform.platform(),
    }


def _median_s(function: Callable[[], object], repeats: int, device: torch.device) -> float:
    """Median seconds of ``function`` after two warm-up calls, synchronised on a CUDA
    ``device`` (the parts run on the CPU too, which is how they are tested)."""

    def sync() -> None:
        if device.type == "cuda":
            torch.cuda.synchronize(device)

    for _ in range(2):
        function()
    sync()
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        function()
        sync()
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def prompt_vocabulary(max_tokens: int):
    """A vocabulary of ``PROMPT``'s words and sos/eos/unk with seeded random ``WORD_DIM``-d
    vectors: what the text encoder reads has the shape and size of a GloVe lookup."""
    from t2m.data.words import END_TOKEN, START_TOKEN, UNKNOWN_TOKEN, WordVectors, split_token

    tokens = (START_TOKEN, END_TOKEN, UNKNOWN_TOKEN, *PROMPT_TOKENS)
    words = list(dict.fromkeys(split_token(token)[0] for token in tokens))
    vectors = np.random.default_rng(0).standard_normal((len(words), WORD_DIM)).astype(np.float32)
    return WordVectors(words, vectors, "gpu-check", max_tokens)


def _paper_pipeline(device: torch.device, precision: str):
    from t2m.data.normalization import Normalizer
    from t2m.models.autoencoder import MovementDecoder
    from t2m.models.temporal_vae import TemporalVAE
    from t2m.pipeline import TextToMotion
    from t2m.presets import paper

    config = paper()
    vectorizer = prompt_vocabulary(config.data.max_text_tokens)
    torch.manual_seed(0)
    code_size = config.autoencoder.model.code_size
    vae = TemporalVAE(vectorizer.dim, code_size, config.generator.model)
    decoder = MovementDecoder(263, config.autoencoder.model)
    normalizer = Normalizer(np.zeros(263, np.float32), np.ones(263, np.float32))
    return TextToMotion(
        vae,
        decoder,
        normalizer,
        vectorizer,
        torch.zeros(code_size),
        device=device,
        precision=precision,
        copy_models=False,
    )


def generation(device: torch.device, repeats: int) -> dict:
    """Batch-1 latency and batch-32 throughput, fp32 and bf16."""
    results = {}
    for precision in ("fp32", "bf16"):
        pipe = _paper_pipeline(device, precision)
        encoded = [pipe.vectorizer.encode_tokens(PROMPT_TOKENS)]
        generator = torch.Generator(device).manual_seed(0)

        def run(batch: int, pipe=pipe, encoded=encoded, generator=generator):
            return lambda: pipe.generate_features(encoded * batch, [FRAMES] * batch, generator)

        one = _median_s(run(1), repeats, device)
        many = _median_s(run(BATCH), max(3, repeats // 3), device)
        results[f"gpu.{precision}_batch1_ms"] = round(one * 1e3, 2)
        results[f"gpu.{precision}_batch32_motions_per_s"] = round(BATCH / many, 1)
    return results


def cuda_graph(device: torch.device, repeats: int) -> dict:
    """The 49-step recurrent loop (generation plan, batch 1, fp32) eagerly and as a CUDA graph."""
    from t2m.accel.plans import generation_plan
    from t2m.inference.generation import text_batch

    pipe = _paper_pipeline(device, "fp32")
    vae = pipe.vae
    words, pos, lengths = text_batch(
        [pipe.vectorizer.encode_tokens(PROMPT_TOKENS)], pipe.device, torch.float32
    )
    steps = FRAMES // pipe.spec.snippet_length
    with torch.inference_mode():
        features, sentence, mask = vae.encode_text(words, pos, lengths)
        state = vae.initial_state(sentence, pipe.initial_code)
        context = vae.word_context(features, mask)
        times = vae.time_codes(torch.tensor([steps], device=device), steps)
        noise = torch.randn(1, steps, vae.config.latent_size, device=device)
        plan = generation_plan(vae)
        if plan is None:
            return {"gpu.cuda_graph": "no generation plan for this model"}

        def loop():
            return plan(state, context, times, noise)

        results = {"gpu.loop_batch1_eager_ms": round(_median_s(loop, repeats, device) * 1e3, 2)}
        try:
            side = torch.cuda.Stream(device)
            side.wait_stream(torch.cuda.current_stream(device))
            with torch.cuda.stream(side):
                for _ in range(3):
                    loop()
            torch.cuda.current_stream(device).wait_stream(side)
            graph = torch.cuda.CUDAGraph()
            with torch.cuda.graph(graph):
                loop()
        except RuntimeError as error:  # e.g. a host sync inside the loop
            results["gpu.cuda_graph"] = f"not captured: {' '.join(str(error).split())[:200]}"
            return results
        replay = _median_s(graph.replay, repeats, device)
        results["gpu.loop_batch1_cuda_graph_ms"] = round(replay * 1e3, 2)
    return results


def _ddp_worker(rank: int, world: int, port: int, out: str) -> None:
    """One process of :func:`ddp`: the generator stage's objective in DDP, as training wraps it."""
    import torch.distributed as dist

    from t2m.accel import accelerate
    from t2m.models.autoencoder import MovementAutoencoder
    from t2m.models.temporal_vae import TemporalVAE
    from t2m.presets import paper
    from t2m.train.generator import GeneratorObjective

    os.environ.update(MASTER_ADDR="127.0.0.1", MASTER_PORT=str(port))
    dist.init_process_group("nccl", rank=rank, world_size=world)
    device = torch.device("cuda", rank)
    torch.cuda.set_device(device)
    config = paper()
    torch.manual_seed(0)
    autoencoder = accelerate(MovementAutoencoder(263, config.autoencoder.model))
    code_size = config.autoencoder.model.code_size
    vae = accelerate(TemporalVAE(300, code_size, config.generator.model))
    objective = GeneratorObjective(
        vae, autoencoder.encoder, autoencoder.decoder, torch.zeros(code_size), config
    ).to(device)
    model = torch.nn.parallel.DistributedDataParallel(objective, device_ids=[rank])
    trainable = [p for p in objective.parameters() if p.requires_grad]
    optimizer = torch.optim.Adam(trainable, lr=config.generator.lr)
    batch = {
        "motion": torch.randn(BATCH, FRAMES, 263, device=device),
        "words": torch.randn(BATCH, 22, 300, device=device),
        "pos": torch.zeros(BATCH, 22, 15, device=device),
        "text_lengths": torch.full((BATCH,), 12),
    }

    def step() -> None:
        with torch.autocast("cuda", dtype=torch.bfloat16):
            losses = model(batch, True)
        optimizer.zero_grad(set_to_none=True)
        losses["loss"].backward()
        torch.nn.utils.clip_grad_norm_(trainable, config.generator.grad_clip)
        optimizer.step()

    seconds = _median_s(step, 5, device)
    if rank == 0:
        write_json_atomic(Path(out), {"gpu.ddp_2proc_vae_step_bf16_s": round(seconds, 4)})
    dist.destroy_process_group()


def ddp(folder: Path) -> dict:
    """A two-process DDP temporal-VAE step (bf16 autocast, batch 32 per process)."""
    if torch.cuda.device_count() < 2:
        return {"gpu.ddp": f"skipped: {torch.cuda.device_count()} device"}
    import socket

    import torch.multiprocessing as mp

    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    out = folder / "gpu_ddp.json"
    mp.spawn(_ddp_worker, args=(2, port, str(out)), nprocs=2, join=True)
    return json.loads(out.read_text())


@command
def main(argv: list[str] | None = None) -> int:
    parser = CommandParser(prog="python -m t2m.benchmarks.gpu", description=__doc__.split("\n")[0])
    config = parse_config(parser, GpuConfig, argv)
    if not torch.cuda.is_available():
        raise UsageError(
            f"no CUDA device (torch {torch.__version__}, built with CUDA {torch.version.cuda}); "
            "run this check on a machine with a GPU"
        )
    device = torch.device(config.device)
    from t2m.benchmarks import train

    results: dict = {"environment": versions()}
    print(json.dumps(results["environment"], indent=1), flush=True)
    for name, part in (
        ("generation", lambda: generation(device, config.repeats)),
        ("cuda_graph", lambda: cuda_graph(device, config.repeats)),
        ("training", lambda: train.run(quick=False, device=str(device))),
        ("ddp", lambda: ddp(config.out.parent)),
    ):
        start = time.perf_counter()
        try:
            results[name] = part()
        except Exception as error:  # one part failing must not hide the others' numbers
            results[name] = {"error": f"{type(error).__name__}: {error}"}
        results[name]["seconds"] = round(time.perf_counter() - start, 1)
        print(name, json.dumps(results[name]), flush=True)
        write_json_atomic(config.out, results)  # what is measured so far survives a crash
    return 0


if __name__ == "__main__":
    sys.exit(main())
