"""Float32 products through oneDNN on the CPU, gradients included: a one-layer bidirectional GRU
over captions of different lengths as one autograd node (:class:`FusedGRU`), a Linear
(:class:`FastLinear`) and the autoencoder's halving convolution (:class:`FastConv1d`), each a
subclass of the torch layer it stands for, tested equal to it (``tests/test_onednn.py``) and
holding the same parameters (checkpoints do not change). :func:`t2m.accel.accelerate` puts them
in place of the plain layers of the models (``__class__`` swapped, parameters untouched).

Why: torch's float32 matrix products on the CPU go to MKL, which runs its AVX2 code on AMD
processors; oneDNN's products use AVX-512 there and took 0.41-0.52x of ``F.linear``'s time on the
development machine (AMD EPYC, Zen 5, one thread, 32-6,000 rows). A
packed ``nn.GRU`` also records about fifteen autograd nodes per step; :class:`FusedGRU` is one
node:

* the input products of every step are one product over all (item, step) rows before the loop;
* each step reads its hidden state through a weight packed once per call for oneDNN;
* the backward runs the steps in reverse with the GRU's gradients written out, and each weight's
  gradient is one (3H, N) x (N, I) product over all rows instead of one thin product per step.

It reads the rows of the ``PackedSequence`` the model packs: time-major and sorted by length, so
the items alive at step t are a prefix of the batch and no step computes padding.

Every layer here takes its fused path for float32 CPU tensors outside autocast with oneDNN
available (:func:`fused_path`) and is the torch layer otherwise (CUDA, bfloat16 autocast,
float64).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn
from torch.nn.utils.rnn import PackedSequence, pack_padded_sequence, pad_packed_sequence

from t2m.models.autoencoder import SNIPPET_FRAMES, MovementEncoder
from t2m.models.temporal_vae import TemporalVAE

_ONEDNN = torch.backends.mkldnn.is_available()

MIN_WEIGHT = 32_768
"""Weights of fewer elements stay with torch's own layers: for the demo preset's small layers
(hidden sizes 64-192) the fused GRU was no faster than ``nn.GRU`` at two threads (H 64: 16.5
vs 14.4 ms forward + backward; H 256: 48 vs 58 ms; H 512: 115 vs 186 ms), and a 64 x 64 product
runs faster through MKL (21 vs 29 us)."""


def _linear(inputs: torch.Tensor, weight: torch.Tensor, bias: torch.Tensor | None = None):
    """``inputs @ weight.T + bias`` through oneDNN (``weight`` plain or packed)."""
    return torch.ops.mkldnn._linear_pointwise(inputs, weight, bias, "none", [], "")


def _matmul(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """``a @ b`` through oneDNN."""
    return _linear(a.contiguous(), b.t().contiguous())


MIN_GRADIENT = 1 << 20
"""Results (O x I) of fewer elements stay with torch's product in :func:`matmul`: the paper
preset's recurrent weights (3,072 x 1,024) go to oneDNN, the demo preset's (768 x 256 and
smaller) do not. With the demo's too, ``make demo``'s generator stage took 525 s against 515 s
without (one run each, two threads): no gain there, and another rounding of its sums."""


def matmul(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """``a @ b`` for 2-d tensors, through oneDNN for float32 CPU tensors with a result of
    :data:`MIN_GRADIENT` elements or more (the weight gradients of the temporal VAE's training
    loop: one (O, N) x (N, I) product per weight), else torch's."""
    if (
        _ONEDNN
        and a.dtype == b.dtype == torch.float32
        and a.device.type == b.device.type == "cpu"
        and a.dim() == b.dim() == 2
        and a.shape[0] * b.shape[1] >= MIN_GRADIENT
    ):
        return _matmul(a, b)
    return a @ b


def fused_path(inputs: torch.Tensor) -> bool:
    """Whether the layers here may take their oneDNN path for ``inputs``: float32 on a CPU,
    outside autocast, oneDNN available (each layer adds its own size gate)."""
    return (
        inputs.device.type == "cpu"
        and inputs.dtype == torch.float32
        and _ONEDNN
        and not torch.is_autocast_enabled("cpu")
    )


