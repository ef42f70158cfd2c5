"""The temporal VAE's training pass, rearranged for speed: the arithmetic of
:meth:`t2m.models.temporal_vae.TemporalVAE.rollout` over :meth:`~TemporalVAE.step`, tested equal
to it (``tests/test_temporal_vae.py``, ``tests/test_fast_recurrence.py``).
:func:`t2m.accel.accelerate` makes it a model's training pass
(:meth:`TemporalVAE.set_training_pass`); generation has its own plans (:mod:`t2m.accel.plans`).

The rearrangements, each the same sums in another order:

1. Split projections. The blocks' input Linears act on concatenations [previous code, current
   code, attention, z]. Their weight matrices are split by input part and the prior's,
   posterior's and generator's rows stacked (3H, .), so the parts known before the loop (the
   current codes, the previous codes under teacher forcing) are projected for all steps in one
   matrix product, and the rest in one product per part per step instead of one per block.
2. Stacked state readers. Each GRU state is read by one product right after it is computed:
   the generator's by the next step's attention query and hidden gates (and, free-running, this
   step's output head), the posterior's by its next hidden gates and this step's Gaussian, the
   prior's by its next hidden gates.
3. One autograd node for the loop (:class:`_Recurrence`): the forward runs without recording a
   graph; the backward runs the steps in reverse with the gradients written out (GRU, LayerNorm,
   LeakyReLU, attention), and each weight's gradient is one (O, S*B) x (S*B, I) product over all
   steps instead of S thin ones. Every product in the loop runs through weights packed once per
   sequence for oneDNN on a CPU (its transpose too, for the input gradients;
   :class:`t2m.accel.packed.StepProduct`).
4. What the loop does not feed back runs once over all steps outside it: the prior's input path
   (its GRU alone stays a loop, of its own) and Gaussian; the output head under teacher
   forcing.

Measured (one process, interleaved with the previous version, CPU time, one thread): 1 and 4
with per-product autograd nodes took 0.79-0.82x of the plain step at paper size; 2, 3 and the
prior's loop of its own took 0.78-0.85x of that at demo size.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING, NamedTuple

import torch
import torch.nn.functional as F
from torch import nn

from t2m.accel.onednn import matmul
from t2m.accel.packed import StepProduct, weight_gradient

if TYPE_CHECKING:
    from t2m.models.temporal_vae import TemporalVAE


def _gru_forward(
    input_gates: torch.Tensor, hidden_gates: torch.Tensor, hidden: torch.Tensor
) -> tuple[torch.Tensor, tuple[torch.Tensor, ...]]:
    """The GRU cell (as ``nn.GRUCell``) from its input and hidden gate pre-activations (B, 3H)
    -> (next hidden (B, H), what :func:`_gru_backward` needs)."""
    size = hidden.shape[-1]
    gates = torch.sigmoid(input_gates[:, : 2 * size] + hidden_gates[:, : 2 * size])
    reset, update = gates.split(size, dim=-1)
    hidden_n = hidden_gates[:, 2 * size :]
    candidate = torch.tanh(torch.addcmul(input_gates[:, 2 * size :], reset, hidden_n))
    return candidate + update * (hidden - candidate), (gates, hidden_n, candidate, hidden)


def _gru_backward(
    saved: tuple[torch.Tensor, ...], grad: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Gradient (B, H) of :func:`_gru_forward`'s next hidden -> gradients of its input gates
    (B, 3H), hidden gates (B, 3H) and hidden (B, H)."""
    gates, hidden_n, candidate, hidden = saved
    reset, update = gates.split(hidden.shape[-1], dim=-1)
    grad_hidden = grad * update
    grad_n = (grad - grad_hidden) * (1 - candidate * candidate)  # tanh's input
    grad_rz = torch.cat([grad_n * hidden_n, grad * (hidden - candidate)], dim=-1)
    grad_rz = grad_rz * gates * (1 - gates)  # the sigmoids' inputs
    grad_input = torch.cat([grad_rz, grad_n], dim=-1)
    return grad_input, torch.cat([grad_rz, grad_n * reset], dim=-1), grad_hidden


