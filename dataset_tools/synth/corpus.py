"""Writing the procedural demo corpus: a raw source folder that ``dataset_tools build`` reads.

Layout of ``out/``:
    joints/synth_000000.npy   (T, 22, 3) float32, z-up, metres, 60 fps, SMPL 22-joint order
    texts/synth_000000.txt    three different captions, one per line
    labels.json               {"fps": 60, "clips": {name: {"frames", "segments", "subject", ...}}}
    source.json               {"fps": 60, "up": "z", "skeleton": "smpl", "generator": ..., ...}

After the ``clips`` clips come ``paraphrase_clips`` more (default a tenth as many), captioned with
the ``"paraphrase"`` pool of :mod:`dataset_tools.synth.captions` (phrasing families no training
caption uses) and labelled ``"split": "test_paraphrase"``: the builder puts them and their
mirrors into ``test_paraphrase.txt`` and into no other split, so no stage trains on their wording
and ``t2m.evaluate --split test_paraphrase`` scores it.

z-up here is the y-up motion turned by +90 degrees about x, (x, y, z) -> (x, -z, y): the inverse
of the builder's z-up reader, so building restores the generated y-up motion exactly.

Clip ``i`` of seed ``s`` is generated from its own random streams (``[s, i]`` for the motion,
``[s, i, 1]`` for the captions): the corpus does not depend on the number of workers, and the
same seed gives the same bytes. ``source.json`` is written last: a folder without it is an
unfinished corpus (a killed run), which ``--force`` replaces. Replacing removes only files this
writer names (``synth_NNNNNN.npy|txt``, ``labels.json``, ``source.json``, temporaries); a folder
holding anything else is refused.
"""

from __future__ import annotations

import logging
import os
import re
import shutil
from dataclasses import asdict
from pathlib import Path

import numpy as np
from tqdm import tqdm

from dataset_tools.command import UsageError
from dataset_tools.humanml3d import LABELS_FILE
from dataset_tools.io import (
    check_output_folder,
    is_partial_file,
    save_npy_atomic,
    write_json_atomic,
    write_text_atomic,
)
from dataset_tools.parallel import imap_unordered
from dataset_tools.rotations import y_up_to_z_up, z_up_to_y_up
from dataset_tools.synth.captions import captions_for
from dataset_tools.synth.clip import FPS, synthesize_clip

log = logging.getLogger(__name__)

GENERATOR = "dataset_tools.synth"
FORMAT_VERSION = 1
SOURCE_FILE = "source.json"
# The demo corpus is meant for thousands of clips (HumanML3D has 14,616); labels of every clip
# are held in memory until the end.
MAX_CLIPS = 200_000
# Disk use of one clip, rounded up from the longest clips (joints ~158 KB, texts and label).
BYTES_PER_CLIP = 170_000
_CLIP_FILE = re.compile(r"synth_\d{6,}\.(npy|txt)")


def clip_name(index: int) -> str:
    return f"synth_{index:06d}"


PARAPHRASE_SPLIT = "test_paraphrase"
"""The split of the clips captioned in held-out phrasing families."""
PARAPHRASE_FRACTION = 10
"""By default one paraphrase clip per this many clips."""


def make_clip(
    seed: int, index: int, heldout: bool = False, pool: str | None = None
) -> tuple[np.ndarray, list[str], dict]:
    """Clip ``index`` of corpus ``seed``: joints (T, 22, 3) float32 z-up, 3 captions, its label.

    ``pool`` words the captions (:data:`dataset_tools.synth.captions.POOLS`; default "train",
    "heldout" with ``heldout``); "paraphrase" clips are labelled for :data:`PARAPHRASE_SPLIT`."""
    pool = pool or ("heldout" if heldout else "train")
    clip = synthesize_clip(seed, index)
    caption_rng = np.random.default_rng([seed, index, 1])
    plan = [(s.action, s.params) for s in clip.segments]
    texts = captions_for(plan, caption_rng, count=3, pool=pool)
    label = {
        "frames": int(clip.joints.shape[0]),
        "segments": [s.label() for s in clip.segments],
        "subject": clip.body.label(),
        "style": {k: round(v, 4) for k, v in asdict(clip.style).items()},
        "caption_pool": pool,
    }
    if pool == "paraphrase":
        label["split"] = PARAPHRASE_SPLIT
    joints = y_up_to_z_up(clip.joints).astype(np.float32)
    return joints, texts, label


