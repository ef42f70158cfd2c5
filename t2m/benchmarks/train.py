"""Training-step speed of every stage at a preset's sizes and batch sizes (``paper``, or
``demo`` for ``make demo``'s models), on synthetic batches.

One step = forward, backward, gradient clipping where the stage clips (length, temporal VAE,
evaluator) and optimizer update, as in the training loops (the temporal VAE with the frozen
encoder and the fine-tuned decoder). Reported per stage:
seconds per step and steps/s (fp32), the temporal-VAE step under bf16 autocast too, and the peak
memory (resident set on CPU, allocated on CUDA). Word vectors are 300-d as in the paper, 50-d
(the default vectors) for the other presets.

``python -m t2m.benchmarks.train [--quick] [--device auto|cpu|cuda] [--threads N]
[--preset paper|demo]``
"""

from __future__ import annotations

import argparse
import contextlib
import json
import resource
import sys
import time
from collections.abc import Callable

import torch
import torch.nn.functional as F

from t2m.accel import accelerate
from t2m.config import Config
from t2m.models.autoencoder import MovementAutoencoder, autoencoder_loss
from t2m.models.evaluator import Evaluator, contrastive_loss
from t2m.models.length import LengthEstimator, length_loss
from t2m.models.temporal_vae import TemporalVAE, temporal_vae_loss
from t2m.presets import preset as preset_config
from t2m.train.generator import decode
from t2m.train.runtime import adam, resolve_device

FEATURE_DIM, TOKENS = 263, 22
WORD_DIMS = {"paper": 300}
"""Word-vector size per preset; 50 (the default vectors) for the others."""


def _text(batch: int, generator: torch.Generator, device: torch.device, word_dim: int):
    words = torch.randn(batch, TOKENS, word_dim, generator=generator).to(device)
    pos = (
        F.one_hot(torch.randint(0, 15, (batch, TOKENS), generator=generator), 15).float().to(device)
    )
    lengths = torch.randint(5, TOKENS + 1, (batch,), generator=generator)
    return words, pos, lengths


def _peak_memory_mb(device: torch.device) -> float:
    if device.type == "cuda":
        return torch.cuda.max_memory_allocated(device) / 2**20
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # kB on Linux


def _time(step: Callable[[], None], steps: int, device: torch.device, warmup: bool = True) -> float:
    """Mean seconds per step (after one warm-up step unless ``warmup`` is False)."""
    if warmup:
        step()
    if device.type == "cuda":
        torch.cuda.synchronize(device)
    start = time.perf_counter()
    for _ in range(steps):
        step()
    if device.type == "cuda":
        torch.cuda.synchronize(device)
    return (time.perf_counter() - start) / steps


def _autoencoder_steps(
    config: Config, generator: torch.Generator, device: torch.device, steps: int
) -> tuple[dict, MovementAutoencoder]:
    """Stage 1, the autoencoder: batches of windows of 24 frames (128 at paper size)."""
    ae = accelerate(MovementAutoencoder(FEATURE_DIM, config.autoencoder.model).to(device))
    ae_opt = adam(ae.parameters(), lr=config.autoencoder.lr)
    windows = torch.randn(
        config.autoencoder.batch_size,
        config.autoencoder.window_frames,
        FEATURE_DIM,
        generator=generator,
    ).to(device)

    def ae_step() -> None:
        reconstruction, codes = ae(windows)
        ae_opt.zero_grad(set_to_none=True)
        autoencoder_loss(reconstruction, windows, codes)["loss"].backward()
        ae_opt.step()

    seconds = _time(ae_step, steps * 3, device)
    row = dict(
        ae_step_s=round(seconds, 4),
        ae_steps_per_s=round(1 / seconds, 2),
        ae_peak_memory_mb=round(_peak_memory_mb(device), 1),
    )
    return row, ae


