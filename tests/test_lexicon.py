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
        "guy": [0.0, 0.95, 0.2],  # near "jump" by the vectors (cosine 0.98)
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
        read = read_untrained("guy", [("guy", "NOUN")], TRAINED, TABLE, common=0)
    assert read == [("jump", "NOUN")]
    assert "nearest trained word in the word vectors, cosine 0.98" in caplog.text
    # a word among the table's most frequent (here its first 4 rows) is too general
    assert read_untrained("", [("guy", "NOUN")], TRAINED, TABLE, common=4) == [("guy", "NOUN")]
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
    from t2m.lexicon import read_untrained_tokens

    tokens = ["a/DET", "person/NOUN", "bounce/VERB", "twice/ADV"]
    assert read_untrained_tokens("", tokens, TRAINED, TABLE) == [
        "a/DET",
        "person/NOUN",
        "jump/VERB",
        "twice/ADV",
    ]
