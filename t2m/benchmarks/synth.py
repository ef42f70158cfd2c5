"""Demo-corpus speed and quality: clip generation, corpus writing, detectors and plausibility.

Generation must reach 50 clips/s on one core (the issue's target). Quality figures: the fraction
of labelled segments the detectors recover at 20 fps (the ground-truth ceiling of "semantic
accuracy") on the clips and on their mirror images, and the median / worst plausibility figures.
"""

from __future__ import annotations

import tempfile
import time

import numpy as np

from dataset_tools.mirror import mirror_joints
from dataset_tools.synth.clip import synthesize_clip
from dataset_tools.synth.corpus import write_corpus
from dataset_tools.synth.detectors import plausibility
from dataset_tools.synth.matching import clip_matches, mirror_label

SEED = 1234


def run(quick: bool = False) -> dict:
    clips = 60 if quick else 400
    result: dict = {"clips": clips}

    # 1. Generation alone, one process.
    start = time.perf_counter()
    generated = [synthesize_clip(SEED, i) for i in range(clips)]
    elapsed = time.perf_counter() - start
    result["generate_clips_per_s"] = round(clips / elapsed, 1)
    frames = sum(len(c.joints) for c in generated)
    result["generate_frames_per_s"] = round(frames / elapsed)
    result["mean_clip_s"] = round(frames / clips / 60.0, 2)

    # 2. Writing a corpus (generation + captions + atomic .npy/.txt writes), one process.
    with tempfile.TemporaryDirectory() as folder:
        start = time.perf_counter()
        write_corpus(folder, clips, seed=SEED, progress=False)
        result["write_corpus_clips_per_s"] = round(clips / (time.perf_counter() - start), 1)

    # 3. Detectors on the 20 fps versions, and on the mirrored motions.
    matched = mirrored = segments = 0
    start = time.perf_counter()
    for clip in generated:
        labels = [s.label() for s in clip.segments]
        joints = clip.joints[::3].astype(np.float64)
        matched += sum(clip_matches(joints, 20.0, labels, len(clip.joints)))
        swapped = [mirror_label(s) for s in labels]
        mirrored += sum(clip_matches(mirror_joints(joints), 20.0, swapped, len(clip.joints)))
        segments += len(labels)
    result["detect_clips_per_s"] = round(2 * clips / (time.perf_counter() - start), 1)
    result["label_recovery"] = round(matched / segments, 4)
    result["label_recovery_mirrored"] = round(mirrored / segments, 4)

    # 4. Plausibility at 20 fps.
    figures = [plausibility(c.joints[::3].astype(np.float64), 20.0) for c in generated]
    for key in ("foot_skate_mps", "root_jerk_mps3"):
        values = np.array([f[key] for f in figures])
        result[f"{key}_median"] = round(float(np.median(values)), 4)
        result[f"{key}_max"] = round(float(values.max()), 4)
    result["penetration_m_max"] = round(max(f["penetration_m"] for f in figures), 5)
    result["bone_length_cv_max"] = float(f"{max(f['bone_length_cv'] for f in figures):.2e}")
    result["knee_flexion_min_deg"] = round(min(f["knee_flexion_min_deg"] for f in figures), 2)
    return result


if __name__ == "__main__":
    for key, value in run().items():
        print(f"{key}: {value}")
