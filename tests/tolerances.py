"""Float32 error bounds for the numerics tests, computed from the data instead of picked on one
machine.

Model (Higham, *Accuracy and Stability of Numerical Algorithms*, 2nd ed., 3.1 and 3.5): each
float32 operation is exact up to a relative error of at most u = 2^-24 (round to nearest), and a
sum of n products computed in *any* order, with or without fused multiply-adds, blocked or
pairwise, as any BLAS, oneDNN or vectorised ATen kernel does, satisfies

    |fl(x . w + b) - (x . w + b)| <= gamma_{n+1} (|x| . |w| + |b|),  gamma_n = n u / (1 - n u).

These bounds assume round to nearest in float32 arithmetic throughout: no bfloat16 or TF32
``fpmath`` shortcuts, no Winograd or FFT convolutions (which are not sums of the products), and
no flushed subnormals (a flush adds at most 2^-126 per term: nothing at these magnitudes). The
float64 evaluations standing for the exact values carry errors 2^-29 times smaller than the
float32 bounds; :data:`U` takes them in (u = 2^-24 + 2^-53).

Where a rigorous bound is impractical (recurrences, attention, many steps of a nonlinear state)
the tests use :func:`measured_bound`: a stated factor times the distance of a float32 evaluation
to the float64 evaluation of the same weights on the same input.
"""

from __future__ import annotations

import copy
from collections.abc import Iterable

import torch
import torch.nn.functional as F
from torch import nn

U = 2.0**-24 + 2.0**-53
"""float32's unit roundoff, plus float64's for the reference evaluations."""


def gamma(n: int, u: float = U) -> float:
    """Higham's gamma_n = n u / (1 - n u): the relative error bound of n rounded operations."""
    if n * u >= 1:
        raise ValueError(f"gamma_{n} is unbounded for u = {u}")
    return n * u / (1 - n * u)


def sin_cos_bound(angle: torch.Tensor, roundings: int) -> torch.Tensor:
    """Elementwise bound on |fl32(sin a) - sin(angle)| (or cos) where the float32 angle a is
    ``angle`` (exact, float64) computed with ``roundings`` rounded float32 products and quotients
    of exact values (2 pi rounded to float32 is one): |a - angle| <= gamma_roundings |angle|,
    sin and cos have slope at most 1, and their float32 value is within 1 ulp (ATen's Sleef
    ``u10`` kernels, glibc's sinf / cosf), at most 2u for a value in [-1, 1]."""
    return gamma(roundings) * angle.double().abs() + 2 * U


def max_abs(tensor: torch.Tensor) -> float:
    return float(tensor.detach().double().abs().max())


def max_diff(a: torch.Tensor, b: torch.Tensor) -> float:
    """The largest |a - b|, in float64."""
    return float((a.detach().double() - b.detach().double()).abs().max())


def as_float64(module: nn.Module) -> nn.Module:
    """A float64 copy of ``module`` (float32 weights convert exactly)."""
    return copy.deepcopy(module).double()


def linear_bound(
    inputs: torch.Tensor, weight: torch.Tensor, bias: torch.Tensor | None = None
) -> torch.Tensor:
    """Elementwise bound on |fl32(inputs @ weight.T + bias) - exact| for any summation order:
    gamma_{n+1} (|inputs| @ |weight|.T + |bias|), n = in_features, evaluated in float64."""
    magnitude = F.linear(inputs.double().abs(), weight.double().abs(), _abs(bias))
    return gamma(weight.shape[-1] + 1) * magnitude


def float32_pair_bound(inputs, weight, bias=None) -> torch.Tensor:
    """Bound on the distance between two float32 evaluations of the same product in any two
    orders: the sum of both sides' :func:`linear_bound` (each side within its bound of the exact
    value)."""
    return 2 * linear_bound(inputs, weight, bias)


def _abs(tensor: torch.Tensor | None) -> torch.Tensor | None:
    return None if tensor is None else tensor.detach().double().abs()


