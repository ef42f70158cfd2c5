"""Training: one loop per stage (autoencoder, length, generator, evaluator) and what they share.

``python -m t2m.train <stage> --preset demo --dataset data/demo`` trains a stage (the command
line); in Python::

    from t2m.presets import tiny
    from t2m.train import load_stage, train_stage

    train_stage("autoencoder", tiny(), "data/demo", "checkpoints/tiny")
    autoencoder = load_stage("checkpoints/tiny", "autoencoder")

The stages, their make targets, models and prerequisites are one table, :mod:`t2m.train.stages`.
"""

from t2m.train.checkpoint import ModelSizes, TrainedStage
from t2m.train.job import Stage
from t2m.train.stages import STAGE_NAMES, STAGES, find_stage, load_stage, train_stage

__all__ = [
    "STAGES",
    "STAGE_NAMES",
    "ModelSizes",
    "Stage",
    "TrainedStage",
    "find_stage",
    "load_stage",
    "train_stage",
]
