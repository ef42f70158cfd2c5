"""Words the model never trained on, read as words it did (t2m.lexicon.read_untrained)."""

import logging

import numpy as np
import pytest

from t2m.lexicon import MIN_SIMILARITY, SYNONYMS, nearest_trained, read_untrained


class Table:
    """A word table as :class:`t2m.data.words.WordVectors` holds one: ``index`` and ``vectors``."""

    def __init__(self, vectors: dict[str, list[float]]):
        self.index = {word: row for row, word in enumerate(vectors)}
        self.vectors = np.asarray(list(vectors.values()), dtype=np.float32)


TABLE = Table(
    {
        "run": [1.0, 0.0, 0.0],
        "jump": [0.0, 1.0, 0.0],
        "squat": [0.0, 0.0, 1.0],
        "gallop": [0.0, 0.95, 0.2],  # near "jump" by the vectors (cosine 0.98)
        "dash": [0.2, 1.0, 0.0],  # nearer "jump" than "run": the table must win
        "quickly": [0.0, 1.0, 0.01],  # an adverb: never read through the vectors
        "blorf": [0.6, 0.6, 0.5],  # no trained word within MIN_SIMILARITY
    }
)
TRAINED = frozenset({"a", "person", "run", "jump", "squat", "forward", "twice"})


def test_the_synonym_table_names_the_issues_examples():
    assert SYNONYMS["dash"][0] == "run"
    assert SYNONYMS["bounce"][0] == "jump"
    assert SYNONYMS["duck"][0] == "squat"


def test_synonyms_are_read_as_the_first_trained_meaning(caplog):
    pairs = [("a", "DET"), ("person", "NOUN"), ("dash", "VERB"), ("forward", "ADV")]
    with caplog.at_level(logging.WARNING, logger="t2m.lexicon"):
        read = read_untrained("a person dashes forward", pairs, TRAINED, TABLE)
    assert read == [("a", "DET"), ("person", "NOUN"), ("run", "VERB"), ("forward", "ADV")]
    assert "'dash' was not trained on; read as 'run'" in caplog.text
    # the first meaning untrained: the next one the model knows
    assert read_untrained("", [("dash", "VERB")], {"jog"}, None) == [("jog", "VERB")]
    # a tagger that calls the verb a noun ("duck down twice") changes nothing
    assert read_untrained("", [("duck", "NOUN")], TRAINED, None) == [("squat", "NOUN")]


def test_vectors_read_only_near_identical_verbs_and_nouns(caplog):
    with caplog.at_level(logging.WARNING, logger="t2m.lexicon"):
        read = read_untrained("gallop", [("gallop", "NOUN")], TRAINED, TABLE, common=0)
    assert read == [("jump", "NOUN")]
    assert "nearest trained word in the word vectors, cosine 0.98" in caplog.text
    # a word among the table's most frequent (here its first 4 rows) is too general
    assert read_untrained("", [("gallop", "NOUN")], TRAINED, TABLE, common=4) == [
        ("gallop", "NOUN")
    ]
    word, cosine = nearest_trained("blorf", TRAINED, TABLE.index, TABLE.vectors)
    assert cosine < MIN_SIMILARITY
    assert read_untrained("", [("blorf", "NOUN")], TRAINED, TABLE, 0) == [("blorf", "NOUN")]
    # adjectives and adverbs keep their own vectors (their nearest word is often an opposite)
    assert read_untrained("", [("quickly", "ADV")], TRAINED, TABLE, 0) == [("quickly", "ADV")]
    # no vector, no table entry: left as it is (the model reads it as unk)
    assert read_untrained("", [("zzz", "VERB")], TRAINED, TABLE) == [("zzz", "VERB")]
    assert nearest_trained("zzz", TRAINED, TABLE.index, TABLE.vectors) is None


def test_trained_words_and_function_words_are_left_alone(caplog):
    pairs = [("jump", "VERB"), ("twice", "ADV"), ("with", "ADP"), ("dash", "DET")]
    with caplog.at_level(logging.WARNING, logger="t2m.lexicon"):
        assert read_untrained("", pairs, TRAINED, TABLE) == pairs
    assert caplog.text == ""


def test_a_repeated_word_is_read_and_named_once(caplog):
    pairs = [("dash", "VERB"), ("then", "ADV"), ("dash", "VERB")]
    with caplog.at_level(logging.WARNING, logger="t2m.lexicon"):
        read = read_untrained("", pairs, TRAINED, TABLE)
    assert [w for w, _ in read] == ["run", "then", "run"]
    assert caplog.text.count("read as") == 1


