"""Generation through ONNX Runtime (CPU): the prior / generator step of a
:class:`~t2m.accel.plans.GenerationPlan` as one ONNX graph, one session call per snippet.

The graph is written here from the plan's weights (``onnx.helper``, no tracing): the same sums as
:meth:`GenerationPlan.forward` (stacked products, attention through the per-sequence tables,
the GRU gates written out), except that each GRU's hidden-gate product reads the state at the
start of the step instead of being stacked with the previous step's readers of that state (the
same products; the step needs no state but the plan's three, and no first step in torch).
ONNX Runtime runs the step as about 60 kernels, with less overhead than torch's ~250 operator
calls, and its matrix-vector kernels read the weights faster.

Two precisions:

* ``fp32``: ``Gemm`` on the plan's float32 weights;
* ``int8``: symmetric int8 weights, activations quantised on the fly, in two sessions. One
  sequence runs ``MatMulNBits`` (one scale per block of :data:`INT8_BLOCK` inputs of a row, made
  by ONNX Runtime's own quantiser, int8 arithmetic); batches run ``DynamicQuantizeMatMul``
  (one scale per output, 7-bit weights so that no CPU's u8 x s8 kernel can saturate:
  :data:`DYNAMIC_WEIGHT_LEVELS`), whose kernel is the faster one from two sequences on
  (:data:`BATCHED_FROM`); its weights are made from the blockwise ones, and only when a batch
  first comes.

int8 is made from the float32 model before it is quantised (:class:`OnnxGenerationPlan`
holds no float32 weights): the products' weights, and the per-sequence tables' as torch int8
Linears (the tables run once per motion, in torch).

Its speed beside the torch plan and the original code: ``docs/performance.md``. Needs the
``onnx`` and ``onnxruntime`` packages (the ``onnx`` extra of ``setup.cfg``);
:func:`available` says whether they are installed.
"""

from __future__ import annotations

import copy
import importlib.util
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from functools import partial
from typing import TYPE_CHECKING, NamedTuple

import numpy as np
import torch

from t2m.accel.plans import (
    FLOAT32_TOLERANCE,
    INT8_TOLERANCE,
    GenerationPlan,
    TorchPlanRollout,
    float_plan,
)

if TYPE_CHECKING:
    from t2m.models.temporal_vae import RecurrentState, TemporalVAE, WordContext

ONNX_PRECISIONS = ("fp32", "int8")
"""What the ONNX Runtime backend runs (bfloat16 has no fast CPU kernels there)."""

OPSET = 17  # LayerNormalization is in the default domain from opset 17

BATCHED_FROM = 2
"""int8: batches of this many sequences or more run the ``DynamicQuantizeMatMul`` session,
smaller ones the ``MatMulNBits`` session. One step, 1 thread, paper size, ms ``MatMulNBits`` /
the batched session (measured on 2026-12-01, when it ran ``MatMulInteger``): batch 1 0.93 /
1.25, 2 5.1 / 1.3, 4 5.9 / 1.6, 8 7.8 / 2.3, 32 8.7 / 5.2 (``MatMulNBits`` has a matrix-vector
kernel for a single row only)."""

WEIGHT_FORMATS = ("fp32", "blockwise", "dynamic")
"""How :func:`step_model` stores the products' weights: float32 (``Gemm``), int8 with a scale
per block of :data:`INT8_BLOCK` inputs (``MatMulNBits``), int8 with one scale per output and
activations quantised per call (``DynamicQuantizeMatMul``)."""

MICROSOFT = "com.microsoft"  # ONNX Runtime's own operators (MatMulNBits, DynamicQuantizeMatMul)

INT8_BLOCK = 128
"""Inputs per quantisation block of ``MatMulNBits``."""

STEP_INPUTS = (
    "h_prior",  # (B, H)
    "h_gen",  # (B, H)
    "previous",  # (B, C)
    "time_code",  # (B, H)
    "noise",  # (B, Z)
    "score_table",  # (B, H, L): the plan's score table, transposed
    "score_bias",  # (B, 1, L)
    "value_table",  # (B, L, 2H)
)
STATE_INPUTS = STEP_INPUTS[:3]
"""The inputs that the next step reads from this step's outputs, in :data:`STEP_OUTPUTS`' order."""
STEP_OUTPUTS = ("new_prior", "new_gen", "code")


