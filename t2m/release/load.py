"""Load the original T2M release: generator, length estimator, evaluator, meta/, GloVe subset.

Every size comes from the tensors' shapes; every file is read without running code (``.tar``
with ``torch.load(weights_only=True)``, the vocabulary pickles with every global refused), and
checked before use: every weight a finite floating-point tensor of the shape its role needs, the
vocabulary's rows whole numbers, ``meta/`` two equal vectors; what fails is a UsageError, one line
naming the file (a crafted release never ends in a traceback). The
release's arithmetic where ours differs is set as recorded model options: the generator's text
encoder flips the backward word features (``TextEncoderConfig.flip_backward_words``); the
normalisation is ``meta/`` as stored (the dataset std / 25 on the root and contact dimensions,
see the ``paper`` preset's notes); the attention's padding mask changes nothing at batch 1, where
the release runs, and makes batches equal to it. ``tests/test_release.py`` checks every array
the original computed (``../shared/reference/t2m-original/expected.npz``) within 1e-5.
"""

from __future__ import annotations

import hashlib
import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from dataset_tools.command import UsageError
from dataset_tools.io import load_npy
from dataset_tools.spec import DatasetSpec, spec_for_dim
from t2m.config import (
    AutoencoderConfig,
    EvaluatorConfig,
    LengthModelConfig,
    TemporalVAEConfig,
    TextEncoderConfig,
)
from t2m.data.normalization import Normalizer
from t2m.data.words import WordVectors, read_glove_folder
from t2m.models.autoencoder import (
    CONTACT_DIMS,
    SNIPPET_FRAMES,
    MovementDecoder,
    MovementEncoder,
    check_snippet_length,
)
from t2m.models.evaluator import Evaluator
from t2m.models.length import LengthEstimator
from t2m.models.temporal_vae import TemporalVAE, sinusoidal_table
from t2m.release.keys import (
    EVALUATOR_KEYS,
    GENERATOR_KEYS,
    LENGTH_KEYS,
    release_to_ours,
)
from t2m.release.layout import FLIP_OPTION, ReleaseLayout, find_release, read_opt

logger = logging.getLogger(__name__)

Weights = dict[str, torch.Tensor]


@dataclass
class ReleaseGenerator:
    """What :class:`t2m.pipeline.TextToMotion` needs, from a release (models in eval mode).

    Attributes:
        vae: text encoder + temporal VAE; decoder: movement decoder (codes -> features);
        encoder: the movement encoder (features without contacts -> codes);
        initial_code: (C,) the encoder's code of 4 normalised-zero frames, fed before step 1;
        normalizer: ``meta/`` as stored; vectorizer: the GloVe subset with the release's lists;
        spec: HumanML3D or KIT-ML, by the feature dimension;
        length_model: the length estimator (None when not asked for); layout: where it was.
    """

    vae: TemporalVAE
    decoder: MovementDecoder
    encoder: MovementEncoder
    initial_code: torch.Tensor
    normalizer: Normalizer
    vectorizer: WordVectors
    spec: DatasetSpec
    length_model: LengthEstimator | None
    layout: ReleaseLayout


@dataclass
class ReleaseEvaluator:
    """The release's evaluator (``text_mot_match``) as our :class:`Evaluator`, fed as the
    release feeds it: motions normalised with ``normalizer`` (the generator's ``meta/``), zero
    padded; :meth:`Evaluator.embed_motion` drops the contacts and runs ``frames // 4`` steps;
    captions encoded by ``vectorizer`` with their true token count.

    Attributes:
        path: the ``finest.tar``; sha256: its hash (to name the evaluator in result tables).
    """

    evaluator: Evaluator
    normalizer: Normalizer
    vectorizer: WordVectors
    spec: DatasetSpec
    path: Path
    sha256: str


# -- files -------------------------------------------------------------------------------------


