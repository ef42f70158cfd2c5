"""Side by side with the original T2M code: the same measurements on both, in one process,
interleaved round by round; each row reports both medians and the median of the per-round
ratios ours / original (below 1: ours is faster).

    python -m t2m.benchmarks.versus_original --original PATH [--rounds N] [--threads 2] [--out JSON]

``PATH`` is a checkout of github.com/EricGuo5513/text-to-motion; its own modules are imported
from there (``networks/modules.py``, ``networks/trainers.py``, ``scripts/motion_process.py``:
:mod:`t2m.benchmarks.original`) and driven through its trainers' methods. Nothing of it is
copied here; the one accommodation is ``np.float`` (removed in numpy 1.24, read by its
``common/quaternion.py``), set to ``float`` before the import. Both sides get random weights at
the paper's sizes and the same inputs. What each row times:

* ``features``: one 200-frame joint array -> 263-d features (ours ``process_motion``: retarget,
  canonicalise, features; the original's ``process_file``), one thread.
* ``generation_b1_*``, ``generation_b32_*``: "text in, joints out" for 196 frames: spaCy
  tagging (the same function on both sides), word vectors (the same 300-d table), text encoder,
  49 prior / generator steps, movement decoder, de-normalisation, each side's
  ``recover_from_ric``. The original at fp32 (its ``CompTrainerV6.generate`` on the batch);
  ours at fp32, bf16 and int8 (:class:`t2m.pipeline.TextToMotion`), and with the ONNX
  Runtime backend (``backend="onnx"``) at fp32 and int8 when it is installed. Batch 32: 32 copies of
  the prompt; reported as seconds per batch (the ratio is the inverse of the throughput ratio).
* ``vae_step_*``: one temporal-VAE training step, batch 32 x 49 snippets: encoder codes,
  forward, loss, backward, clipping at 0.5, Adam (ours: the fused Adam that training uses,
  :func:`t2m.train.runtime.adam`); 0.4 x teacher-forced + 0.6 x free-running
  (the mix of both trainers). The original's ``CompTrainerV6.forward`` / ``update`` (without
  the anomaly detection its script switches on); ours fp32 and under bf16 autocast.
* ``autoencoder_step`` (batch 128 x 24 frames), ``length_step`` (batch 64),
  ``evaluator_step`` (batch 32, 196 frames): forward, loss, backward, clipping where the stage
  clips, Adam (ours fused, as in training); the original's trainers' ``forward`` / ``update``
  (its length loop's body); ours in fp32 and under bf16 autocast (what ``--bf16`` does in
  training).
* ``peak_memory_*``: a fresh process per side that builds the paper-size generation models
  (random weights) and generates one 196-frame motion at batch 1; its peak resident set.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import platform
import random
import statistics
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path
from types import SimpleNamespace
from typing import TYPE_CHECKING

import numpy as np
import torch
import torch.nn.functional as F

from t2m.benchmarks.original import (
    FEATURES,
    WORD_DIM,
    import_original,
    original_generation_models,
    original_options,
)

if TYPE_CHECKING:
    from t2m.config import Config

PROMPT = "a person walks forward and waves with the right hand"
FRAMES, SNIPPETS = 196, 49


# -- inputs --------------------------------------------------------------------------------


def vectorizer_300d():
    """A 300-d word table (random vectors) holding the prompt's words: both sides look up the
    same vectors."""
    from dataset_tools.texts import tag_prompts
    from t2m.data.words import WordVectors

    words = ["sos", "eos", "unk", *sorted({w for w, _ in tag_prompts([PROMPT])[0]})]
    vectors = np.random.default_rng(0).normal(size=(len(words), WORD_DIM)).astype(np.float32)
    return WordVectors(words, vectors, "versus-original")


def text_batch(vectorizer, batch: int):
    from dataset_tools.texts import tag_prompts

    pairs = tag_prompts([PROMPT])[0]
    encoded = vectorizer.encode_tokens([f"{w}/{p}" for w, p in pairs])
    words = torch.from_numpy(np.stack([encoded.words] * batch))
    pos = torch.from_numpy(np.stack([encoded.pos_onehot] * batch))
    return words, pos, torch.full((batch,), encoded.length, dtype=torch.long)


def random_text(batch: int, generator: torch.Generator):
    """Word vectors (B, 22, 300), POS one-hots and lengths sorted descending (the original's
    packing needs sorted captions; ours does not care)."""
    words = torch.randn(batch, 22, WORD_DIM, generator=generator)
    pos = F.one_hot(torch.randint(0, 15, (batch, 22), generator=generator), 15).float()
    lengths = torch.randint(5, 23, (batch,), generator=generator).sort(descending=True).values
    return words, pos, lengths


# -- rows: (ours, original) callables ------------------------------------------------------


def features_row(orig: SimpleNamespace) -> dict[str, Callable[[], object]]:
    from dataset_tools.representation import process_motion
    from t2m.benchmarks.representation import _random_motion

    joints = _random_motion(np.random.default_rng(0), 200)
    mp = orig.motion_process
    # what the original's script sets up as globals under its __main__
    mp.l_idx1, mp.l_idx2, mp.fid_r, mp.fid_l = 5, 8, [8, 11], [7, 10]
    mp.face_joint_indx, mp.r_hip, mp.l_hip, mp.joints_num = [2, 1, 17, 16], 2, 1, 22
    mp.n_raw_offsets = torch.from_numpy(orig.param.t2m_raw_offsets)
    mp.kinematic_chain = orig.param.t2m_kinematic_chain
    skeleton = orig.skeleton.Skeleton(mp.n_raw_offsets, mp.kinematic_chain, "cpu")
    mp.tgt_offsets = skeleton.get_offsets_joints(torch.from_numpy(joints[0]).float())
    return {
        "ours": lambda: process_motion(joints),
        "original": lambda: mp.process_file(joints.copy(), 0.002),
    }


def _finishing_as_the_original(pipe):
    """``pipe`` finishing its motions as the original's generation row does: features to joints
    (``recover_from_ric``), no rigid fit and no clean-up, so that both sides time the same work.
    The rigid fit that every motion of ours gets (``TextToMotion.finish``, about 4 ms a motion
    on one core) is not in these rows."""
    from dataset_tools.representation import recover_from_ric

    def finish(features: np.ndarray, clean: bool = True) -> tuple[np.ndarray, np.ndarray]:
        return recover_from_ric(features, 22).astype(np.float32), features

    pipe.finish = finish
    return pipe


def generation_rows(orig: SimpleNamespace, batch: int) -> dict[str, Callable[[], object]]:
    from dataset_tools.texts import tag_prompts
    from t2m.accel import onnx as onnx_backend
    from t2m.data.normalization import Normalizer
    from t2m.models.autoencoder import MovementDecoder
    from t2m.models.temporal_vae import TemporalVAE
    from t2m.pipeline import TextToMotion
    from t2m.presets import paper

    vectorizer = vectorizer_300d()
    mean, std = np.zeros(FEATURES, np.float32), np.ones(FEATURES, np.float32)
    config = paper()
    torch.manual_seed(0)
    vae = TemporalVAE(WORD_DIM, 512, config.generator.model)
    decoder = MovementDecoder(FEATURES, config.autoencoder.model)
    pipes = {
        precision: TextToMotion(
            vae, decoder, Normalizer(mean, std), vectorizer, torch.zeros(512), precision=precision
        )
        for precision in ("fp32", "bf16", "int8")
        if precision != "bf16" or _BF16["run"]
    }
    if onnx_backend.available():  # the optional ONNX Runtime backend, same weights
        for precision in onnx_backend.ONNX_PRECISIONS:
            pipes[f"onnx_{precision}"] = TextToMotion(
                vae,
                decoder,
                Normalizer(mean, std),
                vectorizer,
                torch.zeros(512),
                precision=precision,
                backend="onnx",
            )
    models = original_generation_models(orig)
    for module in models.values():
        module.eval()
    trainer = orig.trainers.CompTrainerV6(
        original_options(is_train=False), **{k: v for k, v in models.items() if k != "seq_post"}
    )
    recover = orig.motion_process.recover_from_ric
    mean_t, std_t = torch.from_numpy(mean), torch.from_numpy(std)

    def original() -> np.ndarray:
        pairs = tag_prompts([PROMPT] * batch)  # the same tagging as ours
        encoded = [vectorizer.encode_tokens([f"{w}/{p}" for w, p in item]) for item in pairs]
        words = torch.from_numpy(np.stack([e.words for e in encoded]))
        pos = torch.from_numpy(np.stack([e.pos_onehot for e in encoded]))
        lengths = torch.tensor([e.length for e in encoded])
        m_lens = torch.full((batch,), FRAMES)
        with torch.no_grad():
            motions, _, _ = trainer.generate(words, pos, lengths, m_lens, SNIPPETS, FEATURES)
            joints = recover(motions * std_t + mean_t, 22)
        return joints.numpy()

    rows = {"original": original}
    for precision, pipe in pipes.items():
        _finishing_as_the_original(pipe)
        rows[f"ours_{precision}"] = lambda pipe=pipe: pipe.generate(
            [PROMPT] * batch, lengths=FRAMES, clean=False, seed=0, batch_size=batch
        )
    return rows


def vae_step_rows(orig: SimpleNamespace) -> dict[str, Callable[[], object]]:
    from t2m.accel import accelerate
    from t2m.models.autoencoder import MovementAutoencoder
    from t2m.models.temporal_vae import TemporalVAE, temporal_vae_loss
    from t2m.presets import paper
    from t2m.train.runtime import adam

    batch, config = 32, paper()
    generator = torch.Generator().manual_seed(1)
    words, pos, lengths = random_text(batch, generator)
    motion = torch.randn(batch, FRAMES, FEATURES, generator=generator)
    # ours
    torch.manual_seed(0)
    ae = accelerate(MovementAutoencoder(FEATURES, config.autoencoder.model))
    ae.encoder.eval().requires_grad_(False)
    vae = accelerate(TemporalVAE(WORD_DIM, 512, config.generator.model))
    optimizer = adam(
        [{"params": vae.parameters()}, {"params": ae.decoder.parameters(), "lr": 2e-5}], lr=2e-4
    )
    trainable = list(vae.parameters()) + list(ae.decoder.parameters())
    with torch.no_grad():
        initial = ae.encode(torch.zeros(1, 4, FEATURES))[0, 0]

    def ours_step(teacher_forcing: bool, bf16: bool) -> None:
        with _autocast(bf16):
            with torch.no_grad():
                codes = ae.encode(motion)
            features, sentence, mask = vae.encode_text(words, pos, lengths)
            outputs = vae(features, sentence, mask, codes, initial, teacher_forcing)
            losses = temporal_vae_loss(outputs, codes, ae.decode(outputs["codes"]), motion)
        optimizer.zero_grad(set_to_none=True)
        losses["loss"].backward()
        torch.nn.utils.clip_grad_norm_(trainable, 0.5)
        optimizer.step()

    # the original
    models = original_generation_models(orig)
    opts = original_options(
        text_enc_mod="bigru", lambda_rec_mov=1.0, lambda_rec_mot=1.0, lambda_kld=0.01
    )
    trainer = orig.trainers.CompTrainerV6(opts, **models)
    for name in ("text_enc", "seq_pri", "seq_dec", "seq_post", "att_layer"):
        setattr(trainer, f"opt_{name}", torch.optim.Adam(models[name].parameters(), lr=2e-4))
    trainer.opt_mov_dec = torch.optim.Adam(models["mov_dec"].parameters(), lr=2e-5)
    models["mov_enc"].eval()
    for module in ("text_enc", "seq_pri", "seq_dec", "seq_post", "att_layer", "mov_dec"):
        models[module].train()
    data = (words, pos, None, lengths, motion, torch.full((batch,), FRAMES))

    def original_step(teacher_forcing: bool) -> None:
        trainer.forward(data, 1.0 if teacher_forcing else 0.0, SNIPPETS)
        trainer.update()

    def mixed(step: Callable[[bool], None]) -> Callable[[], tuple[float, float]]:
        def run() -> tuple[float, float]:
            """The 0.4 / 0.6 mix of the two kinds of step: (wall, CPU) seconds."""
            forced = _seconds(lambda: step(True))
            free = _seconds(lambda: step(False))
            return tuple(0.4 * a + 0.6 * b for a, b in zip(forced, free))  # type: ignore[return-value]

        return run

    return {
        "original": mixed(original_step),
        "ours_fp32": mixed(lambda tf: ours_step(tf, False)),
        "ours_bf16": mixed(lambda tf: ours_step(tf, True)),
    }


def _autocast(bf16: bool) -> contextlib.AbstractContextManager:
    return torch.autocast("cpu", dtype=torch.bfloat16) if bf16 else contextlib.nullcontext()


def _sides(ours: Callable[[bool], None], original: Callable[[], None]) -> dict:
    """The original, ours in fp32 and ours under bf16 autocast (``--bf16`` in training)."""
    return {
        "original": original,
        "ours_fp32": lambda: ours(False),
        "ours_bf16": lambda: ours(True),
    }


def small_step_rows(orig: SimpleNamespace) -> dict[str, dict[str, Callable[[], object]]]:
    from t2m.presets import paper

    config = paper()
    generator = torch.Generator().manual_seed(2)
    torch.manual_seed(0)
    return {
        "autoencoder_step": _autoencoder_sides(orig, config, generator),
        "length_step": _length_sides(orig, config, generator),
        "evaluator_step": _evaluator_sides(orig, config, generator),
    }


def _autoencoder_sides(
    orig: SimpleNamespace, config: Config, generator: torch.Generator
) -> dict[str, Callable[[], object]]:
    """The autoencoder's step, batch 128 x 24 frames."""
    from t2m.accel import accelerate
    from t2m.models.autoencoder import MovementAutoencoder, autoencoder_loss
    from t2m.train.runtime import adam

    m = orig.modules
    windows = torch.randn(128, 24, FEATURES, generator=generator)
    ae = accelerate(MovementAutoencoder(FEATURES, config.autoencoder.model)).train()
    ae_opt = adam(ae.parameters(), lr=1e-4)

    def ours_ae(bf16: bool) -> None:
        with _autocast(bf16):
            reconstruction, codes = ae(windows)
            loss = autoencoder_loss(reconstruction, windows, codes)["loss"]
        ae_opt.zero_grad(set_to_none=True)
        loss.backward()
        ae_opt.step()

    enc, dec = m.MovementConvEncoder(FEATURES - 4, 512, 512), m.MovementConvDecoder(512, 512, 263)
    decomp = orig.trainers.DecompTrainerV3(
        original_options(lambda_sparsity=0.001, lambda_smooth=0.001), enc.train(), dec.train()
    )
    decomp.opt_movement_enc = torch.optim.Adam(enc.parameters(), lr=1e-4)
    decomp.opt_movement_dec = torch.optim.Adam(dec.parameters(), lr=1e-4)

    def original_ae() -> None:
        decomp.forward(windows)
        decomp.update()

    return _sides(ours_ae, original_ae)


