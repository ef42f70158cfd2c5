"""Evaluation of a trained run with the protocol of Guo et al. (CVPR 2022), Table 2.

``python -m t2m.evaluate --dataset DIR --checkpoints DIR`` writes ``results.md`` (the table) and
``results.json`` (every number, every replication, the settings and any deviation from the
standard protocol). The package's rooms:

- :mod:`~t2m.evaluate.protocol`: settings (:class:`EvalConfig`), drawing the test items, the
  replications and metric rows (:func:`run_protocol`), the scorer plug-ins (:func:`find_scorer`);
- :mod:`~t2m.evaluate.metrics`: the formulas (R-precision, FID, MM-Dist, diversity, ...);
- physical plausibility (foot skating ratio, jerk, ground penetration, floating), tabled beside
  the protocol's metrics for every row, is measured by :mod:`dataset_tools.physical` (numpy);
- :mod:`~t2m.evaluate.backend`: what the protocol needs from the models (:class:`Backend`), the
  generator behind it (:class:`CheckpointBackend`: a run of ours or the original T2M release) and
  the evaluator that embeds, fed its way (:class:`Embedder`: the run's own, or the release's
  ``text_mot_match``, the field's standard evaluator);
- :mod:`~t2m.evaluate.report`: summary, markdown table, results files;
- :mod:`~t2m.evaluate.run`: :func:`evaluate`, the library entry point (folders in, files out);
- ``__main__``: the command.

The names below are the public API; import them from here.
"""

from typing import Any

from t2m.evaluate.backend import Backend, CheckpointBackend, Embedder
from t2m.evaluate.protocol import (
    EXTRA_METRICS,
    GT_LENGTH,
    METRICS,
    QUICK_SETTINGS,
    REAL,
    ROWS,
    SAMPLED_LENGTH,
    STANDARD,
    Draw,
    EvalConfig,
    ProtocolResult,
    Scorer,
    deviations,
    draw_items,
    find_scorer,
    quick_config,
    run_protocol,
)
from t2m.evaluate.report import COLUMN_TITLES, format_markdown, summarize, write_results
from t2m.evaluate.run import evaluate

__all__ = [
    "COLUMN_TITLES",
    "EXTRA_METRICS",
    "GT_LENGTH",
    "METRICS",
    "QUICK_SETTINGS",
    "REAL",
    "ROWS",
    "SAMPLED_LENGTH",
    "STANDARD",
    "Backend",
    "CheckpointBackend",
    "Draw",
    "Embedder",
    "EvalConfig",
    "ProtocolResult",
    "Scorer",
    "deviations",
    "draw_items",
    "evaluate",
    "find_scorer",
    "format_markdown",
    "main",
    "quick_config",
    "run_protocol",
    "summarize",
    "write_results",
]


def __getattr__(name: str) -> Any:
    """``main`` (the command) is imported on first use: importing ``__main__`` here would make
    ``python -m t2m.evaluate`` load the command module twice."""
    if name == "main":
        from t2m.evaluate.__main__ import main

        return main
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
