"""The library entry point: evaluate a run folder on a dataset folder and write the results.

:func:`evaluate` is what ``python -m t2m.evaluate`` calls: check the inputs (:func:`check_inputs`,
one-line :class:`~dataset_tools.command.UsageError` before anything is loaded), load the stages
(or the original T2M release) and the evaluator as a
:class:`~t2m.evaluate.backend.CheckpointBackend`, read the split (and find the dataset's scorer,
if any), run the protocol, summarise and write ``results.json`` and ``results.md`` (which name
the evaluator, its file's hash and the statistics that normalise its input).
"""

from __future__ import annotations

import json
import logging
from pathlib import Path
from typing import Any

import torch

from dataset_tools.command import UsageError
from dataset_tools.io import check_output_folder
from dataset_tools.spec import spec_for_folder
from t2m.data.dataset import load_split
from t2m.evaluate.backend import Backend, CheckpointBackend
from t2m.evaluate.protocol import EvalConfig, find_scorer, run_protocol
from t2m.evaluate.report import summarize, write_results
from t2m.train.runtime import inference_device

logger = logging.getLogger("t2m.evaluate")


def check_inputs(
    dataset_dir: str | Path,
    checkpoints_dir: str | Path,
    out_dir: str | Path | None,
    split: str,
    evaluator_dir: str | Path | None = None,
    glove_dir: str | Path | None = None,
) -> None:
    """What can be checked before anything is loaded: :class:`UsageError` (one line) for a
    missing dataset, run, evaluator or GloVe folder, an evaluator folder that is not (in) a T2M
    release, a missing or empty split file, an ``out_dir`` that is a file."""
    from t2m.release import is_release_folder

    dataset_dir, checkpoints_dir = Path(dataset_dir), Path(checkpoints_dir)
    folders = {"--dataset": dataset_dir, "--checkpoints": checkpoints_dir}
    folders.update({"--evaluator": evaluator_dir, "--glove": glove_dir})
    for name, folder in folders.items():
        if folder is not None and not Path(folder).is_dir():
            raise UsageError(f"{name} {folder}: no such folder")
    if evaluator_dir is not None and not is_release_folder(evaluator_dir):
        raise UsageError(
            f"--evaluator {evaluator_dir}: not a T2M release folder (pass the release's "
            "checkpoints/<t2m|kit>/text_mot_match)"
        )
    split_file = dataset_dir / f"{split}.txt"
    if not split_file.is_file():
        raise UsageError(f"--dataset {dataset_dir}: no split file {split_file.name} (--split)")
    if not split_file.read_text(encoding="utf-8").strip():
        raise UsageError(f"--split {split}: {split_file} lists no clip")
    if out_dir is not None:
        check_output_folder(out_dir, "--out")
        _check_replaceable(Path(out_dir))


def _check_replaceable(out_dir: Path) -> None:
    """UsageError when ``out_dir`` holds a results.json or results.md that no evaluation wrote
    (an evaluation's results.json has its ``rows`` and ``settings``): they would be replaced."""
    json_path = out_dir / "results.json"
    if not (json_path.exists() or (out_dir / "results.md").exists()):
        return
    try:
        earlier = json.loads(json_path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        earlier = None
    if not (isinstance(earlier, dict) and {"rows", "settings"} <= earlier.keys()):
        raise UsageError(
            f"--out {out_dir} holds a results.json or results.md that no evaluation wrote; "
            "choose another --out"
        )


def evaluate(
    dataset_dir: str | Path,
    checkpoints_dir: str | Path,
    out_dir: str | Path | None,
    config: EvalConfig,
    backend: Backend | None = None,
    evaluator_dir: str | Path | None = None,
    glove_dir: str | Path | None = None,
) -> dict[str, Any]:
    """Evaluate the run (or T2M release) in ``checkpoints_dir`` on ``dataset_dir``; write
    results into ``out_dir``.

    ``evaluator_dir``: the original release's ``text_mot_match`` (the field's standard
    evaluator) instead of the run's own evaluator stage; ``glove_dir``: a release's GloVe subset
    (default: ``glove/`` beside its ``checkpoints/``). Both are ignored when ``backend`` is given.

    Steps: 0. check the inputs, 1. load the stages, 2. read the split, 3. run the protocol,
    4. summarise and write. Returns the summary (the content of results.json). What the user got
    wrong (folders, split, device, a missing stage, too few items) is a :class:`UsageError`,
    raised before the long work.
    """
    # 0. inputs
    check_inputs(dataset_dir, checkpoints_dir, out_dir, config.split, evaluator_dir, glove_dir)
    # 1. models
    if config.num_threads > 0:
        torch.set_num_threads(config.num_threads)
    if backend is None:
        device = inference_device(config.device, config.precision)
        try:
            backend = CheckpointBackend.from_run_dir(
                checkpoints_dir,
                device,
                config.which,
                config.batch_size,
                config.precision,
                evaluator_dir,
                glove_dir,
                config.plan,
            )
        except ValueError as error:  # unknown device, missing stage or file, models that differ
            raise UsageError(str(error)) from None
        logger.info("evaluator and generator on %s", backend.device)
    # 2. data, read as the models' dataset (a backend without a spec: the folder's own)
    try:
        spec = getattr(backend, "spec", None) or spec_for_folder(dataset_dir)
        clips = load_split(dataset_dir, config.split, spec=spec)
    except ValueError as error:  # not a dataset folder, unreadable clip, no usable clip
        raise UsageError(str(error)) from None
    semantic = find_scorer(dataset_dir)
    # 3. protocol
    result = run_protocol(
        clips,
        backend,
        config,
        spec=spec,
        semantic=semantic,
    )
    # 4. report
    summary = summarize(result)
    summary["dataset"] = str(dataset_dir)
    summary["checkpoints"] = str(checkpoints_dir)
    if isinstance(backend, CheckpointBackend):
        summary["device"] = str(backend.device)
        summary["evaluator"] = backend.embedder.description
    if out_dir is not None:
        write_results(summary, out_dir)
    return summary
