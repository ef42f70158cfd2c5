"""An edit's foot-contact clean-up (:func:`t2m.edit.keep.finish_plan`, with
:func:`dataset_tools.cleanup.clean_joints`'s ``held`` joints): it plants the sliding feet of the
regenerated frames and never moves a kept joint.

Synthetic features: the regenerated motion stands on bent knees, both feet predicted planted,
while the whole body sways 12 cm sideways at 1 Hz, feet included (so they skate, as they do when
a bent root path drags them); the source is a procedural walk. Plans: its first 24 frames kept
(as ``continue`` keeps them), or its lower body kept throughout (as ``body`` with ``lower``).
"""

from __future__ import annotations

import numpy as np
import pytest

from dataset_tools import cleanup
from dataset_tools.kinematics import forward_kinematics
from dataset_tools.physical import skating_ratio
from dataset_tools.representation import FeatureLayout, process_motion, recover_from_ric
from dataset_tools.rotations import axis_angle_to_quat
from dataset_tools.skeleton import SMPL
from t2m.edit.keep import finish_plan
from t2m.edit.plan import EditPlan
from t2m.edit.source import half_yaw_of
from tests.conftest import synth_joints

FRAMES, KEPT, FPS = 80, 24, 20.0
LOWER = [0, 1, 2, 4, 5, 7, 8, 10, 11]  # the root and both legs


def sliding_walk_features(seed: int) -> np.ndarray:
    """Features (FRAMES, 263) of a gliding walk on the floor, contacts where a toe is the lower."""
    joints = synth_joints("walk_forward", FRAMES + 1, np.random.default_rng(seed))
    joints = joints.astype(np.float64)
    joints[..., 1] -= joints[..., 1].min()
    features, recovered = process_motion(joints)
    left_lower = recovered[:, 10, 1] <= recovered[:, 11, 1]
    contacts = np.stack([left_lower, left_lower, ~left_lower, ~left_lower], axis=1)
    features[:, FeatureLayout(22).foot_contact] = contacts
    return features.astype(np.float32)


def swaying_stance_features() -> np.ndarray:
    """Features (FRAMES, 263) of the swaying stance, both feet in contact throughout."""
    t = np.arange(FRAMES + 1) / FPS
    axis_angles = np.zeros((FRAMES + 1, 22, 3))
    axis_angles[:, [1, 2, 7, 8], 0] = -0.4  # hips and ankles against the bent knees
    axis_angles[:, [4, 5], 0] = 0.8
    root = np.zeros((FRAMES + 1, 3))
    root[:, 0] = 0.12 * np.sin(2 * np.pi * t)
    joints = forward_kinematics(axis_angle_to_quat(axis_angles), root, SMPL.offsets, SMPL)
    joints[..., 1] -= joints[..., 1].min()
    features, _ = process_motion(joints)
    features[:, FeatureLayout(22).foot_contact] = 1.0
    return features.astype(np.float32)


def plan_of(source: np.ndarray, keep: np.ndarray) -> EditPlan:
    target = np.full((FRAMES, 22, 3), np.nan)
    target[keep] = recover_from_ric(source.astype(np.float64), 22)[keep]
    kept_source = np.where(keep.any(axis=1)[:, None], source, np.nan)
    return EditPlan("a person walks", FRAMES, target, keep, kept_source, half_yaw_of(source))


def kept_start() -> np.ndarray:
    keep = np.zeros((FRAMES, 22), bool)
    keep[:KEPT] = True
    return keep


def kept_legs() -> np.ndarray:
    keep = np.zeros((FRAMES, 22), bool)
    keep[:, LOWER] = True
    return keep


@pytest.fixture(scope="module")
def walks() -> tuple[np.ndarray, np.ndarray]:
    return sliding_walk_features(3), swaying_stance_features()


