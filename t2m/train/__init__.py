"""Training: one loop per stage (ae, length, t2m, eval) and the helpers they share.

``python -m t2m.train {ae,length,t2m,eval} --preset demo --dataset data/demo`` trains a stage;
:func:`t2m.train.checkpoint.load_stage` rebuilds a trained one.
"""

from t2m.train.checkpoint import TrainedStage, load_stage

__all__ = ["TrainedStage", "load_stage", "train_stage"]


def train_stage(stage: str, config, dataset_dir, run_dir, runtime=None, resume: bool = False):
    """Train one stage (see :mod:`t2m.train.__main__`); returns the stage folder."""
    from t2m.train.__main__ import run_stage

    return run_stage(stage, config, dataset_dir, run_dir, runtime=runtime, resume=resume)