def test_the_pipeline_reads_an_untrained_prompt_word_as_a_trained_one(pipe, caplog):
    assert "leap" not in pipe.training_words and "jump" in pipe.training_words
    with caplog.at_level(logging.WARNING):
        (leaps,) = pipe.prepare(["a person leaps"])
    (jumps,) = pipe.prepare(["a person jumps"])
    assert np.array_equal(leaps.encoded.words, jumps.encoded.words)
    assert leaps.unknown_words == ("leap",)  # still named as not trained on
    assert "'leap' was not trained on; read as 'jump'" in caplog.text


@pytest.mark.parametrize("word", sorted(SYNONYMS))
def test_every_synonym_points_to_other_words(word):
    assert SYNONYMS[word] and word not in SYNONYMS[word]


def test_tokens_are_read_as_pairs_are():
    from t2m.lexicon import read_prompt, read_prompt_tokens

    tokens = ["a/DET", "person/NOUN", "bounce/VERB", "twice/ADV"]
    pairs = [tuple(token.split("/")) for token in tokens]
    assert read_prompt_tokens("", tokens, TRAINED, TABLE) == [
        f"{word}/{pos}" for word, pos in read_prompt("", pairs, TRAINED, TABLE)
    ]
    assert read_prompt_tokens("", tokens, TRAINED, TABLE) == [
        "a/DET",
        "person/NOUN",
        "jump/VERB",
        "twice/ADV",
    ]


@pytest.mark.parametrize(
    ("words", "read"),
    [
        # the words after it decide: a strike with a foot is a kick, with a fist a punch
        ("strike forward use the left foot", "kick forward use the left foot"),
        ("strike with the right fist", "punch with the right fist"),
        ("bounce on one left foot", "hop on one left foot"),
        ("bounce up and down", "jump up and down"),
        ("walk at high speed", "walk at fast pace"),
        ("move forward", "walk forward"),
        ("move the left arm", "move the left arm"),
        ("move ahead on foot", "walk ahead on foot"),
        # speed words by the table only (the vectors would give opposites)
        ("walk rapidly", "walk quickly"),
        ("walk unhurriedly", "walk slowly"),
        ("walk at a leisurely speed", "walk at a slow pace"),
        ("walk at an ordinary speed", "walk at a normal pace"),
        ("stay motionless", "stand still"),
        # a word for the one who moves; a capitalised first verb a tagger called a proper noun
        ("an individual applaud", "a person clap"),
        ("Jab use your left arm", "punch use your left arm"),
        # compounds: a side word opens it, or two trained words make it
        ("greet with a lefthanded wave", "wave with a left wave"),
        ("move rightward", "walk to the right"),
        ("move laterally toward the left", "walk sideways to the left"),
        ("reach skyward with both arm", "raise up with both arm"),
        ("an individual walk", "a person walk"),
        ("sideshuffle to the left", "shuffle to the left"),
    ],
)
def test_tables_read_untrained_words_in_context(words, read):
    trained = set(
        "a the at with use on one up and down to walk run jump hop kick punch clap wave raise both "
        "stand still left right foot fist arm forward person pace fast slow slowly quickly "
        "normal shuffle side sideways".split()
    )
    tags = {"left": "ADJ", "right": "ADV", "rapidly": "ADV", "unhurriedly": "ADV", "toward": "ADP"}
    tags |= {"leisurely": "ADJ", "ordinary": "ADJ", "motionless": "NOUN", "high": "ADJ"}
    tags |= {"Jab": "PROPN", "lefthanded": "ADJ", "rightward": "ADV", "individual": "NOUN"}
    pairs = [(w, tags.get(w, "VERB")) for w in words.split()]
    assert " ".join(w for w, _ in read_untrained(words, pairs, trained)) == read


def test_instruments_sides_lemma_slips_and_typos_are_read():
    from t2m.lexicon import typo_reading

    trained = set("a person the to kick jump forward left right foot".split())
    trained |= {"circle", "slow", "slowly", "walk"}

    def read(words, tags=None, vocabulary=TABLE):
        pairs = [(w, (tags or {}).get(w, "VERB")) for w in words.split()]
        return read_untrained(words, pairs, trained, vocabulary)

    # a side with a direction ending: "to the left", the side tagged as the training tags it
    assert read("walk leftward", {"leftward": "ADV"})[1:] == [
        ("to", "ADP"),
        ("the", "DET"),
        ("left", "NOUN"),
    ]
    # the tagger's lemma of the imperative "bound"
    assert read("bind forward")[0] == ("jump", "VERB")
    # a word with no vector at all, one edit from a trained word: a typo
    assert [w for w, _ in read("a persn kick", {"persn": "NOUN"})] == ["a", "person", "kick"]
    assert typo_reading("cirlce", trained) == "circle"  # two letters swapped
    assert typo_reading("slowy", trained) == "slowly"  # nearer "slowly" than "slow"
    assert typo_reading("wlak", trained) == "walk"
    assert typo_reading("kicks", {"kick", "kicky"}) is None  # two equally near
    assert typo_reading("kcik", trained) == "kick"  # two neighbours swapped
    assert typo_reading("kcki", trained) is None  # two edits
    assert typo_reading("tha", trained) is None  # too short to tell
    # a word with a vector is a word, not a typo ("blorf" stays as it is)
    assert read("a blorf kick", {"blorf": "NOUN"})[1] == ("blorf", "NOUN")


