"""The temporal VAE's training pass, rearranged for speed: the arithmetic of
:meth:`t2m.models.temporal_vae.TemporalVAE.rollout` over :meth:`~TemporalVAE.step`, tested equal
to it (``tests/test_temporal_vae.py``). :meth:`TemporalVAE.forward` runs :func:`fast_forward`
unless called with ``fast=False``; :meth:`TemporalVAE.generate` runs a :class:`GenerationPlan`
(the prior / generator step with stacked and folded weights, at the end of this file).

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

Every product inside the loop (the attention query, the posterior's Gaussian, z's projection,
the fed-back output head too) is a :class:`StepLinear`, whose weight is packed once per
sequence for oneDNN on a CPU: with those, a paper-size training step (batch 32, one thread)
took 0.79-0.82x the time in float32 and 0.80-0.84x under bfloat16 autocast.
"""

from __future__ import annotations

import weakref
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING

import torch
import torch.nn.functional as F
from torch import nn

if TYPE_CHECKING:
    from t2m.models.temporal_vae import RecurrentBlock, RecurrentState, TemporalVAE, WordContext


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


def _packable(weight: torch.Tensor) -> bool:
    """Whether oneDNN can pack ``weight`` for its matrix product on this CPU and torch build."""
    if weight.device.type != "cpu" or not torch.backends.mkldnn.is_available():
        return False
    if weight.dtype == torch.bfloat16:
        return torch.ops.mkldnn._is_mkldnn_bf16_supported()
    return weight.dtype == torch.float32


def _packed_product(
    inputs: torch.Tensor, packed: torch.Tensor, bias: torch.Tensor | None
) -> torch.Tensor:
    """``F.linear`` with a weight packed by ``torch.ops.mkldnn._reorder_linear_weight``."""
    return torch.ops.mkldnn._linear_pointwise(inputs, packed, bias, "none", [], "")


class _PackedStepProduct(torch.autograd.Function):
    """One step's ``x W^T + b`` through packed weights; backward gives the input's gradient
    (``grad W``, W^T packed too), the weight's and bias's go through :class:`StepLinear`."""

    @staticmethod
    def forward(ctx, inputs, linear):
        ctx.transposed = linear.transposed
        return _packed_product(inputs, linear.packed, linear.bias)

    @staticmethod
    def backward(ctx, grad):
        return _packed_product(grad.contiguous(), ctx.transposed, None), None


