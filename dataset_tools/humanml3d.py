"""The HumanML3D folder: its file names, caption lines, split files, statistics and mirror names.

This module is the one place that knows the layout; ``dataset_tools.build`` writes it and
``t2m.data`` reads it::

    new_joint_vecs/<clip>.npy   features (T, D) float32 (D = 263 for 22 joints)
    new_joints/<clip>.npy       joints (T, J, 3) float32, metres, y-up
    texts/<clip>.txt            one caption line a caption: ``caption#word/POS ...#from#to``
    Mean.npy, Std.npy           (D,) float32 feature mean and group-pooled std
    train.txt, val.txt, test.txt, train_val.txt, all.txt   clip names, one a line
    build_report.json           what the build did (ours; not in the original release)
    build_options.json          the options that decide the clips' content (ours: a rebuild with
                                other options is refused unless --force)
    labels.json                 ground-truth labels of a procedural corpus (ours, optional)

The mirror of clip ``name`` (x negated, left and right swapped) is the clip ``"M" + name``.
A caption line's ``from``/``to`` are seconds into the clip; ``0.0#0.0`` means the whole clip (in a
text line, so does NaN, as the original release's reader has it). Caption files may start with a
UTF-8 byte-order mark.
"""

from __future__ import annotations

import math
from collections.abc import Collection, Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from dataset_tools.command import UsageError
from dataset_tools.io import load_npy, save_npy_atomic, write_text_atomic
from dataset_tools.representation import FeatureLayout, recover_from_ric
from dataset_tools.skeleton import SKELETONS

FEATURES_DIR = "new_joint_vecs"
JOINTS_DIR = "new_joints"
TEXTS_DIR = "texts"
MEAN_FILE = "Mean.npy"
STD_FILE = "Std.npy"
OPTIONS_FILE = "build_options.json"
REPORT_FILE = "build_report.json"
LABELS_FILE = "labels.json"
SPLITS: tuple[str, ...] = ("train", "val", "test", "train_val", "all")
MIRROR_PREFIX = "M"


# ----------------------------------------------------------------------------- paths


def features_path(folder: str | Path, name: str) -> Path:
    """``new_joint_vecs/<name>.npy`` of a dataset folder."""
    return Path(folder) / FEATURES_DIR / f"{name}.npy"


def joints_path(folder: str | Path, name: str) -> Path:
    """``new_joints/<name>.npy`` of a dataset folder."""
    return Path(folder) / JOINTS_DIR / f"{name}.npy"


def texts_path(folder: str | Path, name: str) -> Path:
    """``texts/<name>.txt`` of a dataset folder."""
    return Path(folder) / TEXTS_DIR / f"{name}.txt"


def split_path(folder: str | Path, split: str) -> Path:
    """``<split>.txt`` of a dataset folder."""
    return Path(folder) / f"{split}.txt"


def clip_files(folder: str | Path, name: str) -> list[Path]:
    """The three files of one clip (features, joints, texts; texts are written last)."""
    return [features_path(folder, name), joints_path(folder, name), texts_path(folder, name)]


def make_folders(folder: str | Path) -> None:
    """Create the per-clip subfolders of a dataset folder."""
    for sub in (FEATURES_DIR, JOINTS_DIR, TEXTS_DIR):
        (Path(folder) / sub).mkdir(parents=True, exist_ok=True)


def require_dataset(folder: str | Path) -> Path:
    """``folder`` as a Path; ValueError when it has no ``new_joint_vecs/``."""
    folder = Path(folder)
    if not (folder / FEATURES_DIR).is_dir():
        raise ValueError(f"{folder}: not a HumanML3D-layout folder (no {FEATURES_DIR}/)")
    return folder


# ----------------------------------------------------------------------------- mirror names


def mirror_name(name: str) -> str:
    """The name of clip ``name``'s mirror: ``"M" + name``."""
    return MIRROR_PREFIX + name