def read_release_checkpoint(path: Path, entries: tuple[str, ...]) -> dict[str, Weights]:
    """The state dicts ``entries`` of a release ``.tar``, loaded with ``weights_only=True``;
    UsageError (one line naming the file) when missing, unsafe or lacking an entry."""
    if not path.is_file():
        raise UsageError(f"no such file: {path}")
    try:
        checkpoint = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as error:  # torch raises many types; every one is a refusal
        first = str(error).strip().splitlines()[0] if str(error).strip() else type(error).__name__
        raise UsageError(f"{path}: refused, not a plain weights file ({first})") from None
    missing = [e for e in entries if not isinstance(checkpoint, dict) or e not in checkpoint]
    if missing:
        raise UsageError(f"{path}: no {', '.join(missing)} (not a T2M release checkpoint)")
    for entry in entries:
        check_weights(checkpoint[entry], entry, path)
    return {entry: checkpoint[entry] for entry in entries}


def check_weights(state: object, entry: str, path: Path) -> None:
    """UsageError (one line naming ``path``) unless ``state`` is a state dict: names to finite
    floating-point tensors (no integers, booleans, complex numbers, NaN or inf) holding every
    value they claim."""
    if not isinstance(state, dict):
        raise UsageError(f"{path}: {entry} is a {type(state).__name__}, not a dict of weights")
    for key, value in state.items():
        where = f"{path}: {entry}.{key}"
        if not isinstance(key, str):
            raise UsageError(f"{path}: {entry} holds a weight named {key!r}, not a string")
        if not isinstance(value, torch.Tensor):
            raise UsageError(f"{where} is a {type(value).__name__}, not a weight tensor")
        if value.layout != torch.strided or not value.is_floating_point():
            raise UsageError(f"{where} holds {value.dtype} ({value.layout}), not float weights")
        if value.numel() * value.element_size() > value.untyped_storage().nbytes():
            # a view with zero strides: a huge shape over a few stored numbers, which would
            # size a model beyond any memory
            raise UsageError(
                f"{where} has shape {tuple(value.shape)} but stores "
                f"{value.untyped_storage().nbytes() // value.element_size()} values"
            )
        if not torch.isfinite(value).all():
            raise UsageError(f"{where} holds NaN or infinite values")


def weight_size(weights: Weights, key: str, dim: int, ndim: int, path: Path) -> int:
    """``weights[key].shape[dim]``, where the layer's weight must have ``ndim`` dimensions (a
    linear layer 2, a convolution 3) and a non-zero size; UsageError naming ``path``
    otherwise (a crafted 0-d tensor made an IndexError)."""
    if key not in weights:
        raise UsageError(f"{path}: no weight {key!r} (not the T2M release's layout)")
    shape = tuple(weights[key].shape)
    if len(shape) != ndim or not all(shape):
        raise UsageError(
            f"{path}: weight {key!r} has shape {shape}, expected {ndim} non-zero sizes"
        )
    return shape[dim]


def file_sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as handle:
        for chunk in iter(lambda: handle.read(1 << 20), b""):
            digest.update(chunk)
    return digest.hexdigest()


def read_normalizer(layout: ReleaseLayout) -> Normalizer:
    """``meta/mean.npy`` and ``meta/std.npy`` as stored (no further weighting)."""
    meta = layout.meta_dir
    mean_file, std_file = meta / "mean.npy", meta / "std.npy"
    mean, std = load_npy(mean_file), load_npy(std_file)  # NaN and infinity: refused there
    for file, values in ((mean_file, mean), (std_file, std)):
        if values.ndim != 1:
            raise UsageError(f"{file}: a vector (D,) of statistics, got shape {values.shape}")
    if mean.shape != std.shape:
        raise UsageError(f"{mean_file} holds {len(mean)} values, {std_file} {len(std)}")
    zero = np.flatnonzero(std <= 1e-8)
    if len(zero):
        raise UsageError(f"{std_file}: std is zero at dimensions {zero[:5].tolist()}")
    return Normalizer(mean, std)


