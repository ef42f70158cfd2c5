"""Text encoder: word vector + POS embedding -> Linear -> bidirectional GRU with a learned h0.

Input per token: the word vector plus ``Linear(15 -> word_dim)`` of the POS one-hot. When the
vocabulary is trainable, the encoder owns the ``nn.Embedding`` and takes integer ids instead of
vectors. Outputs word features (B, L, 2H), zero past each caption's length, and a sentence
feature (B, 2H): the last forward and first backward hidden states.

The padded GRU output is aligned word by word. The original T2M release reverses the backward
half within each caption's length before its attention reads it; ``flip_backward_words`` in the
config does the same, so the release's weights run as trained (:mod:`t2m.release`).
"""

from __future__ import annotations

import torch
from torch import nn
from torch.nn.utils.rnn import pack_padded_sequence, pad_packed_sequence

from t2m.config import TextEncoderConfig
from t2m.data.words import NUM_POS


def bidirectional_gru(
    gru: nn.GRU, inputs: torch.Tensor, lengths: torch.Tensor, h0: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """``gru`` (bidirectional, batch first) over ``inputs`` (B, L, I) of ``lengths`` (B,) from
    ``h0`` (2, B, H) -> (outputs (B, L, 2H), zero past each length; last states (2, B, H))."""
    packed = pack_padded_sequence(inputs, lengths.cpu(), batch_first=True, enforce_sorted=False)
    outputs, last = gru(packed, h0)
    outputs, _ = pad_packed_sequence(outputs, batch_first=True, total_length=inputs.shape[1])
    return outputs, last


class TextEncoder(nn.Module):
    """Words (B, L, Dw) float or (B, L) ids, POS (B, L, 15), lengths (B,) ->
    (word features (B, L, 2H), sentence feature (B, 2H)).

    Args:
        word_dim: word-vector size (or embedding size for a trainable vocabulary).
        config: hidden size.
        vocab_size: > 0 to own a trainable embedding of that many words.
    """

    def __init__(self, word_dim: int, config: TextEncoderConfig, vocab_size: int = 0):
        super().__init__()
        self.hidden_size = config.hidden_size
        self.flip_backward_words = config.flip_backward_words
        self.embedding = nn.Embedding(vocab_size, word_dim) if vocab_size > 0 else None
        self.pos_embedding = nn.Linear(NUM_POS, word_dim)
        self.input_projection = nn.Linear(word_dim, config.hidden_size)
        self.gru = nn.GRU(
            config.hidden_size, config.hidden_size, batch_first=True, bidirectional=True
        )
        self.initial_hidden = nn.Parameter(torch.randn(2, 1, config.hidden_size) * 0.01)

    @property
    def output_size(self) -> int:
        return 2 * self.hidden_size

    def embed(self, words: torch.Tensor, pos: torch.Tensor) -> torch.Tensor:
        """Token inputs (B, L, H) before the GRU."""
        if self.embedding is not None:
            if words.dtype not in (torch.int64, torch.int32):
                raise ValueError("this text encoder owns its embedding: pass word ids (B, L)")
            words = self.embedding(words)
        elif words.dim() != 3:
            raise ValueError(f"expected word vectors (B, L, Dw), got shape {tuple(words.shape)}")
        return self.input_projection(words + self.pos_embedding(pos))

    def _run(self, words: torch.Tensor, pos: torch.Tensor, lengths: torch.Tensor):
        """The GRU over each caption's tokens: (outputs (B, L, 2H), zero past each length; last
        states (2, B, H))."""
        inputs = self.embed(words, pos)
        hidden = self.initial_hidden.expand(2, inputs.shape[0], self.hidden_size).contiguous()
        return bidirectional_gru(self.gru, inputs, lengths, hidden)

    def sentence(
        self, words: torch.Tensor, pos: torch.Tensor, lengths: torch.Tensor
    ) -> torch.Tensor:
        """The sentence feature (B, 2H) alone, as :meth:`forward` gives it."""
        _, last = self._run(words, pos, lengths)
        return torch.cat([last[0], last[1]], dim=-1)

    def forward(
        self, words: torch.Tensor, pos: torch.Tensor, lengths: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        word_features, last = self._run(words, pos, lengths)
        if self.flip_backward_words:
            word_features = self._flip_backward(word_features, lengths.to(word_features.device))
        sentence = torch.cat([last[0], last[1]], dim=-1)  # (B, 2H)
        return word_features, sentence

    def _flip_backward(self, word_features: torch.Tensor, lengths: torch.Tensor) -> torch.Tensor:
        """(B, L, 2H): the backward half's word i becomes word length-1-i (padding stays)."""
        positions = torch.arange(word_features.shape[1], device=word_features.device)[None, :]
        lengths = lengths[:, None]
        source = torch.where(positions < lengths, lengths - 1 - positions, positions)  # (B, L)
        forward, backward = word_features.split(self.hidden_size, dim=-1)
        index = source[..., None].expand(-1, -1, self.hidden_size)
        return torch.cat([forward, backward.gather(1, index)], dim=-1)


class ProjectedTextEncoder(nn.Module):
    """Text encoder + MLP head to one vector per caption: Linear -> LayerNorm -> LeakyReLU -> Linear."""

    def __init__(
        self, word_dim: int, config: TextEncoderConfig, output_size: int, vocab_size: int = 0
    ):
        super().__init__()
        self.encoder = TextEncoder(word_dim, config, vocab_size)
        hidden = config.hidden_size
        self.head = nn.Sequential(
            nn.Linear(2 * hidden, hidden),
            nn.LayerNorm(hidden),
            nn.LeakyReLU(0.2),
            nn.Linear(hidden, output_size),
        )

    def forward(
        self, words: torch.Tensor, pos: torch.Tensor, lengths: torch.Tensor
    ) -> torch.Tensor:
        """-> (B, output_size)."""
        return self.head(self.encoder.sentence(words, pos, lengths))
