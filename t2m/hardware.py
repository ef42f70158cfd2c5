"""What the hardware can compute natively: the one place that decides whether bfloat16 pays.

bfloat16 is only faster than float32 where the hardware multiplies it natively: CUDA GPUs that
support it, and CPUs with AVX512_BF16 or AMX, whose bf16 dot-product instructions oneDNN uses.
Elsewhere (AVX2, and AVX-512 without AVX512_BF16) every bf16 operand is widened to float32 and
rounded back, so bf16 costs more than float32: inference, autocast training and the int8
pipeline's bf16 decoder included. Whoever picks a precision asks :func:`native_bf16`; note that
``torch.ops.mkldnn._is_mkldnn_bf16_supported()`` is no such test (it is true on any AVX-512 CPU,
where oneDNN emulates bf16).

The environment can restrict a CPU below what it has: ``ONEDNN_MAX_CPU_ISA`` (oneDNN's highest
instruction set) and ``ATEN_CPU_CAPABILITY`` (the level of torch's own kernels). The tests run
with ``ONEDNN_MAX_CPU_ISA=AVX2 ATEN_CPU_CAPABILITY=avx2`` so that an AVX-512 machine behaves as
an AVX2 one; :func:`native_bf16` honours both.
"""

from __future__ import annotations

import functools
import os

import torch

ONEDNN_BELOW_BF16 = frozenset(
    {"SSE41", "AVX", "AVX2", "AVX2_VNNI", "AVX2_VNNI_2", "AVX512_CORE", "AVX512_CORE_VNNI"}
)
"""``ONEDNN_MAX_CPU_ISA`` values below AVX512_CORE_BF16 (no native bf16 dot products)."""
ATEN_BELOW_BF16 = frozenset({"default", "avx2"})
"""``ATEN_CPU_CAPABILITY`` values that keep torch's kernels off AVX-512."""


def cpu_restriction() -> str | None:
    """The environment variable that keeps this process below native bf16 (``"NAME=value"``),
    or None."""
    for name in ("ONEDNN_MAX_CPU_ISA", "DNNL_MAX_CPU_ISA"):  # DNNL_: oneDNN's older name
        value = os.environ.get(name, "").strip()
        if value.upper() in ONEDNN_BELOW_BF16:
            return f"{name}={value}"
    value = os.environ.get("ATEN_CPU_CAPABILITY", "").strip()
    if value.lower() in ATEN_BELOW_BF16:
        return f"ATEN_CPU_CAPABILITY={value}"
    return None


def cpu_has_bf16_instructions() -> bool:
    """Whether the CPU has AVX512_BF16 or AMX (what it has, whatever the environment allows)."""
    return torch.cpu._is_avx512_bf16_supported() or torch.cpu._is_amx_tile_supported()


def native_bf16(device: str | torch.device = "cpu") -> bool:
    """Whether bfloat16 computes natively on ``device``, so that bf16 can be faster than fp32.

    CUDA: ``torch.cuda.is_bf16_supported()``. CPU: AVX512_BF16 or AMX present and not
    restricted by ``ONEDNN_MAX_CPU_ISA`` / ``ATEN_CPU_CAPABILITY`` (:func:`cpu_restriction`).
    Any other device (MPS): False, not known to pay.
    """
    device = torch.device(device)
    if device.type == "cuda":
        return torch.cuda.is_available() and torch.cuda.is_bf16_supported()
    if device.type != "cpu":
        return False
    return cpu_has_bf16_instructions() and cpu_restriction() is None


@functools.cache
def _cpu_model() -> str:
    try:
        with open("/proc/cpuinfo", encoding="utf-8", errors="replace") as cpuinfo:
            for line in cpuinfo:
                key, _, value = line.partition(":")
                if key.strip() == "model name" and value.strip():
                    return " ".join(value.split())
    except OSError:
        pass
    return "unknown CPU"


def cpu_description() -> str:
    """One line naming the CPU and what it computes natively, for log lines and benchmarks,
    e.g. ``AMD EPYC 7B13 (torch kernels AVX2; no VNNI, no avx512_bf16, no AMX)``."""
    features = [
        f"{'' if present else 'no '}{name}"
        for name, present in (
            ("VNNI", torch.cpu._is_vnni_supported()),
            ("avx512_bf16", torch.cpu._is_avx512_bf16_supported()),
            ("AMX", torch.cpu._is_amx_tile_supported()),
        )
    ]
    restriction = cpu_restriction()
    if restriction:
        features.append(f"restricted by {restriction}")
    capability = torch.backends.cpu.get_cpu_capability()
    return f"{_cpu_model()} (torch kernels {capability}; {', '.join(features)})"


def device_description(device: str | torch.device) -> str:
    """One line naming ``device``: :func:`cpu_description` for the CPU, the GPU's name for CUDA."""
    device = torch.device(device)
    if device.type == "cpu":
        return cpu_description()
    if device.type == "cuda" and torch.cuda.is_available():
        return torch.cuda.get_device_name(device)
    return str(device)
