"""The real-motion-capture benchmark: Bandai-Namco-1 and -2 with their styles, the full protocol,
one command.

``python -m t2m.evaluate.mocap_bench`` (``make mocap-bench``), in numbered steps, each reused
when it is done and resumed when it was interrupted:

1. read the captures of every ``--mocap`` folder (:func:`read_all`): Bandai-Namco-2
   (``../shared/mocap/bandai-namco-2``, the default: 420 BVH clips, 10 contents x 7 styles x 6
   takes) and, given by its folder, Bandai-Namco-1 (not in ``../shared``: 175 clips of 17
   contents in 15 styles, mostly one take of each). Labels are in ``<clip>.json`` and
   ``cfg/*_label.txt``; a ``.json`` without its ``.bvh`` is skipped. Styles that mean the same
   in both datasets share one label (:data:`STYLE_ALIASES`: Bandai-Namco-1's old, tired,
   masculinity and childish are elderly, exhausted, masculine and youthful), so that the
   captions and the style classifier agree. Captions name content and style in varied wording
   (:func:`clip_captions`); the split (:func:`split_clips`) keeps whole takes apart where a
   content and style has several (:func:`split_takes`) and holds out content x style
   combinations where it has one; a clip's mirror goes with it. The HumanML3D-layout dataset
   with mirrors is built from them (``dataset_tools build --source bvh --texts --splits``);
2. train the four stages (autoencoder, length, generator, evaluator) at the preset (``demo``:
   sized in optimiser steps); the length model and the evaluator train in a second process
   while the autoencoder and the generator train, as ``make demo`` does;
3. train a style classifier on the real clips of the training split (:class:`StyleClassifier`:
   multinomial logistic regression on time-pooled motion features, its regularisation chosen on
   the validation split);
4. run the evaluation protocol of ``python -m t2m.evaluate`` on the test split (R-precision,
   FID, MM-Dist, diversity, multimodality for real and generated rows) with a scorer
   (:class:`BenchScorer`) that adds, for every row, the content accuracy of the real-mocap
   check's detectors (:data:`t2m.evaluate.mocap.CONTENT_CHECKS`; the gestures of
   :data:`t2m.evaluate.mocap.NOT_JUDGED` have no check and count neither way) and the style
   accuracy of the classifier, per content and per style;
5. write ``results.json`` and ``results.md`` (the protocol's table, then per content and per
   style real against generated) and print the table.
"""

from __future__ import annotations

import json
import logging
import os
import sys
import time
import zlib
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
from scipy.optimize import minimize

from dataset_tools.command import CommandParser, UsageError, command, option, parse_config
from dataset_tools.io import write_json_atomic, write_text_atomic
from dataset_tools.representation import FeatureLayout, recover_from_ric
from dataset_tools.spec import HUMANML3D
from t2m.evaluate.mocap import CONTENT_CHECKS, CONTENT_LABELS, NOT_JUDGED, mocap_facts

logger = logging.getLogger("t2m.evaluate.mocap_bench")

DEFAULT_MOCAP = Path("../shared/mocap/bandai-namco-2")

# ----------------------------------------------------------------------------- labels

MIRRORED_CONTENT = {
    "walk-turn-left": "walk-turn-right",
    "wave-left-hand": "wave-right-hand",
    "raise-up-left-hand": "raise-up-right-hand",
    "walk-left": "walk-right",
}
MIRRORED_CONTENT.update({right: left for left, right in MIRRORED_CONTENT.items()})

STYLE_ALIASES = {
    "old": "elderly",
    "tired": "exhausted",
    "masculinity": "masculine",
    "childish": "youthful",
}
"""Bandai-Namco-1's names of the styles Bandai-Namco-2 also has, and Bandai-Namco-2's name the
benchmark uses for both (active, feminine and normal have one name in both)."""

MIN_SECONDS = HUMANML3D.min_frames / HUMANML3D.fps
"""Clips shorter than this are skipped by training and evaluation (the spec's shortest motion);
the split puts them into training, where they count for nothing."""


@dataclass(frozen=True)
class Capture:
    """One BVH clip: its dataset name (the build's: the file's stem), content, style (after
    :data:`STYLE_ALIASES`), take, source (the name's ``dataset-N`` prefix) and length in seconds
    (from the BVH header; None: unknown)."""

    name: str
    path: Path
    content: str
    style: str
    take: str
    source: str = ""
    seconds: float | None = None


def _label_lines(path: Path) -> list[str]:
    """The labels of a ``cfg/*_label.txt`` without their ``dataset-N_`` prefix."""
    lines = [line.strip() for line in path.read_text(encoding="utf-8").splitlines()]
    return [line.split("_", 1)[-1] for line in lines if line]


def data_folder(mocap: Path) -> Path:
    """The folder of the BVH files: ``mocap/data`` (the dataset's root given) or ``mocap``."""
    return mocap / "data" if (mocap / "data").is_dir() else mocap


def bvh_seconds(path: Path) -> float | None:
    """A BVH file's length (frames x frame time) from its header; None when the header does not
    say (the build then judges the file)."""
    frames = None
    try:
        with path.open(encoding="utf-8", errors="replace") as lines:
            for line in lines:
                key, _, value = line.strip().partition(":")
                if key == "Frames":
                    frames = int(value)
                elif key == "Frame Time":
                    return None if frames is None else frames * float(value)
    except (OSError, ValueError):
        return None
    return None


def read_captures(mocap: Path) -> list[Capture]:
    """Every labelled BVH clip of a Bandai-Namco folder (its root, or its ``data/`` folder beside
    ``cfg/``), sorted by name; a ``.json`` without its ``.bvh`` is no clip. UsageError (one
    line) for a missing folder, a wrong layout, or a content or style without caption words."""
    if not mocap.is_dir():
        raise UsageError(
            f"--mocap {mocap}: no such folder (a Bandai-Namco folder: Bandai-Namco-2 is "
            "../shared/mocap/bandai-namco-2, Bandai-Namco-1 is given by its own folder)"
        )
    data = data_folder(mocap)
    cfg = data.parent / "cfg"
    labels = {kind: cfg / f"{kind}_label.txt" for kind in ("content", "style")}
    missing = [path.name for path in labels.values() if not path.is_file()]
    if missing:
        raise UsageError(
            f"--mocap {mocap}: not a Bandai-Namco folder (no {', '.join(missing)} in {cfg}; "
            "expected data/*.bvh with a .json each and cfg/content_label.txt, cfg/style_label.txt)"
        )
    try:
        contents, styles = (_label_lines(path) for path in labels.values())
    except (OSError, UnicodeDecodeError) as error:
        raise UsageError(f"--mocap {mocap}: unreadable label file ({error})") from None
    captures = []
    for path in sorted(data.glob("*.bvh")):
        try:
            indices = json.loads(path.with_suffix(".json").read_text(encoding="utf-8"))
            content, style = contents[int(indices["content"])], styles[int(indices["style"])]
        except (OSError, ValueError, KeyError, IndexError, TypeError) as error:
            raise UsageError(
                f"--mocap {mocap}: {path.with_suffix('.json').name} does not name a content and "
                f"a style of cfg/ ({type(error).__name__}: {error})"
            ) from None
        take = path.stem.rsplit("_", 1)[-1]
        source = path.stem.split("_", 1)[0]
        style = STYLE_ALIASES.get(style, style)
        captures.append(Capture(path.stem, path, content, style, take, source, bvh_seconds(path)))
    if not captures:
        raise UsageError(f"--mocap {mocap}: no .bvh file in {data}")
    for kind, known, found in (
        ("contents", CONTENT_PHRASES, {c.content for c in captures}),
        ("styles", STYLE_WORDS, {c.style for c in captures}),
    ):
        unknown = sorted(found - set(known))
        if unknown:
            raise UsageError(
                f"--mocap {mocap}: {kind} {unknown} have no caption words (the benchmark knows "
                "those of Bandai-Namco-1 and -2)"
            )
    return captures


