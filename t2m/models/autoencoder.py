"""Movement autoencoder: every snippet of 4 frames of features <-> one snippet code.

Encoder (on the features without the 4 foot-contact dims): two strided Conv1d (kernel 4, stride 2,
padding 1) with dropout and LeakyReLU 0.2, then a Linear. Decoder: two ConvTranspose1d back to the
full feature size (contacts included), LeakyReLU after each, then a Linear.

The two stride-2 layers fix the snippet length at :data:`SNIPPET_FRAMES` = 4 frames; a dataset
spec (:class:`dataset_tools.skeleton.DatasetSpec`) with another snippet length is refused by
:func:`check_snippet_length` rather than silently decoded at the wrong rate.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from t2m.config import AutoencoderConfig

CONTACT_DIMS = 4
SNIPPET_FRAMES = 4
"""Frames per snippet code: the encoder's two stride-2 convolutions downsample by 2 x 2."""
# The names are the ones ``AEStageConfig.reconstruction_loss`` accepts (t2m.config validates them).
RECONSTRUCTION_LOSSES = {"l1": F.l1_loss, "smooth_l1": F.smooth_l1_loss}


def check_snippet_length(snippet_length: int) -> None:
    """ValueError (one line) unless a dataset's snippet length is the autoencoder's."""
    if snippet_length != SNIPPET_FRAMES:
        raise ValueError(
            f"the movement autoencoder codes snippets of {SNIPPET_FRAMES} frames (two stride-2 "
            f"convolutions); a dataset with {snippet_length}-frame snippets needs another one"
        )


class MovementEncoder(nn.Module):
    """(B, T, D - 4) normalised features -> (B, T // 4, code_size) codes."""

    def __init__(self, input_size: int, config: AutoencoderConfig):
        super().__init__()
        self.net = nn.Sequential(
            nn.Conv1d(input_size, config.hidden_size, 4, 2, 1),
            nn.Dropout(config.dropout),
            nn.LeakyReLU(0.2),
            nn.Conv1d(config.hidden_size, config.code_size, 4, 2, 1),
            nn.Dropout(config.dropout),
            nn.LeakyReLU(0.2),
        )
        self.out = nn.Linear(config.code_size, config.code_size)

    def forward(self, features: torch.Tensor) -> torch.Tensor:
        hidden = self.net(features.transpose(1, 2)).transpose(1, 2)  # (B, T/4, C)
        return self.out(hidden)


class MovementDecoder(nn.Module):
    """(B, S, code_size) codes -> (B, 4 S, D) normalised features."""

    def __init__(self, output_size: int, config: AutoencoderConfig):
        super().__init__()
        self.net = nn.Sequential(
            nn.ConvTranspose1d(config.code_size, config.hidden_size, 4, 2, 1),
            nn.LeakyReLU(0.2),
            nn.ConvTranspose1d(config.hidden_size, output_size, 4, 2, 1),
            nn.LeakyReLU(0.2),
        )
        self.out = nn.Linear(output_size, output_size)

    def forward(self, codes: torch.Tensor) -> torch.Tensor:
        hidden = self.net(codes.transpose(1, 2)).transpose(1, 2)  # (B, 4S, D)
        return self.out(hidden)


class MovementAutoencoder(nn.Module):
    """Encoder + decoder for features of ``feature_dim`` (263 for HumanML3D)."""

    def __init__(self, feature_dim: int, config: AutoencoderConfig):
        super().__init__()
        if feature_dim <= CONTACT_DIMS:
            raise ValueError(f"feature_dim must exceed {CONTACT_DIMS}, got {feature_dim}")
        self.feature_dim = feature_dim
        self.config = config
        self.encoder = MovementEncoder(feature_dim - CONTACT_DIMS, config)
        self.decoder = MovementDecoder(feature_dim, config)

    def encode(self, features: torch.Tensor) -> torch.Tensor:
        """(B, T, D) normalised features (contacts included, ignored) -> (B, T // 4, C)."""
        if features.shape[1] % SNIPPET_FRAMES:
            raise ValueError(
                f"motion length must be a multiple of {SNIPPET_FRAMES} frames, "
                f"got {features.shape[1]}"
            )
        return self.encoder(features[..., : self.feature_dim - CONTACT_DIMS])

    def decode(self, codes: torch.Tensor) -> torch.Tensor:
        """(B, S, C) -> (B, 4 S, D)."""
        return self.decoder(codes)

    def forward(self, features: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(B, T, D) -> (reconstruction (B, T, D), codes (B, T // 4, C))."""
        codes = self.encode(features)
        return self.decode(codes), codes


def autoencoder_loss(
    reconstruction: torch.Tensor,
    target: torch.Tensor,
    codes: torch.Tensor,
    sparsity_weight: float = 0.001,
    smoothness_weight: float = 0.001,
    reconstruction_loss: str = "l1",
) -> dict[str, torch.Tensor]:
    """Reconstruction (``"l1"`` or ``"smooth_l1"``) + sparsity (mean |code|) + smoothness (L1
    between consecutive codes).

    Returns a dict with ``loss`` (the weighted total) and its parts.
    """
    loss_fn = RECONSTRUCTION_LOSSES.get(reconstruction_loss)
    if loss_fn is None:
        raise ValueError(f"unknown reconstruction loss {reconstruction_loss!r}")
    rebuilt = loss_fn(reconstruction, target)
    sparsity = codes.abs().mean()
    smoothness = F.l1_loss(codes[:, 1:], codes[:, :-1])
    total = rebuilt + sparsity_weight * sparsity + smoothness_weight * smoothness
    return {
        "loss": total,
        "reconstruction": rebuilt,
        "sparsity": sparsity,
        "smoothness": smoothness,
    }