def test_tables_read_only_content_words_and_collect_readings(caplog):
    trained = {"run", "to"}
    found = {}
    with caplog.at_level(logging.WARNING, logger="t2m.lexicon"):
        read = read_untrained("", [("dash", "VERB"), ("toward", "ADP")], trained, readings=found)
    assert read == [("run", "VERB"), ("to", "ADP")]  # a direction word of any part of speech
    assert found == {"dash": "run", "toward": "to"} and caplog.text == ""  # collected, not warned
    assert read_untrained("", [("along", "ADP")], trained) == [("along", "ADP")]


COUNTING = set("a person jump clap once twice three time one two four thrice their".split())


@pytest.mark.parametrize(
    ("pairs", "read"),
    [
        ("two/NUM time/NOUN", "twice"),
        ("a/DET couple/NOUN of/ADP time/NOUN", "twice"),
        ("a/DET single/ADJ time/NOUN", "once"),
        ("couple/NOUN of/ADP time/NOUN", "twice"),
        # each count in one wording: "once", "twice", "three times", "N times"
        ("one/NUM time/NOUN", "once"),
        ("three/NUM time/NOUN in/ADP a/DET row/NOUN", "three time"),
        ("twice/ADV in/ADP a/DET row/NOUN", "twice"),
        ("thrice/ADV", "three time"),
        ("four/NUM time/NOUN", "four time"),
        ("twice/ADV", "twice"),
        # a number before another noun is no count of repetitions
        ("two/NUM squat/NOUN", "two squat"),
    ],
)
def test_counts_are_read_in_their_usual_wording(pairs, read):
    from t2m.lexicon import read_counts

    split = [tuple(token.split("/")) for token in pairs.split()]
    words = [w for w, _ in read_counts([("jump", "VERB"), *split], COUNTING)]
    assert " ".join(words[1:]) == read


def test_a_count_form_with_untrained_words_is_not_used():
    from t2m.lexicon import read_counts

    pairs = [("two", "NUM"), ("time", "NOUN")]
    assert read_counts(pairs, {"two", "time"}) == pairs  # "twice" untrained: the next form
    assert read_counts([("twice", "ADV")], {"two", "time"}) == pairs
    assert read_counts([("twice", "ADV")], {"jump"}) == [("twice", "ADV")]  # none: as said


def test_an_imperative_is_read_in_the_third_person():
    from t2m.lexicon import read_imperative, read_prompt_tokens

    tokens = ["Jump/PROPN", "twice/ADV", "then/ADV", "clap/VERB", "your/PRON", "hand/NOUN"]
    read = read_prompt_tokens("", tokens, COUNTING | {"then", "hand"})
    assert read == ["a/DET", "person/NOUN", "Jump/PROPN", "twice/ADV", "then/ADV", "clap/VERB"] + [
        "their/PRON",
        "hand/NOUN",
    ]
    # a subject already there, or a caption that opens with "after": no subject added
    present = [("a", "DET"), ("person", "NOUN"), ("jump", "VERB")]
    assert read_imperative(present, COUNTING) == present
    after = [("after", "ADP"), ("jump", "VERB"), ("clap", "VERB")]
    assert read_imperative(after, COUNTING) == after
    # no trained subject words: nothing to add
    assert read_imperative([("jump", "VERB")], {"jump"}) == [("jump", "VERB")]
    # an opening motion verb the tagger took for an adverb, adjective or noun; "do" + a kick
    subject = [("a", "DET"), ("person", "NOUN")]
    for opening in (
        [("punch", "ADV"), ("use", "VERB")],  # "jab using your right arm": jab read as punch
        [("Lower", "ADJ"), ("to", "ADP")],
        [("Bow", "NOUN"), ("follow", "VERB")],
        [("Do", "AUX"), ("a", "DET"), ("front", "ADJ"), ("kick", "NOUN")],
    ):
        assert read_imperative(opening, COUNTING) == subject + opening
    # but not a noun that is no motion, nor "do" that is no imperative
    for other in ([("Left", "ADJ"), ("hand", "NOUN")], [("do", "AUX"), ("not", "PART")]):
        assert read_imperative(other, COUNTING) == other