def read_all(folders: Sequence[Path]) -> list[Capture]:
    """The captures of several Bandai-Namco folders (:func:`read_captures`), sorted by name;
    UsageError (one line) when a folder is given twice or two folders hold a clip of one name."""
    if not folders:
        raise UsageError("--mocap needs at least one Bandai-Namco folder")
    seen: dict[Path, Path] = {}
    where: dict[str, Path] = {}
    for folder in folders:
        resolved = data_folder(folder).resolve()
        if resolved in seen:
            raise UsageError(f"--mocap {folder}: given twice (as {seen[resolved]})")
        seen[resolved] = folder
    captures = []
    for folder in folders:
        for capture in read_captures(folder):
            if capture.name in where:
                raise UsageError(
                    f"--mocap {folder}: clip {capture.name} is also in {where[capture.name]}"
                )
            where[capture.name] = folder
            captures.append(capture)
    return sorted(captures, key=lambda capture: capture.name)


def source_title(source: str) -> str:
    """``dataset-1`` -> ``Bandai-Namco-1`` (the datasets' own name); others as they are."""
    prefix, _, number = source.partition("-")
    return f"Bandai-Namco-{number}" if prefix == "dataset" and number.isdigit() else source


def mirrored(capture: Capture) -> Capture:
    """The capture's mirror as the build writes it (``M`` + name): left and right swapped."""
    content = MIRRORED_CONTENT.get(capture.content, capture.content)
    return replace(capture, name=f"M{capture.name}", content=content)


def judged(content: str) -> bool:
    """Whether the content checks judge motions of ``content`` (else :data:`NOT_JUDGED`)."""
    return content in CONTENT_LABELS


# ----------------------------------------------------------------------------- captions

SUBJECTS = ("a person", "someone", "a man", "a woman", "the person", "a figure")

CONTENT_PHRASES = {
    "walk": ("walks forward", "walks straight ahead", "walks ahead", "walks forwards"),
    "walk-turn-left": (
        "walks forward and turns left",
        "walks ahead and then turns to the left",
        "walks forward and makes a left turn",
        "walks straight, then turns left",
    ),
    "run": ("runs forward", "runs straight ahead", "jogs forward", "runs ahead"),
    "wave-both-hands": (
        "waves both hands",
        "waves with both hands",
        "waves both arms",
        "waves with both arms",
    ),
    "wave-left-hand": (
        "waves the left hand",
        "waves with the left hand",
        "waves the left arm",
        "waves with the left arm",
    ),
    "raise-up-both-hands": (
        "raises both hands",
        "raises both arms",
        "lifts both hands up",
        "puts both arms up",
    ),
    "raise-up-left-hand": (
        "raises the left hand",
        "raises the left arm",
        "lifts the left hand up",
        "puts the left arm up",
    ),
    # Bandai-Namco-1 (walk and run above are in both)
    "dash": ("dashes forward", "sprints forward", "sprints ahead", "runs forward very fast"),
    "walk-back": ("walks backward", "walks backwards", "steps backward", "walks back"),
    "walk-left": (
        "walks to the left",
        "walks sideways to the left",
        "moves to the left",
        "steps sideways to the left",
    ),
    "bow": ("bows", "bows politely", "takes a bow", "bends forward in a bow"),
    "bye": (
        "waves goodbye with one hand",
        "waves bye with one hand",
        "says goodbye with a wave of the hand",
        "waves one hand to say goodbye",
    ),
    "byebye": (
        "waves goodbye with both hands",
        "waves bye with both hands",
        "says goodbye waving both hands",
        "waves both hands to say goodbye",
    ),
    "guide": (
        "shows the way with the hand",
        "guides the way with one arm",
        "points the way",
        "gestures to show the way",
    ),
    "respond": ("responds", "answers", "gives a response", "responds to someone"),
    "call": ("calls out to someone", "calls someone", "calls to someone", "calls out"),
    "punch": ("punches", "throws punches", "punches forward", "throws a few punches"),
    "kick": ("kicks", "kicks forward", "does a kick", "kicks with one leg"),
    "slash": ("slashes with a sword", "swings a sword", "slashes", "strikes with a sword"),
    "dance-short": ("dances", "does a short dance", "dances briefly", "dances a little"),
    "dance-long": ("dances", "does a long dance", "dances for a while", "keeps dancing"),
}
"""Ways of saying each content (a verb phrase after the subject); the right-handed and
rightward contents are the left ones with the side swapped."""
for _left, _right in MIRRORED_CONTENT.items():
    if _left in CONTENT_PHRASES and _right not in CONTENT_PHRASES:
        CONTENT_PHRASES[_right] = tuple(p.replace("left", "right") for p in CONTENT_PHRASES[_left])


@dataclass(frozen=True)
class StyleWords:
    """Ways of saying a style: as the subject ("an old person"), as a manner after the verb
    phrase ("in a tired way") and as an adverb before the verb ("proudly")."""

    subjects: tuple[str, ...]
    manners: tuple[str, ...]
    adverbs: tuple[str, ...]