def _norm_forward(
    inputs: torch.Tensor, weight: torch.Tensor, bias: torch.Tensor, eps: float
) -> tuple[torch.Tensor, tuple[torch.Tensor, ...]]:
    """``leaky_relu(layer_norm(inputs), 0.2)`` -> (it, what :func:`_norm_backward` needs)."""
    normed, mean, rstd = torch.native_layer_norm(inputs, (inputs.shape[-1],), weight, bias, eps)
    return F.leaky_relu(normed, 0.2), (inputs, mean, rstd, normed, weight, bias)


def _norm_backward(
    grad: torch.Tensor, saved: tuple[torch.Tensor, ...], parameter_grads: list
) -> torch.Tensor:
    """Gradient of :func:`_norm_forward`'s output -> of its inputs; adds the LayerNorm's weight
    and bias gradients to ``parameter_grads`` (a list of two, None before the first)."""
    inputs, mean, rstd, normed, weight, bias = saved
    grad = torch.ops.aten.leaky_relu_backward(grad, normed, 0.2, False)
    grad_inputs, grad_weight, grad_bias = torch.ops.aten.native_layer_norm_backward(
        grad, inputs, (inputs.shape[-1],), mean, rstd, weight, bias, [True, True, True]
    )
    for k, value in enumerate((grad_weight, grad_bias)):
        parameter_grads[k] = value if parameter_grads[k] is None else parameter_grads[k] + value
    return grad_inputs


class _Loop(NamedTuple):
    """What :class:`_Recurrence` reads besides the tensors it differentiates."""

    mask_bias: torch.Tensor  # (B, L) 0 on words, -inf on padding
    time_codes: torch.Tensor  # (B, S, H)
    noise: torch.Tensor  # (B, S, Z)
    previous_code: torch.Tensor  # (B, C) the code fed to the first step (free-running)
    teacher_forcing: bool
    norm_eps: tuple[float, ...]  # prior, posterior, generator, output head LayerNorm epsilons
    dtype: torch.dtype  # of the products
    work: torch.dtype  # of everything else


# _Recurrence's weights, in order: (3H, A) the three input Linears' rows read by the attention
# vector; (H, Z) the generator's rows read by z; free-running only (else None): (3H, C) the rows
# read by the previous code and the three biases (3H,); LayerNorm weight and bias of the prior,
# posterior, generator and (free-running) output head; GRU weight_ih (3H, H) and bias_ih of the
# prior, posterior, generator; the state readers (O, H) and biases of the prior (its hidden
# gates), posterior (+ this step's mean and log-variance), generator (attention query + hidden
# gates, free-running + the output head's first Linear); free-running: the output head's last
# Linear (C, H) and bias.
WEIGHTS = (
    "attention latent previous input_bias prior_norm prior_norm_bias posterior_norm "
    "posterior_norm_bias generator_norm generator_norm_bias output_norm output_norm_bias "
    "prior_gates prior_gates_bias posterior_gates posterior_gates_bias generator_gates "
    "generator_gates_bias prior_reader prior_reader_bias posterior_reader posterior_reader_bias "
    "generator_reader generator_reader_bias last last_bias"
).split()
BLOCKS = ("prior", "posterior", "generator")


def _step_products(
    w: dict[str, torch.Tensor | None], dtype: torch.dtype, work: torch.dtype, forced: bool
) -> tuple[dict[str, StepProduct], dict[str, list[torch.Tensor]]]:
    """The loop's products (:class:`StepProduct`: the attention and z projections, each block's
    gates and state reader; free-running, the previous code's projection and the output head's
    last Linear, forward only) and the LayerNorm weights and biases in ``work``."""
    products = {name: StepProduct(w[name], None, dtype, work) for name in ("attention", "latent")}
    for name in ("gates", "reader"):
        for block in BLOCKS:
            key = f"{block}_{name}"
            products[key] = StepProduct(w[key], w[key + "_bias"], dtype, work)
    norms = {
        block: [w[f"{block}_norm"].to(work), w[f"{block}_norm_bias"].to(work)]
        for block in (*BLOCKS, "output")
        if w[f"{block}_norm"] is not None
    }
    if not forced:
        products["previous"] = StepProduct(
            w["previous"], w["input_bias"], dtype, work, backward=False
        )
        products["last"] = StepProduct(w["last"], w["last_bias"], dtype, work, backward=False)
    return products, norms


