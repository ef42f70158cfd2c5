"""Captions for synthetic clips in the words people use, with phrasing families held out.

A caption varies as human annotators' do, along six dimensions: the subject ("a person", "a
woman", "someone", "he", ...), the verb phrase of each action (synonyms, sides in several forms:
"the left hand", "with the left", "to the left side"), the speed adverb, the count ("once",
"twice", "three times", "3 times", "thrice", "one time"), the joiner of two actions (", then",
" and then", ", after that", " before", a leading "after") and the sentence shape (present "a
person walks", progressive "a person is walking"); a few captions keep a typo or lose their full
stop, as HumanML3D's texts do.

Each dimension also has held-out families that no training caption uses: subjects ("an
individual", "the subject"), verbs ("strolls", "paces", "dashes", "bounces", "ducks down", ...),
sides ("leftward"), counts ("two times", "2 times", "2x", "a couple of times", "3x"), joiners
(", and afterwards", ", subsequently", " prior to", " followed by") and the imperative shape
("walk forward, then wave"). A ``pool`` picks the wording of a caption: ``"train"`` only the
training families, ``"heldout"`` only the held-out ones, ``"paraphrase"`` each dimension from
either at random with at least one of the subject, verb and shape held out (the paraphrase test split: wording a user might
type that no stage trained on).

Every template exists in two forms, third-person present ("walks forward") and gerund ("walking
forward"), so that order words can join them ("..., then waves", "... before waving", "after
walking forward, ..."); the imperative is the present form's base ("walk forward").

Side and turning words are "left"/"right" (alone or as "leftward") and "clockwise"/
"counterclockwise"/"anticlockwise", which the builder's caption mirroring swaps.
"""

from __future__ import annotations

import re

import numpy as np

Pool = dict[str, list[tuple[str, str]]]

POOLS = ("train", "heldout", "paraphrase")
DIMENSIONS = ("subject", "verb", "speed", "count", "joiner", "shape")
"""What a caption's wording is drawn from, each dimension from the training or held-out pool."""
ALWAYS_SHOWN = ("subject", "verb", "shape")
"""The dimensions every caption shows (the others may be absent: no speed, a single action)."""

SUBJECTS = {
    "train": ["a person", "someone", "a man", "a woman", "the person", "a figure", "the figure",
              "somebody", "a human", "he", "she", "person"],
    "heldout": ["an individual", "the subject", "a character", "the man"],
}  # fmt: skip

_NUMBER_WORDS = {
    1: "one",
    2: "two",
    3: "three",
    4: "four",
    5: "five",
    6: "six",
    7: "seven",
    8: "eight",
}

# Counts of repetitions, " {word}" after the verb phrase. Held out: "two times" in any spelling
# ("2 times", "2x", "a couple of times") and "Nx"; trained: "twice", "N times" in words or digits.
_COUNTS = {
    "train": {1: [" once", " one time"], 2: [" twice"], 3: [" three times", " 3 times", " thrice"],
              "n": [" {word} times", " {digit} times"]},
    "heldout": {1: [" a single time"], 2: [" two times", " 2 times", " 2x", " a couple of times"],
                "n": [" {digit}x", " {word} times in a row"]},
}  # fmt: skip

_SPEED = {
    "train": {"slow": [" slowly", " at a slow pace"], "normal": ["", " at a normal pace", " steadily"],
              "fast": [" quickly", " fast", " at a fast pace"]},
    "heldout": {"slow": [" unhurriedly", " at a leisurely speed"], "normal": [" at an ordinary speed"],
                "fast": [" rapidly", " at high speed"]},
}  # fmt: skip

_CIRCLE_WORD = {
    "clockwise": ["clockwise"],
    "counterclockwise": ["counterclockwise", "anticlockwise"],
}
_CIRCLE_TURN = {"clockwise": "right", "counterclockwise": "left"}