def propagated_bound(
    layers: Iterable[nn.Module],
    inputs: torch.Tensor,
    input_error: torch.Tensor | float = 0.0,
) -> tuple[torch.Tensor, torch.Tensor]:
    """(float64 output, elementwise bound on |float32 output - float64 output|) of ``layers``
    run in turn on frame-major ``inputs`` (B, T, C), as the autoencoder runs them: Conv1d and
    ConvTranspose1d over T (channels C), Linear over C, LeakyReLU / ReLU, Dropout in eval mode.

    Any float32 evaluation whose products are sums of the products in any order (module docstring)
    stays within the bound, whatever its kernels. ``input_error`` bounds |float32 inputs - inputs|
    (inputs that differ, such as codes from another encoder). Per layer, with e the incoming bound
    and y the exact incoming values: a product (n terms with the bias) adds
    |W| e + gamma_n (|W| (|y| + e) + |b|) to its own rounding; an activation of slope at most 1
    keeps e and adds gamma_2 (|f(y)| + e) for the rounded slope product.
    """
    exact = inputs.detach().double()
    error = torch.as_tensor(input_error, dtype=torch.float64).expand_as(exact).clone()
    for layer in layers:
        if isinstance(layer, nn.Dropout):
            if layer.training:
                raise ValueError("dropout in training mode has no bound")
            continue
        if isinstance(layer, (nn.LeakyReLU, nn.ReLU)):
            slope = layer.negative_slope if isinstance(layer, nn.LeakyReLU) else 0.0
            if not 0 <= slope <= 1:
                raise ValueError(f"slope {slope} is not within [0, 1]")
            exact = F.leaky_relu(exact, slope)
            error = error + gamma(2) * (exact.abs() + error)
            continue
        weight, bias = layer.weight.detach().double(), layer.bias
        if isinstance(layer, nn.Linear):
            terms = weight.shape[1] + 1

            def product(x, w, b):
                return F.linear(x, w, b)
        elif isinstance(layer, (nn.Conv1d, nn.ConvTranspose1d)):
            if isinstance(layer, nn.Conv1d):
                op, terms = F.conv1d, weight.shape[1] * weight.shape[2] + 1
            else:  # each output reads at most (K / stride rounded up) taps of each input channel
                op = F.conv_transpose1d
                taps = -(-layer.kernel_size[0] // layer.stride[0])
                terms = weight.shape[0] * taps + 1
            kwargs = dict(stride=layer.stride, padding=layer.padding, dilation=layer.dilation)
            if isinstance(layer, nn.ConvTranspose1d):
                kwargs["output_padding"] = layer.output_padding
            if layer.groups != 1 or layer.padding_mode != "zeros":
                raise ValueError("only plain zero-padded convolutions are bounded here")

            def product(x, w, b, op=op, kwargs=kwargs):
                return op(x.transpose(1, 2), w, b, **kwargs).transpose(1, 2)
        else:
            raise ValueError(f"no bound for {type(layer).__name__}")
        magnitude = product(exact.abs() + error, weight.abs(), _abs(bias))
        error = product(error, weight.abs(), None) + gamma(terms) * magnitude
        exact = product(exact, weight, None if bias is None else bias.detach().double())
    return exact, error


def measured_bound(float32: torch.Tensor, float64: torch.Tensor, factor: float) -> float:
    """``factor`` times the largest distance of a float32 evaluation to the float64 evaluation
    of the same weights on the same input, floored at the float32 rounding of the largest value
    (what any float32 result carries). For computations too deep for :func:`propagated_bound`;
    each use states why its factor covers the other evaluation's order of the sums."""
    return factor * max(max_diff(float32, float64), U * max_abs(float64))


ORDER_FACTOR = 16.0
"""How far apart two float32 evaluations of the same computation, in different summation orders,
may be in their largest distance to the float64 evaluation. An n-term sum's rounding error grows
as about sqrt(n) u times its partial sums whatever the order, but with a constant that depends on
it: one accumulator (ATen's scalar kernels, a GPU thread) against 8 or 16 vector lanes (AVX2,
AVX-512, oneDNN's blocking) differ by about sqrt(8) to sqrt(16), and the largest of a few thousand
entries scatters by up to 2 more. Observed on an AVX2 machine, with ATen's AVX2 and its scalar
(``ATEN_CPU_CAPABILITY=default``) kernels: at most 4.0 (3.9 for the release's movement encoder,
1,036 terms, against the original's recorded codes); 16 leaves a margin of 4. A real defect (a wrong or missing weight, a transposed gate, int8 weights) moves the output by
1e-3 or more against deviations of 1e-7 to 1e-5: a ratio of 100 to 10,000."""


def assert_same_rounding(
    got: torch.Tensor,
    other: torch.Tensor,
    float64: torch.Tensor,
    factor: float = ORDER_FACTOR,
    msg: str = "",
) -> None:
    """``got`` and ``other``, two float32 evaluations of the same computation (another kernel,
    machine or order; a recorded result), each within ``factor`` times the other's distance to
    ``float64``, the float64 evaluation of the same weights on the same input (distances floored
    at u max|float64|). Then |got - other| is at most (1 + factor) times the smaller distance.
    Neither side's own deviation sets its tolerance: a defect in either inflates its distance and
    fails the check against the other."""
    floor = U * max_abs(float64)
    mine = max(max_diff(got, float64), floor)
    theirs = max(max_diff(other, float64), floor)
    assert mine <= factor * theirs and theirs <= factor * mine, (
        f"{msg}: distances to float64 {mine:.3g} and {theirs:.3g} differ by more than {factor}x"
    )


U64 = 2.0**-53
"""float64's unit roundoff: the relative error of one rounded float64 +, -, *, / or sqrt."""

LIBM_ULPS = 4
"""Roundings to count for one float64 sin, cos, arctan2 or arccos in numpy: its own and glibc's
kernels are within 1 ulp, the SVML kernels of numpy's AVX-512 builds within 4 ulp."""


def float64_bound(roundings: float, magnitude: float = 1.0) -> float:
    """gamma_roundings in float64 (u = 2^-53) times ``magnitude``: the bound on the error of a
    float64 computation counted as ``roundings`` rounded operations on values of at most that
    size, in any summation order (each transcendental counted as :data:`LIBM_ULPS`)."""
    return gamma(int(-(-roundings // 1)), U64) * magnitude
