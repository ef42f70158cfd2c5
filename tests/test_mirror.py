"""Mirroring of joints and captions."""

from __future__ import annotations

import numpy as np
import pytest

from dataset_tools.mirror import mirror_caption, mirror_joints
from dataset_tools.skeleton import SMPL


@pytest.mark.parametrize("num_joints", [22, 52, 21])
def test_mirror_joints_twice_is_identity(num_joints):
    joints = np.random.default_rng(0).normal(size=(5, num_joints, 3))
    np.testing.assert_array_equal(mirror_joints(mirror_joints(joints)), joints)


def test_mirror_joints_swaps_sides_and_negates_x():
    joints = np.random.default_rng(1).normal(size=(3, 52, 3))
    mirrored = mirror_joints(joints)
    np.testing.assert_array_equal(mirrored[:, 20], joints[:, 21] * [-1, 1, 1])  # wrists
    np.testing.assert_array_equal(mirrored[:, 0], joints[:, 0] * [-1, 1, 1])  # pelvis stays
    np.testing.assert_array_equal(mirrored[:, 22], joints[:, 37] * [-1, 1, 1])  # hands swap
    np.testing.assert_array_equal(mirrored[:, :22], mirror_joints(joints[:, :22]))
    assert SMPL.joint_names[20] == "left_wrist"


@pytest.mark.parametrize(
    "caption, expected",
    [
        ("a person turns left.", "a person turns right."),
        ("Left foot, then RIGHT hand!", "Right foot, then LEFT hand!"),
        ("walks clockwise", "walks counterclockwise"),
        ("spins counter-clockwise, then anticlockwise", "spins clockwise, then clockwise"),
        ("turns Counter Clockwise; Anti-clockwise", "turns Clockwise; Clockwise"),
        ("moves leftwards then rightward", "moves rightwards then leftward"),
        ("waves the left-hand side; left-handed", "waves the right-hand side; right-handed"),
        ("the rightmost foot", "the leftmost foot"),
        ("bright and alright, leftover", "bright and alright, leftover"),
        ("no sides here.", "no sides here."),
    ],
)
def test_mirror_caption(caption, expected):
    assert mirror_caption(caption) == expected


def test_mirror_caption_twice_restores_left_right():
    caption = "A man steps LEFT, turns Right and waves his left hand clockwise."
    assert mirror_caption(mirror_caption(caption)) == caption
