"""Temporal VAE: text -> a sequence of snippet codes, one GRU step per 4 frames.

Three recurrent blocks share one shape: input Linear -> LayerNorm -> LeakyReLU, plus a sinusoidal
encoding of the time to arrival (snippets left), into a GRU cell whose initial state is a Linear
of the sentence feature.

* prior      input [previous code, attention]               -> mean, log-variance of z
* posterior  input [previous code, current code, attention] -> mean, log-variance of z
* generator  input [previous code, attention, z]            -> next code

Attention: query = Linear(generator state), keys / values = Linears of the word features, scaled
dot product, padding masked (the original neither scales nor masks). The code before step 1 is
the autoencoder's code of the mean pose (zero normalised features), passed in by the caller.

Speed: the input Linears act on concatenations; instead of concatenating per step, their weight
matrices are split by input part, and every part known before the loop (the current codes, the
previous codes under teacher forcing, the time-to-arrival encodings, the keys and values) is
projected for all steps in one matrix product. The arithmetic is that of the concatenated Linears.
"""

from __future__ import annotations

import math

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


class _StepWeightGradient(torch.autograd.Function):
    """Zeros (S, B, O) added to a Linear's per-step outputs, carrying its weight gradient.

    The Linear runs in the loop with detached weights; each step adds its slice of these zeros
    and records its input. In backward, the gradients of all steps arrive here together and the
    weight (and bias) gradient is one (O, S*B) x (S*B, I) product, instead of S thin products of
    inner size B plus S accumulations: the same sum, a fraction of the time.
    """

    @staticmethod
    def forward(ctx, weight, bias, tape, shape):  # noqa: D102
        ctx.tape = tape
        ctx.has_bias = bias is not None
        ctx.dtypes = (weight.dtype, bias.dtype if bias is not None else None)
        return torch.zeros(shape, dtype=weight.dtype, device=weight.device)

    @staticmethod
    def backward(ctx, grad):  # noqa: D102
        inputs = torch.stack(ctx.tape)  # (S, B, I)
        grad = grad.reshape(-1, grad.shape[-1])  # (S*B, O)
        grad_weight = (grad.t() @ inputs.reshape(-1, inputs.shape[-1]).to(grad.dtype)).to(
            ctx.dtypes[0]
        )
        grad_bias = grad.sum(0).to(ctx.dtypes[1]) if ctx.has_bias else None
        return grad_weight, grad_bias, None, None


class StepLinear:
    """``F.linear(x_t, weight, bias)`` for t = 0 .. S-1 inside a recurrent loop, with the weight
    gradient computed once over all steps (see :class:`_StepWeightGradient`).

    Without gradients (generation, validation) it is a plain Linear.
    """

    def __init__(self, weight: torch.Tensor, bias: torch.Tensor | None, steps: int, batch: int):
        device_type = weight.device.type
        dtype = (
            torch.get_autocast_dtype(device_type)
            if torch.is_autocast_enabled(device_type)
            else weight.dtype
        )
        self.weight = weight.detach().to(dtype)
        self.bias = bias.detach().to(dtype) if bias is not None else None
        self.tape: list[torch.Tensor] = []
        self.zeros: tuple[torch.Tensor, ...] | None = None
        if torch.is_grad_enabled() and weight.requires_grad:
            shape = (steps, batch, weight.shape[0])
            zeros = _StepWeightGradient.apply(weight.to(dtype), None if bias is None else bias.to(dtype),
                                              self.tape, shape)  # fmt: skip
            # unbind, not indexing: its backward stacks the step gradients once, where each
            # index's backward would write its slice into a fresh (S, B, O) tensor
            self.zeros = zeros.unbind(0)

    def __call__(self, inputs: torch.Tensor, step: int) -> torch.Tensor:
        output = F.linear(inputs.to(self.weight.dtype), self.weight, self.bias)
        if self.zeros is None:
            return output
        self.tape.append(inputs.detach())
        return output + self.zeros[step]


def gru_update(
    input_gates: torch.Tensor, hidden_gates: torch.Tensor, hidden: torch.Tensor
) -> torch.Tensor:
    """The GRU cell (as ``nn.GRUCell``) from its input and hidden gate pre-activations (B, 3H)."""
    input_r, input_z, input_n = input_gates.chunk(3, dim=-1)
    hidden_r, hidden_z, hidden_n = hidden_gates.chunk(3, dim=-1)
    reset = torch.sigmoid(input_r + hidden_r)
    update = torch.sigmoid(input_z + hidden_z)
    candidate = torch.tanh(input_n + reset * hidden_n)
    return candidate + update * (hidden - candidate)


