"""Clauses of a caption and their share of the motion: the plan of clause-by-clause generation.

A caption such as "a person jumps twice, then waves with the left hand" asks for two things in
turn. Generated in one pass, the temporal VAE knows how far the motion's end is (time to
arrival) but not which part of the sentence it is in nor how much of that part is done, and
what comes second or has a count mostly fails (measured on the demo corpus: items of 1 / 2 / 3
labelled parts 0.88 / 0.56 / 0.24). Clause-by-clause generation (:mod:`t2m.pipeline`, ``plan=
"clauses"``) gives each clause its own stretch of the motion: the attention reads only that
clause's words, the time-to-arrival encoding counts down to the clause's end, and the recurrent
state runs on across the boundary, so the motion stays one continuous sequence.

This module finds the clauses in a caption's ``word/POS`` tokens (lemmatised, punctuation
dropped, as the models read them) and shares a length among them. Temporal connectives start a
new clause: "then", "and then", "after that", "after which", "afterwards", "subsequently",
"next", "finally", "lastly", "eventually", "later", "before ...", "prior to ...", "followed by
..." (with or without a leading "and"). A caption that opens with "after" or "once" ("after
waving, a person sits down"; "once done waving, sit down") splits where its main clause's subject
starts (a subject pronoun, or a determiner before a word for a person) or, in the imperative, at
its next verb. Everything else (including "and" alone, "while") stays in one clause:
simultaneous or unclear parts are left to the model.

Counts are read in the forms people write them (:func:`repetition_count`): "once", "twice",
"thrice", "two times", "a couple of times", "a single time", "one more time", "three jumps",
"three separate times"; digits ("3 times", "2x", "x2") reach the parser spelled out, as the
tagger reads them (:func:`dataset_tools.texts.spell_counts`).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from t2m.lexicon import COUNT_WORDS, MOTION_WORDS, SYNONYMS

CONNECTIVES = frozenset(
    {
        "then",
        "afterwards",
        "afterward",
        "subsequently",
        "finally",
        "lastly",
        "eventually",
        "later",
        "next",
    }
)
"""One-word connectives that start a new clause (with a preceding "and", it starts there)."""

SUBJECT_PRONOUNS = frozenset({"someone", "somebody", "he", "she", "they", "person"})
PERSON_NOUNS = frozenset(
    {
        "person",
        "man",
        "woman",
        "figure",
        "human",
        "guy",
        "girl",
        "boy",
        "individual",
        "character",
        "people",
        "child",
        "kid",
        "lady",
        "player",
        "dancer",
        "subject",
        "actor",
        "performer",
        "athlete",
        "someone",
    }
)

EXTRA_VERBS = frozenset({"bow", "clap", "march", "wave", "hop", "squat", "punch", "kick"})
"""Motion verbs a tagger often calls nouns, besides the vocabulary's action words."""

COUNTED_NOUNS = EXTRA_VERBS | {"jump", "step", "leap", "lunge", "spin", "stomp", "turn"}
"""Nouns of a repeatable action: "one" before them is a count ("throws one left punch"), before
any other noun it is not ("hops on one foot")."""

MIN_CLAUSE_SNIPPETS = 5
"""A clause gets at least this many snippets (1 s at 20 fps) when the motion has room."""


def _word_pos(token: str) -> tuple[str, str]:
    word, _, pos = token.rpartition("/")
    return (word or pos).lower(), pos if word else ""


