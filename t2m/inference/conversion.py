"""Models made ready for inference: on their device, in eval mode, at a precision, with a
generation backend (:func:`convert`, through :func:`t2m.accel.accelerate`).

Precision: ``fp32`` (reference), ``bf16`` (weights and activations in bfloat16) or ``int8``
(dynamic int8 quantisation of the recurrent cells and linear layers, CPU only; the decoder runs
in bfloat16 where the hardware computes it natively, else in float32). ``backend="onnx"`` runs
the generation step in ONNX Runtime (fp32 and int8 on the CPU, :mod:`t2m.accel.onnx`).
"""

from __future__ import annotations

import copy
import logging
from dataclasses import dataclass

import torch

from t2m.accel import BACKENDS, ONNX_PRECISIONS, PRECISIONS, accelerate
from t2m.accel.onnx import require as require_onnx
from t2m.hardware import device_description, native_bf16
from t2m.models.autoencoder import MovementDecoder, MovementEncoder
from t2m.models.length import LengthEstimator
from t2m.models.temporal_vae import TemporalVAE

logger = logging.getLogger(__name__)

BF16_EMULATED_COST = (
    "it took 1.1x fp32's CPU time at batch 1 and 4.9x at batch 32 (the decoder alone 4.6x) on "
    "an AMD EPYC Zen 3 with AVX2 only (paper-size models, one thread)"
)
"""What bf16 costs where bfloat16 is not native (measured with the models and prompts of
:mod:`t2m.benchmarks.sample`); against the original T2M it took 0.80x of its time at batch 1 (0.27x
on an AVX-512 CPU) and 2.79x at batch 32."""


def offered_precisions(device: str | torch.device) -> list[str]:
    """The precisions worth offering on ``device`` (the web app's choices): fp32; bf16 where
    bfloat16 is native (elsewhere it is slower than fp32, though it still runs when asked for);
    int8 on the CPU."""
    device = torch.device(device)
    return [
        precision
        for precision in PRECISIONS
        if (precision != "bf16" or native_bf16(device))
        and (precision != "int8" or device.type == "cpu")
    ]


def check_conversion(precision: str, backend: str, device: torch.device) -> None:
    """ValueError (one line) unless ``precision`` and ``backend`` run on ``device``; a warning
    where bf16 runs slower than fp32."""
    if backend not in BACKENDS:
        raise ValueError(f"unknown backend {backend!r}; use one of {', '.join(BACKENDS)}")
    if backend == "onnx" and (precision not in ONNX_PRECISIONS or device.type != "cpu"):
        raise ValueError(f"the onnx backend runs {' and '.join(ONNX_PRECISIONS)} on the CPU")
    if backend == "onnx":
        require_onnx()
    if precision not in PRECISIONS:
        raise ValueError(f"unknown precision {precision!r}; use one of {', '.join(PRECISIONS)}")
    if precision == "int8" and device.type != "cpu":
        raise ValueError("int8 inference runs on the CPU only; use --precision bf16 on a GPU")
    if precision == "bf16" and not native_bf16(device):
        logger.warning(
            "bf16 runs slower than fp32 on %s, which has no native bfloat16: %s; "
            "fp32 or int8 is faster here",
            device_description(device),
            BF16_EMULATED_COST,
        )


@dataclass(frozen=True)
class InferenceModels:
    """The models :func:`convert` made, and the dtypes they read.

    Attributes:
        vae, decoder, encoder, length_model: converted and accelerated (encoder and length
            model None where none was given).
        dtype: of the text inputs, the initial code and the latent draws (bfloat16 for bf16).
        decoder_dtype: of the decoder's inputs.
    """

    vae: TemporalVAE
    decoder: MovementDecoder
    encoder: MovementEncoder | None
    length_model: LengthEstimator | None
    dtype: torch.dtype
    decoder_dtype: torch.dtype


def convert(
    vae: TemporalVAE,
    decoder: MovementDecoder,
    device: torch.device,
    precision: str = "fp32",
    backend: str = "torch",
    encoder: MovementEncoder | None = None,
    length_model: LengthEstimator | None = None,
    copy_models: bool = True,
) -> InferenceModels:
    """The models on ``device`` in eval mode, the temporal VAE at ``precision`` with its
    generation ``backend``, the decoder in bfloat16 for bf16 (and for int8 where bfloat16 is
    native), everything accelerated (:func:`t2m.accel.accelerate`); the encoder and the
    length model stay float32.

    ``copy_models``: convert copies (the caller's modules stay float32); False converts them in
    place, which saves holding the float32 weights and their converted copy at once, and,
    without an ``encoder``, releases the VAE's posterior (nothing of generation reads it).
    """
    check_conversion(precision, backend, device)
    vae = vae.to(device).eval()
    decoder = decoder.to(device).eval()
    if not copy_models and encoder is None:
        # nothing but an edit's kept start reads the posterior, and edits need the encoder
        vae.release_posterior()
    if copy_models and precision != "fp32":
        vae = copy.deepcopy(vae)
    elif copy_models and backend == "onnx":  # the caller's module keeps its own rollout
        vae = copy.copy(vae)  # shares the weights
    vae = accelerate(vae, precision, backend)
    # The decoder's transposed convolutions have no dynamic-int8 kernels. With int8 they run
    # in bfloat16 where it is native (3x faster at batch 32 with AMX, ~0.5% relative error),
    # else in float32 (bf16 took 4.6x fp32's time there).
    native = native_bf16(device)
    bf16_decoder = precision == "bf16" or (precision == "int8" and native)
    if precision == "int8" and not native:
        logger.info(
            "int8: the movement decoder runs in float32 on %s, which has no native "
            "bfloat16 (a bf16 decoder took 4.6x fp32's time on an AVX2 CPU)",
            device_description(device),
        )
    if bf16_decoder and copy_models:
        decoder = copy.deepcopy(decoder)
    return InferenceModels(
        vae=vae,
        decoder=accelerate(decoder, "bf16" if bf16_decoder else "fp32"),
        encoder=None if encoder is None else accelerate(encoder.to(device).eval()),
        length_model=None if length_model is None else accelerate(length_model.to(device).eval()),
        dtype=torch.bfloat16 if precision == "bf16" else torch.float32,
        decoder_dtype=torch.bfloat16 if bf16_decoder else torch.float32,
    )