def _prior_forward(
    pre: torch.Tensor,
    state: torch.Tensor,
    loop: _Loop,
    products: dict[str, StepProduct],
    norms: dict[str, list[torch.Tensor]],
    kept: dict[str, list],
    read: list[torch.Tensor],
) -> list[torch.Tensor]:
    """The prior's states (B, H) of every step from its input pre-activations (B, S, H) and
    initial state: its input path for all steps at once, then its GRU over the steps. Keeps
    what the backward needs in ``kept`` and the states its reader reads in ``read``."""
    inputs, kept["norm_prior"] = _norm_forward(pre, *norms["prior"], loop.norm_eps[0])
    kept["inputs_prior"] = inputs = inputs + loop.time_codes.to(loop.work)  # (B, S, H)
    input_gates = products["prior_gates"](inputs.flatten(0, 1)).view(*inputs.shape[:2], -1)
    prior, steps, states = state, loop.time_codes.shape[1], []
    prior_gates = products["prior_reader"](prior)
    for i in range(steps):
        prior, saved = _gru_forward(input_gates[:, i], prior_gates, prior)
        kept["gru_prior"].append(saved)
        states.append(prior)
        if i + 1 < steps:
            read.append(prior)
            prior_gates = products["prior_reader"](prior)
    return states


class _Recurrence(torch.autograd.Function):
    """The training loop of :func:`fast_forward` as one autograd node. The forward runs the
    steps without recording a graph and keeps what the backward needs; the backward runs them
    in reverse with the gradients written out (GRU, LayerNorm, attention; :class:`_Backward`),
    and each weight's gradient is one product over all steps. Autograd's graph of the loop held
    about 60 nodes per step; the engine's bookkeeping of them was much of a demo-size step's
    time.

    Inputs: a :class:`_Loop`; keys and values (B, L, A); the posterior's projected current codes
    (B, S, H); under teacher forcing the projected previous codes (B, S, 3H), bias included,
    else None; the initial prior, posterior and generator states (B, H); the weights named by
    :data:`WEIGHTS` (None where unused). Outputs: prior states (B, S, H); generator states
    (B, S, H) under teacher forcing, else the predicted codes (B, S, C); the posterior's mean
    and log-variance (B, S, Z).
    """

    @staticmethod
    def forward(ctx, loop, keys, values, current, previous_all, *tensors):
        with torch.autocast(keys.device.type, enabled=False):
            return _Recurrence._forward(ctx, loop, keys, values, current, previous_all, *tensors)

    @staticmethod
    def _forward(ctx, loop, keys, values, current, previous_all, *tensors):
        dtype, work, forced = loop.dtype, loop.work, loop.teacher_forcing
        ctx.dtypes = [
            None if t is None else t.dtype for t in (keys, values, current, previous_all, *tensors)
        ]
        states = [h.to(work) for h in tensors[:3]]
        w = dict(zip(WEIGHTS, tensors[3:], strict=True))
        attention_size = keys.shape[-1]
        keys, values = keys.to(work) * attention_size**-0.5, values.to(work)  # keys scaled
        hidden, steps = states[0].shape[-1], loop.time_codes.shape[1]
        latent_size, gate_size = loop.noise.shape[-1], 3 * hidden
        products, norms = _step_products(w, dtype, work, forced)
        generator_parts = [attention_size, gate_size] + ([] if forced else [hidden])
        time_codes = loop.time_codes.to(work).unbind(1)
        noise = loop.noise.to(work).unbind(1)
        current = current.to(work).unbind(1)
        if forced:
            previous_all = previous_all.to(work).unbind(1)
        # what the backward needs, per step; the readers' inputs (each state, the initial one
        # and after the steps), per block
        kept = {name: [] for name in ("query", "weights", "attention", "previous", "z", "std")}
        kept.update({f"{name}_{b}": [] for name in ("inputs", "gru", "norm") for b in BLOCKS})
        kept["head"], kept["head_inputs"] = [], []
        read = {block: [state] for block, state in zip(BLOCKS, states, strict=True)}
        posterior_gates = products["posterior_reader"](states[1])[:, :gate_size]
        query, generator_gates = products["generator_reader"](states[2]).split(
            generator_parts, dim=-1
        )[:2]
        previous = loop.previous_code
        outputs = {name: [] for name in ("prior", "second", "mean", "logvar")}
        prior_inputs = []

        def block(name, preactivation, time_code, hidden_gates, state):
            inputs, saved = _norm_forward(
                preactivation, *norms[name], loop.norm_eps[BLOCKS.index(name)]
            )
            inputs = inputs + time_code
            kept[f"norm_{name}"].append(saved)
            kept[f"inputs_{name}"].append(inputs)
            new, saved = _gru_forward(products[f"{name}_gates"](inputs), hidden_gates, state)
            kept[f"gru_{name}"].append(saved)
            return new

        for i in range(steps):
            scores = torch.linalg.vecdot(keys, query[:, None]) + loop.mask_bias
            weights = torch.softmax(scores, dim=-1)  # (B, L)
            attention = torch.bmm(weights[:, None], values)[:, 0]  # (B, A)
            kept["query"].append(query)
            kept["weights"].append(weights)
            kept["attention"].append(attention)
            if forced:
                pre = previous_all[i] + products["attention"](attention)
            else:
                kept["previous"].append(previous)
                pre = products["previous"](previous) + products["attention"](attention)
            pre_prior, pre_post, pre_gen = pre.split(hidden, dim=-1)
            post = block(
                "posterior", pre_post + current[i], time_codes[i], posterior_gates, states[1]
            )
            read["posterior"].append(post)
            posterior_gates, mean, logvar = products["posterior_reader"](post).split(
                [gate_size, latent_size, latent_size], dim=-1
            )
            prior_inputs.append(pre_prior)
            std = torch.exp(0.5 * logvar)
            z = torch.addcmul(mean, std, noise[i])
            kept["z"].append(z)
            kept["std"].append(std)
            generator = block(
                "generator",
                pre_gen + products["latent"](z),
                time_codes[i],
                generator_gates,
                states[2],
            )
            states[1:] = post, generator
            outputs["mean"].append(mean)
            outputs["logvar"].append(logvar)
            if forced:
                outputs["second"].append(generator)
                if i + 1 < steps:
                    read["generator"].append(generator)
                    query, generator_gates = products["generator_reader"](generator).split(
                        generator_parts, dim=-1
                    )
            else:  # the next step needs this code now
                read["generator"].append(generator)
                query, generator_gates, first = products["generator_reader"](generator).split(
                    generator_parts, dim=-1
                )
                head, saved = _norm_forward(first, *norms["output"], loop.norm_eps[3])
                kept["head"].append(saved)
                kept["head_inputs"].append(head)
                previous = products["last"](head)
                outputs["second"].append(previous)
        # the prior: nothing in the loop reads it
        outputs["prior"] = _prior_forward(
            torch.stack(prior_inputs, dim=1), states[0], loop, products, norms, kept, read["prior"]
        )
        ctx.loop, ctx.products, ctx.kept, ctx.read, ctx.norms = loop, products, kept, read, norms
        ctx.keys, ctx.values = keys, values
        ctx.present = [t is not None for t in tensors[3:]]
        second = torch.stack(outputs["second"], dim=1)
        return (
            torch.stack(outputs["prior"], dim=1),
            second if forced else second.to(dtype),
            torch.stack(outputs["mean"], dim=1).to(dtype),
            torch.stack(outputs["logvar"], dim=1).to(dtype),
        )

    @staticmethod
    @torch.autograd.function.once_differentiable
    def backward(ctx, *grads):
        with torch.autocast(ctx.keys.device.type, enabled=False):
            return _Backward(ctx, *grads).run()