@pytest.mark.parametrize("keep", [kept_start(), kept_legs()], ids=["start", "legs"])
def test_the_clean_up_never_moves_a_kept_joint(walks, keep):
    source, generated = walks
    plan = plan_of(source, keep)
    cleaned = recover_from_ric(finish_plan(generated, plan), 22)
    rigid = recover_from_ric(finish_plan(generated, plan, clean=False), 22)
    # kept joints exactly where the finishing without the clean-up leaves them (its rigid fit
    # holds them at the source's positions: within float32 rounding of the targets)
    np.testing.assert_array_equal(cleaned[keep], rigid[keep])
    np.testing.assert_allclose(cleaned[keep], plan.target[keep], rtol=0, atol=1e-5)
    moved = np.abs(cleaned - rigid).max(axis=-1) > 1e-3
    if keep[:, 7].all():  # legs kept throughout: nothing for the clean-up to move
        assert not moved.any()
    else:  # it did plant the regenerated feet
        assert moved[KEPT:, [7, 8, 10, 11]].any()


def test_the_clean_up_plants_the_regenerated_feet(walks):
    source, generated = walks
    plan = plan_of(source, kept_start())
    cleaned = recover_from_ric(finish_plan(generated, plan), 22)
    rigid = recover_from_ric(finish_plan(generated, plan, clean=False), 22)
    before = skating_ratio(rigid[KEPT:], FPS)
    after = skating_ratio(cleaned[KEPT:], FPS)
    # the sway skates on a third of the frames (0.35 observed); planted, on few (0.02 observed)
    assert before > 0.25 and after < 0.25 * before, (before, after)


def test_the_correction_fades_in_from_the_kept_frames(walks):
    source, generated = walks
    plan = plan_of(source, kept_start())
    cleaned = recover_from_ric(finish_plan(generated, plan), 22)
    rigid = recover_from_ric(finish_plan(generated, plan, clean=False), 22)
    feet = [7, 8, 10, 11]
    change = np.linalg.norm(cleaned[:, feet] - rigid[:, feet], axis=-1).max(axis=-1)  # (T,)
    later = change[KEPT + cleanup.HELD_BLEND_FRAMES :].max()
    assert later > 0.05  # the lock moves the feet by centimetres once faded in
    # no step where the feet are let go: the first free frames are corrected by a small share
    assert change[KEPT] < 0.05 * later, (change[KEPT], later)
    step = np.linalg.norm(np.diff(cleaned[:, feet], axis=0), axis=-1).max(axis=-1)
    plain_step = np.linalg.norm(np.diff(rigid[:, feet], axis=0), axis=-1).max(axis=-1)
    seam = slice(KEPT - 2, KEPT + 3)
    assert step[seam].max() <= plain_step[seam].max() + 0.01


def test_clean_joints_leaves_held_joints_exactly(walks):
    joints = recover_from_ric(walks[1].astype(np.float64), 22)
    contacts = walks[1][:, FeatureLayout(22).foot_contact]
    held = np.zeros((FRAMES, 22), bool)
    held[30:45, 7] = True  # the left ankle for a while: the whole left leg stays there
    held[::7, 11] = True  # the right foot now and then
    cleaned = cleanup.clean_joints(joints, contacts, held=held)
    np.testing.assert_array_equal(cleaned[30:45][:, [4, 7, 10]], joints[30:45][:, [4, 7, 10]])
    np.testing.assert_array_equal(cleaned[held], joints[held])
    assert np.abs(cleaned - joints).max() > 0.05  # and the rest was cleaned
    # None is the plain clean-up; a mask of the wrong shape is refused
    plain = cleanup.clean_joints(joints, contacts)
    np.testing.assert_array_equal(cleanup.clean_joints(joints, contacts, held=None), plain)
    with pytest.raises(ValueError, match="held must be"):
        cleanup.clean_joints(joints, contacts, held=held[:, :5])


def test_a_held_legs_correction_is_whole_within_0_8_s():
    """The clean-up's correction fades in over 16 frames (0.8 s) from held legs: over 20 the
    feet that the bent root path drags before an inbetween's kept end skated more than real
    motion's once edits keep the body on the floor (edit benchmark 0.159 against 0.158; 0.148
    over 16, seam jerk 1.11x real motion's)."""
    held = np.zeros(60, bool)
    held[:20] = True
    weights = cleanup._held_weights(held)
    assert np.all(weights[:20] == 0.0)
    assert weights[20 + 15] > 0.99 and weights[20 + 16] == 1.0  # whole 0.8 s after the held legs
    assert 0.3 < weights[20 + 7] < 0.7  # eased, not cut


