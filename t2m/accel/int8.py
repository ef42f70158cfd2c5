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

A :class:`TemporalVAE` also gets its :class:`~t2m.accel.plans.GenerationPlan` (what
``generate`` runs, :meth:`~TemporalVAE.set_rollout`), built from the float weights and quantised Linear by Linear before the model
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

from t2m.accel.onednn import plain_layer
from t2m.accel.plans import INT8_TOLERANCE, FixedPlanRollout, GenerationPlan
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


def int8_linear(
    weights: Sequence[torch.Tensor], biases: Sequence[torch.Tensor] | None
) -> nn.Module:
    """The dynamically quantised Linear of the row blocks ``weights`` stacked (a
    :data:`~t2m.accel.plans.LinearFactory`), as ``quantize_dynamic`` makes it from
    the stacked float weight (the same observer, so the same scale and int8 values), but
    quantised a few rows at a time into the int8 weight: no float copy of the stack, and no
    temporaries as large as the weight (those fragmented the heap: +35 MB resident at paper
    size)."""
    from torch.ao.nn.quantized.dynamic import Linear as DynamicLinear
    from torch.ao.quantization import default_dynamic_qconfig

    observer = default_dynamic_qconfig.weight()  # per-tensor symmetric, as quantize_dynamic
    for weight in weights:
        observer(weight.detach())
    scale, zero_point = (q.item() for q in observer.calculate_qparams())
    rows = sum(weight.shape[0] for weight in weights)
    qweight = torch._empty_affine_quantized(
        (rows, weights[0].shape[1]), scale=scale, zero_point=int(zero_point), dtype=torch.qint8
    )
    start = 0
    for weight in weights:
        for part in weight.detach().split(_QUANTISE_ROWS):
            quantized = torch.quantize_per_tensor(part.float(), scale, zero_point, torch.qint8)
            qweight[start : start + part.shape[0]].copy_(quantized)
            start += part.shape[0]
    bias = None if biases is None else torch.cat([b.detach().float() for b in biases])
    linear = DynamicLinear(qweight.shape[1], qweight.shape[0], dtype=torch.qint8)
    linear.set_weight_bias(qweight, bias)
    return linear


_QUANTISE_ROWS = 128
"""Rows quantised at a time by :func:`int8_linear`."""


def _dynamic_int8_types() -> dict[type, type]:
    """Float module type -> its dynamically quantised type (what ``quantize_dynamic`` maps)."""
    import torch.ao.nn.quantized.dynamic as dynamic

    return {nn.Linear: dynamic.Linear, nn.GRUCell: dynamic.GRUCell, nn.GRU: dynamic.GRU}


def _convert(module: nn.Module, types: dict[type, type]) -> nn.Module:
    """``module`` with its Linears, GRU cells and GRUs replaced by int8 ones, in place, one at
    a time. Each float layer is freed as soon as it is replaced: torch's ``quantize_dynamic``
    leaves the replaced layers in reference cycles until a garbage collection (+84 MB of a
    paper-size generation process's peak)."""
    from torch.ao.quantization import default_dynamic_qconfig

    module = plain_layer(module)
    quantized = types.get(type(module))
    if quantized is not None:
        module.qconfig = default_dynamic_qconfig
        return quantized.from_float(module)
    for name in list(module._modules):  # names only: no list holding the float layers
        child = module._modules[name]
        if child is not None:
            module._modules[name] = _convert(child, types)
        del child
    return module


def quantize_int8(module: nn.Module, inplace: bool = False, plan: bool = True) -> nn.Module:
    """``module`` with every ``nn.Linear``, ``nn.GRUCell`` and ``nn.GRU`` dynamically quantised
    to int8 (as torch's ``quantize_dynamic`` does), a :class:`TemporalVAE`'s generator input
    split first (see the module docstring).

    By default a copy (the original is left as is, and the process holds both for a while:
    +41% peak memory of a paper-size generation process); ``inplace``: the module's own layers
    are replaced one by one, each float weight freed as its int8 copy is made. ``plan``: give
    a :class:`TemporalVAE` its int8 generation plan; False for a caller that sets its own (the
    onnx backend: 15.6 MB less at paper size, 20 MB less at the peak while quantising).
    """
    if not inplace:
        module = copy.deepcopy(module)
    with warnings.catch_warnings():
        # torch marks eager-mode quantisation as deprecated in favour of torchao (not a
        # dependency here); the API still works in the pinned torch.
        warnings.simplefilter("ignore", DeprecationWarning)
        warnings.simplefilter("ignore", UserWarning)

        for vae in module.modules():
            if isinstance(vae, TemporalVAE):
                if plan:
                    int8_plan = GenerationPlan(vae, int8_linear)
                    vae.set_rollout(FixedPlanRollout(vae, int8_plan, INT8_TOLERANCE))
                latent = vae.config.latent_size
                block = vae.generator
                block.input = PartwiseLinear(
                    block.input, (block.input.in_features - latent, latent)
                )
        return _convert(module, _dynamic_int8_types())
