"""The temporal VAE's training pass, rearranged for speed: the arithmetic of
:meth:`t2m.models.temporal_vae.TemporalVAE.rollout` over :meth:`~TemporalVAE.step`, tested equal
to it (``tests/test_temporal_vae.py``). :meth:`TemporalVAE.forward` runs :func:`fast_forward`
unless called with ``fast=False``; generation runs the plain step (measured as fast).

Three rearrangements, each the same sum in another order:

1. Split projections. The blocks' input Linears act on concatenations [previous code, current
   code, attention, z]. Their weight matrices are split by input part and the prior's,
   posterior's and generator's rows stacked (3H, .), so the parts known before the loop (the
   current codes, the previous codes under teacher forcing) are projected for all steps in one
   matrix product, and the rest in one product per part per step instead of one per block.
2. Deferred weight gradients. A Linear inside the loop (the GRU cells' input and hidden
   Linears, the per-step projections) runs with detached weights and records its input; the
   gradient of its weight is then one (O, S*B) x (S*B, I) product in backward instead of S
   thin products of inner size B (:class:`StepLinear`). The GRU gates are written out
   (:func:`gru_update`) because ``nn.GRUCell`` reads its weights itself.
3. Heads whose outputs the loop does not feed back (the prior's Gaussian; the output head under
   teacher forcing) run once over all steps.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import torch
import torch.nn.functional as F

if TYPE_CHECKING:
    from t2m.models.temporal_vae import RecurrentBlock, TemporalVAE


class _StepWeightGradient(torch.autograd.Function):
    """Zeros (S, B, O) added to a Linear's per-step outputs, carrying its weight gradient.

    The Linear runs in the loop with detached weights; each step adds its slice of these zeros
    and records its input. In backward, the gradients of all steps arrive here together and the
    weight (and bias) gradient is one (O, S*B) x (S*B, I) product.
    """

    @staticmethod
    def forward(ctx, weight, bias, tape, shape):
        ctx.tape = tape
        ctx.has_bias = bias is not None
        ctx.dtypes = (weight.dtype, bias.dtype if bias is not None else None)
        return torch.zeros(shape, dtype=weight.dtype, device=weight.device)

    @staticmethod
    def backward(ctx, grad):
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

    Without gradients (validation) it is a plain Linear.
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
            bias = None if bias is None else bias.to(dtype)
            zeros = _StepWeightGradient.apply(
                weight.to(dtype), bias, self.tape, (steps, batch, weight.shape[0])
            )
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


class _FastBlock:
    """A :class:`RecurrentBlock` given its input Linear's output, its GRU Linears deferred."""

    def __init__(self, block: RecurrentBlock, steps: int, batch: int):
        self.norm = block.norm
        cell = block.cell
        self.input_gates = StepLinear(cell.weight_ih, cell.bias_ih, steps, batch)
        self.hidden_gates = StepLinear(cell.weight_hh, cell.bias_hh, steps, batch)

    def __call__(
        self, preactivation: torch.Tensor, time_code: torch.Tensor, hidden: torch.Tensor, step: int
    ) -> torch.Tensor:
        inputs = F.leaky_relu(self.norm(preactivation), 0.2) + time_code
        return gru_update(self.input_gates(inputs, step), self.hidden_gates(hidden, step), hidden)


def split_input_weights(vae: TemporalVAE) -> dict[str, torch.Tensor]:
    """The blocks' input-Linear weights split by input part; prior / posterior / generator rows
    stacked (3H, .) for the parts all three read."""
    c, a = vae.code_size, vae.config.attention_size
    blocks = (vae.prior.input, vae.posterior.input, vae.generator.input)
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


def fast_forward(
    vae: TemporalVAE,
    word_features: torch.Tensor,
    sentence: torch.Tensor,
    word_mask: torch.Tensor,
    codes: torch.Tensor,
    initial_code: torch.Tensor,
    teacher_forcing: bool,
    noise: torch.Tensor,
) -> dict[str, torch.Tensor]:
    """:meth:`TemporalVAE.forward` (same arguments and results, ``noise`` required), faster."""
    batch, steps, _ = codes.shape
    hidden_size = vae.config.hidden_size
    weights = split_input_weights(vae)
    context = vae.word_context(word_features, word_mask)
    state = vae.initial_state(sentence, initial_code, posterior=True)
    snippets_left = torch.full((batch,), steps, dtype=torch.long, device=codes.device)
    time_codes = vae.time_codes(snippets_left, steps)  # (B, S, H)
    current = F.linear(codes, weights["current"])  # (B, S, H)
    if teacher_forcing:
        previous_codes = torch.cat([state.previous_code[:, None], codes[:, :-1]], dim=1)
        previous_all = F.linear(previous_codes, weights["previous"], weights["bias"])  # (B, S, 3H)
    prior_block = _FastBlock(vae.prior, steps, batch)
    posterior_block = _FastBlock(vae.posterior, steps, batch)
    generator_block = _FastBlock(vae.generator, steps, batch)
    previous_linear = StepLinear(weights["previous"], weights["bias"], steps, batch)
    attention_linear = StepLinear(weights["attention"], None, steps, batch)

    h_prior, h_gen, previous, h_post = state
    prior_states, generator_states, codes_out, post_means, post_logvars = [], [], [], [], []
    for i in range(steps):
        attention, _ = vae.attend(h_gen, context)
        pre = previous_all[:, i] if teacher_forcing else previous_linear(previous, i)
        pre = pre + attention_linear(attention, i)  # (B, 3H)
        pre_prior, pre_post, pre_gen = pre.split(hidden_size, dim=-1)
        time_code = time_codes[:, i]
        h_post = posterior_block(pre_post + current[:, i], time_code, h_post, i)
        h_prior = prior_block(pre_prior, time_code, h_prior, i)
        post_mean, post_logvar = vae.posterior_gaussian(h_post)
        z = post_mean + torch.exp(0.5 * post_logvar) * noise[:, i]
        h_gen = generator_block(pre_gen + F.linear(z, weights["latent"]), time_code, h_gen, i)
        prior_states.append(h_prior)
        generator_states.append(h_gen)
        post_means.append(post_mean)
        post_logvars.append(post_logvar)
        if not teacher_forcing:  # the next step needs this code now
            code = vae.output(h_gen)
            codes_out.append(code)
            previous = code.detach()
    prior_mean, prior_logvar = vae.prior_gaussian(torch.stack(prior_states, dim=1))
    if teacher_forcing:
        codes_all = vae.output(torch.stack(generator_states, dim=1))
    else:
        codes_all = torch.stack(codes_out, dim=1)
    return {
        "codes": codes_all,
        "prior_mean": prior_mean,
        "prior_logvar": prior_logvar,
        "posterior_mean": torch.stack(post_means, dim=1),
        "posterior_logvar": torch.stack(post_logvars, dim=1),
    }