def available() -> bool:
    """Whether ``onnx`` and ``onnxruntime`` are installed."""
    return all(importlib.util.find_spec(name) is not None for name in ("onnx", "onnxruntime"))


def require() -> None:
    """Raise UsageError (one line, what to install) unless :func:`available`."""
    from dataset_tools.command import UsageError

    if not available():
        raise UsageError(
            "the onnx backend needs the onnx and onnxruntime packages: "
            "pip install onnx onnxruntime (or the project's [onnx] extra)"
        )


STEP_LINEARS = {
    "previous": ("previous", 0, 2),  # (2H, C): both blocks' inputs from the previous code
    "prior_gates": ("prior_gates", 0, 3),  # (3H, H)
    "prior_hidden": ("prior_state", 0, 3),  # (3H, H)
    "prior_gaussian": ("prior_state", 3, None),  # (2Z, H): mean, log-variance
    "latent": ("latent", 0, 1),  # (H, Z)
    "generator_gates": ("generator_gates", 0, 3),
    "generator_hidden": ("generator_state", 0, 3),
    "output_first": ("generator_state", 3, 4),  # (H, H)
    "output_last": ("output_last", 0, None),  # (C, H)
}
"""The step graph's products: name -> (the plan's Linear, its first row, its end row in units
of the hidden size H; None: to the last row)."""
NORMS = ("prior_norm", "generator_norm", "output_norm")

_QUANTISE_ROWS = 256
"""Output rows quantised at a time (no temporaries as large as a weight: freed, they stay in
the process's heap)."""


class RowBlocks(NamedTuple):
    """A Linear as the row blocks of its weight (O_i, I) and bias (O_i,) (or None), as
    :class:`GenerationPlan` hands them to its Linear factory: views of the model's weights,
    stacked by nobody."""

    weights: list[torch.Tensor]
    biases: list[torch.Tensor] | None

    @staticmethod
    def of(weights: Sequence[torch.Tensor], biases: Sequence[torch.Tensor] | None) -> RowBlocks:
        """A :data:`~t2m.accel.plans.LinearFactory` that keeps the blocks as they
        are (``GenerationPlan(vae, RowBlocks.of)`` copies no weight)."""
        detached = [w.detach() for w in weights]
        return RowBlocks(detached, None if biases is None else [b.detach() for b in biases])

    def rows(self, start: int, stop: int | None) -> RowBlocks:
        """Rows ``start`` to ``stop`` (None: the end) of the stacked blocks, as views."""
        weights, biases = [], []
        offset = 0
        for index, weight in enumerate(self.weights):
            low = max(start - offset, 0)
            high = weight.shape[0] if stop is None else min(weight.shape[0], stop - offset)
            if low < high:
                weights.append(weight[low:high])
                if self.biases is not None:
                    biases.append(self.biases[index][low:high])
            offset += weight.shape[0]
        return RowBlocks(weights, None if self.biases is None else biases)


def _blocks(linear: torch.nn.Module | RowBlocks) -> RowBlocks:
    """A float32 plan's Linear (or :class:`RowBlocks`) as row blocks."""
    if isinstance(linear, RowBlocks):
        return linear
    if isinstance(linear, torch.nn.Linear) and linear.weight.dtype == torch.float32:
        return RowBlocks.of([linear.weight], None if linear.bias is None else [linear.bias])
    raise ValueError("the onnx backend is made from a float32 model or generation plan")


@dataclass(frozen=True)
class StepWeights:
    """What :func:`step_model` builds a step graph from, numpy only (no ``onnx`` needed to make
    it): the plan's sizes, its LayerNorms' epsilons, each product's input size and every
    initialiser by name: ``<product>.weight`` in the format ``weights`` (:data:`WEIGHT_FORMATS`;
    ``blockwise`` adds ``.scales``, ``dynamic`` ``.scale``), ``<product>.bias`` where there is
    one, ``<norm>.weight`` and ``<norm>.bias``."""

    weights: str
    hidden_size: int
    latent_size: int
    code_size: int
    input_sizes: dict[str, int]
    epsilons: dict[str, float]
    arrays: dict[str, np.ndarray]

    def to_dynamic(self) -> StepWeights:
        """Blockwise weights as ``dynamic`` ones: each output's int8 row rescaled to one scale
        (:func:`per_output_int8` of the dequantised blocks; the rest shared)."""
        if self.weights != "blockwise":
            raise ValueError(f"to_dynamic converts blockwise weights, not {self.weights}")
        arrays = dict(self.arrays)
        for name, inputs in self.input_sizes.items():
            packed, scales = arrays.pop(f"{name}.weight"), arrays.pop(f"{name}.scales")
            arrays[f"{name}.weight"], arrays[f"{name}.scale"] = per_output_int8(
                partial(_dequantised, packed, scales, inputs), len(packed)
            )
        return replace(self, weights="dynamic", arrays=arrays)


