"""What every training loop shares: device choice, processes (DDP), seeding, autocast, clipping.

A run is one process, or several started by ``torchrun`` (``WORLD_SIZE`` > 1 in the environment):
then a process group is opened (gloo on CPU, nccl on CUDA), each process takes its own slice of
every epoch, and the trainable module is wrapped in ``DistributedDataParallel``.
"""

from __future__ import annotations

import contextlib
import logging
import os
from collections.abc import Callable, Iterator
from dataclasses import dataclass

import torch
import torch.distributed as dist
from torch import nn

from dataset_tools.command import UsageError
from t2m.hardware import device_description, native_bf16

logger = logging.getLogger(__name__)

BF16_AUTOCAST_COST = (
    "an autoencoder step took 33x its fp32 time, a temporal-VAE step 12x, on an AMD EPYC Zen 3 "
    "with AVX2 only (demo sizes, one thread)"
)
"""What ``--bf16`` costs where bfloat16 is not native (:func:`t2m.hardware.native_bf16`;
measured as :mod:`t2m.benchmarks.train` steps); at paper size the autoencoder step took 38x the
original T2M's time (28 s a step)."""


@dataclass
class Runtime:
    """The process's place in the run and its device."""

    device: torch.device
    rank: int = 0
    world_size: int = 1
    bf16: bool = False

    @property
    def is_main(self) -> bool:
        return self.rank == 0

    @property
    def distributed(self) -> bool:
        return self.world_size > 1

    epoch_threads: Callable[[], int] | None = None
    """Asked before each training epoch; a positive answer becomes torch's CPU thread count
    (``t2m.demo``: one thread while its second process trains, two once it is done)."""

    def before_epoch(self) -> None:
        """Apply :attr:`epoch_threads` (set between epochs, never inside a parallel region)."""
        if self.epoch_threads is None:
            return
        threads = self.epoch_threads()
        if threads > 0 and threads != torch.get_num_threads():
            torch.set_num_threads(threads)
            logger.info("%d CPU threads from this epoch on", threads)

    def autocast(self) -> contextlib.AbstractContextManager:
        """bfloat16 autocast when enabled (CUDA or CPU), else a no-op (:func:`start` warns
        where bfloat16 is not native)."""
        if not self.bf16:
            return contextlib.nullcontext()
        return torch.autocast(device_type=self.device.type, dtype=torch.bfloat16)

    def wrap(self, module: nn.Module) -> nn.Module:
        """The module wrapped for gradient averaging across processes (itself when alone)."""
        if not self.distributed:
            return module
        device_ids = [self.device.index] if self.device.type == "cuda" else None
        return nn.parallel.DistributedDataParallel(module, device_ids=device_ids)

    def barrier(self) -> None:
        if self.distributed:
            dist.barrier()

    def broadcast_float(self, value: float) -> float:
        """Rank 0's value on every process (so every process takes the same decisions)."""
        if not self.distributed:
            return value
        tensor = torch.tensor([value], dtype=torch.float64, device=self._comm_device())
        dist.broadcast(tensor, src=0)
        return float(tensor.item())

    def _comm_device(self) -> torch.device:
        return self.device if dist.get_backend() == "nccl" else torch.device("cpu")


def resolve_device(name: str, local_rank: int = 0) -> torch.device:
    """``auto`` -> CUDA when present, else CPU; ``cuda`` with several processes -> cuda:local_rank.

    Raises UsageError (a ValueError) for an unavailable or unknown device.
    """
    if name == "auto":
        name = "cuda" if torch.cuda.is_available() else "cpu"
    try:
        device = torch.device(name)
    except RuntimeError:
        raise UsageError(f"unknown device {name!r} (auto, cpu, cuda, cuda:N)") from None
    if device.type == "cuda":
        if not torch.cuda.is_available():
            raise UsageError("device 'cuda' requested but CUDA is not available")
        if device.index is None:
            device = torch.device("cuda", local_rank % torch.cuda.device_count())
        torch.cuda.set_device(device)
    elif device.type not in ("cpu", "mps"):
        raise UsageError(f"unsupported device {name!r}")
    return device