def is_mirror(name: str, names: Collection[str]) -> bool:
    """Whether ``name`` is the mirror of a clip in ``names`` (a clip may itself start with "M",
    e.g. ``MPI_...``, so the prefix alone does not tell)."""
    return name.startswith(MIRROR_PREFIX) and name[len(MIRROR_PREFIX) :] in names


def unmirrored_name(name: str) -> str:
    """The clip that mirror ``name`` was made from (``name`` without its "M")."""
    if not name.startswith(MIRROR_PREFIX):
        raise ValueError(f"{name!r} is not a mirror name")
    return name[len(MIRROR_PREFIX) :]


# ----------------------------------------------------------------------------- caption lines


@dataclass(frozen=True)
class Caption:
    """One caption of a clip.

    Attributes:
        text: the caption as written.
        tokens: its ``word/POS`` tokens (empty until tagged).
        start / end: seconds into the clip; both 0.0 for the whole clip.
    """

    text: str
    tokens: Sequence[str] = ()
    start: float = 0.0
    end: float = 0.0

    @property
    def whole_clip(self) -> bool:
        return self.start == 0.0 and self.end == 0.0


def format_caption_line(caption: Caption, pairs: Iterable[tuple[str, str]] | None = None) -> str:
    """One text line ``caption#word/POS ...#start#end``; tokens from ``pairs`` (word, POS) or,
    without them, ``caption.tokens``."""
    tokens = caption.tokens if pairs is None else [f"{word}/{pos}" for word, pos in pairs]
    # Plain float text ("0.0", "1.25") as HumanML3D writes it; rounding to 1 decimal would move
    # a caption's start by up to a frame.
    start, end = float(round(caption.start, 3)), float(round(caption.end, 3))
    return f"{caption.text}#{' '.join(tokens)}#{start!r}#{end!r}"


def parse_caption_line(line: str, where: str = "caption", tagged: bool = False) -> Caption:
    """Parse ``caption``, ``caption#start#end`` or a text line ``caption#tokens#start#end``.

    With ``tagged`` only the last form (a ``texts/`` line) is accepted. Raises ValueError naming
    ``where`` (file and line) for an empty caption, a wrong number of fields, times that are not
    numbers or are infinite, and NaN times except in a text line: there NaN reads as 0.0, as the
    original release's reader has it (its ``nan#nan`` is the whole clip).
    """
    fields = [field.strip() for field in line.strip().split("#")]
    if tagged and len(fields) != 4:
        raise ValueError(f"{where}: expected 'caption#tokens#from#to', got {line.strip()[:60]!r}")
    text = fields[0]
    if not text:
        raise ValueError(f"{where}: empty caption")
    if len(fields) == 1:
        return Caption(text)
    if len(fields) not in (3, 4):
        raise ValueError(f"{where}: expected 'caption', 'caption#start#end' or a HumanML3D line")
    try:
        times = [float(fields[-2] or 0.0), float(fields[-1] or 0.0)]
    except ValueError:
        raise ValueError(f"{where}: start/end must be numbers in seconds") from None
    text_line = len(fields) == 4
    for index, value in enumerate(times):
        if math.isnan(value) and text_line:
            times[index] = 0.0
        elif not math.isfinite(value):
            raise ValueError(
                f"{where}: start/end must be finite numbers of seconds (0#0: the whole clip), "
                f"got {fields[-2]!r}#{fields[-1]!r}"
            )
    tokens = tuple(fields[1].split()) if text_line else ()
    return Caption(text, tokens, times[0], times[1])


def read_caption_lines(path: str | Path) -> list[tuple[int, str]]:
    """The non-blank lines of a UTF-8 caption file with their line numbers (from 1); a leading
    byte-order mark is dropped. Raises ValueError naming the file when it is not UTF-8."""
    path = Path(path)
    try:
        content = path.read_text(encoding="utf-8-sig")
    except UnicodeDecodeError:
        raise ValueError(f"{path}: caption file is not UTF-8") from None
    return [
        (number, line) for number, line in enumerate(content.splitlines(), start=1) if line.strip()
    ]