def _length_sides(
    orig: SimpleNamespace, config: Config, generator: torch.Generator
) -> dict[str, Callable[[], object]]:
    """The length estimator's step, batch 64."""
    from t2m.accel import accelerate
    from t2m.models.length import LengthEstimator, length_loss
    from t2m.train.runtime import adam

    m = orig.modules
    text64 = random_text(64, generator)
    classes = torch.randint(10, 50, (64,), generator=generator)
    estimator = accelerate(LengthEstimator(WORD_DIM, config.length.model)).train()
    length_opt = adam(estimator.parameters(), lr=1e-4)

    def ours_length(bf16: bool) -> None:
        with _autocast(bf16):
            loss = length_loss(estimator(*text64), classes)["loss"]
        length_opt.zero_grad(set_to_none=True)
        loss.backward()
        torch.nn.utils.clip_grad_norm_(list(estimator.parameters()), config.length.grad_clip)
        length_opt.step()

    original_estimator = m.MotionLenEstimatorBiGRU(WORD_DIM, 15, 512, 200).train()
    length_trainer = orig.trainers.LengthEstTrainer(original_options(), original_estimator)
    length_trainer.opt_estimator = torch.optim.Adam(original_estimator.parameters(), lr=1e-4)

    def original_length() -> None:  # the body of LengthEstTrainer.train's loop
        logits = original_estimator(*text64)
        length_trainer.zero_grad([length_trainer.opt_estimator])
        loss = length_trainer.mul_cls_criterion(logits, classes)
        loss.backward()
        length_trainer.clip_norm([original_estimator])
        length_trainer.step([length_trainer.opt_estimator])

    return _sides(ours_length, original_length)


