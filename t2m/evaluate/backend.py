"""The models behind the evaluation: what the protocol asks of them, and the trained stages.

:class:`Backend` is all :func:`~t2m.evaluate.protocol.run_protocol` needs: text and motion
embeddings from an evaluator, and a generator. :class:`CheckpointBackend` is a generator (a run
of ours or the original T2M release, through the shared text-to-motion pipeline
:class:`~t2m.pipeline.TextToMotion`) and an :class:`Embedder`: the evaluator with the statistics
and vocabulary that feed it, either a run's own evaluator stage (:meth:`Embedder.from_stage`) or
the release's ``text_mot_match``, the field's standard evaluator (:meth:`Embedder.from_release`).
Motions pass between the two as raw features: the generator de-normalises with its own
statistics, the embedder normalises with the evaluator's. The generator reads a caption as it
would read the caption typed as a prompt: words it was not trained on read as trained ones
(:func:`t2m.lexicon.read_prompt_tokens`); the evaluator reads the caption as stored.
"""

from __future__ import annotations

import copy
import logging
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import numpy as np
import torch

from dataset_tools.spec import DatasetSpec
from t2m.data.dataset import Caption
from t2m.data.normalization import Normalizer
from t2m.data.words import WordVectors
from t2m.lexicon import read_prompt_tokens
from t2m.models.evaluator import Evaluator

logger = logging.getLogger(__name__)


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


# A backend may also offer ``with_plan(plan) -> Backend`` (the same models generating with the
# other plan) and ``plans_differ(captions) -> bool`` (whether the plans generate some caption
# differently): the protocol then tables the other plan's rows too (EvalConfig.both_plans).


@dataclass(frozen=True)
class Embedder:
    """An evaluator and how it is fed: raw features are normalised with ``normalizer`` and
    zero-padded to the longest motion, captions encoded by ``vectorizer`` with their true token
    count (:meth:`Evaluator.embed_motion` drops the contacts and runs ``frames // 4`` steps).

    Attributes:
        evaluator: the contrastive text/motion evaluator (eval mode, float32).
        normalizer: (D,) mean/std of the evaluator's input.
        vectorizer: the vocabulary of its text encoder.
        spec: the dataset spec it reads (feature dimension, snippet length, longest motion).
        description: what the results name it by (results.json ``evaluator``): ``source``,
            ``path`` and ``sha256`` of its file, ``normalization`` (which mean/std).
    """

    evaluator: Evaluator
    normalizer: Normalizer
    vectorizer: WordVectors
    spec: DatasetSpec
    description: dict[str, str | None]

    @classmethod
    def from_stage(cls, stage: Any) -> Embedder:
        """A run's own trained ``evaluator`` stage (:class:`~t2m.train.checkpoint.TrainedStage`;
        one built without a checkpoint, as the benchmark does, has no path)."""
        from t2m.release.load import file_sha256

        path = stage.path
        return cls(
            evaluator=stage.models["evaluator"],
            normalizer=stage.normalizer,
            vectorizer=stage.vectorizer,
            spec=stage.spec,
            description={
                "source": "the run's own evaluator stage",
                "path": None if path is None else str(path),
                "sha256": None if path is None else file_sha256(Path(path)),
                "normalization": "the mean/std stored with the evaluator stage",
            },
        )

    @classmethod
    def from_release(cls, release: Any) -> Embedder:
        """The original T2M release's evaluator (:class:`~t2m.release.ReleaseEvaluator`), fed
        as the release feeds it: its generator's ``meta/`` statistics as stored, its GloVe
        subset; accelerated (:func:`t2m.accel.accelerate`) as a run's evaluator stage is."""
        from t2m.accel import accelerate
        from t2m.release import find_release

        meta = find_release(release.path.parents[1]).meta_dir
        return cls(
            evaluator=accelerate(release.evaluator),
            normalizer=release.normalizer,
            vectorizer=release.vectorizer,
            spec=release.spec,
            description={
                "source": "the original T2M release's text_mot_match",
                "path": str(release.path),
                "sha256": release.sha256,
                "normalization": f"{meta}/mean.npy and std.npy (the release's meta/, as stored)",
            },
        )

    @classmethod
    def load(
        cls,
        folder: str | Path,
        device: str | torch.device = "cpu",
        which: str = "best",
        glove_dir: str | Path | None = None,
    ) -> Embedder:
        """The release's evaluator when ``folder`` is (in) a release
        (:func:`t2m.release.load_release_evaluator`, ``glove_dir`` its GloVe subset), else the
        ``evaluator`` stage of the run folder ``folder``."""
        from t2m.release import is_release_folder, load_release_evaluator
        from t2m.train import load_stage

        if is_release_folder(folder):
            return cls.from_release(load_release_evaluator(folder, glove_dir, device))
        return cls.from_stage(load_stage(folder, "evaluator", device, which))


