"""Generation through ONNX Runtime (CPU): the prior / generator step of a
:class:`~t2m.models.fast_recurrence.GenerationPlan` as one ONNX graph, one session call per snippet.

The graph is written here from the plan's weights (``onnx.helper``, no tracing): the same sums as
:meth:`GenerationPlan.forward` (stacked products, attention through the per-sequence tables,
the GRU gates written out). ONNX Runtime runs the step as about 55 kernels, with less overhead than
torch's ~250 operator calls, and its matrix-vector kernels read the weights faster.

Two precisions:

* ``fp32``: ``Gemm`` on the plan's float32 weights, handed to ONNX Runtime without a copy
  (it keeps its own packed copy of them);
* ``int8``: symmetric int8 weights, activations quantised on the fly, in two sessions, each
  with its own int8 copy of the weights (15.6 MB at paper size). One sequence runs
  ``MatMulNBits`` (one scale per block of :data:`INT8_BLOCK` inputs of a row, made by ONNX
  Runtime's own quantiser, int8 arithmetic); batches run ``DynamicQuantizeMatMul`` (one scale
  per weight, as torch's dynamic quantisation), whose kernel is the faster one from two
  sequences on (:data:`BATCHED_FROM`).

The per-sequence tables and the first step's hidden-gate products stay in torch, in a torch
plan (``base``): they run once per motion.

Measured against the torch plan in ``README.md`` ("ONNX Runtime generation"). Needs the
``onnx`` and ``onnxruntime`` packages (the ``onnx`` extra of ``setup.cfg``);
:func:`available` says whether they are installed.
"""

from __future__ import annotations

import importlib.util
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
import torch

if TYPE_CHECKING:
    from t2m.models.fast_recurrence import GenerationPlan
    from t2m.models.temporal_vae import RecurrentState, WordContext

BACKENDS = ("torch", "onnx")
"""Generation backends of :class:`t2m.pipeline.TextToMotion`."""

ONNX_PRECISIONS = ("fp32", "int8")
"""What the ONNX Runtime backend runs (bfloat16 has no fast CPU kernels there)."""

OPSET = 17  # LayerNormalization is in the default domain from opset 17

BATCHED_FROM = 2
"""int8: batches of this many sequences or more run the ``MatMulInteger`` session, smaller
ones the ``MatMulNBits`` session. One step, 1 thread, paper size, ms ``MatMulNBits`` /
``MatMulInteger``: batch 1 0.93 / 1.25, 2 5.1 / 1.3, 4 5.9 / 1.6, 8 7.8 / 2.3, 32 8.7 / 5.2
(``MatMulNBits`` has a matrix-vector kernel for a single row only)."""

WEIGHT_FORMATS = ("fp32", "blockwise", "dynamic")
"""How :func:`step_model` stores the products' weights: float32 (``Gemm``), int8 with a scale
per block of :data:`INT8_BLOCK` inputs (``MatMulNBits``), int8 with one scale per weight and
activations quantised per call (``DynamicQuantizeMatMul``)."""

MICROSOFT = "com.microsoft"  # ONNX Runtime's own operators (MatMulNBits, DynamicQuantizeMatMul)

INT8_BLOCK = 128
"""Inputs per quantisation block of ``MatMulNBits``."""

STEP_INPUTS = (
    "h_prior",  # (B, H)
    "h_gen",  # (B, H)
    "previous",  # (B, C)
    "prior_hidden",  # (B, 3H): the prior GRU's hidden-gate pre-activations of h_prior
    "gen_hidden",  # (B, 3H)
    "time_code",  # (B, H)
    "noise",  # (B, Z)
    "score_table",  # (B, H, L): the plan's score table, transposed
    "score_bias",  # (B, 1, L)
    "value_table",  # (B, L, 2H)
)
STATE_INPUTS = STEP_INPUTS[:5]
"""The inputs that the next step reads from this step's outputs, in :data:`STEP_OUTPUTS`' order."""
STEP_OUTPUTS = ("new_prior", "new_gen", "code", "next_prior_hidden", "next_gen_hidden")


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