def _evaluator_sides(
    orig: SimpleNamespace, config: Config, generator: torch.Generator
) -> dict[str, Callable[[], object]]:
    """The evaluator's step, batch 32, 196 frames."""
    from t2m.accel import accelerate
    from t2m.models.evaluator import Evaluator, contrastive_loss
    from t2m.train.runtime import adam

    m = orig.modules
    words, pos, lengths = random_text(32, generator)
    motion = torch.randn(32, FRAMES, FEATURES, generator=generator)
    motion_lengths = torch.randint(10, 50, (32,), generator=generator) * 4
    evaluator = Evaluator(WORD_DIM, FEATURES, config.autoencoder.model, config.evaluator.model)
    accelerate(evaluator).train()
    trainable = [p for p in evaluator.parameters() if p.requires_grad]
    eval_opt = adam(trainable, lr=1e-4)

    def ours_evaluator(bf16: bool) -> None:
        with _autocast(bf16):
            text, moving = evaluator(words, pos, lengths, motion, motion_lengths)
            loss = contrastive_loss(text, moving, 1)["loss"]
        eval_opt.zero_grad(set_to_none=True)
        loss.backward()
        torch.nn.utils.clip_grad_norm_(trainable, config.evaluator.grad_clip)
        eval_opt.step()

    text_encoder = m.TextEncoderBiGRUCo(WORD_DIM, 15, 512, 512, "cpu").train()
    motion_encoder = m.MotionEncoderBiGRUCo(512, 1024, 512, "cpu").train()
    movement_encoder = m.MovementConvEncoder(FEATURES - 4, 512, 512).eval()
    match = orig.trainers.TextMotionMatchTrainer(
        original_options(negative_margin=10.0), text_encoder, motion_encoder, movement_encoder
    )
    match.opt_text_encoder = torch.optim.Adam(text_encoder.parameters(), lr=1e-4)
    match.opt_motion_encoder = torch.optim.Adam(motion_encoder.parameters(), lr=1e-4)
    data = (words, pos, None, lengths, motion, motion_lengths, None)

    def original_evaluator() -> None:
        match.forward(data)
        match.update()

    return _sides(ours_evaluator, original_evaluator)