class _Backward:
    """:class:`_Recurrence`'s backward, in the order it runs: the output head (free-running),
    the prior's GRU through time and its input path (:meth:`prior`), the steps in reverse
    (:meth:`step`: the generator, the latent, the posterior, the attention), the readers' calls
    on the initial states (:meth:`initial_states`), then one product per weight over all steps
    (:meth:`weight_gradients`). Gradients of step i + 1's inputs are carried between steps:
    each block's state (through its GRU alone, ``carry``), the hidden gates its reader made
    (``next_gates``) and the attention query (``next_query``)."""

    def __init__(self, ctx, grad_prior, grad_second, grad_mean, grad_logvar):
        self.ctx, loop = ctx, ctx.loop
        self.loop, self.products, self.kept, self.norms = loop, ctx.products, ctx.kept, ctx.norms
        self.keys, self.values, self.work = ctx.keys, ctx.values, loop.work
        self.forced = loop.teacher_forcing
        self.steps, self.batch = len(self.kept["z"]), self.keys.shape[0]
        self.hidden = loop.time_codes.shape[-1]
        self.attention_size, self.latent_size = self.keys.shape[-1], loop.noise.shape[-1]
        self.grad_prior = self.given(grad_prior, self.hidden).unbind(1)
        self.grad_mean = self.given(grad_mean, self.latent_size).unbind(1)
        self.grad_logvar = self.given(grad_logvar, self.latent_size).unbind(1)
        self.grad_second = grad_second
        self.noise = loop.noise.to(self.work).unbind(1)
        self.result = {}
        self.norm_grads = {name: [None, None] for name in self.norms}
        self.reader_grads = {block: [] for block in BLOCKS}  # per call, from the last one back
        self.gate_grads = {block: [] for block in BLOCKS}
        self.pre_grads, self.latent_grads, self.current_grads = [], [], []
        self.score_grads, self.attention_grads = [], []
        self.carry = dict.fromkeys(BLOCKS)
        self.next_gates = dict.fromkeys(BLOCKS)
        self.next_query = None

    def given(self, grad: torch.Tensor | None, size: int) -> torch.Tensor:
        """An output's gradient (B, S, size) in the working dtype, zeros where none came."""
        if grad is None:
            return self.keys.new_zeros(self.batch, self.steps, size)
        return grad.to(self.work)

    def zeros(self, size: int) -> torch.Tensor:
        return self.keys.new_zeros(self.batch, size)

    def run(self) -> tuple:
        """The gradients of :meth:`_Recurrence.forward`'s inputs, in its order."""
        if self.forced:
            self.grad_states = self.given(self.grad_second, self.hidden).unbind(1)
        else:
            self.output_head()
        grad_pre_prior = self.prior()
        for i in reversed(range(self.steps)):
            self.step(i, grad_pre_prior[i])
        initial = self.initial_states()
        return self.weight_gradients(initial)

    def output_head(self) -> None:
        """Free-running: no gradient through the fed-back codes, so the output head's backward
        runs at once for all steps; ``grad_first`` (per step) reaches the generator's reader."""
        kept, products, work = self.kept, self.products, self.work
        grad_codes = self.given(self.grad_second, products["last"].weight.shape[0])  # (B, S, C)
        head_inputs = torch.stack(kept["head_inputs"], dim=1)  # (B, S, H)
        self.result["last"] = matmul(grad_codes.flatten(0, 1).t(), head_inputs.flatten(0, 1))
        self.result["last_bias"] = grad_codes.sum((0, 1))
        saved = [torch.stack(parts, dim=1) for parts in list(zip(*kept["head"]))[:4]]
        saved += self.norms["output"]
        grad_head = grad_codes @ products["last"].weight.to(work)
        self.grad_first = _norm_backward(grad_head, saved, self.norm_grads["output"]).unbind(1)

    def state_grad(self, block: str, direct, call_grad):
        """Gradient of a state after step i: its reader's call after the step (if made),
        the next step's GRU, and ``direct`` (an output's gradient)."""
        grad = direct
        if self.carry[block] is not None:
            grad = self.carry[block] if grad is None else grad + self.carry[block]
        if call_grad is not None:
            self.reader_grads[block].append(call_grad)
            through = self.products[f"{block}_reader"].backward(call_grad)
            grad = through if grad is None else grad + through
        return self.zeros(self.hidden) if grad is None else grad

    def block_backward(self, block: str, i: int, grad_state: torch.Tensor) -> torch.Tensor:
        """Gradient of the state after step i -> of the block's preactivation (B, H); keeps
        the gradients of its hidden gates and of the state before the step."""
        grad_gates, self.next_gates[block], self.carry[block] = _gru_backward(
            self.kept[f"gru_{block}"][i], grad_state
        )
        self.gate_grads[block].append(grad_gates)
        grad = self.products[f"{block}_gates"].backward(grad_gates)
        return _norm_backward(grad, self.kept[f"norm_{block}"][i], self.norm_grads[block])

    def prior(self) -> tuple[torch.Tensor, ...]:
        """The prior (nothing in the loop reads it): its GRU backward through time, then its
        input path for all steps at once -> the gradient of its preactivation per step."""
        kept, steps, batch, hidden = self.kept, self.steps, self.batch, self.hidden
        grad_gates = []
        for i in reversed(range(steps)):
            call = self.next_gates["prior"] if i + 1 < steps else None
            grad, self.next_gates["prior"], self.carry["prior"] = _gru_backward(
                kept["gru_prior"][i], self.state_grad("prior", self.grad_prior[i], call)
            )
            grad_gates.append(grad)
        grad_gates = torch.stack(grad_gates[::-1], dim=1).flatten(0, 1)  # (B*S, 3H)
        inputs = kept["inputs_prior"].flatten(0, 1)
        self.result["prior_gates"], self.result["prior_gates_bias"] = weight_gradient(
            [grad_gates], [inputs]
        )
        grad_inputs = self.products["prior_gates"].backward(grad_gates).view(batch, steps, hidden)
        return _norm_backward(grad_inputs, kept["norm_prior"], self.norm_grads["prior"]).unbind(1)

    def step(self, i: int, grad_pre_prior: torch.Tensor) -> None:
        """Step i in reverse: the generator's state and block, z, the posterior's state and
        block, then the attention (its query's gradient goes to step i - 1's reader)."""
        kept, products, hidden = self.kept, self.products, self.hidden
        # the generator's reader after step i: next query and hidden gates, this step's head
        call = None
        if not self.forced or i + 1 < self.steps:
            call = [
                self.zeros(self.attention_size) if self.next_query is None else self.next_query,
                self.zeros(3 * hidden)
                if self.next_gates["generator"] is None
                else self.next_gates["generator"],
            ]
            call = torch.cat(call + ([] if self.forced else [self.grad_first[i]]), dim=-1)
        grad = self.state_grad("generator", self.grad_states[i] if self.forced else None, call)
        grad_pre_gen = self.block_backward("generator", i, grad)
        self.latent_grads.append(grad_pre_gen)
        grad_z = products["latent"].backward(grad_pre_gen)
        grad_mean = grad_z + self.grad_mean[i]
        grad_logvar = torch.addcmul(
            self.grad_logvar[i], grad_z, kept["std"][i] * self.noise[i], value=0.5
        )
        next_post = self.next_gates["posterior"]
        call = [
            self.zeros(3 * hidden) if next_post is None else next_post,
            grad_mean,
            grad_logvar,
        ]
        grad = self.state_grad("posterior", None, torch.cat(call, dim=-1))
        grad_pre_post = self.block_backward("posterior", i, grad)
        self.current_grads.append(grad_pre_post)
        grad_pre = torch.cat([grad_pre_prior, grad_pre_post, grad_pre_gen], dim=-1)
        self.pre_grads.append(grad_pre)
        grad_attention = products["attention"].backward(grad_pre)  # (B, A)
        self.attention_grads.append(grad_attention)
        grad_weights = torch.linalg.vecdot(self.values, grad_attention[:, None])  # (B, L)
        grad_scores = torch.ops.aten._softmax_backward_data(
            grad_weights, kept["weights"][i], -1, self.work
        )
        self.score_grads.append(grad_scores)
        self.next_query = torch.bmm(grad_scores[:, None], self.keys)[:, 0]

    def initial_states(self) -> list[torch.Tensor]:
        """The readers' calls on the initial states -> the gradients of those states."""
        next_gates, forced = self.next_gates, self.forced
        generator_call = [self.next_query, next_gates["generator"]]
        generator_call += [] if forced else [self.zeros(self.hidden)]
        posterior_call = [next_gates["posterior"], self.zeros(2 * self.latent_size)]
        return [
            self.state_grad("prior", None, next_gates["prior"]),
            self.state_grad("posterior", None, torch.cat(posterior_call, -1)),
            self.state_grad("generator", None, torch.cat(generator_call, dim=-1)),
        ]

    def weight_gradients(self, initial: list[torch.Tensor]) -> tuple:
        """Per-sequence tensors and weights, one product each over all steps, and every
        gradient in the order and dtypes of the forward's inputs."""
        kept, result, ctx = self.kept, self.result, self.ctx
        weights = torch.stack(kept["weights"], dim=1)  # (B, S, L)
        grad_values = weights.transpose(1, 2) @ torch.stack(self.attention_grads[::-1], dim=1)
        grad_keys = torch.stack(self.score_grads[::-1], dim=1).transpose(1, 2) @ torch.stack(
            kept["query"], dim=1
        )
        pre_grads = self.pre_grads[::-1]
        result["attention"] = weight_gradient(pre_grads, kept["attention"])[0]
        result["latent"] = weight_gradient(self.latent_grads[::-1], kept["z"])[0]
        grad_previous_all = None
        if self.forced:
            grad_previous_all = torch.stack(pre_grads, dim=1)
        else:
            result["previous"], result["input_bias"] = weight_gradient(pre_grads, kept["previous"])
        for block in BLOCKS:
            if block != "prior":
                result[f"{block}_gates"], result[f"{block}_gates_bias"] = weight_gradient(
                    self.gate_grads[block][::-1], kept[f"inputs_{block}"]
                )
            result[f"{block}_reader"], result[f"{block}_reader_bias"] = weight_gradient(
                self.reader_grads[block][::-1], ctx.read[block]
            )
        for name, (weight_grad, bias_grad) in self.norm_grads.items():
            result[f"{name}_norm"], result[f"{name}_norm_bias"] = weight_grad, bias_grad
        grads = [
            grad_keys * self.attention_size**-0.5,
            grad_values,
            torch.stack(self.current_grads[::-1], dim=1),
            grad_previous_all,
            *initial,
            *(
                result[name] if present else None
                for name, present in zip(WEIGHTS, ctx.present, strict=True)
            ),
        ]
        return (
            None,
            *(g if g is None else g.to(d) for g, d in zip(grads, ctx.dtypes, strict=True)),
        )


