"""Contrastive evaluator: a text embedder and a motion embedder sharing one embedding space.

The motion side reads the frozen autoencoder's snippet codes: Linear -> bidirectional GRU (learned
h0) -> Linear -> LayerNorm -> LeakyReLU -> Linear. The evaluator owns a frozen copy of that
movement encoder, so a saved evaluator embeds normalised features on its own. The text side is the BiGRU text encoder with the
same kind of head. The metrics (R-precision, FID, MM-Dist, diversity) are computed on these
embeddings.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from t2m.config import AutoencoderConfig, EvaluatorConfig
from t2m.models.autoencoder import CONTACT_DIMS, SNIPPET_FRAMES, MovementEncoder
from t2m.models.text_encoder import ProjectedTextEncoder, bidirectional_gru


class MotionEmbedder(nn.Module):
    """Codes (B, S, C) and lengths in snippets (B,) -> embeddings (B, E)."""

    def __init__(self, code_size: int, hidden_size: int, embedding_size: int):
        super().__init__()
        self.hidden_size = hidden_size
        self.input_projection = nn.Linear(code_size, hidden_size)
        self.gru = nn.GRU(hidden_size, hidden_size, batch_first=True, bidirectional=True)
        self.initial_hidden = nn.Parameter(torch.randn(2, 1, hidden_size) * 0.01)
        self.head = nn.Sequential(
            nn.Linear(2 * hidden_size, hidden_size),
            nn.LayerNorm(hidden_size),
            nn.LeakyReLU(0.2),
            nn.Linear(hidden_size, embedding_size),
        )

    def forward(self, codes: torch.Tensor, num_snippets: torch.Tensor) -> torch.Tensor:
        inputs = self.input_projection(codes)
        hidden = self.initial_hidden.expand(2, codes.shape[0], self.hidden_size).contiguous()
        _, last = bidirectional_gru(self.gru, inputs, num_snippets.cpu().clamp(min=1), hidden)
        return self.head(torch.cat([last[0], last[1]], dim=-1))


class Evaluator(nn.Module):
    """Text embedder + motion embedder over a frozen movement encoder.

    Args:
        word_dim: word-vector size; feature_dim: motion feature size (263).
        autoencoder_config: sizes of the (frozen) movement encoder.
        config: embedder sizes; vocab_size > 0 for a trainable word embedding.
    """

    def __init__(
        self,
        word_dim: int,
        feature_dim: int,
        autoencoder_config: AutoencoderConfig,
        config: EvaluatorConfig,
        vocab_size: int = 0,
    ):
        super().__init__()
        self.config = config
        self.feature_dim = feature_dim
        self.movement_encoder = MovementEncoder(feature_dim - CONTACT_DIMS, autoencoder_config)
        self.movement_encoder.requires_grad_(False)
        self.text = ProjectedTextEncoder(word_dim, config.text, config.embedding_size, vocab_size)
        self.motion = MotionEmbedder(
            autoencoder_config.code_size, config.motion_hidden_size, config.embedding_size
        )

    def train(self, mode: bool = True) -> Evaluator:
        super().train(mode)
        self.movement_encoder.eval()  # frozen: no dropout, ever
        return self

    def encode_motion(self, features: torch.Tensor) -> torch.Tensor:
        """Normalised features (B, T, D), T a multiple of 4 -> codes (B, T // 4, C)."""
        return self.movement_encoder(features[..., : self.feature_dim - CONTACT_DIMS])

    def embed_text(
        self, words: torch.Tensor, pos: torch.Tensor, text_lengths: torch.Tensor
    ) -> torch.Tensor:
        """-> (B, E)."""
        return self.text(words, pos, text_lengths)

    def embed_motion(self, features: torch.Tensor, motion_lengths: torch.Tensor) -> torch.Tensor:
        """Normalised features (B, T, D), zero-padded, and lengths in frames (B,) -> (B, E).

        T must be a multiple of 4 (``SNIPPET_FRAMES``); each length is used in whole snippets
        (frames // 4).
        """
        with torch.no_grad():
            codes = self.encode_motion(features)
        return self.motion(codes, motion_lengths // SNIPPET_FRAMES)

    def forward(
        self,
        words: torch.Tensor,
        pos: torch.Tensor,
        text_lengths: torch.Tensor,
        features: torch.Tensor,
        motion_lengths: torch.Tensor,
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """-> (text embeddings (B, E), motion embeddings (B, E))."""
        return self.embed_text(words, pos, text_lengths), self.embed_motion(
            features, motion_lengths
        )


def contrastive_loss(
    text_embeddings: torch.Tensor,
    motion_embeddings: torch.Tensor,
    shift: int,
    margin: float = 10.0,
    negative_weight: float = 1.0,
) -> dict[str, torch.Tensor]:
    """Matched pairs pulled together; mismatched pairs pushed beyond ``margin``.

    Negatives pair each caption with the motion ``shift`` places further in the batch; ``shift``
    must be in 1 .. B-1 (the original drew 0 too, making some "negatives" matched pairs).

    Returns ``loss``, ``positive`` (mean squared distance of matched pairs), ``negative``.
    """
    batch = text_embeddings.shape[0]
    if not 1 <= shift < batch:
        raise ValueError(
            f"shift must be in 1..{batch - 1} (a zero shift pairs items with themselves)"
        )
    positive_distance = F.pairwise_distance(text_embeddings, motion_embeddings)
    negative_distance = F.pairwise_distance(text_embeddings, motion_embeddings.roll(shift, dims=0))
    positive = positive_distance.pow(2).mean()
    negative = torch.clamp(margin - negative_distance, min=0.0).pow(2).mean()
    return {
        "loss": positive + negative_weight * negative,
        "positive": positive,
        "negative": negative,
    }