class StepLinear:
    """``F.linear(x_t, weight, bias)`` for t = 0 .. S-1 inside a recurrent loop, with the weight
    gradient computed once over all steps (see :class:`_StepWeightGradient`).

    On a CPU the weight (and for the input's gradient its transpose) is packed once for
    oneDNN: at the loop's batch of 32 its products take 0.55-0.7x the time of ``F.linear``'s
    on one thread (paper size, float32), and packing costs about one product.
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
        training = torch.is_grad_enabled() and weight.requires_grad
        self.packed = self.transposed = None
        if _packable(self.weight):
            self.packed = torch.ops.mkldnn._reorder_linear_weight(self.weight)
            if torch.is_grad_enabled():
                transposed = self.weight.t().contiguous()
                self.transposed = torch.ops.mkldnn._reorder_linear_weight(transposed)
        if training:
            bias = None if bias is None else bias.to(dtype)
            zeros = _StepWeightGradient.apply(
                weight.to(dtype), bias, self.tape, (steps, batch, weight.shape[0])
            )
            # unbind, not indexing: its backward stacks the step gradients once, where each
            # index's backward would write its slice into a fresh (S, B, O) tensor
            self.zeros = zeros.unbind(0)

    def __call__(self, inputs: torch.Tensor, step: int) -> torch.Tensor:
        inputs = inputs.to(self.weight.dtype)
        if self.packed is None:
            output = F.linear(inputs, self.weight, self.bias)
        elif self.transposed is not None and inputs.requires_grad:
            output = _PackedStepProduct.apply(inputs, self)
        else:
            output = _packed_product(inputs, self.packed, self.bias)
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


class _GRUUpdate(torch.autograd.Function):
    """:func:`gru_update` as one autograd node with its backward written out: the same values,
    a third of the operators of the graph autograd records for it (no per-gate slices, whose
    backward concatenates the gate gradients)."""

    @staticmethod
    def forward(ctx, input_gates, hidden_gates, hidden):
        size = hidden.shape[-1]
        gates = torch.sigmoid(input_gates[..., : 2 * size] + hidden_gates[..., : 2 * size])
        reset, update = gates.split(size, dim=-1)
        hidden_n = hidden_gates[..., 2 * size :]
        candidate = torch.tanh(torch.addcmul(input_gates[..., 2 * size :], reset, hidden_n))
        ctx.save_for_backward(gates, hidden_n, candidate, hidden)
        return candidate + update * (hidden - candidate)

    @staticmethod
    def backward(ctx, grad):
        gates, hidden_n, candidate, hidden = ctx.saved_tensors
        reset, update = gates.split(hidden.shape[-1], dim=-1)
        grad_hidden = grad * update
        grad_n = (grad - grad_hidden) * (1 - candidate * candidate)  # tanh's input
        grad_rz = torch.cat([grad_n * hidden_n, grad * (hidden - candidate)], dim=-1)
        grad_rz = grad_rz * gates * (1 - gates)  # the sigmoids' inputs
        grad_input = torch.cat([grad_rz, grad_n], dim=-1)
        grad_hidden_gates = torch.cat([grad_rz, grad_n * reset], dim=-1)
        return grad_input, grad_hidden_gates, grad_hidden


class _FastBlock:
    """A :class:`RecurrentBlock` given its input Linear's output and its hidden gates, its GRU
    input Linear deferred."""

    def __init__(self, block: RecurrentBlock, steps: int, batch: int):
        self.norm = block.norm
        cell = block.cell
        self.input_gates = StepLinear(cell.weight_ih, cell.bias_ih, steps, batch)

    def __call__(
        self,
        preactivation: torch.Tensor,
        time_code: torch.Tensor,
        hidden_gates: torch.Tensor,
        hidden: torch.Tensor,
        step: int,
    ) -> torch.Tensor:
        inputs = F.leaky_relu(self.norm(preactivation), 0.2) + time_code
        return _GRUUpdate.apply(self.input_gates(inputs, step), hidden_gates, hidden)


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


def _stacked(layers: Sequence[nn.Module], steps: int, batch: int) -> StepLinear:
    """One :class:`StepLinear` for Linears (or GRU cells' hidden products) that read the same
    input: their weights (and biases) stacked by rows."""
    weights, biases = [], []
    for layer in layers:
        if isinstance(layer, nn.GRUCell):
            weights.append(layer.weight_hh)
            biases.append(layer.bias_hh)
        else:
            weights.append(layer.weight)
            biases.append(layer.bias)
    return StepLinear(torch.cat(weights), torch.cat(biases), steps, batch)


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
    """:meth:`TemporalVAE.forward` (same arguments and results, ``noise`` required), faster.

    Each GRU state is read by one stacked product right after it is computed: the generator's
    by the next step's attention query and hidden gates (and, free-running, this step's output
    head), the posterior's by its next hidden gates and this step's Gaussian, the prior's by its
    next hidden gates. Attention scores and the attended vector are per-item dot products
    (elementwise products and sums: torch's batched matrix products of these thin shapes cost
    several times more, forward and backward)."""
    batch, steps, _ = codes.shape
    hidden_size = vae.config.hidden_size
    attention_size = vae.config.attention_size
    scale = attention_size**-0.5
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
    attention_linear = StepLinear(weights["attention"], None, steps, batch)
    latent_linear = StepLinear(weights["latent"], None, steps, batch)
    # the states' readers, each called on the initial state and after every step but the last
    # (the prior's), the last too where that step's Gaussian or code needs it
    prior_state = _stacked([vae.prior.cell], steps, batch)  # (3H, H)
    gaussian = vae.posterior_gaussian
    posterior_state = _stacked(  # (3H + 2Z, H): hidden gates, this step's mean and log-variance
        [vae.posterior.cell, gaussian.mean, gaussian.logvar], steps + 1, batch
    )
    first, output_norm, _, last = vae.output
    generator_readers = [vae.query, vae.generator.cell]  # (A + 3H, H)
    if not teacher_forcing:  # the model's own code, fed back: previous code and output head
        generator_readers.append(first)  # + (H, H): this step's output head
        previous_linear = StepLinear(weights["previous"], weights["bias"], steps, batch)
        last_linear = StepLinear(last.weight, last.bias, steps, batch)
    generator_state = _stacked(generator_readers, steps + (not teacher_forcing), batch)
    gate_size, latent_size = 3 * hidden_size, vae.config.latent_size
    generator_parts = [attention_size, gate_size] + ([] if teacher_forcing else [hidden_size])
    posterior_parts = [gate_size, 2 * latent_size]

    h_prior, h_gen, previous, h_post = state
    prior_gates = prior_state(h_prior, 0)
    post_gates = posterior_state(h_post, 0).split(posterior_parts, dim=-1)[0]
    query, gen_gates = generator_state(h_gen, 0).split(generator_parts, dim=-1)[:2]
    keys, values, mask_bias = context
    # per step: unbind, not indexing; an index's backward writes its step into a zero-filled
    # (B, S, .) tensor, once per step
    current, time_codes, noise = current.unbind(1), time_codes.unbind(1), noise.unbind(1)
    if teacher_forcing:
        previous_all = previous_all.unbind(1)
    prior_states, generator_states, codes_out, post_means, post_logvars = [], [], [], [], []
    for i in range(steps):
        # attention of the previous generator state: (B, L) scores, (B, A) attended vector
        scores = torch.linalg.vecdot(keys, query[:, None]) * scale + mask_bias
        attention_weights = torch.softmax(scores, dim=-1)
        attention = torch.linalg.vecdot(values.transpose(1, 2), attention_weights[:, None])
        pre = previous_all[i] if teacher_forcing else previous_linear(previous, i)
        pre = pre + attention_linear(attention, i)  # (B, 3H)
        pre_prior, pre_post, pre_gen = pre.split(hidden_size, dim=-1)
        time_code = time_codes[i]
        h_post = posterior_block(pre_post + current[i], time_code, post_gates, h_post, i)
        post_gates, post_stats = posterior_state(h_post, i + 1).split(posterior_parts, dim=-1)
        h_prior = prior_block(pre_prior, time_code, prior_gates, h_prior, i)
        if i + 1 < steps:
            prior_gates = prior_state(h_prior, i + 1)
        post_mean, post_logvar = post_stats.chunk(2, dim=-1)
        z = post_mean + torch.exp(0.5 * post_logvar) * noise[i]
        h_gen = generator_block(pre_gen + latent_linear(z, i), time_code, gen_gates, h_gen, i)
        prior_states.append(h_prior)
        generator_states.append(h_gen)
        post_means.append(post_mean)
        post_logvars.append(post_logvar)
        if teacher_forcing:
            if i + 1 < steps:
                query, gen_gates = generator_state(h_gen, i + 1).split(generator_parts, dim=-1)
        else:  # the next step needs this code now
            query, gen_gates, hidden = generator_state(h_gen, i + 1).split(generator_parts, dim=-1)
            code = last_linear(F.leaky_relu(output_norm(hidden), 0.2), i)
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


# -- generation ---------------------------------------------------------------------------------


class PackedLinear(nn.Module):
    """``F.linear`` with a bfloat16 weight laid out once for oneDNN's matrix product (CPU; the
    layout is opaque, so the module is for inference only). torch's own bfloat16
    matrix-vector product reads its weight slowly: at batch 1, one thread, a (4096, 1024)
    weight took 0.3-0.4x of ``F.linear``'s time packed (0.7x at batch 32). Float32 weights
    are not packed: 0.65x alone, but the whole generation step ran 1.18x slower with them."""

    def __init__(self, weight: torch.Tensor, bias: torch.Tensor | None):
        super().__init__()
        self.out_features = weight.shape[0]
        self.packed = torch.ops.mkldnn._reorder_linear_weight(weight.detach())
        self.bias = None if bias is None else bias.detach().clone()

    @staticmethod
    def supports(weight: torch.Tensor) -> bool:
        """Whether this CPU and torch build can pack ``weight``."""
        if weight.device.type != "cpu" or weight.dtype != torch.bfloat16:
            return False
        return torch.backends.mkldnn.is_available() and torch.ops.mkldnn._is_mkldnn_bf16_supported()

    def forward(self, inputs: torch.Tensor) -> torch.Tensor:
        """(..., I) -> (..., O), in the weight's dtype (under autocast too)."""
        inputs = inputs.to(self.packed.dtype)
        return torch.ops.mkldnn._linear_pointwise(inputs, self.packed, self.bias, "none", [], "")


