"""Command line: ``python -m t2m.train {ae,length,t2m,eval} [options] [--key.sub=value ...]``.

Examples::

    python -m t2m.train ae --preset demo --dataset data/demo
    python -m t2m.train t2m --preset paper --dataset data/HumanML3D --checkpoints checkpoints/hml
    python -m t2m.train ae --preset tiny --ae.epochs=3 --data.word_vectors=trainable --resume
    torchrun --nproc_per_node=2 -m t2m.train ae --preset demo      # DistributedDataParallel

Config overrides name any field of :class:`t2m.config.Config` with dots; an unknown key or a value
of the wrong type is an error. Exit status 2 with a one-line message on bad input.
"""

from __future__ import annotations

import argparse
import logging
import os
import sys
import time
from pathlib import Path

from t2m.config import STAGES, Config, apply_overrides, preset
from t2m.train import runtime as runtime_module

logger = logging.getLogger("t2m.train")

TRAINERS = {
    "ae": ("t2m.train.ae", "train_autoencoder"),
    "length": ("t2m.train.length", "train_length"),
    "t2m": ("t2m.train.t2m", "train_text_to_motion"),
    "eval": ("t2m.train.evaluator", "train_evaluator"),
}


def run_stage(
    stage: str,
    config: Config,
    dataset_dir: str | Path,
    run_dir: str | Path,
    runtime: runtime_module.Runtime | None = None,
    resume: bool = False,
) -> Path:
    """Train ``stage`` with ``config``; opens (and closes) the runtime when not given one."""
    import importlib

    if stage not in TRAINERS:
        raise ValueError(f"unknown stage {stage!r}; choose one of {', '.join(STAGES)}")
    own_runtime = runtime is None
    if runtime is None:
        runtime = runtime_module.start(config.device, config.bf16, config.num_threads)
    try:
        module_name, function_name = TRAINERS[stage]
        trainer = getattr(importlib.import_module(module_name), function_name)
        return trainer(config, dataset_dir, run_dir, runtime, resume)
    finally:
        if own_runtime:
            runtime_module.finish(runtime)


def parse_overrides(extra: list[str]) -> dict[str, str]:
    """``--a.b=v`` / ``--a.b v`` pairs -> {"a.b": "v"}; ValueError for anything else."""
    overrides: dict[str, str] = {}
    index = 0
    while index < len(extra):
        item = extra[index]
        if not item.startswith("--") or len(item) <= 2:
            raise ValueError(
                f"unexpected argument {item!r} (overrides look like --t2m.batch_size=16)"
            )
        key, sep, value = item[2:].partition("=")
        if not sep:
            if index + 1 >= len(extra):
                raise ValueError(f"override --{key} needs a value")
            value = extra[index + 1]
            index += 1
        overrides[key.replace("-", "_")] = value
        index += 1
    return overrides


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="python -m t2m.train",
        description="Train one stage of T2M (Guo et al., CVPR 2022). Extra --key.sub=value "
        "arguments override config fields (e.g. --t2m.batch_size=16, --data.word_vectors=PATH).",
    )
    parser.add_argument(
        "stage", choices=STAGES, help="ae, length, t2m (needs ae) or eval (needs ae)"
    )
    parser.add_argument("--preset", default="demo", help="paper, demo or tiny (default demo)")
    parser.add_argument(
        "--dataset", default="data/demo", help="HumanML3D-layout folder (default data/demo)"
    )
    parser.add_argument(
        "--checkpoints", default=None, help="run folder (default checkpoints/<preset>)"
    )
    parser.add_argument("--resume", action="store_true", help="continue from <stage>/latest.pt")
    parser.add_argument(
        "--device", default=None, help="auto, cpu, cuda, cuda:N (default: the config's, auto)"
    )
    parser.add_argument("--bf16", action="store_true", help="bfloat16 autocast")
    parser.add_argument(
        "--seed", type=int, default=None, help="random seed (default: the config's, 0)"
    )
    parser.add_argument(
        "--print-config", action="store_true", help="print the resolved config as JSON and exit"
    )
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args, extra = parser.parse_known_args(sys.argv[1:] if argv is None else argv)
    main_process = os.environ.get("RANK", "0") == "0"  # under torchrun, only rank 0 talks
    logging.basicConfig(
        level=(logging.DEBUG if args.verbose else logging.INFO)
        if main_process
        else logging.WARNING,
        format="%(asctime)s %(name)s: %(message)s",
        datefmt="%H:%M:%S",
    )
    try:
        overrides = parse_overrides(extra)
        if args.device is not None:
            overrides["device"] = args.device
        if args.bf16:
            overrides["bf16"] = "true"
        if args.seed is not None:
            overrides["seed"] = str(args.seed)
        config = apply_overrides(preset(args.preset), overrides)
        if args.print_config:
            print(config.to_json())
            return 0
        run_dir = Path(args.checkpoints or f"checkpoints/{args.preset}")
        start = time.time()
        stage_dir = run_stage(args.stage, config, args.dataset, run_dir, resume=args.resume)
    except ValueError as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("interrupted; continue with --resume", file=sys.stderr)
        return 130
    logger.info("%s trained in %.0f s: %s", args.stage, time.time() - start, stage_dir)
    return 0


if __name__ == "__main__":
    sys.exit(main())