def _length_steps(
    config: Config, word_dim: int, generator: torch.Generator, device: torch.device, steps: int
) -> dict:
    """Stage 2, text2length (batch 64 at paper size)."""
    estimator = accelerate(LengthEstimator(word_dim, config.length.model).to(device))
    len_opt = adam(estimator.parameters(), lr=config.length.lr)
    words, pos, lengths = _text(config.length.batch_size, generator, device, word_dim)
    classes = torch.randint(10, 50, (config.length.batch_size,), generator=generator).to(device)

    def length_step() -> None:
        len_opt.zero_grad(set_to_none=True)
        length_loss(estimator(words, pos, lengths), classes)["loss"].backward()
        torch.nn.utils.clip_grad_norm_(list(estimator.parameters()), config.length.grad_clip)
        len_opt.step()

    seconds = _time(length_step, steps * 3, device)
    return dict(
        length_step_s=round(seconds, 4),
        length_steps_per_s=round(1 / seconds, 2),
        length_peak_memory_mb=round(_peak_memory_mb(device), 1),
    )


def _temporal_vae_steps(
    config: Config,
    ae: MovementAutoencoder,
    word_dim: int,
    generator: torch.Generator,
    device: torch.device,
    steps: int,
    quick: bool,
) -> tuple[dict, tuple[torch.Tensor, torch.Tensor, torch.Tensor]]:
    """Stage 3, the temporal VAE with the frozen encoder and the fine-tuned decoder (batch 32,
    49 snippets: 196 frames at paper size), in fp32 and under bf16 autocast, then generation;
    also returns its text batch (the evaluator's too)."""
    batch, snippets = config.generator.batch_size, config.generator.end_snippets
    code_size = config.autoencoder.model.code_size
    vae = accelerate(TemporalVAE(word_dim, code_size, config.generator.model).to(device))
    t2m_opt = adam(
        [
            {"params": vae.parameters(), "lr": config.generator.lr},
            {"params": ae.decoder.parameters(), "lr": config.generator.decoder_lr},
        ]
    )
    words, pos, lengths = _text(batch, generator, device, word_dim)
    motion = torch.randn(batch, snippets * 4, FEATURE_DIM, generator=generator).to(device)
    ae.encoder.eval().requires_grad_(False)
    with torch.no_grad():
        initial_code = ae.encode(torch.zeros(1, 4, FEATURE_DIM, device=device))[0, 0]
    trainable = [p for p in vae.parameters()] + list(ae.decoder.parameters())

    def t2m_step(teacher_forcing: bool, bf16: bool) -> Callable[[], None]:
        def step() -> None:
            autocast = (
                torch.autocast(device_type=device.type, dtype=torch.bfloat16)
                if bf16
                else contextlib.nullcontext()
            )
            with autocast:
                with torch.no_grad():
                    codes = ae.encode(motion)
                features, sentence, mask = vae.encode_text(words, pos, lengths)
                outputs = vae(features, sentence, mask, codes, initial_code, teacher_forcing)
                decoded = decode(ae.decoder, outputs["codes"])  # as the generator stage
                losses = temporal_vae_loss(outputs, codes, decoded, motion)
            t2m_opt.zero_grad(set_to_none=True)
            losses["loss"].backward()
            torch.nn.utils.clip_grad_norm_(trainable, config.generator.grad_clip)
            t2m_opt.step()

        return step

    # the loop mixes both kinds of batch: 40% teacher-forced, 60% free-running
    forced = _time(t2m_step(True, False), steps, device)
    free = _time(t2m_step(False, False), steps, device, warmup=not quick)
    mixed = 0.4 * forced + 0.6 * free
    row = dict(
        t2m_step_teacher_forced_s=round(forced, 3),
        t2m_step_free_running_s=round(free, 3),
        t2m_step_s=round(mixed, 3),
        t2m_steps_per_s=round(1 / mixed, 3),
        t2m_peak_memory_mb=round(_peak_memory_mb(device), 1),
    )
    forced_bf16 = _time(t2m_step(True, True), steps, device)
    free_bf16 = _time(t2m_step(False, True), steps, device, warmup=not quick)
    row.update(t2m_step_bf16_s=round(0.4 * forced_bf16 + 0.6 * free_bf16, 3))

    # generation (sampling) of 32 motions of 49 snippets, no gradients
    vae.eval()
    gen = torch.Generator(device=device).manual_seed(0)
    num = torch.full((batch,), snippets, device=device)

    def sample_step() -> None:
        with torch.no_grad():
            features, sentence, mask = vae.encode_text(words, pos, lengths)
            ae.decode(vae.generate(features, sentence, mask, num, initial_code, gen))

    seconds = _time(sample_step, steps, device, warmup=not quick)
    row.update(t2m_generate_batch32_s=round(seconds, 3))
    return row, (words, pos, lengths)