def float_linear(weight: torch.Tensor, bias: torch.Tensor | None, copy: bool = True) -> nn.Linear:
    """A Linear holding ``weight`` (O, I) and ``bias`` (O,), no gradients: copies of them, or
    (``copy=False``) the tensors themselves, for a caller about to convert it."""
    linear = nn.Linear(weight.shape[1], weight.shape[0], bias=bias is not None, device="meta")
    weight, bias = weight.detach(), None if bias is None else bias.detach()
    if copy:
        weight, bias = weight.clone(), None if bias is None else bias.clone()
    linear.weight = nn.Parameter(weight, requires_grad=False)
    if bias is not None:
        linear.bias = nn.Parameter(bias, requires_grad=False)
    return linear


LinearFactory = Callable[[Sequence[torch.Tensor], Sequence[torch.Tensor] | None], nn.Module]
"""Makes the Linear whose weight is the given (O_i, I) blocks stacked by rows (sum O_i, I) and
whose bias is the bias blocks concatenated (or none)."""


def packed_linear(weights: Sequence[torch.Tensor], biases: Sequence[torch.Tensor] | None):
    """A :class:`PackedLinear` for bfloat16 weights on a CPU that supports it, else
    :func:`float_linear` (a :data:`LinearFactory`)."""
    weight = torch.cat([w.detach() for w in weights])
    bias = None if biases is None else torch.cat([b.detach() for b in biases])
    if PackedLinear.supports(weight):
        return PackedLinear(weight, bias)
    return float_linear(weight, bias, copy=False)


