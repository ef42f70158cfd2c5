"""A pipeline of paper-sized models with random weights, for measuring speed where no trained
checkpoint is at hand: the time a generation takes depends on the models' sizes, not on their
weights. The sampling speed benchmark (``t2m.benchmarks.sample``) and the edit benchmark's
latency column (:mod:`t2m.evaluate.edit_bench`) time it.
"""

from __future__ import annotations

import numpy as np
import torch

from t2m.data.normalization import Normalizer
from t2m.data.words import BUILTIN_GLOVE, load_vectorizer
from t2m.models.autoencoder import MovementDecoder
from t2m.models.temporal_vae import TemporalVAE
from t2m.pipeline import TextToMotion
from t2m.presets import paper


def paper_sized_pipeline(
    precision: str = "fp32", modules: tuple | None = None, backend: str = "torch"
) -> tuple[TextToMotion, tuple]:
    """A pipeline of paper-sized random-weight models (HumanML3D's 263-d features, the built-in
    GloVe vectors, identity normalisation) and its ``(vae, decoder, initial_code)``.

    ``modules``: the models of an earlier call, so that every precision and backend runs the
    same weights; by default they are made afresh from seed 0.
    """
    config = paper()
    vectorizer = load_vectorizer(BUILTIN_GLOVE, config.data.max_text_tokens)
    if modules is None:
        torch.manual_seed(0)
        vae = TemporalVAE(
            vectorizer.dim, config.autoencoder.model.code_size, config.generator.model
        )
        decoder = MovementDecoder(263, config.autoencoder.model)
        initial_code = torch.zeros(config.autoencoder.model.code_size)
        modules = (vae, decoder, initial_code)
    vae, decoder, initial_code = modules
    normalizer = Normalizer(np.zeros(263, np.float32), np.ones(263, np.float32))
    pipe = TextToMotion(
        vae, decoder, normalizer, vectorizer, initial_code, precision=precision, backend=backend
    )
    return pipe, modules