# -- peak memory (child processes) ----------------------------------------------------------


def memory_child(side: str, original_path: str) -> float:
    """Build the paper-size generation models, generate one motion; peak RSS in MB."""
    from t2m.benchmarks.memory import peak_rss_mb

    torch.set_num_threads(1)
    orig = import_original(Path(original_path))
    rows = generation_rows_for_memory(orig, side)
    rows()
    return peak_rss_mb()


def generation_rows_for_memory(orig: SimpleNamespace, side: str) -> Callable[[], object]:
    """One side's batch-1 generation, built as a user's process would (ours converts in place)."""
    from t2m.data.normalization import Normalizer
    from t2m.models.autoencoder import MovementDecoder
    from t2m.models.temporal_vae import TemporalVAE
    from t2m.pipeline import TextToMotion
    from t2m.presets import paper

    if side == "original":
        models = original_generation_models(orig)
        for module in models.values():
            module.eval()
        trainer = orig.trainers.CompTrainerV6(
            original_options(is_train=False), **{k: v for k, v in models.items() if k != "seq_post"}
        )
        words, pos, lengths = text_batch(vectorizer_300d(), 1)

        def original() -> object:
            with torch.no_grad():
                motions = trainer.generate(
                    words, pos, lengths, torch.tensor([FRAMES]), SNIPPETS, FEATURES
                )[0]
                return orig.motion_process.recover_from_ric(motions, 22)

        return original
    config = paper()
    backend, precision = side.split("_") if side.startswith("onnx_") else ("torch", side)
    pipe = TextToMotion(
        TemporalVAE(WORD_DIM, 512, config.generator.model),
        MovementDecoder(FEATURES, config.autoencoder.model),
        Normalizer(np.zeros(FEATURES, np.float32), np.ones(FEATURES, np.float32)),
        vectorizer_300d(),
        torch.zeros(512),
        precision=precision,
        copy_models=False,
        backend=backend,
    )
    _finishing_as_the_original(pipe)
    return lambda: pipe.generate(PROMPT, lengths=FRAMES, clean=False, seed=0)


