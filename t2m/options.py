"""The options ``python -m t2m.sample`` and ``python -m t2m.edit`` share: which checkpoints,
which files into which folder, where and how to run (:class:`OutputOptions`)."""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

from dataset_tools.command import UsageError, option
from t2m.config import check_threads
from t2m.outputs import RENDER_CHOICES, Render, check_out
from t2m.pipeline import TextToMotion


@dataclass
class OutputOptions:
    """The options ``python -m t2m.sample`` and ``python -m t2m.edit`` share: which checkpoints,
    which files into which folder, where and how to run."""

    checkpoints: Path = field(default=Path("checkpoints/demo"), metadata=option(metavar="DIR"))
    """run folder with the trained stages, or the original T2M release's folder"""
    glove: Path | None = field(default=None, metadata=option(metavar="DIR"))
    """the release's GloVe subset (default: glove/ beside the release's checkpoints/)"""
    out: Path | None = field(default=None, metadata=option(metavar="DIR"))
    """output folder (default outputs/<timestamp>/)"""
    overwrite: bool = False
    """replace a non-empty --out written by an earlier run"""
    render: Render = "mp4"
    """stick-figure animation format (an edit's kept joints in green), or none"""
    bvh: bool = False
    """also write a BVH file per motion"""
    glb: bool = False
    """also write an animated glTF binary (.glb) per motion"""
    smpl: bool = False
    """also write SMPL-H body parameters per motion (sampleNN_repRR_smpl.npz, AMASS's layout)"""
    device: str = "auto"
    """auto, cpu, cuda or cuda:N (auto: CUDA when present)"""
    threads: int = field(default=0, metadata=option(metavar="N"))
    """torch CPU threads (0: torch's choice; 1 is fastest on a busy machine)"""
    precision: Literal["fp32", "bf16", "int8"] = "fp32"
    """inference precision (int8 is CPU only, and an edit cannot optimise through it; bf16 is
    faster only on a GPU or a CPU with AVX512_BF16 or AMX, elsewhere slower, with a warning)"""
    backend: Literal["torch", "onnx"] = "torch"
    """what runs the generation steps: torch, or ONNX Runtime (fp32 and int8 on the CPU)"""

    def __post_init__(self) -> None:
        check_threads(self.threads)
        if self.render not in RENDER_CHOICES:
            raise UsageError(f"--render must be one of {', '.join(RENDER_CHOICES)}")

    def output_folder(self, prefix: str = "") -> Path:
        """``--out`` (default ``outputs/<prefix><timestamp>``), checked before any model work."""
        out = self.out or Path("outputs") / time.strftime(f"{prefix}%Y-%m-%d_%H-%M-%S")
        return check_out(out, self.overwrite)

    def file_options(self) -> dict:
        """Which files the writers (:func:`t2m.outputs.write_motions`) write, and whether they
        may replace an earlier run's folder: the keyword arguments every command passes."""
        return {
            "render": self.render,
            "bvh": self.bvh,
            "glb": self.glb,
            "smpl": self.smpl,
            "overwrite": self.overwrite,
        }

    def load_pipeline(self, need_length_model: bool) -> TextToMotion:
        """The models of ``--checkpoints`` on the chosen device, threads and precision; what is
        missing or mismatched is a one-line UsageError (the library's message names the make
        target)."""
        from t2m.train.runtime import inference_device

        if self.threads:
            import torch

            torch.set_num_threads(self.threads)
        device = inference_device(self.device, self.precision)
        try:
            return TextToMotion.from_checkpoints(
                self.checkpoints,
                device=device,
                precision=self.precision,
                backend=self.backend,
                need_length_model=need_length_model,
                glove_dir=self.glove,
            )
        except ValueError as error:
            raise UsageError(str(error)) from None