def read_vocabulary(layout: ReleaseLayout, glove_dir: str | Path | None) -> WordVectors:
    """The GloVe subset: ``glove_dir``, or ``glove/`` beside the release's ``checkpoints/``."""
    folder = Path(glove_dir).expanduser() if glove_dir else layout.default_glove_dir
    if not folder.is_dir():
        raise UsageError(
            f"no GloVe folder {folder} (the release's glove/ with our_vab_*: pass --glove DIR)"
        )
    return read_glove_folder(folder)


def read_generator_options(model_dir: Path) -> bool:
    """Check the generator's ``opt.txt`` (snippet length) and return whether its text encoder
    flips the backward word features (the release's always do; an export of ours says)."""
    opt_file = model_dir / "opt.txt"
    options = read_opt(opt_file) if opt_file.exists() else {}
    unit = options.get("unit_length", str(SNIPPET_FRAMES))
    if not (unit.isascii() and unit.isdigit()):
        raise UsageError(f"{opt_file}: unit_length {unit!r} is not a number")
    try:
        check_snippet_length(int(unit))
    except ValueError as error:
        raise UsageError(f"{opt_file}: {error}") from None
    flip = options.get(FLIP_OPTION, "True")
    if flip not in ("True", "False"):
        raise UsageError(f"{opt_file}: {FLIP_OPTION} must be True or False, got {flip!r}")
    return flip == "True"


def _load(module: torch.nn.Module, weights: Weights, where: Path) -> None:
    try:
        module.load_state_dict(weights)
    except RuntimeError as error:
        first = str(error).strip().splitlines()[1:2] or [str(error)]
        raise UsageError(f"{where}: weights do not fit ({first[0].strip()})") from None


# -- models ------------------------------------------------------------------------------------


def _text_config(
    weights: Weights, prefix: str, path: Path, flip: bool = False
) -> TextEncoderConfig:
    return TextEncoderConfig(
        hidden_size=weight_size(weights, f"{prefix}input_projection.weight", 0, 2, path),
        flip_backward_words=flip,
    )


def build_generator(
    path: Path, models: dict[str, Weights], flip: bool = True
) -> tuple[TemporalVAE, MovementDecoder, MovementEncoder]:
    """Our modules holding the release generator's weights (``release_to_ours`` output);
    ``flip``: the text encoder flips the backward word features (the release's does)."""
    vae_w, encoder_w, decoder_w = (models.get(name, {}) for name in ("vae", "encoder", "decoder"))
    hidden = weight_size(vae_w, "generator.input.weight", 0, 2, path)
    for block in ("prior", "posterior"):
        if weight_size(vae_w, f"{block}.input.weight", 0, 2, path) != hidden:
            raise UsageError(f"{path}: prior, posterior and generator sizes differ (unsupported)")
    for block in ("prior", "posterior", "generator"):
        if weight_size(vae_w, f"{block}.initial.weight", 0, 2, path) != hidden:
            raise UsageError(f"{path}: recurrent blocks with several GRU layers (unsupported)")
    tables = models.get("tables", {})
    for entry, table in tables.items():
        if table.dim() != 2 or not all(table.shape):
            raise UsageError(
                f"{path}: {entry}'s time encoding has shape {tuple(table.shape)}, expected "
                "(steps, size)"
            )
    rows = {table.shape[0] for table in tables.values()} or {300}
    if len(rows) != 1:
        raise UsageError(f"{path}: time-encoding tables of different lengths {sorted(rows)}")
    code_size = weight_size(encoder_w, "out.weight", 0, 2, path)
    config = TemporalVAEConfig(
        text=_text_config(vae_w, "text_encoder.", path, flip=flip),
        hidden_size=hidden,
        latent_size=weight_size(vae_w, "prior_gaussian.mean.weight", 0, 2, path),
        attention_size=weight_size(vae_w, "query.weight", 0, 2, path),
        max_snippets=rows.pop(),
    )
    word_dim = weight_size(vae_w, "text_encoder.pos_embedding.weight", 0, 2, path)
    vae = TemporalVAE(word_dim, code_size, config)
    for entry, table in tables.items():
        # float32 sin/cos of positions up to ~300 round differently on different CPUs' vector
        # code (1.5e-5 apart at row 290 between an Intel Xeon and the release's numbers)
        if not torch.allclose(table.float(), sinusoidal_table(*table.shape), atol=1e-4):
            raise UsageError(f"{path}: {entry}'s time encoding is not the sinusoidal table")
    feature_dim = weight_size(decoder_w, "out.weight", 0, 2, path)
    if feature_dim <= CONTACT_DIMS:
        raise UsageError(f"{path}: the decoder writes {feature_dim} features, no motion")
    decoder = MovementDecoder(
        feature_dim,
        AutoencoderConfig(
            hidden_size=weight_size(decoder_w, "net.0.weight", 1, 3, path), code_size=code_size
        ),
    )
    encoder = MovementEncoder(
        feature_dim - CONTACT_DIMS,
        AutoencoderConfig(
            hidden_size=weight_size(encoder_w, "net.0.weight", 0, 3, path), code_size=code_size
        ),
    )
    for module, weights in ((vae, vae_w), (decoder, decoder_w), (encoder, encoder_w)):
        _load(module, weights, path)
    return vae.eval(), decoder.eval(), encoder.eval()