def _evaluator_steps(
    config: Config,
    text: tuple[torch.Tensor, torch.Tensor, torch.Tensor],
    word_dim: int,
    generator: torch.Generator,
    device: torch.device,
    steps: int,
) -> dict:
    """Stage 4, the evaluator (batch 32, 196 frames at paper size), on stage 3's text batch."""
    words, pos, lengths = text
    batch = config.generator.batch_size
    evaluator = Evaluator(
        word_dim, FEATURE_DIM, config.autoencoder.model, config.evaluator.model
    ).to(device)
    accelerate(evaluator)
    eval_trainable = [p for p in evaluator.parameters() if p.requires_grad]
    eval_opt = adam(eval_trainable, lr=config.evaluator.lr)
    motion_lengths = torch.randint(10, 50, (batch,), generator=generator).to(device) * 4
    motion = torch.randn(batch, 196, FEATURE_DIM, generator=generator).to(device)

    def eval_step() -> None:
        text, moving = evaluator(words, pos, lengths, motion, motion_lengths)
        eval_opt.zero_grad(set_to_none=True)
        contrastive_loss(text, moving, 1)["loss"].backward()
        torch.nn.utils.clip_grad_norm_(eval_trainable, config.evaluator.grad_clip)
        eval_opt.step()

    seconds = _time(eval_step, steps * 3, device)
    return dict(
        eval_step_s=round(seconds, 4),
        eval_steps_per_s=round(1 / seconds, 2),
        eval_peak_memory_mb=round(_peak_memory_mb(device), 1),
    )


def run(quick: bool = False, device: str = "auto", threads: int = 0, preset: str = "paper") -> dict:
    """Seconds per training step of each stage at ``preset``'s sizes; see the module docstring.

    ``device`` "auto" is CUDA when present, else CPU.
    """
    if threads > 0:
        torch.set_num_threads(threads)
    device_ = resolve_device(device)
    config = preset_config(preset)
    word_dim = WORD_DIMS.get(preset, 50)
    generator = torch.Generator().manual_seed(0)
    torch.manual_seed(0)
    steps = 1 if quick else 3
    results: dict = {
        "device": str(device_),
        "torch_threads": torch.get_num_threads(),
        "preset": preset,
    }

    ae_row, ae = _autoencoder_steps(config, generator, device_, steps)
    results.update(ae_row)
    results.update(_length_steps(config, word_dim, generator, device_, steps))
    vae_row, text = _temporal_vae_steps(config, ae, word_dim, generator, device_, steps, quick)
    results.update(vae_row)
    results.update(_evaluator_steps(config, text, word_dim, generator, device_, steps))
    return results


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m t2m.benchmarks.train", description=__doc__.splitlines()[0]
    )
    parser.add_argument("--quick", action="store_true", help="one timed step per measurement")
    parser.add_argument("--device", default="auto", help="auto (CUDA when present), cpu, cuda")
    parser.add_argument("--threads", type=int, default=0, help="torch threads (0: default)")
    parser.add_argument("--preset", default="paper", choices=("paper", "demo"), help="sizes")
    args = parser.parse_args(argv)
    print(json.dumps(run(args.quick, args.device, args.threads, args.preset), indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