def inference_device(device: str, precision: str) -> str:
    """The device to run inference at ``precision`` on: int8 kernels exist on the CPU only, so
    with int8 ``auto`` means the CPU; any other name is kept (to be resolved by
    :func:`resolve_device`)."""
    return "cpu" if precision == "int8" and device == "auto" else device


def available_memory() -> int | None:
    """Bytes of memory the system can still give (Linux ``MemAvailable``), or None if unknown;
    what sampling and evaluation compare their up-front estimates with."""
    try:
        with open("/proc/meminfo", encoding="ascii") as meminfo:
            for line in meminfo:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    return None


def start(device: str = "auto", bf16: bool = False, num_threads: int = 0) -> Runtime:
    """Open the process group when launched by torchrun, choose the device, set threads.

    ``bf16`` is kept as asked; where bfloat16 is not native (a CPU without AVX512_BF16 or AMX) the
    main process warns once that it runs slower than fp32.
    """
    world_size = int(os.environ.get("WORLD_SIZE", "1"))
    rank = int(os.environ.get("RANK", "0"))
    local_rank = int(os.environ.get("LOCAL_RANK", str(rank)))
    resolved = resolve_device(device, local_rank)
    if num_threads > 0:
        torch.set_num_threads(num_threads)
    if world_size > 1 and not dist.is_initialized():
        backend = "nccl" if resolved.type == "cuda" else "gloo"
        dist.init_process_group(backend=backend, rank=rank, world_size=world_size)
        logger.info("process %d of %d (%s)", rank, world_size, backend)
    if bf16 and rank == 0 and not native_bf16(resolved):
        logger.warning(
            "bf16 autocast trains slower than fp32 on %s, which has no native bfloat16: %s; "
            "leave --bf16 off here",
            device_description(resolved),
            BF16_AUTOCAST_COST,
        )
    return Runtime(resolved, rank, world_size, bf16)


def finish(runtime: Runtime) -> None:
    """Close the process group this run opened."""
    if runtime.distributed and dist.is_initialized():
        dist.destroy_process_group()


def seed_init(seed: int) -> None:
    """Seed torch's global generator before models are built (their initial weights)."""
    torch.manual_seed(seed)


def seed_step(seed: int, epoch: int, step: int, rank: int = 0) -> None:
    """Seed torch's global generator for one step (dropout, latent noise), from its coordinates.

    Seeding every step from (seed, epoch, step, rank) rather than once makes a resumed run draw
    exactly what the uninterrupted run drew.
    """
    torch.manual_seed((((seed * 1_000_003 + epoch) * 1_000_003 + step) * 131 + rank) % (2**63 - 1))


def clip_gradients(
    parameters: Iterator[nn.Parameter] | list[nn.Parameter], max_norm: float
) -> None:
    """Clip the total gradient norm when ``max_norm`` > 0."""
    if max_norm > 0:
        torch.nn.utils.clip_grad_norm_(list(parameters), max_norm)


def unwrap(module: nn.Module) -> nn.Module:
    """The module inside a DDP wrapper."""
    return module.module if isinstance(module, nn.parallel.DistributedDataParallel) else module


def adam(parameters, **options) -> torch.optim.Adam:
    """The stages' optimiser: ``torch.optim.Adam(parameters, **options)`` with its fused kernel
    (one pass over each parameter and its state instead of a dozen elementwise operators per
    parameter): 0-7% of a paper-size small stage's training step on one CPU thread, 3-11% of
    the temporal VAE's. Where the parameters' device has no fused Adam, the default one."""
    parameters = list(parameters)
    try:
        return torch.optim.Adam(parameters, fused=True, **options)
    except (RuntimeError, ValueError):
        return torch.optim.Adam(parameters, **options)