class _Layout:
    """Time-major rows sorted by length, as a ``PackedSequence`` holds them: step t holds the
    ``sizes[t]`` longest items (in ``order``) at rows ``offsets[t] : offsets[t] + sizes[t]``.
    Items of equal length keep their batch order (a stable sort), so that the sums over rows of
    the backward do not depend on how ``pack_padded_sequence`` broke the ties: ``gather`` (None
    where its order is already this one) takes the packed rows to these."""

    def __init__(self, packed: PackedSequence):
        self.sizes = packed.batch_sizes.tolist()
        batch = self.sizes[0]
        packed_order = (
            torch.arange(batch) if packed.sorted_indices is None else packed.sorted_indices.cpu()
        )
        steps = packed.batch_sizes[None, :] > torch.arange(batch)[:, None]
        lengths = torch.empty(batch, dtype=torch.long)
        lengths[packed_order] = steps.sum(1)
        self.order = torch.argsort(-lengths, stable=True)  # longest first
        self.restore = torch.argsort(self.order)
        self.offsets = [0]
        for size in self.sizes:
            self.offsets.append(self.offsets[-1] + size)
        self.rows = self.offsets[-1]
        self.gather = self.scatter = None
        if not torch.equal(self.order, packed_order):
            rank = torch.argsort(packed_order)  # item -> its place in the packed rows of a step
            self.gather = torch.cat(
                [start + rank[self.order[:size]] for start, size in zip(self.offsets, self.sizes)]
            )
            self.scatter = torch.argsort(self.gather)


def _gates(gi: torch.Tensor, gh: torch.Tensor, h: torch.Tensor, hidden: int):
    """One GRU step from the input and hidden pre-activations (n, 3H) and the state (n, H)
    -> (new state, r, z, candidate)."""
    rz = torch.sigmoid(gi[:, : 2 * hidden] + gh[:, : 2 * hidden])
    r, z = rz[:, :hidden], rz[:, hidden:]
    candidate = torch.tanh(torch.addcmul(gi[:, 2 * hidden :], r, gh[:, 2 * hidden :]))
    return torch.lerp(candidate, h, z), r, z, candidate


