"""bfloat16 only where it pays: :func:`t2m.hardware.native_bf16` and the choices made from it.

The CPU's capabilities are faked through the torch functions :mod:`t2m.hardware` reads (and the
environment variables it honours), so every test runs the real chain on any machine.
"""

from __future__ import annotations

import logging
from pathlib import Path

import pytest
import torch

from t2m import hardware
from t2m.pipeline import TextToMotion, offered_precisions
from t2m.train import runtime as runtime_module

RESTRICTIONS = ("ONEDNN_MAX_CPU_ISA", "DNNL_MAX_CPU_ISA", "ATEN_CPU_CAPABILITY")


def fake_cpu(monkeypatch: pytest.MonkeyPatch, bf16: bool, amx: bool = False) -> None:
    """Make the CPU report AVX512_BF16 / AMX, with no restricting environment variable."""
    monkeypatch.setattr(torch.cpu, "_is_avx512_bf16_supported", lambda: bf16)
    monkeypatch.setattr(torch.cpu, "_is_amx_tile_supported", lambda: amx)
    for name in RESTRICTIONS:
        monkeypatch.delenv(name, raising=False)


@pytest.fixture(scope="module")
def fp32_pipe(tiny_run: Path) -> TextToMotion:
    return TextToMotion.from_checkpoints(tiny_run, device="cpu", need_length_model=False)


def records(caplog: pytest.LogCaptureFixture, name: str) -> list[logging.LogRecord]:
    return [record for record in caplog.records if record.name == name]


@pytest.mark.parametrize(
    ("bf16", "amx", "env", "native"),
    [
        (True, False, {}, True),
        (False, True, {}, True),
        (False, False, {}, False),
        (True, True, {"ONEDNN_MAX_CPU_ISA": "AVX2"}, False),
        (True, True, {"ONEDNN_MAX_CPU_ISA": "avx512_core"}, False),
        (True, True, {"ONEDNN_MAX_CPU_ISA": "AVX512_CORE_VNNI"}, False),
        (True, True, {"DNNL_MAX_CPU_ISA": "AVX2"}, False),
        (True, True, {"ONEDNN_MAX_CPU_ISA": "AVX512_CORE_BF16"}, True),
        (True, True, {"ONEDNN_MAX_CPU_ISA": "AVX512_CORE_AMX"}, True),
        (True, True, {"ATEN_CPU_CAPABILITY": "avx2"}, False),
        (True, True, {"ATEN_CPU_CAPABILITY": "default"}, False),
        (True, True, {"ATEN_CPU_CAPABILITY": "avx512"}, True),
        (True, False, {"ONEDNN_MAX_CPU_ISA": "AVX2", "ATEN_CPU_CAPABILITY": "avx2"}, False),
    ],
)
def test_native_bf16_needs_the_instructions_and_no_restriction(monkeypatch, bf16, amx, env, native):
    fake_cpu(monkeypatch, bf16, amx)
    for name, value in env.items():
        monkeypatch.setenv(name, value)
    assert hardware.native_bf16("cpu") is native
    assert hardware.native_bf16(torch.device("cpu")) is native
    description = hardware.cpu_description()
    assert "\n" not in description and torch.backends.cpu.get_cpu_capability() in description
    assert ("no avx512_bf16" in description) is not bf16
    assert ("no AMX" in description) is not amx
    if env and not native:
        assert "restricted by" in description


def test_an_unknown_device_type_is_not_native():
    assert hardware.native_bf16("meta") is False


def test_int8_runs_a_float32_decoder_without_native_bf16(fp32_pipe, monkeypatch, caplog):
    fake_cpu(monkeypatch, bf16=False)
    caplog.set_level(logging.INFO, logger="t2m.inference.conversion")
    pipe = fp32_pipe.with_precision("int8")
    assert pipe.decoder_dtype == torch.float32
    assert next(pipe.decoder.parameters()).dtype == torch.float32
    [line] = records(caplog, "t2m.inference.conversion")
    assert line.levelno == logging.INFO
    message = line.getMessage()
    assert "float32" in message and "no native bfloat16" in message and "no AMX" in message
    motion = pipe.generate("a person walks forward", lengths=40, seed=0)[0][0]
    assert torch.isfinite(torch.from_numpy(motion.joints)).all()


def test_int8_runs_a_bf16_decoder_with_native_bf16(fp32_pipe, monkeypatch, caplog):
    fake_cpu(monkeypatch, bf16=False, amx=True)
    caplog.set_level(logging.INFO, logger="t2m.inference.conversion")
    pipe = fp32_pipe.with_precision("int8")
    assert pipe.decoder_dtype == torch.bfloat16
    assert next(pipe.decoder.parameters()).dtype == torch.bfloat16
    assert records(caplog, "t2m.inference.conversion") == []


def test_explicit_bf16_runs_but_warns_with_its_cost(fp32_pipe, monkeypatch, caplog):
    fake_cpu(monkeypatch, bf16=False)
    monkeypatch.setenv("ONEDNN_MAX_CPU_ISA", "AVX2")
    caplog.set_level(logging.INFO, logger="t2m.inference.conversion")
    pipe = fp32_pipe.with_precision("bf16")
    assert pipe.dtype == pipe.decoder_dtype == torch.bfloat16  # asked for, so it runs
    [line] = records(caplog, "t2m.inference.conversion")
    assert line.levelno == logging.WARNING
    message = line.getMessage()
    assert "4.9x at batch 32" in message and "AVX2" in message and "restricted by" in message

    caplog.clear()
    fake_cpu(monkeypatch, bf16=True)
    assert fp32_pipe.with_precision("bf16").dtype == torch.bfloat16
    assert records(caplog, "t2m.inference.conversion") == []


def test_the_web_app_offers_bf16_only_where_it_is_native(monkeypatch):
    fake_cpu(monkeypatch, bf16=False)
    assert offered_precisions("cpu") == ["fp32", "int8"]
    fake_cpu(monkeypatch, bf16=True)
    assert offered_precisions("cpu") == ["fp32", "bf16", "int8"]


@pytest.mark.parametrize("native", [False, True])
def test_bf16_training_warns_without_native_bf16(monkeypatch, caplog, native):
    fake_cpu(monkeypatch, bf16=native)
    caplog.set_level(logging.INFO, logger="t2m.train.runtime")
    runtime = runtime_module.start("cpu", bf16=True)
    assert runtime.bf16  # asked for, so it runs
    with runtime.autocast():
        assert torch.get_autocast_dtype("cpu") == torch.bfloat16
    warnings = [r for r in records(caplog, "t2m.train.runtime") if r.levelno == logging.WARNING]
    if native:
        assert warnings == []
    else:
        [line] = warnings
        assert "33x its fp32 time" in line.getMessage() and "AVX2" in line.getMessage()

    caplog.clear()
    assert not runtime_module.start("cpu", bf16=False).bf16
    assert records(caplog, "t2m.train.runtime") == []