def memory_sides() -> tuple[str, ...]:
    """Ours: the precisions, and the ONNX Runtime backend's when it is installed."""
    from t2m.accel import onnx as onnx_backend

    onnx = onnx_backend.ONNX_PRECISIONS if onnx_backend.available() else ()
    torch_sides = ("fp32", "bf16", "int8") if _BF16["run"] else ("fp32", "int8")
    return (*torch_sides, *(f"onnx_{precision}" for precision in onnx))


def peak_memory(original: Path) -> dict[str, float]:
    results = {}
    for side in ("original", *memory_sides()):
        out = subprocess.run(
            [
                sys.executable,
                "-m",
                "t2m.benchmarks.versus_original",
                "--memory-child",
                side,
                "--original",
                str(original),
            ],
            check=True,
            capture_output=True,
            text=True,
        ).stdout
        results[side] = float(out.strip().splitlines()[-1])
    return results


# -- the interleaved timing -----------------------------------------------------------------


def _seconds(function: Callable[[], object]) -> tuple[float, float]:
    """(wall, CPU) seconds of one call; a function that times itself returns that pair.

    CPU time is this process's (all its threads): on a machine shared with other jobs it
    leaves out the time the cores were busy with them, and with one thread it is the most
    stable measure; with more threads it also counts their waiting.
    """
    wall, cpu = time.perf_counter(), time.process_time()
    result = function()
    if isinstance(result, tuple) and len(result) == 2 and isinstance(result[0], float):
        return result
    return time.perf_counter() - wall, time.process_time() - cpu


