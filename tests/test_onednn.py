"""The fused oneDNN GRU and Linear (t2m/accel/onednn.py) against torch's own layers.

Tolerances: the fused layers and torch's sum the same products in another order, so each is
compared with torch's float32 layer through both sides' distances to a float64 evaluation of the
same weights (``tests.tolerances.assert_same_rounding``: each within 16x the other's), not with a
constant: sums of 5 to 300 terms give deviations of 1e-7 to 1e-5 by machine and order, a wrong
gate, weight or missing term 1e-2 or more."""

import copy

import pytest
import torch
import torch.nn.functional as F
from torch import nn
from torch.nn.utils.rnn import pack_padded_sequence, pad_packed_sequence

from t2m.accel import onednn
from t2m.accel.onednn import (
    FastConv1d,
    FastLinear,
    bidirectional_gru,
    frame_major,
    fused_gru,
    fused_path,
    matmul,
    plain_linear,
)
from tests.tolerances import assert_same_rounding

pytestmark = pytest.mark.skipif(
    not torch.backends.mkldnn.is_available(), reason="the fused path needs oneDNN"
)


@pytest.fixture(autouse=True)
def fused_at_any_size(monkeypatch):
    """These small layers take the fused path (by default only layers of 32,768 weights and
    more do, ``test_small_layers_stay_with_torch``)."""
    monkeypatch.setattr(onednn, "MIN_WEIGHT", 0)
    monkeypatch.setattr(onednn, "MIN_GRADIENT", 0)


def packed_reference(gru, inputs, lengths, h0):
    packed = pack_padded_sequence(inputs, lengths, batch_first=True, enforce_sorted=False)
    outputs, last = gru(packed, h0)
    outputs, _ = pad_packed_sequence(outputs, batch_first=True, total_length=inputs.shape[1])
    return outputs, last


def values_and_gradients(function, gru, inputs, h0, weights):
    """Outputs, last states and the gradients of a fixed random projection of both."""
    for tensor in (inputs, h0, *gru.parameters()):
        tensor.grad = None
    outputs, last = function()
    ((outputs * weights[0]).sum() + (last * weights[1]).sum()).backward()
    grads = [inputs.grad, h0.grad, *(p.grad for p in gru.parameters())]
    return [outputs.detach(), last.detach(), *(g.clone() for g in grads)]


@pytest.mark.parametrize(
    "lengths", [[3, 9, 1, 5, 9, 2, 4], [9] * 7, [1, 1, 2, 1, 1, 1, 1], [2, 5], [4]]
)
def test_fused_gru_equals_packed_nn_gru(lengths):
    torch.manual_seed(0)
    gru = nn.GRU(5, 6, batch_first=True, bidirectional=True)
    batch = len(lengths)  # under 4: the hidden weights are not packed
    inputs = torch.randn(batch, max(lengths) + 1, 5, requires_grad=True)  # a padded step at least
    h0 = torch.randn(2, batch, 6, requires_grad=True)
    lengths = torch.tensor(lengths)
    weights = torch.randn(batch, inputs.shape[1], 12), torch.randn(2, batch, 6)
    assert fused_gru(gru, inputs)
    expected = values_and_gradients(
        lambda: packed_reference(gru, inputs, lengths, h0), gru, inputs, h0, weights
    )
    got = values_and_gradients(
        lambda: bidirectional_gru(gru, inputs, lengths, h0), gru, inputs, h0, weights
    )
    gru64 = copy.deepcopy(gru).double()
    inputs64, h064 = (x.detach().double().requires_grad_() for x in (inputs, h0))
    exact = values_and_gradients(
        lambda: packed_reference(gru64, inputs64, lengths, h064),
        gru64,
        inputs64,
        h064,
        [w.double() for w in weights],
    )
    names = ["outputs", "last", "d inputs", "d h0"] + [n for n, _ in gru.named_parameters()]
    for name, a, b, c in zip(names, expected, got, exact, strict=True):
        assert a.shape == b.shape, name
        assert_same_rounding(b, a, c, msg=name)
    # zero past each length, as pad_packed_sequence pads
    for item, length in enumerate(lengths.tolist()):
        assert got[0][item, length:].abs().max() == 0


def test_fused_gru_without_gradients_and_fallbacks():
    torch.manual_seed(1)
    gru = nn.GRU(4, 3, batch_first=True, bidirectional=True)
    inputs, h0, lengths = torch.randn(5, 6, 4), torch.randn(2, 5, 3), torch.tensor([6, 2, 4, 1, 3])
    with torch.no_grad():
        expected = packed_reference(gru, inputs, lengths, h0)
        fused = bidirectional_gru(gru, inputs, lengths, h0)
        exact = packed_reference(copy.deepcopy(gru).double(), inputs.double(), lengths, h0.double())
    for a, b, c in zip(expected, fused, exact, strict=True):
        assert_same_rounding(b, a, c)
    # float64 and bfloat16 autocast take nn.GRU itself
    assert not fused_path(inputs.double())
    with torch.autocast("cpu", dtype=torch.bfloat16):
        assert not fused_path(inputs)
    double = nn.GRU(4, 3, batch_first=True, bidirectional=True).double()
    out, last = bidirectional_gru(double, inputs.double(), lengths, h0.double())
    assert out.dtype == torch.float64 and last.shape == (2, 5, 3)
    with pytest.raises(ValueError, match="bidirectional"):
        bidirectional_gru(nn.GRU(4, 3, batch_first=True), inputs, lengths, h0[:1])


