"""``python -m t2m.demo`` (``make demo``): the whole system on a fresh machine, end to end.

Steps, each skipped when its result already exists (so a second run reuses the first):
1. build the procedural demo dataset (``data/demo``);
2. train the four stages at the ``demo`` preset (``checkpoints/demo``), resuming an interrupted
   stage; with ``parallel`` (the default) the autoencoder and then the generator train in this
   process while a second process trains the length model and, once the autoencoder has
   finished, the evaluator (:func:`train_stages`);
3. sample three example prompts, several motions each, rendered (``outputs/demo``; with
   ``parallel`` in a second process, its log in ``outputs/demo.log``);
4. run a quick evaluation (``outputs/demo_eval``), and one of the paraphrase split, captions in
   wording no stage trained on (``outputs/demo_eval_paraphrase``), when the dataset has it;
and print where everything is with a short summary.
"""

from __future__ import annotations

import json
import logging
import multiprocessing
import os
import queue
import resource
import sys
import time
import traceback
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

from dataset_tools.command import (
    CommandParser,
    UsageError,
    command,
    configure_logging,
    option,
    parse_config,
)
from dataset_tools.io import check_output_folder
from t2m.config import check_seed
from t2m.evaluate.report import headline
from t2m.presets import PRESETS, preset
from t2m.train import runtime as runtime_module
from t2m.train.logbook import read_records
from t2m.train.stage import FINISHED
from t2m.train.stages import STAGES, find_stage, train_stage

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


# The stages trained in the demo's own process, in this order: the longest chain (the generator
# is most of the training time, and it needs the autoencoder). With ``parallel``, the others train
# meanwhile in one second process, each once the stages it needs have finished.
MAIN_LANE = ("autoencoder", "generator")
# The second process's log (its progress bars and records), in the run folder.
SIDE_LOG = "side_stages.log"
# Torch threads of the generator stage once the second process is done (the preset's one thread
# elsewhere and before). At demo size a temporal-VAE training step took 0.53-0.71x the time with
# two threads than with one (quiet 2-core machine, 2026-12-01, interleaved); with two threads
# beside the second process's evaluator it ran at a third of one thread's speed (oversubscribed
# cores), hence the switch between epochs.
GENERATOR_THREADS = 2


def _finished(run_dir: Path, name: str) -> bool:
    return (find_stage(name).folder(run_dir) / FINISHED).is_file()


class Stopwatch:
    """Wall time and CPU time (this process and its finished child processes, user + system)
    since it was made: on a shared machine the CPU time says what the wall time would be alone."""

    def __init__(self) -> None:
        self.wall, self.cpu = time.perf_counter(), self._cpu()

    @staticmethod
    def _cpu() -> float:
        own, children = (
            resource.getrusage(who) for who in (resource.RUSAGE_SELF, resource.RUSAGE_CHILDREN)
        )
        return own.ru_utime + own.ru_stime + children.ru_utime + children.ru_stime

    def __str__(self) -> str:
        return f"{time.perf_counter() - self.wall:.0f} s (CPU {self._cpu() - self.cpu:.0f} s)"


def _train_one(
    name: str,
    preset_name: str,
    dataset: Path,
    run_dir: Path,
    side_busy: Callable[[], bool] = lambda: False,
) -> str:
    """Train one stage (resuming an interrupted run of it); returns its status line.

    The generator takes :data:`GENERATOR_THREADS` CPU threads (as many as this process may use)
    from the first epoch that starts while ``side_busy()`` is false, one before."""
    resume = (find_stage(name).folder(run_dir) / "latest.pt").is_file()
    logger.info("training %s (%s) ...", name, "resuming" if resume else "from scratch")
    watch = Stopwatch()
    config = preset(preset_name)
    runtime = None
    cores = min(GENERATOR_THREADS, len(os.sched_getaffinity(0)))
    if name == "generator" and cores > 1:
        runtime = runtime_module.start(config.device, config.bf16, config.num_threads)
        runtime.epoch_threads = lambda: 1 if side_busy() else cores
    train_stage(name, config, dataset, run_dir, runtime=runtime, resume=resume)
    logger.info("%s trained in %s", name, watch)
    return f"trained in {watch}"


def _in_second_process(
    function: Callable[..., Any], args: tuple, log_path: Path, results: multiprocessing.Queue
) -> None:
    """The body of a :class:`SecondProcess`: ``function(*args)`` with its output (progress bars,
    log records) in ``log_path``; puts ``("ok", result)``, ``("usage", message)`` or
    ``("error", message)`` on ``results``."""
    with open(log_path, "a", encoding="utf-8") as log:
        sys.stdout = sys.stderr = log
        configure_logging()
        try:
            results.put(("ok", function(*args)))
        except UsageError as error:
            results.put(("usage", str(error)))
        except BaseException as error:  # reported to the parent, then re-raised
            traceback.print_exc()
            results.put(("error", f"{type(error).__name__}: {error}"))
            raise


