"""``python -m t2m.evaluate``: the command over :func:`t2m.evaluate.run.evaluate`.

Its options are the fields of :class:`EvalFolders` and :class:`~t2m.evaluate.protocol.EvalConfig`
(help from their docstrings). It runs the evaluation, prints the table and where the files went.
Bad input is one line on stderr and exit status 2.
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import dataclass, field
from pathlib import Path

from dataset_tools.command import (
    CommandParser,
    add_config_options,
    command,
    config_from_args,
    configure_logging,
    option,
)
from t2m.evaluate.protocol import QUICK_SETTINGS, STANDARD, EvalConfig, quick_config
from t2m.evaluate.report import format_markdown
from t2m.evaluate.run import evaluate


@dataclass
class EvalFolders:
    """What is evaluated on what, and where the results go."""

    dataset: Path = field(metadata=option(metavar="DIR"))
    """HumanML3D-layout dataset folder"""
    checkpoints: Path = field(metadata=option(metavar="DIR"))
    """run folder with the evaluator, length and generator stages, or a folder of the original
    T2M release"""
    evaluator: Path | None = field(default=None, metadata=option(metavar="DIR"))
    """the standard evaluator: the original T2M release's checkpoints/<t2m|kit>/text_mot_match,
    fed as the release feeds it (default: the run's own evaluator stage; a release's own)"""
    glove: Path | None = field(default=None, metadata=option(metavar="DIR"))
    """the release's GloVe subset (default: glove/ beside the release's checkpoints/)"""
    out: Path | None = field(default=None, metadata=option(metavar="DIR"))
    """output folder (default: <checkpoints>/eval_results, eval_results_quick with --quick)"""

    def out_dir(self, quick: bool) -> Path:
        """``out``, or its default for a standard or a quick run."""
        default = "eval_results_quick" if quick else "eval_results"
        return self.out or self.checkpoints / default


def parser() -> CommandParser:
    """The command's options: one per field of EvalFolders and EvalConfig, plus ``--verbose``.

    The :data:`~t2m.evaluate.protocol.QUICK_SETTINGS` fields default to None (unset), so that
    ``--quick`` lowers only the values the user did not give.
    """
    result = CommandParser(
        prog="python -m t2m.evaluate",
        description="Evaluate trained stages with the protocol of Guo et al. 2022 (Table 2): "
        "R-precision, FID, MM-Dist, Diversity, MultiModality, mean ±95% interval over "
        "replications. Writes results.md and results.json into --out. With --edit MODE: the "
        "edit benchmark (python -m t2m.evaluate --edit MODE --help).",
    )
    add_config_options(result, EvalFolders)
    add_config_options(result, EvalConfig, defaults=dict.fromkeys(QUICK_SETTINGS))
    result.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    return result


def eval_config(arguments: argparse.Namespace) -> EvalConfig:
    """The EvalConfig of parsed options: unset QUICK_SETTINGS take the standard values, or the
    quick ones with ``--quick``. Raises UsageError for impossible values."""
    given = {key for key in QUICK_SETTINGS if getattr(arguments, key) is not None}
    for key in QUICK_SETTINGS.keys() - given:
        setattr(arguments, key, getattr(STANDARD, key))
    config = config_from_args(EvalConfig, arguments)
    return quick_config(config, keep=given) if config.quick else config


@command
def main(argv: list[str] | None = None) -> int:
    """``python -m t2m.evaluate``; exit status 0 on success, 2 with a one-line reason on bad
    input. ``--edit MODE`` runs the edit benchmark instead (:mod:`t2m.evaluate.edit_bench`)."""
    argv = sys.argv[1:] if argv is None else argv
    if any(arg == "--edit" or arg.startswith("--edit=") for arg in argv):
        from t2m.evaluate.edit_bench import main as edit_benchmark

        return edit_benchmark(argv)
    arguments = parser().parse_args(argv)
    configure_logging(arguments.verbose)
    folders = config_from_args(EvalFolders, arguments)
    config = eval_config(arguments)
    out = folders.out_dir(config.quick)
    summary = evaluate(
        folders.dataset,
        folders.checkpoints,
        out,
        config,
        evaluator_dir=folders.evaluator,
        glove_dir=folders.glove,
    )
    print(format_markdown(summary))
    print(f"wrote {out / 'results.md'} and {out / 'results.json'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