STYLE_WORDS = {
    "active": StyleWords(
        ("an energetic person", "a lively person", "an active person", "an energetic man"),
        ("in an energetic way", "with a lot of energy", "in a lively way", "in an active way"),
        ("energetically", "vigorously", "briskly", "actively"),
    ),
    "elderly": StyleWords(
        ("an old person", "an elderly person", "an old man", "an elderly woman"),
        ("like an old person", "in an elderly way", "like an elderly man", "as an old man would"),
        ("stiffly", "feebly", "slowly"),
    ),
    "exhausted": StyleWords(
        ("a tired person", "an exhausted person", "a weary man", "a tired woman"),
        ("in a tired way", "as if exhausted", "like someone who is very tired", "wearily"),
        ("wearily", "tiredly", "sluggishly", "listlessly"),
    ),
    "feminine": StyleWords(
        ("a feminine person", "a graceful woman", "a feminine woman", "an elegant woman"),
        ("in a feminine way", "in a graceful, feminine way", "like a graceful lady"),
        ("gracefully", "elegantly", "daintily"),
    ),
    "masculine": StyleWords(
        ("a masculine person", "a manly man", "a macho man", "a tough man"),
        ("in a masculine way", "in a manly way", "with a macho swagger"),
        ("proudly", "confidently", "boldly"),
    ),
    "normal": StyleWords(
        SUBJECTS,
        ("normally", "in a normal way", "in an ordinary way", "casually"),
        ("calmly", "normally", "casually"),
    ),
    "youthful": StyleWords(
        ("a young person", "a youthful person", "a young boy", "a young girl"),
        ("in a youthful way", "like a young person", "like a child", "with youthful energy"),
        ("playfully", "cheerfully", "happily"),
    ),
    # Bandai-Namco-1 only
    "happy": StyleWords(
        ("a happy person", "a cheerful person", "a happy man", "a joyful woman"),
        ("in a happy way", "with joy", "in a joyful mood", "full of joy"),
        ("joyfully", "gleefully", "merrily"),
    ),
    "sad": StyleWords(
        ("a sad person", "an unhappy person", "a sad man", "a sad woman"),
        ("in a sad way", "sadly", "with sorrow", "in a gloomy way"),
        ("sadly", "gloomily", "mournfully"),
    ),
    "angry": StyleWords(
        ("an angry person", "a furious man", "an angry man", "an angry woman"),
        ("in an angry way", "with anger", "furiously", "in a rage"),
        ("angrily", "furiously", "aggressively"),
    ),
    "proud": StyleWords(
        ("a proud person", "a proud man", "an arrogant man", "a haughty woman"),
        ("in a proud way", "with pride", "with the chest out", "full of pride"),
        ("arrogantly", "haughtily", "pompously"),
    ),
    "not-confident": StyleWords(
        ("a shy person", "an insecure person", "a timid man", "a nervous woman"),
        ("in an unsure way", "without confidence", "in a timid way", "nervously"),
        ("timidly", "hesitantly", "nervously", "shyly"),
    ),
    "musical": StyleWords(
        ("a dancer", "a musical person", "a rhythmic dancer", "a musical man"),
        ("in a musical way", "to a rhythm", "like a dancer", "as if dancing to music"),
        ("rhythmically", "musically", "theatrically"),
    ),
    "giant": StyleWords(
        ("a giant", "a huge man", "a heavy giant", "an enormous person"),
        ("like a giant", "in a heavy way", "with huge heavy steps", "like a huge monster"),
        ("heavily", "ponderously", "clumsily"),
    ),
    "chimpira": StyleWords(
        ("a thug", "a punk", "a gangster", "a hoodlum"),
        ("like a thug", "in a thuggish way", "like a punk", "like a gangster"),
        ("menacingly", "cockily", "insolently"),
    ),
}
"""Style words the word vectors know (GloVe 6B), one set per style label (Bandai-Namco-1's
aliases of :data:`STYLE_ALIASES` read as Bandai-Namco-2's names); the ``normal`` style's subjects
are plain; ``chimpira`` is Japanese for a small-time thug. No word of one style is another's
(Bandai-Namco-2's words are as they were, so that its benchmark alone is unchanged)."""


def clip_captions(capture: Capture, seed: int = 0) -> list[str]:
    """Three captions of a capture, each naming its content and its style, in three shapes:
    the style as the subject ("an old person walks forward."), as a manner ("someone walks
    forward in a tired way.") and as an adverb ("a person proudly waves the left hand.").
    Words drawn with ``seed`` and the clip's name (the same captions on every run)."""
    rng = np.random.default_rng([seed, zlib.crc32(capture.name.encode())])
    words = STYLE_WORDS[capture.style]
    phrases = CONTENT_PHRASES[capture.content]

    def pick(options: Sequence[str]) -> str:
        return options[int(rng.integers(len(options)))]

    return [
        f"{pick(words.subjects)} {pick(phrases)}.",
        f"{pick(SUBJECTS)} {pick(phrases)} {pick(words.manners)}.",
        f"{pick(SUBJECTS)} {pick(words.adverbs)} {pick(phrases)}.",
    ]


def caption_words() -> set[str]:
    """Every word the captions can hold (for the check that the word vectors know them)."""
    texts = [*SUBJECTS, *(p for ps in CONTENT_PHRASES.values() for p in ps)]
    for words in STYLE_WORDS.values():
        texts += [*words.subjects, *words.manners, *words.adverbs]
    return {word.strip(",.") for text in texts for word in text.split()}


# ----------------------------------------------------------------------------- splits

HELD_OUT_MIN_CLIPS = 3
"""A content with at least this many single-take clips (one per style) holds some out."""
HELD_OUT_TEST_SHARE = 0.2
HELD_OUT_VAL_SHARE = 0.1
"""Of such a content's clips, this share (at least one) goes to the test split, this share
(rounded) to validation: 3 test and 2 validation clips of 15 styles."""


def split_takes(captures: Sequence[Capture], seed: int = 0) -> dict[str, list[str]]:
    """Clip names by split, whole takes (a clip: one take of one content and style of one
    source): of each content and style with three takes or more, one drawn for the test split,
    one for the validation split in every other combination (the first included), the rest for
    training; with two, one for test and one for training; with one, training. Mirrors follow
    their clip in the build."""
    groups: dict[tuple[str, str, str], list[Capture]] = {}
    for capture in captures:
        groups.setdefault((capture.source, capture.content, capture.style), []).append(capture)
    rng = np.random.default_rng(seed)
    splits: dict[str, list[str]] = {"train": [], "val": [], "test": []}
    for number, key in enumerate(sorted(groups)):
        takes = sorted(groups[key], key=lambda capture: capture.name)
        order = [takes[i] for i in rng.permutation(len(takes))]
        wanted = ["test"] if len(takes) >= 2 else []
        if len(takes) >= 3 and number % 2 == 0:
            wanted.append("val")
        for capture, split in zip(order, wanted + ["train"] * len(takes), strict=False):
            splits[split].append(capture.name)
    return {split: sorted(names) for split, names in splits.items()}


def split_clips(captures: Sequence[Capture], seed: int = 0) -> dict[str, list[str]]:
    """Clip names by split. A content and style with two takes or more is split by take
    (:func:`split_takes`: Bandai-Namco-2, and Bandai-Namco-1's walk, call, punch and slash).
    Where a content has one take per style (the rest of Bandai-Namco-1), content x style
    combinations are held out: of each content with :data:`HELD_OUT_MIN_CLIPS` such clips or
    more, the clips of some styles go to the test split and to validation
    (:data:`HELD_OUT_TEST_SHARE`, :data:`HELD_OUT_VAL_SHARE`), the others to training; a
    content with fewer goes to training whole, and so do single takes shorter than
    :data:`MIN_SECONDS` (skipped there). The test styles are the next ones in one seeded order
    of the styles from content to content (the validation styles follow them), so that every
    style is held out about equally often.
    Deterministic for a seed; each source's takes are split as if it were alone (Bandai-Namco-2's
    split is the same with Bandai-Namco-1 beside it); mirrors follow their clip in the build."""
    groups: dict[tuple[str, str, str], list[Capture]] = {}
    for capture in captures:
        groups.setdefault((capture.source, capture.content, capture.style), []).append(capture)
    splits: dict[str, list[str]] = {"train": [], "val": [], "test": []}
    several: dict[str, list[Capture]] = {}  # by source: each source's takes as if alone
    for (source, *_), group in groups.items():
        if len(group) >= 2:
            several.setdefault(source, []).extend(group)
    for source in sorted(several):
        for split, names in split_takes(several[source], seed).items():
            splits[split] += names
    singles: dict[tuple[str, str], list[Capture]] = {}
    for (source, content, _), group in groups.items():
        if len(group) == 1:
            capture = group[0]
            if capture.seconds is not None and capture.seconds < MIN_SECONDS:
                splits["train"].append(capture.name)
            else:
                singles.setdefault((source, content), []).append(capture)
    styles = sorted({c.style for group in singles.values() for c in group})
    order = np.random.default_rng([seed, 1]).permutation(len(styles))
    rank = {style: int(position) for style, position in zip(styles, order, strict=True)}
    offset = 0
    for key in sorted(singles):
        clips = singles[key]
        if len(clips) < HELD_OUT_MIN_CLIPS:
            splits["train"] += [c.name for c in clips]
            continue
        clips = sorted(clips, key=lambda c: ((rank[c.style] - offset) % len(styles), c.name))
        num_test = max(1, round(HELD_OUT_TEST_SHARE * len(clips)))
        num_val = round(HELD_OUT_VAL_SHARE * len(clips))
        for k, capture in enumerate(clips):
            split = "test" if k < num_test else "val" if k < num_test + num_val else "train"
            splits[split].append(capture.name)
        offset += num_test
    return {split: sorted(names) for split, names in splits.items()}