# (present, gerund) templates per action and pool. Placeholders: {speed} adverb, {side} left/right,
# {cw} clockwise word, {turnside} the side a circle turns to, {count} " twice", {n} number word,
# {angle} / {turn_noun} turn size as an adverb ("90 degrees") or a noun ("a quarter turn").
_TEMPLATES: dict[str, dict[str, list[tuple[str, str]]]] = {
    "walk_forward": {
        "train": [("walks forward{speed}", "walking forward{speed}"),
                  ("walks straight ahead{speed}", "walking straight ahead{speed}"),
                  ("walks{speed} in a straight line", "walking{speed} in a straight line"),
                  ("goes forward on foot{speed}", "going forward on foot{speed}")],
        "heldout": [("moves ahead on foot{speed}", "moving ahead on foot{speed}"),
                    ("paces forward{speed}", "pacing forward{speed}"),
                    ("strolls forward{speed}", "strolling forward{speed}")],
    },
    "walk_backward": {
        "train": [("walks backward{speed}", "walking backward{speed}"),
                  ("walks backwards{speed}", "walking backwards{speed}"),
                  ("steps backward{speed}", "stepping backward{speed}")],
        "heldout": [("retreats on foot{speed}", "retreating on foot{speed}"),
                    ("moves backward step by step{speed}", "moving backward step by step{speed}")],
    },
    "walk_side": {
        "train": [("walks sideways to the {side}{speed}", "walking sideways to the {side}{speed}"),
                  ("sidesteps to the {side}{speed}", "sidestepping to the {side}{speed}"),
                  ("steps sideways to their {side}{speed}", "stepping sideways to their {side}{speed}"),
                  ("walks to the {side} side{speed}", "walking to the {side} side{speed}")],
        "heldout": [("takes side steps toward the {side}{speed}", "taking side steps toward the {side}{speed}"),
                    ("moves {side}ward{speed}", "moving {side}ward{speed}"),
                    ("moves laterally toward the {side}{speed}", "moving laterally toward the {side}{speed}")],
    },
    "walk_circle": {
        "train": [("walks in a {cw} circle{speed}", "walking in a {cw} circle{speed}"),
                  ("walks {cw} in a circle{speed}", "walking {cw} in a circle{speed}"),
                  ("walks in a circle turning {turnside}{speed}", "walking in a circle turning {turnside}{speed}")],
        "heldout": [("circles around {cw}{speed}", "circling around {cw}{speed}"),
                    ("follows a round path to the {turnside}{speed}", "following a round path to the {turnside}{speed}")],
    },
    "run_forward": {
        "train": [("runs forward{speed}", "running forward{speed}"), ("jogs forward{speed}", "jogging forward{speed}"),
                  ("runs straight ahead{speed}", "running straight ahead{speed}")],
        "heldout": [("dashes ahead{speed}", "dashing ahead{speed}"), ("races forward{speed}", "racing forward{speed}")],
    },
    "run_backward": {
        "train": [("runs backward{speed}", "running backward{speed}"), ("jogs backwards{speed}", "jogging backwards{speed}")],
        "heldout": [("scurries backward{speed}", "scurrying backward{speed}")],
    },
    "run_side": {
        "train": [("runs sideways to the {side}{speed}", "running sideways to the {side}{speed}"),
                  ("shuffles quickly to the {side}", "shuffling quickly to the {side}")],
        "heldout": [("side-shuffles toward the {side}{speed}", "side-shuffling toward the {side}{speed}")],
    },
    "run_circle": {
        "train": [("runs in a {cw} circle{speed}", "running in a {cw} circle{speed}"),
                  ("jogs {cw} in a circle{speed}", "jogging {cw} in a circle{speed}"),
                  ("runs in a circle turning {turnside}{speed}", "running in a circle turning {turnside}{speed}")],
        "heldout": [("races around {cw}{speed}", "racing around {cw}{speed}")],
    },
    "turn": {
        "train": [("makes {turn_noun} to the {side}", "making {turn_noun} to the {side}"),
                  ("turns {side} {angle}", "turning {side} {angle}"),
                  ("turns {angle} to the {side}", "turning {angle} to the {side}")],
        "heldout": [("rotates toward the {side} {angle}", "rotating toward the {side} {angle}"),
                    ("pivots to the {side} {angle}", "pivoting to the {side} {angle}")],
    },
    "jump_in_place": {
        "train": [("jumps in place{count}", "jumping in place{count}"), ("jumps up and down{count}", "jumping up and down{count}"),
                  ("jumps straight up{count}", "jumping straight up{count}")],
        "heldout": [("springs up on the spot{count}", "springing up on the spot{count}"),
                    ("bounces up and down{count}", "bouncing up and down{count}")],
    },
    "jump_forward": {
        "train": [("jumps forward{count}", "jumping forward{count}"), ("leaps forward{count}", "leaping forward{count}"),
                  ("jumps ahead with both feet{count}", "jumping ahead with both feet{count}")],
        "heldout": [("bounds forward{count}", "bounding forward{count}")],
    },
    "hop": {
        "train": [("hops on the {side} foot{count}", "hopping on the {side} foot{count}"),
                  ("hops on their {side} leg{count}", "hopping on their {side} leg{count}")],
        "heldout": [("bounces on one {side} foot{count}", "bouncing on one {side} foot{count}")],
    },
    "wave": {
        "train": [("waves with the {side} hand", "waving with the {side} hand"), ("waves their {side} hand", "waving their {side} hand"),
                  ("waves with the {side}", "waving with the {side}"), ("waves the {side} arm", "waving the {side} arm"),
                  ("raises the {side} hand and waves", "raising the {side} hand and waving")],
        "heldout": [("greets with a {side}-handed wave", "greeting with a {side}-handed wave"),
                    ("signals hello with the {side} arm", "signalling hello with the {side} arm")],
    },
    "wave_both": {
        "train": [("waves with both hands", "waving with both hands"), ("waves both arms", "waving both arms")],
        "heldout": [("greets with both arms swinging overhead", "greeting with both arms swinging overhead")],
    },
    "raise": {
        "train": [("raises the {side} hand", "raising the {side} hand"), ("lifts the {side} arm up", "lifting the {side} arm up"),
                  ("raises their {side} arm above the head", "raising their {side} arm above the head")],
        "heldout": [("reaches up high with the {side} arm", "reaching up high with the {side} arm")],
    },
    "raise_both": {
        "train": [("raises both hands", "raising both hands"), ("lifts both arms above the head", "lifting both arms above the head"),
                  ("puts both hands up", "putting both hands up")],
        "heldout": [("reaches skyward with both arms", "reaching skyward with both arms")],
    },
    "kick": {
        "train": [("kicks with the {side} leg", "kicking with the {side} leg"), ("kicks with the {side} foot", "kicking with the {side} foot"),
                  ("kicks with their {side}", "kicking with their {side}"),
                  ("does a front kick with the {side} leg", "doing a front kick with the {side} leg")],
        "heldout": [("strikes forward using the {side} foot", "striking forward using the {side} foot")],
    },
    "punch": {
        "train": [("punches with the {side} fist{count}", "punching with the {side} fist{count}"),
                  ("punches forward with the {side} hand{count}", "punching forward with the {side} hand{count}"),
                  ("throws {n} {side} {punches}", "throwing {n} {side} {punches}")],
        "heldout": [("jabs using the {side} arm{count}", "jabbing using the {side} arm{count}")],
    },
    "squat": {
        "train": [("squats{count}", "squatting{count}"), ("does {n} {squats}", "doing {n} {squats}"),
                  ("squats down and stands back up{count}", "squatting down and standing back up{count}")],
        "heldout": [("bends the knees deeply{count}", "bending the knees deeply{count}"),
                    ("ducks down and comes back up{count}", "ducking down and coming back up{count}")],
    },
    "sit": {
        "train": [("sits down on the ground and stands back up", "sitting down on the ground and standing back up"),
                  ("sits on the floor for a moment and gets up", "sitting on the floor for a moment and getting up"),
                  ("lowers to the ground, sits a moment and stands up", "lowering to the ground, sitting a moment and standing up")],
        "heldout": [("takes a seat on the floor and rises again", "taking a seat on the floor and rising again")],
    },
    "bow": {
        "train": [("bows", "bowing"), ("bows forward", "bowing forward"), ("takes a bow", "taking a bow"),
                  ("bends forward at the waist", "bending forward at the waist")],
        "heldout": [("leans the upper body down politely", "leaning the upper body down politely")],
    },
    "clap": {
        "train": [("claps{count}", "clapping{count}"), ("claps the hands{count}", "clapping the hands{count}"),
                  ("claps the hands together{count}", "clapping the hands together{count}")],
        "heldout": [("applauds{count}", "applauding{count}")],
    },
    "stand": {
        "train": [("stands still", "standing still"), ("stands in place", "standing in place"),
                  ("remains standing", "remaining standing")],
        "heldout": [("stays motionless", "staying motionless"), ("idles on the spot", "idling on the spot")],
    },
}  # fmt: skip
_ANGLES = {
    "train": {90: ["90 degrees", "ninety degrees"], 180: ["180 degrees", "around"]},
    "heldout": {90: ["by a quarter circle"], 180: ["by half a circle"]},
}
_TURN_NOUNS = {
    90: ["a quarter turn", "a 90 degree turn"],
    180: ["a half turn", "a 180 degree turn"],
}

