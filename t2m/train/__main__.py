"""Command line: ``python -m t2m.train <stage> [options] [--key.sub=value ...]``.

Stages: autoencoder, length, generator (needs the autoencoder), evaluator (needs the
autoencoder); the old names ae, len, text2length, t2m, eval are accepted too. Examples::

    python -m t2m.train autoencoder --preset demo --dataset data/demo
    python -m t2m.train generator --preset paper --dataset data/HumanML3D --checkpoints checkpoints/hml
    python -m t2m.train autoencoder --preset tiny --autoencoder.epochs=3 --resume
    torchrun --nproc_per_node=2 -m t2m.train autoencoder --preset demo   # DistributedDataParallel

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

from t2m.config import PRESETS, apply_overrides, preset
from t2m.train.stages import STAGES, find_stage, train_stage

logger = logging.getLogger("t2m.train")


def parse_overrides(extra: list[str]) -> dict[str, str]:
    """``--a.b=v`` / ``--a.b v`` pairs -> {"a.b": "v"}; ValueError for anything else."""
    overrides: dict[str, str] = {}
    index = 0
    while index < len(extra):
        item = extra[index]
        if not item.startswith("--") or len(item) <= 2:
            raise ValueError(
                f"unexpected argument {item!r} (overrides look like --generator.batch_size=16)"
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
        "arguments override config fields (e.g. --generator.batch_size=16, "
        "--data.word_vectors=PATH).",
    )
    stage_help = ", ".join(
        stage.name + (f" (needs {', '.join(stage.needs)})" if stage.needs else "")
        for stage in STAGES
    )
    parser.add_argument(
        "stage",
        choices=[name for stage in STAGES for name in (stage.name, *stage.old_names)],
        metavar="stage",
        help=f"{stage_help}; old names ae, len, t2m, eval are accepted",
    )
    parser.add_argument("--preset", default="demo", help=f"{', '.join(PRESETS)} (default demo)")
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
        stage = find_stage(args.stage).name
        if args.print_config:
            print(f"# preset {args.preset}: {PRESETS[args.preset].notes}", file=sys.stderr)
            print(config.to_json())
            return 0
        run_dir = Path(args.checkpoints or f"checkpoints/{args.preset}")
        start = time.time()
        stage_dir = train_stage(stage, config, args.dataset, run_dir, resume=args.resume)
    except ValueError as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("interrupted; continue with --resume", file=sys.stderr)
        return 130
    logger.info("%s trained in %.0f s: %s", stage, time.time() - start, stage_dir)
    return 0


if __name__ == "__main__":
    sys.exit(main())