class _BiGRU(torch.autograd.Function):
    """(packed rows (N, I), initial states (2, B, H), the two directions' weights) ->
    (packed outputs (N, 2H), last states (2, B, H))."""

    @staticmethod
    def forward(ctx, layout: _Layout, rows, h0, *weights):
        hidden = h0.shape[-1]
        keep = any(ctx.needs_input_grad[1:])  # the forward itself runs without grad
        outputs = rows.new_empty(layout.rows, 2 * hidden)
        lasts, saved = [], []
        for direction in range(2):
            w_ih, w_hh, b_ih, b_hh = weights[4 * direction : 4 * direction + 4]
            gi_all = _linear(rows, w_ih, b_ih)  # (N, 3H)
            # packing costs about five products of 64 rows: not worth it for a few captions
            packed = (
                torch.ops.mkldnn._reorder_linear_weight(w_hh) if len(layout.order) >= 4 else w_hh
            )
            h = h0[direction][layout.order].clone()  # (B, H), longest first
            states = outputs[:, direction * hidden : (direction + 1) * hidden]
            if keep:
                previous = rows.new_empty(layout.rows, hidden)
                gates = rows.new_empty(layout.rows, 4 * hidden)  # r, z, candidate, W_hn h + b
            steps = range(len(layout.sizes))
            for t in steps if direction == 0 else reversed(steps):
                size, start = layout.sizes[t], layout.offsets[t]
                end = start + size
                h_t = h[:size]
                gh = _linear(h_t, packed, b_hh)
                new, r, z, candidate = _gates(gi_all[start:end], gh, h_t, hidden)
                if keep:
                    previous[start:end] = h_t
                    gates[start:end] = torch.cat([r, z, candidate, gh[:, 2 * hidden :]], 1)
                states[start:end] = new
                h[:size] = new
            lasts.append(h[layout.restore])
            if keep:
                saved += [previous, gates]
        if keep:
            ctx.layout = layout
            ctx.save_for_backward(rows, h0, *saved, *weights)
        return outputs, torch.stack(lasts)

    @staticmethod
    def backward(ctx, grad_outputs, grad_last):
        layout = ctx.layout
        rows, h0, prev_f, gates_f, prev_b, gates_b, *weights = ctx.saved_tensors
        hidden = h0.shape[-1]
        if grad_outputs is None:
            grad_outputs = rows.new_zeros(layout.rows, 2 * hidden)
        if grad_last is None:
            grad_last = torch.zeros_like(h0)
        grad_rows = rows.new_zeros(layout.rows, rows.shape[1])
        grad_h0, grad_weights = [], []
        for direction, (previous, gates) in enumerate(((prev_f, gates_f), (prev_b, gates_b))):
            w_ih, w_hh, b_ih, b_hh = weights[4 * direction : 4 * direction + 4]
            packed_t = torch.ops.mkldnn._reorder_linear_weight(w_hh.t().contiguous())  # (H, 3H)
            grad_in = grad_outputs[:, direction * hidden : (direction + 1) * hidden]
            grad_gi = rows.new_empty(layout.rows, 3 * hidden)
            grad_gh = rows.new_empty(layout.rows, 3 * hidden)
            dh = grad_last[direction][layout.order].clone()  # (B, H)
            # the reverse of the forward's order of steps
            steps = range(len(layout.sizes))
            for t in reversed(steps) if direction == 0 else steps:
                size, start = layout.sizes[t], layout.offsets[t]
                end = start + size
                d = dh[:size] + grad_in[start:end]
                r, z, candidate, gh_n = gates[start:end].split(hidden, dim=1)
                h = previous[start:end]
                d_candidate = d * (1 - z) * (1 - candidate * candidate)
                d_z = d * (h - candidate) * z * (1 - z)
                d_r = d_candidate * gh_n * r * (1 - r)
                grad_gi[start:end] = torch.cat([d_r, d_z, d_candidate], 1)
                grad_gh[start:end] = torch.cat([d_r, d_z, d_candidate * r], 1)
                dh[:size] = d * z + _linear(grad_gh[start:end], packed_t)
            grad_h0.append(dh[layout.restore])
            grad_rows += _matmul(grad_gi, w_ih)
            grad_weights += [
                _matmul(grad_gi.t(), rows),
                _matmul(grad_gh.t(), previous),
                grad_gi.sum(0),
                grad_gh.sum(0),
            ]
        return None, grad_rows, torch.stack(grad_h0), *grad_weights


def fused_gru(gru: nn.Module, inputs: torch.Tensor) -> bool:
    """Whether :class:`FusedGRU` runs ``gru`` over ``inputs`` fused: a float32 one-layer
    bidirectional ``nn.GRU`` of hidden size 256 or more (:data:`MIN_WEIGHT`) on the fused
    path."""
    if not isinstance(gru, nn.GRU) or not fused_path(inputs):
        return False
    if not (gru.bidirectional and gru.num_layers == 1):
        return False
    weight = gru.weight_hh_l0
    return weight.dtype == torch.float32 and weight.numel() >= 6 * MIN_WEIGHT


def _packed_bigru(gru: nn.GRU, packed: PackedSequence, h0: torch.Tensor):
    """:class:`_BiGRU` over ``packed`` -> (packed outputs, last states (2, B, H))."""
    weights = [
        getattr(gru, f"{name}_l0{suffix}")
        for suffix in ("", "_reverse")
        for name in ("weight_ih", "weight_hh", "bias_ih", "bias_hh")
    ]
    layout = _Layout(packed)
    rows = (
        packed.data if layout.gather is None else packed.data[layout.gather.to(packed.data.device)]
    )
    outputs, last = _BiGRU.apply(layout, rows, h0, *weights)
    if layout.scatter is not None:
        outputs = outputs[layout.scatter.to(outputs.device)]
    return PackedSequence(
        outputs, packed.batch_sizes, packed.sorted_indices, packed.unsorted_indices
    ), last


class FusedGRU(nn.GRU):
    """``nn.GRU`` (same parameters and state dict) that runs a float32 one-layer bidirectional
    GRU over a ``PackedSequence`` as one autograd node (:func:`fused_gru` says where);
    elsewhere ``nn.GRU``."""

    def forward(self, inputs, hx=None):
        if isinstance(inputs, PackedSequence) and hx is not None and fused_gru(self, inputs.data):
            return _packed_bigru(self, inputs, hx)
        return super().forward(inputs, hx)