# Joining two clauses: (kind, text). "then": "<A><text> <B present>"; "before": "<A> before <B
# gerund>"; "after": "after <A gerund>, <subject> <B present>".
_JOINERS = {
    "train": [("then", ", then"), ("then", " and then"), ("then", ", after that"), ("then", " then"),
              ("before", " before"), ("after", "after")],
    "heldout": [("then", ", and afterwards"), ("then", ", subsequently"), ("before", " prior to"),
                ("before", " followed by"), ("after", "once done")],
}  # fmt: skip

# Sentence shapes: third-person present, progressive ("is walking"), imperative ("walk").
# "base" (the plain present) is no family of its own: the held-out pool uses it beside the
# imperative so that its held-out subjects appear.
_SHAPES = {"train": ["present", "present", "progressive"], "heldout": ["imperative"],
           "base": ["present"]}  # fmt: skip

# Possessives: "their {side} leg" and, now and then, "the {side} hand" say the subject's own
# ("his left hand", "her right arm"), as annotators write them; an imperative says "your".
_POSSESSIVE = {"he": "his", "a man": "his", "the man": "his", "she": "her", "a woman": "her"}
_NEUTRAL_POSSESSIVES = ["their", "his", "her"]
OWN_SIDE_RATE = 0.3


def _possessive(text: str, owner: str, rng: np.random.Generator) -> str:
    """``text`` with "their" as ``owner`` and, at :data:`OWN_SIDE_RATE`, "the left|right" as
    ``owner`` left|right."""
    if rng.uniform() < OWN_SIDE_RATE:
        text = re.sub(r"\bthe (left|right)\b", rf"{owner} \1", text)
    return re.sub(r"\btheir\b", owner, text)