def build_length(path: Path, weights: Weights) -> LengthEstimator:
    """Our LengthEstimator holding the release estimator's weights (ours, renamed)."""
    heads = [key.split(".") for key in weights if key.startswith("head.")]
    if any(len(parts) != 3 or not (parts[1].isascii() and parts[1].isdigit()) for parts in heads):
        raise UsageError(f"{path}: estimator output weights not named 'output.<number>.<name>'")
    linear = sorted(
        int(index)
        for _, index, name in heads
        if name == "weight" and weights[f"head.{index}.weight"].dim() == 2
    )
    if not linear:
        raise UsageError(f"{path}: the estimator has no linear output layer")
    sizes = [weights[f"head.{index}.weight"].shape[0] for index in linear]
    config = LengthModelConfig(
        text=_text_config(weights, "text_encoder.", path),
        mlp_sizes=tuple(sizes[:-1]),
        num_classes=sizes[-1],
    )
    model = LengthEstimator(
        weight_size(weights, "text_encoder.pos_embedding.weight", 0, 2, path), config
    )
    _load(model, weights, path)
    return model.eval()


def build_evaluator(path: Path, weights: Weights) -> Evaluator:
    """Our Evaluator holding the release evaluator's weights (ours, renamed)."""
    movement = AutoencoderConfig(
        hidden_size=weight_size(weights, "movement_encoder.net.0.weight", 0, 3, path),
        code_size=weight_size(weights, "movement_encoder.out.weight", 0, 2, path),
    )
    config = EvaluatorConfig(
        text=_text_config(weights, "text.encoder.", path),
        motion_hidden_size=weight_size(weights, "motion.input_projection.weight", 0, 2, path),
        embedding_size=weight_size(weights, "motion.head.3.weight", 0, 2, path),
    )
    feature_dim = weight_size(weights, "movement_encoder.net.0.weight", 1, 3, path) + CONTACT_DIMS
    word_dim = weight_size(weights, "text.encoder.pos_embedding.weight", 0, 2, path)
    model = Evaluator(word_dim, feature_dim, movement, config)
    _load(model, weights, path)
    return model.eval()


def _check_words(vectorizer: WordVectors, word_dim: int, path: Path) -> None:
    if vectorizer.dim != word_dim:
        raise UsageError(
            f"{path} reads {word_dim}-d word vectors, the GloVe folder {vectorizer.source} has "
            f"{vectorizer.dim}-d ones"
        )