def step_weights(plan: GenerationPlan, weights: str = "fp32") -> StepWeights:
    """The initialisers of ``plan``'s step graph with the products' weights in the format
    ``weights``: ``fp32``'s are the plan's own float32 arrays (no copy where they are
    contiguous); the int8 formats are quantised a few rows at a time (no float32 copy of a
    weight). ``plan``: a float32 plan, or one built with :meth:`RowBlocks.of`."""
    if weights not in WEIGHT_FORMATS:
        raise ValueError(f"unknown weight format {weights!r}; use one of {WEIGHT_FORMATS}")
    h = plan.hidden_size
    arrays: dict[str, np.ndarray] = {}
    input_sizes = {}

    def floats(tensor: torch.Tensor) -> np.ndarray:  # int8: copies, nothing of the model kept
        return _array(tensor) if weights == "fp32" else _array(tensor).copy()

    for name, (source, start, stop) in STEP_LINEARS.items():
        blocks = _blocks(getattr(plan, source)).rows(start * h, None if stop is None else stop * h)
        input_sizes[name] = blocks.weights[0].shape[1]
        if blocks.biases is not None:
            arrays[f"{name}.bias"] = floats(_stacked(blocks.biases))
        if weights == "fp32":
            arrays[f"{name}.weight"] = _array(_stacked(blocks.weights))
        elif weights == "blockwise":
            arrays[f"{name}.weight"], arrays[f"{name}.scales"] = blockwise_int8_rows(blocks.weights)
        else:
            rows = _stacked(blocks.weights)
            arrays[f"{name}.weight"], arrays[f"{name}.scale"] = per_output_int8(
                lambda start, stop, rows=rows: _array(rows[start:stop]), len(rows)
            )
    for name in NORMS:
        norm = getattr(plan, name)
        arrays[f"{name}.weight"] = floats(norm.weight)
        arrays[f"{name}.bias"] = floats(norm.bias)
    return StepWeights(
        weights=weights,
        hidden_size=h,
        latent_size=plan.latent_size,
        code_size=input_sizes["previous"],
        input_sizes=input_sizes,
        epsilons={name: getattr(plan, name).eps for name in NORMS},
        arrays=arrays,
    )


