"""Writing the procedural demo corpus: a raw source folder that ``dataset_tools build`` reads.

Layout of ``out/``:
    joints/synth_000000.npy   (T, 22, 3) float32, z-up, metres, 60 fps, SMPL 22-joint order
    texts/synth_000000.txt    three different captions, one per line
    labels.json               {"fps": 60, "clips": {name: {"frames", "segments", "subject", ...}}}
    source.json               {"fps": 60, "up": "z", "skeleton": "smpl", "generator": ..., ...}

z-up here is the y-up motion turned by +90 degrees about x, (x, y, z) -> (x, -z, y): the inverse
of the builder's z-up reader, so building restores the generated y-up motion exactly.

Clip ``i`` of seed ``s`` is generated from its own random streams (``[s, i]`` for the motion,
``[s, i, 1]`` for the captions): the corpus does not depend on the number of workers, and the
same seed gives the same bytes.
"""

from __future__ import annotations

import logging
import multiprocessing
import shutil
from dataclasses import asdict
from pathlib import Path

import numpy as np
from tqdm import tqdm

from dataset_tools.command import UsageError
from dataset_tools.humanml3d import LABELS_FILE
from dataset_tools.io import save_npy_atomic, write_json_atomic, write_text_atomic
from dataset_tools.rotations import y_up_to_z_up, z_up_to_y_up
from dataset_tools.synth.captions import captions_for
from dataset_tools.synth.clip import FPS, synthesize_clip

log = logging.getLogger(__name__)

GENERATOR = "dataset_tools.synth"
FORMAT_VERSION = 1


def clip_name(index: int) -> str:
    return f"synth_{index:06d}"


def make_clip(seed: int, index: int, heldout: bool = False) -> tuple[np.ndarray, list[str], dict]:
    """Clip ``index`` of corpus ``seed``: joints (T, 22, 3) float32 z-up, 3 captions, its label."""
    clip = synthesize_clip(seed, index)
    caption_rng = np.random.default_rng([seed, index, 1])
    plan = [(s.action, s.params) for s in clip.segments]
    texts = captions_for(plan, caption_rng, count=3, heldout=heldout)
    label = {
        "frames": int(clip.joints.shape[0]),
        "segments": [s.label() for s in clip.segments],
        "subject": clip.body.label(),
        "style": {k: round(v, 4) for k, v in asdict(clip.style).items()},
        "caption_pool": "heldout" if heldout else "train",
    }
    joints = y_up_to_z_up(clip.joints).astype(np.float32)
    return joints, texts, label


def _write_one(job: tuple[str, int, int, bool]) -> tuple[str, dict]:
    out, seed, index, heldout = job
    name = clip_name(index)
    joints, texts, label = make_clip(seed, index, heldout)
    save_npy_atomic(Path(out) / "joints" / f"{name}.npy", joints)
    write_text_atomic(Path(out) / "texts" / f"{name}.txt", "\n".join(texts) + "\n")
    return name, label


def write_corpus(
    out: str | Path,
    clips: int,
    seed: int = 0,
    heldout_phrasings: bool = False,
    workers: int = 1,
    force: bool = False,
    progress: bool = True,
) -> dict:
    """Generate ``clips`` clips into ``out`` (layout in the module docstring); returns source.json.

    Raises UsageError (a ValueError) for a non-positive clip count or worker count, or when
    ``out`` already holds a corpus and ``force`` is not set (a forced write removes the old clips
    first); nothing is written then.
    """
    if clips < 1:
        raise UsageError(f"--clips must be at least 1, got {clips}")
    if workers < 1:
        raise UsageError(f"--workers must be at least 1, got {workers}")
    out = Path(out)
    source = {
        "fps": int(FPS),
        "up": "z",
        "skeleton": "smpl",
        "generator": GENERATOR,
        "format_version": FORMAT_VERSION,
        "seed": int(seed),
        "clips": int(clips),
        "heldout_phrasings": bool(heldout_phrasings),
    }
    existing = out / "source.json"
    if (out / "joints").exists() or existing.exists():
        if not force:
            raise UsageError(f"{out} already holds a corpus; pass --force to replace it")
        for sub in ("joints", "texts"):
            shutil.rmtree(out / sub, ignore_errors=True)
    (out / "joints").mkdir(parents=True, exist_ok=True)
    (out / "texts").mkdir(parents=True, exist_ok=True)

    jobs = [(str(out), int(seed), i, bool(heldout_phrasings)) for i in range(clips)]
    labels: dict[str, dict] = {}
    bar = tqdm(total=clips, desc="synth", unit="clip", disable=not progress)
    if workers == 1:
        results = map(_write_one, jobs)
        for name, label in results:
            labels[name] = label
            bar.update()
    else:
        with multiprocessing.get_context("fork").Pool(workers) as pool:
            for name, label in pool.imap(_write_one, jobs, chunksize=8):
                labels[name] = label
                bar.update()
    bar.close()
    write_json_atomic(out / LABELS_FILE, {"fps": int(FPS), "up": "z", "clips": labels})
    write_json_atomic(existing, source)
    log.info("wrote %d clips to %s", clips, out)
    return source


def load_clip(corpus: str | Path, name: str) -> tuple[np.ndarray, list[str], dict]:
    """One clip of a written corpus: joints (T, 22, 3) y-up at 60 fps, captions, label."""
    import json

    corpus = Path(corpus)
    joints = z_up_to_y_up(np.load(corpus / "joints" / f"{name}.npy", allow_pickle=False))
    texts = (corpus / "texts" / f"{name}.txt").read_text(encoding="utf-8").splitlines()
    labels = json.loads((corpus / LABELS_FILE).read_text(encoding="utf-8"))
    return joints, texts, labels["clips"][name]
