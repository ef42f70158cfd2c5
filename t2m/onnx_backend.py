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


class _Graph:
    """Collects the nodes and initialisers of one graph; each method adds nodes and returns
    the name of its output."""

    def __init__(self, weights: str) -> None:
        self.weights = weights
        self.external: dict[str, np.ndarray] = {}
        self.nodes: list = []
        self.initializers: list = []
        self._count = 0

    def name(self, stem: str) -> str:
        self._count += 1
        return f"{stem}_{self._count}"

    def constant(self, stem: str, value: np.ndarray) -> str:
        from onnx import numpy_helper

        name = self.name(stem)
        self.initializers.append(numpy_helper.from_array(np.ascontiguousarray(value), name))
        return name

    def shared(self, stem: str, value: np.ndarray) -> str:
        """A float32 initialiser whose data stays in ``value``'s memory (an external
        initialiser: :func:`session` hands ONNX Runtime the array itself, no copy in the
        model)."""
        from onnx import TensorProto

        name = self.name(stem)
        tensor = TensorProto(name=name, data_type=TensorProto.FLOAT, dims=value.shape)
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

    def linear(self, stem: str, inputs: str, linear: torch.nn.Linear) -> str:
        """``linear`` (weight (O, I), bias (O,) or none) on ``inputs`` (B, I), its weight in
        this graph's format (:data:`WEIGHT_FORMATS`)."""
        bias = None
        if linear.bias is not None:
            bias = self.constant(f"{stem}.bias", linear.bias.detach().float().numpy())
        if self.weights == "fp32":  # Gemm on the weight (O, I) itself, in the model's memory
            weight = self.shared(
                f"{stem}.weight", linear.weight.detach().float().contiguous().numpy()
            )
            return self.op("Gemm", [inputs, weight] + ([bias] if bias else []), transB=1)
        weight = linear.weight.detach().float().t().contiguous().numpy()  # (I, O)
        if self.weights == "dynamic":  # int8 per tensor, activations quantised per call
            scale = max(float(np.abs(weight).max()), 1e-12) / 127.0
            quantized = np.clip(np.round(weight / scale), -127, 127).astype(np.int8)
            operands = [
                inputs,
                self.constant(f"{stem}.weight", quantized),
                self.constant(f"{stem}.scale", np.array(scale, np.float32)),
                self.constant(f"{stem}.zero", np.array(0, np.int8)),
            ]
            return self.op(
                "DynamicQuantizeMatMul", operands + ([bias] if bias else []), domain=MICROSOFT
            )
        output = self._blockwise(stem, inputs, weight)
        return output if bias is None else self.op("Add", [output, bias])

    def _blockwise(self, stem: str, inputs: str, weight: np.ndarray) -> str:
        """``inputs @ weight`` (I, O) as ONNX Runtime's ``MatMulNBits`` (8 bits, symmetric,
        int8 arithmetic: ``accuracy_level`` 4) on :func:`blockwise_int8` of the weight."""
        packed, scales = blockwise_int8(weight)
        return self.op(
            "MatMulNBits",
            [
                inputs,
                self.constant(f"{stem}.weight", packed),
                self.constant(f"{stem}.scales", scales),
            ],
            domain=MICROSOFT,
            K=weight.shape[0],
            N=weight.shape[1],
            bits=8,
            block_size=INT8_BLOCK,
            accuracy_level=4,
        )

    def layer_norm_leaky(self, stem: str, inputs: str, norm: torch.nn.LayerNorm) -> str:
        """LeakyReLU(0.2) of LayerNorm (last axis)."""
        scale = self.constant(f"{stem}.weight", norm.weight.detach().float().numpy())
        shift = self.constant(f"{stem}.bias", norm.bias.detach().float().numpy())
        normed = self.op("LayerNormalization", [inputs, scale, shift], axis=-1, epsilon=norm.eps)
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