class _Graph:
    """Collects the nodes and initialisers of one step graph over ``step``'s arrays; each
    method adds nodes and returns the name of its output."""

    def __init__(self, step: StepWeights) -> None:
        self.step = step
        self.external: dict[str, np.ndarray] = {}
        self.nodes: list = []
        self.initializers: list = []
        self._count = 0

    def name(self, stem: str) -> str:
        self._count += 1
        return f"{stem}_{self._count}"

    def constant(self, stem: str, value: np.ndarray) -> str:
        """A small constant, stored in the model."""
        from onnx import numpy_helper

        name = self.name(stem)
        self.initializers.append(numpy_helper.from_array(np.ascontiguousarray(value), name))
        return name

    def array(self, key: str) -> str:
        """``step.arrays[key]`` as an external initialiser: :func:`session` hands ONNX Runtime
        the array itself, the model holds no copy."""
        from onnx import TensorProto, helper

        value = self.step.arrays[key]
        name = self.name(key)
        tensor = TensorProto(
            name=name, data_type=helper.np_dtype_to_tensor_dtype(value.dtype), dims=value.shape
        )
        tensor.data_location = TensorProto.EXTERNAL
        tensor.external_data.add(key="location", value=name)
        self.initializers.append(tensor)
        self.external[name] = value
        return name

    def op(self, op_type: str, inputs: list[str], outputs: int | list[str] = 1, **attrs):
        """One node; returns its output name (or the list of them for several)."""
        from onnx import helper

        names = (
            outputs if isinstance(outputs, list) else [self.name(op_type) for _ in range(outputs)]
        )
        self.nodes.append(helper.make_node(op_type, inputs, names, **attrs))
        return names[0] if len(names) == 1 else names

    def linear(self, stem: str, inputs: str) -> str:
        """The plan's Linear ``stem`` on ``inputs`` (B, I), in the step's weight format."""
        step = self.step
        bias = [self.array(f"{stem}.bias")] if f"{stem}.bias" in step.arrays else []
        if step.weights == "fp32":  # Gemm on the weight (O, I)
            return self.op("Gemm", [inputs, self.array(f"{stem}.weight"), *bias], transB=1)
        if step.weights == "dynamic":  # int8, a scale per output, activations quantised per call
            operands = [self.array(f"{stem}.weight"), self.array(f"{stem}.scale")]
            operands += ["", *bias] if bias else []  # no zero point: symmetric
            return self.op("DynamicQuantizeMatMul", [inputs, *operands], domain=MICROSOFT)
        output = self.op(  # 8 bits, symmetric, int8 arithmetic (accuracy_level 4)
            "MatMulNBits",
            [inputs, self.array(f"{stem}.weight"), self.array(f"{stem}.scales")],
            domain=MICROSOFT,
            K=step.input_sizes[stem],
            N=step.arrays[f"{stem}.weight"].shape[0],
            bits=8,
            block_size=INT8_BLOCK,
            accuracy_level=4,
        )
        return self.op("Add", [output, *bias]) if bias else output

    def layer_norm_leaky(self, stem: str, inputs: str) -> str:
        """LeakyReLU(0.2) of the plan's LayerNorm ``stem`` (last axis)."""
        scale, shift = self.array(f"{stem}.weight"), self.array(f"{stem}.bias")
        epsilon = self.step.epsilons[stem]
        normed = self.op("LayerNormalization", [inputs, scale, shift], axis=-1, epsilon=epsilon)
        return self.op("LeakyRelu", [normed], alpha=0.2)

    def split(self, inputs: str, sizes: list[int]) -> list[str]:
        """Split the last axis into parts of ``sizes``."""
        return self.op(
            "Split", [inputs, self.constant("sizes", np.array(sizes))], len(sizes), axis=-1
        )

    def gru(self, input_gates: str, hidden_gates: str, hidden: str, size: int) -> str:
        """:func:`~t2m.accel.plans.gru_update` (gates (B, 3H) as r, z, n)."""
        input_rz, input_n = self.split(input_gates, [2 * size, size])
        hidden_rz, hidden_n = self.split(hidden_gates, [2 * size, size])
        reset, update = self.split(
            self.op("Sigmoid", [self.op("Add", [input_rz, hidden_rz])]), [size, size]
        )
        candidate = self.op("Tanh", [self.op("Add", [input_n, self.op("Mul", [reset, hidden_n])])])
        change = self.op("Mul", [update, self.op("Sub", [hidden, candidate])])
        return self.op("Add", [candidate, change])


