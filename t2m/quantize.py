"""Dynamic int8 quantisation for CPU inference.

:func:`quantize_int8` gives a module (a copy, or the module itself with ``inplace``) with the
weights of its Linears and GRU cells stored in int8, activations quantised on the fly at each call (one scale per tensor). At batch 1 the
temporal VAE's prior / generator step reads every weight once per snippet, so a quarter of the
bytes is faster.

The generator's input Linear reads [previous code, attention, z]; z = mean + std * noise has a
larger scale than the rest, and one activation scale for the whole concatenation costs the rest
its precision (25% more output error at paper size). So z gets a Linear of its own
(:class:`PartwiseLinear`, W [x_1, x_2] + b = W_1 x_1 + W_2 x_2 + b) before quantising; giving
every part its own gained 2% more and cost two more products per step.

A :class:`TemporalVAE` also gets its :class:`~t2m.models.fast_recurrence.GenerationPlan` (what
``generate`` runs), built from the float weights and quantised Linear by Linear before the model
itself is; the model's own quantised layers serve ``rollout`` and ``prefix_state``.

The error against float32 is tested in ``tests/test_temporal_vae.py`` and measured in
``t2m.benchmarks.sample``.
"""

from __future__ import annotations

import copy
import warnings
from collections.abc import Sequence

import torch
from torch import nn

from t2m.models.fast_recurrence import GenerationPlan, float_linear, set_generation_plan
from t2m.models.temporal_vae import TemporalVAE


class PartwiseLinear(nn.Module):
    """``linear`` on a concatenation of parts of ``sizes``, as one Linear per part, summed."""

    def __init__(self, linear: nn.Linear, sizes: Sequence[int]):
        super().__init__()
        self.sizes = list(sizes)
        self.parts = nn.ModuleList()
        for index, weight in enumerate(linear.weight.detach().split(self.sizes, dim=1)):
            with_bias = index == 0 and linear.bias is not None
            part = nn.Linear(weight.shape[1], weight.shape[0], bias=with_bias)
            part.weight = nn.Parameter(weight.clone(), requires_grad=False)
            if with_bias:
                part.bias = nn.Parameter(linear.bias.detach().clone(), requires_grad=False)
            self.parts.append(part)

    def forward(self, inputs: torch.Tensor) -> torch.Tensor:
        """(..., sum(sizes)) -> (..., out)."""
        pieces = inputs.split(self.sizes, dim=-1)
        output = self.parts[0](pieces[0])
        for part, piece in zip(self.parts[1:], pieces[1:], strict=True):
            output = output + part(piece)
        return output


def quantize_int8(module: nn.Module, inplace: bool = False) -> nn.Module:
    """``module`` with every ``nn.Linear``, ``nn.GRUCell`` and ``nn.GRU`` dynamically quantised
    to int8, a :class:`TemporalVAE`'s generator input split first (see the module docstring).

    By default a copy (the original is left as is, and the process holds both for a while:
    +41% peak memory of a paper-size generation process); ``inplace``: the module's own layers
    are replaced one by one, each float weight freed as its int8 copy is made.
    """
    from torch.ao.quantization import quantize_dynamic

    if not inplace:
        module = copy.deepcopy(module)
    with warnings.catch_warnings():
        # torch marks eager-mode quantisation as deprecated in favour of torchao (not a
        # dependency here); the API still works in the pinned torch.
        warnings.simplefilter("ignore", DeprecationWarning)
        warnings.simplefilter("ignore", UserWarning)

        def int8_linear(weight: torch.Tensor, bias: torch.Tensor | None) -> nn.Module:
            holder = nn.Sequential(float_linear(weight, bias, copy=False))  # quantising copies
            return quantize_dynamic(holder, {nn.Linear}, dtype=torch.qint8, inplace=True)[0]

        for vae in module.modules():
            if isinstance(vae, TemporalVAE):
                set_generation_plan(vae, GenerationPlan(vae, int8_linear))
                latent = vae.config.latent_size
                block = vae.generator
                block.input = PartwiseLinear(
                    block.input, (block.input.in_features - latent, latent)
                )
        return quantize_dynamic(
            module, {nn.Linear, nn.GRUCell, nn.GRU}, dtype=torch.qint8, inplace=True
        )