def blockwise_int8(weight: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``MatMulNBits``' 8-bit symmetric layout of ``weight`` (I, O) float32: each output's
    inputs in blocks of :data:`INT8_BLOCK` (the last zero-padded); a block's scale maps its
    entry of largest magnitude to -128, and the stored bytes are round(w / scale) + 128 (0 in
    the padding).
    Returns packed (O, blocks, INT8_BLOCK) uint8 and scales (O, blocks) float32; the same bytes
    as ONNX Runtime's ``MatMulNBitsQuantizer`` (tested)."""
    inputs, outputs = weight.shape
    blocks = -(-inputs // INT8_BLOCK)
    padded = np.zeros((outputs, blocks * INT8_BLOCK), np.float32)
    padded[:, :inputs] = weight.T
    padded = padded.reshape(outputs, blocks, INT8_BLOCK)
    largest = np.take_along_axis(padded, np.abs(padded).argmax(-1)[..., None], -1)[..., 0]
    scales = (largest / -128.0).astype(np.float32)  # (O, blocks)
    divisor = np.where(scales == 0, 1.0, scales)[..., None]
    packed = (np.clip(np.round(padded / divisor), -128, 127) + 128).astype(np.uint8)
    packed.reshape(outputs, -1)[:, inputs:] = 0  # the padding, as the quantiser leaves it
    return packed, scales


def step_model(plan: GenerationPlan, weights: str = "fp32"):
    """The ONNX model (``onnx.ModelProto``) of one step of ``plan`` (float32 weights), inputs
    :data:`STEP_INPUTS`, outputs :data:`STEP_OUTPUTS`, batch and word counts dynamic, the
    products' weights in the format ``weights`` (:data:`WEIGHT_FORMATS`), and its external
    initialisers {name: array}: ``fp32``'s product weights are the plan's own arrays (no copy);
    the int8 formats are made weight by weight (no float32 copy of all the weights)."""
    from onnx import TensorProto, helper

    if weights not in WEIGHT_FORMATS:
        raise ValueError(f"unknown weight format {weights!r}; use one of {WEIGHT_FORMATS}")
    h, z = plan.hidden_size, plan.latent_size
    code_size = plan.output_last.weight.shape[0]
    g = _Graph(weights)
    (h_prior, h_gen, previous, prior_hidden, gen_hidden, time_code, noise) = STEP_INPUTS[:7]
    score_table, score_bias, value_table = STEP_INPUTS[7:]
    # attention over the words: softmax(h_gen (keys W_q) + bias) (values W_att^T)
    query = g.op("Unsqueeze", [h_gen, g.constant("axis", np.array([1]))])  # (B, 1, H)
    scores = g.op("Add", [g.op("MatMul", [query, score_table]), score_bias])  # (B, 1, L)
    word_weights = g.op("Softmax", [scores], axis=-1)
    attention = g.op(
        "Squeeze", [g.op("MatMul", [word_weights, value_table]), g.constant("axis", np.array([1]))]
    )  # (B, 2H)
    pre_prior, pre_gen = g.split(
        g.op("Add", [g.linear("previous", previous, plan.previous), attention]), [h, h]
    )
    # prior
    inputs = g.op("Add", [g.layer_norm_leaky("prior_norm", pre_prior, plan.prior_norm), time_code])
    new_prior = g.gru(g.linear("prior_gates", inputs, plan.prior_gates), prior_hidden, h_prior, h)
    next_prior_hidden, mean, logvar = g.split(
        g.linear("prior_state", new_prior, plan.prior_state), [3 * h, z, z]
    )
    half = g.constant("half", np.array(0.5, np.float32))
    std = g.op("Exp", [g.op("Mul", [logvar, half])])
    latent = g.op("Add", [mean, g.op("Mul", [std, noise])])
    # generator
    pre_gen = g.op("Add", [pre_gen, g.linear("latent", latent, plan.latent)])
    inputs = g.op(
        "Add", [g.layer_norm_leaky("generator_norm", pre_gen, plan.generator_norm), time_code]
    )
    new_gen = g.gru(g.linear("generator_gates", inputs, plan.generator_gates), gen_hidden, h_gen, h)
    next_gen_hidden, first = g.split(
        g.linear("generator_state", new_gen, plan.generator_state), [3 * h, h]
    )
    code = g.linear(
        "output_last", g.layer_norm_leaky("output_norm", first, plan.output_norm), plan.output_last
    )
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


def session(model, external: dict[str, object], threads: int):
    """An ONNX Runtime CPU session of ``model`` with ``threads`` threads (no spinning);
    ``external``: its external initialisers' values (OrtValues, which must outlive it)."""
    import onnxruntime as ort

    options = ort.SessionOptions()
    if external:
        options.add_external_initializers(list(external), list(external.values()))
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

    Args:
        plan: a float32 plan (or a float32 :class:`OnnxGenerationPlan`: its ``base``). int8
            sessions hold their own int8 weights; the fp32 session reads the plan's float32
            arrays (kept alive here) and packs its own copy of them, so later changes to the
            model's weights are not seen.
        precision: ``"fp32"`` or ``"int8"``.
        threads: ONNX Runtime's intra-op threads (default: torch's thread count now).
        base: the torch plan that makes the per-sequence tables (:meth:`GenerationPlan.tables`)
            and the first step's hidden-gate pre-activations (default ``plan``); a public
            attribute: an int8 pipeline sets it to its model's quantised plan once the model is
            quantised, so that the float32 one is not kept.
    """

    def __init__(
        self,
        plan: GenerationPlan,
        precision: str = "fp32",
        threads: int | None = None,
        base: GenerationPlan | None = None,
    ) -> None:
        require()
        import onnxruntime as ort

        if isinstance(plan, OnnxGenerationPlan):  # a float32 pipeline's: its torch plan
            plan = plan.base
        if precision not in ONNX_PRECISIONS:
            raise ValueError(
                f"the onnx backend runs {' and '.join(ONNX_PRECISIONS)}, not {precision!r}"
            )
        if plan.output_last.weight.dtype != torch.float32:
            raise ValueError("OnnxGenerationPlan is built from a float32 GenerationPlan")
        self.precision = precision
        self.hidden_size = plan.hidden_size
        self.base = base or plan
        threads = threads or torch.get_num_threads()
        formats = {1: "fp32"} if precision == "fp32" else {1: "blockwise", BATCHED_FROM: "dynamic"}
        self.sessions = {}  # batch size from which each session runs
        self.shared_weights: dict[str, object] = {}  # OrtValues on the plan's own arrays
        for batch, weights in formats.items():
            model, external = step_model(plan, weights)
            values = {k: ort.OrtValue.ortvalue_from_numpy(v) for k, v in external.items()}
            self.shared_weights.update(values)
            self.sessions[batch] = session(model, values, threads)

    def _session(self, batch: int):
        return self.sessions[max(b for b in self.sessions if b <= batch)]

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