def write_build_inputs(captures: Sequence[Capture], folder: Path, seed: int) -> tuple[Path, Path]:
    """The captions (``texts/<clip>.txt``) and split files (``splits/*.txt``) the build reads;
    returns the two folders."""
    texts, splits = folder / "texts", folder / "splits"
    texts.mkdir(parents=True, exist_ok=True)
    splits.mkdir(parents=True, exist_ok=True)
    for capture in captures:
        lines = [f"{caption}#0.0#0.0" for caption in clip_captions(capture, seed)]
        write_text_atomic(texts / f"{capture.name}.txt", "\n".join(lines) + "\n")
    for split, names in split_clips(captures, seed).items():
        write_text_atomic(splits / f"{split}.txt", "".join(f"{name}\n" for name in names))
    return texts, splits


def build_input_folder(captures: Sequence[Capture], folders: Sequence[Path], inputs: Path) -> Path:
    """The folder the build reads the BVH files from: the one ``--mocap`` folder's ``data/``,
    or for several, ``<inputs>/bvh`` with a link to every clip (names are unique: they carry
    their ``dataset-N_`` prefix)."""
    if len(folders) == 1:
        return data_folder(folders[0])
    links = inputs / "bvh"
    links.mkdir(parents=True, exist_ok=True)
    for capture in captures:
        link = links / capture.path.name
        if link.is_symlink() or link.exists():
            link.unlink()
        link.symlink_to(capture.path.resolve())
    return links


# ----------------------------------------------------------------------------- style classifier


def pooled_features(motion: np.ndarray, num_joints: int = 22) -> np.ndarray:
    """A motion's (T, D raw features) description for the style classifier: mean and standard
    deviation over time of root height and velocities, joint positions relative to the root
    (facing-aligned), local joint velocities and foot contacts: (2 x 137,) for 22 joints."""
    layout = FeatureLayout(num_joints)
    parts = [
        layout.root_rot_velocity,
        layout.root_linear_velocity,
        layout.root_height,
        layout.ric,
        layout.local_velocity,
        layout.foot_contact,
    ]
    chosen = np.concatenate([motion[:, part] for part in parts], axis=1)  # (T, 137)
    return np.concatenate([chosen.mean(axis=0), chosen.std(axis=0)]).astype(np.float64)


@dataclass
class StyleClassifier:
    """Multinomial logistic regression on :func:`pooled_features`, standardised; L2 weight
    chosen on validation clips (:meth:`fit`)."""

    styles: list[str]
    mean: np.ndarray
    scale: np.ndarray
    weights: np.ndarray  # (F + 1, S): the last row is the bias
    l2: float

    @staticmethod
    def _train(x: np.ndarray, y: np.ndarray, num_classes: int, l2: float) -> np.ndarray:
        x1 = np.concatenate([x, np.ones((len(x), 1))], axis=1)
        onehot = np.eye(num_classes)[y]

        def loss(flat: np.ndarray) -> tuple[float, np.ndarray]:
            w = flat.reshape(x1.shape[1], num_classes)
            logits = x1 @ w
            logits -= logits.max(axis=1, keepdims=True)
            log_p = logits - np.log(np.exp(logits).sum(axis=1, keepdims=True))
            penalty = 0.5 * l2 * np.sum(w[:-1] ** 2)
            grad = x1.T @ (np.exp(log_p) - onehot) / len(x)
            grad[:-1] += l2 * w[:-1]
            return float(-np.mean(np.sum(onehot * log_p, axis=1)) + penalty), grad.ravel()

        start = np.zeros(x1.shape[1] * num_classes)
        result = minimize(loss, start, jac=True, method="L-BFGS-B", options={"maxiter": 500})
        return result.x.reshape(x1.shape[1], num_classes)

    @classmethod
    def fit(
        cls,
        train: tuple[np.ndarray, list[str]],
        val: tuple[np.ndarray, list[str]],
        l2_grid: Sequence[float] = (0.001, 0.01, 0.1, 1.0),
    ) -> tuple[StyleClassifier, dict]:
        """Fit on ``train`` (pooled features (N, F), style names) at each L2 weight of the grid,
        keep the one most accurate on ``val`` (ties: the stronger). Returns the classifier and
        its accuracies (train, val, per L2 weight)."""
        styles = sorted(set(train[1]))
        index = {style: k for k, style in enumerate(styles)}
        x, y = train[0], np.array([index[s] for s in train[1]])
        mean, scale = x.mean(axis=0), x.std(axis=0) + 1e-6
        best, scores = None, {}
        for l2 in sorted(l2_grid, reverse=True):
            weights = cls._train((x - mean) / scale, y, len(styles), l2)
            model = cls(styles, mean, scale, weights, l2)
            scores[l2] = model.accuracy(*val)
            if best is None or scores[l2] > scores[best.l2]:
                best = model
        assert best is not None
        info = {
            "l2": best.l2,
            "train_accuracy": best.accuracy(*train),
            "val_accuracy": scores[best.l2],
            "val_accuracy_by_l2": {str(k): v for k, v in scores.items()},
            "train_clips": len(x),
            "val_clips": len(val[0]),
        }
        return best, info

    def predict(self, features: np.ndarray) -> list[str]:
        """Style names of pooled features (N, F)."""
        x = (np.atleast_2d(features) - self.mean) / self.scale
        logits = np.concatenate([x, np.ones((len(x), 1))], axis=1) @ self.weights
        return [self.styles[k] for k in logits.argmax(axis=1)]

    def accuracy(self, features: np.ndarray, styles: Sequence[str]) -> float:
        if len(styles) == 0:
            return float("nan")
        return float(np.mean([p == s for p, s in zip(self.predict(features), styles, strict=True)]))


# ----------------------------------------------------------------------------- scoring


SCORES_VERSION = 3
"""What :class:`BenchScorer` returns, numbered: an evaluation made with other scores is redone."""