def _shared_rows(parameters: Sequence[torch.Tensor]) -> torch.Tensor:
    """The parameters' rows stacked (sum O_i, ...), each parameter made a view of its rows
    (``.data`` replaced: the same Parameter objects, so an optimiser's references stay valid):
    the model and its plan hold the weights once. One parameter: itself."""
    if len(parameters) == 1:
        return parameters[0].detach()
    stacked = torch.cat([p.detach() for p in parameters])
    start = 0
    for parameter in parameters:
        parameter.data = stacked[start : start + parameter.shape[0]]
        start += parameter.shape[0]
    return stacked


def shared_linear(weights: Sequence[torch.Tensor], biases: Sequence[torch.Tensor] | None):
    """A :data:`LinearFactory` for float weights that the plan shares with the model: the
    stacked weight (and bias) is the storage of the model's parameters (:func:`_shared_rows`)."""
    bias = None if biases is None else _shared_rows(biases)
    return float_linear(_shared_rows(weights), bias, copy=False)


def _input_weights(vae: TemporalVAE, share: bool) -> dict[str, list[torch.Tensor]]:
    """The prior's and generator's input-Linear weights as row blocks for the plan:
    ``previous`` (2H, C) and ``attention`` (2H, A), the two blocks' rows, and the generator's
    ``latent`` (H, Z). ``share``: single views of one (2H, C + A + Z) tensor whose rows are
    [prior weight, zeros (H, Z)] and the generator's weight, the blocks' weights made views of
    it (as :func:`_shared_rows`); otherwise views of the blocks' weights."""
    c, a = vae.code_size, vae.config.attention_size
    prior, generator = vae.prior.input.weight.detach(), vae.generator.input.weight.detach()
    if not share:
        return {
            "previous": [prior[:, :c], generator[:, :c]],
            "attention": [prior[:, c : c + a], generator[:, c : c + a]],
            "latent": [generator[:, c + a :]],
        }
    hidden = prior.shape[0]
    stacked = prior.new_zeros(2 * hidden, generator.shape[1])
    stacked[:hidden, : c + a] = prior
    stacked[hidden:] = generator
    vae.prior.input.weight.data = stacked[:hidden, : c + a]
    vae.generator.input.weight.data = stacked[hidden:]
    return {
        "previous": [stacked[:, :c]],
        "attention": [stacked[:, c : c + a]],
        "latent": [stacked[hidden:, c + a :]],
    }