# Misspellings found in HumanML3D's texts; a few training captions carry one.
_TYPOS = {"forward": "foward", "person": "persn", "slowly": "slowy", "backward": "backwords",
          "quickly": "quikly", "circle": "cirlce", "straight": "stright"}  # fmt: skip
TYPO_RATE = 0.03
NO_STOP_RATE = 0.05


def _pick(rng: np.random.Generator, options: list):
    return options[int(rng.integers(len(options)))]


def _template_key(action: str, params: dict) -> str:
    if action in ("walk", "run"):
        direction = params["direction"]
        kind = {
            "left": "side",
            "right": "side",
            "clockwise": "circle",
            "counterclockwise": "circle",
        }.get(direction, direction)
        return f"{action}_{kind}"
    if action == "jump":
        return "jump_forward" if params.get("mode") == "forward" else "jump_in_place"
    if action in ("wave", "raise") and params.get("side") == "both":
        return f"{action}_both"
    return action


def count_phrase(count: int, rng: np.random.Generator, pool: str = "train") -> str:
    """`` twice``, `` 3 times``, `` a couple of times``, ...: ``count`` repetitions in a wording
    of ``pool`` ("train" or "heldout"), with its leading space."""
    forms = _COUNTS[pool]
    options = forms.get(count, forms["n"])
    word = _NUMBER_WORDS.get(count, str(count))
    return _pick(rng, options).format(word=word, digit=count)