def split_input_weights(vae: TemporalVAE) -> dict[str, torch.Tensor]:
    """The blocks' input-Linear weights split by input part; prior / posterior / generator rows
    stacked (3H, .) for the parts all three read."""
    c, a = vae.code_size, vae.config.attention_size
    blocks = (vae.prior.input, vae.posterior.input, vae.generator.input)
    prior, post, gen = (block.weight for block in blocks)
    return {
        "previous": torch.cat([prior[:, :c], post[:, :c], gen[:, :c]]),  # (3H, C)
        "attention": torch.cat([prior[:, c:], post[:, 2 * c :], gen[:, c : c + a]]),  # (3H, A)
        "bias": torch.cat([block.bias for block in blocks]),  # (3H,)
        "current": post[:, c : 2 * c],  # (H, C), posterior only
        "latent": gen[:, c + a :],  # (H, Z), generator only
    }


def _readers(vae: TemporalVAE, teacher_forcing: bool) -> dict[str, list[nn.Module]]:
    """Per block, the layers that read its state, in the order their rows are stacked: the
    prior's hidden gates; the posterior's hidden gates and Gaussian; the generator's attention
    query, hidden gates and (free-running) the output head's first Linear."""
    gaussian = vae.posterior_gaussian
    generator = [vae.query, vae.generator.cell] + ([] if teacher_forcing else [vae.output[0]])
    return {
        "prior": [vae.prior.cell],
        "posterior": [vae.posterior.cell, gaussian.mean, gaussian.logvar],
        "generator": generator,
    }


