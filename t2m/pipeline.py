"""Text to motion: the Python API that ``python -m t2m.sample`` is a thin shell over.

    pipe = TextToMotion.from_checkpoints("checkpoints/demo")
    motions = pipe.generate(["a person walks forward and waves"], num_samples=3, seed=0)
    motions[0][2].joints      # (T, 22, 3) metres, y-up, at pipe.spec.fps: prompt 0, sample 2

Steps of :meth:`TextToMotion.generate`:

1. lower-case and tag every prompt with spaCy (as the dataset builder tags captions) and look
   its words up; words the model was not trained on are named in a warning, a prompt without
   any word it was trained on is an error;
2. fix every motion's length: given frames are rounded to whole snippets and clamped to the
   dataset's limits (HumanML3D: 4-frame snippets, 40..196 frames at 20 fps; KIT-ML: 24..196 at
   12.5 fps; :class:`dataset_tools.skeleton.DatasetSpec`, stored in the checkpoints), missing
   ones are drawn from the text2length model (with ``plan="clauses"``, a prompt of several
   clauses as the sum of its clauses' draws, :meth:`TextToMotion.sample_lengths`);
3. generate snippet codes with the temporal VAE's prior, batched across prompts and samples
   (items sorted by length so a batch wastes few steps), and decode them to features. With
   ``plan="clauses"`` (the default) a prompt of several clauses ("jumps twice, then waves") is
   generated clause by clause (:mod:`t2m.clauses`): each clause, as a caption of its own, gets
   the length the text2length model expects for it plus a variance-weighted share of the rest
   (:meth:`TextToMotion.clause_snippets`), and continues from the code
   the previous clause ended on; at a length the user fixed, a clause that names a count keeps
   the time it needs and stands still for the rest (:meth:`TextToMotion.settle_plan`);
   ``plan="whole"`` is the paper's single pass over the prompt;
4. de-normalise the features with the statistics stored in the checkpoint, make the motion
   rigid on the model's skeleton and clean up its foot contacts (:meth:`TextToMotion.finish`)
   and recover joints (the spec's number) with ``dataset_tools.representation.recover_from_ric``.

All randomness comes from one ``torch.Generator`` seeded by ``seed``: the same seed, prompts,
lengths, batch size and precision give the same motions, bit for bit, on the same machine.

Precision: ``fp32`` (reference), ``bf16`` (weights and activations in bfloat16) or ``int8``
(dynamic int8 quantisation of the recurrent cells and linear layers, CPU only; the decoder runs
in bfloat16 where the hardware computes it natively, else in float32). At batch 1 the prior /
generator step reads every weight once per 4 frames, so smaller weights are faster, but only
where bfloat16 is native (:func:`t2m.hardware.native_bf16`: a GPU, or a CPU with AVX512_BF16 or
AMX). Elsewhere bf16 is slower than fp32
(:data:`t2m.inference.conversion.BF16_EMULATED_COST`): it still runs when asked for, with a
warning. ``backend="onnx"`` runs that step in ONNX Runtime instead of torch (fp32 and int8,
:mod:`t2m.accel.onnx`). Loading is :mod:`t2m.inference.loading`, conversion (device, precision,
backend, :func:`t2m.accel.accelerate`) :func:`t2m.inference.conversion.convert`.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Collection, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from dataset_tools.command import UsageError
from dataset_tools.representation import recover_from_ric
from dataset_tools.rigid import finish_features
from dataset_tools.spec import HUMANML3D, DatasetSpec, spec_for_dim
from t2m.accel import PRECISIONS as PRECISIONS
from t2m.clauses import (
    MIN_SETTLE_SNIPPETS,
    SETTLE_TEXT,
    SETTLE_TOKENS,
    clause_captions,
    clause_targets,
    needed_snippets,
    settle_counted,
    share_snippets,
)
from t2m.data.normalization import Normalizer
from t2m.data.words import EncodedText, WordVectors
from t2m.inference.conversion import BF16_EMULATED_COST as BF16_EMULATED_COST
from t2m.inference.conversion import convert
from t2m.inference.conversion import offered_precisions as offered_precisions
from t2m.inference.generation import clause_codes, decode_features, text_batch
from t2m.inference.loading import load_models
from t2m.lexicon import read_prompt
from t2m.models.autoencoder import (
    CONTACT_DIMS,
    MovementDecoder,
    MovementEncoder,
    check_snippet_length,
)
from t2m.models.length import LengthEstimator, sample_lengths
from t2m.models.temporal_vae import TemporalVAE
from t2m.motion import GeneratedMotion

logger = logging.getLogger(__name__)

SHORT_COUNT_SHARE = 0.9
"""A fixed length under this share of what a prompt's count needs gets a warning
(:meth:`TextToMotion.warn_short_counts`)."""

PLANS = ("clauses", "whole")
"""How a prompt is generated: clause by clause (:mod:`t2m.clauses`) or in one pass (the paper)."""


def _moments(logits: torch.Tensor) -> tuple[np.ndarray, np.ndarray]:
    """Expected lengths in snippets and their variances (float64 (N,) each) of length logits
    (N, K)."""
    probs = torch.softmax(logits.detach().double(), -1).cpu().numpy()
    units = np.arange(probs.shape[-1], dtype=np.float64)
    means = probs @ units
    return means, probs @ units**2 - means**2


@dataclass(frozen=True)
class PreparedText:
    """A prompt ready for the text encoders, and what the vocabulary made of it.

    Attributes:
        text: the prompt as given.
        encoded: its encoding (lower-cased, tagged, looked up).
        unknown_words: its words the model was not trained on (in prompt order).
        dropped_words: its words past the text encoder's ``max_tokens``.
        clauses: for a prompt of several clauses (:func:`t2m.clauses.clause_captions`), each
            clause encoded as a caption of its own; empty for a single clause.
    """

    text: str
    encoded: EncodedText
    unknown_words: tuple[str, ...]
    dropped_words: tuple[str, ...]
    clauses: tuple[EncodedText, ...] = ()


@dataclass(frozen=True)
class GenerationBatch:
    """Everything a generation draws before its models run (:meth:`TextToMotion.plan`), in the
    order it is drawn: the motions with their lengths, then their latent draws.

    Attributes:
        prepared: the prompts (:meth:`TextToMotion.prepare`), in the order given.
        items: (prompt, sample) of each motion, longest first (ties keep prompt-major order):
            the order the models run them in.
        frames: each item's length in frames, in that order.
        noise: the latent draws of each run of ``batch_size`` items in that order,
            (items, their longest length in snippets, Z) each.
        batch_size: motions generated together.
        fixed: whether each item's length was given (True) or drawn from the text2length model,
            in that order: where counted clauses settle (:meth:`TextToMotion.settle_plan`).
    """

    prepared: list[PreparedText]
    items: list[tuple[int, int]]
    frames: list[int]
    noise: list[torch.Tensor]
    batch_size: int
    fixed: list[bool] = field(default_factory=list)

    def batches(self) -> Iterator[tuple[list[tuple[int, int]], list[int], torch.Tensor]]:
        """(items, frames, noise) of each run of the models."""
        for index, start in enumerate(range(0, len(self.items), self.batch_size)):
            end = start + self.batch_size
            yield self.items[start:end], self.frames[start:end], self.noise[index]


def frames_for(frames: float, spec: DatasetSpec = HUMANML3D) -> int:
    """A requested length in frames rounded to whole snippets of ``spec`` and clamped to its
    ``min_frames .. max_frames`` (with a warning)."""
    if not math.isfinite(frames) or frames <= 0:
        raise ValueError(f"motion length must be a positive number of frames, got {frames}")
    unit = spec.snippet_length
    rounded = math.floor(frames / unit + 0.5) * unit  # halves round up
    clamped = min(max(rounded, spec.min_frames), spec.max_frames)
    if clamped != rounded:
        logger.warning(
            "length %g frames is outside %d..%d; using %d frames",
            frames,
            spec.min_frames,
            spec.max_frames,
            clamped,
        )
    return clamped


def frames_for_seconds(seconds: float, spec: DatasetSpec = HUMANML3D) -> int:
    """A length in seconds as frames at ``spec.fps``, rounded and clamped as :func:`frames_for`."""
    if not math.isfinite(seconds) or seconds <= 0:
        raise ValueError(f"motion length must be a positive number of seconds, got {seconds}")
    return frames_for(seconds * spec.fps, spec)


class TextToMotion:
    """Trained T2M models ready to turn prompts into motions.

    Args:
        vae: the text encoder + temporal VAE (eval mode).
        decoder: the fine-tuned movement decoder (codes -> normalised features).
        normalizer: the statistics the models were trained with.
        vectorizer: the vocabulary of the VAE's text encoder.
        initial_code: (C,) the mean-pose code fed before the first snippet.
        spec: the dataset the models were trained on (fps, snippet length, frame limits,
            joints); default: the one of the statistics' feature dimension.
        length_model: text2length (needed only when lengths are not given).
        length_vectorizer: its vocabulary; must be cut from the VAE's (same origin).
        device: where the models run (the modules are moved there).
        precision: "fp32", "bf16" or "int8" (CPU only). bf16 pays only where bfloat16 is
            native (:func:`t2m.hardware.native_bf16`); elsewhere it runs with a warning.
        training_words: the words of the captions the model was trained on (stored in
            generator checkpoints); prompts are checked against them. Default (checkpoints
            written before they were stored): the vocabulary's words.
        spacy_pos: tag prompts with spaCy 3's own POS instead of the published HumanML3D
            conventions (for models trained on a dataset built with ``--spacy-pos``).
        encoder: the frozen movement encoder (features -> snippet codes), for edits that
            continue from known frames (:meth:`edit`); None: edits search without it.
        copy_models: for bf16 / int8, convert copies of ``vae`` and ``decoder`` (the caller's
            modules stay float32); False converts them in place, which saves holding the float32
            weights and their converted copy at once (``from_checkpoints`` owns what it loads),
            and, without an ``encoder``, releases the VAE's posterior
            (:meth:`~t2m.models.temporal_vae.TemporalVAE.release_posterior`: nothing here reads it).
        backend: ``"torch"``, or ``"onnx"``: the prior / generator steps run in ONNX Runtime
            (:mod:`t2m.accel.onnx`; fp32 and int8 on the CPU, needs the ``onnx`` extra), from
            a snapshot of the weights (int8: taken here; fp32: at the first generation).
    """

    def __init__(
        self,
        vae: TemporalVAE,
        decoder: MovementDecoder,
        normalizer: Normalizer,
        vectorizer: WordVectors,
        initial_code: torch.Tensor,
        spec: DatasetSpec | None = None,
        length_model: LengthEstimator | None = None,
        length_vectorizer: WordVectors | None = None,
        device: str | torch.device = "cpu",
        precision: str = "fp32",
        training_words: Collection[str] | None = None,
        spacy_pos: bool = False,
        encoder: MovementEncoder | None = None,
        *,
        copy_models: bool = True,
        backend: str = "torch",
    ) -> None:
        # what the models read: checked before anything is converted
        spec = spec or spec_for_dim(normalizer.dim)
        if spec.feature_dim != normalizer.dim:
            raise ValueError(
                f"{spec.name} has {spec.feature_dim}-d features, the statistics {normalizer.dim}"
            )
        check_snippet_length(spec.snippet_length)
        length_vectorizer = length_vectorizer or vectorizer
        if not length_vectorizer.compatible(vectorizer):
            raise ValueError(
                "the text2length model and the text-to-motion model use different "
                "word vectors (retrain with `make train-len` on the same dataset)"
            )
        if training_words is None:
            logger.debug(
                "no training words stored with the model (an older checkpoint): prompts are "
                "checked against the %d words of the vocabulary",
                vectorizer.size,
            )
            training_words = set(vectorizer.words) - {"sos", "eos", "unk"}
        # the models, converted (device, precision, backend) and accelerated
        self.device = torch.device(device)
        models = convert(
            vae,
            decoder,
            self.device,
            precision,
            backend,
            encoder=encoder,
            length_model=length_model,
            copy_models=copy_models,
        )
        self.precision, self.backend = precision, backend
        self.vae, self.decoder, self.encoder = models.vae, models.decoder, models.encoder
        self.length_model = models.length_model
        self.dtype, self.decoder_dtype = models.dtype, models.decoder_dtype
        self.spec = spec
        self.normalizer = normalizer
        self.vectorizer, self.length_vectorizer = vectorizer, length_vectorizer
        self.training_words = frozenset(training_words)
        self.spacy_pos = spacy_pos
        self.encoder_input_size = spec.feature_dim - CONTACT_DIMS
        self.initial_code = initial_code.to(self.device, self.dtype)

    def with_precision(self, precision: str) -> TextToMotion:
        """The same models, vocabulary and settings behind another inference precision (from a
        float32 pipeline: reduced-precision weights are not converted back)."""
        if self.precision != "fp32":
            raise ValueError(f"with_precision needs a fp32 pipeline, this one is {self.precision}")
        return TextToMotion(
            vae=self.vae,
            decoder=self.decoder,
            normalizer=self.normalizer,
            vectorizer=self.vectorizer,
            initial_code=self.initial_code,
            spec=self.spec,
            length_model=self.length_model,
            length_vectorizer=self.length_vectorizer,
            device=self.device,
            precision=precision,
            training_words=self.training_words,
            spacy_pos=self.spacy_pos,
            encoder=self.encoder,
            backend=self.backend,
        )

    # -- loading -----------------------------------------------------------------------------

    @classmethod
    def from_checkpoints(
        cls,
        run_dir: str | Path,
        device: str = "cpu",
        precision: str = "fp32",
        need_length_model: bool = True,
        which: str = "best",
        glove_dir: str | Path | None = None,
        backend: str = "torch",
    ) -> TextToMotion:
        """Load the ``generator`` (and ``length``) stages of a run folder, or the original T2M
        release's models from any folder of its layout (:func:`t2m.inference.loading.load_models`;
        ``glove_dir``: its GloVe subset, default ``glove/`` beside its ``checkpoints/``), and
        convert them in place (the pipeline owns what it loads).

        Raises ValueError, one line naming the make target that trains a missing stage, when a
        stage is missing, unreadable or does not belong with the other.
        """
        loaded = load_models(run_dir, device, need_length_model, which, glove_dir)
        return cls(**loaded.arguments(), precision=precision, copy_models=False, backend=backend)

    # -- steps -------------------------------------------------------------------------------

    def prepare(self, texts: Sequence[str], quiet: bool = False) -> list[PreparedText]:
        """Lower-case, tag and encode prompts (:func:`dataset_tools.texts.tag_prompts`).

        Words the model was not trained on (``training_words``) are read as trained ones where
        they can be (:func:`t2m.lexicon.read_untrained`: "dash" as "run", a warning names the
        reading); those still untrained are named in a warning and keep their word vector where
        the vocabulary has one, else ``unk``. ``quiet``: no warnings (a check before the work
        that prepares the same prompts again).
        Counts and imperatives are read in the wording the model was trained on
        (:func:`t2m.lexicon.read_prompt`: "two times" as "twice", "wave your hand" as "a person
        wave their hand"). Raises
        UsageError (one line) for an empty prompt or one with no word the model was trained on.
        """
        from dataset_tools.texts import tag_prompts

        texts = [texts] if isinstance(texts, str) else list(texts)
        if not texts:
            raise UsageError("no prompt given")
        for text in texts:
            if not isinstance(text, str) or not text.strip():
                raise UsageError("empty prompt: give a sentence describing the motion")
        prepared = []
        max_words = self.vectorizer.max_tokens
        for text, pairs in zip(texts, tag_prompts(texts, spacy_pos=self.spacy_pos)):
            words = [word for word, _ in pairs]
            unknown = tuple(dict.fromkeys(w for w in words if w not in self.training_words))
            if not words:
                raise UsageError(
                    f"no known word in prompt {text!r}: the model was trained on none of its "
                    "words (it has no words)"
                )
            dropped = tuple(words[max_words:])
            if dropped and not quiet:
                logger.warning(
                    "prompt %r is longer than %d words; ignoring: %s",
                    text,
                    max_words,
                    " ".join(dropped),
                )
            # quiet: the readings are collected instead of logged
            readings = {} if quiet else None
            pairs = read_prompt(
                text, pairs, self.training_words, self.vectorizer, readings=readings
            )
            unread = tuple(dict.fromkeys(w for w, _ in pairs if w not in self.training_words))
            if len(unread) == len({w for w, _ in pairs}):  # nothing trained, even as read
                raise UsageError(
                    f"no known word in prompt {text!r}: the model was trained on none of its "
                    f"words, nor on any reading of them (unknown: {', '.join(unknown)})"
                )
            if unread and not quiet:
                logger.warning(
                    "prompt %r has words the model was not trained on: %s",
                    text,
                    ", ".join(unread),
                )
            tokens = [f"{word}/{pos}" for word, pos in pairs]
            prepared.append(
                PreparedText(
                    text,
                    self.vectorizer.encode_tokens(tokens),
                    unknown,
                    dropped,
                    self.encode_clauses(tokens),
                )
            )
        return prepared

    def encode_clauses(self, tokens: Sequence[str]) -> tuple[EncodedText, ...]:
        """``word/POS`` tokens -> their clauses encoded as standalone captions
        (:func:`t2m.clauses.clause_captions`), or () for a caption of one clause."""
        clauses = clause_captions(tokens)
        if len(clauses) < 2:
            return ()
        return tuple(self.vectorizer.encode_tokens(c) for c in clauses)

    def clause_snippets(
        self, clauses: Sequence[Sequence[EncodedText]], frames: Sequence[int]
    ) -> list[list[int]]:
        """Each item's snippets (``frames // snippet_length``) shared among its clauses: each
        clause gets the length the text2length model expects for it as a clause (its mean) plus a
        share of the difference to the item's length in proportion to that length's variance
        (:func:`t2m.clauses.clause_targets`; equal shares without a length model), a clause that
        names a count exactly the snippets its count needs while a clause without one can take
        up the difference, at least 1 s each where there is room
        (:func:`t2m.clauses.share_snippets`). An item with fewer snippets than clauses gets one
        clause: ``[total]``."""
        unit = self.spec.snippet_length
        flat = [c for item in clauses if len(item) > 1 for c in item]  # one clause: no sharing
        means, variances = np.ones(len(flat)), np.ones(len(flat))
        if self.length_model is not None and flat:
            means, variances = self.length_moments(flat, clause=True)
        out, start = [], 0
        for item, total_frames in zip(clauses, frames, strict=True):
            total = total_frames // unit
            if len(item) < 2:
                out.append([total])
                continue
            part = slice(start, start + len(item))
            start += len(item)
            if total < len(item):
                out.append([total])
                continue
            if self.length_model is None:
                out.append(share_snippets(total, means[part]))
            else:
                counted = [c.count > 0 for c in item]
                targets = clause_targets(total, means[part], variances[part], counted)
                out.append(share_snippets(total, targets))
        return out

    def length_moments(
        self, encoded: Sequence[EncodedText], clause: bool = False
    ) -> tuple[np.ndarray, np.ndarray]:
        """The text2length model's expected length of each caption and its variance, in snippets
        (float64 (N,) each; ``clause``: as clauses of longer motions). Needs the length model."""
        if self.length_model is None:
            raise ValueError("no text2length model loaded (`make train-len`)")
        if not encoded:
            return np.zeros(0), np.zeros(0)
        with torch.inference_mode():
            return _moments(self._length_logits(encoded, batch_size=256, clause=clause))

    def sample_lengths(
        self,
        prepared: Sequence[PreparedText],
        generator: torch.Generator,
        repeats: int = 1,
        batch_size: int = 256,
        by_clause: bool = True,
    ) -> list[int]:
        """Draw lengths in frames from the text2length model: ``repeats`` draws per prompt,
        prompt-major (the model runs once per prompt, in batches of ``batch_size``).

        With ``by_clause`` (the clause plan) and a length model that reads clauses
        (``LengthModelConfig.plan_inputs``), a prompt of several clauses draws each clause's
        length as a clause, with its count, and takes their sum (at least the dataset's
        shortest motion): "throws one punch, then claps five times" gets the five claps' time,
        which a whole caption's count-blind draw does not. Prompts of one clause, and every
        prompt otherwise, draw the whole caption's length (the paper's), first and in order.

        With ``by_clause``, a clause (or a prompt of one clause) that names a count takes the
        length the model expects for it (:func:`t2m.clauses.needed_snippets` of its mean)
        instead of a draw: the temporal VAE repeats an action at its trained pace, so a draw a
        deviation off the mean adds or drops a repetition (measured on the demo model, typed
        prompts of the paraphrase split: counted items right 0.76 with draws, 0.82 with the
        mean alone, 0.88 with the mean and the clause plan's exact share; 3 seeds of 300). The draws are still
        made, so prompts without a count get the lengths they got before."""
        if self.length_model is None:
            raise ValueError(
                "no text2length model loaded: give lengths (--length / --seconds) "
                "or load the `length` stage (`make train-len`)"
            )
        unit = self.spec.snippet_length
        min_units, max_units = self.spec.min_frames // unit, self.spec.max_snippets
        at_mean = by_clause  # the clause plan: counted lengths at the mean (see above)
        by_clause = by_clause and self.length_model.config.plan_inputs
        split = [by_clause and len(item.clauses) > 1 for item in prepared]
        # Both models share one vocabulary (checked on construction), so one encoding serves.
        whole = [item.encoded for item, parts in zip(prepared, split) if not parts]
        units = torch.zeros(len(prepared), repeats, dtype=torch.long)
        with torch.inference_mode():
            if whole:
                logits = self._length_logits(whole, batch_size)
                per_draw = logits.repeat_interleave(repeats, dim=0)
                drawn = sample_lengths(per_draw, generator, min_units=min_units).view(-1, repeats)
                if at_mean:
                    single = [item for item, parts in zip(prepared, split) if not parts]
                    counted = torch.tensor(
                        [len(item.clauses) < 2 and item.encoded.count > 0 for item in single]
                    )
                    if counted.any():
                        need = torch.from_numpy(needed_snippets(_moments(logits[counted])[0]))
                        drawn[counted] = need.clamp(min=min_units).to(drawn)[:, None]
                units[torch.tensor([not parts for parts in split])] = drawn.cpu()
            clauses = [c for item, parts in zip(prepared, split) if parts for c in item.clauses]
            if clauses:
                logits = self._length_logits(clauses, batch_size, clause=True)
                probs = torch.softmax(logits, -1).repeat_interleave(repeats, dim=0)
                drawn = torch.multinomial(probs, 1, generator=generator).view(-1, repeats).cpu()
                counted = torch.tensor([c.count > 0 for c in clauses])
                if at_mean and counted.any():
                    need = torch.from_numpy(needed_snippets(_moments(logits[counted])[0]))
                    drawn[counted] = need.to(drawn)[:, None]
                start = 0
                for row, (item, parts) in enumerate(zip(prepared, split)):
                    if parts:
                        end = start + len(item.clauses)
                        units[row] = drawn[start:end].sum(0).clamp(min=min_units)
                        start = end
        return [int(u) * unit for u in units.clamp(max=max_units).flatten().tolist()]

    def _length_logits(
        self, encoded: Sequence[EncodedText], batch_size: int, clause: bool = False
    ) -> torch.Tensor:
        """(N, K) float32 length logits of captions (``clause``: as clauses of longer motions),
        in batches of ``batch_size``."""
        logits = []
        for start in range(0, len(encoded), batch_size):
            chunk = encoded[start : start + batch_size]
            words, pos, lengths = text_batch(chunk, self.device, torch.float32)
            counts = torch.tensor([c.count for c in chunk], device=self.device)
            logits.append(self.length_model(words, pos, lengths, counts, clause).float())
        return torch.cat(logits)

    def plan(
        self,
        texts: str | Sequence[str],
        num_samples: int = 1,
        lengths: int | Sequence[int | None] | None = None,
        generator: torch.Generator | None = None,
        *,
        batch_size: int = 32,
        by_clause: bool = True,
    ) -> GenerationBatch:
        """Steps 1-3 of :meth:`generate` before the models run: the prompts' words, every
        motion's length (given, or drawn from ``generator``) and the latent draws of each batch,
        drawn in that order. Arguments as :meth:`generate`'s (``generator``: default seed 0;
        ``by_clause``: draw a prompt's length clause by clause, :meth:`sample_lengths`)."""
        return self.plan_prepared(
            self.prepare(texts),
            num_samples,
            lengths,
            generator,
            batch_size=batch_size,
            by_clause=by_clause,
        )

    def plan_prepared(
        self,
        prepared: Sequence[PreparedText],
        num_samples: int = 1,
        lengths: int | Sequence[int | None] | None = None,
        generator: torch.Generator | None = None,
        *,
        batch_size: int = 32,
        by_clause: bool = True,
        length_batch: int | None = None,
    ) -> GenerationBatch:
        """:meth:`plan` of prompts already prepared (the evaluation's captions, encoded from
        their dataset tokens). ``length_batch``: draw the lengths of this many prompts at a
        time (the evaluation protocol's order of draws); None: all at once."""
        prepared = list(prepared)
        if generator is None:
            generator = torch.Generator(self.device).manual_seed(0)
        # 2. lengths, one per motion (prompt-major)
        if lengths is None or isinstance(lengths, (int, np.integer)):
            per_prompt: list[int | None] = [lengths] * len(prepared)  # type: ignore[list-item]
        else:
            per_prompt = list(lengths)
            if len(per_prompt) != len(prepared):
                raise ValueError(f"{len(per_prompt)} lengths for {len(prepared)} prompts")
        fixed = [None if n is None else self._clamp(n) for n in per_prompt]
        items = [(p, r) for p in range(len(prepared)) for r in range(num_samples)]
        frames = {item: fixed[item[0]] for item in items}
        unsized = [prepared[p] for p in range(len(prepared)) if fixed[p] is None]
        step = length_batch or max(len(unsized), 1)
        drawn = iter(
            length
            for start in range(0, len(unsized), step)
            for length in self.sample_lengths(
                unsized[start : start + step],
                generator,
                repeats=num_samples,
                batch_size=batch_size,
                by_clause=by_clause,
            )
        )
        for item in items:
            if frames[item] is None:
                frames[item] = next(drawn)
        # 3. the motions longest first (stable: ties keep prompt-major order), then the latent
        # draws of each batch of them
        order = sorted(items, key=lambda item: -frames[item])
        ordered = [frames[item] for item in order]
        unit, latent = self.spec.snippet_length, self.vae.config.latent_size
        noise = [
            torch.randn(
                len(chunk),
                max(chunk) // unit,
                latent,
                generator=generator,
                device=self.device,
                dtype=self.dtype,
            )
            for chunk in (ordered[s : s + batch_size] for s in range(0, len(ordered), batch_size))
        ]
        given = [fixed[p] is not None for p, _ in order]
        return GenerationBatch(prepared, order, ordered, noise, batch_size, given)

    @torch.inference_mode()
    def generate_features(
        self,
        encoded: Sequence[EncodedText],
        frames: Sequence[int],
        generator: torch.Generator,
        noise: torch.Tensor | None = None,
        clauses: Sequence[Sequence[EncodedText]] | None = None,
        settle: bool | Sequence[bool] = False,
    ) -> list[np.ndarray]:
        """One batch: normalised-space generation -> de-normalised features (frames_i, D) each.

        ``noise``: the latent draws (B, max snippets, Z) (default: drawn from ``generator``);
        given by a caller that batches requests of different seeds (``t2m.serve``).
        ``clauses``: per item, its clauses as standalone captions (:meth:`encode_clauses`; ()
        for a caption of one clause): the clause plan (:meth:`clause_plan`), in which an item of
        two or more clauses, or with ``settle`` a counted clause given more time than it needs,
        is generated part by part (:func:`t2m.inference.generation.clause_codes`), the others
        in one pass; None: every item in one pass (the paper's plan). ``settle``: for every
        item, or per item (the lengths the user fixed, :attr:`GenerationBatch.fixed`)."""
        unit = self.spec.snippet_length
        num_snippets = torch.tensor([f // unit for f in frames], dtype=torch.long)
        if clauses is not None and len(clauses) != len(encoded):
            raise ValueError(f"{len(clauses)} clause lists for {len(encoded)} captions")
        lists, snippets = (
            ([], [])
            if clauses is None
            else self.clause_plan(encoded, clauses, frames, settle=settle)
        )
        if any(len(parts) > 1 for parts in lists):
            codes = clause_codes(
                self.vae,
                lists,
                snippets,
                self.initial_code,
                generator,
                noise,
                self.device,
                self.dtype,
            )
        else:
            words, pos, text_lengths = text_batch(encoded, self.device, self.dtype)
            word_features, sentence, mask = self.vae.encode_text(words, pos, text_lengths)
            codes = self.vae.generate(
                word_features,
                sentence,
                mask,
                num_snippets.to(self.device),
                self.initial_code,
                generator,
                noise=noise,
                counts=torch.tensor([e.count for e in encoded], device=self.device),
            )
        return decode_features(
            self.decoder, self.normalizer, codes, num_snippets, frames, self.decoder_dtype
        )

    def clause_plan(
        self,
        encoded: Sequence[EncodedText],
        clauses: Sequence[Sequence[EncodedText]],
        frames: Sequence[int],
        settle: bool | Sequence[bool] = True,
    ) -> tuple[list[list[EncodedText]], list[list[int]]]:
        """The clause plan of a batch: per item, the captions of its parts in order and their
        snippets (summing to ``frames // snippet_length``). An item's clauses (``clauses[i]``,
        standalone captions; () or one for a caption of one clause: ``encoded[i]``) share its
        snippets by :meth:`clause_snippets` (an item with fewer snippets than clauses runs as
        one). With ``settle`` (for all items, or per item; and a length model), a clause that
        names a count and was given more time than it needs keeps what it needs and is followed
        by a part of :data:`t2m.clauses.SETTLE_TEXT` (:meth:`settle_plan`)."""
        lists = [list(c) if len(c) > 1 else [e] for c, e in zip(clauses, encoded, strict=True)]
        snippets = self.clause_snippets(lists, frames)
        lists = [c if len(n) == len(c) else [e] for c, n, e in zip(lists, snippets, encoded)]
        flags = [settle] * len(lists) if isinstance(settle, bool) else list(settle)
        if len(flags) != len(lists):
            raise ValueError(f"{len(flags)} settle flags for {len(lists)} items")
        chosen = [b for b, flag in enumerate(flags) if flag]
        if chosen:
            settled = self.settle_plan([lists[b] for b in chosen], [snippets[b] for b in chosen])
            for b, parts, shares in zip(chosen, *settled):
                lists[b], snippets[b] = parts, shares
        return lists, snippets

    def settle_plan(
        self, lists: Sequence[Sequence[EncodedText]], snippets: Sequence[Sequence[int]]
    ) -> tuple[list[list[EncodedText]], list[list[int]]]:
        """Counts follow the text at any length: each item's parts (captions ``lists[i]`` with
        ``snippets[i]`` snippets) with every counted part given more than it needs cut to what
        it needs, the surplus a settling part after it (at least
        :data:`t2m.clauses.MIN_SETTLE_SNIPPETS`) or given to a neighbouring part without a
        count (:func:`t2m.clauses.settle_counted`). What a part needs is
        :func:`t2m.clauses.needed_snippets` of the text2length model's estimate: as a clause for
        an item of several parts, as a whole caption for an item of one (the estimate its own
        length comes from, so a length at it is left as it is). Unchanged without a length
        model or when the model was not trained on the settling caption's words."""
        lists = [list(parts) for parts in lists]
        snippets = [list(n) for n in snippets]
        filler = self._settle_caption()
        counted = [(b, k) for b, parts in enumerate(lists) for k, c in enumerate(parts) if c.count]
        if filler is None or self.length_model is None or not counted:
            return lists, snippets
        needs: dict[tuple[int, int], int] = {}
        for clause in (False, True):
            keys = [(b, k) for b, k in counted if (len(lists[b]) > 1) == clause]
            means, _ = self.length_moments([lists[b][k] for b, k in keys], clause)
            needs.update(zip(keys, needed_snippets(means).tolist()))
        for b, parts in enumerate(lists):
            plan = settle_counted(
                [c.count for c in parts],
                snippets[b],
                [needs.get((b, k), 0) for k in range(len(parts))],
            )
            lists[b] = [filler if k < 0 else parts[k] for k, _ in plan]
            snippets[b] = [n for _, n in plan]
        return lists, snippets

    def count_parts(self, text: str | PreparedText, frames: int) -> list[tuple[str, int]]:
        """One prompt's length as the plans that generate a prompt in one pass (edits, compose,
        the live stream) should make it, so that its counts follow the text: ``[(text,
        frames)]``, or, for a prompt that names a count ("jumps twice"; "jumps twice, then
        waves") given at least :data:`t2m.clauses.MIN_SETTLE_SNIPPETS` snippets more than it
        needs, ``[(text, needed frames), (SETTLE_TEXT, the rest)]``. What a prompt of one
        clause needs is its count's time (:meth:`count_frames`, the clause plan's decision,
        :meth:`settle_plan`); a prompt of several, the sum of its clauses' expected lengths (in
        one pass its clauses cannot settle each on its own). ``frames`` is cut to whole
        snippets, the remainder left with the last part."""
        prepared = self.prepare([text])[0] if isinstance(text, str) else text
        unit = self.spec.snippet_length
        whole = [(prepared.text, frames)]
        if self.length_model is None or self._settle_caption() is None:
            return whole
        if prepared.clauses:
            if not any(c.count for c in prepared.clauses):
                return whole
            means, _ = self.length_moments(list(prepared.clauses), clause=True)
            need = int(needed_snippets(means).sum()) * unit
        else:
            need = self.count_frames([prepared])[0]
        if not need or frames // unit - need // unit < MIN_SETTLE_SNIPPETS:
            return whole
        return [(prepared.text, need), (SETTLE_TEXT, frames - need)]

    def count_frames(self, prepared: Sequence[PreparedText]) -> list[int]:
        """The frames each prompt's count needs (:func:`t2m.clauses.needed_snippets` of the
        text2length model's estimate): 0 for a prompt without a count, of several clauses, or
        without a length model."""
        counted = [i for i, p in enumerate(prepared) if p.encoded.count and not p.clauses]
        out = [0] * len(prepared)
        if self.length_model is None or not counted:
            return out
        means, _ = self.length_moments([prepared[i].encoded for i in counted])
        for i, need in zip(counted, needed_snippets(means).tolist()):
            out[i] = int(need) * self.spec.snippet_length
        return out

    def warn_short_counts(self, prepared: Sequence[PreparedText], frames: Sequence[int]) -> None:
        """Warn (once per prompt) where a length the user fixed is under
        :data:`SHORT_COUNT_SHARE` of what the prompt's count needs: there the model makes fewer
        repetitions than asked (demo model, at 0.75 of the need: 0.29 right, against 0.95)."""
        needs = self.count_frames(prepared)
        for item, given, need in zip(prepared, frames, needs, strict=True):
            if need and given < SHORT_COUNT_SHARE * need:
                logger.warning(
                    "prompt %r names a count that needs about %.1f s; at %.1f s it may be done "
                    "fewer times",
                    item.text,
                    need / self.spec.fps,
                    given / self.spec.fps,
                )

    def _settle_caption(self) -> EncodedText | None:
        """:data:`t2m.clauses.SETTLE_TOKENS` encoded, or None when the model was not trained on
        its words (then nothing settles)."""
        if not hasattr(self, "_settle_encoded"):
            words = [token.rpartition("/")[0] for token in SETTLE_TOKENS]
            known = all(w in self.training_words for w in words)
            self._settle_encoded = self.vectorizer.encode_tokens(SETTLE_TOKENS) if known else None
        return self._settle_encoded

    def generate(
        self,
        texts: str | Sequence[str],
        num_samples: int = 1,
        lengths: int | Sequence[int | None] | None = None,
        seed: int = 0,
        batch_size: int = 32,
        progress: bool = False,
        clean: bool = True,
        plan: str = "clauses",
        settle: bool = True,
    ) -> list[list[GeneratedMotion]]:
        """Generate ``num_samples`` motions per prompt.

        Args:
            texts: one prompt or a list of prompts.
            num_samples: different motions per prompt.
            lengths: frames for every prompt (int), per prompt (None entries are sampled), or
                None to sample every length from the text2length model (one draw per motion).
            seed: seeds the one generator all draws come from.
            batch_size: motions generated together.
            progress: show a progress bar.
            clean: foot-contact clean-up (:mod:`dataset_tools.cleanup`: planted feet
                held still and on the floor, legs fixed by IK); False gives the model's output
                made rigid only (:meth:`finish`).
            plan: ``"clauses"``: a prompt of several clauses is generated clause by clause
                (:meth:`generate_features`); ``"whole"``: every prompt in one pass (the paper).
            settle: with the clause plan and a length given in ``lengths``, a clause that names
                a count ("jumps twice") and is given more time than it needs does its count in
                the time it needs and stands still for the rest (:meth:`settle_plan`); False:
                the count is spread over the whole length (the model then repeats at its own
                pace: more repetitions). Drawn lengths are the model's own and never settle.

        Returns:
            ``motions[prompt][sample]``.
        """
        from tqdm import tqdm

        texts = [texts] if isinstance(texts, str) else list(texts)
        if num_samples < 1:
            raise ValueError(f"num_samples must be >= 1, got {num_samples}")
        if batch_size < 1:
            raise ValueError(f"batch_size must be >= 1, got {batch_size}")
        if plan not in PLANS:
            raise ValueError(f"unknown plan {plan!r}; use one of {', '.join(PLANS)}")
        # 1.-3. words, lengths and latent draws
        generator = torch.Generator(self.device).manual_seed(seed)
        planned = self.plan(
            texts,
            num_samples,
            lengths,
            generator,
            batch_size=batch_size,
            by_clause=plan == "clauses",
        )
        prepared = planned.prepared
        if settle and plan == "clauses":
            given = {
                p: frames
                for (p, _), frames, fixed in zip(planned.items, planned.frames, planned.fixed)
                if fixed
            }
            self.warn_short_counts([prepared[p] for p in given], list(given.values()))
        # 3.-4. the models, batch by batch
        results: dict[tuple[int, int], GeneratedMotion] = {}
        bar = tqdm(total=len(planned.items), desc="generating", unit="motion", disable=not progress)
        fixed = dict(zip(planned.items, planned.fixed, strict=True))
        for batch, frames, noise in planned.batches():
            features = self.generate_features(
                [prepared[p].encoded for p, _ in batch],
                frames,
                generator,
                noise=noise,
                clauses=[prepared[p].clauses for p, _ in batch] if plan == "clauses" else None,
                settle=[settle and fixed[item] for item in batch],
            )
            for (p, r), feats in zip(batch, features):
                joints, feats = self.finish(feats, clean)
                results[(p, r)] = GeneratedMotion(texts[p], p, r, joints, feats)
            bar.update(len(batch))
        bar.close()
        return [[results[(p, r)] for r in range(num_samples)] for p in range(len(texts))]

    def finish(self, features: np.ndarray, clean: bool = True) -> tuple[np.ndarray, np.ndarray]:
        """One generated motion's de-normalised features (T, D) -> (joints (T, J, 3), features
        (T, D)), float32: rigid on the model's skeleton (every bone at the dataset's target
        length in every frame, hips and collars one rigid piece with the pelvis and spine3:
        :func:`dataset_tools.rigid.finish_features`), then the foot-contact clean-up when
        ``clean``. What :meth:`generate` and the web app return; the BVH and glTF writers
        reproduce these joints exactly. Non-finite features (a broken checkpoint) pass through
        unfinished, so that the writers' check names the motion (:mod:`t2m.outputs`)."""
        if np.isfinite(features).all():
            features = finish_features(features, clean)
        joints = recover_from_ric(features, self.spec.num_joints)
        return joints.astype(np.float32), features

    def _clamp(self, frames: int) -> int:
        return frames_for(frames, self.spec)

    def edit(self, text: str, mode: str, source=None, **options):
        """Edit or compose motions: continue a source, fill in between, redo a body part, follow
        a path or joint targets, or chain prompts on a timeline. Delegates to
        :func:`t2m.edit.edit`, which documents the modes, options and the returned
        :class:`t2m.edit.EditedMotion` list."""
        from t2m.edit import edit

        return edit(self, text, mode, source, **options)

    def stream(self, text: str, seed: int = 0, **options):
        """Live generation: a :class:`t2m.live.LiveStream` that yields snippets from a running
        state without end and takes new prompts (``stream.prompt(text)``) at snippet
        boundaries. Delegates to :class:`t2m.live.LiveStream`, which documents the options."""
        from t2m.live import LiveStream

        return LiveStream(self, text, seed, **options)