def split_clauses(tokens: Sequence[str]) -> list[range]:
    """``word/POS`` tokens -> the token ranges of the caption's clauses, in order (one range for
    a caption with no temporal connective; empty ranges only for no tokens)."""
    pairs = [_word_pos(t) for t in tokens]
    words = [w for w, _ in pairs]
    tags = [p for _, p in pairs]
    count = len(words)
    starts = [0]
    leading = count > 0 and words[0] in ("after", "once")
    # "once done waving, ...": the leading clause's own verb comes after "done"
    first_verb = 2 if words[:1] == ["once"] and count > 1 and words[1] in ("do", "done") else 1
    split_leading = False

    def subject_at(i: int) -> bool:
        return words[i] in SUBJECT_PRONOUNS or (
            tags[i] == "DET" and i + 1 < count and words[i + 1] in PERSON_NOUNS
        )

    imperative = leading and not any(subject_at(i) for i in range(1, count))

    def connective_at(i: int) -> bool:
        word = words[i]
        following = words[i + 1] if i + 1 < count else ""
        if word in CONNECTIVES or word == "before":
            return True
        if word == "after":
            return following in ("that", "which", "this")
        return (word, following) in (("prior", "to"), ("followed", "by"), ("follow", "by"))

    for i in range(1, count):
        word = words[i]
        if word == "and":
            starts_here = i + 1 < count and connective_at(i + 1)
        elif connective_at(i):
            starts_here = words[i - 1] != "and"
        elif (
            leading
            and not split_leading
            and any(_is_action(words[j], tags[j]) for j in range(first_verb, i))
        ):
            # "after <clause> <subject> <main clause>": the subject starts the main clause; with
            # no subject (the imperative "after walking forward, wave"), its verb does
            starts_here = subject_at(i) or (
                imperative
                and _is_action(word, tags[i])
                and words[i - 1] not in ("and", "or", "to")
                and tags[i - 1] not in ("DET", "ADJ", "NUM")
                and not words[i - 1].endswith("ing")  # "once done jabbing using the arm"
                and word != "use"  # "using the arm" says how, lemmatised or read ("jab using")
            )
            split_leading = starts_here
        else:
            starts_here = False
        if starts_here and i > starts[-1]:
            starts.append(i)
    ends = starts[1:] + [count]
    ranges = [range(s, e) for s, e in zip(starts, ends)]
    # A part that names no action ("walks forward, then back", "raises the arm, then down") is
    # no clause of its own: it joins the one before it (the first such part, the one after it).
    kept: list[range] = []
    pending: int | None = None
    for part in ranges:
        start = part.start if pending is None else pending
        if _has_predicate([words[i] for i in part], [tags[i] for i in part]):
            kept.append(range(start, part.stop))
            pending = None
        elif kept:
            kept[-1] = range(kept[-1].start, part.stop)
        else:
            pending = start
    if pending is not None:  # no part names an action: one clause
        return [range(0, count)]
    return kept


def _motion_verb(word: str) -> bool:
    return word in MOTION_WORDS["ACTION"] or word in EXTRA_VERBS or word in SYNONYMS


def _is_action(word: str, tag: str) -> bool:
    """A word tagged VERB or a motion verb the tagger may call a noun (see :func:`_has_predicate`),
    also as a gerund left unlemmatised ("kicking", "running", "waving")."""
    if tag == "VERB" or _motion_verb(word):
        return True
    stem = word[:-3] if word.endswith("ing") else ""
    return bool(stem) and any(_motion_verb(s) for s in (stem, stem + "e", stem[:-1]))


def _has_predicate(words: Sequence[str], tags: Sequence[str]) -> bool:
    """Whether a part names an action: a word tagged VERB, a motion verb the tagger may call a
    noun ("waves", "lowers": the vocabulary's action words, :data:`EXTRA_VERBS`, the motion
    verbs of :data:`t2m.lexicon.SYNONYMS`: "Signal hello" opening a caption), or a noun right
    after its connective and subject ("then sidestep to the left", "then leap forward")."""
    if any(_is_action(w, t) for w, t in zip(words, tags)):
        return True
    start = _connective_length(words)
    if start < len(words) and words[start] in SUBJECT_PRONOUNS:
        start += 1
    elif start + 1 < len(words) and tags[start] == "DET" and words[start + 1] in PERSON_NOUNS:
        start += 2
    return start < len(words) and tags[start] == "NOUN"