def phrase(
    action: str, params: dict, rng: np.random.Generator, pool: str | dict[str, str] = "train"
) -> tuple[str, str]:
    """(present, gerund) verb phrases describing one action with its parameters; ``pool`` is
    "train", "heldout" or a pool per dimension (:data:`DIMENSIONS`)."""
    pools = _dimension_pools(pool)
    present, gerund = _pick(rng, _TEMPLATES[_template_key(action, params)][pools["verb"]])
    count = params.get("count", 1)
    direction = params.get("direction", "")
    values = {
        "speed": _pick(rng, _SPEED[pools["speed"]][params["speed"]]) if "speed" in params else "",
        "side": params.get("side", direction),
        "cw": _pick(rng, _CIRCLE_WORD.get(direction, [""])),
        "turnside": _CIRCLE_TURN.get(direction, ""),
        "count": ""
        if count == 1 and rng.uniform() < 0.5
        else count_phrase(count, rng, pools["count"]),
        "n": _NUMBER_WORDS.get(count, str(count)),
        "punches": "punch" if count == 1 else "punches",
        "squats": "squat" if count == 1 else "squats",
        "angle": _pick(rng, _ANGLES[pools["verb"]][params["angle"]]) if action == "turn" else "",
        "turn_noun": _pick(rng, _TURN_NOUNS[params["angle"]]) if action == "turn" else "",
    }
    if action == "jump" and count > 1 and not values["count"]:
        values["count"] = count_phrase(count, rng, pools["count"])
    return present.format(**values), gerund.format(**values)


_IRREGULAR_BASE = {"does": "do", "goes": "go", "is": "be", "has": "have"}


def base_form(present: str) -> str:
    """A present verb phrase in the imperative: the first word and each verb after "and",
    "then" or a comma lose their third-person ending ("raises the hand and waves" -> "raise the
    hand and wave", "does two squats" -> "do two squats")."""
    words = present.split(" ")
    for i, word in enumerate(words):
        if i and not (words[i - 1] in ("and", "then") or words[i - 1].endswith(",")):
            continue
        bare = word.rstrip(",")
        if bare in _IRREGULAR_BASE:
            base = _IRREGULAR_BASE[bare]
        elif bare.endswith("ies") and len(bare) > 4:
            base = bare[:-3] + "y"
        elif bare.endswith(("sses", "shes", "ches", "xes", "zes")):
            base = bare[:-2]
        elif bare.endswith("s") and not bare.endswith("ss"):
            base = bare[:-1]
        else:
            base = bare
        words[i] = base + word[len(bare) :]
    return " ".join(words)


