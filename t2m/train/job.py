"""A training stage's record and the job its loop is given.

:class:`Stage` is one row of the stage table (:data:`t2m.train.stages.STAGES`): its name, make
target, models, how they are built, its loop and the stages it needs. :class:`StageJob` is what
the table hands that loop (a function in ``t2m/train/autoencoder.py`` ...): the stage's record,
the config, the folders, the runtime and the stages it builds on, loaded.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from torch import nn

from dataset_tools.command import UsageError
from t2m.config import Config
from t2m.train.checkpoint import ModelSizes, TrainedStage
from t2m.train.runtime import Runtime


@dataclass(frozen=True)
class Stage:
    """One training stage.

    Attributes:
        name: what users see and type; also its config section and its folder.
        make_target: the ``make`` target that trains it (named in "run this first" messages).
        models: the names of the modules its checkpoints store.
        build: fresh (untrained) models from a Config and the data's sizes, by name.
        train: its loop (see :class:`StageJob`).
        needs: the stages it builds on (trained first; given to ``train`` loaded).
        old_names: names of the first releases: accepted wherever a stage is named, and the
            folder and checkpoint names of runs written then.
    """

    name: str
    make_target: str
    models: tuple[str, ...]
    build: Callable[[Config, ModelSizes], dict[str, nn.Module]]
    train: Callable[[StageJob], Path]
    needs: tuple[str, ...] = ()
    old_names: tuple[str, ...] = ()

    def folder(self, run_dir: str | Path) -> Path:
        """The stage's folder in ``run_dir``: the one that exists (a run of the first releases
        keeps its old folder name), else the stage's name."""
        for name in (self.name, *self.old_names):
            if (Path(run_dir) / name).is_dir():
                return Path(run_dir) / name
        return Path(run_dir) / self.name

    def not_trained(self, run_dir: str | Path) -> UsageError:
        """The one-line error for a missing stage, naming the make target that trains it."""
        return UsageError(
            f"no trained {self.name!r} stage in {self.folder(run_dir)} (run "
            f"`make {self.make_target}` with the same PRESET/CHECKPOINTS first)"
        )


@dataclass
class StageJob:
    """What a stage's loop is given (by :func:`t2m.train.stages.train_stage`).

    Attributes:
        stage: the registry's record of the stage.
        config: the run's settings.
        dataset_dir: the HumanML3D-layout folder to train on.
        run_dir: the run folder; the stage writes into its own folder there.
        runtime: device and process rank.
        resume: continue from ``latest.pt``.
        prerequisites: the trained stages this one builds on, by name.
    """

    stage: Stage
    config: Config
    dataset_dir: Path
    run_dir: Path
    runtime: Runtime
    resume: bool = False
    prerequisites: dict[str, TrainedStage] = field(default_factory=dict)