LEADING_CONNECTIVES = (
    ("and", "after", "that"),
    ("and", "then"),
    ("and", "afterwards"),
    ("and", "afterward"),
    ("after", "that"),
    ("after", "which"),
    ("after", "this"),
    ("and", "before"),
    ("and", "finally"),
    ("and", "next"),
    ("and", "later"),
    ("and", "subsequently"),
    ("once", "do"),
    ("once", "done"),
    ("prior", "to"),
    ("followed", "by"),
    ("follow", "by"),
    ("then",),
    ("afterwards",),
    ("afterward",),
    ("subsequently",),
    ("finally",),
    ("lastly",),
    ("eventually",),
    ("later",),
    ("next",),
    ("before",),
    ("after",),
    ("once",),
)
"""What a clause may open with that its standalone caption drops (longest first)."""

SUBJECT = ("a/DET", "person/NOUN")
"""The subject given to a clause that has none ("then waves" -> "a person waves")."""


def _connective_length(words: Sequence[str]) -> int:
    """How many of ``words`` open a clause as its connective (0: none; one word is always left)."""
    for pattern in LEADING_CONNECTIVES:
        if tuple(words[: len(pattern)]) == pattern and len(words) > len(pattern):
            return len(pattern)
    return 0


def standalone(tokens: Sequence[str]) -> list[str]:
    """One clause's tokens as a caption of its own, as the models were trained on: the opening
    connective dropped ("then", "after that", "before", ...) and, where the clause does not
    start with a subject, "a person" put in front. Measured on the demo corpus (2-3-part test
    captions): the length model's estimates of standalone clauses follow the clauses' real
    lengths with correlation 0.87 (0.73 as cut), their shares of the motion within 0.05 (0.08)."""
    words = [_word_pos(t)[0] for t in tokens]
    start = _connective_length(words)
    rest = list(tokens[start:])
    first = words[start:]
    has_subject = bool(first) and (
        first[0] in SUBJECT_PRONOUNS
        or (_word_pos(rest[0])[1] == "DET" and len(first) > 1 and first[1] in PERSON_NOUNS)
    )
    return rest if has_subject else [*SUBJECT, *rest]


def clause_captions(tokens: Sequence[str]) -> list[list[str]]:
    """A caption's clauses (:func:`split_clauses`) as standalone captions (:func:`standalone`);
    a caption of one clause comes back whole, unchanged."""
    ranges = split_clauses(tokens)
    if len(ranges) < 2:
        return [list(tokens)]
    return [standalone([tokens[i] for i in r]) for r in ranges]


def clause_targets(
    total: int,
    means: Sequence[float],
    variances: Sequence[float],
    counted: Sequence[bool] | None = None,
) -> np.ndarray:
    """Where a motion of ``total`` snippets puts its clauses' lengths, given the length each
    clause would have alone (the text2length model's ``means`` and ``variances``, snippets):
    each clause gets its mean plus a share of the difference ``total - sum(means)`` in
    proportion to its variance, the most probable split were the lengths independent normals.
    A clause whose length is well known ("claps five times") keeps it; one whose length is not
    ("walks forward") takes up the difference. A clause flagged in ``counted`` (it names a
    count) keeps exactly what its count needs (:func:`needed_snippets` of its mean) while a
    clause without a count is there to take up the difference: a counted clause given a snippet
    or two less than its mean drops a repetition (measured on the demo model: "walks quickly,
    then claps six times" at 6 s, 15 of the clap's 18 snippets, made four or five claps).
    Targets below a snippet are raised to 0.1 (a total far below the means;
    :func:`share_snippets` then rescales them)."""
    means = np.asarray(means, dtype=np.float64)
    spread = np.maximum(np.asarray(variances, dtype=np.float64), 1e-3)
    if counted is not None:
        keep = np.asarray(counted, dtype=bool)
        if keep.shape != means.shape:
            raise ValueError(f"{keep.size} counted flags for {means.size} clauses")
        if keep.any() and not keep.all():
            means = np.where(keep, needed_snippets(means), means)
            spread = np.where(keep, 0.0, spread)
    targets = means + spread / spread.sum() * (total - means.sum())
    return np.maximum(targets, 0.1)


