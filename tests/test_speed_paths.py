"""The performance work's contracts: gradient clipping as the original, int8 / bf16 pipelines
without a deep copy, the GloVe binary cache."""

from __future__ import annotations

import pytest

from t2m.config import PRESETS, preset


@pytest.mark.parametrize("name", sorted(PRESETS))
def test_clipping_follows_the_original(name):
    # The original clips 0.5 in its length, temporal-VAE and evaluator trainers, not the
    # autoencoder's.
    config = preset(name)
    assert config.length.grad_clip == 0.5
    assert config.generator.grad_clip == 0.5
    assert config.evaluator.grad_clip == 0.5
    assert config.autoencoder.grad_clip == 0.0
