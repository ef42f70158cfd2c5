"""Temporal VAE (Guo et al., CVPR 2022): text -> a sequence of snippet codes, one step per
4 frames.

Three recurrent blocks share one shape: input Linear -> LayerNorm -> LeakyReLU, plus a sinusoidal
encoding of the time to arrival (snippets left before the end), into a GRU cell whose initial
state is a Linear of the sentence feature. Options beyond the paper put two more signals in that
time code (:meth:`TemporalVAE.time_codes`): the progress (``config.progress_frequencies``) and a
count clock that turns once per repetition a clause names (``config.count_clock``).

* prior      input [previous code, attention]               -> mean, log-variance of z
* posterior  input [previous code, current code, attention] -> mean, log-variance of z
* generator  input [previous code, attention, z]            -> next code (through ``output``)

Attention: query = Linear(generator state), keys / values = Linears of the word features, dot
product scaled by 1/sqrt(attention size) as in the original, padding masked. The original does
not mask, which changes nothing where it runs (batch 1: its word features end with the caption);
masking makes a batch give what each caption gives alone. The code before step 1 is
the autoencoder's code of the mean pose (zero normalised features), passed in by the caller.

:meth:`TemporalVAE.step` is the model: one snippet, as written above. :meth:`TemporalVAE.rollout`
runs it over a sequence: the training pass (teacher-forced or free-running, :meth:`forward`),
generation (:meth:`generate`) and reading a known prefix (:meth:`prefix_state`).

Faster implementations of the same arithmetic live in :mod:`t2m.accel`, which this module never
imports: :func:`t2m.accel.accelerate` hands a model its training pass
(:meth:`TemporalVAE.set_training_pass`) and its generation :class:`Rollout`
(:meth:`TemporalVAE.set_rollout`); a model without them runs the loops written here.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import NamedTuple, Protocol

import torch
import torch.nn.functional as F
from torch import nn

from t2m.config import TemporalVAEConfig
from t2m.models.text_encoder import TextEncoder


def sinusoidal_table(num_positions: int, size: int) -> torch.Tensor:
    """(num_positions, size) table: sin on even, cos on odd dimensions (Vaswani et al.)."""
    position = torch.arange(num_positions, dtype=torch.float32)[:, None]
    frequency = torch.exp(
        torch.arange(0, size, 2, dtype=torch.float32) * (-math.log(10000.0) / size)
    )
    table = torch.zeros(num_positions, size)
    table[:, 0::2] = torch.sin(position * frequency)
    table[:, 1::2] = torch.cos(position * frequency)[:, : size // 2]
    return table


class RecurrentState(NamedTuple):
    """What one step hands the next: the GRU states (B, H) and the code fed next (B, C).

    ``posterior`` is None where the posterior does not run (generation)."""

    prior: torch.Tensor
    generator: torch.Tensor
    previous_code: torch.Tensor
    posterior: torch.Tensor | None = None


class StepOutput(NamedTuple):
    """One step's predicted code (B, C), the statistics of z (B, Z), the posterior's None where
    it does not run, and the attention weights over the words (B, L), zero on padding. Stacked
    over steps by :meth:`TemporalVAE.rollout`: (B, S, .)."""

    code: torch.Tensor
    prior_mean: torch.Tensor
    prior_logvar: torch.Tensor
    posterior_mean: torch.Tensor | None = None
    posterior_logvar: torch.Tensor | None = None
    attention_weights: torch.Tensor | None = None


class WordContext(NamedTuple):
    """Attention keys and values (B, L, A), computed once per sequence, and the additive mask
    (B, L): 0 on words, -inf on padding."""

    keys: torch.Tensor
    values: torch.Tensor
    mask_bias: torch.Tensor


class Rollout(Protocol):
    """What :meth:`TemporalVAE.generate` runs: :meth:`TemporalVAE.step` from the prior over S
    snippets, as :class:`StepRollout` runs it, by any means (a generation backend).

    Called with the state to start from, the :class:`WordContext`, the time codes (B, S, H), the
    latent draws (B, S, Z) and optionally ``lengths`` (B,): each item's state stops changing
    after its last step. Returns the state after the last step (``posterior`` None) and the
    codes (B, S, C).

    ``tolerance``: the largest difference from :class:`StepRollout`'s codes on the float32
    model the backend promises, as a share of the largest code (0: the same arithmetic in the
    same order); ``tests/test_rollouts.py`` holds every backend to it.
    """

    tolerance: float

    def __call__(
        self,
        state: RecurrentState,
        context: WordContext,
        time_codes: torch.Tensor,
        noise: torch.Tensor,
        lengths: torch.Tensor | None = None,
    ) -> tuple[RecurrentState, torch.Tensor]: ...


class StepRollout:
    """The plain :class:`Rollout`: :meth:`TemporalVAE.rollout` from the prior, step by step
    (what :meth:`TemporalVAE.generate` runs when no other rollout is set)."""

    tolerance = 0.0

    def __init__(self, vae: TemporalVAE):
        self.vae = vae

    def __call__(
        self,
        state: RecurrentState,
        context: WordContext,
        time_codes: torch.Tensor,
        noise: torch.Tensor,
        lengths: torch.Tensor | None = None,
    ) -> tuple[RecurrentState, torch.Tensor]:
        final, outputs = self.vae.rollout(state, context, time_codes, noise, lengths=lengths)
        return final, outputs.code


TrainingPass = Callable[..., dict[str, torch.Tensor]]
"""A replacement for :meth:`TemporalVAE.forward`'s loop: called with the model, word features,
sentence, word mask, target codes, initial code, teacher forcing, noise and time codes (the
arguments of :meth:`~TemporalVAE.forward` after its defaults are filled in), it returns what
:meth:`~TemporalVAE.forward` returns."""


class RecurrentBlock(nn.Module):
    """Linear -> LayerNorm -> LeakyReLU (+ time encoding) -> GRUCell; initial state from the sentence."""

    def __init__(self, input_size: int, hidden_size: int, sentence_size: int):
        super().__init__()
        self.input = nn.Linear(input_size, hidden_size)
        self.norm = nn.LayerNorm(hidden_size)
        self.cell = nn.GRUCell(hidden_size, hidden_size)
        self.initial = nn.Linear(sentence_size, hidden_size)

    def forward(
        self, inputs: torch.Tensor, time_code: torch.Tensor, hidden: torch.Tensor
    ) -> torch.Tensor:
        """inputs (B, I), time code (B, H), hidden (B, H) -> next hidden (B, H)."""
        return self.cell(F.leaky_relu(self.norm(self.input(inputs)), 0.2) + time_code, hidden)


class Gaussian(nn.Module):
    """Hidden state -> (mean, log-variance) of z."""

    def __init__(self, hidden_size: int, latent_size: int):
        super().__init__()
        self.mean = nn.Linear(hidden_size, latent_size)
        self.logvar = nn.Linear(hidden_size, latent_size)

    def forward(self, hidden: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        return self.mean(hidden), self.logvar(hidden)


class TemporalVAE(nn.Module):
    """Text encoder + prior / posterior / generator with word attention.

    Args:
        word_dim: word-vector size; code_size: the autoencoder's code size.
        config: sizes; vocab_size > 0 for a trainable word embedding.
    """

    def __init__(
        self, word_dim: int, code_size: int, config: TemporalVAEConfig, vocab_size: int = 0
    ):
        super().__init__()
        self.config = config
        self.code_size = code_size
        self.text_encoder = TextEncoder(word_dim, config.text, vocab_size)
        text_size = self.text_encoder.output_size
        hidden, latent, attention = config.hidden_size, config.latent_size, config.attention_size
        self.query = nn.Linear(hidden, attention)
        self.key = nn.Linear(text_size, attention, bias=False)
        self.value = nn.Linear(text_size, attention)
        self.prior = RecurrentBlock(code_size + attention, hidden, text_size)
        self.posterior = RecurrentBlock(2 * code_size + attention, hidden, text_size)
        self.generator = RecurrentBlock(code_size + attention + latent, hidden, text_size)
        self.prior_gaussian = Gaussian(hidden, latent)
        self.posterior_gaussian = Gaussian(hidden, latent)
        self.output = nn.Sequential(
            nn.Linear(hidden, hidden),
            nn.LayerNorm(hidden),
            nn.LeakyReLU(0.2),
            nn.Linear(hidden, code_size),
        )
        self.register_buffer(
            "time_table", sinusoidal_table(config.max_snippets, hidden), persistent=False
        )
        # set by t2m.accel.accelerate; None: the loops of this file
        self.training_pass: TrainingPass | None = None
        self.generation_rollout: Rollout | None = None

    def set_training_pass(self, training_pass: TrainingPass | None) -> None:
        """Run :meth:`forward`'s loop with ``training_pass`` (None: :meth:`rollout`)."""
        self.__dict__["training_pass"] = training_pass

    def set_rollout(self, rollout: Rollout | None) -> None:
        """Generate with ``rollout`` (None: :class:`StepRollout`). Held as a plain attribute,
        not a submodule: the state dict stays the model's own."""
        self.__dict__["generation_rollout"] = rollout

    # -- per sequence ------------------------------------------------------------------------

    def encode_text(
        self, words: torch.Tensor, pos: torch.Tensor, text_lengths: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """-> word features (B, L, 2Ht), sentence feature (B, 2Ht), word mask (B, L) bool."""
        word_features, sentence = self.text_encoder(words, pos, text_lengths)
        positions = torch.arange(word_features.shape[1], device=word_features.device)
        mask = positions[None, :] < text_lengths.to(word_features.device)[:, None]
        return word_features, sentence, mask

    def word_context(self, word_features: torch.Tensor, word_mask: torch.Tensor) -> WordContext:
        """Keys, values and padding mask of the words, from :meth:`encode_text`'s outputs."""
        keys = self.key(word_features)  # (B, L, A)
        values = self.value(word_features)
        bias = torch.zeros(word_mask.shape, dtype=keys.dtype, device=keys.device)
        return WordContext(keys, values, bias.masked_fill(~word_mask, float("-inf")))

    def initial_state(
        self, sentence: torch.Tensor, initial_code: torch.Tensor, posterior: bool = False
    ) -> RecurrentState:
        """The state before step 1: GRU states from the sentence (B, 2Ht), ``initial_code`` (C,)
        or (B, C) as the previous code; the posterior's too if ``posterior``."""
        return RecurrentState(
            prior=self.prior.initial(sentence),
            generator=self.generator.initial(sentence),
            previous_code=initial_code.expand(sentence.shape[0], self.code_size),
            posterior=self.posterior.initial(sentence) if posterior else None,
        )

    def time_codes(
        self,
        snippets_left: torch.Tensor,
        steps: int,
        motion_snippets: torch.Tensor | None = None,
        counts: torch.Tensor | None = None,
        done: torch.Tensor | None = None,
        clause_snippets: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """(B, steps, H) encodings of the time to arrival, ``snippets_left - i`` at step i; with
        ``config.progress_frequencies`` K > 0 the last 2K dimensions hold the progress instead:
        sin and cos of 2 pi k f (k = 1..K), f the share of the motion done before the step; with
        ``config.count_clock`` the two before them hold sin and cos of 2 pi N g, N = ``counts``
        (B,) the repetitions each caption names, or (B, steps) each step's clause names (0, or
        ``counts`` None: both zero), g the share of its turns the clock has made
        (:meth:`_clock_share`: f, or f with a wind-up and wind-down).
        ``motion_snippets`` (B,): the whole motion's snippets (default ``snippets_left``: the
        call starts the motion); ``done`` (B, steps): f itself, where the steps are not the end
        of their motion (a training crop), else from ``motion_snippets``; with it,
        ``clause_snippets`` (B, steps): the length of each step's motion (or clause), for the
        clock's margins (``config.count_clock_margin``)."""
        left = snippets_left[:, None] - torch.arange(steps, device=snippets_left.device)[None, :]
        codes = self.time_table[left.clamp(0, self.config.max_snippets - 1)]
        k, clock = self.config.progress_frequencies, int(self.config.count_clock)
        if not k and not clock:
            return codes
        if done is None:
            total = snippets_left if motion_snippets is None else motion_snippets
            whole = total.to(codes.device, codes.dtype)[:, None].clamp(min=1)
            done = (whole - left.to(codes.dtype)) / whole  # (B, S)
        else:
            whole = (
                None if clause_snippets is None else clause_snippets.to(codes.device, codes.dtype)
            )
        done = done.to(codes.device, codes.dtype)
        parts = [codes[..., : codes.shape[-1] - 2 * (k + clock)]]
        if clock:
            if counts is None:
                parts.append(codes.new_zeros(*done.shape, 2))
            else:
                turns = counts.to(codes.device, codes.dtype)
                turns = turns[:, None] if turns.dim() == 1 else turns  # (B, 1) or (B, S)
                angle = (2 * math.pi) * turns * self._clock_share(done, whole)
                on = (turns > 0).to(codes.dtype)
                parts.append(torch.stack([angle.sin() * on, angle.cos() * on], dim=-1))
        if k:
            frequencies = torch.arange(1, k + 1, device=codes.device, dtype=codes.dtype)
            angle = (2 * math.pi) * done[..., None] * frequencies  # (B, S, K)
            parts += [angle.sin(), angle.cos()]
        return torch.cat(parts, dim=-1)

    def _clock_share(self, done: torch.Tensor, whole: torch.Tensor | None) -> torch.Tensor:
        """The share of its turns the count clock has made at each step: ``done``, or with
        ``config.count_clock_margin`` M, (position - M) / (length - 2M) clamped to [0, 1], so
        that it turns between a wind-up and a wind-down of M snippets (a clause of 2M + 1
        snippets or fewer, or ``whole`` None: ``done``)."""
        margin = self.config.count_clock_margin
        if not margin or whole is None:
            return done
        position = done * whole
        inner = (whole - 2 * margin).clamp(min=1)
        share = ((position - margin) / inner).clamp(0, 1)
        return torch.where(whole > 2 * margin + 1, share, done)

    def release_posterior(self) -> None:
        """Free the posterior (its block and Gaussian) of a model that will only sample: the
        posterior runs in training (:meth:`forward`) and in :meth:`prefix_state` with
        ``posterior=True``, which refuse afterwards (ValueError). At paper size it is 9.2M of
        the 32M weights."""
        self.posterior = None
        self.posterior_gaussian = None

    def _check_posterior(self) -> None:
        if self.posterior is None:
            raise ValueError(
                "this temporal VAE's posterior was released (a generation-only model): "
                "it can sample from the prior, not train or read a known prefix"
            )

    # -- one step ----------------------------------------------------------------------------

    def attend(
        self, hidden: torch.Tensor, context: WordContext
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Generator state (B, H) -> (attention vector (B, A), weights over the words (B, L))."""
        query = self.query(hidden)[..., None]  # (B, A, 1)
        # mask + keys . query / sqrt(A) as one batched product (einsum cost more per step)
        scores = torch.baddbmm(
            context.mask_bias[..., None], context.keys, query, alpha=query.shape[1] ** -0.5
        )  # (B, L, 1)
        weights = torch.softmax(scores[..., 0], dim=-1)
        return torch.bmm(weights[:, None], context.values)[:, 0], weights

    def step(
        self,
        state: RecurrentState,
        context: WordContext,
        time_code: torch.Tensor,
        noise: torch.Tensor,
        target: torch.Tensor | None = None,
    ) -> tuple[RecurrentState, StepOutput]:
        """One snippet: the paper's recurrence.

        Args:
            state: the previous step's (or :meth:`initial_state`).
            context: :meth:`word_context`; time_code (B, H): this step's row of :meth:`time_codes`.
            noise: (B, Z) standard normal; z = mean + exp(logvar / 2) * noise.
            target: (B, C) this snippet's true code: the posterior runs (``state.posterior``
                must be set) and z is drawn from it (training); None: z from the prior.

        Returns: the next state, whose previous code is this step's predicted code (a caller
        feeding something else replaces it), and this step's outputs.
        """
        previous = state.previous_code
        attention, weights = self.attend(state.generator, context)
        prior = self.prior(torch.cat([previous, attention], -1), time_code, state.prior)
        prior_mean, prior_logvar = self.prior_gaussian(prior)
        posterior = posterior_mean = posterior_logvar = None
        mean, logvar = prior_mean, prior_logvar
        if target is not None:
            posterior_input = torch.cat([previous, target, attention], -1)
            posterior = self.posterior(posterior_input, time_code, state.posterior)
            mean, logvar = posterior_mean, posterior_logvar = self.posterior_gaussian(posterior)
        z = mean + torch.exp(0.5 * logvar) * noise
        generator = self.generator(
            torch.cat([previous, attention, z], -1), time_code, state.generator
        )
        code = self.output(generator)
        return (
            RecurrentState(prior, generator, code, posterior),
            StepOutput(code, prior_mean, prior_logvar, posterior_mean, posterior_logvar, weights),
        )

    def rollout(
        self,
        state: RecurrentState,
        context: WordContext,
        time_codes: torch.Tensor,
        noise: torch.Tensor,
        targets: torch.Tensor | None = None,
        feed: torch.Tensor | None = None,
        detach_feedback: bool = False,
        lengths: torch.Tensor | None = None,
    ) -> tuple[RecurrentState, StepOutput]:
        """:meth:`step` over S snippets.

        Args:
            state, context: as for :meth:`step`; time_codes (B, S, H), noise (B, S, Z).
            targets: (B, S, C) true codes for the posterior (None: z from the prior).
            feed: (B, S, C) codes fed as the previous code of the next step (teacher forcing);
                None: the model's own predictions, detached if ``detach_feedback``.
            lengths: (B,) steps per item; an item's state stops changing after its last step
                (so the returned state is each item's own final state). None: all S.

        Returns: the state after the last step and the step outputs stacked to (B, S, .).
        """
        outputs = []
        for i in range(time_codes.shape[1]):
            target = None if targets is None else targets[:, i]
            new, output = self.step(state, context, time_codes[:, i], noise[:, i], target)
            if feed is not None:
                new = new._replace(previous_code=feed[:, i])
            elif detach_feedback:
                new = new._replace(previous_code=output.code.detach())
            if lengths is not None:
                active = (i < lengths)[:, None]
                kept = (
                    None if n is None else torch.where(active, n, o) for n, o in zip(new, state)
                )
                new = RecurrentState(*kept)
            state = new
            outputs.append(output)
        stacked = (None if o[0] is None else torch.stack(o, dim=1) for o in zip(*outputs))
        return state, StepOutput(*stacked)

    # -- training ----------------------------------------------------------------------------

    def forward(
        self,
        word_features: torch.Tensor,
        sentence: torch.Tensor,
        word_mask: torch.Tensor,
        codes: torch.Tensor,
        initial_code: torch.Tensor,
        teacher_forcing: bool,
        noise: torch.Tensor | None = None,
        counts: torch.Tensor | None = None,
        done: torch.Tensor | None = None,
        clause_snippets: torch.Tensor | None = None,
    ) -> dict[str, torch.Tensor]:
        """Teacher-forced or free-running pass over target codes (z from the posterior).

        Args:
            word_features (B, L, 2Ht), sentence (B, 2Ht), word_mask (B, L): from :meth:`encode_text`.
            codes: (B, S, C) target codes (from the frozen encoder); the motion ends after them.
            initial_code: (C,) or (B, C), the mean-pose code fed before step 1.
            teacher_forcing: feed the target previous code (else the model's own, detached).
            noise: (B, S, Z) standard normal draws; drawn from the global generator if None.
            counts, done, clause_snippets: the repetitions named (B,) or (B, S), the share of
                each step's motion (or clause) done (B, S) and its length (B, S), for
                :meth:`time_codes`; None: no counts, the codes end their motion.

        Returns: ``codes`` (B, S, C) predicted; ``posterior_mean``, ``posterior_logvar``,
        ``prior_mean``, ``prior_logvar`` (B, S, Z).
        """
        self._check_posterior()
        batch, steps, _ = codes.shape
        if noise is None:
            noise = torch.randn(
                batch, steps, self.config.latent_size, device=codes.device, dtype=codes.dtype
            )
        snippets_left = torch.full((batch,), steps, dtype=torch.long, device=codes.device)
        time_codes = self.time_codes(
            snippets_left, steps, counts=counts, done=done, clause_snippets=clause_snippets
        )
        if self.training_pass is not None:  # the same loop, faster (t2m.accel)
            return self.training_pass(
                self,
                word_features,
                sentence,
                word_mask,
                codes,
                initial_code,
                teacher_forcing,
                noise,
                time_codes,
            )
        _, outputs = self.rollout(
            self.initial_state(sentence, initial_code, posterior=True),
            self.word_context(word_features, word_mask),
            time_codes,
            noise,
            targets=codes,
            feed=codes if teacher_forcing else None,
            detach_feedback=not teacher_forcing,
        )
        return {
            "codes": outputs.code,
            "prior_mean": outputs.prior_mean,
            "prior_logvar": outputs.prior_logvar,
            "posterior_mean": outputs.posterior_mean,
            "posterior_logvar": outputs.posterior_logvar,
        }

    # -- generation --------------------------------------------------------------------------

    @torch.no_grad()
    def generate(
        self,
        word_features: torch.Tensor,
        sentence: torch.Tensor,
        word_mask: torch.Tensor,
        num_snippets: torch.Tensor,
        initial_code: torch.Tensor | None = None,
        generator: torch.Generator | None = None,
        *,
        noise: torch.Tensor | None = None,
        state: RecurrentState | None = None,
        snippets_left: torch.Tensor | None = None,
        motion_snippets: torch.Tensor | None = None,
        counts: torch.Tensor | None = None,
        return_state: bool = False,
        rollout: Rollout | None = None,
    ) -> torch.Tensor | tuple[torch.Tensor, RecurrentState]:
        """Sample codes from the prior, each item for its own number of snippets.

        Args:
            word_features (B, L, 2Ht), sentence (B, 2Ht), word_mask (B, L): :meth:`encode_text`.
            num_snippets: (B,) int, snippets to generate per item (frames // 4).
            initial_code: (C,) or (B, C) mean-pose code; unused when ``state`` is given.
            generator: the source of the latent draws when ``noise`` is None.
            noise: (B, max(num_snippets), Z) standard normal draws: z = mean + exp(logvar / 2)
                * noise; None: drawn from ``generator``.
            state: where to start (a :meth:`prefix_state`, or a state this method returned);
                None: :meth:`initial_state`.
            snippets_left: (B,) snippets from this call's first step to the motion's end, which
                sets the time-to-arrival encoding (default ``num_snippets``: this call ends the
                motion); larger to generate the start of a longer motion.
            motion_snippets: (B,) the whole motion's snippets, which sets the progress encoding
                of a model with ``config.progress_frequencies`` (default ``snippets_left``: this
                call starts the motion); give it when continuing from a ``state``.
            counts: (B,) the repetitions each caption names, for a model with
                ``config.count_clock`` (:attr:`t2m.data.words.EncodedText.count`); None: none.
            return_state: also return each item's state after its last step.
            rollout: what runs the steps; None: the rollout set by :meth:`set_rollout`
                (:func:`t2m.accel.accelerate`), else :class:`StepRollout`.

        Returns: codes (B, max(num_snippets), C), rows past an item's length zero; with
        ``return_state``, (codes, state).
        """
        batch, device = word_features.shape[0], word_features.device
        num_snippets = num_snippets.to(device).long()
        steps = int(num_snippets.max())  # a host sync: the loop's length
        limit = self.config.max_snippets - 1
        if snippets_left is None:
            snippets_left, bad = num_snippets, steps > limit
        else:
            snippets_left = snippets_left.to(device).long()
            bad = bool((snippets_left < num_snippets).any()) or int(snippets_left.max()) > limit
        if motion_snippets is not None:
            motion_snippets = motion_snippets.to(device).long()
            bad = bad or bool((motion_snippets < snippets_left).any())
        if bad or int(num_snippets.min()) < 1:
            raise ValueError(
                f"num_snippets must be in 1..{limit}, and <= snippets_left <= {limit} "
                "(<= motion_snippets)"
            )
        if noise is None:
            noise = torch.randn(
                batch,
                steps,
                self.config.latent_size,
                generator=generator,
                device=device,
                dtype=word_features.dtype,
            )
        elif noise.shape != (batch, steps, self.config.latent_size):
            raise ValueError(
                f"noise must be (B, S, Z) = {(batch, steps, self.config.latent_size)}, "
                f"got {tuple(noise.shape)}"
            )
        if state is None:
            if initial_code is None:
                raise ValueError("generate needs an initial_code or a state to start from")
            state = self.initial_state(sentence, initial_code)
        rollout = rollout or self.generation_rollout or StepRollout(self)
        final, codes = rollout(
            state,
            self.word_context(word_features, word_mask),
            self.time_codes(snippets_left, steps, motion_snippets, counts),
            noise,
            lengths=num_snippets if return_state else None,
        )
        valid = torch.arange(steps, device=device)[None, :] < num_snippets[:, None]
        codes = codes * valid[..., None]  # (B, S, C)
        return (codes, final) if return_state else codes

    def prefix_state(
        self,
        word_features: torch.Tensor,
        sentence: torch.Tensor,
        word_mask: torch.Tensor,
        codes: torch.Tensor,
        initial_code: torch.Tensor,
        snippets_left: torch.Tensor,
        posterior: bool = True,
        noise: torch.Tensor | None = None,
        counts: torch.Tensor | None = None,
    ) -> RecurrentState:
        """The state after the known codes ``codes`` (B, K, C), for :meth:`generate` to continue.

        Runs :meth:`step` teacher-forced over the codes: each step is fed the known previous
        code, and the returned state's previous code is ``codes[:, -1]``. z is drawn from the
        posterior, which reads each known code (``posterior=True``: what the generator saw in
        training), or from the prior. ``noise`` (B, K, Z) defaults to zeros: z is the mean, so
        the state is deterministic. ``snippets_left`` (B,): snippets from the first known code
        to the end of the whole motion; continue with ``generate(num_snippets=snippets_left -
        K, state=...)``. ``counts`` (B,): the repetitions each caption names (a model with
        ``config.count_clock``; continue with the same ``counts``).
        """
        if posterior:
            self._check_posterior()
        batch, steps, _ = codes.shape
        if noise is None:
            noise = codes.new_zeros(batch, steps, self.config.latent_size)
        state, _ = self.rollout(
            self.initial_state(sentence, initial_code, posterior=posterior),
            self.word_context(word_features, word_mask),
            self.time_codes(snippets_left.to(codes.device).long(), steps, counts=counts),
            noise,
            targets=codes if posterior else None,
            feed=codes,
        )
        return state


def gaussian_kl(
    mean_q: torch.Tensor, logvar_q: torch.Tensor, mean_p: torch.Tensor, logvar_p: torch.Tensor
) -> torch.Tensor:
    """KL(N(mean_q, exp(logvar_q)) || N(mean_p, exp(logvar_p))), summed over the last axis."""
    kl = 0.5 * (
        logvar_p
        - logvar_q
        + (torch.exp(logvar_q) + (mean_q - mean_p) ** 2) / torch.exp(logvar_p)
        - 1.0
    )
    return kl.sum(-1)


def temporal_vae_loss(
    outputs: dict[str, torch.Tensor],
    target_codes: torch.Tensor,
    decoded: torch.Tensor,
    target_motion: torch.Tensor,
    kl_weight: float = 0.01,
    code_weight: float = 1.0,
    feature_weight: float = 1.0,
) -> dict[str, torch.Tensor]:
    """SmoothL1 on decoded features + SmoothL1 on codes + kl_weight * KL(posterior || prior).

    KL is summed over latent dimensions and averaged over items and steps.
    """
    feature_loss = F.smooth_l1_loss(decoded, target_motion)
    code_loss = F.smooth_l1_loss(outputs["codes"], target_codes)
    kl = gaussian_kl(
        outputs["posterior_mean"],
        outputs["posterior_logvar"],
        outputs["prior_mean"],
        outputs["prior_logvar"],
    ).mean()
    total = feature_weight * feature_loss + code_weight * code_loss + kl_weight * kl
    return {"loss": total, "features": feature_loss, "codes": code_loss, "kl": kl}