def test_a_usual_count_keeps_its_tags():
    from t2m.lexicon import read_counts

    pairs = [("once", "SCONJ"), ("do", "VERB"), ("jump", "VERB")]  # "once done jumping, ..."
    assert read_counts(pairs, COUNTING) == pairs


def test_a_trained_word_is_read_in_context_only_when_the_deciding_word_is_untrained(caplog):
    trained = {"a", "person", "bend", "forward", "squat", "the", "leg"}
    pairs = [("bend", "VERB"), ("the", "DET"), ("knee", "NOUN")]
    with caplog.at_level(logging.WARNING, logger="t2m.lexicon"):
        read = read_untrained("bends the knees", pairs, trained)
    assert [w for w, _ in read] == ["squat", "the", "knee"]
    assert "'bend' read as 'squat' (the untrained 'knee' after it)" in caplog.text
    # "leg" was trained on: the model reads "bend the leg" itself
    pairs = [("bend", "VERB"), ("the", "DET"), ("leg", "NOUN")]
    assert read_untrained("", pairs, trained) == pairs
    assert read_untrained("", [("bend", "VERB"), ("forward", "ADV")], trained)[0][0] == "bend"


def test_two_word_phrases_are_read_as_trained_words():
    from t2m.lexicon import read_phrases

    trained = {"sidestep", "turn", "quarter", "half", "a", "circle", "walk", "in", "to"}
    read = read_phrases([("take", "VERB"), ("side", "NOUN"), ("step", "NOUN")], trained)
    assert read == [("take", "VERB"), ("sidestep", "NOUN")]
    for said in ("by a quarter circle", "by half a circle"):
        pairs = [(w, "NOUN") for w in said.split()]
        assert [w for w, _ in read_phrases(pairs, trained)][-1] == "turn"
    # a circle walked stays one; function words are never joined ("a round" is no "around")
    pairs = [("walk", "VERB"), ("in", "ADP"), ("a", "DET"), ("circle", "NOUN")]
    assert read_phrases(pairs, trained) == pairs
    pairs = [("a", "DET"), ("round", "ADJ")]
    assert read_phrases(pairs, trained | {"around"}) == pairs


def test_a_trained_noun_used_as_a_verb_and_an_untagged_gerund_are_read():
    trained = {"walk", "pace", "forward", "at", "a", "slow", "wave", "with", "both", "arm"}
    pairs = [("pace", "VERB"), ("forward", "ADV"), ("at", "ADP"), ("a", "DET")]
    pairs += [("slow", "ADJ"), ("pace", "NOUN")]
    read = [w for w, _ in read_untrained("", pairs, trained)]
    assert read == ["walk", "forward", "at", "a", "slow", "pace"]  # the noun stays
    pairs = [("greeting", "NOUN"), ("with", "ADP"), ("both", "DET"), ("arm", "NOUN")]
    assert read_untrained("", pairs, trained)[0] == ("wave", "NOUN")


def test_a_prompt_names_each_reading_once_and_only_unread_words_as_untrained(pipe, caplog):
    """The pipeline warns of what is still untrained after the reading (a read word is named
    by its reading only), and a quiet prepare (the command's check before the work prepares
    the same prompts again) logs nothing."""
    trained = pipe.training_words
    assert "walk" in trained and "stroll" not in trained and "zorbly" not in trained
    text = "a person strolls forward zorbly"
    with caplog.at_level(logging.WARNING):
        pipe.prepare([text], quiet=True)
    assert caplog.records == []
    with caplog.at_level(logging.WARNING):
        pipe.prepare([text])
    messages = [record.getMessage() for record in caplog.records]
    assert sum("read as 'walk'" in m for m in messages) == 1, messages
    untrained = [m for m in messages if "has words the model was not trained on" in m]
    assert len(untrained) == 1 and untrained[0].endswith(": zorbly"), messages


def test_the_article_an_is_named_as_an_article(caplog):
    trained = {"a", "person", "jump"}
    pairs = [("an", "DET"), ("individual", "NOUN"), ("jump", "VERB")]
    with caplog.at_level(logging.WARNING, logger="t2m.lexicon"):
        read = read_untrained("an individual jumps", pairs, trained)
    assert [w for w, _ in read] == ["a", "person", "jump"]
    assert "'an' was not trained on; read as 'a' (the article)" in caplog.text