class BenchScorer:
    """A protocol scorer (:class:`t2m.evaluate.protocol.Scorer`): per motion, whether the
    content checks recognise its clip's content and whether the classifier names its style.

    Keys: ``all`` (content accuracy, tabled as the protocol's semantic accuracy),
    ``action_<content>``, ``style`` and ``style_<style>``, ``style_in_<content>`` and
    ``content_in_<style>`` (the accuracies within one content or style), ``speed_<content>``
    and ``speed_<style>`` (mean horizontal root speed, m/s: the walking-in-place symptom).
    Motions of a content without a check (:data:`t2m.evaluate.mocap.NOT_JUDGED`) are left out
    of every content accuracy (no ``action_<content>``; ``all`` and ``content_in_<style>`` over
    the judged motions only, absent when there are none); they count for style and speed."""

    def __init__(self, labels: dict[str, Capture], classifier: StyleClassifier, fps: float):
        self.labels, self.classifier, self.fps = labels, classifier, fps

    def __call__(self, names: Sequence[str], motions: Sequence[np.ndarray]) -> dict[str, float]:
        known = [
            (self.labels[n], m) for n, m in zip(names, motions, strict=True) if n in self.labels
        ]
        if not known:
            return {}
        styles = self.classifier.predict(np.stack([pooled_features(m) for _, m in known]))
        content_ok: list[bool | None] = []  # None: not judged
        style_ok, speeds = [], []
        for (capture, motion), style in zip(known, styles, strict=True):
            facts = mocap_facts(recover_from_ric(motion, 22), self.fps)
            check = CONTENT_CHECKS.get(CONTENT_LABELS.get(capture.content, ""))
            content_ok.append(None if check is None else bool(check(facts)))
            style_ok.append(style == capture.style)
            speeds.append(facts["path_speed_mps"])

        def judged_share(members: Sequence[int]) -> float | None:
            judged = [content_ok[k] for k in members if content_ok[k] is not None]
            return float(np.mean(judged)) if judged else None

        scores = {"style": float(np.mean(style_ok))}
        content = judged_share(range(len(known)))
        if content is not None:
            scores["all"] = content
        groups: dict[str, list[int]] = {}
        for k, (capture, _) in enumerate(known):
            groups.setdefault(f"content:{capture.content}", []).append(k)
            groups.setdefault(f"style:{capture.style}", []).append(k)
        for group, members in groups.items():
            kind, label = group.split(":")
            content = judged_share(members)
            style = float(np.mean([style_ok[k] for k in members]))
            scores[f"speed_{label}"] = float(np.mean([speeds[k] for k in members]))
            if kind == "content":
                if content is not None:
                    scores[f"action_{label}"] = content
                scores[f"style_in_{label}"] = style
            else:
                scores[f"style_{label}"] = style
                if content is not None:
                    scores[f"content_in_{label}"] = content
        return scores


# ----------------------------------------------------------------------------- the command


@dataclass
class MocapBenchConfig:
    """``python -m t2m.evaluate.mocap_bench``: what to build, train and evaluate, and where."""

    mocap: tuple[Path, ...] = field(default=(), metadata=option(metavar="DIR"))
    """one or more Bandai-Namco folders, each data/*.bvh with a .json each and
    cfg/*_label.txt (none given: Bandai-Namco-2, ../shared/mocap/bandai-namco-2); Bandai-Namco-1
    is not in ../shared: give its folder beside Bandai-Namco-2's (--mocap BN2 BN1)"""
    dataset: Path = field(default=Path("data/bandai_bench"), metadata=option(metavar="DIR"))
    """the dataset folder to build (reused when built; its captions and splits go beside it,
    into <dataset>_inputs)"""
    checkpoints: Path = field(
        default=Path("checkpoints/bandai_bench"), metadata=option(metavar="DIR")
    )
    """the run folder (finished stages are reused, an interrupted one resumes)"""
    out: Path = field(default=Path("outputs/bandai_bench"), metadata=option(metavar="DIR"))
    """where results.json and results.md go (the protocol's own files in <out>/protocol)"""
    preset: str = "demo"
    """training preset of the four stages (demo: sized in optimiser steps)"""
    replications: int = field(default=20, metadata=option(metavar="N"))
    """protocol replications"""
    mm_texts: int = field(default=32, metadata=option(metavar="N"))
    """captions for MultiModality (the standard protocol's 100 would take most of the hour)"""
    mm_samples: int = field(default=10, metadata=option(metavar="N"))
    """generations per MultiModality caption (standard: 30)"""
    pool_size: int = field(default=32, metadata=option(metavar="N"))
    """R-precision pool size (standard: 32)"""
    parallel: bool = True
    """train the length model and the evaluator in a second process meanwhile"""
    threads: int = field(default=0, metadata=option(metavar="N"))
    """torch CPU threads of every stage and of the evaluation (0: as make demo: the preset's one
    thread, two for the generator once the second process is done; torch's choice in the
    evaluation); on a CPU busy with other work, 1 avoids oversubscribing it"""
    seed: int = 0
    """seed of the captions, the split and the evaluation"""
    workers: int = 2
    """processes for the dataset build"""

    def __post_init__(self) -> None:
        if isinstance(self.mocap, (str, os.PathLike)):
            self.mocap = (Path(self.mocap),)
        self.mocap = tuple(Path(folder) for folder in self.mocap) or (DEFAULT_MOCAP,)
        if self.threads < 0:
            raise UsageError("--threads must be 0 (the default choice) or more")
        if min(self.replications, self.mm_texts, self.workers) < 1:
            raise UsageError("--replications, --mm-texts and --workers must be at least 1")
        if self.mm_samples < 2 or self.pool_size < 3:
            raise UsageError("--mm-samples must be at least 2 and --pool-size at least 3")

    def eval_settings(self) -> dict:
        keys = ("replications", "mm_texts", "mm_samples", "pool_size", "seed")
        return {key: getattr(self, key) for key in keys}


def _stage_done(run_dir: Path, name: str) -> bool:
    from t2m.train.stage import FINISHED
    from t2m.train.stages import find_stage

    return (find_stage(name).folder(run_dir) / FINISHED).is_file()


def train_one(
    name: str, preset_name: str, dataset: Path, run_dir: Path, threads: int = 0, side_busy=None
) -> dict:
    """Train (or resume) one stage on ``threads`` torch threads (0: the preset's; the generator
    takes two once ``side_busy()`` is false). Returns its wall and CPU seconds."""
    from t2m.config import apply_overrides
    from t2m.demo import Stopwatch
    from t2m.presets import preset
    from t2m.train import runtime as runtime_module
    from t2m.train.stages import find_stage, train_stage

    resume = (find_stage(name).folder(run_dir) / "latest.pt").is_file()
    logger.info("training %s (%s) ...", name, "resuming" if resume else "from scratch")
    config = preset(preset_name)
    if threads:
        config = apply_overrides(config, {"num_threads": str(threads)})
    runtime = None
    cores = min(2, len(os.sched_getaffinity(0)))
    if name == "generator" and cores > 1 and not threads:
        runtime = runtime_module.start(config.device, config.bf16, config.num_threads)
        busy = side_busy or (lambda: False)
        runtime.epoch_threads = lambda: 1 if busy() else cores
    watch = Stopwatch()
    start, cpu = watch.wall, watch.cpu
    train_stage(name, config, dataset, run_dir, runtime=runtime, resume=resume)
    seconds = {"wall_s": time.perf_counter() - start, "cpu_s": watch._cpu() - cpu}
    logger.info("%s trained in %s", name, watch)
    return seconds


