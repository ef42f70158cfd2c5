"""int8 products that cannot saturate, on any x86-64 CPU.

x86 CPUs without VNNI (AVX2: AMD Zen 1-3, Intel before Ice Lake) multiply unsigned by signed
bytes with ``vpmaddubsw``, which adds each pair of adjacent products into a saturating int16:
|a0 w0 + a1 w1| must stay <= 32767. VNNI CPUs sum into int32 and never clip, so a test that only
compares a model's output on random weights passes there and hides the clipping elsewhere.
Two kinds of test here, so the suite proves the int8 paths on whatever CPU runs it:

* the formats: the integers each path stores and feeds its kernel cannot reach the clip
  (a check of the numbers, independent of the CPU);
* the worst cases: one product with weights and inputs chosen to saturate u8 x s8 pair sums
  (every weight of a row at the row's largest magnitude, every input at the top of its range),
  run through the same nodes / layers as generation, against float64 within the error bound of
  the quantisation itself (below). Clipping errs by about half the result; the bound is about
  1% of it.

Bound for y = sum_i x_i w_i computed from quantised x and w: with per-entry rounding errors
e_x (activations) and e_w (weights), |y_q - y| <= sum_i (|x_i| e_w + |w_i| e_x + e_w e_x), plus
float32 accumulation (gamma_n sum |x_i w_i|, n u / (1 - n u), u = 2^-24). e_w is one full
quantisation step (half a step of rounding, and the clip of a block's largest value at 127
where it is negative and mapped to +128), e_x one step of the activation scale (rounding plus
the rounding of the zero point).
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest
import torch

pytest.importorskip("onnx", reason="the onnx backend's optional packages are not installed")
pytest.importorskip("onnxruntime", reason="the onnx backend's optional packages are not installed")

from t2m.accel.int8 import int8_linear
from t2m.accel.onnx import (
    DYNAMIC_WEIGHT_LEVELS,
    INT8_BLOCK,
    product_model,
    session,
    step_weights,
)

INPUTS, OUTPUTS = 256, 6
INT16_MAX = 32767
U8_MAX = 255


def worst_cases() -> tuple[np.ndarray, np.ndarray]:
    """Weights (O, I) and inputs (B, I) float32 that drive u8 x s8 pair sums to the clip:
    rows of one sign at full magnitude against inputs at the top of their range, plus a
    random row and a random input as the ordinary case."""
    rng = np.random.default_rng(0)
    weight = np.empty((OUTPUTS, INPUTS), np.float32)
    weight[0] = 1.0  # every product at the largest weight and the largest input
    weight[1] = -1.0
    weight[2] = 0.25 + rng.random(INPUTS, dtype=np.float32)  # one sign, not all largest
    weight[3] = rng.standard_normal(INPUTS, dtype=np.float32)
    weight[4, ::2], weight[4, 1::2] = 1.0, -1.0
    weight[5] = 0.0  # a zero row: scale 0 must not divide
    inputs = np.empty((4, INPUTS), np.float32)
    inputs[0] = 3.0  # all at the top of the range: u8 255 (s8 127)
    inputs[1] = rng.standard_normal(INPUTS, dtype=np.float32)
    inputs[2] = np.where(np.arange(INPUTS) % 2 == 0, 3.0, 0.0)  # range [0, 3]: zero point 0
    inputs[3] = np.where(np.arange(INPUTS) % 3 == 0, -0.5, 3.0)  # mostly at the top
    return weight, inputs


def error_bound(x: np.ndarray, w: np.ndarray, e_x: np.ndarray, e_w: np.ndarray) -> np.ndarray:
    """The bound of the module docstring, (B, O), float64. ``e_x`` (B, I) and ``e_w`` (O, I)
    are the per-entry quantisation errors allowed."""
    x, w = np.abs(x.astype(np.float64)), np.abs(w.astype(np.float64))
    n = x.shape[1]
    gamma = n * 2.0**-24 / (1 - n * 2.0**-24)
    return x @ e_w.T + e_x @ w.T + e_x @ e_w.T + gamma * (x @ w.T)


def dynamic_activation_step(x: np.ndarray) -> np.ndarray:
    """``DynamicQuantizeLinear``'s scale per row of ``x`` (B, 1): the range including 0 over
    255 (one call quantises the whole batch: its range is the batch's)."""
    top, bottom = max(float(x.max()), 0.0), min(float(x.min()), 0.0)
    return np.full((len(x), 1), (top - bottom) / U8_MAX)


def blockwise_steps(values: np.ndarray, levels: float) -> np.ndarray:
    """Per entry of ``values`` (R, I): its block of :data:`INT8_BLOCK`'s largest magnitude over
    ``levels`` (one quantisation step)."""
    rows, inputs = values.shape
    width = -(-inputs // INT8_BLOCK)
    padded = np.zeros((rows, width * INT8_BLOCK))
    padded[:, :inputs] = np.abs(values)
    largest = padded.reshape(rows, width, INT8_BLOCK).max(-1)
    return np.repeat(largest / levels, INT8_BLOCK, axis=1)[:, :inputs]


def test_batched_int8_weights_cannot_saturate_u8_s8_pair_sums():
    """The batched session's weights, as generation makes them, leave room for 255 x w pairs."""
    from t2m.accel.onnx import RowBlocks
    from t2m.accel.plans import GenerationPlan
    from t2m.config import TemporalVAEConfig, TextEncoderConfig
    from t2m.models.temporal_vae import TemporalVAE

    torch.manual_seed(0)
    config = TemporalVAEConfig(
        text=TextEncoderConfig(hidden_size=10), hidden_size=20, latent_size=6, attention_size=8
    )
    vae = TemporalVAE(12, 16, config).eval()
    step = step_weights(GenerationPlan(vae, RowBlocks.of), "blockwise").to_dynamic()
    largest = max(
        int(np.abs(step.arrays[f"{name}.weight"].astype(np.int32)).max())
        for name in step.input_sizes
    )
    assert largest == DYNAMIC_WEIGHT_LEVELS  # each row's largest weight uses the full 7 bits
    assert 2 * U8_MAX * largest <= INT16_MAX


@pytest.mark.parametrize("batch", [1, 2, 4])
@pytest.mark.parametrize("weights", ["blockwise", "dynamic"])
def test_onnx_int8_product_is_within_its_quantisation_bound(weights, batch):
    weight, inputs = worst_cases()
    inputs = inputs[:batch]
    product = session(*product_model(weight, weights), threads=1)
    result = product.run(None, {"x": inputs})[0].astype(np.float64)
    exact = inputs.astype(np.float64) @ weight.astype(np.float64).T
    if weights == "dynamic":
        e_w = np.abs(weight).max(1, keepdims=True) / DYNAMIC_WEIGHT_LEVELS * np.ones_like(weight)
        e_x = dynamic_activation_step(inputs) * np.ones_like(inputs)
    else:  # MatMulNBits, accuracy_level 4: int8 activations per block, symmetric
        e_w = blockwise_steps(weight, 128)
        e_x = blockwise_steps(inputs, 127)
    bound = error_bound(inputs, weight, e_x, e_w)
    error = np.abs(result - exact)
    worst = np.unravel_index((error - bound).argmax(), error.shape)
    assert (error <= bound).all(), (
        f"{weights} int8 product off by {error[worst]:.4g} where the bound is {bound[worst]:.4g} "
        f"(exact {exact[worst]:.4g}): the kernel saturates"
    )
    # the bound is far below what clipping costs (about half the result of row 0)
    assert bound[:, 0].max() < 0.1 * np.abs(exact[:, 0]).max()


@pytest.mark.parametrize("batch", [1, 4])
def test_torch_int8_linear_is_within_its_quantisation_bound(batch):
    """torch's dynamic int8 Linear (the torch int8 plan's products) quantises activations to
    7 bits (``reduce_range``: 0..127), so 2 x 127 x 128 = 32512 cannot clip."""
    weight, inputs = worst_cases()
    inputs = inputs[:batch]
    with warnings.catch_warnings():  # torch's deprecation of its eager int8 API
        warnings.simplefilter("ignore", UserWarning)
        linear = int8_linear([torch.from_numpy(weight)], None)
        with torch.inference_mode():
            result = linear(torch.from_numpy(inputs)).double().numpy()
    exact = inputs.astype(np.float64) @ weight.astype(np.float64).T
    e_w = np.full_like(weight, np.abs(weight).max() / 127.5, dtype=np.float64)  # per tensor
    top, bottom = max(float(inputs.max()), 0.0), min(float(inputs.min()), 0.0)
    e_x = np.full_like(inputs, (top - bottom) / 127, dtype=np.float64)  # reduce_range: 7 bits
    bound = error_bound(inputs, weight, e_x, e_w)
    error = np.abs(result - exact)
    assert (error <= bound).all(), f"torch int8 product off by {error.max():.4g}"
    assert bound[:, 0].max() < 0.1 * np.abs(exact[:, 0]).max()  # far below a clip's error