class RecurrentBlock(nn.Module):
    """Linear -> LayerNorm -> LeakyReLU (+ time encoding) -> GRUCell; initial state from the sentence."""

    def __init__(self, input_size: int, hidden_size: int, sentence_size: int):
        super().__init__()
        self.input = nn.Linear(input_size, hidden_size)
        self.norm = nn.LayerNorm(hidden_size)
        self.cell = nn.GRUCell(hidden_size, hidden_size)
        self.initial = nn.Linear(sentence_size, hidden_size)

    def step(
        self, preactivation: torch.Tensor, time_code: torch.Tensor, hidden: torch.Tensor
    ) -> torch.Tensor:
        """Given ``input(x)`` (B, H) already computed, the next hidden state (B, H)."""
        return self.cell(F.leaky_relu(self.norm(preactivation), 0.2) + time_code, hidden)

    def step_linears(self, steps: int, batch: int) -> tuple[StepLinear, StepLinear]:
        """The GRU cell's input and hidden Linears for a loop of ``steps`` steps."""
        cell = self.cell
        return (StepLinear(cell.weight_ih, cell.bias_ih, steps, batch),
                StepLinear(cell.weight_hh, cell.bias_hh, steps, batch))  # fmt: skip

    def step_at(
        self,
        preactivation: torch.Tensor,
        time_code: torch.Tensor,
        hidden: torch.Tensor,
        linears: tuple[StepLinear, StepLinear],
        index: int,
    ) -> torch.Tensor:
        """:meth:`step` for loop step ``index``, with the weight gradients deferred."""
        inputs = F.leaky_relu(self.norm(preactivation), 0.2) + time_code
        return gru_update(linears[0](inputs, index), linears[1](hidden, index), hidden)