def _train_side(
    names: list[str], preset_name: str, dataset: Path, run_dir: Path, threads: int
) -> dict:
    """The second process: ``names`` in order, each once the stages it needs are finished."""
    import multiprocessing

    from t2m.train.stages import find_stage

    timings = {}
    for name in names:
        while not all(_stage_done(run_dir, need) for need in find_stage(name).needs):
            parent = multiprocessing.parent_process()
            if parent is not None and not parent.is_alive():
                raise RuntimeError("the benchmark's main process ended")
            time.sleep(1.0)
        seconds = train_one(name, preset_name, dataset, run_dir, threads)
        timings[name] = {**seconds, "second_process": True}
    return timings


def train_stages(config: MocapBenchConfig) -> dict:
    """Step 2: the four stages; finished ones reused. Returns per stage its seconds or
    ``"reused"``."""
    from t2m.demo import SecondProcess

    names = ("autoencoder", "length", "generator", "evaluator")
    timings: dict = {name: "reused" for name in names if _stage_done(config.checkpoints, name)}
    todo = [name for name in names if name not in timings]
    side = [n for n in todo if n in ("length", "evaluator")] if config.parallel else []
    main = [name for name in todo if name not in side]
    args = (config.preset, config.dataset, config.checkpoints, config.threads)
    if not side:
        for name in main:
            timings[name] = train_one(name, *args)
    else:
        log = config.checkpoints / "side_stages.log"
        with SecondProcess(f"training {', '.join(side)}", _train_side, (side, *args), log) as other:
            for name in main:
                timings[name] = train_one(name, *args, side_busy=other.process.is_alive)
            timings.update(other.join())
    return {name: timings[name] for name in names}


def _clips_features(clips) -> np.ndarray:
    return np.stack([pooled_features(clip.motion) for clip in clips])


def train_classifier(config: MocapBenchConfig, labels: dict[str, Capture], spec) -> tuple:
    """Step 3: the style classifier on the training split's real clips; its accuracy on the
    real test clips (whole clips) beside it."""
    from t2m.data.dataset import load_split

    found = {}
    for split in ("train", "val", "test"):
        clips = [c for c in load_split(config.dataset, split, spec=spec) if c.name in labels]
        found[split] = (_clips_features(clips), [labels[c.name].style for c in clips])
    classifier, info = StyleClassifier.fit(found["train"], found["val"])
    info["test_accuracy"] = classifier.accuracy(*found["test"])
    info["test_clips"] = len(found["test"][1])
    predicted = classifier.predict(found["test"][0])
    info["test_accuracy_by_style"] = {
        style: float(np.mean([p == s for p, s in zip(predicted, found["test"][1], strict=True)
                              if s == style] or [np.nan]))
        for style in classifier.styles
    }  # fmt: skip
    logger.info(
        "style classifier: train %.2f, val %.2f, real test clips %.2f (%d clips, chance %.2f)",
        info["train_accuracy"],
        info["val_accuracy"],
        info["test_accuracy"],
        info["test_clips"],
        1 / len(classifier.styles),
    )
    return classifier, info


def run_evaluation(config: MocapBenchConfig, scorer: BenchScorer) -> dict:
    """Step 4: the protocol of ``python -m t2m.evaluate`` on the test split with the scorer."""
    from dataset_tools.spec import spec_for_folder
    from t2m.data.dataset import load_split
    from t2m.evaluate.backend import CheckpointBackend
    from t2m.evaluate.protocol import EvalConfig, run_protocol
    from t2m.evaluate.report import summarize
    from t2m.train.runtime import inference_device

    eval_config = EvalConfig(
        replications=config.replications,
        mm_texts=config.mm_texts,
        mm_samples=config.mm_samples,
        pool_size=config.pool_size,
        seed=config.seed,
        num_threads=config.threads,
    )
    if config.threads:
        import torch

        torch.set_num_threads(config.threads)
    backend = CheckpointBackend.from_run_dir(
        config.checkpoints, inference_device("auto", "fp32"), "best", eval_config.batch_size
    )
    spec = backend.spec or spec_for_folder(config.dataset)
    clips = load_split(config.dataset, "test", spec=spec)
    result = run_protocol(clips, backend, eval_config, spec=spec, semantic=scorer)
    summary = summarize(result)
    summary.update(dataset=str(config.dataset), checkpoints=str(config.checkpoints))
    summary["evaluator"] = backend.embedder.description
    return summary


def _write_protocol(summary: dict, folder: Path) -> None:
    from t2m.evaluate.report import format_markdown

    text = format_markdown(summary, "Bandai-Namco benchmark: the evaluation protocol")
    text += (
        "\nHere the semantic accuracy is the content accuracy: the share of motions in which "
        "the real-mocap check's content detectors (t2m.evaluate.mocap.CONTENT_CHECKS) recognise "
        "the clip's content, over the contents they judge (t2m.evaluate.mocap.NOT_JUDGED are "
        "left out); the per-action table is per content. Style accuracies are in "
        "results.json (semantic_accuracy_style*) and in ../results.md.\n"
    )
    folder.mkdir(parents=True, exist_ok=True)
    write_json_atomic(folder / "results.json", summary)
    write_text_atomic(folder / "results.md", text)


def _fingerprint(config: MocapBenchConfig, classifier_info: dict) -> dict:
    """What an evaluation's results depend on: its settings, the stages' finish stamps and the
    classifier."""
    from t2m.train.stage import FINISHED
    from t2m.train.stages import find_stage

    stamps = {}
    for name in ("autoencoder", "length", "generator", "evaluator"):
        path = find_stage(name).folder(config.checkpoints) / FINISHED
        stamps[name] = path.read_text(encoding="utf-8") if path.is_file() else None
    return {
        "settings": config.eval_settings(),
        "stages": stamps,
        "classifier": classifier_info,
        "scores": SCORES_VERSION,
    }