def gliding_stance(frames: int = 40, step: float = 0.02) -> np.ndarray:
    """Joints (frames, 22, 3): a stance on bent knees (thigh 0.40, shin 0.42, hip to ankle 0.76,
    toe 0.14 from the ankle) whose whole body glides forward ``step`` m a frame (0.4 m/s at
    20 fps): planted feet slide with it, as they do when a seam's correction moves the legs."""
    thigh, shin, reach = 0.40, 0.42, 0.76
    down = (thigh**2 - shin**2 + reach**2) / (2 * reach)
    pose = np.zeros((22, 3))
    pose[:, 1] = np.linspace(0.9, 1.7, 22)
    for side, (hip, knee, ankle, toe) in zip((1.0, -1.0), ((1, 4, 7, 10), (2, 5, 8, 11))):
        pose[hip] = [0.1 * side, 0.85, 0.0]
        pose[knee] = [0.1 * side, 0.85 - down, np.sqrt(thigh**2 - down**2)]
        pose[ankle] = [0.1 * side, 0.85 - reach, 0.0]
        pose[toe] = [0.1 * side, 0.01, 0.12]
    joints = np.repeat(pose[None], frames, axis=0)
    joints[..., 2] += step * np.arange(frames)[:, None]
    return joints


GLIDE = 60  # frames of the gliding stance: the glide outruns the planted leg within them


def _held_legs(frames: int, rows: slice) -> np.ndarray:
    held = np.zeros((frames, 22), bool)
    held[rows, LOWER] = True
    return held


def test_a_foot_planted_at_a_kept_start_stays_where_the_kept_frames_left_it(monkeypatch):
    """A contact run going on from held frames keeps the toe where they leave it (no fade), the
    heel lifting once the leg cannot reach it, and lets go where even that cannot reach."""
    joints = gliding_stance(GLIDE)
    contacts = np.zeros((GLIDE, 4))
    contacts[:, :2] = 1.0  # the left foot planted throughout
    held = _held_legs(GLIDE, slice(0, 10))
    cleaned = cleanup.clean_joints(joints, contacts, held=held)
    np.testing.assert_array_equal(cleaned[held], joints[held])
    toe, ankle, knee, hip = 10, 7, 4, 1
    anchor = joints[9, toe, [0, 2]]
    full = 10 + cleanup.HELD_PLANT_RAMP_FRAMES + 1  # the plant's share is whole from here
    # Exactly still while planted (the anchor copied; the IK's unit direction times distance
    # rounds the ankle, which the toe follows: a few roundings at <= 1 m). Without the plant
    # the faded correction lets the toe slide 1-2 cm a frame here (the glide is 2 cm).
    drift = np.abs(cleaned[full : full + 8, toe][:, [0, 2]] - anchor).max()
    assert drift < 1e-9, drift
    monkeypatch.setattr(cleanup, "plant_near_held", lambda joints, cleaned, *args: cleaned)
    faded = cleanup.clean_joints(joints, contacts, held=held)
    assert np.abs(faded[full : full + 8, toe][:, [0, 2]] - anchor).max() > 0.02
    # the foot keeps its length and the leg its bones (IK), the heel lifts as the body moves on
    for a, b in ((toe, ankle), (ankle, knee), (knee, hip)):
        np.testing.assert_allclose(
            np.linalg.norm(cleaned[:, a] - cleaned[:, b], axis=-1),
            np.linalg.norm(joints[:, a] - joints[:, b], axis=-1),
            rtol=0,
            atol=1e-9,  # the bisection's 2^-30 of a turn moves no length; roundings at <= 1 m
        )
    lifted = cleaned[full:, ankle, 1] - joints[full:, ankle, 1]
    assert lifted.max() > 0.02  # the heel rose while the toe stayed
    # out of reach even turned toward the hip: the plant ends and hands back to the faded
    # correction over HELD_PLANT_RELEASE_FRAMES
    still = np.abs(cleaned[:, toe][:, [0, 2]] - anchor).max(axis=-1) < 1e-9
    end = int(np.flatnonzero(still)[-1]) + 1
    assert end < GLIDE - cleanup.HELD_PLANT_RELEASE_FRAMES - 2, end  # the glide outruns the leg
    assert np.linalg.norm(joints[end, hip] - cleaned[end - 1, toe]) > 0.82  # beyond the leg
    # eased: the toe's largest step is a fraction of the way back (1.5 / 7 of it for a smoothstep
    # over 6 frames; all of it in one frame without the release)
    way = np.linalg.norm(faded[end + 6, toe] - cleaned[end - 1, toe])
    steps = np.linalg.norm(np.diff(cleaned[end - 1 : end + 7, toe], axis=0), axis=-1)
    assert way > 0.1 and steps.max() < 0.4 * way, (way, steps.max())
    back = slice(end + cleanup.HELD_PLANT_RELEASE_FRAMES, None)
    np.testing.assert_allclose(cleaned[back], faded[back], rtol=0, atol=1e-12)