def _write_one(job: tuple[str, int, int, str]) -> tuple[str, dict]:
    out, seed, index, pool = job
    name = clip_name(index)
    joints, texts, label = make_clip(seed, index, pool=pool)
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
    paraphrase_clips: int | None = None,
) -> dict:
    """Generate ``clips`` clips into ``out`` (layout in the module docstring), then
    ``paraphrase_clips`` clips for the paraphrase test split (default ``clips //``
    :data:`PARAPHRASE_FRACTION`; none with ``heldout_phrasings``, whose every caption is held
    out); returns source.json.

    Raises UsageError (a ValueError), before anything is written, for a clip count outside
    [1, MAX_CLIPS], a worker count outside [1, 4 per CPU core], a negative seed, an output
    folder that cannot be written or lacks the disk space, or when ``out`` already holds a
    corpus and ``force`` is not set (a forced write removes the old corpus's files first, and
    refuses a folder holding files it did not write). ChildProcessError when a worker dies.
    """
    most_workers = 4 * (os.cpu_count() or 1)
    if not 1 <= clips <= MAX_CLIPS:
        raise UsageError(f"--clips must be between 1 and {MAX_CLIPS}, got {clips}")
    if not 1 <= workers <= most_workers:
        raise UsageError(f"--workers must be between 1 and {most_workers}, got {workers}")
    if seed < 0:
        raise UsageError(f"--seed must be 0 or more, got {seed}")
    if paraphrase_clips is None:
        paraphrase_clips = 0 if heldout_phrasings else clips // PARAPHRASE_FRACTION
    if not 0 <= paraphrase_clips <= MAX_CLIPS - clips:
        raise UsageError(
            f"paraphrase clips must be between 0 and {MAX_CLIPS - clips}, got {paraphrase_clips}"
        )
    out = check_output_folder(out, "--out folder")
    source = {
        "fps": int(FPS),
        "up": "z",
        "skeleton": "smpl",
        "generator": GENERATOR,
        "format_version": FORMAT_VERSION,
        "seed": int(seed),
        "clips": int(clips),
        "heldout_phrasings": bool(heldout_phrasings),
        "paraphrase_clips": int(paraphrase_clips),
    }
    existing = out / SOURCE_FILE
    if (out / "joints").exists() or (out / "texts").exists() or existing.exists():
        if not force:
            raise UsageError(f"{out} already holds a corpus; pass --force to replace it")
        _remove_corpus(out)
    _check_disk_space(out, clips + paraphrase_clips)
    (out / "joints").mkdir(parents=True, exist_ok=True)
    (out / "texts").mkdir(parents=True, exist_ok=True)

    pool = "heldout" if heldout_phrasings else "train"
    jobs = [(str(out), int(seed), i, pool) for i in range(clips)]
    jobs += [(str(out), int(seed), clips + i, "paraphrase") for i in range(paraphrase_clips)]
    labels: dict[str, dict] = {}
    bar = tqdm(total=len(jobs), desc="synth", unit="clip", disable=not progress)
    for name, label in imap_unordered(_write_one, iter(jobs), min(workers, len(jobs))):
        labels[name] = label
        bar.update()
    bar.close()
    labels = {name: labels[name] for name in sorted(labels)}  # bytes independent of workers
    write_json_atomic(out / LABELS_FILE, {"fps": int(FPS), "up": "z", "clips": labels})
    write_json_atomic(existing, source)
    log.info("wrote %d clips (%d for %s) to %s", len(jobs), paraphrase_clips, PARAPHRASE_SPLIT, out)
    return source


def _remove_corpus(out: Path) -> None:
    """Remove the files of an earlier (or killed) corpus in ``out``; UsageError, removing
    nothing, when ``joints/`` or ``texts/`` hold anything this writer does not name."""
    for sub in ("joints", "texts"):
        folder = out / sub
        if folder.exists() and not folder.is_dir():
            raise UsageError(f"{folder} is a file; choose another --out")
        for entry in folder.iterdir() if folder.is_dir() else ():
            if not (
                entry.is_file() and (_CLIP_FILE.fullmatch(entry.name) or is_partial_file(entry))
            ):
                raise UsageError(
                    f"{folder} holds {entry.name}, which synth did not write; "
                    "choose another --out (nothing was removed)"
                )
    for sub in ("joints", "texts"):
        if (out / sub).is_dir():
            for entry in (out / sub).iterdir():
                entry.unlink()
    for name in (LABELS_FILE, SOURCE_FILE):
        (out / name).unlink(missing_ok=True)


def _check_disk_space(out: Path, clips: int) -> None:
    """UsageError when the corpus would not fit on the disk that holds ``out``."""
    existing = out
    while not existing.exists():
        existing = existing.parent
    needed, free = clips * BYTES_PER_CLIP, shutil.disk_usage(existing).free
    if needed > free:
        raise UsageError(
            f"{clips} clips need about {needed / 1e9:.1f} GB but {out} has {free / 1e9:.1f} GB "
            "free; ask for fewer --clips"
        )


def load_clip(corpus: str | Path, name: str) -> tuple[np.ndarray, list[str], dict]:
    """One clip of a written corpus: joints (T, 22, 3) y-up at 60 fps, captions, label."""
    import json

    corpus = Path(corpus)
    joints = z_up_to_y_up(np.load(corpus / "joints" / f"{name}.npy", allow_pickle=False))
    texts = (corpus / "texts" / f"{name}.txt").read_text(encoding="utf-8").splitlines()
    labels = json.loads((corpus / LABELS_FILE).read_text(encoding="utf-8"))
    return joints, texts, labels["clips"][name]
