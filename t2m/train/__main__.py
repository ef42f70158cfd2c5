"""Command line: ``python -m t2m.train <stage> [options] [--key.sub=value ...]``.

Stages: autoencoder, length, generator (needs the autoencoder), evaluator (needs the
autoencoder); the old names ae, len, text2length, t2m, eval are accepted too. Examples::

    python -m t2m.train autoencoder --preset demo --dataset data/demo
    python -m t2m.train generator --preset paper --dataset data/HumanML3D --checkpoints checkpoints/hml
    python -m t2m.train autoencoder --preset tiny --autoencoder.epochs=3 --resume
    torchrun --nproc_per_node=2 -m t2m.train autoencoder --preset demo   # DistributedDataParallel

The command's own options are the fields of :class:`TrainOptions` (help from their docstrings).
Config overrides name any field of :class:`t2m.config.Config` with dots; an unknown key or a value
of the wrong type is an error. Exit status 2 with a one-line message on bad input.
"""

from __future__ import annotations

import logging
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

from dataset_tools.command import (
    CommandParser,
    UsageError,
    add_config_options,
    command,
    config_from_args,
    configure_logging,
    option,
)
from dataset_tools.io import check_output_folder
from t2m.config import Config, apply_overrides
from t2m.data.words import check_word_vectors
from t2m.presets import PRESETS, preset
from t2m.train.stages import STAGES, find_stage, train_stage

logger = logging.getLogger("t2m.train")

STAGE_CHOICES = tuple(name for stage in STAGES for name in (stage.name, *stage.old_names))


@dataclass
class TrainOptions:
    """The options of ``python -m t2m.train`` besides the ``--key.sub=value`` config overrides."""

    stage: str = field(metadata=option(positional=True, choices=STAGE_CHOICES, metavar="stage"))
    """autoencoder, length, generator (needs autoencoder) or evaluator (needs autoencoder); the
    old names ae, len, text2length, t2m, eval are accepted"""
    preset: str = field(default="demo", metadata=option(choices=PRESETS))
    """the config to start from (overrides change it)"""
    dataset: Path = field(default=Path("data/demo"), metadata=option(metavar="DIR"))
    """HumanML3D-layout dataset folder"""
    checkpoints: Path | None = field(default=None, metadata=option(metavar="DIR"))
    """run folder (default: checkpoints/<preset>)"""
    resume: bool = False
    """continue from the stage's latest.pt"""
    force: bool = False
    """retrain a stage whose folder already holds a run (its files move into previous/ first)"""
    device: str | None = None
    """auto, cpu, cuda, cuda:N (default: the config's, auto)"""
    bf16: bool | None = None
    """bfloat16 autocast (default: the config's, off); faster only on a GPU or a CPU with
    AVX512_BF16 or AMX, elsewhere much slower (with a warning)"""
    seed: int | None = None
    """random seed (default: the config's, 0)"""
    print_config: bool = False
    """print the resolved config as JSON and exit"""

    def config(self, overrides: dict[str, str]) -> Config:
        """The preset with ``--device/--bf16/--seed`` and ``overrides`` applied (UsageError for
        an unknown key or a value of the wrong type)."""
        given = {"device": self.device, "bf16": self.bf16, "seed": self.seed}
        options = {key: str(value) for key, value in given.items() if value is not None}
        return apply_overrides(preset(self.preset), {**overrides, **options})

    def run_dir(self) -> Path:
        """``--checkpoints``, or ``checkpoints/<preset>``."""
        return self.checkpoints or Path("checkpoints") / self.preset


def parse_overrides(extra: list[str]) -> dict[str, str]:
    """``--a.b=v`` / ``--a.b v`` pairs -> {"a.b": "v"}; UsageError for anything else."""
    overrides: dict[str, str] = {}
    index = 0
    while index < len(extra):
        item = extra[index]
        if not item.startswith("--") or len(item) <= 2:
            raise UsageError(
                f"unexpected argument {item!r} (overrides look like --generator.batch_size=16)"
            )
        key, sep, value = item[2:].partition("=")
        if not sep:
            if index + 1 >= len(extra):
                raise UsageError(f"override --{key} needs a value")
            value = extra[index + 1]
            index += 1
        overrides[key.replace("-", "_")] = value
        index += 1
    return overrides


def parser() -> CommandParser:
    """The command's options: one per field of :class:`TrainOptions`, plus ``--verbose``."""
    result = CommandParser(
        prog="python -m t2m.train",
        description="Train one stage of T2M (Guo et al., CVPR 2022). Extra --key.sub=value "
        "arguments override config fields (e.g. --generator.batch_size=16, "
        "--data.word_vectors=PATH); --print-config shows them all.",
    )
    add_config_options(result, TrainOptions)
    result.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    return result


@command(interrupted="interrupted; continue with --resume")
def main(argv: list[str] | None = None) -> int:
    """``python -m t2m.train``; exit status 0 on success, 2 with a one-line reason on bad input."""
    arguments, extra = parser().parse_known_args(sys.argv[1:] if argv is None else argv)
    configure_logging(arguments.verbose)
    options = config_from_args(TrainOptions, arguments)
    config = options.config(parse_overrides(extra))
    if options.print_config:
        print(f"# preset {options.preset}: {PRESETS[options.preset].notes}", file=sys.stderr)
        print(config.to_json())
        return 0
    stage = find_stage(options.stage).name
    check_word_vectors(config.data.word_vectors)  # before any long work
    check_output_folder(options.run_dir(), "--checkpoints")
    start = time.time()
    stage_dir = train_stage(
        stage,
        config,
        options.dataset,
        options.run_dir(),
        resume=options.resume,
        force=options.force,
    )
    logger.info("%s trained in %.0f s: %s", stage, time.time() - start, stage_dir)
    return 0


if __name__ == "__main__":
    sys.exit(main())