def interleave(
    sides: dict[str, Callable[[], object]], rounds: int
) -> dict[str, list[tuple[float, float]]]:
    """Every side once per round (order rotated each round), after one warm-up call each."""
    for function in sides.values():
        function()
    names = list(sides)
    times: dict[str, list[tuple[float, float]]] = {name: [] for name in names}
    for index in range(rounds):
        shift = index % len(names)
        for name in names[shift:] + names[:shift]:
            random.seed(index)  # the original's trainers draw teacher forcing from it
            times[name].append(_seconds(sides[name]))
    return times


def summarise(name: str, times: dict[str, list[tuple[float, float]]]) -> list[dict]:
    """Per side: medians of wall and CPU seconds, and the median (min, max) of the per-round
    ratios ours / original, of wall and of CPU time."""
    base = times["original"]
    rows = []
    for side, values in times.items():
        if side == "original":
            continue
        ratios = [ours[0] / theirs[0] for ours, theirs in zip(values, base)]
        cpu_ratios = [ours[1] / theirs[1] for ours, theirs in zip(values, base)]
        rows.append(
            {
                "measure": name if side == "ours" else f"{name} {side.removeprefix('ours_')}",
                "original_s": round(statistics.median(v[0] for v in base), 4),
                "ours_s": round(statistics.median(v[0] for v in values), 4),
                "ratio": round(statistics.median(ratios), 3),
                "ratio_min": round(min(ratios), 3),
                "ratio_max": round(max(ratios), 3),
                "original_cpu_s": round(statistics.median(v[1] for v in base), 4),
                "ours_cpu_s": round(statistics.median(v[1] for v in values), 4),
                "cpu_ratio": round(statistics.median(cpu_ratios), 3),
                "rounds": len(ratios),
            }
        )
    return rows


_BF16 = {"run": True}
"""Whether the bf16 sides run (:func:`measure` sets it): only where bfloat16 is native, unless
asked for (elsewhere they are slower than fp32 and only show the cost of emulation)."""


