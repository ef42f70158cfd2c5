"""The count and clause parser reads the ways people write a prompt (t2m.clauses on tagged text).

Each row is a prompt as a user might type it, tagged as prompts are
(:func:`dataset_tools.texts.tag_prompts`), and the repetition count each of its clauses names
(0: none). The number of entries is the number of clauses the clause plan generates.
"""

import pytest

from t2m.clauses import clause_captions, repetition_count

pytest.importorskip("spacy")

PHRASINGS: list[tuple[str, list[int]]] = [
    # counts as words, digits and idioms
    ("a person jumps twice", [2]),
    ("a person jumps two times", [2]),
    ("a person jumps 2 times", [2]),
    ("a person jumps 2x", [2]),
    ("a person jumps x2", [2]),
    ("a person jumps a couple of times", [2]),
    ("someone hops thrice", [3]),
    ("someone hops three times", [3]),
    ("someone hops 3 times", [3]),
    ("someone hops 3x", [3]),
    ("someone hops 3X on the left foot", [3]),
    ("someone hops three times in a row", [3]),
    ("the man claps once", [1]),
    ("the man claps one time", [1]),
    ("the man claps a single time", [1]),
    ("the man claps one more time", [1]),
    ("a woman claps five times", [5]),
    ("a woman claps 5 times", [5]),
    ("a woman claps 5x", [5]),
    ("a woman claps her hands six times", [6]),
    ("a woman claps 6 times with both hands", [6]),
    ("a figure squats four times", [4]),
    ("a figure does four squats", [4]),
    ("a figure does 4 squats", [4]),
    ("a figure does three deep squats", [3]),
    ("a figure does a couple of squats", [2]),
    ("a figure does a pair of jumps", [2]),
    ("the person throws two left punches", [2]),
    ("the person throws 2 left punches", [2]),
    ("the person throws one right punch", [1]),
    ("the person punches with the right fist three times", [3]),
    ("the person punches with the right fist 3 times", [3]),
    ("the person punches twice with the left hand", [2]),
    ("a human jumps forward seven times", [7]),
    ("a human jumps forward eight separate times", [8]),
    ("a human jumps up and down two times", [2]),
    ("a human jumps up and down twice over", [2]),
    ("somebody kicks 2 times with the left leg", [2]),
    ("somebody takes four steps forward", [4]),
    ("somebody takes one step back", [1]),
    # no count: one of something, an angle, a number that counts nothing
    ("a person walks forward", [0]),
    ("a person hops on one foot", [0]),
    ("a person turns 90 degrees to the left", [0]),
    ("a person turns ninety degrees to the right", [0]),
    ("a person makes a 180 degree turn", [0]),
    ("a person waves with one hand", [0]),
    ("a person stands still", [0]),
    ("a person raises both hands", [0]),
    ("someone sits down and stands back up", [0]),
    ("a man bows", [0]),
    # sentence shapes: imperative, progressive, no article, pronouns
    ("jump twice", [2]),
    ("Jump 2 times.", [2]),
    ("clap three times", [3]),
    ("walk forward then wave with the left hand", [0, 0]),
    ("Walk forward, then wave.", [0, 0]),
    ("walk forward and then jump twice", [0, 2]),
    ("squat 3x, then jump once", [3, 1]),
    ("hop on the left foot two times, then clap a couple of times", [2, 2]),
    ("person is jumping three times", [3]),
    ("the person is walking forward and then waving", [0, 0]),
    ("a person is clapping 4 times then bowing", [4, 0]),
    ("he jumps twice then waves", [2, 0]),
    ("she claps five times, then bows", [5, 0]),
    ("they walk backward then jump 2x", [0, 2]),
    ("person walks forward then turns around", [0, 0]),
    # joiners
    ("a person jumps twice, then waves", [2, 0]),
    ("a person jumps twice and then waves", [2, 0]),
    ("a person jumps twice, after that waves", [2, 0]),
    ("a person jumps twice and after that waves", [2, 0]),
    ("a person jumps twice, afterwards waves", [2, 0]),
    ("a person jumps twice, and afterwards waves", [2, 0]),
    ("a person jumps twice, subsequently waves", [2, 0]),
    ("a person jumps twice, next waves", [2, 0]),
    ("a person jumps twice, finally waves", [2, 0]),
    ("a person jumps twice. Then the person waves.", [2, 0]),
    ("a person jumps twice; then waves", [2, 0]),
    ("a person jumps twice before waving", [2, 0]),
    ("a person jumps twice prior to waving", [2, 0]),
    ("a person jumps twice followed by waving", [2, 0]),
    ("a person jumps twice, after which they wave", [2, 0]),
    ("after jumping twice, a person waves", [2, 0]),
    ("after jumping two times, someone claps three times", [2, 3]),
    ("after walking forward, the figure bows", [0, 0]),
    ("After waving, she sits down", [0, 0]),
    ("once done walking forward, the subject waves", [0, 0]),
    ("after walking forward, wave", [0, 0]),
    ("once done jumping 3 times, sit down", [3, 0]),
    ("after doing two squats, a human walks backwards quickly", [2, 0]),
    ("after doing a front kick with the right leg, the figure waves", [0, 0]),
    ("a person walks forward, then turns left, then jumps twice", [0, 0, 2]),
    ("walk forward, then turn, then clap 3x", [0, 0, 3]),
    ("a person squats twice then jumps and then kicks after that bows", [2, 0, 0, 0]),
    ("a man claps five times then hops twice", [5, 2]),
    ("a man claps 5 times then hops 2 times", [5, 2]),
    ("a man claps five times, then hops on the left foot a couple of times", [5, 2]),
    # "and" alone and "while" keep one clause (simultaneous or unclear)
    ("a person walks and waves", [0]),
    ("a person walks forward while waving the right hand", [0]),
    ("someone jumps up and down three times", [3]),
    # parts without an action join the clause before them
    ("a person walks forward, then back", [0]),
    ("a person walks forward then back twice", [2]),
    # sides and directions in several forms do not disturb the parse
    ("a person waves his left hand twice", [2]),
    ("a person waves the left arm two times", [2]),
    ("a person kicks with the left, then with the right", [0]),
    ("a person walks leftward then jumps 2x", [0, 2]),
    ("a person walks to the left side then claps thrice", [0, 3]),
    ("a person sidesteps to the right 3 times", [3]),
    # casing and typos as found in HumanML3D's texts
    ("A PERSON JUMPS TWICE", [2]),
    ("A person jumps Twice", [2]),
    ("a persn jumps two times", [2]),
    ("a person walks foward then claps 3 times", [0, 3]),
    ("a person  jumps   twice", [2]),
    # words the model may never have trained on still parse
    ("a person dashes ahead, then bounces up and down 3 times", [0, 3]),
    ("someone ducks down twice", [2]),
    ("someone ducks down two times, then applauds a couple of times", [2, 2]),
    ("the subject paces forward, and afterwards leaps 2x", [0, 2]),
]