def blockwise_int8(weight: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``MatMulNBits``' 8-bit symmetric layout of ``weight`` (I, O) float32: each output's
    inputs in blocks of :data:`INT8_BLOCK` (the last zero-padded); a block's scale maps its
    entry of largest magnitude to -128, and the stored bytes are round(w / scale) + 128 (0 in
    the padding).
    Returns packed (O, blocks, INT8_BLOCK) uint8 and scales (O, blocks) float32; the same bytes
    as ONNX Runtime's ``MatMulNBitsQuantizer`` (tested)."""
    return blockwise_int8_rows([torch.from_numpy(weight.T)])


def blockwise_int8_rows(blocks: Sequence[torch.Tensor]) -> tuple[np.ndarray, np.ndarray]:
    """:func:`blockwise_int8` of the weight whose rows (outputs) are ``blocks`` (O_i, I)
    float32 stacked, a few rows at a time (no float32 copy of the stack)."""
    inputs = blocks[0].shape[1]
    outputs = sum(block.shape[0] for block in blocks)
    width = -(-inputs // INT8_BLOCK)
    packed = np.empty((outputs, width, INT8_BLOCK), np.uint8)
    scales = np.empty((outputs, width), np.float32)
    padded = np.zeros((_QUANTISE_ROWS, width * INT8_BLOCK), np.float32)
    start = 0
    for block in blocks:
        for rows in block.split(_QUANTISE_ROWS):
            chunk = padded[: len(rows)]
            chunk[:, :inputs] = rows.numpy()
            chunk = chunk.reshape(len(rows), width, INT8_BLOCK)
            largest = np.take_along_axis(chunk, np.abs(chunk).argmax(-1)[..., None], -1)[..., 0]
            scale = (largest / -128.0).astype(np.float32)  # (r, width)
            divisor = np.where(scale == 0, 1.0, scale)[..., None]
            packed[start : start + len(rows)] = np.clip(np.round(chunk / divisor), -128, 127) + 128
            scales[start : start + len(rows)] = scale
            start += len(rows)
    packed.reshape(outputs, -1)[:, inputs:] = 0  # the padding, as the quantiser leaves it
    return packed, scales


def _dequantised(
    packed: np.ndarray, scales: np.ndarray, inputs: int, start: int, stop: int
) -> np.ndarray:
    """Rows ``start:stop`` (r, inputs) float32 of blockwise int8 weights."""
    values = (packed[start:stop].astype(np.float32) - 128.0) * scales[start:stop, :, None]
    return values.reshape(len(values), -1)[:, :inputs]


DYNAMIC_WEIGHT_LEVELS = 63
"""``DynamicQuantizeMatMul``'s weights take the integers -63..63 (7 bits), not -127..127.

Its activations are quantised per call to the full unsigned range 0..255, and on x86 CPUs
without VNNI ONNX Runtime multiplies u8 by s8 with ``vpmaddubsw``, which adds each pair of
adjacent products into a *saturating* int16: |a0 w0 + a1 w1| <= 2 * 255 * |w|max must stay
<= 32767, so |w|max <= 64. With 127, a row of same-signed weights against large activations
clips the pair sums (codes off by 17-20 % of the largest at paper size on AVX2; tested by
``tests/test_onnx_backend.py::test_int8_products_cannot_saturate``). 63 leaves
2 * 255 * 63 = 32130. The cost is one bit of weight resolution (the weight rounding error
doubles); VNNI CPUs (``vpdpbusd``, int32 sums) would not need it, but the same weights run on
every CPU."""


def per_output_int8(
    rows: Callable[[int, int], np.ndarray], outputs: int
) -> tuple[np.ndarray, np.ndarray]:
    """``DynamicQuantizeMatMul``'s int8 (I, O) of the weight (O, I) that ``rows(start, stop)``
    gives a few float32 rows at a time, and its scales (O,): symmetric, each output's largest
    magnitude mapped to :data:`DYNAMIC_WEIGHT_LEVELS`, zero point 0."""
    first = rows(0, _QUANTISE_ROWS)
    quantized = np.empty((first.shape[1], outputs), np.int8)
    scales = np.empty(outputs, np.float32)
    for start in range(0, outputs, _QUANTISE_ROWS):
        chunk = first if start == 0 else rows(start, start + _QUANTISE_ROWS)
        scale = np.maximum(np.abs(chunk).max(1), 1e-12) / DYNAMIC_WEIGHT_LEVELS
        quantized[:, start : start + len(chunk)] = np.round(chunk / scale[:, None]).T
        scales[start : start + len(chunk)] = scale
    return quantized, scales


def step_model(step: StepWeights):
    """The ONNX model (``onnx.ModelProto``) of one step, inputs :data:`STEP_INPUTS`, outputs
    :data:`STEP_OUTPUTS`, batch and word counts dynamic, and its initialisers {name: array}:
    all of ``step``'s arrays, external (the model holds no copy of them)."""
    from onnx import TensorProto, helper

    h, z, code_size = step.hidden_size, step.latent_size, step.code_size
    g = _Graph(step)
    h_prior, h_gen, previous, time_code, noise = STEP_INPUTS[:5]
    score_table, score_bias, value_table = STEP_INPUTS[5:]
    # attention over the words: softmax(h_gen (keys W_q) + bias) (values W_att^T)
    query = g.op("Unsqueeze", [h_gen, g.constant("axis", np.array([1]))])  # (B, 1, H)
    scores = g.op("Add", [g.op("MatMul", [query, score_table]), score_bias])  # (B, 1, L)
    word_weights = g.op("Softmax", [scores], axis=-1)
    attention = g.op(
        "Squeeze", [g.op("MatMul", [word_weights, value_table]), g.constant("axis", np.array([1]))]
    )  # (B, 2H)
    pre_prior, pre_gen = g.split(g.op("Add", [g.linear("previous", previous), attention]), [h, h])
    # prior
    inputs = g.op("Add", [g.layer_norm_leaky("prior_norm", pre_prior), time_code])
    hidden = g.linear("prior_hidden", h_prior)
    new_prior = g.gru(g.linear("prior_gates", inputs), hidden, h_prior, h)
    mean, logvar = g.split(g.linear("prior_gaussian", new_prior), [z, z])
    half = g.constant("half", np.array(0.5, np.float32))
    std = g.op("Exp", [g.op("Mul", [logvar, half])])
    latent = g.op("Add", [mean, g.op("Mul", [std, noise])])
    # generator
    pre_gen = g.op("Add", [pre_gen, g.linear("latent", latent)])
    inputs = g.op("Add", [g.layer_norm_leaky("generator_norm", pre_gen), time_code])
    hidden = g.linear("generator_hidden", h_gen)
    new_gen = g.gru(g.linear("generator_gates", inputs), hidden, h_gen, h)
    first = g.linear("output_first", new_gen)
    code = g.linear("output_last", g.layer_norm_leaky("output_norm", first))
    # name the outputs
    for name, value in zip(STEP_OUTPUTS, (new_prior, new_gen, code), strict=True):
        g.op("Identity", [value], [name])

    def tensor(name: str, *shape) -> object:
        return helper.make_tensor_value_info(name, TensorProto.FLOAT, ["batch", *shape])

    sizes = {"h_prior": [h], "h_gen": [h], "previous": [code_size], "time_code": [h]}
    sizes.update(noise=[z], score_table=[h, "words"], score_bias=[1, "words"])
    sizes.update(value_table=["words", 2 * h])
    out_sizes = dict(new_prior=[h], new_gen=[h], code=[code_size])
    graph = helper.make_graph(
        g.nodes,
        "t2m_generation_step",
        [tensor(name, *sizes[name]) for name in STEP_INPUTS],
        [tensor(name, *out_sizes[name]) for name in STEP_OUTPUTS],
        g.initializers,
    )
    opsets = [helper.make_opsetid("", OPSET), helper.make_opsetid(MICROSOFT, 1)]
    return helper.make_model(graph, opset_imports=opsets), g.external


def product_model(weight: np.ndarray, weights: str):
    """The ONNX model of one product ``x (B, I) -> x W^T (B, O)`` with ``weight`` (O, I) float32
    stored in the format ``weights`` (:data:`WEIGHT_FORMATS`), as :func:`step_model` stores
    each of its products: the same nodes and the same quantisation, for checking one product
    against float arithmetic on the CPU at hand. Returns (model, external initialisers)."""
    from onnx import TensorProto, helper

    if weights not in WEIGHT_FORMATS:
        raise ValueError(f"unknown weight format {weights!r}; use one of {WEIGHT_FORMATS}")
    outputs, inputs = weight.shape
    arrays: dict[str, np.ndarray] = {}
    rows = torch.from_numpy(np.ascontiguousarray(weight, np.float32))
    if weights == "fp32":
        arrays["product.weight"] = rows.numpy()
    elif weights == "blockwise":
        arrays["product.weight"], arrays["product.scales"] = blockwise_int8_rows([rows])
    else:
        arrays["product.weight"], arrays["product.scale"] = per_output_int8(
            lambda start, stop: rows[start:stop].numpy(), outputs
        )
    step = StepWeights(weights, 0, 0, inputs, {"product": inputs}, {}, arrays)
    g = _Graph(step)
    g.op("Identity", [g.linear("product", "x")], ["y"])
    graph = helper.make_graph(
        g.nodes,
        "t2m_product",
        [helper.make_tensor_value_info("x", TensorProto.FLOAT, ["batch", inputs])],
        [helper.make_tensor_value_info("y", TensorProto.FLOAT, ["batch", outputs])],
        g.initializers,
    )
    opsets = [helper.make_opsetid("", OPSET), helper.make_opsetid(MICROSOFT, 1)]
    return helper.make_model(graph, opset_imports=opsets), g.external


def session(model, external: dict[str, np.ndarray], threads: int):
    """An ONNX Runtime CPU session of ``model`` with ``threads`` threads (no spinning);
    ``external``: its external initialisers' arrays (ONNX Runtime copies them: they need not
    outlive the session, tested)."""
    import onnxruntime as ort

    options = ort.SessionOptions()
    if external:
        values = [ort.OrtValue.ortvalue_from_numpy(value) for value in external.values()]
        options.add_external_initializers(list(external), values)
    options.intra_op_num_threads = threads
    options.inter_op_num_threads = 1
    options.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
    options.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
    options.add_session_config_entry("session.intra_op.allow_spinning", "0")
    return ort.InferenceSession(
        model.SerializeToString(), options, providers=["CPUExecutionProvider"]
    )


class WordTables(torch.nn.Module):
    """The per-sequence tables of a :class:`GenerationPlan` (:meth:`GenerationPlan.tables`,
    the same function) from its score and value tables and query bias alone."""

    tables = GenerationPlan.tables

    def __init__(self, score_table, value_table, query_bias: torch.Tensor) -> None:
        super().__init__()
        self.score_table, self.value_table = score_table, value_table
        self.register_buffer("query_bias", query_bias)


class OnnxGenerationPlan:
    """A :class:`GenerationPlan`'s rollout with the step in ONNX Runtime; call it as the plan
    (:meth:`TemporalVAE.set_rollout` makes ``TemporalVAE.generate`` use it: a
    :class:`~t2m.models.temporal_vae.Rollout`).

    Made from a float32 model: fp32 holds its generation plan (the tables in torch, the
    session's weights); int8 holds the blockwise int8 weights and the tables as torch int8
    Linears, no float32 weights, so the model may be quantised in place afterwards
    (:func:`t2m.accel.int8.quantize_int8` with ``plan=False``: nothing else reads torch's int8
    plan).

    The sessions are made on first use, each for the batch sizes it runs (an int8 plan that
    only ever sees one sequence never makes the batched one). ONNX Runtime copies the weights
    when it makes a session (tested), so the fp32 session sees the model's weights as they
    were at the first generation, and the arrays of a session's weights are let go then
    (int8 keeps the blockwise ones for the batched session).

    Args:
        vae: a float32 :class:`~t2m.models.temporal_vae.TemporalVAE` (a float32 pipeline's,
            whose plan is already an :class:`OnnxGenerationPlan`, too).
        precision: ``"fp32"`` or ``"int8"``.
        threads: ONNX Runtime's intra-op threads (default: torch's thread count now).
    """

    def __init__(self, vae: TemporalVAE, precision: str = "fp32", threads: int | None = None):
        require()
        self.vae = vae
        from t2m.accel.int8 import int8_linear

        if precision not in ONNX_PRECISIONS:
            raise ValueError(
                f"the onnx backend runs {' and '.join(ONNX_PRECISIONS)}, not {precision!r}"
            )
        self.precision = precision
        self.tolerance = FLOAT32_TOLERANCE if precision == "fp32" else INT8_TOLERANCE
        self.threads = threads or torch.get_num_threads()
        if precision == "fp32":
            rollout = vae.generation_rollout
            if isinstance(rollout, OnnxGenerationPlan):  # a float32 pipeline's model
                plan = rollout.tables
            else:
                plan = float_plan(vae)
            if plan is None or not isinstance(plan.output_last, torch.nn.Linear):
                raise ValueError("the onnx backend is made from a float32 model")
            weights = step_weights(plan, "fp32")
            self.tables: GenerationPlan | WordTables = plan
        else:
            plan = GenerationPlan(vae, RowBlocks.of)  # views of the model's weights
            weights = step_weights(plan, "blockwise")
            with warnings.catch_warnings():  # torch's deprecation of its eager int8 API
                warnings.simplefilter("ignore", UserWarning)
                self.tables = WordTables(
                    int8_linear(*plan.score_table), int8_linear(*plan.value_table), plan.query_bias
                )
        self.hidden_size = weights.hidden_size
        # batch size from which a session runs -> its weights, until the session is made
        self._weights: dict[int, StepWeights | None] = {1: weights}
        if precision == "int8":
            self._weights[BATCHED_FROM] = None  # from the blockwise ones
        self.sessions = {}  # batch size from which each session runs -> the session

    def __deepcopy__(self, memo: dict):
        """A copy of the model generates in torch (sessions are not copied)."""
        return TorchPlanRollout(copy.deepcopy(self.vae, memo))

    def _session(self, batch: int):
        """The session for ``batch`` sequences, made on first use."""
        start = max(b for b in self._weights if b <= batch)
        if start not in self.sessions:
            step = self._weights[start] or self._weights[1].to_dynamic()
            self.sessions[start] = session(*step_model(step), self.threads)
            if len(self.sessions) == len(self._weights):  # ONNX Runtime holds copies of all
                self._weights = dict.fromkeys(self._weights)
        return self.sessions[start]

    @torch.inference_mode()
    def __call__(
        self,
        state: RecurrentState,
        context: WordContext,
        time_codes: torch.Tensor,
        noise: torch.Tensor,
        lengths: torch.Tensor | None = None,
    ) -> tuple[RecurrentState, torch.Tensor]:
        """:meth:`GenerationPlan.forward` (arguments and results as there, float32, CPU)."""
        import onnxruntime as ort

        score_table, score_bias, value_table = self.tables.tables(context)
        fixed = {  # per sequence: contiguous float32 arrays, read by every step
            "score_table": _array(score_table.transpose(1, 2)),
            "score_bias": _array(score_bias.transpose(1, 2)),
            "value_table": _array(value_table),
        }
        # two sets of state arrays: step i reads set i % 2 and writes the other (no allocations)
        states = [[_array(t).copy() for t in state[:3]] for _ in range(2)]
        time_codes = _array(time_codes.transpose(0, 1))  # (S, B, H)
        noise = _array(noise.transpose(0, 1))  # (S, B, Z)
        step = {"time_code": time_codes[0].copy(), "noise": noise[0].copy()}
        session = self._session(len(states[0][0]))
        bindings, values = [], []  # values: the OrtValues that share the arrays' memory
        for parity in (0, 1):
            binding = session.io_binding()
            feeds = {**dict(zip(STATE_INPUTS, states[parity], strict=True)), **fixed, **step}
            for name, array in feeds.items():
                values.append(ort.OrtValue.ortvalue_from_numpy(array))
                binding.bind_ortvalue_input(name, values[-1])
            for name, array in zip(STEP_OUTPUTS, states[1 - parity], strict=True):
                values.append(ort.OrtValue.ortvalue_from_numpy(array))
                binding.bind_ortvalue_output(name, values[-1])
            bindings.append(binding)
        steps = len(time_codes)
        codes = np.empty((steps, *states[0][2].shape), np.float32)  # (S, B, C)
        stopped = None if lengths is None else (np.arange(steps)[:, None] >= lengths.cpu().numpy())
        stopping = [False] * steps if stopped is None else stopped.any(1).tolist()
        for i in range(steps):
            np.copyto(step["time_code"], time_codes[i])
            np.copyto(step["noise"], noise[i])
            session.run_with_iobinding(bindings[i % 2])
            old, new = states[i % 2], states[1 - i % 2]
            codes[i] = new[2]
            if stopping[i]:  # an item's state stops after its last step
                for array, before in zip(new, old, strict=True):
                    np.copyto(array, before, where=stopped[i, :, None])
        h_prior, h_gen, previous = (torch.from_numpy(a) for a in states[steps % 2])
        final = state._replace(
            prior=h_prior, generator=h_gen, previous_code=previous, posterior=None
        )
        return final, torch.from_numpy(codes).transpose(0, 1)


def _stacked(blocks: Sequence[torch.Tensor]) -> torch.Tensor:
    """The blocks concatenated on the first axis (one block: itself, no copy)."""
    return blocks[0] if len(blocks) == 1 else torch.cat(blocks)


def _array(tensor: torch.Tensor) -> np.ndarray:
    """A contiguous float32 numpy array of ``tensor`` (no copy when it already is one)."""
    return np.ascontiguousarray(tensor.detach().float().cpu().numpy())