def test_a_foot_landing_before_a_kept_end_stands_where_the_kept_frames_put_it(monkeypatch):
    """A contact run that goes on into held frames (a kept end) stands where the held frames
    put the toe from its first free frame on, instead of sliding there with the faded
    correction (the edit benchmark's inbetween: skating peaked over the last 8 frames before a
    kept end); the step before it moves the toe there in the air, eased over
    HELD_PLANT_RELEASE_FRAMES."""
    joints = gliding_stance(GLIDE)
    contacts = np.zeros((GLIDE, 4))
    land = GLIDE - 20
    contacts[land:, :2] = 1.0  # the left foot lands 10 frames before the kept end
    held = _held_legs(GLIDE, slice(GLIDE - 10, GLIDE))
    cleaned = cleanup.clean_joints(joints, contacts, held=held)
    np.testing.assert_array_equal(cleaned[held], joints[held])
    toe = 10
    anchor = joints[GLIDE - 10, toe, [0, 2]]  # where the first kept frame has the toe
    drift = np.abs(cleaned[land : GLIDE - 10, toe][:, [0, 2]] - anchor).max()
    assert drift < 1e-9, drift
    # the toe got there before the landing, over the frames before it, eased
    before = cleaned[land - cleanup.HELD_PLANT_RELEASE_FRAMES - 1 : land + 1, toe]
    steps = np.linalg.norm(np.diff(before, axis=0), axis=-1)
    way = np.linalg.norm(before[-1] - before[0])
    assert way > 0.1 and steps.max() < 0.4 * way, (way, steps.max())
    monkeypatch.setattr(cleanup, "plant_near_held", lambda joints, cleaned, *args: cleaned)
    faded = cleanup.clean_joints(joints, contacts, held=held)
    slide = np.abs(np.diff(faded[land : GLIDE - 10, toe][:, [0, 2]], axis=0)).max()
    assert slide > 0.01, slide  # without the plant the toe slides with the glide
    early = slice(0, land - cleanup.HELD_PLANT_RELEASE_FRAMES)
    np.testing.assert_allclose(cleaned[early], faded[early], rtol=0, atol=1e-12)


def test_a_run_into_a_kept_end_that_the_leg_cannot_reach_is_planted_only_where_it_can():
    """The plant before a kept end begins where the leg reaches the kept toe (the body glides
    toward it); frames before that keep the faded correction."""
    joints = gliding_stance(GLIDE)
    contacts = np.zeros((GLIDE, 4))
    contacts[:, :2] = 1.0  # planted throughout: 50 free frames before the kept end, 1 m away
    held = _held_legs(GLIDE, slice(GLIDE - 10, GLIDE))
    cleaned = cleanup.clean_joints(joints, contacts, held=held)
    toe, hip = 10, 1
    anchor = joints[GLIDE - 10, toe]
    still = np.abs(cleaned[: GLIDE - 10, toe][:, [0, 2]] - anchor[[0, 2]]).max(axis=-1) < 1e-9
    first = int(np.argmax(still))
    assert 5 < first < GLIDE - 20, first
    assert still[first:].all()
    assert np.linalg.norm(joints[first - 1, hip] - anchor) > 0.82  # beyond the leg before