def test_fast_linear_equals_linear_and_quantises():
    torch.manual_seed(2)
    fast = FastLinear(7, 5)
    plain = nn.Linear(7, 5)
    plain.load_state_dict(fast.state_dict())
    assert list(fast.state_dict()) == ["weight", "bias"]
    inputs = torch.randn(3, 4, 7, requires_grad=True)
    for layer in (plain, fast):
        layer.zero_grad()
    inputs.grad = None
    a = plain(inputs)
    a.square().sum().backward()
    grads_plain = inputs.grad.clone(), plain.weight.grad.clone(), plain.bias.grad.clone()
    inputs.grad = None
    b = fast(inputs)
    b.square().sum().backward()
    exact64 = copy.deepcopy(plain).double()
    inputs64 = inputs.detach().double().requires_grad_()
    c = exact64(inputs64)
    c.square().sum().backward()
    assert_same_rounding(b, a, c)
    for g_fast, g_plain, g_exact in zip(
        (inputs.grad, fast.weight.grad, fast.bias.grad),
        grads_plain,
        (inputs64.grad, exact64.weight.grad, exact64.bias.grad),
        strict=True,
    ):
        assert_same_rounding(g_fast, g_plain, g_exact)
    # without a graph: the bare oneDNN product
    assert_same_rounding(fast(inputs.detach()), F.linear(inputs, fast.weight, fast.bias), c)
    # torch's dynamic quantisation maps exact types: the plain view shares the parameters
    view = plain_linear(fast)
    assert type(view) is nn.Linear and view.weight is fast.weight

    from t2m.accel.int8 import quantize_int8

    model = nn.Sequential(FastLinear(7, 5))
    quantized = quantize_int8(model)
    assert type(quantized[0]).__name__ == "Linear" and "dynamic" in type(quantized[0]).__module__


def test_fast_conv_equals_conv1d_against_float64():
    """Values and gradients within float32 rounding of a float64 reference, as torch's own."""
    torch.manual_seed(3)
    conv = nn.Conv1d(9, 6, 4, 2, 1)
    fast = FastConv1d(9, 6, 4, 2, 1)
    fast.load_state_dict(conv.state_dict())
    inputs = torch.randn(5, 9, 12)
    grad = torch.randn(5, 6, 6)
    results = {}
    for name, layer, dtype in (("torch", conv, torch.float32), ("fast", fast, torch.float32)):
        x = inputs.to(dtype).clone().requires_grad_()
        (layer(x) * grad).sum().backward()
        results[name] = [layer(x).detach(), x.grad, layer.weight.grad, layer.bias.grad]
    reference = nn.Conv1d(9, 6, 4, 2, 1).double()
    reference.load_state_dict(conv.state_dict())
    x = inputs.double().requires_grad_()
    (reference(x) * grad.double()).sum().backward()
    expected = [reference(x).detach(), x.grad, reference.weight.grad, reference.bias.grad]
    for got, plain, want in zip(results["fast"], results["torch"], expected, strict=True):
        assert_same_rounding(got, plain, want)
    # frame-major through a Sequential, odd lengths and other kernels fall back: the same
    # kernels on the same operands, equal bit for bit
    net = nn.Sequential(fast, nn.LeakyReLU(0.2))
    assert torch.equal(frame_major(net, inputs.transpose(1, 2), 2), net(inputs).transpose(1, 2))
    assert frame_major(net, inputs[..., :11].transpose(1, 2), 2) is None
    assert torch.equal(fast(inputs[..., :11]), conv(inputs[..., :11]))
    other = FastConv1d(9, 6, 3, 1, 1)
    assert frame_major(nn.Sequential(other), inputs.transpose(1, 2), 1) is None


def test_small_layers_stay_with_torch(monkeypatch):
    monkeypatch.setattr(onednn, "MIN_WEIGHT", 32_768)
    inputs = torch.randn(2, 5, 64)
    assert not fused_gru(nn.GRU(64, 64, batch_first=True, bidirectional=True), inputs)
    assert fused_gru(nn.GRU(64, 256, batch_first=True, bidirectional=True), inputs)
    assert not fused_gru(nn.GRU(64, 256, batch_first=True, bidirectional=True), inputs.double())
    small, conv = FastConv1d(64, 64, 4, 2, 1), FastConv1d(259, 512, 4, 2, 1)
    assert frame_major(nn.Sequential(small), inputs, 2) is None
    assert frame_major(nn.Sequential(conv), torch.randn(2, 6, 259), 2) is not None


def test_matmul_through_onednn_equals_torch():
    torch.manual_seed(4)
    a, b = torch.randn(40, 300), torch.randn(300, 70)
    exact = a.double() @ b.double()
    assert_same_rounding(matmul(a, b), a @ b, exact)
    assert_same_rounding(matmul(a.t().t(), b.t().contiguous().t()), a @ b, exact)
    assert matmul(a.double(), b.double()).dtype == torch.float64  # torch's own