class SecondProcess:
    """``function(*args)`` in a spawned process (no state shared with this one) while this one
    works on; a context manager that ends the process if this one fails or is interrupted.

    Args:
        what: what it does, for the log lines and errors ("training length, evaluator").
        function, args: a module-level function and its (picklable) arguments.
        log: the file that gets its output.
    """

    def __init__(self, what: str, function: Callable[..., Any], args: tuple, log: Path):
        log.parent.mkdir(parents=True, exist_ok=True)
        self.what, self.log = what, log
        context = multiprocessing.get_context("spawn")
        self.results = context.Queue()
        self.process = context.Process(
            target=_in_second_process, args=(function, args, log, self.results), daemon=True
        )
        self.process.start()
        logger.info("%s in a second process meanwhile (log: %s)", what, log)

    def __enter__(self) -> SecondProcess:
        return self

    def __exit__(self, *exc_info: object) -> None:
        if self.process.is_alive():
            self.process.terminate()
        self.process.join()

    def join(self) -> Any:
        """Wait for the function's result; its UsageError again, or RuntimeError naming the log."""
        logger.info("waiting for the second process (%s) ...", self.what)
        while True:
            try:
                kind, value = self.results.get(timeout=1.0)
                break
            except queue.Empty:  # still running, unless it died
                if not self.process.is_alive() and self.results.empty():
                    kind, value = "error", f"it ended with exit code {self.process.exitcode}"
                    break
        self.process.join()
        if kind == "usage":
            raise UsageError(value)
        if kind == "error":
            raise RuntimeError(
                f"{self.what} in the second process failed: {value} (see {self.log})"
            )
        return value


def _train_side(names: list[str], preset_name: str, dataset: Path, run_dir: Path) -> dict:
    """The second process's training: ``names`` in order, each once its needs have finished
    (trained by the first process); returns their status lines."""
    status = {}
    for name in names:
        while not all(_finished(run_dir, need) for need in find_stage(name).needs):
            parent = multiprocessing.parent_process()
            if parent is not None and not parent.is_alive():
                raise RuntimeError("the demo's main process ended")
            time.sleep(1.0)
        status[name] = _train_one(name, preset_name, dataset, run_dir) + " (2nd process)"
    return status


def train_stages(
    dataset: Path, run_dir: Path, preset_name: str, parallel: bool = False
) -> dict[str, str]:
    """Step 2: every stage not yet finished; an interrupted one resumes from latest.pt.

    With ``parallel``, the stages off :data:`MAIN_LANE` train in a second process at the same
    time (:class:`SecondProcess`); every stage seeds itself, so the result is the same as training
    them one after the other. Returns stage name -> status line, in :data:`STAGES` order.
    """
    status, todo = {}, []
    for stage in STAGES:
        if _finished(run_dir, stage.name):
            status[stage.name] = "reused"
        else:
            todo.append(stage.name)
    side = [name for name in todo if name not in MAIN_LANE] if parallel else []
    main = [name for name in todo if name not in side]
    if not side:
        for name in main:
            status[name] = _train_one(name, preset_name, dataset, run_dir)
    else:
        args = (side, preset_name, dataset, run_dir)
        what = f"training {', '.join(side)}"
        with SecondProcess(what, _train_side, args, run_dir / SIDE_LOG) as helper:
            for name in main:
                status[name] = _train_one(
                    name, preset_name, dataset, run_dir, helper.process.is_alive
                )
            status.update(helper.join())
    return {stage.name: status[stage.name] for stage in STAGES}


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
    from t2m.outputs import sample_to_folder
    from t2m.pipeline import TextToMotion
    from t2m.prompts import Prompt

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


# The quick evaluation's torch threads, pinned: the thread count changes the order of float sums
# and so, now and then, a detector's verdict; left to torch, it was what the generator's training
# last set (one or two threads, depending on when the second process finished), and the demo's
# table differed in the third digit from the same evaluation run alone.
EVALUATION_THREADS = 1

OMITTED_SPREAD = (
    "not in this spread: the generator's training seed (training it three times would add "
    "about 10 minutes to make demo); measured apart in docs/results.md"
)