class GenerationPlan(nn.Module):
    """The prior / generator step of :meth:`TemporalVAE.step` without the posterior, its weights
    rearranged for sampling (the same sums in another order, fewer and larger products):

    * the prior's and generator's input rows read by the previous code are stacked (2H, C);
    * attention: keys . (W_q h + b_q) = (keys W_q) h + keys . b_q, and the attention vector
      enters the two input Linears as W_att (sum_l w_l v_l) = sum_l w_l (W_att v_l); so
      (keys W_q) (B, L, H) and (values W_att^T) (B, L, 2H) are per-sequence tables
      (:meth:`tables`) and the query and attention weights are not read per step;
    * a GRU's hidden-gate product for step t+1 reads the state of step t, as do the prior's
      Gaussian and the output head's first Linear: each state is read by one stacked Linear,
      (3H + 2Z, H) for the prior and (3H + H, H) for the generator.

    Built from a float model (:func:`generation_plan`). ``linear`` (a :data:`LinearFactory`)
    makes each Linear from its row blocks; :func:`t2m.quantize.quantize_int8` passes one that
    quantises the blocks one by one, so no float copy of a stacked weight is ever held. The
    default: :func:`packed_linear` for bfloat16 weights, and for float32 ones
    :func:`shared_linear`: the plan holds no weights of its own, the model's stacked
    parameters become views into the plan's (a separate copy cost a paper-size float32
    generation process +13% peak memory).
    """

    def __init__(self, vae: TemporalVAE, linear: LinearFactory | None = None):
        super().__init__()
        prior, gen = vae.prior, vae.generator
        share = linear is None and not PackedLinear.supports(prior.input.weight)
        if linear is None:
            linear = shared_linear if share else packed_linear
        self.hidden_size, self.latent_size = vae.config.hidden_size, vae.config.latent_size
        inputs = _input_weights(vae, share)
        # largest first: each int8 weight's temporaries then fit where the previous one's were
        first, norm, _, last = vae.output
        self.generator_state = linear(  # (3H + H, H): next hidden gates, output's first Linear
            [gen.cell.weight_hh, first.weight], [gen.cell.bias_hh, first.bias]
        )
        gaussian = vae.prior_gaussian
        self.prior_state = linear(  # (3H + 2Z, H): next hidden gates, mean, log-variance
            [prior.cell.weight_hh, gaussian.mean.weight, gaussian.logvar.weight],
            [prior.cell.bias_hh, gaussian.mean.bias, gaussian.logvar.bias],
        )
        self.prior_gates = linear([prior.cell.weight_ih], [prior.cell.bias_ih])  # (3H, H)
        self.generator_gates = linear([gen.cell.weight_ih], [gen.cell.bias_ih])
        self.previous = linear(inputs["previous"], [prior.input.bias, gen.input.bias])  # (2H, C)
        # per-sequence tables: keys -> keys W_q (A -> H), values -> values W_att^T (A -> 2H)
        self.value_table = linear(inputs["attention"], None)
        self.score_table = linear([vae.query.weight.detach().t()], None)
        self.register_buffer("query_bias", vae.query.bias.detach().clone())  # (A,)
        self.output_last = linear([last.weight], [last.bias])
        self.latent = linear(inputs["latent"], None)  # (H, Z)
        self.prior_norm, self.generator_norm, self.output_norm = (
            prior.norm,
            gen.norm,
            norm,
        )  # shared

    def tables(self, context: WordContext) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Per sequence: score table (B, L, H), score bias (B, L, 1) (mask included) and value
        table (B, L, 2H), from :meth:`TemporalVAE.word_context`."""
        keys = context.keys
        scale = self.query_bias.shape[0] ** -0.5
        score_table = self.score_table(keys) * scale
        score_bias = (keys @ self.query_bias.to(keys.dtype)) * scale + context.mask_bias
        value_table = self.value_table(context.values)
        return score_table, score_bias[..., None], value_table

    def forward(
        self,
        state: RecurrentState,
        context: WordContext,
        time_codes: torch.Tensor,
        noise: torch.Tensor,
        lengths: torch.Tensor | None = None,
    ) -> tuple[RecurrentState, torch.Tensor]:
        """:meth:`TemporalVAE.rollout` from the prior (arguments as there) -> (state, codes (B, S, C))."""
        h, z_size = self.hidden_size, self.latent_size
        score_table, score_bias, value_table = self.tables(context)
        h_prior, h_gen, previous, _ = state
        prior_hidden = self.prior_state(h_prior)[:, : 3 * h]
        gen_hidden = self.generator_state(h_gen)[:, : 3 * h]
        if h_gen.shape[0] == 1:  # one batched product is fastest for one sequence ...

            def score(hidden: torch.Tensor) -> torch.Tensor:
                return torch.baddbmm(score_bias, score_table, hidden[..., None])[..., 0]

        else:  # ... and 6x slower than a vector dot product for 32 (1 thread, paper size)

            def score(hidden: torch.Tensor) -> torch.Tensor:
                return torch.linalg.vecdot(score_table, hidden[:, None]) + score_bias[..., 0]

        codes = []
        for i in range(time_codes.shape[1]):
            weights = torch.softmax(score(h_gen), dim=-1)  # (B, L)
            attention = torch.bmm(weights[:, None], value_table)[:, 0]  # (B, 2H)
            pre_prior, pre_gen = (self.previous(previous) + attention).split(h, dim=-1)
            time_code = time_codes[:, i]
            inputs = F.leaky_relu(self.prior_norm(pre_prior), 0.2) + time_code
            new_prior = gru_update(self.prior_gates(inputs), prior_hidden, h_prior)
            next_prior_hidden, mean, logvar = self.prior_state(new_prior).split(
                [3 * h, z_size, z_size], dim=-1
            )
            z = mean + torch.exp(0.5 * logvar) * noise[:, i]
            inputs = F.leaky_relu(self.generator_norm(pre_gen + self.latent(z)), 0.2) + time_code
            new_gen = gru_update(self.generator_gates(inputs), gen_hidden, h_gen)
            next_gen_hidden, first = self.generator_state(new_gen).split([3 * h, h], dim=-1)
            code = self.output_last(F.leaky_relu(self.output_norm(first), 0.2))
            codes.append(code)
            if lengths is not None:  # an item's state stops after its last step
                active = (i < lengths)[:, None]
                new_prior, new_gen = (
                    torch.where(active, new_prior, h_prior),
                    torch.where(active, new_gen, h_gen),
                )
                code = torch.where(active, code, previous)
                next_prior_hidden = torch.where(active, next_prior_hidden, prior_hidden)
                next_gen_hidden = torch.where(active, next_gen_hidden, gen_hidden)
            h_prior, h_gen, previous = new_prior, new_gen, code
            prior_hidden, gen_hidden = next_prior_hidden, next_gen_hidden
        final = state._replace(
            prior=h_prior, generator=h_gen, previous_code=previous, posterior=None
        )
        return final, torch.stack(codes, dim=1)


def _plan_key(vae: TemporalVAE) -> tuple:
    """Changes whenever a parameter is replaced, moved or updated in place."""
    return tuple((p.data_ptr(), p._version, p.dtype, p.device) for p in vae.parameters())


# model -> (key, plan): outside the model, so neither its state dict nor a deep copy holds it
_PLANS: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def generation_plan(vae: TemporalVAE) -> GenerationPlan | None:
    """``vae``'s :class:`GenerationPlan`, built on first use and kept until a parameter
    changes; one set by :func:`set_generation_plan` is kept for good. None for a model whose
    layers are no longer float Linears and GRU cells without a plan set (a copy of a
    quantised model): it generates through :meth:`TemporalVAE.rollout`."""
    cached = _PLANS.get(vae)
    if cached is not None and (cached[0] is None or cached[0] == _plan_key(vae)):
        return cached[1]
    if not (isinstance(vae.prior.cell, nn.GRUCell) and isinstance(vae.query, nn.Linear)):
        return None
    plan = GenerationPlan(vae)
    _PLANS[vae] = (_plan_key(vae), plan)
    return plan


def set_generation_plan(vae: TemporalVAE, plan: GenerationPlan) -> None:
    """Generate ``vae``'s samples with ``plan`` from now on (a quantised model's)."""
    _PLANS[vae] = (None, plan)
