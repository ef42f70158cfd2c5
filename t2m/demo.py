"""``python -m t2m.demo`` (``make demo``): the whole system on a fresh machine, end to end.

Steps, each skipped when its result already exists (so a second run reuses the first):
1. build the procedural demo dataset (``data/demo``);
2. train the four stages at the ``demo`` preset (``checkpoints/demo``), resuming an interrupted
   stage;
3. sample three example prompts, several motions each, rendered (``outputs/demo``);
4. run a quick evaluation (``outputs/demo_eval``);
and print where everything is with a short summary.
"""

from __future__ import annotations

import json
import logging
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

from dataset_tools.command import (
    CommandParser,
    UsageError,
    command,
    option,
    parse_config,
)
from dataset_tools.io import check_output_folder
from t2m.config import PRESETS, check_seed, preset
from t2m.train.logbook import read_records
from t2m.train.stage import FINISHED
from t2m.train.stages import STAGES, train_stage

logger = logging.getLogger("t2m.demo")

PROMPTS = (
    "a person walks forward and then waves with the right hand",
    "someone jumps up and down twice",
    "a man walks backward slowly, then raises his left arm",
)


def _dataset_ready(dataset: Path) -> bool:
    return all((dataset / name).exists() for name in ("Mean.npy", "Std.npy", "all.txt", "texts"))


def build_dataset(dataset: Path, source: Path, clips: int, seed: int, workers: int) -> None:
    """Step 1: the procedural corpus, then the HumanML3D-layout build."""
    from dataset_tools.build import BuildConfig, build_dataset
    from dataset_tools.synth.corpus import write_corpus

    if not (source / "source.json").is_file():
        write_corpus(source, clips, seed=seed, workers=workers, force=True)
    report = build_dataset(BuildConfig("joints", source, dataset, workers=workers, seed=seed))
    if not report["clips_out"]:
        raise UsageError(f"building {dataset} from {source} gave no clip (see build_report.json)")


def train_stages(dataset: Path, run_dir: Path, preset_name: str) -> dict[str, str]:
    """Step 2: every stage not yet finished; an interrupted one resumes from latest.pt."""
    config = preset(preset_name)
    status = {}
    for stage in STAGES:
        stage_dir = stage.folder(run_dir)
        if (stage_dir / FINISHED).is_file():
            status[stage.name] = "reused"
            continue
        resume = (stage_dir / "latest.pt").is_file()
        logger.info("training %s (%s) ...", stage.name, "resuming" if resume else "from scratch")
        start = time.perf_counter()
        train_stage(stage.name, config, dataset, run_dir, resume=resume)
        status[stage.name] = f"trained in {time.perf_counter() - start:.0f} s"
    return status


def final_losses(run_dir: Path) -> dict[str, dict]:
    """The last validation record of each stage (from its metrics.jsonl)."""
    losses = {}
    for stage in STAGES:
        last = None
        for record in read_records(stage.folder(run_dir) / "metrics.jsonl"):
            if record.get("split") == "val":
                last = record
        if last:
            losses[stage.name] = {k: v for k, v in last.items() if isinstance(v, float)}
    return losses


def sample_prompts(run_dir: Path, out: Path, num_samples: int, render: str, seed: int) -> None:
    """Step 3: the example prompts, several motions each, rendered, with BVH files."""
    from t2m.pipeline import TextToMotion
    from t2m.sample import Prompt, sample_to_folder

    pipe = TextToMotion.from_checkpoints(run_dir, device="auto")
    sample_to_folder(
        pipe,
        [Prompt(text) for text in PROMPTS],
        out,
        num_samples=num_samples,
        seed=seed,
        render=render,
        bvh=True,
        overwrite=True,
        extra_info={"checkpoints": str(run_dir)},
    )


def quick_evaluation(dataset: Path, run_dir: Path, out: Path) -> dict:
    """Step 4: the evaluation protocol in its quick form (marked as such in its output)."""
    from t2m.evaluate import EvalConfig, evaluate, quick_config

    return evaluate(dataset, run_dir, out, quick_config(EvalConfig()))


