"""The models behind the evaluation: what the protocol asks of them, and the trained stages.

:class:`Backend` is all :func:`~t2m.evaluate.protocol.run_protocol` needs: text and motion
embeddings from an evaluator, and a generator. :class:`CheckpointBackend` is the trained run:
the contrastive evaluator of the ``eval`` stage embeds, the shared text-to-motion pipeline
(:class:`~t2m.pipeline.TextToMotion`) generates, both in batches.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any, Protocol

import numpy as np
import torch

from t2m.data.dataset import Caption


class Backend(Protocol):
    """Embedders and generator behind the protocol (see :class:`CheckpointBackend`)."""

    def embed_texts(self, captions: Sequence[Caption]) -> np.ndarray:
        """Captions -> (N, E) embeddings."""
        ...

    def embed_motions(self, motions: Sequence[np.ndarray]) -> np.ndarray:
        """Raw features, each (T_i, D) with T_i a multiple of the snippet length (4) -> (N, E)
        embeddings."""
        ...

    def generate(
        self, captions: Sequence[Caption], lengths: np.ndarray | None, seed: int
    ) -> list[np.ndarray]:
        """One motion per caption as raw features (T_i, D); ``lengths`` in frames (multiples
        of 4), or None to let the length model draw them. Deterministic for a seed."""
        ...


def _chunks(count: int, size: int) -> list[slice]:
    """Consecutive slices of at most ``size`` items that cover ``range(count)``."""
    return [slice(start, min(start + size, count)) for start in range(0, count, size)]


class CheckpointBackend:
    """The trained evaluator (embeddings) and the shared text-to-motion pipeline (generation).

    Build one with :meth:`from_run_dir`, or from an evaluator stage
    (:class:`~t2m.train.checkpoint.TrainedStage`) and a :class:`~t2m.pipeline.TextToMotion`
    (the benchmark builds untrained ones of a preset's sizes).

    Args:
        evaluator_stage: the trained ``evaluator`` stage (its evaluator, statistics and vocabulary).
        pipeline: generation (text2length + temporal VAE + decoder), batched.
        batch_size: items per forward pass.
    """

    def __init__(self, evaluator_stage: Any, pipeline: Any, batch_size: int = 128):
        if batch_size < 1:
            raise ValueError(f"batch_size must be >= 1, got {batch_size}")
        self.evaluator_stage = evaluator_stage
        self.pipeline = pipeline
        self.batch_size = batch_size
        self.evaluator = evaluator_stage.models["evaluator"]
        self.device = next(self.evaluator.parameters()).device
        if evaluator_stage.normalizer.dim != pipeline.normalizer.dim:
            raise ValueError(
                f"the evaluator reads {evaluator_stage.normalizer.dim}-d features but the generator "
                f"writes {pipeline.normalizer.dim}-d ones"
            )
        if evaluator_stage.spec != pipeline.spec:
            raise ValueError(
                f"the evaluator was trained on {evaluator_stage.spec.name}, the generator on "
                f"{pipeline.spec.name}"
            )
        self.spec = evaluator_stage.spec
        """The dataset spec of the models (snippet length, longest motion, fps)."""
        # Replications reuse captions: encode each once per vocabulary.
        self._encoded: dict[tuple[str, tuple[str, ...]], Any] = {}

    @classmethod
    def from_run_dir(
        cls,
        run_dir: str | Path,
        device: str = "cpu",
        which: str = "best",
        batch_size: int = 128,
        precision: str = "fp32",
    ) -> CheckpointBackend:
        """Load the evaluator, length and generator stages of a run folder (a one-line
        UsageError names the make target of a missing stage)."""
        from t2m.pipeline import TextToMotion
        from t2m.train import load_stage
        from t2m.train.runtime import resolve_device

        resolved = resolve_device(device)
        evaluator_stage = load_stage(run_dir, "evaluator", resolved, which)
        pipeline = TextToMotion.from_checkpoints(run_dir, str(resolved), precision, which=which)
        return cls(evaluator_stage, pipeline, batch_size)

    def _encode(self, vectorizer: Any, captions: Sequence[Caption]) -> list[Any]:
        """Dataset tokens (``word/POS``) -> EncodedText, as the models were trained on them."""
        fingerprint = vectorizer.fingerprint()
        out = []
        for caption in captions:
            key = (fingerprint, tuple(caption.tokens))
            if key not in self._encoded:
                self._encoded[key] = vectorizer.encode_tokens(caption.tokens)
            out.append(self._encoded[key])
        return out

    @torch.no_grad()
    def embed_texts(self, captions: Sequence[Caption]) -> np.ndarray:
        encoded = self._encode(self.evaluator_stage.vectorizer, captions)
        out = []
        for chunk in _chunks(len(encoded), self.batch_size):
            items = encoded[chunk]
            words = torch.from_numpy(np.stack([e.words for e in items])).to(self.device)
            pos = torch.from_numpy(np.stack([e.pos_onehot for e in items])).to(self.device)
            lengths = torch.tensor([e.length for e in items], dtype=torch.long, device=self.device)
            out.append(self.evaluator.embed_text(words, pos, lengths).float().cpu().numpy())
        return np.concatenate(out)

    @torch.no_grad()
    def embed_motions(self, motions: Sequence[np.ndarray]) -> np.ndarray:
        normalizer = self.evaluator_stage.normalizer
        unit = self.spec.snippet_length
        lengths = np.array([len(m) for m in motions], dtype=np.int64)
        if np.any(lengths % unit) or np.any(lengths < unit):
            raise ValueError(f"motion lengths must be positive multiples of {unit}")
        # Every motion is zero-padded to max_frames, as the original evaluator's loader did and
        # as the evaluator is trained: the second encoder convolution sees the padding's
        # activations, so a shorter padding would shift the last snippets' codes and make an
        # embedding depend on the batch it happens to be in.
        frames = max(self.spec.max_frames, int(lengths.max()))
        out = []
        for chunk in _chunks(len(motions), self.batch_size):
            batch = motions[chunk]
            padded = np.zeros((len(batch), frames, normalizer.dim), np.float32)
            for row, motion in enumerate(batch):
                padded[row, : len(motion)] = normalizer.normalize(np.asarray(motion, np.float32))
            embeddings = self.evaluator.embed_motion(
                torch.from_numpy(padded).to(self.device),
                torch.from_numpy(lengths[chunk]).to(self.device),
            )
            out.append(embeddings.float().cpu().numpy())
        return np.concatenate(out)

    def generate(
        self, captions: Sequence[Caption], lengths: np.ndarray | None, seed: int
    ) -> list[np.ndarray]:
        from t2m.pipeline import PreparedText

        pipeline = self.pipeline
        generator = torch.Generator(pipeline.device).manual_seed(seed)
        encoded = self._encode(pipeline.vectorizer, captions)
        if lengths is None:
            prepared = [
                PreparedText(c.text, e, (), ()) for c, e in zip(captions, encoded, strict=True)
            ]
            frames = np.concatenate(
                [
                    pipeline.sample_lengths(prepared[chunk], generator)
                    for chunk in _chunks(len(prepared), self.batch_size)
                ]
            ).astype(np.int64)
        else:
            frames = np.asarray(lengths, dtype=np.int64)
            if len(frames) != len(captions):
                raise ValueError(f"{len(frames)} lengths for {len(captions)} captions")
        # Batches of similar length waste fewer recurrent steps on padding.
        order = np.argsort(-frames, kind="stable")
        out: list[np.ndarray | None] = [None] * len(captions)
        for chunk in _chunks(len(order), self.batch_size):
            index = order[chunk]
            features = pipeline.generate_features(
                [encoded[i] for i in index], [int(frames[i]) for i in index], generator
            )
            for item, feats in zip(index, features, strict=True):
                out[item] = feats
        return out  # type: ignore[return-value]