def _stacked(layers: Sequence[nn.Module]) -> tuple[torch.Tensor, torch.Tensor]:
    """The weights (O_i, I) and biases of Linears or GRU cells' hidden products, stacked."""
    weights = [
        layer.weight_hh if isinstance(layer, nn.GRUCell) else layer.weight for layer in layers
    ]
    biases = [layer.bias_hh if isinstance(layer, nn.GRUCell) else layer.bias for layer in layers]
    return torch.cat(weights), torch.cat(biases)


def _loop_weights(
    vae: TemporalVAE, weights: dict[str, torch.Tensor], teacher_forcing: bool
) -> dict[str, torch.Tensor | None]:
    """The tensors :class:`_Recurrence` reads, by the names of :data:`WEIGHTS` (None where
    unused): the split input weights, the LayerNorms', the GRUs' input gates and the stacked
    state readers."""
    free = not teacher_forcing
    tensors = dict.fromkeys(WEIGHTS)
    tensors.update(attention=weights["attention"], latent=weights["latent"])
    if free:
        tensors.update(previous=weights["previous"], input_bias=weights["bias"])
    _, output_norm, _, last = vae.output
    norms = {
        "prior": vae.prior.norm,
        "posterior": vae.posterior.norm,
        "generator": vae.generator.norm,
    }
    if free:
        norms["output"] = output_norm
        tensors.update(last=last.weight, last_bias=last.bias)
    for name, norm in norms.items():
        tensors[f"{name}_norm"], tensors[f"{name}_norm_bias"] = norm.weight, norm.bias
    blocks = {"prior": vae.prior, "posterior": vae.posterior, "generator": vae.generator}
    for name, layers in _readers(vae, teacher_forcing).items():
        cell = blocks[name].cell
        tensors[f"{name}_gates"], tensors[f"{name}_gates_bias"] = cell.weight_ih, cell.bias_ih
        tensors[f"{name}_reader"], tensors[f"{name}_reader_bias"] = _stacked(layers)
    return tensors