def test_a_planted_foot_with_its_toes_up_stays_above_the_floor():
    """The plant sets heights as the lock does (the foot's lowest joint into [0, 2 cm]): a toe
    raised above its heel is not pulled to the floor, which would push the heel through it
    (sitting down, the demo model's feet do this: a heel 9 cm under the floor read as no sit)."""
    joints = gliding_stance(GLIDE, step=0.005)
    joints[:, [10, 11], 1] = 0.15  # toes 6 cm above the ankles (0.09)
    joints[..., 1] -= 0.05  # ankles at 4 cm: a contact the clean-up plants
    above = [j for j in range(22) if j not in (4, 5, 7, 8, 10, 11)]
    joints[:, above, 1] -= 0.25  # the body low over its feet (sitting down): the leg reaches
    contacts = np.zeros((GLIDE, 4))
    contacts[:, :2] = 1.0
    held = _held_legs(GLIDE, slice(0, 10))
    cleaned = cleanup.clean_joints(joints, contacts, held=held)
    assert cleaned[:, [7, 10], 1].min() >= 0.0
    full = 10 + cleanup.HELD_PLANT_RAMP_FRAMES + 1
    drift = np.abs(cleaned[full : full + 8, 10][:, [0, 2]] - joints[9, 10, [0, 2]]).max()
    assert drift < 1e-9, drift  # still planted where the kept frames left it
    # the heel at the lock's 2 cm, or above it where it lifts as the body moves on
    assert cleaned[full : full + 8, 7, 1].min() >= 0.02 - 1e-9


def test_a_planted_knee_bends_toward_the_toes_when_the_generated_leg_is_straight(monkeypatch):
    """The planted leg's knee is placed by IK in the plane of the generated knee; a straight
    generated leg gives no such plane, and one that wobbles a millimetre from side to side made
    the knee bend left on one frame and right on the next (20-30 cm jumps at the edit benchmark's
    seams; backward knees in the plain clean-up). Knees bend toward the toes there
    (:data:`cleanup.KNEE_POLE_PRIOR_M`)."""
    frames = 8
    hip = np.zeros((frames, 3))
    ankle = np.repeat([[0.0, -0.82, 0.0]], frames, axis=0)  # straight down, thigh + shin 0.82
    knee = (hip + ankle) / 2
    knee[:, 0] += 0.001 * (-1.0) ** np.arange(frames)  # wobbling sideways by a millimetre
    target = ankle + [0.0, 0.1, 0.0]  # 10 cm closer: the knee must bend
    toes = np.repeat([[0.0, 0.0, 1.0]], frames, axis=0)
    sides = {}
    for hint in (None, toes):
        bent, _ = cleanup.two_bone_knee(hip, knee, ankle, target, hint)
        sides[hint is None] = bent[:, [0, 2]]
    flips = np.sign(sides[True][:, 0])
    assert np.all(flips[1:] != flips[:-1])  # without the toes' direction: left, right, left...
    forward = sides[False]
    assert np.all(forward[:, 1] > 0.15) and np.abs(forward[:, 0]).max() < 0.01  # toward the toes
    # the plant gives the IK its foot's direction
    given = []
    ik = cleanup.two_bone_knee

    def recording(hip, knee, ankle, target, forward=None, prior=None):
        given.append(forward)
        return ik(hip, knee, ankle, target, forward, prior)

    monkeypatch.setattr(cleanup, "two_bone_knee", recording)
    joints = gliding_stance(GLIDE)
    contacts = np.zeros((GLIDE, 4))
    contacts[:, :2] = 1.0
    for held in (None, _held_legs(GLIDE, slice(0, 10))):  # the plain clean-up, and the plant
        given.clear()
        cleanup.clean_joints(joints, contacts, held=held)
        assert given and all(f is not None for f in given)  # every IK gets the foot's direction:
        assert np.mean(np.concatenate(given)[:, 2] > 0.0) > 0.8  # ankle to toe, mostly ahead


