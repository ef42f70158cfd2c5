"""Generation plans: the prior / generator step of
:meth:`t2m.models.temporal_vae.TemporalVAE.step` without the posterior, its weights rearranged
for sampling (:class:`GenerationPlan`), and the :class:`TorchPlanRollout` that holds a model's
plan (built on first use, rebuilt when a parameter changes). Tested equal to the step-by-step
rollout (``tests/test_rollouts.py``, ``tests/test_temporal_vae.py``).
"""

from __future__ import annotations

import copy
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING

import torch
import torch.nn.functional as F
from torch import nn

from t2m.accel.onednn import FastLinear
from t2m.models.temporal_vae import StepRollout

if TYPE_CHECKING:
    from t2m.models.temporal_vae import RecurrentState, TemporalVAE, WordContext


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
    linear = FastLinear(weight.shape[1], weight.shape[0], bias=bias is not None, device="meta")
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

    Built from a float model (:class:`TorchPlanRollout`). ``linear`` (a :data:`LinearFactory`)
    makes each Linear from its row blocks; :func:`t2m.accel.int8.quantize_int8` passes one that
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


FLOAT32_TOLERANCE = 1e-5
"""What a float32 plan may differ from the step by step rollout, as a share of the largest
code: the same sums in another order differ by some 1e-7 of it (a wrong weight or a stale plan
by 1e-2 and more)."""

INT8_TOLERANCE = 0.05
"""What an int8 plan may differ from the float32 step by step rollout, as a share of the
largest code: int8 rounding of weights and activations, about 2% after a dozen steps
(``tests/test_temporal_vae.py::test_int8_copy_is_close_to_float32`` derives it)."""


class TorchPlanRollout:
    """A float model's :class:`GenerationPlan` as its :class:`~t2m.models.temporal_vae.Rollout`:
    built on first use and rebuilt whenever a parameter changes (an optimiser step, ``.to``),
    so that training can go on between generations. A model whose layers are no longer float
    Linears and GRU cells (a quantised one) runs the step by step rollout."""

    tolerance = FLOAT32_TOLERANCE

    def __init__(self, vae: TemporalVAE):
        self.vae = vae
        self._key: tuple | None = None
        self._plan: GenerationPlan | None = None

    def __deepcopy__(self, memo: dict) -> TorchPlanRollout:
        """A copy of the model makes its own plan on first use (none is copied)."""
        return TorchPlanRollout(copy.deepcopy(self.vae, memo))

    def plan(self) -> GenerationPlan | None:
        """The plan of the model's weights as they are now (None: not a float model)."""
        vae = self.vae
        if self._plan is not None and self._key == _plan_key(vae):
            return self._plan
        if not (isinstance(vae.prior.cell, nn.GRUCell) and isinstance(vae.query, nn.Linear)):
            return None
        # Outside inference mode: a float32 plan makes the model's parameters views of its
        # stacked weights, and made inside inference mode (a first generation) they would become
        # inference tensors that no later autograd pass may use (an edit's noise optimisation).
        with torch.inference_mode(False):
            self._plan = GenerationPlan(vae)
        self._key = _plan_key(vae)  # after: a float32 plan makes the parameters its views
        return self._plan

    def __call__(
        self,
        state: RecurrentState,
        context: WordContext,
        time_codes: torch.Tensor,
        noise: torch.Tensor,
        lengths: torch.Tensor | None = None,
    ) -> tuple[RecurrentState, torch.Tensor]:
        plan = self.plan()
        if plan is None:
            return StepRollout(self.vae)(state, context, time_codes, noise, lengths)
        return plan(state, context, time_codes, noise, lengths)


class FixedPlanRollout:
    """A plan made once and kept (an int8 one, quantised from the float weights before the
    model itself is) as a :class:`~t2m.models.temporal_vae.Rollout`."""

    def __init__(self, vae: TemporalVAE, plan: GenerationPlan, tolerance: float):
        self.vae, self._plan, self.tolerance = vae, plan, tolerance

    def __deepcopy__(self, memo: dict) -> TorchPlanRollout:
        """A copy of the model holds no plan: it runs its own (quantised) layers step by step."""
        return TorchPlanRollout(copy.deepcopy(self.vae, memo))

    def plan(self) -> GenerationPlan:
        return self._plan

    def __call__(
        self,
        state: RecurrentState,
        context: WordContext,
        time_codes: torch.Tensor,
        noise: torch.Tensor,
        lengths: torch.Tensor | None = None,
    ) -> tuple[RecurrentState, torch.Tensor]:
        return self._plan(state, context, time_codes, noise, lengths)


def float_plan(vae: TemporalVAE) -> GenerationPlan | None:
    """The plan of ``vae``'s :class:`TorchPlanRollout`, or of a new one (None: not a float
    model)."""
    rollout = vae.generation_rollout
    if not isinstance(rollout, TorchPlanRollout):
        rollout = TorchPlanRollout(vae)
    return rollout.plan()


def generation_plan(vae: TemporalVAE) -> GenerationPlan | None:
    """The :class:`GenerationPlan` ``vae`` generates with now (None: it has no plan, or its
    rollout is not a torch plan)."""
    rollout = vae.generation_rollout
    plan = getattr(rollout, "plan", None)
    return plan() if callable(plan) else None