def read_texts(folder: str | Path, name: str) -> list[Caption]:
    """The tagged captions of clip ``name`` (``texts/<name>.txt``; blank lines ignored)."""
    path = texts_path(folder, name)
    return [
        parse_caption_line(line, f"{path}:{number}", tagged=True)
        for number, line in read_caption_lines(path)
    ]


def write_texts(folder: str | Path, name: str, lines: Sequence[str]) -> Path:
    """Write clip ``name``'s caption lines (from :func:`format_caption_line`) atomically."""
    return write_text_atomic(texts_path(folder, name), "\n".join(lines) + "\n")


# ----------------------------------------------------------------------------- splits


def read_split(folder: str | Path, split: str) -> list[str]:
    """Clip names listed in ``<split>.txt`` (file order); ValueError when the file is missing."""
    path = split_path(folder, split)
    if not path.is_file():
        raise ValueError(f"{folder}: no split file {path.name}")
    return [line.strip() for line in path.read_text(encoding="utf-8").splitlines() if line.strip()]


def write_split(folder: str | Path, split: str, names: Iterable[str]) -> Path:
    """Write ``<split>.txt`` (one name a line) atomically."""
    return write_text_atomic(split_path(folder, split), "".join(f"{name}\n" for name in names))


def write_splits(
    folder: str | Path, splits: Mapping[str, Sequence[str]], all_names: Iterable[str]
) -> None:
    """Write train/val/test from ``splits``, plus train_val (their union) and all (sorted)."""
    contents = {split: list(splits[split]) for split in ("train", "val", "test")}
    contents["train_val"] = sorted(contents["train"] + contents["val"])
    contents["all"] = sorted(all_names)
    for split, names in contents.items():
        write_split(folder, split, names)


# ----------------------------------------------------------------------------- statistics


def read_mean_std(folder: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """``Mean.npy`` and ``Std.npy`` of a dataset folder, each (D,) as stored; UsageError (one
    line naming the file) for a missing or malformed one (pickles are never loaded)."""
    folder = Path(folder)
    return load_npy(folder / MEAN_FILE), load_npy(folder / STD_FILE)


def write_mean_std(folder: str | Path, mean: np.ndarray, std: np.ndarray) -> None:
    """Write ``Mean.npy`` and ``Std.npy`` (each (D,)) atomically."""
    folder = Path(folder)
    save_npy_atomic(folder / MEAN_FILE, mean)
    save_npy_atomic(folder / STD_FILE, std)


# ----------------------------------------------------------------------------- motion arrays


def read_joints(path: str | Path) -> np.ndarray:
    """Joints (T, J, 3) from a .npy file that a user named, holding joints (T, J, 3) of a known
    skeleton (as in ``new_joints/``) or features (T, D) of a known layout (as in
    ``new_joint_vecs/``, recovered to joints), T >= 1. Raises UsageError (one line) for anything
    else (see :func:`dataset_tools.io.load_npy` for what a readable file is)."""
    array = load_npy(path)
    joint_counts = sorted((spec.num_joints for spec in SKELETONS.values()), reverse=True)
    widths = {FeatureLayout(count).dim: count for count in joint_counts}
    frames = array.shape[0] if array.ndim else 0
    if frames and array.ndim == 3 and array.shape[1:] in [(n, 3) for n in joint_counts]:
        return array
    if frames and array.ndim == 2 and array.shape[1] in widths:
        return recover_from_ric(array, widths[array.shape[1]])
    raise UsageError(
        f"{path}: expected joints (T, {' or '.join(map(str, joint_counts))}, 3) or features "
        f"(T, {' or '.join(map(str, widths))}) with T >= 1, got shape {array.shape}"
    )