# Captions as the dataset builder tags them (case kept: a capitalised imperative may come out a
# noun), from the demo corpus's paraphrase pool.
AS_BUILT: list[tuple[str, list[int]]] = [
    ("Signal hello with the right arm before bouncing on one left foot three times in a row.", [0, 3]),
    ("Once done signalling hello with the right arm, bounce on one left foot 3x.", [0, 3]),
    ("After bouncing on one right foot 4x, pivot to the left by half a circle.", [4, 0]),
    ("Once done kicking with the right foot, a person walks straight ahead slowly.", [0, 0]),
    ("once done greeting with a left-handed wave, he bounces up and down two times.", [0, 2]),
    ("Duck down and come back up a couple of times.", [2]),
    ("Once done jabbing using the right arm a single time, stay motionless.", [1, 0]),
    ("The subject paces forward, subsequently applauds 2x.", [0, 2]),
    ("Once done jabbing using your right arm thrice, scurry backward quickly.", [3, 0]),
]  # fmt: skip


@pytest.mark.parametrize(("text", "counts"), AS_BUILT, ids=[t for t, _ in AS_BUILT])
def test_parser_reads_captions_tagged_as_built(text, counts):
    from dataset_tools.texts import tag_captions

    (pairs,) = tag_captions([text])
    tokens = [f"{word}/{pos}" for word, pos in pairs]
    assert [repetition_count(clause) for clause in clause_captions(tokens)] == counts


@pytest.fixture(scope="module")
def parsed() -> dict[str, list[int]]:
    """Every phrasing's clause counts, tagged in one batch (one spaCy pass)."""
    from dataset_tools.texts import tag_prompts

    texts = [text for text, _ in PHRASINGS]
    out = {}
    for text, pairs in zip(texts, tag_prompts(texts), strict=True):
        tokens = [f"{word}/{pos}" for word, pos in pairs]
        out[text] = [repetition_count(clause) for clause in clause_captions(tokens)]
    return out


def test_the_reading_of_prompts_keeps_every_clause_and_count():
    """Read in the wording the model trained on (:func:`t2m.lexicon.read_prompt`: counts in
    their usual wording, an imperative in the third person, "jabbing" read as "punch"), every
    phrasing still gives its clauses and counts."""
    from dataset_tools.texts import tag_captions, tag_prompts
    from t2m.lexicon import read_prompt

    texts = [text for text, _ in PHRASINGS + AS_BUILT]
    tagged = tag_prompts([t for t, _ in PHRASINGS]) + tag_captions([t for t, _ in AS_BUILT])
    trained = {word.lower() for pairs in tagged for word, _ in pairs}
    trained |= {"a", "person", "their", "once", "twice", "punch"}
    trained -= {"jab", "jabbing", "your"}
    for text, pairs, (_, counts) in zip(texts, tagged, PHRASINGS + AS_BUILT, strict=True):
        read = read_prompt(text, pairs, trained)
        tokens = [f"{word}/{pos}" for word, pos in read]
        assert [repetition_count(c) for c in clause_captions(tokens)] == counts, (text, tokens)


def test_the_table_is_large_and_distinct():
    texts = [text for text, _ in PHRASINGS]
    assert len(texts) >= 100 and len(set(texts)) == len(texts)


@pytest.mark.parametrize(("text", "counts"), PHRASINGS, ids=[t for t, _ in PHRASINGS])
def test_parser_reads_the_phrasing(parsed, text, counts):
    assert parsed[text] == counts


@pytest.mark.parametrize(
    ("text", "spelled"),
    [
        ("jumps 2x", "jumps two times"),
        ("jumps x3.", "jumps three times."),
        ("Claps 4 X", "Claps four times"),
        ("hops 12 times", "hops twelve times"),
        ("turns 90 degrees", "turns 90 degrees"),  # above twenty: left as digits
        ("a 4x4 grid", "a 4x4 grid"),
        ("box max2", "box max2"),
    ],
)
def test_small_numbers_are_spelled_out_before_tagging(text, spelled):
    from dataset_tools.texts import spell_counts

    assert spell_counts(text) == spelled
