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
"""

from __future__ import annotations

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
