"""Body edits of every part (t2m.edit, ``--mode body --part``) on the tiny trained run: each part
gives the search targets (``lower`` the positions of its joints, the others their heights), the
candidates are judged and ``--method optimize`` optimised against them, and the kept part keeps
its pose exactly."""

from __future__ import annotations

import logging

import numpy as np
import pytest
from conftest import synth_joints

from dataset_tools.representation import FeatureLayout
from dataset_tools.skeleton import SMPL
from dataset_tools.spec import HUMANML3D
from t2m.edit import BODY_PARTS, SearchSettings, edit, prepare_source
from t2m.edit.core import has_soft_targets
from t2m.edit.modes import plan_body

HANGING = [part for part in BODY_PARTS if 0 not in BODY_PARTS[part]]  # all but lower


@pytest.fixture(scope="module")
def walk() -> np.ndarray:
    return synth_joints("walk_forward", 81, np.random.default_rng(3))


@pytest.mark.parametrize("part", list(BODY_PARTS))
def test_every_part_gives_targets_on_its_kept_joints(walk, part):
    source = prepare_source(walk)
    plan = plan_body("a person waves", source, HUMANML3D, part)
    joints = list(BODY_PARTS[part])
    given = np.isfinite(plan.target)
    assert given.any(-1)[:, joints].all()  # every kept joint on every frame
    assert not given.any(-1)[:, [j for j in range(22) if j not in joints]].any()
    assert not has_soft_targets(plan)  # all on kept joints: the hard keep holds the rest
    frames = plan.num_frames
    if part == "lower":  # the root path is kept: positions
        np.testing.assert_array_equal(plan.target[:, joints], source.joints[:frames, joints])
    else:  # a regenerated root and facing: heights only
        np.testing.assert_array_equal(plan.target[:, joints, 1], source.joints[:frames, joints, 1])
        assert not given[..., [0, 2]].any()


@pytest.mark.parametrize("part", HANGING)
def test_each_part_is_searched_and_optimised(pipe, walk, part, caplog):
    settings = SearchSettings(method="optimize", candidates=3, steps=4)
    with caplog.at_level(logging.INFO, logger="t2m.edit.core"):
        motion = edit(pipe, "a person raises the left arm", "body", walk, part=part, seed=0,
                      settings=settings)[0]  # fmt: skip
    assert "1 results of 4.0 s, 3 candidates each, 4 optimisation steps" in caplog.text
    assert np.isfinite(motion.constraint_error) and motion.constraint_error > 0
    # the default (auto) judges the candidates against the targets without optimising
    caplog.clear()
    with caplog.at_level(logging.INFO, logger="t2m.edit.core"):
        edit(pipe, "a person raises the left arm", "body", walk, part=part, seed=0,
             settings=SearchSettings(candidates=3, steps=4))  # fmt: skip
    assert "3 candidates each, 0 optimisation steps" in caplog.text


def _bones_in(part: str) -> list[tuple[int, int]]:
    """(parent, joint) of the bones whose both ends are in ``part`` (the root excluded: its
    position is not a ric entry)."""
    joints = set(BODY_PARTS[part])
    return [(SMPL.parents[j], j) for j in sorted(joints) if SMPL.parents[j] in joints - {0}]


@pytest.mark.parametrize("part", HANGING)
def test_the_kept_part_keeps_its_pose(pipe, walk, part):
    """The part hangs from the regenerated body (its floor position and facing are the new
    motion's), and within it every bone is the source's, in the body's facing frame."""
    source = prepare_source(walk)
    motion = edit(pipe, "a person raises the left arm", "body", walk, part=part, seed=1,
                  settings=SearchSettings(method="optimize", candidates=2, steps=3))[0]  # fmt: skip
    frames = motion.features.shape[0]
    ric = FeatureLayout(22).ric
    made = motion.features[:, ric].reshape(frames, 21, 3)
    kept = source.features[:frames, ric].reshape(frames, 21, 3)
    bones = _bones_in(part)
    assert bones
    for parent, joint in bones:
        np.testing.assert_allclose(
            made[:, joint - 1] - made[:, parent - 1],
            kept[:, joint - 1] - kept[:, parent - 1],
            atol=2e-4,
            err_msg=f"bone {parent}->{joint}",
        )
    assert motion.kept[:, list(BODY_PARTS[part])].all()
    others = [j for j in range(22) if j not in BODY_PARTS[part]]
    assert not motion.kept[:, others].any()