def test_next_to_held_frames_the_knee_eases_toward_the_toes(monkeypatch):
    """The IK's lean toward the toes fades in with the correction next to held frames: there the
    leg is the kept one, and the full lean turned the knee toward a foot pointing sideways on the
    first free frame, a jump at the seam."""
    joints = gliding_stance(GLIDE, step=0.0)
    joints[:, 10] = joints[:, 7] + [0.12, -0.08, 0.0]  # the left foot points sideways (+x)
    contacts = np.zeros((GLIDE, 4))
    contacts[:, :2] = 1.0
    held = _held_legs(GLIDE, slice(0, 10))
    knee = 4
    cleaned = cleanup.clean_joints(joints, contacts, held=held)
    # eased in over HELD_PLANT_RAMP_FRAMES: no step of the knee is more than a fraction of its way
    way = np.linalg.norm(cleaned[30, knee] - joints[30, knee])
    steps = np.linalg.norm(np.diff(cleaned[9:30, knee], axis=0), axis=-1)
    assert way > 0.03 and steps.max() < 0.4 * way, (way, steps.max())
    ik = cleanup.two_bone_knee

    def full_lean(hip, knee, ankle, target, forward=None, prior=None):
        return ik(hip, knee, ankle, target, forward)

    monkeypatch.setattr(cleanup, "two_bone_knee", full_lean)
    leaning = cleanup.clean_joints(joints, contacts, held=held)
    jump = np.linalg.norm(leaning[10, knee] - joints[9, knee])
    assert jump > 0.8 * way, (jump, way)  # all of it on the first free frame


def backward_knee_stance_features() -> np.ndarray:
    """Features (FRAMES, 263) of a stance whose knees bend behind the legs (thighs back, shins
    forward), as the hard keep's joint-by-joint seam easing can leave them; feet planted."""
    axis_angles = np.zeros((FRAMES + 1, 22, 3))
    axis_angles[:, [4, 5], 0] = 0.4  # each joint's rotation turns its bone: thighs back
    axis_angles[:, [7, 8], 0] = -0.8  # shins forward
    root = np.zeros((FRAMES + 1, 3))
    joints = forward_kinematics(axis_angle_to_quat(axis_angles), root, SMPL.offsets, SMPL)
    joints[..., 1] -= joints[..., 1].min()
    features, _ = process_motion(joints)
    features[:, FeatureLayout(22).foot_contact] = 1.0
    return features.astype(np.float32)


def knee_ahead(joints: np.ndarray) -> np.ndarray:
    """(T, 2) how far each knee sits in front of its hip-ankle line (m; negative: behind)."""
    out = []
    for hip, knee, ankle, _ in ((1, 4, 7, 10), (2, 5, 8, 11)):
        line = joints[:, ankle] - joints[:, hip]
        line /= np.linalg.norm(line, axis=-1, keepdims=True)
        front = np.cross(joints[:, 2] - joints[:, 1], line)
        front /= np.linalg.norm(front, axis=-1, keepdims=True)
        out.append(np.sum((joints[:, knee] - joints[:, hip]) * front, axis=-1))
    return np.stack(out, axis=1)


@pytest.mark.parametrize("clean", [True, False], ids=["cleaned", "rigid"])
def test_a_finished_edit_bends_no_free_knee_behind_the_leg(walks, clean):
    """finish_plan mirrors free knees bent behind the hip-ankle line to the front
    (t2m.edit.keep.knees_to_front) and leaves the kept frames, hips and ankles where they were:
    a stance on backward knees after a kept walk ends with every knee in front."""
    source = walks[0]
    generated = backward_knee_stance_features()
    assert (knee_ahead(recover_from_ric(generated.astype(np.float64), 22)) < -0.05).all()
    plan = plan_of(source, kept_start())
    finished = recover_from_ric(finish_plan(generated, plan, clean=clean), 22)
    ahead = knee_ahead(finished)
    # every free knee in front; one on the line may sit behind it by the float32 features'
    # rounding (a few 2^-24 at 2 m: under 1e-6 m)
    assert (ahead[KEPT:] > -1e-6).all(), ahead[KEPT:].min()
    assert (ahead[KEPT + cleanup.HELD_BLEND_FRAMES :] > 0.05).all()
    np.testing.assert_allclose(finished[plan.keep], plan.target[plan.keep], rtol=0, atol=1e-5)
