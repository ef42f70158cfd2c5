"""Models: shapes, determinism, masking, and the fast temporal-VAE loop against a plain one."""

from __future__ import annotations

import pytest
import torch
import torch.nn.functional as F

from t2m.config import (
    AutoencoderConfig,
    EvaluatorConfig,
    LengthModelConfig,
    TemporalVAEConfig,
    TextEncoderConfig,
)
from t2m.models.autoencoder import MovementAutoencoder, autoencoder_loss
from t2m.models.evaluator import Evaluator, contrastive_loss
from t2m.models.length import LengthEstimator, sample_lengths
from t2m.models.temporal_vae import TemporalVAE, gaussian_kl, temporal_vae_loss
from t2m.models.text_encoder import TextEncoder

WORD_DIM, L = 12, 22
AE = AutoencoderConfig(hidden_size=24, code_size=16, dropout=0.2)
VAE = TemporalVAEConfig(
    text=TextEncoderConfig(hidden_size=10), hidden_size=20, latent_size=6, attention_size=8
)


def text_batch(batch: int, seed: int = 0, vocab: int = 0):
    generator = torch.Generator().manual_seed(seed)
    if vocab:
        words = torch.randint(0, vocab, (batch, L), generator=generator)
    else:
        words = torch.randn(batch, L, WORD_DIM, generator=generator)
    pos = F.one_hot(torch.randint(0, 15, (batch, L), generator=generator), 15).float()
    lengths = torch.randint(3, L + 1, (batch,), generator=generator)
    return words, pos, lengths


def test_autoencoder_shapes_and_loss():
    torch.manual_seed(0)
    model = MovementAutoencoder(263, AE).eval()
    motion = torch.randn(3, 24, 263)
    reconstruction, codes = model(motion)
    assert codes.shape == (3, 6, 16) and reconstruction.shape == (3, 24, 263)
    # the encoder ignores the four contact dims
    changed = motion.clone()
    changed[..., -4:] = 5.0
    assert torch.equal(model.encode(changed), codes)
    losses = autoencoder_loss(reconstruction, motion, codes)
    expected = (
        F.l1_loss(reconstruction, motion)
        + 0.001 * codes.abs().mean()
        + 0.001 * (codes[:, 1:] - codes[:, :-1]).abs().mean()
    )
    assert torch.allclose(losses["loss"], expected)
    smooth = autoencoder_loss(reconstruction, motion, codes, reconstruction_loss="smooth_l1")
    # Huber with beta 1: half the squared error below 1, the error less a half above
    error = (reconstruction - motion).abs()
    huber = torch.where(error < 1, 0.5 * error**2, error - 0.5).mean()
    assert torch.allclose(smooth["reconstruction"], huber)
    assert torch.allclose(
        smooth["loss"] - smooth["reconstruction"], expected - losses["reconstruction"]
    )
    with pytest.raises(ValueError, match="unknown reconstruction loss"):
        autoencoder_loss(reconstruction, motion, codes, reconstruction_loss="l2")
    with pytest.raises(ValueError, match="multiple of 4"):
        model.encode(torch.randn(1, 10, 263))


def test_text_encoder_masks_padding_and_takes_ids():
    torch.manual_seed(0)
    encoder = TextEncoder(WORD_DIM, TextEncoderConfig(hidden_size=10))
    words, pos, lengths = text_batch(4)
    features, sentence = encoder(words, pos, lengths)
    assert features.shape == (4, L, 20) and sentence.shape == (4, 20)
    for row, length in enumerate(lengths.tolist()):
        assert torch.all(features[row, length:] == 0)
    noisy = words.clone()
    noisy[0, lengths[0] :] = 100.0  # padding content must not matter
    _, sentence2 = encoder(noisy, pos, lengths)
    assert torch.allclose(sentence, sentence2)
    trainable = TextEncoder(WORD_DIM, TextEncoderConfig(hidden_size=10), vocab_size=30)
    ids, pos, lengths = text_batch(2, vocab=30)
    assert trainable(ids, pos, lengths)[1].shape == (2, 20)
    with pytest.raises(ValueError, match="word ids"):
        trainable(torch.randn(2, L, WORD_DIM), pos, lengths)


def test_length_estimator_and_sampling():
    torch.manual_seed(0)
    model = LengthEstimator(
        WORD_DIM, LengthModelConfig(text=TextEncoderConfig(hidden_size=8), mlp_sizes=(16, 8))
    ).eval()
    logits = model(*text_batch(5))
    assert logits.shape == (5, 50)
    # all mass on class 3 (< 10 units): redraws cannot escape it, so the floor applies
    peaked = torch.full((4, 50), -1e4)
    peaked[:, 3] = 0
    units = sample_lengths(peaked, torch.Generator().manual_seed(0))
    assert torch.equal(units, torch.full((4,), 10))
    draw = lambda seed: sample_lengths(logits, torch.Generator().manual_seed(seed))  # noqa: E731
    assert torch.equal(draw(1), draw(1))
    assert (draw(2) >= 10).all()