def fast_forward(
    vae: TemporalVAE,
    word_features: torch.Tensor,
    sentence: torch.Tensor,
    word_mask: torch.Tensor,
    codes: torch.Tensor,
    initial_code: torch.Tensor,
    teacher_forcing: bool,
    noise: torch.Tensor,
    time_codes: torch.Tensor | None = None,
) -> dict[str, torch.Tensor]:
    """:meth:`TemporalVAE.forward` (same arguments and results, ``noise`` required; ``time_codes``
    (B, S, H) default to those of codes that end their motion, without counts), faster:
    the loop is one :class:`_Recurrence` node; the parts known before it (the current codes,
    under teacher forcing the previous ones) are projected for all steps at once, and the heads
    the loop does not feed back (the prior's Gaussian; the output head under teacher forcing)
    run once after it."""
    batch, steps, _ = codes.shape
    weights = split_input_weights(vae)
    context = vae.word_context(word_features, word_mask)
    state = vae.initial_state(sentence, initial_code, posterior=True)
    if time_codes is None:
        snippets_left = torch.full((batch,), steps, dtype=torch.long, device=codes.device)
        time_codes = vae.time_codes(snippets_left, steps)  # (B, S, H)
    current = F.linear(codes, weights["current"])  # (B, S, H)
    previous_all = None
    if teacher_forcing:
        previous_codes = torch.cat([state.previous_code[:, None], codes[:, :-1]], dim=1)
        previous_all = F.linear(previous_codes, weights["previous"], weights["bias"])  # (B, S, 3H)
    tensors = _loop_weights(vae, weights, teacher_forcing)
    output_norm = vae.output[1]
    device_type = codes.device.type
    dtype = vae.query.weight.dtype
    work = dtype
    if torch.is_autocast_enabled(device_type):
        dtype, work = torch.get_autocast_dtype(device_type), torch.float32
    loop = _Loop(
        context.mask_bias,
        time_codes,
        noise,
        state.previous_code,
        teacher_forcing,
        tuple(
            norm.eps
            for norm in (vae.prior.norm, vae.posterior.norm, vae.generator.norm, output_norm)
        ),
        dtype,
        work,
    )
    prior_states, second, posterior_mean, posterior_logvar = _Recurrence.apply(
        loop,
        context.keys,
        context.values,
        current,
        previous_all,
        state.prior,
        state.posterior,
        state.generator,
        *(tensors[name] for name in WEIGHTS),
    )
    prior_mean, prior_logvar = vae.prior_gaussian(prior_states)
    return {
        "codes": vae.output(second) if teacher_forcing else second,
        "prior_mean": prior_mean,
        "prior_logvar": prior_logvar,
        "posterior_mean": posterior_mean,
        "posterior_logvar": posterior_logvar,
    }
