"""The output contract of ``t2m.sample``, ``t2m.edit``, the web app and ``make demo``: file
names, the per-motion writers, ``results.npy`` / ``results.json``, the output folder
transaction and the resource estimate.

Per prompt NN and sample RR a folder holds ``sampleNN_repRR.npy`` (joints (T, J, 3), metres,
y-up, at the dataset's fps), ``sampleNN_repRR_feats.npy`` (de-normalised features (T, D)),
``sampleNN_repRR_kept.npy`` for an edit ((T, J) bool: the joints from its source),
``sampleNN_repRR.mp4|gif|bvh|glb`` and ``sampleNN_repRR_smpl.npz`` (SMPL-H parameters in AMASS's
layout, :mod:`dataset_tools.smplh`) as asked; plus ``results.npy`` (the MDM layout: a dict with
``motion`` (N, J, 3, T_max), ``text``, ``lengths``, ``num_samples``, ``num_repetitions``; motion
``i = rep * num_samples + prompt``, padded past its length with its last pose) and
``results.json``, each written once.

:func:`write_motions` is the transaction: the request is checked against free memory and disk
(:func:`check_resources`) and ``out`` (:func:`check_out`) before any model work, everything is
written into a hidden folder beside ``out`` and renamed at the end, so an error leaves nothing
half-written; the hidden folder of a killed run is removed by the next run into the same ``out``.
Every output folder holds :data:`MARKER`, the list of the files written there: ``overwrite``
replaces only such a folder, and only while it holds nothing else. Motions with NaN or infinite
values are refused before anything is written. :func:`sample_to_folder` generates prompts with a
:class:`t2m.pipeline.TextToMotion` through it.
"""

from __future__ import annotations

import glob
import json
import logging
import os
import re
import shutil
import tempfile
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Literal, get_args

import numpy as np

from dataset_tools.command import UsageError
from dataset_tools.io import atomic_write, check_output_folder, write_json_atomic
from t2m.motion import GeneratedMotion
from t2m.prompts import Prompt

if TYPE_CHECKING:
    from dataset_tools.spec import DatasetSpec

logger = logging.getLogger(__name__)

Render = Literal["mp4", "gif", "none"]
RENDER_CHOICES = get_args(Render)


# ---------------------------------------------------------------------------- names and writers


def stem(prompt: int, repetition: int) -> str:
    """File stem of one motion: ``sampleNN_repRR``."""
    return f"sample{prompt:02d}_rep{repetition:02d}"


def _save_npy(path: Path, array) -> None:
    # atomic: the web app (t2m.serve) writes into a folder that is being read
    atomic_write(path, lambda handle: np.save(handle, array, allow_pickle=isinstance(array, dict)))


MOTION_FILE_KINDS = ("npy", "feats", "kept", "bvh", "glb", "smpl", "mp4", "gif")
"""The per-motion files :func:`write_motion_file` writes (``feats``: ``<stem>_feats.npy``,
``kept``: ``<stem>_kept.npy``, an edit's (T, J) bool mask of the joints from its source;
``smpl``: ``<stem>_smpl.npz``, SMPL-H parameters)."""


def motion_file_name(prompt: int, repetition: int, kind: str) -> str:
    """File name of one per-motion file: ``sampleNN_repRR.npy``, ``..._feats.npy``, ``.bvh``..."""
    if kind not in MOTION_FILE_KINDS:
        raise ValueError(f"unknown motion file kind {kind!r}; use one of {MOTION_FILE_KINDS}")
    name = stem(prompt, repetition)
    if kind == "smpl":
        return f"{name}_smpl.npz"
    return f"{name}_{kind}.npy" if kind in ("feats", "kept") else f"{name}.{kind}"


def write_motion_file(motion: GeneratedMotion, folder: Path, kind: str, fps: float) -> str:
    """Write one file of ``motion`` into ``folder`` (atomically): ``kind`` one of
    :data:`MOTION_FILE_KINDS`; returns the file name."""
    name = motion_file_name(motion.prompt_index, motion.repetition, kind)
    path = Path(folder) / name
    if kind == "npy":
        _save_npy(path, motion.joints)
    elif kind == "feats":
        _save_npy(path, motion.features)
    elif kind == "kept":
        _save_npy(path, motion.kept)
    elif kind == "bvh":
        from dataset_tools.bvh import write_bvh

        write_bvh(motion.joints, path, fps=fps)
    elif kind == "glb":
        from dataset_tools.gltf import write_glb

        write_glb(motion.joints, path, fps=fps, name=motion.text[:200])
    elif kind == "smpl":
        from dataset_tools.smplh import fit_smplh, write_smplh

        write_smplh(fit_smplh(motion.joints, fps=fps), path)
    else:
        from dataset_tools.viz import render_animation

        # an edit's kept joints (EditedMotion.kept, (T, J) bool) are drawn in another colour
        kept = getattr(motion, "kept", None)
        render_animation(motion.joints, path, motion.text, fps, highlight=kept)
    return name