def reference_forward(
    vae: TemporalVAE, words, pos, lengths, codes, initial, teacher_forcing, noise
):
    """The temporal VAE written plainly: concatenated inputs, attention recomputed each step."""
    features, sentence, mask = vae.encode_text(words, pos, lengths)
    batch, steps, _ = codes.shape
    h_pri, h_pos, h_gen = (
        block.initial(sentence) for block in (vae.prior, vae.posterior, vae.generator)
    )
    previous = initial.expand(batch, -1)
    outputs = []
    for i in range(steps):
        query = vae.query(h_gen)
        keys, values = vae.key(features), vae.value(features)
        scores = (keys @ query[:, :, None]).squeeze(-1) / keys.shape[-1] ** 0.5
        weights = torch.softmax(scores.masked_fill(~mask, float("-inf")), -1)
        attention = (weights[:, :, None] * values).sum(1)
        time_code = vae.time_table[torch.full((batch,), steps - i)]

        def run(block, inputs, hidden, time_code=time_code):
            pre = block.norm(block.input(inputs))
            return block.cell(F.leaky_relu(pre, 0.2) + time_code, hidden)

        h_pos = run(vae.posterior, torch.cat([previous, codes[:, i], attention], -1), h_pos)
        h_pri = run(vae.prior, torch.cat([previous, attention], -1), h_pri)
        mean, logvar = vae.posterior_gaussian(h_pos)
        z = mean + torch.exp(0.5 * logvar) * noise[:, i]
        h_gen = run(vae.generator, torch.cat([previous, attention, z], -1), h_gen)
        code = vae.output(h_gen)
        outputs.append(code)
        previous = codes[:, i] if teacher_forcing else code.detach()
    return torch.stack(outputs, 1)


@pytest.mark.parametrize("teacher_forcing", [True, False])
def test_temporal_vae_fast_loop_equals_plain_arithmetic(teacher_forcing):
    torch.manual_seed(0)
    vae = TemporalVAE(WORD_DIM, 16, VAE).eval()
    words, pos, lengths = text_batch(3)
    codes = torch.randn(3, 7, 16)
    initial = torch.randn(16)
    noise = torch.randn(3, 7, 6)
    features, sentence, mask = vae.encode_text(words, pos, lengths)
    fast = vae(features, sentence, mask, codes, initial, teacher_forcing, noise)
    plain = reference_forward(vae, words, pos, lengths, codes, initial, teacher_forcing, noise)
    assert fast["codes"].shape == (3, 7, 16) and fast["prior_mean"].shape == (3, 7, 6)
    assert torch.allclose(fast["codes"], plain, atol=1e-5)


def test_temporal_vae_generate_masks_lengths_and_is_seeded():
    torch.manual_seed(0)
    vae = TemporalVAE(WORD_DIM, 16, VAE).eval()
    words, pos, lengths = text_batch(3)
    features, sentence, mask = vae.encode_text(words, pos, lengths)
    snippets = torch.tensor([10, 4, 7])
    initial = torch.zeros(16)
    codes = vae.generate(
        features, sentence, mask, snippets, initial, torch.Generator().manual_seed(5)
    )
    assert codes.shape == (3, 10, 16)
    assert (
        torch.all(codes[1, 4:] == 0)
        and torch.all(codes[2, 7:] == 0)
        and codes[1, :4].abs().sum() > 0
    )
    again = vae.generate(
        features, sentence, mask, snippets, initial, torch.Generator().manual_seed(5)
    )
    other = vae.generate(
        features, sentence, mask, snippets, initial, torch.Generator().manual_seed(6)
    )
    assert torch.equal(codes, again) and not torch.allclose(codes, other)
    with pytest.raises(ValueError, match="num_snippets"):
        vae.generate(features, sentence, mask, torch.tensor([0, 3, 3]), initial)


def test_temporal_vae_loss_and_kl():
    mean = torch.randn(2, 3, 4)
    logvar = torch.randn(2, 3, 4)
    assert torch.allclose(gaussian_kl(mean, logvar, mean, logvar), torch.zeros(2, 3), atol=1e-6)
    kl = gaussian_kl(torch.ones(1, 1), torch.zeros(1, 1), torch.zeros(1, 1), torch.zeros(1, 1))
    assert torch.allclose(kl, torch.tensor([[0.5]]))
    outputs = {"codes": torch.zeros(2, 3, 5), "posterior_mean": mean, "posterior_logvar": logvar,
               "prior_mean": mean, "prior_logvar": logvar}  # fmt: skip
    losses = temporal_vae_loss(
        outputs, torch.ones(2, 3, 5), torch.zeros(2, 12, 7), torch.zeros(2, 12, 7)
    )
    assert torch.allclose(losses["loss"], torch.tensor(0.5))  # SmoothL1(0, 1) = 0.5, rest zero


