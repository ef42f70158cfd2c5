"""Scoring motions against the demo corpus' labels: the corpus' plug-in for the evaluation.

A dataset built from a corpus written by ``dataset_tools.synth`` still knows, through the corpus'
``labels.json``, which actions (with side, direction, ...) each clip performs, and the corpus'
detectors (:mod:`dataset_tools.synth.detectors`) recognise those labels from joints alone. So a
motion generated for an item's caption can be checked for the item's labels: the *semantic
accuracy* that ``python -m t2m.evaluate`` adds to its table when :func:`scorer_for` returns a
scorer. Numpy only; the evaluation finds this module by name (``t2m.evaluate.protocol``'s
``SCORER_PLUGINS``) and calls :func:`scorer_for`.
"""

from __future__ import annotations

import json
import logging
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from dataset_tools import humanml3d
from dataset_tools.build_clips import DATASET_FPS
from dataset_tools.representation import FeatureLayout, recover_from_ric
from dataset_tools.synth.corpus import GENERATOR
from dataset_tools.synth.detectors import MotionSignals
from dataset_tools.synth.matching import align_segments, mirror_label

logger = logging.getLogger(__name__)


def find_corpus_labels(dataset_dir: str | Path) -> Path | None:
    """The demo corpus' ``labels.json`` behind a built dataset, or None.

    Looked for in the dataset folder itself, then in the source folder its ``build_report.json``
    names, which must be a corpus written by ``dataset_tools.synth`` (its ``source.json`` says so).
    """
    dataset_dir = Path(dataset_dir)
    if (dataset_dir / humanml3d.LABELS_FILE).is_file():
        return dataset_dir / humanml3d.LABELS_FILE
    report_path = dataset_dir / humanml3d.REPORT_FILE
    if not report_path.is_file():
        return None
    try:
        report = json.loads(report_path.read_text(encoding="utf-8"))
        source_dir = Path(report["config"]["input_dir"])
        source = json.loads((source_dir / "source.json").read_text(encoding="utf-8"))
    except (OSError, KeyError, TypeError, json.JSONDecodeError):
        return None
    labels = source_dir / humanml3d.LABELS_FILE
    if source.get("generator") != GENERATOR or not labels.is_file():
        return None
    return labels


class SemanticScorer:
    """Semantic accuracy on the demo corpus: do the corpus' own detectors find an item's labels?

    An item counts as right when every labelled segment of its source clip is found in the
    joints, in the labelled order, wherever the motion performs it
    (:func:`~dataset_tools.synth.matching.align_segments`: captions give the order and the
    counts, never the timing). The strict score that cuts the motion in the proportions of the
    labelled clip (:func:`~dataset_tools.synth.matching.clip_matches`) is reported beside it
    under ``*_fixed_timing`` names. Mirrored clips (:func:`~dataset_tools.humanml3d.mirror_name`)
    are checked against the mirrored labels. Sub-clips with their own time range are not scored.

    Args:
        labels: the content of ``labels.json`` (``{"fps", "clips": {name: {"frames",
            "segments"}}}``).
        fps: frame rate of the dataset's motions.
    """

    def __init__(self, labels: dict[str, Any], fps: float):
        self.clips = labels["clips"]
        self.fps = fps

    def segments_for(self, name: str) -> list[dict] | None:
        """The ground-truth segments of a dataset clip name, or None when it has none."""
        if "#" in name:  # a captioned sub-clip: its labels are not known
            return None
        if name in self.clips:
            return self.clips[name]["segments"]
        if humanml3d.is_mirror(name, self.clips):
            original = self.clips[humanml3d.unmirrored_name(name)]
            return [mirror_label(segment) for segment in original["segments"]]
        return None

    def __call__(self, names: Sequence[str], motions: Sequence[np.ndarray]) -> dict[str, float]:
        """Raw features (T_i, D) of the named items -> ``all`` (items fully right),
        ``segments`` (segments right), ``action_<name>`` (segments of that action right), and
        the same with the clip's own timing: ``all_fixed_timing``, ``segments_fixed_timing``,
        ``fixed_timing_action_<name>``; ``scored_action_<name>``: how many segments of that
        action were scored (what a per-action share rests on)."""
        items = 0
        right = {"aligned": 0, "fixed": 0}
        per_action: dict[str, list[int]] = {}  # action -> [aligned right, fixed right, total]
        for name, motion in zip(names, motions, strict=True):
            segments = self.segments_for(name)
            if segments is None:
                continue
            base = name if name in self.clips else humanml3d.unmirrored_name(name)
            joints = recover_from_ric(motion, FeatureLayout.for_dim(motion.shape[-1]).num_joints)
            signals = MotionSignals(joints, self.fps)
            found = align_segments(signals, self.fps, segments, self.clips[base]["frames"])
            items += 1
            right["aligned"] += all(found.matches)
            right["fixed"] += all(found.fixed)
            for segment, ok, fixed in zip(segments, found.matches, found.fixed, strict=True):
                tally = per_action.setdefault(segment["action"], [0, 0, 0])
                tally[0] += ok
                tally[1] += fixed
                tally[2] += 1
        if items == 0:
            return {}
        total = sum(t[2] for t in per_action.values())
        scores = {
            "all": right["aligned"] / items,
            "segments": sum(t[0] for t in per_action.values()) / total,
            "all_fixed_timing": right["fixed"] / items,
            "segments_fixed_timing": sum(t[1] for t in per_action.values()) / total,
        }
        for action, (aligned, fixed, count) in sorted(per_action.items()):
            scores[f"action_{action}"] = aligned / count
            scores[f"fixed_timing_action_{action}"] = fixed / count
            scores[f"scored_action_{action}"] = float(count)
        return scores


def scorer_for(dataset_dir: str | Path) -> SemanticScorer | None:
    """The evaluation's plug-in hook: a scorer when the dataset was built from the demo corpus,
    else None."""
    path = find_corpus_labels(dataset_dir)
    if path is None:
        return None
    logger.info("semantic accuracy from the corpus labels in %s", path)
    # The builder writes every dataset at HumanML3D's rate (build_clips.DATASET_FPS).
    return SemanticScorer(json.loads(path.read_text(encoding="utf-8")), fps=DATASET_FPS)
