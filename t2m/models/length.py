"""Text2length: a caption -> a distribution over motion lengths in snippets.

Text encoder (BiGRU) -> sentence feature (2H) [+ count and clause inputs, ``config.plan_inputs``] ->
[Linear -> LayerNorm -> LeakyReLU] per MLP size -> Linear to ``num_classes``; class ``c`` means
``c`` snippets, ``c * snippet_length`` frames of the dataset's spec
(:class:`dataset_tools.skeleton.DatasetSpec`; 4 for HumanML3D and KIT-ML).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from dataset_tools.spec import HUMANML3D
from t2m.config import LengthModelConfig
from t2m.models.text_encoder import TextEncoder


class LengthEstimator(nn.Module):
    """Words, POS (B, L, 15), text lengths (B,) -> logits (B, num_classes)."""

    def __init__(self, word_dim: int, config: LengthModelConfig, vocab_size: int = 0):
        super().__init__()
        self.config = config
        self.text_encoder = TextEncoder(word_dim, config.text, vocab_size)
        layers: list[nn.Module] = []
        size = self.text_encoder.output_size + PLAN_INPUTS * config.plan_inputs
        for width in config.mlp_sizes:
            layers += [nn.Linear(size, width), nn.LayerNorm(width), nn.LeakyReLU(0.2)]
            size = width
        layers.append(nn.Linear(size, config.num_classes))
        self.head = nn.Sequential(*layers)

    def forward(
        self,
        words: torch.Tensor,
        pos: torch.Tensor,
        lengths: torch.Tensor,
        counts: torch.Tensor | None = None,
        clause: bool = False,
    ) -> torch.Tensor:
        """``counts`` (B,): the repetitions each caption names (None: none named); ``clause``:
        the captions are clauses of longer motions, as the clause plan asks (bool or (B,)).
        Both read only with ``config.plan_inputs``."""
        sentence = self.text_encoder.sentence(words, pos, lengths)
        if self.config.plan_inputs:
            sentence = torch.cat([sentence, plan_features(counts, clause, sentence)], dim=-1)
        return self.head(sentence)


PLAN_INPUTS = 3
"""Inputs ``LengthModelConfig.plan_inputs`` adds (:func:`plan_features`)."""

COUNT_SCALE = 10.0
"""A count's input is count / COUNT_SCALE (counts above 2 x COUNT_SCALE read as 2 x COUNT_SCALE)."""


def plan_features(
    counts: torch.Tensor | None, clause: bool | torch.Tensor, like: torch.Tensor
) -> torch.Tensor:
    """(B, 3) inputs, in ``like``'s (B, F) dtype and device: count / COUNT_SCALE and whether
    there is one (``counts`` (B,), None: all 0), and whether the caption is a clause of a longer
    motion (``clause``, bool or (B,))."""
    batch = like.shape[0]
    if counts is None:
        counts = like.new_zeros(batch)
    counts = counts.to(like.device, like.dtype).clamp(0, 2 * COUNT_SCALE)
    part = torch.as_tensor(clause, device=like.device).to(like.dtype).expand(batch)
    return torch.stack([counts / COUNT_SCALE, (counts > 0).to(like.dtype), part], dim=-1)


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
