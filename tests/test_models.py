"""Models: shapes, determinism and masking (the temporal VAE: tests/test_temporal_vae.py)."""

from __future__ import annotations

import pytest
import torch
import torch.nn.functional as F

from t2m.config import (
    AutoencoderConfig,
    EvaluatorConfig,
    LengthModelConfig,
    TextEncoderConfig,
)
from t2m.models.autoencoder import MovementAutoencoder, autoencoder_loss
from t2m.models.evaluator import Evaluator, contrastive_loss
from t2m.models.length import LengthEstimator, sample_lengths
from t2m.models.text_encoder import TextEncoder
from tests.tolerances import assert_same_rounding, gamma

WORD_DIM, L = 12, 22
AE = AutoencoderConfig(hidden_size=24, code_size=16, dropout=0.2)


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
    # Tolerances: means of 18,936 (and 288, 270) terms summed by other kernels in another
    # order, so both sides are held to the float64 loss of the same tensors (each within 16x
    # the other's distance; tests.tolerances.assert_same_rounding). A wrong weight or term
    # (0.01 for 0.001, the smoothness left out) moves the loss by 1e-3 or more, rounding 1e-7.
    exact = autoencoder_loss(reconstruction.double(), motion.double(), codes.double())
    assert_same_rounding(losses["loss"], expected, exact["loss"])
    smooth = autoencoder_loss(reconstruction, motion, codes, reconstruction_loss="smooth_l1")
    exact_smooth = autoencoder_loss(
        reconstruction.double(), motion.double(), codes.double(), reconstruction_loss="smooth_l1"
    )
    # Huber with beta 1: half the squared error below 1, the error less a half above
    error = (reconstruction - motion).abs()
    huber = torch.where(error < 1, 0.5 * error**2, error - 0.5).mean()
    assert_same_rounding(smooth["reconstruction"], huber, exact_smooth["reconstruction"])
    # the regularisers alone, each side a loss less its reconstruction (cancellation: the float64
    # difference is the reference, floored at u times it)
    assert_same_rounding(
        smooth["loss"] - smooth["reconstruction"],
        expected - losses["reconstruction"],
        exact_smooth["loss"] - exact_smooth["reconstruction"],
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
    # the same operations on the same shapes; the valid tokens' values are the same and no
    # product of theirs reads a padding row: equal bit for bit
    assert torch.equal(sentence, sentence2)
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


def test_length_estimator_reads_counts_and_clauses():
    """With ``plan_inputs`` the count and whether the caption is a clause enter beside the
    sentence feature (count / 10, whether there is one, clause or not; None reads as 0, as a
    caption without a count); without it they are ignored and the weights are the paper
    model's."""
    from t2m.models.length import plan_features

    torch.manual_seed(0)
    sizes = dict(text=TextEncoderConfig(hidden_size=8), mlp_sizes=(16, 8))
    plain = LengthEstimator(WORD_DIM, LengthModelConfig(**sizes)).eval()
    planned = LengthEstimator(WORD_DIM, LengthModelConfig(**sizes, plan_inputs=True)).eval()
    assert planned.head[0].in_features == plain.head[0].in_features + 3
    batch = text_batch(3)
    counts = torch.tensor([0, 2, 30])
    with torch.no_grad():
        assert torch.equal(plain(*batch), plain(*batch, counts, clause=True))
        assert torch.equal(planned(*batch), planned(*batch, torch.zeros(3, dtype=torch.long)))
        assert not torch.allclose(planned(*batch)[1:], planned(*batch, counts)[1:])
        assert not torch.allclose(planned(*batch), planned(*batch, clause=True))
    features = plan_features(counts, torch.tensor([False, True, False]), torch.zeros(3, 5))
    expected = torch.tensor([[0.0, 0.0, 0.0], [0.2, 1.0, 1.0], [2.0, 1.0, 0.0]])
    torch.testing.assert_close(features, expected)
    torch.testing.assert_close(plan_features(None, True, torch.zeros(2, 5))[:, 2], torch.ones(2))


def test_evaluator_shapes_frozen_encoder_and_contrastive_loss():
    torch.manual_seed(0)
    evaluator = Evaluator(
        WORD_DIM,
        263,
        AE,
        EvaluatorConfig(
            text=TextEncoderConfig(hidden_size=8), motion_hidden_size=12, embedding_size=6
        ),
    )
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
    # the same operations on the same shapes, and no output read reaches the changed frames:
    # equal bit for bit
    assert torch.equal(evaluator.embed_motion(padded, motion_lengths)[1], moving[1])
    with pytest.raises(ValueError, match="zero shift"):
        contrastive_loss(text, moving, 0)
    same = contrastive_loss(text, text, 1, margin=10.0)
    # pairwise_distance adds eps = 1e-6 to each of the 6 differences: 6e-12 per pair, within
    # 8 roundings (eps to float32, squares, sum, sqrt, square, mean; observed 6.0000004e-12);
    # any real distance is 1e-6 or more
    assert same["positive"] <= 6 * (1e-6) ** 2 * (1 + gamma(8))
    far = contrastive_loss(
        torch.zeros(3, 2), torch.tensor([[0.0, 20.0], [0.0, 0.0], [0.0, 0.0]]), 1, margin=10.0
    )
    # squared distances (20 - eps)^2 + eps^2, 2 eps^2, 2 eps^2 (pairwise_distance's eps = 1e-6),
    # their mean within 8 roundings of positive terms, gamma_8 = 4.8e-7 relative (observed
    # 5.3e-8); a distance not squared, or summed instead of averaged, is off by 3x or more
    expected = ((20 - 1e-6) ** 2 + 1e-12 + 2 * 2e-12) / 3
    assert abs(far["positive"].item() - expected) <= gamma(8) * expected


def test_config_accepts_exactly_the_autoencoder_losses():
    from t2m.config import RECONSTRUCTION_LOSSES as CONFIG_NAMES
    from t2m.models.autoencoder import RECONSTRUCTION_LOSSES

    assert tuple(RECONSTRUCTION_LOSSES) == CONFIG_NAMES