def test_temporal_vae_backward_reaches_every_parameter():
    torch.manual_seed(0)
    vae = TemporalVAE(WORD_DIM, 16, VAE)
    features, sentence, mask = vae.encode_text(*text_batch(2))
    out = vae(features, sentence, mask, torch.randn(2, 5, 16), torch.zeros(16), False)
    (out["codes"].square().mean() + gaussian_kl(out["posterior_mean"], out["posterior_logvar"],
                                                out["prior_mean"], out["prior_logvar"]).mean()).backward()  # fmt: skip
    missing = [
        name
        for name, p in vae.named_parameters()
        if p.grad is None or not torch.isfinite(p.grad).all()
    ]
    assert not missing


def test_evaluator_shapes_frozen_encoder_and_contrastive_loss():
    torch.manual_seed(0)
    evaluator = Evaluator(WORD_DIM, 263, AE, EvaluatorConfig(text=TextEncoderConfig(hidden_size=8),
                                                              motion_hidden_size=12, embedding_size=6))  # fmt: skip
    evaluator.train()
    assert not evaluator.movement_encoder.training
    assert not any(p.requires_grad for p in evaluator.movement_encoder.parameters())
    words, pos, lengths = text_batch(4)
    motion = torch.randn(4, 40, 263)
    motion_lengths = torch.tensor([40, 24, 16, 40])
    text, moving = evaluator(words, pos, lengths, motion, motion_lengths)
    assert text.shape == (4, 6) and moving.shape == (4, 6)
    # content past a motion's length (beyond the convolutions' reach of 3 frames) is ignored
    padded = motion.clone()
    padded[1, 27:] = 3.0
    assert torch.allclose(evaluator.embed_motion(padded, motion_lengths)[1], moving[1], atol=1e-6)
    with pytest.raises(ValueError, match="zero shift"):
        contrastive_loss(text, moving, 0)
    same = contrastive_loss(text, text, 1, margin=10.0)
    assert same["positive"] < 1e-9
    far = contrastive_loss(
        torch.zeros(3, 2), torch.tensor([[0.0, 20.0], [0.0, 0.0], [0.0, 0.0]]), 1, margin=10.0
    )
    assert torch.allclose(far["positive"], torch.tensor(400.0 / 3), rtol=1e-4)


def test_temporal_vae_runs_under_bf16_autocast():
    torch.manual_seed(0)
    vae = TemporalVAE(WORD_DIM, 16, VAE).eval()
    features, sentence, mask = vae.encode_text(*text_batch(2))
    codes, noise = torch.randn(2, 5, 16), torch.randn(2, 5, 6)
    reference = vae(features, sentence, mask, codes, torch.zeros(16), False, noise)["codes"]
    with torch.autocast("cpu", dtype=torch.bfloat16):
        low = vae(features, sentence, mask, codes, torch.zeros(16), False, noise)["codes"]
    assert low.dtype == torch.bfloat16 and torch.isfinite(low.float()).all()
    assert (low.float() - reference).abs().max() < 0.1


@pytest.mark.parametrize("teacher_forcing", [True, False])
def test_temporal_vae_fast_loop_gradients_equal_plain(teacher_forcing):
    torch.manual_seed(0)
    vae = TemporalVAE(WORD_DIM, 16, VAE).double()
    words, pos, lengths = text_batch(3)
    words = words.double()
    pos = pos.double()
    codes, initial, noise = (
        torch.randn(*s, dtype=torch.float64) for s in ((3, 6, 16), (16,), (3, 6, 6))
    )
    features, sentence, mask = vae.encode_text(words, pos, lengths)
    fast = vae(features, sentence, mask, codes, initial, teacher_forcing, noise)["codes"]
    fast_grads = torch.autograd.grad(fast.square().sum(), list(vae.parameters()), allow_unused=True)
    plain = reference_forward(vae, words, pos, lengths, codes, initial, teacher_forcing, noise)
    plain_grads = torch.autograd.grad(
        plain.square().sum(), list(vae.parameters()), allow_unused=True
    )
    for (name, parameter), a, b in zip(vae.named_parameters(), fast_grads, plain_grads):
        # the prior does not shape the codes: no gradient (plain) or zeros (fused weights)
        a = torch.zeros_like(parameter) if a is None else a
        b = torch.zeros_like(parameter) if b is None else b
        assert torch.allclose(a, b, atol=1e-10), name


def test_config_accepts_exactly_the_autoencoder_losses():
    from t2m.config import RECONSTRUCTION_LOSSES as CONFIG_NAMES
    from t2m.models.autoencoder import RECONSTRUCTION_LOSSES

    assert tuple(RECONSTRUCTION_LOSSES) == CONFIG_NAMES
