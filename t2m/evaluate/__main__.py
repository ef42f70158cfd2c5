"""``python -m t2m.evaluate``: the command over :func:`t2m.evaluate.run.evaluate`.

Parses the options into an :class:`~t2m.evaluate.protocol.EvalConfig`, checks the folders, runs
the evaluation, prints the table and where the files went. Bad input is one line on stderr and
exit code 2.
"""

from __future__ import annotations

import argparse
import dataclasses
import logging
import sys
from pathlib import Path

from t2m.evaluate.protocol import STANDARD, EvalConfig, quick_config
from t2m.evaluate.report import format_markdown
from t2m.evaluate.run import evaluate


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="python -m t2m.evaluate",
        description="Evaluate trained stages with the protocol of Guo et al. 2022 (Table 2): "
        "R-precision, FID, MM-Dist, Diversity, MultiModality, mean ±95% interval over "
        "replications. Writes results.md and results.json into --out.",
    )
    parser.add_argument("--dataset", required=True, help="HumanML3D-layout dataset folder")
    parser.add_argument("--checkpoints", required=True, help="run folder with eval/ length/ t2m/")
    parser.add_argument(
        "--split", default=STANDARD.split, help="split file to evaluate (default: test)"
    )
    parser.add_argument(
        "--replications", type=int, default=None, help="default 20 (3 with --quick)"
    )
    parser.add_argument(
        "--mm-texts", type=int, default=None, help="MultiModality captions (default 100)"
    )
    parser.add_argument(
        "--mm-samples", type=int, default=None, help="generations per caption (default 30)"
    )
    parser.add_argument(
        "--max-items", type=int, default=None, help="evaluate at most this many items"
    )
    parser.add_argument(
        "--quick",
        action="store_true",
        help="development run: 3 replications on a subset, marked as such",
    )
    parser.add_argument(
        "--out", default=None, help="output folder (default: <checkpoints>/eval_results[_quick])"
    )
    parser.add_argument("--device", default="cpu", help="torch device (default cpu)")
    parser.add_argument(
        "--batch-size",
        type=int,
        default=STANDARD.batch_size,
        help="items per forward pass (speed only; default 128, raise it on a GPU)",
    )
    parser.add_argument(
        "--seed", type=int, default=STANDARD.seed, help="seed of replication 0 (default 0)"
    )
    parser.add_argument(
        "--threads", type=int, default=0, help="torch CPU threads (default: torch's choice)"
    )
    parser.add_argument(
        "--which", choices=("best", "latest"), default="best", help="checkpoint of each stage"
    )
    parser.add_argument(
        "--precision",
        choices=("fp32", "bf16", "int8"),
        default="fp32",
        help="generator precision (default fp32; others are marked as deviations)",
    )
    return parser


def config_from_args(args: argparse.Namespace) -> EvalConfig:
    """An EvalConfig from parsed arguments (None means: the default, or the quick value)."""
    explicit = {
        key: getattr(args, key)
        for key in ("replications", "mm_texts", "mm_samples", "max_items")
        if getattr(args, key) is not None
    }
    for key, value in explicit.items():
        if value < 1:
            raise ValueError(f"--{key.replace('_', '-')} must be >= 1, got {value}")
    config = EvalConfig(
        split=args.split,
        batch_size=args.batch_size,
        seed=args.seed,
        device=args.device,
        which=args.which,
        precision=args.precision,
        num_threads=args.threads,
    )
    if args.quick:
        config = quick_config(config)
    return dataclasses.replace(config, **explicit)


def main(argv: list[str] | None = None) -> int:
    """``python -m t2m.evaluate``; exit code 0 on success, 2 with a one-line reason on bad input."""
    args = _parser().parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    try:
        config = config_from_args(args)
        if config.batch_size < 1:
            raise ValueError(f"--batch-size must be >= 1, got {config.batch_size}")
        if config.num_threads < 0:
            raise ValueError(f"--threads must be >= 0, got {config.num_threads}")
        if not Path(args.dataset).is_dir():
            raise ValueError(f"--dataset {args.dataset}: no such folder")
        if not Path(args.checkpoints).is_dir():
            raise ValueError(f"--checkpoints {args.checkpoints}: no such folder")
        if not (Path(args.dataset) / f"{config.split}.txt").is_file():
            raise ValueError(f"--dataset {args.dataset}: no split file {config.split}.txt")
        out = args.out or str(
            Path(args.checkpoints) / ("eval_results_quick" if config.quick else "eval_results")
        )
        summary = evaluate(args.dataset, args.checkpoints, out, config)
    except ValueError as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    print(format_markdown(summary))
    print(f"wrote {Path(out) / 'results.md'} and {Path(out) / 'results.json'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
