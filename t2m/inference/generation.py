"""The models' part of a generation: encoded captions -> snippet codes -> features.

:func:`text_batch` stacks encoded captions into the text encoder's tensors; :func:`clause_codes`
generates the codes of items planned clause by clause; :func:`decode_features` turns codes into
de-normalised features, one length at a time. :class:`t2m.pipeline.TextToMotion` prepares the
prompts, draws the lengths and latent draws (its plan) and runs these batch by batch.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np
import torch

if TYPE_CHECKING:
    from t2m.data.normalization import Normalizer
    from t2m.data.words import EncodedText
    from t2m.models.autoencoder import MovementDecoder
    from t2m.models.temporal_vae import TemporalVAE


def text_batch(
    encoded: Sequence[EncodedText], device: torch.device, dtype: torch.dtype
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Stack encoded captions into (words, pos, lengths) tensors: words (word vectors in
    ``dtype``, indices as they are) and pos (in ``dtype``) on ``device``, lengths on the CPU."""
    words = np.stack([item.words for item in encoded])
    pos = np.stack([item.pos_onehot for item in encoded])
    lengths = torch.tensor([item.length for item in encoded], dtype=torch.long)
    words_tensor = torch.from_numpy(words).to(device)
    if words_tensor.is_floating_point():
        words_tensor = words_tensor.to(dtype)
    return words_tensor, torch.from_numpy(pos).to(device, dtype), lengths


def clause_codes(
    vae: TemporalVAE,
    lists: Sequence[Sequence[EncodedText]],
    snippets: Sequence[Sequence[int]],
    initial_code: torch.Tensor,
    generator: torch.Generator,
    noise: torch.Tensor | None,
    device: torch.device,
    dtype: torch.dtype,
) -> torch.Tensor:
    """Codes (B, max snippets, C) of items generated clause by clause: item b's clauses
    ``lists[b]`` (encoded as standalone captions; one for an item of one clause) with
    ``snippets[b]`` snippets each (:meth:`t2m.pipeline.TextToMotion.clause_snippets`).

    Clause k of every item that has one runs as one batch: its standalone caption's words are
    what the attention reads, its GRU states start from that caption's sentence feature (as a
    caption's do in training), the time-to-arrival counts down to the clause's end, and the
    previous code fed to its first step is the code the item's previous clause ended on
    (``initial_code``, the mean-pose code, for the first). The latent draws ``noise`` are the
    one-pass draws (B, max snippets, Z) (default: drawn from ``generator``), each clause reading
    its own stretch of them, so an item of one clause gets exactly what the one-pass plan gives
    it."""
    batch = len(lists)
    steps = max(sum(n) for n in snippets)
    latent = vae.config.latent_size
    if noise is None:
        noise = torch.randn(batch, steps, latent, generator=generator, device=device, dtype=dtype)
    elif noise.shape != (batch, steps, latent):
        raise ValueError(
            f"noise must be (B, S, Z) = {(batch, steps, latent)}, got {tuple(noise.shape)}"
        )
    codes = torch.zeros(batch, steps, vae.code_size, device=device, dtype=dtype)
    previous = initial_code.to(device, dtype).expand(batch, vae.code_size).clone()
    offset = torch.zeros(batch, dtype=torch.long, device=device)
    for k in range(max(len(c) for c in lists)):
        members = [b for b in range(batch) if len(lists[b]) > k]  # items with a clause k
        sizes = [snippets[b][k] for b in members]
        rows = torch.tensor(members, device=device)
        words, pos, text_lengths = text_batch([lists[b][k] for b in members], device, dtype)
        word_features, sentence, mask = vae.encode_text(words, pos, text_lengths)
        count = torch.tensor(sizes, device=device)
        width = max(sizes)  # from the host's lists: no device sync
        span = offset[rows, None] + torch.arange(width, device=device)[None, :]  # (R, W)
        span = span.clamp(max=steps - 1)
        draws = noise[rows[:, None], span]  # (R, W, Z)
        made = vae.generate(
            word_features,
            sentence,
            mask,
            count,
            noise=draws,
            state=vae.initial_state(sentence, previous[rows]),
            counts=torch.tensor([lists[b][k].count for b in members], device=device),
        )
        inside = torch.arange(width, device=device)[None, :] < count[:, None]
        row_index = rows[:, None].expand(-1, width)[inside]
        codes[row_index, span[inside]] = made[inside].to(codes.dtype)
        previous[rows] = made[torch.arange(len(rows), device=device), count - 1].to(previous.dtype)
        offset[rows] += count
    return codes


def decode_features(
    decoder: MovementDecoder,
    normalizer: Normalizer,
    codes: torch.Tensor,
    num_snippets: torch.Tensor,
    frames: Sequence[int],
    decoder_dtype: torch.dtype,
) -> list[np.ndarray]:
    """Codes (B, max snippets, C) -> de-normalised features (frames_i, D) of each item, its
    first ``num_snippets[i]`` codes decoded and cut to ``frames[i]``."""
    # Decode each length on its own: the transposed convolutions would carry the padding
    # past a shorter item's end into its last frames (a batch must give what batch 1 gives).
    features: list[np.ndarray] = [np.empty(0)] * len(frames)
    for steps in sorted(set(num_snippets.tolist())):
        rows = [i for i, n in enumerate(num_snippets.tolist()) if n == steps]
        group = codes[rows, :steps].to(decoder_dtype)  # (G, steps, C)
        normalised = decoder(group).float()  # (G, unit * steps, D)
        decoded = normalizer.denormalize(normalised).cpu().numpy()
        for row, item in zip(rows, decoded):
            features[row] = item[: frames[row]]
    return features