LINEARS = (
    "previous",
    "prior_gates",
    "prior_state",
    "latent",
    "generator_gates",
    "generator_state",
    "output_last",
)
"""The plan's Linears that the step graph runs (the tables' two stay in torch)."""
NORMS = ("prior_norm", "generator_norm", "output_norm")

_QUANTISE_ROWS = 256
"""Output rows quantised at a time (no temporaries as large as a weight: freed, they stay in
the process's heap)."""


@dataclass(frozen=True)
class StepWeights:
    """What :func:`step_model` builds a step graph from, numpy only (no ``onnx`` needed to make
    it): the plan's sizes, its LayerNorms' epsilons, each Linear's input size and every
    initialiser by name: ``<linear>.weight`` in the format ``weights`` (:data:`WEIGHT_FORMATS`;
    ``blockwise`` adds ``.scales``, ``dynamic`` ``.scale`` and ``.zero``), ``<linear>.bias``
    where there is one, ``<norm>.weight`` and ``<norm>.bias``."""

    weights: str
    hidden_size: int
    latent_size: int
    code_size: int
    input_sizes: dict[str, int]
    epsilons: dict[str, float]
    arrays: dict[str, np.ndarray]


def step_weights(plan: GenerationPlan, weights: str = "fp32") -> StepWeights:
    """The initialisers of ``plan``'s step graph with the products' weights in the format
    ``weights``: ``fp32``'s are the plan's own float32 arrays (no copy where they are
    contiguous); the int8 formats are quantised a few rows at a time, from float32 Linears or,
    for ``dynamic``, also from torch's dynamically quantised ones (their int8 values and scale
    as they are: :func:`t2m.quantize.quantize_int8`'s plan). A float32 pipeline's
    :class:`OnnxGenerationPlan` stands for its torch plan."""
    if weights not in WEIGHT_FORMATS:
        raise ValueError(f"unknown weight format {weights!r}; use one of {WEIGHT_FORMATS}")
    if isinstance(plan, OnnxGenerationPlan):  # a float32 pipeline's: its torch plan
        plan = plan.base
    arrays: dict[str, np.ndarray] = {}
    input_sizes = {}
    for stem in LINEARS:
        linear = getattr(plan, stem)
        weight, bias = _weight_and_bias(linear)
        input_sizes[stem] = weight.shape[1]
        if bias is not None:
            arrays[f"{stem}.bias"] = _array(bias)
        if weights != "dynamic" and weight.is_quantized:
            raise ValueError(f"{weights} weights are made from a float32 plan")
        if weights == "fp32":
            arrays[f"{stem}.weight"] = _array(weight)
        elif weights == "blockwise":
            packed, scales = blockwise_int8(_array(weight).T)
            arrays[f"{stem}.weight"], arrays[f"{stem}.scales"] = packed, scales
        else:
            arrays[f"{stem}.weight"], scale = per_tensor_int8(weight)
            arrays[f"{stem}.scale"] = np.array(scale, np.float32)
            arrays[f"{stem}.zero"] = np.array(0, np.int8)
    for stem in NORMS:
        norm = getattr(plan, stem)
        arrays[f"{stem}.weight"] = _array(norm.weight)
        arrays[f"{stem}.bias"] = _array(norm.bias)
    return StepWeights(
        weights=weights,
        hidden_size=plan.hidden_size,
        latent_size=plan.latent_size,
        code_size=input_sizes["previous"],
        input_sizes=input_sizes,
        epsilons={stem: getattr(plan, stem).eps for stem in NORMS},
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
        if step.weights == "dynamic":  # int8 per tensor, activations quantised per call
            operands = [self.array(f"{stem}.{key}") for key in ("weight", "scale", "zero")]
            return self.op("DynamicQuantizeMatMul", [inputs, *operands, *bias], domain=MICROSOFT)
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
        """:func:`~t2m.models.fast_recurrence.gru_update` (gates (B, 3H) as r, z, n)."""
        input_rz, input_n = self.split(input_gates, [2 * size, size])
        hidden_rz, hidden_n = self.split(hidden_gates, [2 * size, size])
        reset, update = self.split(
            self.op("Sigmoid", [self.op("Add", [input_rz, hidden_rz])]), [size, size]
        )
        candidate = self.op("Tanh", [self.op("Add", [input_n, self.op("Mul", [reset, hidden_n])])])
        change = self.op("Mul", [update, self.op("Sub", [hidden, candidate])])
        return self.op("Add", [candidate, change])


def _weight_and_bias(linear: torch.nn.Module) -> tuple[torch.Tensor, torch.Tensor | None]:
    """A float32 Linear's or a dynamically quantised Linear's weight (O, I) and bias (or None)."""
    from torch.ao.nn.quantized.dynamic import Linear as DynamicLinear

    if isinstance(linear, DynamicLinear):
        return linear.weight(), linear.bias()
    if isinstance(linear, torch.nn.Linear) and linear.weight.dtype == torch.float32:
        return linear.weight.detach(), None if linear.bias is None else linear.bias.detach()
    raise ValueError("the onnx backend reads float32 or torch's int8 generation plans")


def per_tensor_int8(weight: torch.Tensor) -> tuple[np.ndarray, float]:
    """``weight`` (O, I) as ``DynamicQuantizeMatMul``'s int8 (I, O) and its one scale
    (symmetric, zero point 0): a float weight quantised (scale: the largest magnitude / 127),
    a per-tensor qint8 one with zero point 0 as it is."""
    outputs, inputs = weight.shape
    quantized = np.empty((inputs, outputs), np.int8)
    if weight.is_quantized:
        if weight.qscheme() != torch.per_tensor_affine or weight.q_zero_point() != 0:
            raise ValueError("expected a per-tensor int8 weight with zero point 0")
        for start in range(0, outputs, _QUANTISE_ROWS):
            rows = weight[start : start + _QUANTISE_ROWS].int_repr().numpy()
            quantized[:, start : start + len(rows)] = rows.T
        return quantized, float(weight.q_scale())
    scale = max(float(weight.abs().max()), 1e-12) / 127.0
    for start in range(0, outputs, _QUANTISE_ROWS):
        rows = _array(weight[start : start + _QUANTISE_ROWS])
        quantized[:, start : start + len(rows)] = np.clip(np.round(rows / scale), -127, 127).T
    return quantized, scale


def blockwise_int8(weight: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``MatMulNBits``' 8-bit symmetric layout of ``weight`` (I, O) float32: each output's
    inputs in blocks of :data:`INT8_BLOCK` (the last zero-padded); a block's scale maps its
    entry of largest magnitude to -128, and the stored bytes are round(w / scale) + 128 (0 in
    the padding).
    Returns packed (O, blocks, INT8_BLOCK) uint8 and scales (O, blocks) float32; the same bytes
    as ONNX Runtime's ``MatMulNBitsQuantizer`` (tested). Quantised a few outputs at a time
    (``weight.T`` of a torch weight (O, I) is read without a copy)."""
    inputs, outputs = weight.shape
    blocks = -(-inputs // INT8_BLOCK)
    packed = np.empty((outputs, blocks, INT8_BLOCK), np.uint8)
    scales = np.empty((outputs, blocks), np.float32)
    padded = np.zeros((min(outputs, _QUANTISE_ROWS), blocks * INT8_BLOCK), np.float32)
    for start in range(0, outputs, _QUANTISE_ROWS):
        rows = weight[:, start : start + _QUANTISE_ROWS].T  # (r, I)
        chunk = padded[: len(rows)]
        chunk[:, :inputs] = rows
        chunk = chunk.reshape(len(rows), blocks, INT8_BLOCK)
        largest = np.take_along_axis(chunk, np.abs(chunk).argmax(-1)[..., None], -1)[..., 0]
        scale = (largest / -128.0).astype(np.float32)  # (r, blocks)
        divisor = np.where(scale == 0, 1.0, scale)[..., None]
        quantized = np.clip(np.round(chunk / divisor), -128, 127) + 128
        packed[start : start + len(rows)] = quantized
        scales[start : start + len(rows)] = scale
    packed.reshape(outputs, -1)[:, inputs:] = 0  # the padding, as the quantiser leaves it
    return packed, scales


def step_model(step: StepWeights):
    """The ONNX model (``onnx.ModelProto``) of one step, inputs :data:`STEP_INPUTS`, outputs
    :data:`STEP_OUTPUTS`, batch and word counts dynamic, and its initialisers {name: array}:
    all of ``step``'s arrays, external (the model holds no copy of them)."""
    from onnx import TensorProto, helper

    h, z, code_size = step.hidden_size, step.latent_size, step.code_size
    g = _Graph(step)
    (h_prior, h_gen, previous, prior_hidden, gen_hidden, time_code, noise) = STEP_INPUTS[:7]
    score_table, score_bias, value_table = STEP_INPUTS[7:]
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
    new_prior = g.gru(g.linear("prior_gates", inputs), prior_hidden, h_prior, h)
    next_prior_hidden, mean, logvar = g.split(g.linear("prior_state", new_prior), [3 * h, z, z])
    half = g.constant("half", np.array(0.5, np.float32))
    std = g.op("Exp", [g.op("Mul", [logvar, half])])
    latent = g.op("Add", [mean, g.op("Mul", [std, noise])])
    # generator
    pre_gen = g.op("Add", [pre_gen, g.linear("latent", latent)])
    inputs = g.op("Add", [g.layer_norm_leaky("generator_norm", pre_gen), time_code])
    new_gen = g.gru(g.linear("generator_gates", inputs), gen_hidden, h_gen, h)
    next_gen_hidden, first = g.split(g.linear("generator_state", new_gen), [3 * h, h])
    code = g.linear("output_last", g.layer_norm_leaky("output_norm", first))
    # name the outputs
    for name, value in zip(
        STEP_OUTPUTS, (new_prior, new_gen, code, next_prior_hidden, next_gen_hidden), strict=True
    ):
        g.op("Identity", [value], [name])

    def tensor(name: str, *shape) -> object:
        return helper.make_tensor_value_info(name, TensorProto.FLOAT, ["batch", *shape])

    sizes = {"h_prior": [h], "h_gen": [h], "previous": [code_size], "prior_hidden": [3 * h]}
    sizes.update(gen_hidden=[3 * h], time_code=[h], noise=[z], score_table=[h, "words"])
    sizes.update(score_bias=[1, "words"], value_table=["words", 2 * h])
    out_sizes = dict(new_prior=[h], new_gen=[h], code=[code_size])
    out_sizes.update(next_prior_hidden=[3 * h], next_gen_hidden=[3 * h])
    graph = helper.make_graph(
        g.nodes,
        "t2m_generation_step",
        [tensor(name, *sizes[name]) for name in STEP_INPUTS],
        [tensor(name, *out_sizes[name]) for name in STEP_OUTPUTS],
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


class OnnxGenerationPlan:
    """A :class:`GenerationPlan`'s rollout with the step in ONNX Runtime; call it as the plan
    (:func:`~t2m.models.fast_recurrence.set_generation_plan` makes ``TemporalVAE.generate``
    use it).

    The sessions are made on first use, each for the batch sizes it runs (an int8 plan that
    only ever sees one sequence never makes the batched one). ONNX Runtime copies the weights
    it is given when it makes a session (tested), so the arrays they were made from are let go
    then, and later changes to the model's weights are not seen.

    Args:
        base: the torch plan that makes the per-sequence tables (:meth:`GenerationPlan.tables`)
            and the first step's hidden-gate pre-activations, and whose products the sessions
            run unless ``weights`` is given: fp32 needs a float32 plan; int8 quantises a
            float32 plan's weights, or reads those of torch's int8 plan
            (:func:`t2m.quantize.quantize_int8`) as they are for the batched session. A
            float32 pipeline's :class:`OnnxGenerationPlan` stands for its ``base``.
        precision: ``"fp32"`` or ``"int8"``.
        threads: ONNX Runtime's intra-op threads (default: torch's thread count now).
        weights: int8: the one-sequence session's weights, ``step_weights(float_plan,
            "blockwise")``, for a ``base`` that is torch's int8 plan: a pipeline makes them
            before it quantises its model in place, and never holds the float32 weights, the
            int8 model and ONNX Runtime at once.
    """

    def __init__(
        self,
        base: GenerationPlan,
        precision: str = "fp32",
        threads: int | None = None,
        weights: StepWeights | None = None,
    ) -> None:
        require()
        if isinstance(base, OnnxGenerationPlan):  # a float32 pipeline's: its torch plan
            base = base.base
        if precision not in ONNX_PRECISIONS:
            raise ValueError(
                f"the onnx backend runs {' and '.join(ONNX_PRECISIONS)}, not {precision!r}"
            )
        one_sequence = "fp32" if precision == "fp32" else "blockwise"
        if weights is None:
            weights = step_weights(base, one_sequence)
        elif weights.weights != one_sequence:
            raise ValueError(f"{precision} runs {one_sequence} weights, not {weights.weights}")
        self.precision = precision
        self.hidden_size = base.hidden_size
        self.base = base
        self.threads = threads or torch.get_num_threads()
        # batch size from which a session runs -> its weights (None: base's), until it is made
        self._weights: dict[int, StepWeights | None] = {1: weights}
        if precision == "int8":
            self._weights[BATCHED_FROM] = None
        self.sessions = {}  # batch size from which each session runs -> the session

    def _session(self, batch: int):
        """The session for ``batch`` sequences, made on first use."""
        start = max(b for b in self._weights if b <= batch)
        if start not in self.sessions:
            step = self._weights.pop(start) or step_weights(self.base, "dynamic")
            self._weights[start] = None
            self.sessions[start] = session(*step_model(step), self.threads)
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

        h = self.hidden_size
        score_table, score_bias, value_table = self.base.tables(context)
        fixed = {  # per sequence: contiguous float32 arrays, read by every step
            "score_table": _array(score_table.transpose(1, 2)),
            "score_bias": _array(score_bias.transpose(1, 2)),
            "value_table": _array(value_table),
        }
        # the first step's hidden-gate pre-activations (later steps get them from the previous)
        start = [
            *state[:3],
            self.base.prior_state(state.prior)[:, : 3 * h],
            self.base.generator_state(state.generator)[:, : 3 * h],
        ]
        # two sets of state arrays: step i reads set i % 2 and writes the other (no allocations)
        states = [[_array(t).copy() for t in start], [_array(t).copy() for t in start]]
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
        for i in range(steps):
            np.copyto(step["time_code"], time_codes[i])
            np.copyto(step["noise"], noise[i])
            session.run_with_iobinding(bindings[i % 2])
            old, new = states[i % 2], states[1 - i % 2]
            codes[i] = new[2]
            if stopped is not None:  # an item's state stops after its last step
                for array, before in zip(new, old, strict=True):
                    np.copyto(array, before, where=stopped[i, :, None])
        h_prior, h_gen, previous = (torch.from_numpy(a) for a in states[steps % 2][:3])
        final = state._replace(
            prior=h_prior, generator=h_gen, previous_code=previous, posterior=None
        )
        return final, torch.from_numpy(codes).transpose(0, 1)


def _array(tensor: torch.Tensor) -> np.ndarray:
    """A contiguous float32 numpy array of ``tensor`` (no copy when it already is one)."""
    return np.ascontiguousarray(tensor.detach().float().cpu().numpy())