def _dimension_pools(pool: str | dict[str, str], rng: np.random.Generator | None = None) -> dict:
    """Each dimension's pool: all "train", all "heldout" (the shape imperative or plain
    present), or (``"paraphrase"``, drawn with ``rng``) each at random with at least one held
    out."""
    if isinstance(pool, dict):
        return pool
    if pool not in POOLS:
        raise ValueError(f"unknown caption pool {pool!r}; use one of {', '.join(POOLS)}")
    if pool == "train":
        return dict.fromkeys(DIMENSIONS, pool)
    if pool == "heldout":
        shape = "heldout" if rng is None or rng.uniform() < 0.5 else "base"
        return {**dict.fromkeys(DIMENSIONS, pool), "shape": shape}
    if rng is None:
        raise ValueError("the paraphrase pool draws its dimensions: give rng")
    drawn = {d: "heldout" if rng.uniform() < 0.5 else "train" for d in DIMENSIONS}
    # Speed, count and joiner are absent from some captions (no speed, a single action): one of
    # the dimensions every caption shows is held out, so no paraphrase is a training caption.
    if all(drawn[d] == "train" for d in ALWAYS_SHOWN):
        drawn[_pick(rng, list(ALWAYS_SHOWN))] = "heldout"
    return drawn


def caption(segments: list[tuple[str, dict]], rng: np.random.Generator, pool: str = "train") -> str:
    """One caption for a sequence of (action, params), worded from ``pool`` (:data:`POOLS`)."""
    pools = _dimension_pools(pool, rng)
    shape = _pick(rng, _SHAPES[pools["shape"]])
    subject = _pick(rng, SUBJECTS[pools["subject"]])
    phrases = [phrase(a, p, rng, pools) for a, p in segments]
    owner = "your" if shape == "imperative" else _POSSESSIVE.get(subject)
    owner = owner or _pick(rng, _NEUTRAL_POSSESSIVES)
    phrases = [(_possessive(p, owner, rng), _possessive(g, owner, rng)) for p, g in phrases]
    if shape == "imperative":
        phrases = [(base_form(present), gerund) for present, gerund in phrases]
        subject = ""
    elif shape == "progressive":
        verb = "are" if subject == "they" else "is"
        phrases = [(f"{verb} {phrases[0][1]}", phrases[0][1])] + [(g, g) for _, g in phrases[1:]]
    joiners = _JOINERS[pools["joiner"]]
    kind, text = _pick(rng, joiners) if len(phrases) > 1 else ("then", "")
    if kind == "after" and len(phrases) == 2:
        main = phrases[1][0] if shape != "progressive" else f"is {phrases[1][1]}"
        sentence = f"{text} {phrases[0][1]}, {subject} {main}"
    else:
        sentence = f"{subject} {phrases[0][0]}"
        for present, gerund in phrases[1:]:
            if kind == "before" and len(phrases) == 2:
                sentence += f"{text} {gerund}"
            else:
                joiner = _pick(rng, [t for k, t in joiners if k == "then"])
                sentence += f"{joiner} {present}"
    sentence = " ".join(sentence.split()).replace(" ,", ",")
    if pools["shape"] == "train" and rng.uniform() < TYPO_RATE:
        words = sentence.split(" ")
        spots = [i for i, w in enumerate(words) if w.rstrip(",") in _TYPOS]
        if spots:
            i = _pick(rng, spots)
            words[i] = words[i].replace(words[i].rstrip(","), _TYPOS[words[i].rstrip(",")])
            sentence = " ".join(words)
    if shape == "imperative" or rng.uniform() < 0.5:
        sentence = sentence[0].upper() + sentence[1:]
    return sentence if rng.uniform() < NO_STOP_RATE else sentence + "."


def captions_for(
    segments: list[tuple[str, dict]],
    rng: np.random.Generator,
    count: int = 3,
    heldout: bool = False,
    pool: str | None = None,
) -> list[str]:
    """``count`` different captions of a clip worded from ``pool`` (:data:`POOLS`; default
    "train", or "heldout" when ``heldout``)."""
    pool = pool or ("heldout" if heldout else "train")
    found: list[str] = []
    for _ in range(50 * count):
        text = caption(segments, rng, pool)
        if text.lower().rstrip(".") not in {f.lower().rstrip(".") for f in found}:
            found.append(text)
        if len(found) == count:
            break
    while len(found) < count:
        # Tiny template pools (a single stand still) can run out of distinct wordings.
        found.append(found[len(found) % len(found)].rstrip(".") + " for a while.")
    return found