def run_bench(config: MocapBenchConfig) -> dict:
    """Steps 1-5; returns (and writes) the results."""
    from dataset_tools.build import BuildConfig, build_dataset
    from dataset_tools.io import check_output_folder
    from dataset_tools.spec import spec_for_folder
    from t2m.presets import PRESETS

    if config.preset not in PRESETS:
        raise UsageError(f"--preset {config.preset}: unknown (one of {', '.join(PRESETS)})")
    for folder, name in ((config.dataset, "--dataset"), (config.checkpoints, "--checkpoints")):
        check_output_folder(folder, name)
    check_output_folder(config.out, "--out")
    start = time.perf_counter()
    load = {"start": os.getloadavg()}
    timings: dict = {}
    # 1. captures, captions, splits, dataset
    captures = read_all(config.mocap)
    labels = {c.name: c for capture in captures for c in (capture, mirrored(capture))}
    sources = sorted({source_title(c.source) for c in captures})
    logger.info(
        "%d captures of %s: %d contents x %d styles",
        len(captures),
        " and ".join(sources),
        len({c.content for c in captures}),
        len({c.style for c in captures}),
    )
    inputs = Path(f"{config.dataset}_inputs")
    if (config.dataset / "Mean.npy").is_file():
        if not (inputs / "splits" / "test.txt").is_file():
            raise UsageError(
                f"--dataset {config.dataset} holds a dataset that this benchmark did not build "
                f"(no {inputs}/splits beside it); choose another --dataset"
            )
        built = {
            name
            for split in ("train", "val", "test")
            for name in (inputs / "splits" / f"{split}.txt").read_text(encoding="utf-8").split()
        }
        if built != {c.name for c in captures}:
            raise UsageError(
                f"--dataset {config.dataset} was built from other captures than those of "
                f"--mocap {' '.join(map(str, config.mocap))}; choose another --dataset"
            )
        timings["build"] = "reused"
    else:
        clock = time.perf_counter()
        texts, splits = write_build_inputs(captures, inputs, config.seed)
        build_dataset(
            BuildConfig(
                "bvh",
                build_input_folder(captures, config.mocap, inputs),
                config.dataset,
                texts_dir=texts,
                splits_dir=splits,
                workers=config.workers,
                seed=config.seed,
            )
        )
        timings["build"] = {"wall_s": time.perf_counter() - clock}
    # 2. the four stages
    timings["stages"] = train_stages(config)
    # 3. the style classifier
    clock = time.perf_counter()
    spec = spec_for_folder(config.dataset)
    classifier, classifier_info = train_classifier(config, labels, spec)
    timings["classifier"] = {"wall_s": time.perf_counter() - clock}
    # 4. the protocol with content and style scores
    protocol_dir = config.out / "protocol"
    fingerprint = _fingerprint(config, classifier_info)
    earlier = _read_json(protocol_dir / "results.json")
    if earlier is not None and earlier.get("bench") == fingerprint:
        summary, timings["evaluation"] = earlier, "reused"
    else:
        clock = time.perf_counter()
        logger.info("evaluating on the test split (%d replications) ...", config.replications)
        summary = run_evaluation(config, BenchScorer(labels, classifier, spec.fps))
        summary["bench"] = fingerprint
        _write_protocol(summary, protocol_dir)
        timings["evaluation"] = {"wall_s": time.perf_counter() - clock}
    timings["total_wall_s"] = time.perf_counter() - start
    load["end"] = os.getloadavg()
    _keep_earlier_times(timings, _read_json(config.out / "results.json"))
    # 5. results
    contents = sorted({c.content for c in captures})
    results = {
        "mocap": [str(folder) for folder in config.mocap],
        "sources": sources,
        "missing_sources": [
            f"{name} (not given: --mocap takes its folder)"
            for name in ("Bandai-Namco-1", "Bandai-Namco-2")
            if name not in sources
        ],
        "dataset": str(config.dataset),
        "checkpoints": str(config.checkpoints),
        "preset": config.preset,
        "settings": config.eval_settings(),
        "captures": len(captures),
        "captures_by_source": {
            name: sum(source_title(c.source) == name for c in captures) for name in sources
        },
        "contents": contents,
        "not_judged": {
            content: NOT_JUDGED.get(content, "no check")
            for content in contents
            if not judged(content)
        },
        "styles": sorted({c.style for c in captures}),
        "style_aliases": {
            alias: style
            for alias, style in STYLE_ALIASES.items()
            if style in {c.style for c in captures}
        },
        "style_classifier": classifier_info,
        "protocol": {row: _row_summary(values) for row, values in summary["rows"].items()},
        "deviations": summary["deviations"],
        "num_items": summary["num_items"],
        "num_items_available": summary["num_items_available"],
        "timings": timings,
        "load_average": load,
        "cpu_count": os.cpu_count(),
    }
    write_json_atomic(config.out / "results.json", results)
    write_text_atomic(config.out / "results.md", format_results(results))
    return results


def _keep_earlier_times(timings: dict, earlier: dict | None) -> None:
    """Steps reused from an earlier run keep the seconds that run measured (marked
    ``earlier_run``), so that a rerun's results still say what each step took."""
    before = (earlier or {}).get("timings")
    if not isinstance(before, dict):
        return
    for key in ("build", "evaluation"):
        if timings.get(key) == "reused" and isinstance(before.get(key), dict):
            timings[key] = {**before[key], "earlier_run": True}
    stages = before.get("stages") if isinstance(before.get("stages"), dict) else {}
    for name, entry in timings.get("stages", {}).items():
        if entry == "reused" and isinstance(stages.get(name), dict):
            timings["stages"][name] = {**stages[name], "earlier_run": True}


def _read_json(path: Path) -> dict | None:
    try:
        content = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return content if isinstance(content, dict) else None


def _row_summary(values: dict) -> dict:
    """A protocol row's means and intervals under the benchmark's names: the scorer's keys
    (``semantic_accuracy*``) as ``content_accuracy``, ``content_accuracy_<content>``,
    ``content_accuracy_in_<style>``, ``style_accuracy``, ``style_accuracy_<style>`` and
    ``style_accuracy_in_<content>``, ``speed_mps_<content or style>``; the physical figures
    left out (they are in the protocol's results)."""
    row = {}
    for key, entry in values.items():
        if key.startswith("physical_"):
            continue
        name = key
        if key == "semantic_accuracy":
            name = "content_accuracy"
        elif key.startswith("semantic_accuracy_"):
            rest = key.removeprefix("semantic_accuracy_")
            if rest.startswith("action_"):
                name = "content_accuracy_" + rest.removeprefix("action_")
            elif rest.startswith("content_in_"):
                name = "content_accuracy_in_" + rest.removeprefix("content_in_")
            elif rest == "style" or rest.startswith("style_"):
                name = "style_accuracy" + rest.removeprefix("style")
            elif rest.startswith("speed_"):
                name = "speed_mps_" + rest.removeprefix("speed_")
        row[name] = {"mean": entry["mean"], "interval": entry["interval"]}
    return row


def _cell(entry: dict | None, digits: int = 3) -> str:
    if not entry or entry.get("mean") is None:
        return "-"
    interval = entry.get("interval")
    spread = "" if interval is None else f" ±{interval:.{digits}f}"
    return f"{entry['mean']:.{digits}f}{spread}"


