"""Captions for synthetic clips from varied templates, with a held-out pool of phrasings.

Every template exists in two forms, third-person present ("walks forward") and gerund ("walking
forward"), so that order words can join them ("..., then waves", "... before waving", "after
walking forward, ..."). Subjects, verb phrases, adverbs and order words come in a training pool and
a held-out pool that share no template: captions written with ``heldout=True`` use only held-out
wording, so a model trained on the default captions can be tested on phrasings it never saw.

Side and turning words are exactly "left"/"right" and "clockwise"/"counterclockwise"/
"anticlockwise", which the builder's caption mirroring swaps.
"""

from __future__ import annotations

import numpy as np

Pool = dict[str, list[tuple[str, str]]]

SUBJECTS = {
    "train": ["a person", "someone", "a man", "a woman", "the person", "a figure", "the figure", "somebody", "a human"],
    "heldout": ["an individual", "the subject", "a character", "the man"],
}  # fmt: skip

_COUNT_WORDS = {
    1: "once",
    2: "twice",
    3: "three times",
    4: "four times",
    5: "five times",
    6: "six times",
    7: "seven times",
    8: "eight times",
}
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
                  ("strolls forward{speed}", "strolling forward{speed}")],
        "heldout": [("moves ahead on foot{speed}", "moving ahead on foot{speed}"),
                    ("paces forward{speed}", "pacing forward{speed}")],
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
                  ("steps sideways to their {side}{speed}", "stepping sideways to their {side}{speed}")],
        "heldout": [("shuffles toward the {side}{speed}", "shuffling toward the {side}{speed}"),
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
        "heldout": [("springs up on the spot{count}", "springing up on the spot{count}")],
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
        "heldout": [("bends the knees deeply{count}", "bending the knees deeply{count}")],
    },
    "sit": {
        "train": [("sits down on the ground and stands back up", "sitting down on the ground and standing back up"),
                  ("sits on the floor for a moment and gets up", "sitting on the floor for a moment and getting up"),
                  ("lowers to the ground, sits, then stands up", "lowering to the ground, sitting, then standing up")],
        "heldout": [("takes a seat on the floor before rising again", "taking a seat on the floor before rising again")],
    },
    "bow": {
        "train": [("bows", "bowing"), ("bows forward", "bowing forward"), ("takes a bow", "taking a bow"),
                  ("bends forward at the waist", "bending forward at the waist")],
        "heldout": [("leans the upper body down politely", "leaning the upper body down politely")],
    },
    "clap": {
        "train": [("claps{count}", "clapping{count}"), ("claps the hands{count}", "clapping the hands{count}"),
                  ("claps {n} times", "clapping {n} times")],
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
    "heldout": {90: ["by a right angle"], 180: ["by half a circle"]},
}
_TURN_NOUNS = {
    90: ["a quarter turn", "a 90 degree turn"],
    180: ["a half turn", "a 180 degree turn"],
}

# Joining two clauses: (kind, text). "then": "<A><text> <B present>"; "before": "<A> before <B
# gerund>"; "after": "after <A gerund>, <subject> <B present>".
_JOINERS = {
    "train": [("then", ", then"), ("then", " and then"), ("then", ", after that"),
              ("before", " before"), ("after", "after")],
    "heldout": [("then", ", and afterwards"), ("then", ", subsequently"), ("before", " prior to"),
                ("after", "once done")],
}  # fmt: skip


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


def phrase(
    action: str, params: dict, rng: np.random.Generator, pool: str = "train"
) -> tuple[str, str]:
    """(present, gerund) verb phrases describing one action with its parameters."""
    present, gerund = _pick(rng, _TEMPLATES[_template_key(action, params)][pool])
    count = params.get("count", 1)
    direction = params.get("direction", "")
    values = {
        "speed": _pick(rng, _SPEED[pool][params["speed"]]) if "speed" in params else "",
        "side": params.get("side", direction),
        "cw": _pick(rng, _CIRCLE_WORD.get(direction, [""])),
        "turnside": _CIRCLE_TURN.get(direction, ""),
        "count": ""
        if count == 1 and rng.uniform() < 0.5
        else " " + _COUNT_WORDS.get(count, f"{count} times"),
        "n": _NUMBER_WORDS.get(count, str(count)),
        "punches": "punch" if count == 1 else "punches",
        "squats": "squat" if count == 1 else "squats",
        "angle": _pick(rng, _ANGLES[pool][params["angle"]]) if action == "turn" else "",
        "turn_noun": _pick(rng, _TURN_NOUNS[params["angle"]]) if action == "turn" else "",
    }
    if action == "jump" and count > 1 and not values["count"]:
        values["count"] = " " + _COUNT_WORDS.get(count, f"{count} times")
    return present.format(**values), gerund.format(**values)


def caption(segments: list[tuple[str, dict]], rng: np.random.Generator, pool: str = "train") -> str:
    """One caption for a sequence of (action, params)."""
    if pool not in SUBJECTS:
        raise ValueError(f"unknown caption pool {pool!r}; use 'train' or 'heldout'")
    subject = _pick(rng, SUBJECTS[pool])
    phrases = [phrase(a, p, rng, pool) for a, p in segments]
    kind, text = _pick(rng, _JOINERS[pool]) if len(phrases) > 1 else ("then", "")
    if kind == "after" and len(phrases) == 2:
        sentence = f"{text} {phrases[0][1]}, {subject} {phrases[1][0]}"
    else:
        sentence = f"{subject} {phrases[0][0]}"
        for present, gerund in phrases[1:]:
            if kind == "before" and len(phrases) == 2:
                sentence += f"{text} {gerund}"
            else:
                joiner = _pick(rng, [t for k, t in _JOINERS[pool] if k == "then"])
                sentence += f"{joiner} {present}"
    sentence = sentence.replace(" ,", ",")
    if rng.uniform() < 0.5:
        sentence = sentence[0].upper() + sentence[1:]
    return sentence + "."


def captions_for(
    segments: list[tuple[str, dict]],
    rng: np.random.Generator,
    count: int = 3,
    heldout: bool = False,
) -> list[str]:
    """``count`` different captions of a clip (from the held-out pool when ``heldout``)."""
    pool = "heldout" if heldout else "train"
    found: list[str] = []
    for _ in range(50 * count):
        text = caption(segments, rng, pool)
        if text.lower() not in {f.lower() for f in found}:
            found.append(text)
        if len(found) == count:
            break
    while len(found) < count:
        # Tiny template pools (a single stand still) can run out of distinct wordings.
        found.append(found[len(found) % len(found)].rstrip(".") + " for a while.")
    return found
