"""Every generation backend (a :class:`t2m.models.temporal_vae.Rollout`) against the plain one,
:class:`~t2m.models.temporal_vae.StepRollout`, within the tolerance the backend states; and the
models' independence of :mod:`t2m.accel`.

Each backend is made by :func:`t2m.accel.accelerate` from a copy of one float32 model and run on
the same state, word context, time codes and draws, computed by the float32 model: what differs
is the rollout alone. Tolerances (a share of the largest code) are the backends' own:
``FLOAT32_TOLERANCE`` 1e-5 for the same sums in another order (observed about 1e-7),
``INT8_TOLERANCE`` 5% for int8 weights and activations (derived in
``tests/test_temporal_vae.py::test_int8_copy_is_close_to_float32``)."""

from __future__ import annotations

import copy
import subprocess
import sys

import pytest
import torch

from t2m.accel import accelerate
from t2m.accel.onnx import available as onnx_available
from t2m.models.temporal_vae import StepRollout, TemporalVAE
from tests.test_temporal_vae import CODE, CONFIG, LATENT, WORD_DIM, randn, text

BACKENDS = [
    ("fp32", "torch"),
    ("int8", "torch"),
    pytest.param(
        "fp32",
        "onnx",
        marks=pytest.mark.skipif(not onnx_available(), reason="no onnxruntime"),
    ),
    pytest.param(
        "int8",
        "onnx",
        marks=pytest.mark.skipif(not onnx_available(), reason="no onnxruntime"),
    ),
]


def inputs(vae: TemporalVAE, batch: int):
    """(state, context, time codes, noise, lengths) of the float model, items 10, 7, 4, ... long."""
    features, sentence, mask = text(vae, batch)
    lengths = torch.tensor([10 - 3 * (i % 3) for i in range(batch)])
    state = vae.initial_state(sentence, randn(CODE, seed=2))
    return (
        state,
        vae.word_context(features, mask),
        vae.time_codes(lengths, 10),
        randn(batch, 10, LATENT, seed=3),
        lengths,
    )


@pytest.mark.parametrize("batch", [1, 3])
@pytest.mark.parametrize(("precision", "backend"), BACKENDS)
def test_each_rollout_is_the_step_within_its_tolerance(precision, backend, batch):
    torch.manual_seed(0)
    vae = TemporalVAE(WORD_DIM, CODE, CONFIG).eval()
    fast = accelerate(copy.deepcopy(vae), precision, backend)
    rollout = fast.generation_rollout
    assert rollout is not None and 0 < rollout.tolerance <= 0.05
    with torch.inference_mode():
        args = inputs(vae, batch)
        reference_state, reference = StepRollout(vae)(*args)
        state, codes = rollout(*args)
    scale = reference.abs().max()
    assert codes.shape == reference.shape
    assert (codes - reference).abs().max() <= rollout.tolerance * scale
    # each item's state stops after its last step, as the step's does
    for ours, theirs in zip(state[:3], reference_state[:3], strict=True):
        assert (ours - theirs).abs().max() <= rollout.tolerance * theirs.abs().max()
    assert state.posterior is None


@torch.no_grad()
def test_generate_runs_the_rollout_set_and_the_step_without_one():
    torch.manual_seed(0)
    vae = TemporalVAE(WORD_DIM, CODE, CONFIG).eval()
    features, sentence, mask = text(vae)
    args = (features, sentence, mask, torch.tensor([6, 3, 5]), randn(CODE, seed=2))
    noise = randn(3, 6, LATENT, seed=3)
    plain = vae.generate(*args, noise=noise)
    assert torch.equal(plain, vae.generate(*args, noise=noise, rollout=StepRollout(vae)))
    calls = []

    class Recording(StepRollout):
        def __call__(self, *arguments, **options):
            calls.append(len(arguments))
            return super().__call__(*arguments, **options)

    vae.set_rollout(Recording(vae))
    assert torch.equal(vae.generate(*args, noise=noise), plain) and calls == [4]
    vae.set_rollout(None)
    assert "generation_rollout" not in "".join(vae.state_dict())


def test_accelerate_keeps_the_state_dict_and_copies_make_their_own_plans():
    torch.manual_seed(0)
    vae = TemporalVAE(WORD_DIM, CODE, CONFIG).eval()
    keys = {name: tensor.shape for name, tensor in vae.state_dict().items()}
    fast = accelerate(vae)
    assert {name: tensor.shape for name, tensor in fast.state_dict().items()} == keys
    assert type(fast.text_encoder.gru).__module__ == "t2m.accel.onednn"
    assert type(fast.query) is torch.nn.Linear  # its own layers run in the plans
    copied = copy.deepcopy(fast)
    assert copied.generation_rollout.vae is copied and copied.training_pass is not None


def test_the_models_import_nothing_from_accel():
    code = (
        "import sys, t2m.models.temporal_vae, t2m.models.evaluator, t2m.models.length, "
        "t2m.models.autoencoder; print(any(m.startswith('t2m.accel') for m in sys.modules))"
    )
    found = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert found.returncode == 0, found.stderr
    assert found.stdout.strip() == "False"