def write_summaries(
    motions: Sequence[Sequence[GeneratedMotion]],
    folder: Path,
    seed: int,
    fps: float,
    files: Sequence[str],
    extra_info: dict | None = None,
) -> dict:
    """Write ``results.npy`` (the MDM layout) and ``results.json`` for ``motions[prompt][rep]``
    into ``folder``; ``files``: the per-motion files written. Returns the results.json dict."""
    num_samples = len(motions[0])
    _save_npy(Path(folder) / "results.npy", mdm_results(motions, num_samples))
    summary = {
        "texts": [row[0].text for row in motions],
        "lengths": [[m.num_frames for m in row] for row in motions],
        "seed": seed,
        "num_samples": num_samples,
        "fps": fps,
        "files": list(files) + ["results.npy", "results.json"],
        **(extra_info or {}),
    }
    write_json_atomic(Path(folder) / "results.json", summary)
    return summary


def mdm_results(motions: Sequence[Sequence[GeneratedMotion]], num_repetitions: int) -> dict:
    """The ``results.npy`` dict of the MDM layout from ``motions[prompt][rep]``."""
    flat = [motions[p][r] for r in range(num_repetitions) for p in range(len(motions))]
    max_frames = max(m.num_frames for m in flat)
    num_joints = flat[0].joints.shape[1]
    stacked = np.empty((len(flat), num_joints, 3, max_frames), np.float32)  # (N, J, 3, T)
    for row, motion in enumerate(flat):  # filled in place: one copy of the joints, not three
        stacked[row, ..., : motion.num_frames] = motion.joints.transpose(1, 2, 0)
        stacked[row, ..., motion.num_frames :] = motion.joints[-1][..., None]  # the last pose
    return {
        "motion": stacked,
        "text": [m.text for m in flat],
        "lengths": np.array([m.num_frames for m in flat], dtype=np.int64),
        "num_samples": len(motions),
        "num_repetitions": num_repetitions,
    }


# ---------------------------------------------------------------------------- the output folder

MARKER = ".t2m-sample.json"
"""Written into every output folder with the list of the files this tool wrote there:
``--overwrite`` replaces only a folder that has one and holds nothing else."""

_TEMP = r"\.{name}\.(?P<pid>\d+)\.\w+\.tmp"  # the hidden folder a run writes into
_OLD = r"\.{name}\.old-(?P<pid>\d+)"  # the replaced output, for the moment of the swap