def share_snippets(
    total: int, weights: Sequence[float], minimum: int = MIN_CLAUSE_SNIPPETS
) -> list[int]:
    """Split ``total`` snippets among clauses in proportion to ``weights`` (each clause's own
    expected length), every clause at least ``minimum`` (less when the motion is too short for
    that, never below one); the parts sum to ``total``."""
    parts = len(weights)
    if parts < 1 or total < parts:
        raise ValueError(f"cannot share {total} snippets among {parts} clauses")
    share = np.maximum(np.asarray(weights, dtype=np.float64), 1e-6)
    share = share / share.sum() * total
    floor = max(1, min(minimum, total // parts))
    counts = np.maximum(np.floor(share).astype(np.int64), floor)
    while counts.sum() > total:  # take from the clause furthest above its share
        over = np.where(counts > floor, counts - share, -np.inf)
        counts[int(np.argmax(over))] -= 1
    while counts.sum() < total:  # give to the clause furthest below its share
        counts[int(np.argmax(share - counts))] += 1
    return [int(c) for c in counts]


PLAIN_COUNTS = frozenset({"once", "twice", "thrice"})
"""Words that are a count of repetitions on their own ("jumps twice")."""

COUNT_OF = {"couple": 2, "pair": 2}
"""Count nouns read through "of" ("a couple of times", "a pair of jumps": 2)."""


def repetition_count(tokens: Sequence[str]) -> int:
    """How many times a clause's ``word/POS`` tokens say its action happens, 0 when they do not
    say: "once" / "twice" / "thrice", a number followed by "time(s)", adjectives between ("claps
    five times", "hops 3 times", "one more time", "three separate times"), a number word of two
    or more before a noun, adjectives between ("does three squats", "throws two right punches";
    "on one foot", "turns 90 degrees" are no counts), "one" before a repeatable action's noun
    (:data:`COUNTED_NOUNS`: "throws one left punch"), or "couple" / "pair" and "of" before times
    or a noun ("a couple of times", "a pair of jumps"). The first such count in the clause."""
    pairs = [_word_pos(t) for t in tokens]
    for i, (word, _) in enumerate(pairs):
        if word in PLAIN_COUNTS:
            return int(COUNT_WORDS[word])
        digits = word.isdigit() and len(word) <= 2
        number = int(word) if digits else int(COUNT_WORDS.get(word, COUNT_OF.get(word, 0)))
        if not number or i + 1 >= len(pairs):
            continue
        noun = i + 1
        if word in COUNT_OF:
            if pairs[noun][0] != "of":
                continue
            noun += 1
        while noun < len(pairs) and pairs[noun][1] == "ADJ":  # "three separate times"
            noun += 1
        if noun >= len(pairs):
            continue
        if pairs[noun][0] in ("time", "times"):
            return number
        if word in COUNT_OF and pairs[noun][1] == "NOUN":
            return number
        if not digits and pairs[noun][1] == "NOUN":
            if number >= 2 or pairs[noun][0] in COUNTED_NOUNS:
                return number
    return 0


def caption_count(tokens: Sequence[str]) -> int:
    """The repetition count of a caption of one clause (:func:`repetition_count`); 0 for a
    caption of several clauses, whose counts belong to its clauses (:func:`clause_captions`)."""
    return repetition_count(tokens) if len(split_clauses(tokens)) == 1 else 0


SETTLE_TEXT = "a person stands still"
"""The caption of a settling part: what a counted clause's spare time becomes
(:func:`settle_counted`), and what a live stream's "stop" becomes (:mod:`t2m.live`)."""

SETTLE_TOKENS = ("a/DET", "person/NOUN", "stand/VERB", "still/ADV")
""":data:`SETTLE_TEXT` as prompts are tagged (either POS convention), so that a plan needs no
tagger to use it."""

MIN_SETTLE_SNIPPETS = 4
"""A counted clause is split only when at least this many snippets (0.8 s at 20 fps) are spare."""


def needed_snippets(means: Sequence[float]) -> np.ndarray:
    """The snippets a counted clause keeps (int (N,), at least 1): the length the text2length
    model expects for it (its mean), rounded. Not more: on the demo model every snippet beyond
    it risks one more repetition (the mean plus one standard deviation, rounded up, made one
    more jump, hop or punch in most samples), and not less (the mean less half a deviation cut
    punches and hops short)."""
    means = np.asarray(means, dtype=np.float64)
    return np.maximum(np.floor(means + 0.5), 1).astype(np.int64)


def settle_counted(
    counts: Sequence[int],
    snippets: Sequence[int],
    needs: Sequence[int],
    minimum: int = MIN_SETTLE_SNIPPETS,
) -> list[tuple[int, int]]:
    """A clause plan in which counts follow the text, not the length: ``(clause, snippets)`` in
    order, ``clause`` the index of one of the caption's clauses or -1 for a settling part
    (:data:`SETTLE_TEXT`). A clause that names a count (``counts[i]`` > 0) given more snippets
    than it needs (``needs[i]``, :func:`needed_snippets`) keeps what it needs; the surplus goes
    to a settling part after it when it is at least ``minimum`` snippets, else to a neighbouring
    clause without a count (the next, else the one before), else it stays. Every other clause
    keeps its ``snippets[i]`` (plus what it takes over). The parts' snippets sum to
    ``sum(snippets)``.

    Why: the temporal VAE repeats an action at the pace it was trained on, whatever its count
    clock says, so "jumps twice" stretched over 6 s jumps five or six times (demo model), and
    even two snippets over its time often make one more clap or jump. Given only the time the
    count takes, it makes the count; standing still (or the clause beside it) takes the rest."""
    if not len(counts) == len(snippets) == len(needs):
        raise ValueError(f"{len(counts)} counts, {len(snippets)} lengths, {len(needs)} needs")
    sizes = [int(n) for n in snippets]
    settle = [0] * len(sizes)
    for index, (count, need) in enumerate(zip(counts, needs)):
        surplus = sizes[index] - max(int(need), 1)
        if count <= 0 or surplus <= 0:
            continue
        if surplus >= max(minimum, 1):
            sizes[index] -= surplus
            settle[index] = surplus
            continue
        free = [j for j in (index + 1, index - 1) if 0 <= j < len(sizes) and counts[j] <= 0]
        if free:
            sizes[index] -= surplus
            sizes[free[0]] += surplus
    parts: list[tuple[int, int]] = []
    for index, size in enumerate(sizes):
        parts.append((index, size))
        if settle[index]:
            parts.append((-1, settle[index]))
    return parts


def settled_captions(
    captions: Sequence[Sequence[str]],
    snippets: Sequence[int],
    needs: Sequence[int],
    settle: Sequence[str],
    minimum: int = MIN_SETTLE_SNIPPETS,
) -> list[tuple[list[str], int]]:
    """:func:`settle_counted` on captions: a plan's standalone clause captions (``word/POS``
    tokens, :func:`clause_captions`) with their snippets and needs -> ``(caption, snippets)``
    in order, the settling parts' caption ``settle`` (the tokens of :data:`SETTLE_TEXT`). The
    counts are the captions' own (:func:`repetition_count`)."""
    counts = [repetition_count(c) for c in captions]
    plan = settle_counted(counts, snippets, needs, minimum)
    return [(list(settle) if i < 0 else list(captions[i]), n) for i, n in plan]
