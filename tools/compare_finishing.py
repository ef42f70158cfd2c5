"""Compare ways of finishing generated motions (rigid skeleton, foot clean-up) on one model.

Each construction turns the model's raw features into the features of the output motion; every
construction sees the same generations (same captions, lengths and seeds), so differences are
the finishing step's alone. Printed per construction: bone stretch (``dataset_tools.physical``),
how far the joints move from the model's, the physical figures and milliseconds per motion on
``--motions`` test captions; with ``--eval``, the quick evaluation (``t2m.evaluate``'s quick
protocol, clause plan, as ``make demo`` runs it) of each, written to ``--out`` as JSON::

    python tools/compare_finishing.py --dataset data/demo --checkpoints checkpoints/demo --eval

Constructions: ``raw`` (the model's output), ``clean`` (the foot clean-up alone),
``rigid+clean`` (``dataset_tools.rigid.finish_features``, what the project outputs),
``rigid`` (the fit alone), ``median+clean`` (the fit with each motion's median bone lengths),
``rot6d+clean`` (forward kinematics of the features' 6-D rotations, then the clean-up).
"""

from __future__ import annotations

import argparse
import json
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch

from dataset_tools import cleanup, physical, rigid
from dataset_tools.representation import FeatureLayout, recover_from_ric, recover_from_rot
from dataset_tools.skeleton import skeleton_for


def _rot6d_clean(features: np.ndarray) -> np.ndarray:
    layout = FeatureLayout.for_dim(features.shape[-1])
    joints = recover_from_rot(features.astype(np.float64), skeleton_for(layout.num_joints))
    cleaned = cleanup.clean_joints(joints, features[:, layout.foot_contact])
    return rigid.features_with_joints(features, cleaned)


def _median_clean(features: np.ndarray) -> np.ndarray:
    joints = recover_from_ric(features.astype(np.float64))
    lengths = np.median(skeleton_for(joints.shape[1]).bone_lengths_of(joints), axis=0)
    return rigid.finish_features(features, lengths=lengths)


CONSTRUCTIONS: dict[str, Callable[[np.ndarray], np.ndarray]] = {
    "raw": lambda features: features,
    "clean": cleanup.clean_features,
    "rigid+clean": rigid.finish_features,
    "rigid": lambda features: rigid.finish_features(features, clean=False),
    "median+clean": _median_clean,
    "rot6d+clean": _rot6d_clean,
}


class Finished:
    """A backend whose generations (cached across constructions) pass through ``finish``."""

    def __init__(self, backend, finish: Callable[[np.ndarray], np.ndarray], cache: dict):
        self.backend, self.finish, self.cache = backend, finish, cache

    def embed_texts(self, captions):
        return self.backend.embed_texts(captions)

    def embed_motions(self, motions):
        return self.backend.embed_motions(motions)

    def generate(self, captions, lengths, seed):
        key = (tuple(c.text for c in captions), None if lengths is None else tuple(lengths), seed)
        if key not in self.cache:
            self.cache[key] = self.backend.generate(captions, lengths, seed)
        return [self.finish(features) for features in self.cache[key]]


def sample_figures(raw: list[np.ndarray], finish, fps: float) -> dict[str, float]:
    """Bone stretch, displacement from the raw joints and physical figures of finished motions."""
    start = time.perf_counter()
    done = [finish(features) for features in raw]
    seconds = (time.perf_counter() - start) / len(raw)
    joints = [recover_from_ric(features.astype(np.float64)) for features in done]
    before = [recover_from_ric(features.astype(np.float64)) for features in raw]
    stretch = [physical.bone_stretch(j) for j in joints]
    moved = np.concatenate([np.linalg.norm(a - b, axis=-1).ravel() for a, b in zip(joints, before)])
    figures = physical.row_physics(done, fps).metrics
    return {
        "stretch_max_m": float(max(s["max_m"] for s in stretch)),
        "stretch_max_rel": float(max(s["max_rel"] for s in stretch)),
        "moved_mean_m": float(moved.mean()),
        "moved_max_m": float(moved.max()),
        "skating_ratio": figures["skating_ratio"],
        "penetration_mm": figures["penetration_mm"],
        "floating_ratio": figures["floating_ratio"],
        "jerk_mean": figures["jerk_mean"],
        "ms_per_motion": seconds * 1000,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--dataset", type=Path, required=True)
    parser.add_argument("--checkpoints", type=Path, required=True)
    parser.add_argument("--constructions", nargs="+", default=list(CONSTRUCTIONS))
    parser.add_argument("--motions", type=int, default=64, help="test captions for the figures")
    parser.add_argument("--eval", action="store_true", help="also the quick evaluation of each")
    parser.add_argument("--out", type=Path, default=Path("finishing.json"))
    args = parser.parse_args()
    unknown = set(args.constructions) - set(CONSTRUCTIONS)
    if unknown:
        parser.error(f"unknown constructions {sorted(unknown)}; choose from {list(CONSTRUCTIONS)}")

    from t2m.data.dataset import load_split
    from t2m.evaluate import EvalConfig, evaluate, quick_config
    from t2m.evaluate.backend import CheckpointBackend

    torch.set_num_threads(1)
    backend = CheckpointBackend.from_run_dir(args.checkpoints, "cpu", plan="clauses")
    spec = backend.spec
    clips = load_split(args.dataset, "test", spec=spec)
    pick = np.random.default_rng(0).permutation(len(clips))[: args.motions]
    captions = [clips[i].captions[0] for i in pick]
    unit = spec.snippet_length
    lengths = np.array([min(len(clips[i].motion), spec.max_frames) // unit * unit for i in pick])
    raw = backend.generate(captions, lengths, 1234)
    joints = [recover_from_ric(f.astype(np.float64)) for f in raw]
    rotations = [recover_from_rot(f.astype(np.float64), spec.skeleton) for f in raw]
    apart = np.concatenate(
        [np.linalg.norm(a - b, axis=-1).ravel() for a, b in zip(joints, rotations)]
    )
    report: dict = {
        "rot6d_fk_vs_ric_m": {"mean": float(apart.mean()), "max": float(apart.max())},
        "samples": {},
        "evaluation": {},
    }
    print(f"FK of the 6-D rotations vs the joint positions (raw): mean {apart.mean() * 1000:.1f} mm, max {apart.max() * 1000:.0f} mm")  # fmt: skip
    for name in args.constructions:
        figures = sample_figures(raw, CONSTRUCTIONS[name], spec.fps)
        report["samples"][name] = figures
        print(name, json.dumps({k: round(v, 5) for k, v in figures.items()}), flush=True)
    cache: dict = {}
    for name in args.constructions if args.eval else []:
        config = quick_config(EvalConfig(plan="clauses"))
        summary = evaluate(
            args.dataset,
            args.checkpoints,
            None,
            config,
            Finished(backend, CONSTRUCTIONS[name], cache),
        )
        report["evaluation"][name] = summary["rows"]
        row = summary["rows"]["Ours (ground-truth length)"]
        print(name, {k: round(row[k]["mean"], 4) for k in ("semantic_accuracy", "r_precision_top1", "fid") if k in row}, flush=True)  # fmt: skip
    args.out.write_text(json.dumps(report, indent=1))


if __name__ == "__main__":
    main()
