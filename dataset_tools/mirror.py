"""Mirroring of motions (negate x, swap left and right) and of their captions."""

from __future__ import annotations

import re

import numpy as np

from dataset_tools.skeleton import SMPL

# SMPL-H hands: joints 22..36 are the left hand, 37..51 the right hand, in the same order.
_HAND_SWAP = np.concatenate([np.arange(37, 52), np.arange(22, 37)])


def mirror_joints(joints: np.ndarray) -> np.ndarray:
    """Mirror joints (..., J, 3), J = 22 (SMPL body), 52 (SMPL-H) or 21 (KIT), about the YZ plane.

    x is negated and every left joint swaps with its right twin; mirroring twice is the identity.
    """
    joints = np.asarray(joints)
    num_joints = joints.shape[-2]
    if num_joints == 52:
        perm = np.concatenate([SMPL.mirror_permutation, _HAND_SWAP])
    else:
        from dataset_tools.skeleton import skeleton_for

        perm = skeleton_for(num_joints).mirror_permutation
    mirrored = joints[..., perm, :].copy()
    mirrored[..., 0] *= -1
    return mirrored


# "counter clockwise", "counter-clockwise", "anticlockwise", ... then plain "clockwise", then
# left/right with the suffixes captions use ("leftward(s)", "rightmost", "left-hand(ed)").
_CAPTION_WORD = re.compile(
    r"\b(?:(?P<counter>(?:counter|anti)[- ]?clockwise)|(?P<clockwise>clockwise)"
    r"|(?P<side>left|right)(?P<suffix>wards?|most|hand(?:ed)?)?)\b",
    re.IGNORECASE,
)


def _match_case(template: str, word: str) -> str:
    """``word`` written in the case pattern of ``template`` (UPPER, Title or lower)."""
    if template.isupper() and len(template) > 1:
        return word.upper()
    if template[:1].isupper():
        return word[:1].upper() + word[1:]
    return word


def _mirror_word(match: re.Match) -> str:
    text = match.group(0)
    if match.group("counter"):
        return _match_case(text, "clockwise")
    if match.group("clockwise"):
        return _match_case(text, "counterclockwise")
    side = match.group("side")
    swapped = "right" if side.lower() == "left" else "left"
    return _match_case(side, swapped) + (match.group("suffix") or "")


def mirror_caption(text: str) -> str:
    """The caption of the mirrored motion: left <-> right, clockwise <-> counterclockwise.

    Variants are covered ("leftwards", "right-hand", "anti-clockwise", "counter clockwise", ...);
    case and punctuation are kept ("Left" -> "Right", "LEFT" -> "RIGHT"). Applying it twice gives
    back the caption except that every counter-clockwise spelling becomes "counterclockwise".
    """
    return _CAPTION_WORD.sub(_mirror_word, text)
