"""Training: one loop per stage (ae, length, t2m, eval) and the helpers they share.

``python -m t2m.train {ae,length,t2m,eval} --preset demo --dataset data/demo`` trains a stage;
:func:`t2m.train.checkpoint.load_stage` rebuilds a trained one::

    from t2m.train import load_stage, train_stage
    train_stage("ae", tiny(), "data/demo", "checkpoints/tiny")
    ae = load_stage("checkpoints/tiny", "ae")
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from t2m.train.checkpoint import TrainedStage, load_stage

if TYPE_CHECKING:
    from t2m.config import Config
    from t2m.train.runtime import Runtime

__all__ = ["TrainedStage", "load_stage", "train_stage"]


def train_stage(
    stage: str,
    config: Config,
    dataset_dir: str | Path,
    run_dir: str | Path,
    runtime: Runtime | None = None,
    resume: bool = False,
) -> Path:
    """Train one stage into ``run_dir/<stage>``; returns that folder (see ``python -m t2m.train``)."""
    from t2m.train.__main__ import run_stage

    return run_stage(stage, config, dataset_dir, run_dir, runtime=runtime, resume=resume)
