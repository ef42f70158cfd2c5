"""Clause splitting and length sharing (t2m.clauses)."""

import numpy as np
import pytest

from t2m.clauses import (
    caption_count,
    clause_captions,
    clause_targets,
    repetition_count,
    share_snippets,
    split_clauses,
    standalone,
)


def tokens(tagged: str) -> list[str]:
    return tagged.split()


def words_of(tagged: str) -> list[str]:
    toks = tokens(tagged)
    return [" ".join(t.split("/")[0] for t in toks[r.start : r.stop]) for r in split_clauses(toks)]


@pytest.mark.parametrize(
    ("tagged", "expected"),
    [
        ("a/DET person/NOUN walk/VERB forward/ADV", ["a person walk forward"]),
        (
            "a/DET person/NOUN jump/VERB twice/ADV then/ADV wave/VERB",
            ["a person jump twice", "then wave"],
        ),
        (
            "a/DET man/NOUN kick/VERB and/CCONJ then/ADV sit/VERB down/ADP",
            ["a man kick", "and then sit down"],
        ),
        (
            "someone/PRON hop/VERB after/ADP that/DET run/VERB",
            ["someone hop", "after that run"],
        ),
        (
            "a/DET figure/NOUN bow/VERB before/ADP walk/VERB backward/ADV",
            ["a figure bow", "before walk backward"],
        ),
        (  # a leading "after" clause ends where the main clause's subject starts
            "after/ADP raise/VERB the/DET right/ADJ hand/NOUN up/ADP the/DET figure/NOUN "
            "take/VERB a/DET bow/NOUN",
            ["after raise the right hand up", "the figure take a bow"],
        ),
        (
            "after/ADP wave/VERB someone/PRON sit/VERB",
            ["after wave", "someone sit"],
        ),
        (  # "and" alone and "while" keep one clause: simultaneous or unclear
            "a/DET person/NOUN walk/VERB and/CCONJ wave/VERB while/SCONJ turn/VERB",
            ["a person walk and wave while turn"],
        ),
        (
            "a/DET person/NOUN squat/VERB then/ADV jump/VERB and/CCONJ then/ADV kick/VERB "
            "after/ADP that/DET bow/VERB",
            ["a person squat", "then jump", "and then kick", "after that bow"],
        ),
        ("then/ADV walk/VERB", ["then walk"]),
    ],
)
def test_split_clauses(tagged, expected):
    assert words_of(tagged) == expected


def test_split_clauses_covers_every_token_once():
    toks = tokens("a/DET person/NOUN run/VERB then/ADV then/ADV stop/VERB")
    ranges = split_clauses(toks)
    assert [i for r in ranges for i in r] == list(range(len(toks)))
    assert all(len(r) > 0 for r in ranges)
    assert split_clauses([]) == [range(0, 0)]


def test_share_snippets_proportional_with_a_floor():
    assert share_snippets(40, [1.0, 3.0]) == [10, 30]
    assert sum(share_snippets(49, [1.0, 1.0, 1.0])) == 49
    # a clause expected to be tiny still gets the floor (5 snippets = 1 s)
    assert share_snippets(40, [0.01, 1.0]) == [5, 35]
    # too short for the floor: as even as it gets, never zero
    assert share_snippets(6, [1.0, 100.0, 1.0]) == [2, 2, 2]
    assert share_snippets(3, [1.0, 1.0, 1.0]) == [1, 1, 1]
    with pytest.raises(ValueError):
        share_snippets(2, [1.0, 1.0, 1.0])


@pytest.mark.parametrize(
    ("clause", "expected"),
    [
        ("then/ADV wave/VERB", "a person wave"),
        ("and/CCONJ then/ADV sit/VERB down/ADP", "a person sit down"),
        ("after/ADP that/DET bow/VERB", "a person bow"),
        ("before/ADP walk/VERB backward/ADV", "a person walk backward"),
        ("after/ADP raise/VERB the/DET hand/NOUN", "a person raise the hand"),
        ("the/DET figure/NOUN take/VERB a/DET bow/NOUN", "the figure take a bow"),
        ("someone/PRON hop/VERB", "someone hop"),
        ("a/DET man/NOUN kick/VERB", "a man kick"),
    ],
)
def test_standalone(clause, expected):
    assert " ".join(t.split("/")[0] for t in standalone(tokens(clause))) == expected


def test_clause_captions():
    one = tokens("a/DET person/NOUN walk/VERB and/CCONJ wave/VERB")
    assert clause_captions(one) == [one]
    two = clause_captions(tokens("a/DET woman/NOUN jump/VERB twice/ADV then/ADV clap/VERB"))
    assert two == [
        tokens("a/DET woman/NOUN jump/VERB twice/ADV"),
        tokens("a/DET person/NOUN clap/VERB"),
    ]