def _chunks(count: int, size: int) -> list[slice]:
    """Consecutive slices of at most ``size`` items that cover ``range(count)``."""
    return [slice(start, min(start + size, count)) for start in range(0, count, size)]


def generation_batches(frames: np.ndarray, batch_size: int) -> list[np.ndarray]:
    """The batches :meth:`CheckpointBackend.generate` runs: item indices in order of decreasing
    length (``frames`` (N,)), cut every ``batch_size``; batches of similar length waste fewer
    recurrent steps on padding (a batch runs as many steps as its longest item)."""
    order = np.argsort(-np.asarray(frames), kind="stable")
    return [order[chunk] for chunk in _chunks(len(order), batch_size)]


def padding_share(frames: np.ndarray, batch_size: int) -> float:
    """The share of the recurrent item-steps of :func:`generation_batches` spent on padding:
    1 - sum(lengths) / sum(batch size x its longest length)."""
    frames = np.asarray(frames)
    run = sum(
        len(batch) * int(frames[batch].max()) for batch in generation_batches(frames, batch_size)
    )
    return 1.0 - float(frames.sum()) / run


class CheckpointBackend:
    """An evaluator (embeddings) and the shared text-to-motion pipeline (generation).

    Build one with :meth:`from_run_dir`, or from an evaluator and a
    :class:`~t2m.pipeline.TextToMotion` (the benchmark builds untrained ones of a preset's sizes).

    Args:
        evaluator: an :class:`Embedder`, or a trained ``evaluator`` stage
            (:class:`~t2m.train.checkpoint.TrainedStage`: its evaluator, statistics and
            vocabulary, :meth:`Embedder.from_stage`).
        pipeline: generation (text2length + temporal VAE + decoder), batched.
        batch_size: items per forward pass.
    """

    def __init__(self, evaluator: Any, pipeline: Any, batch_size: int = 128, plan: str = "clauses"):
        if batch_size < 1:
            raise ValueError(f"batch_size must be >= 1, got {batch_size}")
        embedder = evaluator if isinstance(evaluator, Embedder) else Embedder.from_stage(evaluator)
        self.embedder = embedder
        self.pipeline = pipeline
        self.batch_size = batch_size
        if plan not in ("clauses", "whole"):
            raise ValueError(f"plan must be 'clauses' or 'whole', got {plan!r}")
        self.plan = plan
        """how captions are generated: "clauses" (:meth:`t2m.pipeline.TextToMotion.
        generate_features` with each caption's clauses, as t2m.sample) or "whole" (one pass,
        the paper)"""
        self.evaluator = embedder.evaluator
        self.device = next(self.evaluator.parameters()).device
        if embedder.normalizer.dim != pipeline.normalizer.dim:
            raise ValueError(
                f"the evaluator reads {embedder.normalizer.dim}-d features but the generator "
                f"writes {pipeline.normalizer.dim}-d ones"
            )
        if embedder.spec != pipeline.spec:
            raise ValueError(
                f"the evaluator was trained on {embedder.spec.name}, the generator on "
                f"{pipeline.spec.name}"
            )
        self.spec = embedder.spec
        """The dataset spec of the models (snippet length, longest motion, fps)."""
        # Replications reuse captions: encode each once per vocabulary.
        self._encoded: dict[tuple[str, tuple[str, ...]], Any] = {}
        self.readings: dict[str, str] = {}
        """Untrained words of the generated captions -> the trained words they were read as."""

    @classmethod
    def from_run_dir(
        cls,
        run_dir: str | Path,
        device: str = "cpu",
        which: str = "best",
        batch_size: int = 128,
        precision: str = "fp32",
        evaluator_dir: str | Path | None = None,
        glove_dir: str | Path | None = None,
        plan: str = "clauses",
    ) -> CheckpointBackend:
        """Load the generator and length stages of a run folder, or the original T2M release's
        models (any folder of its layout), and the evaluator (:meth:`Embedder.load`): the one
        of ``evaluator_dir`` (the release's ``text_mot_match``) when given, else the run's own
        (a release's own for a release). ``glove_dir``: the GloVe subset of a release (default:
        ``glove/`` beside its ``checkpoints/``). A one-line UsageError names the make target of
        a missing stage."""
        from t2m.pipeline import TextToMotion
        from t2m.train.runtime import resolve_device

        resolved = resolve_device(device)
        embedder = Embedder.load(evaluator_dir or run_dir, resolved, which, glove_dir)
        pipeline = TextToMotion.from_checkpoints(
            run_dir, str(resolved), precision, which=which, glove_dir=glove_dir
        )
        return cls(embedder, pipeline, batch_size, plan)

    def with_plan(self, plan: str) -> CheckpointBackend:
        """The same models and caches, generating with ``plan``."""
        other = copy.copy(self)
        if plan not in ("clauses", "whole"):
            raise ValueError(f"plan must be 'clauses' or 'whole', got {plan!r}")
        other.plan = plan
        return other

    def plans_differ(self, captions: Sequence[Caption]) -> bool:
        """Whether the clause plan generates some of ``captions`` otherwise than one pass: one
        of them reads as several clauses (:meth:`~t2m.pipeline.TextToMotion.encode_clauses`)."""
        return any(len(self._clauses(self.pipeline, caption)) > 1 for caption in captions)

    def _encode(self, vectorizer: Any, tokens: Sequence[tuple[str, ...]]) -> list[Any]:
        """``word/POS`` tokens of each caption -> EncodedText."""
        fingerprint = vectorizer.fingerprint()
        out = []
        for words in tokens:
            key = (fingerprint, words)
            if key not in self._encoded:
                self._encoded[key] = vectorizer.encode_tokens(words)
            out.append(self._encoded[key])
        return out

    def _read(self, caption: Caption) -> tuple[str, ...]:
        """A caption's dataset tokens as the generator reads them: its words the generator was
        not trained on read as trained ones, as a typed prompt's are
        (:func:`t2m.lexicon.read_prompt_tokens`); the readings are collected in
        :attr:`readings` and logged once each."""
        key = ("read", tuple(caption.tokens))
        if key not in self._encoded:
            pipeline, found = self.pipeline, {}
            self._encoded[key] = tuple(
                read_prompt_tokens(
                    caption.text,
                    caption.tokens,
                    pipeline.training_words,
                    pipeline.vectorizer,
                    readings=found,
                )
            )
            for word, reading in found.items():
                if self.readings.get(word) != reading:
                    logger.info("captions' word %r read as %r, as in a prompt", word, reading)
                self.readings[word] = reading
        return self._encoded[key]

    def _clauses(self, pipeline: Any, caption: Caption) -> tuple[Any, ...]:
        """A caption's clauses (of its tokens as the generator reads them, :meth:`_read`)
        encoded as standalone captions (cached like :meth:`_encode`)."""
        key = ("clauses", tuple(caption.tokens))
        if key not in self._encoded:
            self._encoded[key] = pipeline.encode_clauses(self._read(caption))
        return self._encoded[key]

    @torch.no_grad()
    def embed_texts(self, captions: Sequence[Caption]) -> np.ndarray:
        # the evaluator reads the captions as stored (its own measure, untrained words included)
        encoded = self._encode(self.embedder.vectorizer, [tuple(c.tokens) for c in captions])
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
        normalizer = self.embedder.normalizer
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
        """Features (frames, D) of one motion per caption: the pipeline's plan
        (:meth:`~t2m.pipeline.TextToMotion.plan_prepared`: lengths drawn ``batch_size``
        captions at a time where not given, then the latent draws of each batch of
        :func:`generation_batches`) and its models. With the clause plan, a counted clause
        given a length (the ground-truth lengths) keeps the time its count needs and stands
        still for the rest, as ``t2m.sample`` does at a fixed length
        (:meth:`~t2m.pipeline.TextToMotion.clause_plan`); drawn lengths never settle."""
        from t2m.pipeline import PreparedText

        pipeline = self.pipeline
        generator = torch.Generator(pipeline.device).manual_seed(seed)
        # the generator reads each caption as it would read the caption typed as a prompt
        encoded = self._encode(pipeline.vectorizer, [self._read(c) for c in captions])
        # the clause plan draws and generates a caption of several clauses clause by clause (as
        # t2m.sample does); the paper's plan whole captions
        parts = [self._clauses(pipeline, c) if self.plan == "clauses" else () for c in captions]
        prepared = [
            PreparedText(c.text, e, (), (), p)
            for c, e, p in zip(captions, encoded, parts, strict=True)
        ]
        if lengths is not None:
            lengths = [int(n) for n in lengths]
        planned = pipeline.plan_prepared(
            prepared,
            1,
            lengths,
            generator,
            batch_size=self.batch_size,
            length_batch=self.batch_size,
        )
        out: list[np.ndarray | None] = [None] * len(captions)
        fixed = dict(zip(planned.items, planned.fixed, strict=True))
        for items, frames, noise in planned.batches():
            index = [p for p, _ in items]
            features = pipeline.generate_features(
                [encoded[i] for i in index],
                frames,
                generator,
                noise=noise,
                clauses=None if self.plan != "clauses" else [parts[i] for i in index],
                # as t2m.sample: at a given length a counted clause keeps the time it needs
                settle=[fixed[item] for item in items] if self.plan == "clauses" else False,
            )
            for item, feats in zip(index, features, strict=True):
                out[item] = feats
        return out  # type: ignore[return-value]