def measure(
    original: Path, rounds: int, threads: int, only: set[str] | None, bf16: bool | None = None
) -> dict:
    """Every row of the module docstring (those of ``only``); ``bf16``: run the bf16 sides
    (default: where :func:`t2m.hardware.native_bf16` says bfloat16 is native)."""
    from t2m.hardware import cpu_description, native_bf16

    _BF16["run"] = native_bf16("cpu") if bf16 is None else bf16
    orig = import_original(original)
    results: list[dict] = []

    def wanted(name: str) -> bool:
        return only is None or name in only

    def add(name: str, sides: dict[str, Callable[[], object]], count: int) -> None:
        if not _BF16["run"]:
            sides = {side: run for side, run in sides.items() if "bf16" not in side}
        rows = summarise(name, interleave(sides, count))
        for row in rows:  # as it comes: a long run shows its progress
            print(json.dumps(row), file=sys.stderr, flush=True)
        results.extend(rows)

    if wanted("features"):
        torch.set_num_threads(1)
        add("features (1 thread)", features_row(orig), rounds * 3)
    torch.set_num_threads(threads)
    if wanted("generation"):
        add("generation_b1", generation_rows(orig, 1), rounds)
        add("generation_b32", generation_rows(orig, 32), rounds)
    if wanted("training"):
        for name, sides in small_step_rows(orig).items():
            add(name, sides, rounds)
        add("vae_step", vae_step_rows(orig), max(2, rounds // 2))
    memory = peak_memory(original) if wanted("memory") else {}
    for side in memory_sides():
        if memory:
            results.append(
                {
                    "measure": f"peak_memory_mb {side}",
                    "original_s": memory["original"],
                    "ours_s": memory[side],
                    "ratio": round(memory[side] / memory["original"], 3),
                    "rounds": 1,
                }
            )
    return {
        "environment": {
            "date": time.strftime("%Y-%m-%d %H:%M:%S %Z"),
            "cpu": _cpu(),
            "cpu_kernels": cpu_description(),
            "bf16_rows": _BF16["run"],
            "cores": os.cpu_count(),
            "threads": threads,
            "load_average_at_end": os.getloadavg(),
            "python": platform.python_version(),
            "torch": torch.__version__,
            "numpy": np.__version__,
            "original": str(original),
            "rounds": rounds,
        },
        "rows": results,
    }


def _cpu() -> str:
    from t2m.bench import _cpu_name

    return _cpu_name()


def to_markdown(results: dict) -> str:
    env = results["environment"]
    lines = [
        f"Measured {env['date']} on {env['cpu']} ({env['cores']} cores, {env['threads']} torch "
        f"threads, load average at the end {', '.join(f'{x:.1f}' for x in env['load_average_at_end'])}"
        f"); torch {env['torch']}, Python {env['python']}; {env['rounds']} interleaved rounds.",
        f"Kernels: {env.get('cpu_kernels', '-')}"
        + ("" if env.get("bf16_rows", True) else "; bf16 rows not run (no native bfloat16)."),
        "",
        "| measure | original | ours | ratio ours / original (min-max) | CPU-time ratio |",
        "| --- | --- | --- | --- | --- |",
    ]
    for row in results["rows"]:
        unit = "MB" if row["measure"].startswith("peak_memory") else "s"
        spread = f" ({row['ratio_min']}-{row['ratio_max']})" if "ratio_min" in row else ""
        lines.append(
            f"| {row['measure']} | {row['original_s']} {unit} | {row['ours_s']} {unit} | "
            f"{row['ratio']}{spread} | {row.get('cpu_ratio', '-')} |"
        )
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m t2m.benchmarks.versus_original", description=__doc__.splitlines()[0]
    )
    parser.add_argument("--original", type=Path, required=True, help="the original's checkout")
    parser.add_argument("--rounds", type=int, default=5, help="interleaved rounds per row")
    parser.add_argument("--threads", type=int, default=2, help="torch threads (both sides)")
    parser.add_argument(
        "--only", nargs="*", choices=("features", "generation", "training", "memory")
    )
    parser.add_argument("--out", type=Path, help="write the results as JSON here")
    parser.add_argument(
        "--bf16",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="run the bf16 rows (default: only where bfloat16 is native; elsewhere they are "
        "slower than fp32)",
    )
    parser.add_argument("--memory-child", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.memory_child:
        print(memory_child(args.memory_child, str(args.original)))
        return 0
    results = measure(
        args.original, args.rounds, args.threads, set(args.only or []) or None, args.bf16
    )
    if args.out:
        from dataset_tools.io import write_json_atomic

        write_json_atomic(args.out, results)
    print(to_markdown(results))
    return 0


if __name__ == "__main__":
    sys.exit(main())