@pytest.mark.parametrize(
    ("tagged", "expected"),
    [
        (  # elliptic parts join the clause before them
            "a/DET person/NOUN walk/VERB forward/ADV then/ADV back/ADV",
            ["a person walk forward then back"],
        ),
        (
            "someone/PRON raise/VERB the/DET arm/NOUN then/ADV down/ADP then/ADV clap/NOUN",
            ["someone raise the arm then down", "then clap"],
        ),
        (  # a motion verb the tagger called a noun still makes a clause
            "a/DET human/NOUN hop/VERB twice/ADV then/ADV wave/NOUN with/ADP both/DET hand/NOUN",
            ["a human hop twice", "then wave with both hand"],
        ),
        ("then/ADV quickly/ADV", ["then quickly"]),
    ],
)
def test_parts_without_a_verb_are_no_clauses(tagged, expected):
    assert words_of(tagged) == expected


@pytest.mark.parametrize(
    ("tagged", "count"),
    [
        ("a/DET person/NOUN clap/VERB six/NUM time/NOUN", 6),
        ("someone/PRON jump/VERB up/ADP and/CCONJ down/ADP twice/ADV", 2),
        ("a/DET man/NOUN squat/VERB once/ADV", 1),
        ("a/DET woman/NOUN do/VERB three/NUM squat/NOUN", 3),
        ("a/DET person/NOUN hop/VERB 3/NUM time/NOUN", 3),
        ("a/DET person/NOUN take/VERB four/NUM step/NOUN forward/ADV", 4),
        ("someone/PRON throw/VERB two/NUM right/ADJ punch/NOUN", 2),
        ("someone/PRON throw/VERB one/NUM left/ADJ punch/NOUN", 1),
        ("a/DET person/NOUN take/VERB one/NUM step/NOUN back/ADV", 1),
        # no count: one of something, an angle, a number that counts nothing
        ("someone/PRON bounce/VERB on/ADP one/NUM left/ADJ foot/NOUN", 0),
        ("a/DET person/NOUN turn/VERB 90/NUM degree/NOUN", 0),
        ("a/DET person/NOUN wave/VERB with/ADP one/NUM hand/NOUN", 0),
        ("a/DET person/NOUN walk/VERB forward/ADV", 0),
        ("", 0),
    ],
)
def test_repetition_count(tagged, count):
    assert repetition_count(tokens(tagged)) == count


def test_caption_count_belongs_to_captions_of_one_clause():
    both = tokens("a/DET person/NOUN clap/VERB five/NUM time/NOUN then/ADV hop/VERB twice/ADV")
    assert caption_count(both) == 0  # each clause has its own: 5, then 2
    assert [caption_count(c) for c in clause_captions(both)] == [5, 2]
    assert caption_count(tokens("a/DET person/NOUN clap/VERB five/NUM time/NOUN")) == 5


def test_clause_targets_give_the_difference_to_the_uncertain_clauses():
    # 30 snippets for clauses of 10 +- 1 and 10 +- 3: the second takes 9 / 10 of the 10 extra
    np.testing.assert_allclose(clause_targets(30, [10, 10], [1, 9]), [11, 19])
    # equal spreads: equal parts of the difference, here a shortfall
    np.testing.assert_allclose(clause_targets(16, [12, 8], [4, 4]), [10, 6])
    # far too short a total: targets stay positive (share_snippets rescales them)
    targets = clause_targets(6, [5, 20], [1, 1])
    assert targets.min() > 0
    assert share_snippets(6, targets, minimum=2) == [2, 4]


def test_a_counted_clause_keeps_what_its_count_needs_while_another_can_give():
    # "walks quickly, then claps six times": 30 snippets for means 18.3 and 17.8 (variances 13.5
    # and 9.4) gave the claps 15 by the variance shares alone; counted, they get their 18
    means, variances = [18.3, 17.8], [13.5, 9.4]
    assert round(clause_targets(30, means, variances)[1]) == 15
    counted = clause_targets(30, means, variances, counted=[False, True])
    np.testing.assert_allclose(counted, [12, 18])
    assert share_snippets(30, counted) == [12, 18]
    # a surplus goes to the clause without a count too
    np.testing.assert_allclose(clause_targets(40, means, variances, [False, True]), [22, 18])
    # every clause counted (or none): the variance shares as before
    for flags in ([True, True], [False, False]):
        np.testing.assert_allclose(
            clause_targets(30, means, variances, flags), clause_targets(30, means, variances)
        )
    with pytest.raises(ValueError, match="3 counted flags for 2 clauses"):
        clause_targets(30, means, variances, [True, False, False])
