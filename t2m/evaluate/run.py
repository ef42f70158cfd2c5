"""The library entry point: evaluate a run folder on a dataset folder and write the results.

:func:`evaluate` is what ``python -m t2m.evaluate`` calls, in four steps: load the trained stages
as a :class:`~t2m.evaluate.backend.CheckpointBackend`, read the split (and find the dataset's
scorer, if any), run the protocol, summarise and write ``results.json`` and ``results.md``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import torch

from t2m.config import DataConfig
from t2m.data.dataset import load_split
from t2m.evaluate.backend import Backend, CheckpointBackend
from t2m.evaluate.protocol import EvalConfig, find_scorer, run_protocol
from t2m.evaluate.report import summarize, write_results


def evaluate(
    dataset_dir: str | Path,
    checkpoints_dir: str | Path,
    out_dir: str | Path | None,
    config: EvalConfig,
    backend: Backend | None = None,
) -> dict[str, Any]:
    """Evaluate the run in ``checkpoints_dir`` on ``dataset_dir``; write results into ``out_dir``.

    Steps: 1. load the stages, 2. read the split, 3. run the protocol, 4. summarise and write.
    Returns the summary (the content of results.json).
    """
    # 1. models
    if config.num_threads > 0:
        torch.set_num_threads(config.num_threads)
    if backend is None:
        backend = CheckpointBackend.from_run_dir(
            checkpoints_dir, config.device, config.which, config.batch_size, config.precision
        )
    data_config = getattr(backend, "data_config", None)
    if data_config is None:
        data_config = DataConfig()
    # 2. data
    clips = load_split(dataset_dir, config.split, data_config)
    semantic = find_scorer(dataset_dir)
    # 3. protocol
    result = run_protocol(
        clips,
        backend,
        config,
        unit_length=data_config.unit_length,
        max_frames=data_config.max_frames,
        semantic=semantic,
    )
    # 4. report
    summary = summarize(result)
    summary["dataset"] = str(dataset_dir)
    summary["checkpoints"] = str(checkpoints_dir)
    if out_dir is not None:
        write_results(summary, out_dir)
    return summary
