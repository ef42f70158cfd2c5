"""Text2length: a caption -> a distribution over motion lengths in snippets.

Text encoder (BiGRU) -> sentence feature (2H) [+ the caption's count, ``config.count_input``] ->
[Linear -> LayerNorm -> LeakyReLU] per MLP size -> Linear to ``num_classes``; class ``c`` means
``c`` snippets, ``c * snippet_length`` frames of the dataset's spec
(:class:`dataset_tools.skeleton.DatasetSpec`; 4 for HumanML3D and KIT-ML).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from dataset_tools.skeleton import HUMANML3D
from t2m.config import LengthModelConfig
from t2m.models.onednn import FastLinear
from t2m.models.text_encoder import TextEncoder


class LengthEstimator(nn.Module):
    """Words, POS (B, L, 15), text lengths (B,) -> logits (B, num_classes)."""

    def __init__(self, word_dim: int, config: LengthModelConfig, vocab_size: int = 0):
        super().__init__()
        self.config = config
        self.text_encoder = TextEncoder(word_dim, config.text, vocab_size)
        layers: list[nn.Module] = []
        size = self.text_encoder.output_size + COUNT_INPUTS * config.count_input
        for width in config.mlp_sizes:
            layers += [FastLinear(size, width), nn.LayerNorm(width), nn.LeakyReLU(0.2)]
            size = width
        layers.append(FastLinear(size, config.num_classes))
        self.head = nn.Sequential(*layers)

    def forward(
        self,
        words: torch.Tensor,
        pos: torch.Tensor,
        lengths: torch.Tensor,
        counts: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """``counts`` (B,): the repetitions each caption names (``config.count_input``; None:
        none named); ignored without ``count_input``."""
        sentence = self.text_encoder.sentence(words, pos, lengths)
        if self.config.count_input:
            sentence = torch.cat([sentence, count_features(counts, sentence)], dim=-1)
        return self.head(sentence)


COUNT_INPUTS = 2
"""Inputs a count adds (:func:`count_features`)."""

COUNT_SCALE = 10.0
"""A count's input is count / COUNT_SCALE (counts above 2 x COUNT_SCALE read as 2 x COUNT_SCALE)."""


def count_features(counts: torch.Tensor | None, like: torch.Tensor) -> torch.Tensor:
    """(B, 2) inputs of the counts (B,) captions name (None: all 0): count / COUNT_SCALE and
    whether there is one, in ``like``'s dtype and device."""
    if counts is None:
        return like.new_zeros(like.shape[0], COUNT_INPUTS)
    counts = counts.to(like.device, like.dtype).clamp(0, 2 * COUNT_SCALE)
    return torch.stack([counts / COUNT_SCALE, (counts > 0).to(like.dtype)], dim=-1)


def length_loss(logits: torch.Tensor, target_class: torch.Tensor) -> dict[str, torch.Tensor]:
    """Cross-entropy and accuracy for logits (B, K) and classes (B,)."""
    loss = F.cross_entropy(logits, target_class)
    accuracy = (logits.argmax(-1) == target_class).float().mean()
    return {"loss": loss, "accuracy": accuracy}


def sample_lengths(
    logits: torch.Tensor,
    generator: torch.Generator,
    min_units: int = HUMANML3D.min_frames // HUMANML3D.snippet_length,
    retries: int = 2,
) -> torch.Tensor:
    """Draw a length in snippets (B,) from softmax(logits (B, K)).

    A draw under ``min_units`` (the spec's ``min_frames // snippet_length``) is redrawn, at most
    ``retries`` times; if still short it is raised to ``min_units`` (so every motion has at
    least the dataset's shortest length).
    """
    probs = torch.softmax(logits.float(), dim=-1)
    units = torch.multinomial(probs, 1, generator=generator).squeeze(-1)
    for _ in range(retries):
        again = torch.multinomial(probs, 1, generator=generator).squeeze(-1)
        units = torch.where(units < min_units, again, units)
    return units.clamp(min=min_units)