@torch.no_grad()
def initial_code(encoder: MovementEncoder) -> torch.Tensor:
    """(C,): the movement encoder's code of one snippet of normalised-zero (mean) frames."""
    size = encoder.net[0].in_channels
    parameter = next(encoder.parameters())
    zeros = torch.zeros(1, SNIPPET_FRAMES, size, dtype=parameter.dtype, device=parameter.device)
    return encoder.eval()(zeros)[0, 0]


def load_release(
    folder: str | Path,
    glove_dir: str | Path | None = None,
    device: str | torch.device = "cpu",
    need_length_model: bool = True,
) -> ReleaseGenerator:
    """The release's generator (and length estimator) with its normalisation and vocabulary.

    Args:
        folder: any folder of the release (:func:`t2m.release.layout.find_release`).
        glove_dir: the GloVe subset (default: ``glove/`` beside ``checkpoints/``).
        device: where the models go.
        need_length_model: also load ``length_est_bigru``.
    """
    layout = find_release(folder)
    path = layout.generator_file
    flip = read_generator_options(layout.require_generator())
    entries = read_release_checkpoint(
        path, tuple(dict.fromkeys(r[0].split(".")[0] for r in GENERATOR_KEYS))
    )
    weights = release_to_ours(entries, GENERATOR_KEYS, str(path))
    vae, decoder, encoder = build_generator(path, weights, flip)
    spec = spec_for_dim(decoder.out.out_features)
    normalizer = read_normalizer(layout)
    if normalizer.dim != spec.feature_dim:
        raise UsageError(
            f"{layout.meta_dir}: {normalizer.dim}-d statistics, {spec.feature_dim}-d model"
        )
    vectorizer = read_vocabulary(layout, glove_dir)
    _check_words(vectorizer, vae.text_encoder.pos_embedding.out_features, path)
    length_model = None
    if need_length_model:
        length_path = layout.length_file
        weights = release_to_ours(
            read_release_checkpoint(length_path, ("estimator",)), LENGTH_KEYS, str(length_path)
        )
        length_model = build_length(length_path, weights["length"])
        _check_words(vectorizer, length_model.text_encoder.pos_embedding.out_features, length_path)
    device = torch.device(device)
    logger.info("T2M release %s (%s)", layout.require_generator(), spec.name)
    return ReleaseGenerator(
        vae=vae.to(device),
        decoder=decoder.to(device),
        encoder=encoder.to(device),
        initial_code=initial_code(encoder.to(device)),
        normalizer=normalizer,
        vectorizer=vectorizer,
        spec=spec,
        length_model=length_model.to(device) if length_model else None,
        layout=layout,
    )


def load_release_evaluator(
    folder: str | Path,
    glove_dir: str | Path | None = None,
    device: str | torch.device = "cpu",
) -> ReleaseEvaluator:
    """The release's evaluator (``text_mot_match``), with the generator's ``meta/`` and the
    GloVe subset: the standard evaluator of the field. ``folder``: any folder of the release,
    ``text_mot_match`` itself included."""
    layout = find_release(folder)
    path = layout.evaluator_file
    entries = read_release_checkpoint(path, ("text_encoder", "motion_encoder", "movement_encoder"))
    evaluator = build_evaluator(
        path, release_to_ours(entries, EVALUATOR_KEYS, str(path))["evaluator"]
    )
    spec = spec_for_dim(evaluator.feature_dim)
    normalizer = read_normalizer(layout)
    if normalizer.dim != spec.feature_dim:
        raise UsageError(
            f"{layout.meta_dir}: {normalizer.dim}-d statistics, {spec.feature_dim}-d evaluator"
        )
    vectorizer = read_vocabulary(layout, glove_dir)
    _check_words(vectorizer, evaluator.text.encoder.pos_embedding.out_features, path)
    return ReleaseEvaluator(
        evaluator=evaluator.to(torch.device(device)),
        normalizer=normalizer,
        vectorizer=vectorizer,
        spec=spec,
        path=path,
        sha256=file_sha256(path),
    )