def bidirectional_gru(
    gru: nn.GRU, inputs: torch.Tensor, lengths: torch.Tensor, h0: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """``gru`` (one layer, bidirectional, batch first) over ``inputs`` (B, L, I) of ``lengths``
    (B,) from ``h0`` (2, B, H) -> (outputs (B, L, 2H), zero past each length; last states
    (2, B, H)): what ``gru`` gives over ``pack_padded_sequence(inputs, lengths,
    enforce_sorted=False)`` padded back to L, fused where :func:`fused_gru` allows."""
    if not (gru.bidirectional and gru.num_layers == 1 and gru.batch_first):
        raise ValueError("bidirectional_gru needs a one-layer bidirectional batch-first GRU")
    packed = pack_padded_sequence(inputs, lengths.cpu(), batch_first=True, enforce_sorted=False)
    if fused_gru(gru, inputs):
        outputs, last = _packed_bigru(gru, packed, h0)
    else:
        outputs, last = gru(packed, h0)
    outputs, _ = pad_packed_sequence(outputs, batch_first=True, total_length=inputs.shape[1])
    return outputs, last


class FastLinear(nn.Linear):
    """``nn.Linear`` (same parameters and state dict) whose float32 CPU product runs through
    oneDNN, its gradients too (:func:`_product`); elsewhere ``F.linear``. A weight that is a
    strided view (a column block of a stacked matrix) goes to ``F.linear`` too: oneDNN
    rearranges such a weight on every call (10-100x slower)."""

    def forward(self, inputs: torch.Tensor) -> torch.Tensor:
        weight = self.weight
        if not (
            fused_path(inputs)
            and weight.dtype == torch.float32
            and weight.is_contiguous()
            and weight.numel() >= MIN_WEIGHT
        ):
            return F.linear(inputs, weight, self.bias)
        flat = inputs.reshape(-1, inputs.shape[-1]).contiguous()
        return _product(flat, weight, self.bias).view(*inputs.shape[:-1], weight.shape[0])


def plain_linear(linear: FastLinear) -> nn.Linear:
    """An ``nn.Linear`` holding ``linear``'s parameters (for code that maps exact types, such
    as torch's dynamic quantisation)."""
    plain = nn.Linear(
        linear.in_features, linear.out_features, bias=linear.bias is not None, device="meta"
    )
    plain.weight = linear.weight
    if linear.bias is not None:
        plain.bias = linear.bias
    return plain


class _Product(torch.autograd.Function):
    """``inputs (N, I) @ weight (O, I).T + bias`` through oneDNN, gradients too (the products
    of :class:`FastLinear` and :class:`FastConv1d`)."""

    @staticmethod
    def forward(ctx, inputs, weight, bias):
        ctx.save_for_backward(inputs, weight)
        ctx.has_bias = bias is not None
        return _linear(inputs, weight, bias)

    @staticmethod
    def backward(ctx, grad):
        inputs, weight = ctx.saved_tensors
        grad = grad.contiguous()
        grad_inputs = _matmul(grad, weight) if ctx.needs_input_grad[0] else None
        grad_weight = _matmul(grad.t(), inputs) if ctx.needs_input_grad[1] else None
        grad_bias = grad.sum(0) if ctx.has_bias and ctx.needs_input_grad[2] else None
        return grad_inputs, grad_weight, grad_bias


def _product(inputs: torch.Tensor, weight: torch.Tensor, bias: torch.Tensor | None):
    """:class:`_Product` where a graph is recorded, the bare oneDNN product where none is."""
    if torch.is_grad_enabled() and (inputs.requires_grad or weight.requires_grad):
        return _Product.apply(inputs, weight, bias)
    return _linear(inputs, weight, bias)


def _halving(layer: nn.Module) -> bool:
    """Whether a 1-d convolution is the autoencoder's (kernel 4, stride 2, padding 1, no
    dilation or groups) and large enough for the fused path (the paper's, not the demo's)."""
    return (
        layer.weight.numel() >= 8 * MIN_WEIGHT
        and layer.kernel_size == (4,)
        and layer.stride == (2,)
        and layer.padding == (1,)
        and layer.dilation == (1,)
        and layer.groups == 1
        and layer.padding_mode == "zeros"
    )


class FastConv1d(nn.Conv1d):
    """``nn.Conv1d`` (same parameters) that, for kernel 4, stride 2, padding 1 on float32 CPU
    tensors of even length, runs as one oneDNN product over the frame windows: output frame i
    reads padded frames 2i .. 2i + 3, that is the pairs i and i + 1 of the padded sequence
    seen as (T / 2 + 1) pairs. Elsewhere ``nn.Conv1d``. :meth:`frames` takes and gives
    frame-major tensors (B, T, C), saving the transposes."""

    def forward(self, inputs: torch.Tensor) -> torch.Tensor:
        if not (fused_path(inputs) and _halving(self) and inputs.shape[-1] % 2 == 0):
            return super().forward(inputs)
        return self.frames(inputs.transpose(1, 2)).transpose(1, 2)

    def frames(self, inputs: torch.Tensor) -> torch.Tensor:
        """(B, T, C), T even -> (B, T / 2, O) on the fused path."""
        batch, frames, channels = inputs.shape
        padded = F.pad(inputs, (0, 0, 1, 1))  # (B, T + 2, C)
        pairs = padded.view(batch, frames // 2 + 1, 2 * channels)
        windows = torch.cat([pairs[:, :-1], pairs[:, 1:]], dim=-1)  # (B, T/2, 4C)
        # (O, C, 4) -> (O, 4, C) -> (O, 4C): the windows' order, tap by tap
        weight = self.weight.permute(0, 2, 1).reshape(self.out_channels, -1)
        out = _product(windows.view(-1, 4 * channels), weight, self.bias)
        return out.view(batch, frames // 2, self.out_channels)


def frame_major(net: nn.Sequential, inputs: torch.Tensor, factor: int) -> torch.Tensor | None:
    """``net`` (:class:`FastConv1d` layers, dropout, activations) on frame-major ``inputs``
    (B, T, C) through :meth:`FastConv1d.frames`, or None where the fused path does not apply
    (T not a multiple of ``factor``, the time reduction)."""
    if not fused_path(inputs) or inputs.shape[1] % factor:
        return None
    for layer in net:
        if isinstance(layer, nn.Conv1d) and not (isinstance(layer, FastConv1d) and _halving(layer)):
            return None
    hidden = inputs
    for layer in net:
        hidden = layer.frames(hidden) if hasattr(layer, "frames") else layer(hidden)
    return hidden


class FastMovementEncoder(MovementEncoder):
    """:class:`~t2m.models.autoencoder.MovementEncoder` whose convolutions run frame-major
    (:func:`frame_major`: no transposes between its :class:`FastConv1d` layers) where they can."""

    def forward(self, features: torch.Tensor) -> torch.Tensor:
        hidden = frame_major(self.net, features, SNIPPET_FRAMES)
        if hidden is None:
            return super().forward(features)
        return self.out(hidden)


ACCELERATED = {
    nn.Linear: FastLinear,
    nn.Conv1d: FastConv1d,
    nn.GRU: FusedGRU,
    MovementEncoder: FastMovementEncoder,
}
"""Each plain layer and the oneDNN subclass :func:`use_onednn` puts in its place."""


def use_onednn(module: nn.Module) -> None:
    """Swap the layers of ``module`` whose exact type :data:`ACCELERATED` names for their
    oneDNN subclass, in place (the same parameters, buffers and state dict keys). A temporal
    VAE's own layers stay as they are (its loops run in :mod:`t2m.accel.recurrence` and
    :mod:`t2m.accel.plans`): only its text encoder's are swapped."""
    if isinstance(module, TemporalVAE):
        use_onednn(module.text_encoder)
        return
    fast = ACCELERATED.get(type(module))
    if fast is not None:
        module.__class__ = fast
    for child in module.children():
        use_onednn(child)


def plain_layer(layer: nn.Module) -> nn.Module:
    """``layer`` as the torch layer it stands for, for code that maps exact types (torch's
    dynamic quantisation): a :class:`FastLinear` as a new ``nn.Linear`` holding its parameters;
    any other layer of :data:`ACCELERATED` turned back in place; anything else as it is."""
    if isinstance(layer, FastLinear):
        return plain_linear(layer)
    for plain, fast in ACCELERATED.items():
        if type(layer) is fast:
            layer.__class__ = plain
    return layer