def format_results(results: dict) -> str:
    """The results as markdown: the protocol's rows, then per content and per style."""
    from t2m.evaluate.protocol import GT_LENGTH, REAL, SAMPLED_LENGTH

    rows = results["protocol"]
    classifier = results["style_classifier"]
    settings = results["settings"]
    metrics = (
        ("r_precision_top1", "R@1 ↑"),
        ("r_precision_top2", "R@2 ↑"),
        ("r_precision_top3", "R@3 ↑"),
        ("fid", "FID ↓"),
        ("mm_dist", "MM-Dist ↓"),
        ("diversity", "Diversity →"),
        ("multimodality", "MModality ↑"),
        ("content_accuracy", "Content acc. ↑"),
        ("style_accuracy", "Style acc. ↑"),
    )
    sources = results["sources"]
    by_source = results.get("captures_by_source", {})
    counts = ", ".join(f"{by_source[name]} of {name}" for name in sources if name in by_source)
    missing = "".join(f" {name} is not covered (not given)." for name in results["missing_sources"])
    aliases = results.get("style_aliases", {})
    merged = (
        " Styles of one meaning share a label: "
        + ", ".join(f"{alias} = {style}" for alias, style in aliases.items())
        + "."
        if aliases and len(sources) > 1
        else ""
    )
    lines = [
        f"# Real motion capture benchmark ({' and '.join(sources)})",
        "",
        f"{results['captures']} captures ({counts}; {len(results['contents'])} contents, "
        f"{len(results['styles'])} styles, with mirrors).{missing}{merged} Preset "
        f"`{results['preset']}`, all four stages trained on the training split; test split: "
        f"held-out takes of each content and style with several takes, held-out content x "
        f"style combinations where there is one take, each with its mirror; "
        f"{results['num_items']} items a replication (of {results['num_items_available']}), "
        f"{settings['replications']} replications, seed {settings['seed']}; mean ±95% interval.",
        "",
        "| row | " + " | ".join(title for _, title in metrics) + " |",
        "|---|" + "---|" * len(metrics),
    ]
    for row, values in rows.items():
        lines.append(f"| {row} | " + " | ".join(_cell(values.get(k)) for k, _ in metrics) + " |")
    lines += [
        "",
        f"Style classifier (logistic regression on time-pooled motion features, L2 "
        f"{classifier['l2']:g}): trained on {classifier['train_clips']} real training clips, "
        f"accuracy {classifier['test_accuracy']:.2f} on the {classifier['test_clips']} whole "
        f"real test clips ({classifier['val_accuracy']:.2f} on validation; chance "
        f"{1 / len(results['styles']):.2f}): the ceiling a generated style accuracy is read "
        "against.",
    ]
    if results["deviations"]:
        lines += ["", "Deviations from the standard protocol: " + "; ".join(results["deviations"])]
    # the generated rows: ground-truth lengths, the other plan's at ground-truth lengths where
    # tabled, sampled lengths
    columns = [(REAL, "real"), (GT_LENGTH, "ground-truth length")]
    columns += [
        (row, row.removeprefix("Ours (").removesuffix(")"))
        for row in rows
        if row.startswith(GT_LENGTH[:-1] + ", ")
    ]
    columns.append((SAMPLED_LENGTH, "sampled length"))
    columns = [(row, title) for row, title in columns if row in rows]
    # contents and styles without test motions (all their clips in training) are named below
    untested = [
        label
        for label in (*results["contents"], *results["styles"])
        if f"speed_mps_{label}" not in rows.get(REAL, {})
    ]
    labelled = [
        (content, content, f"_{content}", f"_in_{content}")
        for content in results["contents"]
        if content not in untested
    ]
    labelled += [
        (f"*{style}*", style, f"_in_{style}", f"_{style}")
        for style in results["styles"]
        if style not in untested
    ]
    labelled.append(("**all**", None, "", ""))
    speed_columns = columns[:2]
    lines += [
        "",
        "Content accuracy (the real-mocap check's detectors, t2m.evaluate.mocap.CONTENT_CHECKS, "
        "recognise the clip's content) and mean horizontal speed, per content and per style, "
        "real test motions against generated ones:",
        "",
        "| | "
        + " | ".join(title for _, title in columns)
        + " | "
        + " | ".join(f"speed {title}, m/s" for _, title in speed_columns)
        + " |",
        "|---|" + "---|" * (len(columns) + len(speed_columns)),
    ]
    not_judged = results.get("not_judged", {})
    for title, label, content_key, _ in labelled:
        cells = [_cell(rows[row].get(f"content_accuracy{content_key}"), 2) for row, _ in columns]
        if label in not_judged:
            cells = ["not judged"] * len(columns)
        cells += [_cell(rows[row].get(f"speed_mps_{label}"), 2) for row, _ in speed_columns]
        lines.append(f"| {title} | " + " | ".join(cells) + " |")
    if not_judged:
        lines += [
            "",
            "Not judged (no content check; left out of every content accuracy, counted for "
            "style and speed): "
            + "; ".join(f"{content}: {why}" for content, why in not_judged.items())
            + ".",
        ]
    if untested:
        lines += ["", f"No test motions (every clip in training): {', '.join(untested)}."]
    lines += [
        "",
        "Style accuracy (the classifier names the clip's style), per content and per style:",
        "",
        "| | " + " | ".join(title for _, title in columns) + " |",
        "|---|" + "---|" * len(columns),
    ]
    for title, _, _, style_key in labelled:
        cells = [_cell(rows[row].get(f"style_accuracy{style_key}"), 2) for row, _ in columns]
        lines.append(f"| {title} | " + " | ".join(cells) + " |")
    timings = results["timings"]
    lines += [
        "",
        "Times: " + _times_line(timings) + f"; load average at start {_load(results, 'start')}, "
        f"at end {_load(results, 'end')}, {results['cpu_count']} CPUs.",
    ]
    return "\n".join(lines) + "\n"


def _load(results: dict, when: str) -> str:
    values = results.get("load_average", {}).get(when)
    return "-" if not values else "/".join(f"{v:.1f}" for v in values)


def _seconds(entry) -> str:
    if entry == "reused" or not isinstance(entry, dict):
        return str(entry)
    notes = [
        note
        for key, note in (("second_process", "2nd process"), ("earlier_run", "an earlier run"))
        if entry.get(key)
    ]
    return f"{entry['wall_s']:.0f} s" + (f" ({', '.join(notes)})" if notes else "")


def _times_line(timings: dict) -> str:
    parts = [f"build {_seconds(timings.get('build'))}"]
    parts += [f"{name} {_seconds(entry)}" for name, entry in timings.get("stages", {}).items()]
    parts += [f"classifier {_seconds(timings.get('classifier'))}"]
    parts += [f"evaluation {_seconds(timings.get('evaluation'))}"]
    parts.append(f"total {timings['total_wall_s'] / 60:.1f} min")
    return ", ".join(parts)


@command(interrupted="interrupted; run it again to continue where it stopped")
def main(argv: list[str] | None = None) -> int:
    """``python -m t2m.evaluate.mocap_bench``; exit status 0, or 2 with a one-line reason."""
    parser = CommandParser(
        prog="python -m t2m.evaluate.mocap_bench",
        description="Real motion capture benchmark: build Bandai-Namco-2 and, given, "
        "Bandai-Namco-1 (every content and style, mirrors) with captions naming content and "
        "style, train the four stages, run the evaluation protocol on held-out takes and "
        "content x style combinations with content and style accuracy.",
    )
    config = parse_config(parser, MocapBenchConfig, argv)
    results = run_bench(config)
    print(format_results(results))
    print(f"wrote {config.out / 'results.md'} and {config.out / 'results.json'}")
    return 0


__all__ = [
    "BenchScorer",
    "Capture",
    "MocapBenchConfig",
    "StyleClassifier",
    "clip_captions",
    "main",
    "read_all",
    "read_captures",
    "run_bench",
    "split_clips",
    "split_takes",
]

if __name__ == "__main__":
    sys.exit(main())
