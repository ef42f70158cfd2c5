"""Matrix products through weights packed once for oneDNN (CPU, float32 or bfloat16):
:func:`linear` (``F.linear`` with its forward and input gradient in oneDNN, for the fine-tuned
decoder) and :class:`StepProduct` (a weight read at every step of a loop, packed once per
sequence, with :func:`weight_gradient` summing its gradient over all steps in one product), for
the temporal VAE's training loop (:mod:`t2m.accel.recurrence`). Elsewhere (another device or
dtype, autocast) they fall back to torch's own products.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

from t2m.accel.onednn import matmul


def packable(weight: torch.Tensor) -> bool:
    """Whether oneDNN can pack ``weight`` for its matrix product on this CPU and torch build."""
    if weight.device.type != "cpu" or not torch.backends.mkldnn.is_available():
        return False
    if weight.dtype == torch.bfloat16:
        return torch.ops.mkldnn._is_mkldnn_bf16_supported()
    return weight.dtype == torch.float32


def packed_product(
    inputs: torch.Tensor, packed: torch.Tensor, bias: torch.Tensor | None
) -> torch.Tensor:
    """``F.linear`` with a weight packed by ``torch.ops.mkldnn._reorder_linear_weight``."""
    return torch.ops.mkldnn._linear_pointwise(inputs, packed, bias, "none", [], "")


class _OneDNNLinear(torch.autograd.Function):
    """``F.linear`` (inputs (..., I), weight (O, I), bias (O,)) whose forward and input gradient
    run through oneDNN; the weight gradient is one matrix product."""

    @staticmethod
    def forward(ctx, inputs, weight, bias):
        inputs = inputs.contiguous()  # once: the backward reads it as (N, I) too
        ctx.save_for_backward(inputs, weight)
        ctx.has_bias = bias is not None
        return packed_product(inputs, weight, bias)

    @staticmethod
    @torch.autograd.function.once_differentiable
    def backward(ctx, grad):
        inputs, weight = ctx.saved_tensors
        grad = grad.contiguous()
        flat = grad.reshape(-1, grad.shape[-1])
        grad_inputs = packed_product(grad, weight.t().contiguous(), None)
        grad_weight = matmul(flat.t(), inputs.reshape(-1, inputs.shape[-1]))
        return grad_inputs, grad_weight, flat.sum(0) if ctx.has_bias else None


def linear(inputs: torch.Tensor, weight: torch.Tensor, bias: torch.Tensor | None) -> torch.Tensor:
    """``F.linear``, through oneDNN where it takes float32 weights on a CPU outside autocast: for
    shapes such as the decoder's (263, 263) output Linear over 32 x 196 frames, torch's own
    product (MKL) ran at 42 GFLOP/s on one thread, oneDNN's at 90."""
    device_type = weight.device.type
    if (
        weight.dtype != torch.float32
        or inputs.dtype != torch.float32
        or not packable(weight)
        or torch.is_autocast_enabled(device_type)
    ):
        return F.linear(inputs, weight, bias)
    return _OneDNNLinear.apply(inputs, weight, bias)


class StepProduct:
    """A weight (O, I) (and bias) read at every step of the loop: ``x W^T + b`` forward and the
    input gradient ``g W`` backward, computed in ``dtype`` (the autocast dtype, or the
    weight's), returned in ``work``. On a CPU the weight (and its transpose, for the backward)
    is packed once per sequence for oneDNN: at the loop's batch of 32, one thread, its
    products take 0.55-0.8x the time of ``F.linear``'s, and packing costs one to three."""

    def __init__(
        self,
        weight: torch.Tensor,
        bias: torch.Tensor | None,
        dtype: torch.dtype,
        work: torch.dtype,
        backward: bool = True,
    ):
        self.weight = weight.detach().to(dtype)
        self.bias = None if bias is None else bias.detach().to(dtype)
        self.dtype, self.work = dtype, work
        self.packed = self.transposed = None
        if packable(self.weight):
            self.packed = torch.ops.mkldnn._reorder_linear_weight(self.weight)
            if backward:
                transposed = self.weight.t().contiguous()
                self.transposed = torch.ops.mkldnn._reorder_linear_weight(transposed)

    def __call__(self, inputs: torch.Tensor) -> torch.Tensor:
        """(B, I) -> (B, O)."""
        if self.dtype != self.work:
            inputs = inputs.to(self.dtype)
        if self.packed is None:
            output = F.linear(inputs, self.weight, self.bias)
        else:
            output = packed_product(inputs, self.packed, self.bias)
        return output if self.dtype == self.work else output.to(self.work)

    def backward(self, grad: torch.Tensor) -> torch.Tensor:
        """(B, O) gradient of the outputs -> (B, I) gradient of the inputs."""
        if self.dtype != self.work:
            grad = grad.to(self.dtype)
        if self.transposed is None:
            output = grad @ self.weight
        else:
            output = packed_product(grad, self.transposed, None)
        return output if self.dtype == self.work else output.to(self.work)


def weight_gradient(
    grads: list[torch.Tensor], inputs: list[torch.Tensor]
) -> tuple[torch.Tensor, torch.Tensor]:
    """A step product's weight (O, I) and bias (O,) gradients from the output gradients and
    inputs of all its calls ((B, O) and (B, I) each, in call order): one (O, N*B) x (N*B, I)
    product instead of N thin ones."""
    grad = torch.cat(grads)
    return matmul(grad.t(), torch.cat(inputs).to(grad.dtype)), grad.sum(0)