class Gaussian(nn.Module):
    """Hidden state -> (mean, log-variance) of z."""

    def __init__(self, hidden_size: int, latent_size: int):
        super().__init__()
        self.mean = nn.Linear(hidden_size, latent_size)
        self.logvar = nn.Linear(hidden_size, latent_size)

    def forward(self, hidden: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        return self.mean(hidden), self.logvar(hidden)


class GenerationProjections(nn.Module):
    """The three per-step input projections of generation (see
    :meth:`TemporalVAE.generation_projections`)."""

    def __init__(self, previous: nn.Module, attention: nn.Module, latent: nn.Module):
        super().__init__()
        self.previous, self.attention, self.latent = previous, attention, latent


def _linear(weight: torch.Tensor, bias: torch.Tensor | None = None) -> nn.Linear:
    """An ``nn.Linear`` holding the given (freshly made) weight and bias, detached."""
    # skip_init: the copy below replaces the weights, so don't pay for a random initialisation.
    layer = torch.nn.utils.skip_init(nn.Linear, weight.shape[1], weight.shape[0],
                                     bias=bias is not None, device=weight.device,
                                     dtype=weight.dtype)  # fmt: skip
    # The tensors are fresh copies already: adopt them rather than copying again.
    layer.weight = nn.Parameter(weight.detach(), requires_grad=False)
    if bias is not None:
        layer.bias = nn.Parameter(bias.detach(), requires_grad=False)
    return layer


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

    # -- pieces ------------------------------------------------------------------------------

    def encode_text(
        self, words: torch.Tensor, pos: torch.Tensor, text_lengths: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """-> word features (B, L, 2Ht), sentence feature (B, 2Ht), word mask (B, L) bool."""
        word_features, sentence = self.text_encoder(words, pos, text_lengths)
        positions = torch.arange(word_features.shape[1], device=word_features.device)
        mask = positions[None, :] < text_lengths.to(word_features.device)[:, None]
        return word_features, sentence, mask

    def _split_weights(self) -> dict[str, torch.Tensor]:
        """Input-Linear weights split by input part; prior/posterior/generator stacked (3H, .)."""
        c, a = self.code_size, self.config.attention_size
        blocks = (self.prior.input, self.posterior.input, self.generator.input)
        prior, post, gen = (block.weight for block in blocks)
        bias = torch.cat([block.bias for block in blocks])
        device_type = prior.device.type
        if torch.is_autocast_enabled(device_type):
            # Autocast caches the casts of parameters only: cast these derived weights once per
            # sequence rather than once per step.
            dtype = torch.get_autocast_dtype(device_type)
            prior, post, gen, bias = prior.to(dtype), post.to(dtype), gen.to(dtype), bias.to(dtype)
        return {
            "previous": torch.cat([prior[:, :c], post[:, :c], gen[:, :c]]),  # (3H, C)
            "attention": torch.cat([prior[:, c:], post[:, 2 * c :], gen[:, c : c + a]]),  # (3H, A)
            "bias": bias,  # (3H,)
            "current": post[:, c : 2 * c],  # (H, C), posterior only
            "latent": gen[:, c + a :],  # (H, Z), generator only
        }

    def generation_projections(self) -> GenerationProjections:
        """The prior's and generator's input Linears, split by input part, as modules.

        ``previous`` and ``attention`` stack the prior's rows over the generator's (2H out);
        ``latent`` is the generator's alone. Built once per sequence; modules (not raw weights)
        so that dynamic int8 quantisation can reach them.
        """
        c, a = self.code_size, self.config.attention_size
        prior, gen = self.prior.input, self.generator.input
        weights = (prior.weight, gen.weight, prior.bias, gen.bias)
        device_type = prior.weight.device.type
        if torch.is_autocast_enabled(device_type):
            dtype = torch.get_autocast_dtype(device_type)
            weights = tuple(w.to(dtype) for w in weights)
        prior_w, gen_w, prior_b, gen_b = weights
        # Only the prior's and generator's rows are copied (the posterior's are not needed).
        return GenerationProjections(
            _linear(torch.cat([prior_w[:, :c], gen_w[:, :c]]), torch.cat([prior_b, gen_b])),
            _linear(torch.cat([prior_w[:, c:], gen_w[:, c : c + a]])),
            _linear(gen_w[:, c + a :].contiguous()),
        )

    def _time_codes(self, num_snippets: torch.Tensor, steps: int) -> torch.Tensor:
        """(B, S, H) encodings of the snippets left before the end: num_snippets - i."""
        left = num_snippets[:, None] - torch.arange(steps, device=num_snippets.device)[None, :]
        left = left.clamp(0, self.config.max_snippets - 1)
        return self.time_table[left]

    def _context(
        self, word_features: torch.Tensor, word_mask: torch.Tensor
    ) -> tuple[torch.Tensor, ...]:
        keys = self.key(word_features)  # (B, L, A), once per sequence
        values = self.value(word_features)
        bias = torch.zeros(word_mask.shape, dtype=keys.dtype, device=keys.device)
        bias = bias.masked_fill(~word_mask, float("-inf"))
        return keys, values, bias

    def _attend(
        self, hidden: torch.Tensor, keys: torch.Tensor, values: torch.Tensor, bias: torch.Tensor
    ) -> torch.Tensor:
        """Generator state (B, H) -> attention vector (B, A)."""
        query = self.query(hidden)
        scores = torch.einsum("bla,ba->bl", keys, query) / math.sqrt(keys.shape[-1]) + bias
        return torch.einsum("bl,bla->ba", torch.softmax(scores, dim=-1), values)

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
    ) -> dict[str, torch.Tensor]:
        """Teacher-forced or free-running pass over target codes (posterior sampling).

        Args:
            word_features (B, L, 2Ht), sentence (B, 2Ht), word_mask (B, L): from :meth:`encode_text`.
            codes: (B, S, C) target codes (from the frozen encoder).
            initial_code: (C,) or (B, C), the mean-pose code fed before step 1.
            teacher_forcing: feed the target previous code (else the model's own, detached).
            noise: (B, S, Z) standard normal draws; drawn from the global generator if None.

        Returns: ``codes`` (B, S, C) predicted; ``posterior_mean``, ``posterior_logvar``,
        ``prior_mean``, ``prior_logvar`` (B, S, Z).
        """
        batch, steps, _ = codes.shape
        hidden_size = self.config.hidden_size
        weights = self._split_weights()
        keys, values, bias = self._context(word_features, word_mask)
        initial_code = initial_code.expand(batch, self.code_size)
        num_snippets = torch.full((batch,), steps, dtype=torch.long, device=codes.device)
        time_codes = self._time_codes(num_snippets, steps)  # (B, S, H)
        current = F.linear(codes, weights["current"])  # (B, S, H)
        if teacher_forcing:
            previous_codes = torch.cat([initial_code[:, None], codes[:, :-1]], dim=1)
            previous_all = F.linear(
                previous_codes, weights["previous"], weights["bias"]
            )  # (B, S, 3H)
        if noise is None:
            noise = torch.randn(
                batch, steps, self.config.latent_size, device=codes.device, dtype=codes.dtype
            )

        prior_cell = self.prior.step_linears(steps, batch)
        post_cell = self.posterior.step_linears(steps, batch)
        gen_cell = self.generator.step_linears(steps, batch)
        previous_linear = StepLinear(weights["previous"], weights["bias"], steps, batch)
        attention_linear = StepLinear(weights["attention"], None, steps, batch)

        h_prior = self.prior.initial(sentence)
        h_post = self.posterior.initial(sentence)
        h_gen = self.generator.initial(sentence)
        previous = initial_code
        prior_states, generator_states, codes_out, post_means, post_logvars = [], [], [], [], []
        for i in range(steps):
            attention = self._attend(h_gen, keys, values, bias)
            if teacher_forcing:
                pre = previous_all[:, i]
            else:
                pre = previous_linear(previous, i)
            pre = pre + attention_linear(attention, i)  # (B, 3H)
            pre_prior, pre_post, pre_gen = pre.split(hidden_size, dim=-1)
            time_code = time_codes[:, i]
            h_post = self.posterior.step_at(
                pre_post + current[:, i], time_code, h_post, post_cell, i
            )
            h_prior = self.prior.step_at(pre_prior, time_code, h_prior, prior_cell, i)
            post_mean, post_logvar = self.posterior_gaussian(h_post)
            z = post_mean + torch.exp(0.5 * post_logvar) * noise[:, i]
            pre_gen = pre_gen + F.linear(z, weights["latent"])
            h_gen = self.generator.step_at(pre_gen, time_code, h_gen, gen_cell, i)
            prior_states.append(h_prior)
            generator_states.append(h_gen)
            post_means.append(post_mean)
            post_logvars.append(post_logvar)
            if not teacher_forcing:  # the next step needs this code now
                code = self.output(h_gen)
                codes_out.append(code)
                previous = code.detach()
        # Heads whose outputs the loop does not feed back run once over all steps.
        prior_mean, prior_logvar = self.prior_gaussian(torch.stack(prior_states, dim=1))
        if teacher_forcing:
            codes_all = self.output(torch.stack(generator_states, dim=1))
        else:
            codes_all = torch.stack(codes_out, dim=1)
        return {
            "codes": codes_all,
            "prior_mean": prior_mean,
            "prior_logvar": prior_logvar,
            "posterior_mean": torch.stack(post_means, dim=1),
            "posterior_logvar": torch.stack(post_logvars, dim=1),
        }

    # -- generation --------------------------------------------------------------------------

    @torch.no_grad()
    def generate(
        self,
        word_features: torch.Tensor,
        sentence: torch.Tensor,
        word_mask: torch.Tensor,
        num_snippets: torch.Tensor,
        initial_code: torch.Tensor,
        generator: torch.Generator | None = None,
        projections: GenerationProjections | None = None,
    ) -> torch.Tensor:
        """Sample codes from the prior, each item for its own number of snippets.

        Args:
            word_features (B, L, 2Ht), sentence (B, 2Ht), word_mask (B, L): :meth:`encode_text`.
            num_snippets: (B,) int, snippets per item (frames // 4), 1 .. max_snippets - 1.
            initial_code: (C,) or (B, C) mean-pose code.
            generator: the source of the latent draws (on the model's device).
            projections: the per-step input projections of the prior and generator (default:
                :meth:`generation_projections`, float); an int8 copy of them can be passed in.

        Returns: (B, max(num_snippets), C); rows past an item's length are zero.
        """
        batch = word_features.shape[0]
        hidden_size = self.config.hidden_size
        num_snippets = num_snippets.to(word_features.device).long()
        steps = int(num_snippets.max())  # the one host sync: the loop's length
        if steps >= self.config.max_snippets or int(num_snippets.min()) < 1:
            raise ValueError(f"num_snippets must be in 1..{self.config.max_snippets - 1}")
        if projections is None:
            projections = self.generation_projections()
        keys, values, bias = self._context(word_features, word_mask)
        time_codes = self._time_codes(num_snippets, steps)
        noise = torch.randn(
            batch, steps, self.config.latent_size, generator=generator,
            device=word_features.device, dtype=word_features.dtype,
        )  # fmt: skip
        h_prior = self.prior.initial(sentence)
        h_gen = self.generator.initial(sentence)
        previous = initial_code.expand(batch, self.code_size)
        codes = []
        for i in range(steps):
            attention = self._attend(h_gen, keys, values, bias)
            time_code = time_codes[:, i]
            # Prior and generator rows in one product each: (B, 2H), split below.
            pre = projections.previous(previous) + projections.attention(attention)
            pre_prior, pre_gen = pre.split(hidden_size, dim=-1)
            h_prior = self.prior.step(pre_prior, time_code, h_prior)
            prior_mean, prior_logvar = self.prior_gaussian(h_prior)
            z = prior_mean + torch.exp(0.5 * prior_logvar) * noise[:, i]
            h_gen = self.generator.step(pre_gen + projections.latent(z), time_code, h_gen)
            previous = self.output(h_gen)
            codes.append(previous)
        codes_tensor = torch.stack(codes, dim=1)  # (B, S, C)
        valid = torch.arange(steps, device=codes_tensor.device)[None, :] < num_snippets[:, None]
        return codes_tensor * valid[..., None]


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
        outputs["posterior_mean"], outputs["posterior_logvar"],
        outputs["prior_mean"], outputs["prior_logvar"],
    ).mean()  # fmt: skip
    total = feature_weight * feature_loss + code_weight * code_loss + kl_weight * kl
    return {"loss": total, "features": feature_loss, "codes": code_loss, "kl": kl}