@dataclass
class DemoConfig:
    """What ``make demo`` builds, trains, samples and evaluates, and where it puts it."""

    clips: int = 2000
    """demo corpus size (clips before mirroring)"""
    samples: int = 3
    """motions per example prompt"""
    render: Literal["mp4", "gif", "none"] = "mp4"
    """animation of each sampled motion"""
    preset: str = field(default="demo", metadata=option(choices=PRESETS))
    """training preset"""
    seed: int = 0
    """seed of the corpus, the dataset build and the samples"""
    workers: int = 2
    """processes for the corpus and the dataset build"""
    dataset: Path = field(default=Path("data/demo"), metadata=option(metavar="DIR"))
    """the HumanML3D-layout dataset folder"""
    source: Path = field(default=Path("data/demo_src"), metadata=option(metavar="DIR"))
    """the procedural corpus folder the dataset is built from"""
    checkpoints: Path = field(default=Path("checkpoints/demo"), metadata=option(metavar="DIR"))
    """the run folder"""
    out: Path = field(default=Path("outputs/demo"), metadata=option(metavar="DIR"))
    """the samples folder (the quick evaluation goes beside it, into <out>_eval)"""

    def __post_init__(self) -> None:
        for name in ("clips", "samples", "workers"):
            if getattr(self, name) < 1:
                raise UsageError(f"--{name} must be at least 1, got {getattr(self, name)}")
        check_seed(self.seed)


def run_demo(config: DemoConfig) -> str:
    """Run every step that has no result yet; return the summary text."""
    start = time.perf_counter()
    dataset, run_dir, out = config.dataset, config.checkpoints, config.out
    eval_dir = out.parent / f"{out.name}_eval"
    # 0. the output folders, before the long work (the samples replace only an earlier demo's)
    from t2m.sample import check_out

    check_out(out, overwrite=True)
    check_output_folder(eval_dir, "the evaluation folder")
    # 1. dataset
    if _dataset_ready(dataset):
        logger.info("dataset %s exists: reused", dataset)
    else:
        build_dataset(dataset, config.source, config.clips, config.seed, config.workers)
    report = json.loads((dataset / "build_report.json").read_text(encoding="utf-8"))
    # 2. training
    status = train_stages(dataset, run_dir, config.preset)
    # 3. samples
    sample_prompts(run_dir, out, config.samples, config.render, config.seed)
    # 4. evaluation
    quick_evaluation(dataset, run_dir, eval_dir)
    table = (eval_dir / "results.md").read_text(encoding="utf-8")

    lines = [
        "",
        "=" * 78,
        f"make demo finished in {(time.perf_counter() - start) / 60:.1f} min",
        f"dataset      {dataset}: {report['clips_out']} clips ({report['hours_out']:.2f} h), "
        f"splits {report.get('splits')}",
        f"checkpoints  {run_dir}: "
        + ", ".join(f"{stage} {state}" for stage, state in status.items()),
    ]
    for stage, values in final_losses(run_dir).items():
        shown = ", ".join(f"{k} {v:.4g}" for k, v in list(values.items())[:4])
        lines.append(f"  {stage:<11} last validation: {shown}")
    lines += [
        f"samples      {out}/ (sampleNN_repRR.mp4|npy|bvh, results.npy, results.json)",
        f"curves       {run_dir}/<stage>/curves.png",
        f"evaluation   {eval_dir}/results.md (quick mode: a development check, not a paper number)",
        "",
        table,
    ]
    return "\n".join(lines)


@command(interrupted="interrupted; run it again to continue where it stopped")
def main(argv: list[str] | None = None) -> int:
    """``python -m t2m.demo``; exit status 0 on success, 2 with a one-line reason on bad input."""
    parser = CommandParser(
        prog="python -m t2m.demo",
        description="The whole system end to end: build the demo dataset, train the four "
        "stages, sample example prompts, run a quick evaluation. A step whose result exists "
        "is skipped (an interrupted training stage resumes).",
    )
    config = parse_config(parser, DemoConfig, argv)
    print(run_demo(config))
    return 0


if __name__ == "__main__":
    sys.exit(main())