def quick_evaluation(dataset: Path, run_dir: Path, out: Path, split: str = "test") -> dict:
    """Step 4: the evaluation protocol in its quick form (marked as such in its output), what
    ``python -m t2m.evaluate --dataset DATASET --checkpoints RUN --quick --threads 1 [--split
    SPLIT]`` runs."""
    from t2m.evaluate import EvalConfig, evaluate, quick_config

    config = quick_config(EvalConfig(split=split, num_threads=EVALUATION_THREADS))
    return evaluate(dataset, run_dir, out, config)


PARAPHRASE_SPLIT = "test_paraphrase"
"""The demo corpus's split captioned in wording no stage trained on
(:data:`dataset_tools.synth.corpus.PARAPHRASE_SPLIT`), evaluated beside the test split."""


def paraphrase_evaluation(dataset: Path, run_dir: Path, out: Path) -> dict | str | None:
    """Step 4 again on the paraphrase split (into ``out``), when the dataset has one: its
    summary, or why it could not be evaluated (a split of a small corpus holds fewer items than
    one R-precision pool); None without such a split."""
    split_file = dataset / f"{PARAPHRASE_SPLIT}.txt"
    if not split_file.is_file() or not split_file.read_text(encoding="utf-8").strip():
        return None
    try:
        return quick_evaluation(dataset, run_dir, out, PARAPHRASE_SPLIT)
    except UsageError as error:
        logger.warning("the %s split is not evaluated: %s", PARAPHRASE_SPLIT, error)
        return str(error)


def _evaluations(dataset: Path, run_dir: Path, eval_dir: Path) -> tuple[dict, dict | str | None]:
    """The quick evaluation of the test split, then of the paraphrase split."""
    summary = quick_evaluation(dataset, run_dir, eval_dir)
    paraphrase_dir = eval_dir.parent / f"{eval_dir.name}_paraphrase"
    return summary, paraphrase_evaluation(dataset, run_dir, paraphrase_dir)


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
    parallel: bool = True
    """use a second process: the length model and the evaluator train while the autoencoder and
    the generator do, the samples are made while the evaluation runs (the same results, sooner
    on two cores)"""
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
    start, times = time.perf_counter(), {}
    dataset, run_dir, out = config.dataset, config.checkpoints, config.out
    eval_dir = out.parent / f"{out.name}_eval"
    # 0. the output folders, before the long work (the samples replace only an earlier demo's)
    from t2m.outputs import check_out

    check_out(out, overwrite=True)
    check_output_folder(eval_dir, "the evaluation folder")
    check_output_folder(eval_dir.parent / f"{eval_dir.name}_paraphrase", "the evaluation folder")
    # 1. dataset
    watch = Stopwatch()
    if _dataset_ready(dataset):
        logger.info("dataset %s exists: reused", dataset)
    else:
        build_dataset(dataset, config.source, config.clips, config.seed, config.workers)
    report = json.loads((dataset / "build_report.json").read_text(encoding="utf-8"))
    times["dataset"] = str(watch)
    # 2. training
    watch = Stopwatch()
    status = train_stages(dataset, run_dir, config.preset, parallel=config.parallel)
    times["training"] = str(watch)
    # 3. samples and 4. evaluation (with ``parallel``: the samples, mostly video encoding, in a
    # second process)
    watch = Stopwatch()
    sampling = (run_dir, out, config.samples, config.render, config.seed)
    if config.parallel:
        log = out.parent / f"{out.name}.log"
        with SecondProcess("sampling the example prompts", sample_prompts, sampling, log) as side:
            summary, paraphrase = _evaluations(dataset, run_dir, eval_dir)
            side.join()
        times["samples and evaluation"] = str(watch)
    else:
        sample_prompts(*sampling)
        times["samples"], watch = str(watch), Stopwatch()
        summary, paraphrase = _evaluations(dataset, run_dir, eval_dir)
        times["evaluation"] = str(watch)
    table = (eval_dir / "results.md").read_text(encoding="utf-8")

    lines = [
        "",
        "=" * 78,
        f"make demo finished in {(time.perf_counter() - start) / 60:.1f} min",
        "steps        " + ", ".join(f"{step} {took}" for step, took in times.items()),
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
        f"  evaluation took {summary['timings_s']['total_s']:.0f} s",
        "",
        "headline     " + "\n".join(headline(summary)),
        f"  {OMITTED_SPREAD}",
    ]
    if isinstance(paraphrase, str):
        lines += ["", f"paraphrases  the {PARAPHRASE_SPLIT} split is not evaluated: {paraphrase}"]
    elif paraphrase is not None:
        lines += [
            "",
            f"paraphrases  the {PARAPHRASE_SPLIT} split: captions in wording no stage trained "
            f"on ({eval_dir.name}_paraphrase/results.md), " + "\n".join(headline(paraphrase)),
        ]
    lines += [
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