def _written_files(folder: Path) -> set[str] | None:
    """The files our marker in ``folder`` lists, or None when ``folder`` has no marker of ours."""
    try:
        marker = json.loads((folder / MARKER).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    if not isinstance(marker, dict) or marker.get("written_by") != "t2m.sample":
        return None
    return {name for name in marker.get("files", []) if isinstance(name, str)}


def check_out(out: str | Path, overwrite: bool) -> Path:
    """Check that ``out`` can take the results (before any model work); returns it resolved.

    First removes what killed runs left beside it (:func:`clean_stale`). A missing or empty
    folder is fine; a non-empty one only with ``overwrite`` and only when
    this tool wrote it (our marker) and everything in it is a file the marker lists, since
    ``--overwrite`` replaces the whole folder. Raises UsageError (one line) otherwise.
    """
    out = check_output_folder(Path(out).resolve(), "--out")
    if out.parent.is_dir():
        clean_stale(out)
    if not out.is_dir() or not any(out.iterdir()):
        return out
    if not overwrite:
        raise UsageError(f"--out {out} exists and is not empty (choose another or add --overwrite)")
    written = _written_files(out)
    if written is None:
        raise UsageError(
            f"--overwrite refuses to replace {out}: it has no {MARKER}, so t2m.sample did not "
            "write it"
        )
    foreign = sorted(
        p.name
        for p in out.iterdir()
        if p.name != MARKER and (p.name not in written or p.is_symlink() or not p.is_file())
    )
    if foreign:
        more = f" (and {len(foreign) - 1} more)" if len(foreign) > 1 else ""
        raise UsageError(
            f"--overwrite refuses to replace {out}: {foreign[0]}{more} was not written by "
            "t2m.sample; move it away first"
        )
    return out


def _process_alive(pid: int) -> bool:
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:  # someone else's process
        return True
    return True


def clean_stale(out: Path) -> None:
    """Remove the hidden temp folders beside ``out`` that a killed run left (our name pattern,
    our marker inside, and a process id no longer running); a replaced output left by a run
    killed in the middle of its final swap is put back when ``out`` is missing."""
    temp, old = (re.compile(p.format(name=re.escape(out.name))) for p in (_TEMP, _OLD))
    for path in out.parent.glob(f".{glob.escape(out.name)}.*"):
        match = temp.fullmatch(path.name) or old.fullmatch(path.name)
        if match is None or _process_alive(int(match["pid"])) or path.is_symlink():
            continue
        if _written_files(path) is None:  # not ours after all: leave it
            continue
        if match.re is old and not out.exists():
            os.replace(path, out)
            logger.warning("restored %s from an interrupted run", out)
        else:
            shutil.rmtree(path)
            logger.info("removed %s, left by an interrupted run", path.name)


def _write_marker(folder: Path, files: Sequence[str]) -> None:
    marker = {"written_by": "t2m.sample", "files": sorted(files)}
    (folder / MARKER).write_text(json.dumps(marker, indent=1) + "\n", encoding="utf-8")


def _prepare_out(out: Path, overwrite: bool) -> Path:
    """Check ``out`` and create the hidden temp folder beside it (marked as ours from the
    start) that the results are written into."""
    out = check_out(out, overwrite)
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        tmp = Path(
            tempfile.mkdtemp(prefix=f".{out.name}.{os.getpid()}.", suffix=".tmp", dir=out.parent)
        )
    except OSError as error:
        raise UsageError(f"cannot write to --out {out}: {error.strerror or error}") from None
    _write_marker(tmp, [])
    return tmp


def _publish(tmp: Path, out: Path, overwrite: bool) -> None:
    """Move the finished temp folder to ``out`` (replacing an empty or --overwrite'n one, checked
    again: a file put there while the motions were generated is never deleted)."""
    check_out(out, overwrite)
    umask = os.umask(0)
    os.umask(umask)
    os.chmod(tmp, 0o777 & ~umask)  # mkdtemp makes 0700 folders
    old = None
    if out.exists():
        old = out.parent / f".{out.name}.old-{os.getpid()}"
        os.replace(out, old)
    os.replace(tmp, out)
    if old is not None:
        shutil.rmtree(old)


# ---------------------------------------------------------------------------- resources

# Bytes of each rendered frame with a margin of about two: measured on 22-joint stick figures
# of 196 frames, a gif frame is about 5.7 KB, an mp4 frame 1.2 KB, a BVH frame 0.7 KB of text.
RENDER_BYTES_PER_FRAME = {"mp4": 3_000, "gif": 12_000, "none": 0}
BVH_BYTES_PER_FRAME = 1_500


def _gib(count: int) -> str:
    return f"{count / 2**30:.1f} GiB"


def check_resources(
    frames: Sequence[int],
    num_samples: int,
    spec: DatasetSpec,
    out: Path,
    render: str,
    bvh: bool,
    glb: bool = False,
    smpl: bool = False,
) -> None:
    """Refuse, before generating, a request whose motions cannot fit in memory or on disk.

    ``frames``: the length of each prompt's motions (the longest possible where it is drawn
    later); ``num_samples`` motions each.
    Generation keeps every motion in memory until the end, since ``results.npy`` holds them all:
    joints and features per motion plus the (N, J, 3, T_max) array of ``results.npy``. The files
    are those and the per-motion animations and BVH files. UsageError when either estimate
    exceeds what is free.
    """
    joint_values, feature_values = spec.num_joints * 3, spec.feature_dim
    num_motions, total_frames = len(frames) * num_samples, sum(frames) * num_samples
    in_memory = 4 * total_frames * (joint_values + feature_values)
    results = 4 * num_motions * max(frames) * joint_values
    per_frame_files = RENDER_BYTES_PER_FRAME[render] + BVH_BYTES_PER_FRAME * (bvh + glb + smpl)
    memory = in_memory + results
    disk = in_memory + results + total_frames * per_frame_files
    from t2m.train.runtime import available_memory

    available = available_memory()
    advice = "lower --num-samples or give fewer prompts per run"
    if available is not None and memory > available:
        raise UsageError(
            f"{num_motions} motions need about {_gib(memory)} of memory, {_gib(available)} is "
            f"available; {advice}"
        )
    folder = out.parent
    while not folder.exists():
        folder = folder.parent
    free = shutil.disk_usage(folder).free
    if disk > free:
        raise UsageError(
            f"{num_motions} motions need about {_gib(disk)} on disk, {_gib(free)} is free in "
            f"{folder}; {advice}"
        )


def _check_finite(motions: Sequence[Sequence[GeneratedMotion]]) -> None:
    """UsageError naming the first motion with NaN or infinite values (a broken checkpoint)."""
    for row in motions:
        for motion in row:
            if not (np.isfinite(motion.features).all() and np.isfinite(motion.joints).all()):
                raise UsageError(
                    f"the model produced NaN or infinite values for prompt {motion.prompt_index} "
                    f"({motion.text!r}), sample {motion.repetition}; its checkpoints are "
                    "broken (retrain or resume from a good one); nothing was written"
                )


def sample_to_folder(
    pipe,
    prompts: Sequence[Prompt],
    out: str | Path,
    num_samples: int = 1,
    seed: int = 0,
    batch_size: int = 32,
    render: str = "mp4",
    bvh: bool = False,
    overwrite: bool = False,
    extra_info: dict | None = None,
    glb: bool = False,
    clean: bool = True,
    plan: str = "clauses",
    smpl: bool = False,
    settle: bool = True,
) -> Path:
    """Generate motions for ``prompts`` with a :class:`t2m.pipeline.TextToMotion` and write every
    file of the output contract into ``out``; returns ``out``. Nothing is left in ``out`` on error.

    Raises UsageError (a ValueError) before any generation for an unusable ``out``, ``render``
    or ``bvh`` request.
    """
    longest = pipe.spec.max_frames
    return write_motions(
        lambda: pipe.generate(
            [p.text for p in prompts],
            num_samples=num_samples,
            lengths=[p.frames for p in prompts],
            seed=seed,
            batch_size=batch_size,
            progress=True,
            clean=clean,
            plan=plan,
            settle=settle,
        ),
        pipe.spec,
        out,
        frames=[min(p.frames or longest, longest) for p in prompts],
        num_samples=num_samples,
        seed=seed,
        render=render,
        bvh=bvh,
        overwrite=overwrite,
        extra_info=extra_info,
        glb=glb,
        smpl=smpl,
    )


def write_motions(
    make: Callable[[], Sequence[Sequence[GeneratedMotion]]],
    spec: DatasetSpec,
    out: str | Path,
    frames: Sequence[int],
    num_samples: int = 1,
    seed: int = 0,
    render: str = "mp4",
    bvh: bool = False,
    overwrite: bool = False,
    extra_info: dict | None = None,
    glb: bool = False,
    smpl: bool = False,
) -> Path:
    """Check ``out`` and the resources, call ``make()`` for ``motions[prompt][sample]`` and write
    every file of the output contract into ``out`` (the writer of ``t2m.sample`` and
    ``t2m.edit``); returns ``out``. Nothing is left in ``out`` on error.

    ``frames``: each prompt's longest possible length, for the resource estimate. A motion with
    a ``kept`` (T, J) mask (an edit's) is rendered with the kept joints in another colour, and
    the mask is written as ``sampleNN_repRR_kept.npy``.
    """
    if render not in RENDER_CHOICES:
        raise UsageError(f"--render must be one of {', '.join(RENDER_CHOICES)}, got {render!r}")
    fps = spec.fps
    if (bvh or glb or smpl) and spec.num_joints != 22:
        option = "--bvh" if bvh else "--glb" if glb else "--smpl"
        raise UsageError(f"{option} needs the 22-joint SMPL skeleton (HumanML3D checkpoints)")
    out = Path(out).resolve()  # "." has no name to put a temp folder beside
    # 1. where to write, and whether it fits (fails early, before any model work)
    check_resources(frames, num_samples, spec, out, render, bvh, glb, smpl)
    tmp = _prepare_out(out, overwrite)
    try:
        # 2. generate
        motions = make()
        _check_finite(motions)
        # 3. per-motion files
        files: list[str] = []
        flat = [m for row in motions for m in row]
        from tqdm import tqdm

        kinds = ["npy", "feats"] + [render] * (render != "none") + ["bvh"] * bvh + ["glb"] * glb
        kinds += ["smpl"] * smpl
        for motion in tqdm(flat, desc="writing", unit="motion", disable=len(flat) < 2):
            # an edit's motion also has its kept mask: which joints came from the source
            extra = ["kept"] if getattr(motion, "kept", None) is not None else []
            for kind in kinds[:2] + extra + kinds[2:]:
                files.append(write_motion_file(motion, tmp, kind, fps))
        # 4. the summaries
        summary = write_summaries(motions, tmp, seed, fps, files, extra_info)
        _write_marker(tmp, summary["files"])
        # 5. publish in one rename
        _publish(tmp, out, overwrite)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return out
