"""Foot-contact clean-up of generated motions: planted feet stay put, legs keep their lengths.

A generated motion's features carry four foot-contact channels (left ankle, left toe, right
ankle, right toe; above 0.5 = contact predicted). Where the model says a foot is on the floor
its joints still drift a little, sink below the floor or hover above it; an animator sees that
first. :func:`clean_joints` fixes it with three small steps, per foot:

1. **Contact runs.** The foot is planted while its ankle or toe channel says so; runs shorter
   than :data:`MIN_CONTACT_FRAMES` are ignored and gaps of one frame closed.
2. **Lock.** During a run the toe's horizontal position is held at its mean over the run, and
   the foot is lowered or raised so that its lowest joint sits between the floor and
   :data:`PLANT_HEIGHT_M` (a run whose foot stays above :data:`MAX_PLANT_HEIGHT_M` is a contact
   predicted in the air and left alone). The correction is a translation of ankle and toe
   together (the foot keeps its length); between two runs it moves smoothly from one run's
   value to the next, it fades in and out over :data:`BLEND_FRAMES` frames before the first
   run and after the last, and a Gaussian of :data:`SMOOTH_FRAMES` rounds its corners. Out of
   a run the foot is never lowered: a foot lowered onto the floor during the run leaves it as
   generated (only a lift out of the floor fades out). A foot joint below the floor is lifted
   to it, in contact or not.
3. **Leg IK.** Hip fixed, the knee is re-placed by two-bone inverse kinematics in the plane of the
   hip, the new ankle and the generated knee, so thigh and shin keep their per-frame lengths;
   an ankle pushed towards the leg's full length is held back softly (:data:`SOFT_REACH`), so
   the knee never snaps straight (the lock is then partial).

Everything else (root, spine, arms) is untouched. ``held`` joints (an edit's joints kept from a
source, :func:`clean_joints`) are never moved: a leg whose knee, ankle or foot is held on a frame
is left exactly as given there, a contact run that reaches held frames is planted at its mean
over its free frames, and the correction fades in over :data:`HELD_BLEND_FRAMES` frames away
from held frames; within that fade, and for a run that goes on from held frames, the foot is
planted outright (:func:`plant_near_held`: the toe stays, the heel lifts where the leg cannot
reach); a run that goes on into held frames stands where they put the toe, the step before it
carrying the toe there.

:func:`clean_features` does the same on raw
features and writes the cleaned joints back into them (the root and the model's contact
channels kept), so features and joints stay consistent. Input and output joints (T, J, 3) are
metres, y-up, the floor at y = 0, SMPL (22) or KIT (21) joints.

Measured on the demo model (the evaluation's physical-quality table, docs/evaluation.md): foot skating, penetration and floating go
down, jerk up by a few percent, semantic accuracy unchanged within its interval.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from scipy.ndimage import gaussian_filter1d

from dataset_tools.kinematics import inverse_kinematics
from dataset_tools.representation import (
    FACING_SMOOTH_SIGMA,
    FeatureLayout,
    recover_from_ric,
    recover_root,
)
from dataset_tools.rotations import qrot, quat_to_6d
from dataset_tools.skeleton import SkeletonSpec, skeleton_for

CONTACT_THRESHOLD = 0.5
"""A contact channel above this is a planted joint."""
MIN_CONTACT_FRAMES = 2
"""Shorter contact runs are left alone."""
BLEND_FRAMES = 3
"""Frames over which a lock fades in before a run and out after it."""
PLANT_HEIGHT_M = 0.02
"""A planted foot's lowest joint is brought into [0, this]."""
SMOOTH_FRAMES = 1.0
"""Standard deviation (frames) of the Gaussian that smooths each foot's correction."""
SOFT_REACH = 0.97
"""Hip-to-ankle distances beyond this share of the leg's length are approached softly."""
MAX_PLANT_HEIGHT_M = 0.05
"""A contact run whose foot stays higher than this (median of its lowest joint) is not planted."""
HELD_BLEND_FRAMES = 16
"""Frames over which a leg's correction fades in after (and out before) frames it is held on
(0.8 s at 20 fps). Edit benchmark, inbetween with unrelated kept ends, demo model: over 12
frames the fade itself raised the seam jerk to 1.28x-1.37x that of real motion; over 20 it
left foot skating at 0.159 against real motion's 0.158 once edits keep the body on the floor
(t2m.edit.keep.keep_floor); over 16, 1.11x real jerk and skating 0.148."""


KNEE_POLE_PRIOR_M = 0.08
"""How far ahead (toward the toes) the clean-up's IK assumes the knee is, on top of where the
generated knee is off the hip-ankle line: a straight generated leg gives no bending plane, and
one that wobbled by millimetres bent the knee backward or sideways from one frame to the next
(the plant next to kept frames: 20-30 cm jumps, edit benchmark inbetween with unrelated ends,
seed 3, 300 items: the kept start's seam jerk 727 -> 633, median; 0.03 m and 0.15 m did less on
150 items; the plain clean-up of 300 demo-model motions: knees bent 3 cm or more backward on 164
of 62,096 leg-frames -> 13, and -> 0 with the bend taken off the generated leg's own hip-ankle
line; none in the model's own output). Next to held frames the lean fades with the
correction (the fade's share in the clean-up, the plant's share in :func:`plant_near_held`):
there the leg is the kept one, and the full lean moved the knee off it, a jump at the seam (edit
benchmark, inbetween with the source's own ends, seeds 4, 6, 8, 300 items each: the kept start's
seam jerk median 489-510 -> 430-435)."""
HELD_PLANT_RAMP_FRAMES = 6
"""Frames over which a foot planted next to held frames (:func:`plant_near_held`) takes over
from the faded correction, counted from the nearest held frame (smoothstep)."""
HELD_PLANT_RELEASE_FRAMES = 6
"""Frames over which such a plant hands back to the faded correction after its run ends (and,
before a kept end, takes over from it before the run starts: the step that lands on the kept
toe; over 10 or 14 frames the foot moved while still standing before the step, and skating
rose, the end seam's jerk the same; a quintic instead of the smoothstep: the same)."""


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """[start, end) of each run of True."""
    edges = np.diff(np.concatenate([[0], mask.astype(np.int8), [0]]))
    return list(zip(np.flatnonzero(edges == 1).tolist(), np.flatnonzero(edges == -1).tolist()))


def contact_runs(
    contacts: np.ndarray, min_frames: int = MIN_CONTACT_FRAMES
) -> list[tuple[int, int]]:
    """Runs [start, end) of a (T,) bool contact signal, one-frame gaps closed, short runs dropped."""
    mask = np.asarray(contacts, dtype=bool).copy()
    gaps = [(a, b) for a, b in _runs(~mask) if b - a == 1 and a > 0 and b < len(mask)]
    for a, b in gaps:
        mask[a:b] = True
    return [(a, b) for a, b in _runs(mask) if b - a >= min_frames]


def _smoothstep(x: np.ndarray) -> np.ndarray:
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


def foot_offsets(
    ankle: np.ndarray,
    toe: np.ndarray,
    contact: np.ndarray,
    blend: int | None = None,
    held: np.ndarray | None = None,
) -> np.ndarray:
    """(T, 3) translation of one foot (ankle and toe together) that plants it during contact.

    In each contact run the toe is held at its mean horizontal position and the foot's lowest
    joint brought into [0, :data:`PLANT_HEIGHT_M`]; runs whose foot stays higher than
    :data:`MAX_PLANT_HEIGHT_M` (a contact predicted in the air) are left alone. Between two runs
    the horizontal correction moves smoothly (smoothstep) from the first run's last value to the
    second's first; before the first run and after the last it fades in and out over ``blend``
    frames (default :data:`BLEND_FRAMES`). Vertically a run's lift (a foot raised out of the
    floor) fades out and in over ``blend`` frames, and its lowering (a hovering foot brought
    down) stays within the run: carried on, it held a lifting or landing foot under 5 cm while
    it moved fast, and it skated there (the 900 generated motions of the edit benchmark's
    ``inbetween`` items, seeds 6-8: skating ratio 0.2418 -> 0.2323, real 0.2291). Finally no
    foot joint stays below the floor.

    Args:
        ankle, toe: (T, 3) positions.
        contact: (T,) bool, the foot predicted on the floor.
        blend: frames of fade-in before the first run and fade-out after the last.
        held: (T,) bool, frames where the foot must stay (:func:`clean_joints` fades the
            correction out there): a run that reaches them holds the toe at its mean over the
            run's other frames.
    """
    blend = BLEND_FRAMES if blend is None else blend
    num_frames = len(toe)
    frames = np.arange(num_frames)
    lowest = np.minimum(ankle[:, 1], toe[:, 1])
    offsets = np.zeros((num_frames, 3))
    runs = [
        (start, end)
        for start, end in contact_runs(contact)
        if np.median(lowest[start:end]) <= MAX_PLANT_HEIGHT_M
    ]
    for start, end in runs:
        run = slice(start, end)
        anchor = np.array([toe[run, 0].mean(), 0.0, toe[run, 2].mean()])
        if held is not None and held[run].any() and not held[run].all():
            anchor = toe[run][~held[run]].mean(axis=0)  # where the free frames put the foot
        offsets[run, 0] = anchor[0] - toe[run, 0]
        offsets[run, 2] = anchor[2] - toe[run, 2]
        offsets[run, 1] = np.clip(lowest[run], 0.0, PLANT_HEIGHT_M) - lowest[run]
    # out of a run only a lift fades (see the docstring)
    lift = offsets.copy()
    lift[:, 1] = np.maximum(lift[:, 1], 0.0)
    for (_, end), (start, _) in zip(runs[:-1], runs[1:]):  # gaps: from one run to the next
        gap = frames[end:start]
        # Horizontally, from the one run's correction to the next; vertically, each lift fades
        # out within `blend` frames, so a foot in flight (a hop, a jump) keeps its height.
        weight = _smoothstep((gap - (end - 1)) / (start - end + 1))[:, None]
        offsets[gap] = (1 - weight) * offsets[end - 1] + weight * offsets[start]
        fade_out = 1 - _smoothstep((gap - (end - 1)) / (blend + 1))
        fade_in = 1 - _smoothstep((start - gap) / (blend + 1))
        offsets[gap, 1] = fade_out * lift[end - 1, 1] + fade_in * lift[start, 1]
    if runs:
        first, last = runs[0][0], runs[-1][1] - 1
        before = frames[max(0, first - blend) : first]
        offsets[before] = (1 - _smoothstep((first - before) / (blend + 1)))[:, None] * lift[first]
        after = frames[last + 1 : last + 1 + blend]
        offsets[after] = (1 - _smoothstep((after - last) / (blend + 1)))[:, None] * lift[last]
    if SMOOTH_FRAMES > 0:  # round the corners where a planted foot starts and stops
        offsets = gaussian_filter1d(offsets, SMOOTH_FRAMES, axis=0, mode="nearest")
    # Nothing of the foot below the floor, in contact or not.
    offsets[:, 1] -= np.minimum(lowest + offsets[:, 1], 0.0)
    return offsets


def _soft_reach(target: np.ndarray, current: np.ndarray, full: np.ndarray) -> np.ndarray:
    """Hip-to-ankle distances (T,) to use for ``target`` distances, given the ``current`` ones and
    the ``full`` leg lengths: unchanged up to ``max(current, SOFT_REACH * full)``; beyond it the
    excess approaches the full length exponentially (continuous slope), never reaching it.

    Near full extension the knee moves by sqrt(2 L dD) for a reach change dD: a hard limit
    there makes the knee jump from frame to frame.
    """
    base = np.maximum(current, SOFT_REACH * full)
    room = np.maximum(full - base, 0.0)
    excess = np.maximum(target - base, 0.0)
    soft = base + room * (1.0 - np.exp(-excess / np.maximum(room, 1e-12)))
    return np.where(target > base, soft, target)


def two_bone_knee(
    hip: np.ndarray,
    knee: np.ndarray,
    ankle: np.ndarray,
    target: np.ndarray,
    forward: np.ndarray | None = None,
    prior: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Knee and reachable ankle positions (T, 3) for an ankle ``target`` (T, 3), hip fixed.

    Thigh |knee - hip| and shin |ankle - knee| keep their per-frame lengths; the knee bends the
    way the given knee bends off the given hip-ankle line, turned into the plane of hip and
    target. A target farther from the hip than the
    given ankle and near the leg's full length is brought closer along the hip-target line
    (:func:`_soft_reach`), so a leg never snaps straight. ``forward`` (T, 3), where given (the
    foot's direction, ankle to toe): the bending plane leans toward it by
    :data:`KNEE_POLE_PRIOR_M`, so a straight generated leg bends its knee toward the toes;
    ``prior`` (T,), where given, scales that lean frame by frame.
    """
    thigh = np.linalg.norm(knee - hip, axis=-1)
    shin = np.linalg.norm(ankle - knee, axis=-1)
    reach = target - hip
    distance = np.linalg.norm(reach, axis=-1)
    along = reach / np.maximum(distance, 1e-9)[:, None]
    distance = _soft_reach(distance, np.linalg.norm(ankle - hip, axis=-1), thigh + shin)
    distance = np.maximum(distance, np.abs(thigh - shin) + 1e-6)
    new_ankle = hip + along * distance[:, None]
    # Knee: `a` along the hip-ankle line, `r` off it, towards the generated knee.
    a = (thigh**2 - shin**2 + distance**2) / (2.0 * distance)
    r = np.sqrt(np.maximum(thigh**2 - a**2, 0.0))
    # the generated knee's bend: off its own hip-ankle line (not the target's, which a large
    # correction may swing past the knee and so bend it backward)
    own = (ankle - hip) / np.maximum(np.linalg.norm(ankle - hip, axis=-1, keepdims=True), 1e-9)
    pole = knee - hip
    pole = pole - np.sum(pole * own, axis=-1, keepdims=True) * own
    if forward is not None:
        hint = forward - np.sum(forward * along, axis=-1, keepdims=True) * along
        lean = KNEE_POLE_PRIOR_M if prior is None else KNEE_POLE_PRIOR_M * prior[:, None]
        pole = pole + lean * hint / np.maximum(np.linalg.norm(hint, axis=-1, keepdims=True), 1e-9)
    pole = pole - np.sum(pole * along, axis=-1, keepdims=True) * along
    pole_norm = np.linalg.norm(pole, axis=-1)
    # A straight generated leg gives no bending plane: keep the previous frame's (or any normal).
    fallback = np.cross(along, np.array([1.0, 0.0, 0.0]))
    for t in np.flatnonzero(pole_norm < 1e-6):
        guess = pole[t - 1] if t > 0 else fallback[t]
        guess = guess - np.dot(guess, along[t]) * along[t]
        if np.linalg.norm(guess) < 1e-6:
            guess = fallback[t]
        pole[t] = guess
        pole_norm[t] = np.linalg.norm(guess)
    pole = pole / np.maximum(pole_norm, 1e-12)[:, None]
    new_knee = hip + a[:, None] * along + r[:, None] * pole
    return new_knee, new_ankle


def _held_weights(held: np.ndarray) -> np.ndarray:
    """(T,) share of a leg's correction to apply: 0 on ``held`` (T,) frames, eased up to 1 over
    :data:`HELD_BLEND_FRAMES` frames away from the nearest one (smoothstep)."""
    frames = np.arange(len(held))
    rows = np.flatnonzero(held)
    if rows.size == 0:
        return np.ones(len(held))
    nearest = np.abs(frames[:, None] - rows[None, :]).min(axis=1)
    return _smoothstep(nearest / (HELD_BLEND_FRAMES + 1))


def _unit(vectors: np.ndarray) -> np.ndarray:
    return vectors / np.maximum(np.linalg.norm(vectors, axis=-1, keepdims=True), 1e-12)


def _pivot_ankle(
    toe: np.ndarray, rigid: np.ndarray, hip: np.ndarray, foot: np.ndarray, limit: np.ndarray
) -> np.ndarray:
    """Ankles (N, 3) at distance ``foot`` (N,) from ``toe`` (N, 3), turned about the toe from
    ``rigid`` (where the foot's own shape puts them) toward ``hip`` by the least angle that
    brings them within ``limit`` (N,) of the hip: the heel lifts as a stance foot's does when the
    body moves past it. Every row must be reachable pointing at the hip."""
    start, toward = _unit(rigid - toe), _unit(hip - toe)

    def ankle(share: np.ndarray) -> np.ndarray:
        return toe + foot[:, None] * _unit(_mix(start, toward, share))

    low, high = np.zeros(len(toe)), np.ones(len(toe))
    for _ in range(30):  # bisection on the share of the turn: 1e-9 of it
        middle = 0.5 * (low + high)
        reaches = np.linalg.norm(ankle(middle) - hip, axis=-1) <= limit
        high = np.where(reaches, middle, high)
        low = np.where(reaches, low, middle)
    fits = np.linalg.norm(rigid - hip, axis=-1) <= limit
    return np.where(fits[:, None], rigid, ankle(high))


def _mix(a: np.ndarray, b: np.ndarray, share: np.ndarray) -> np.ndarray:
    """``a + share (b - a)`` row by row (``share`` (N,))."""
    return a + share[:, None] * (b - a)


def _place_foot(
    out: np.ndarray,
    joints: np.ndarray,
    rows: np.ndarray,
    leg: tuple[int, int, int, int],
    children: list[int],
    toes: np.ndarray,
    toe_to_ankle: np.ndarray,
    prior: np.ndarray | None = None,
) -> None:
    """Write one leg into ``out`` on ``rows``: the ankle at ``toes + toe_to_ankle`` (N, 3), the
    knee by :func:`two_bone_knee` from ``joints`` (thigh and shin keep their lengths; bent toward
    the toes where the generated leg is straight, by ``prior`` (N,) of
    :data:`KNEE_POLE_PRIOR_M`, all of it where None), the toe and the ankle's other children
    following the ankle where the IK holds it back."""
    hip, knee, ankle, toe = leg
    wanted = toes + toe_to_ankle
    # nothing of the foot below the floor (a turned foot can point its heel down)
    lift = np.maximum(-np.minimum(wanted[:, 1], toes[:, 1]), 0.0)
    toes = toes + lift[:, None] * np.array([0.0, 1.0, 0.0])
    wanted = toes + toe_to_ankle
    knees, ankles = two_bone_knee(
        joints[rows, hip], joints[rows, knee], joints[rows, ankle], wanted, -toe_to_ankle, prior
    )
    out[rows, knee] = knees
    out[rows, ankle] = ankles
    out[rows, toe] = toes + (ankles - wanted)
    for child in children:
        out[rows, child] = joints[rows, child] + (ankles - joints[rows, ankle])


def plant_near_held(
    joints: np.ndarray,
    cleaned: np.ndarray,
    contact: np.ndarray,
    frozen: np.ndarray,
    leg: tuple[int, int, int, int],
    children: list[int],
    weights: np.ndarray,
) -> np.ndarray:
    """``cleaned`` (T, J, 3) with one leg's contact runs next to held frames planted outright.

    Near held frames :func:`clean_joints` fades its correction in (:data:`HELD_BLEND_FRAMES`),
    so a foot on the floor there still slides with the generated motion (the edit benchmark's
    inbetween: 0.331 of the first second's frames skating against 0.241 in real motion). Here
    a contact run that goes on from held frames keeps the toe where the held frames leave it,
    and one that starts within the fade keeps it where the faded correction puts it on its first
    frame (horizontally: heights as the lock sets them, the foot's lowest joint into
    [0, :data:`PLANT_HEIGHT_M`], and nothing of the foot under the floor; a toe pulled down to
    the floor pushed a raised heel through it); the ankle follows the foot's own
    shape while the leg reaches (:data:`SOFT_REACH` of its length, or more where the generated
    leg is longer), else turns about the toe toward the hip (the heel lifts); where even that
    cannot reach, the plant ends. The planted leg takes over from ``cleaned`` over
    :data:`HELD_PLANT_RAMP_FRAMES` from the nearest held frame and hands back over
    :data:`HELD_PLANT_RELEASE_FRAMES` after the plant ends.

    A run that goes on into held frames (a kept end) stands where the first held frame has the
    toe from the first of its free frames that the leg reaches it on (the same reach and heel
    lift), the foot's direction taken over as above; the :data:`HELD_PLANT_RELEASE_FRAMES`
    frames before the plant carry the toe there (the step that lands on it). With the faded
    correction instead, the foot slid to the kept toe while standing: on the edit benchmark's
    inbetween with unrelated kept ends (demo model, seed 3, 300 items), skating peaked at 45%
    of the items 3 frames before the kept end against 12% in mid-edit.

    ``contact``, ``frozen``: (T,) bool; ``leg``: hip, knee, ankle and toe joints; ``children``:
    the ankle's other children (moved with it); ``weights``: the fade's shares
    (:func:`_held_weights` of ``frozen``, as ``clean_joints`` applied them).
    """
    hip, knee, ankle, toe = leg
    out = cleaned.copy()
    lowest = np.minimum(joints[:, ankle, 1], joints[:, toe, 1])
    held_rows = np.flatnonzero(frozen)
    thigh = np.linalg.norm(joints[:, knee] - joints[:, hip], axis=-1)
    shin = np.linalg.norm(joints[:, ankle] - joints[:, knee], axis=-1)
    foot = np.linalg.norm(joints[:, toe] - joints[:, ankle], axis=-1)
    for start, end in contact_runs(contact):
        if np.median(lowest[start:end]) > MAX_PLANT_HEIGHT_M:
            continue
        held = frozen[start:end]
        rows = np.arange(start, end)[~held]
        if not len(rows):
            continue
        into_held = bool(held.any() and not held[0])  # the run reaches held frames later
        if not held.any() and (weights[rows] >= 1.0).all():
            continue  # out of the fade: the plain clean-up planted it
        if into_held:  # the free frames just before the first held one: the foot stands there
            first_held = start + int(np.argmax(held))
            rows = rows[rows < first_held]
            anchor = joints[first_held, toe]
        else:
            if rows[-1] - rows[0] + 1 != len(rows):
                rows = rows[: int(np.argmax(np.diff(rows) > 1)) + 1]  # up to the next held frame
            anchor = joints[rows[0] - 1, toe] if held.any() else cleaned[rows[0], toe]
        toes = np.repeat(anchor[None], len(rows), axis=0)
        # heights as the lock sets them: the foot's lowest joint into [0, PLANT_HEIGHT_M]
        toes[:, 1] = (
            joints[rows, toe, 1] + np.clip(lowest[rows], 0.0, PLANT_HEIGHT_M) - lowest[rows]
        )
        hips = joints[rows, hip]
        limit = np.maximum(
            np.linalg.norm(joints[rows, ankle] - hips, axis=-1),
            SOFT_REACH * (thigh[rows] + shin[rows]),
        )
        reachable = np.linalg.norm(hips - toes, axis=-1) <= limit + foot[rows]
        out_of_reach = np.flatnonzero(~reachable)
        if into_held:  # the plant begins after the last frame the leg cannot reach the toe on
            keep = slice(out_of_reach[-1] + 1 if len(out_of_reach) else 0, None)
        else:  # the plant ends at the first such frame
            keep = slice(None, out_of_reach[0] if len(out_of_reach) else None)
        rows, toes, hips, limit = rows[keep], toes[keep], hips[keep], limit[keep]
        if not len(rows):
            continue
        if into_held and frozen[max(rows[0] - HELD_PLANT_RELEASE_FRAMES, 0) : rows[0]].any():
            continue  # no room for the step onto the kept toe: it stands on earlier held frames
        rigid = toes + joints[rows, ankle] - joints[rows, toe]
        ankles = _pivot_ankle(toes, rigid, hips, foot[rows], limit)
        # Blend toe positions and foot directions (not joints: the foot keeps its length), the
        # knee placed by IK for the blended ankle: in from the held frames, out after the plant
        # (before it, for a plant that goes on into held frames). Into held frames the toe stays
        # put: it is where the first held frame has it, and the faded correction slides there.
        nearest = np.abs(rows[:, None] - held_rows[None, :]).min(axis=1)
        share = _smoothstep(nearest / (HELD_PLANT_RAMP_FRAMES + 1))
        directions = _mix(
            _unit(cleaned[rows, ankle] - cleaned[rows, toe]), _unit(ankles - toes), share
        )
        if not into_held:
            toes = _mix(cleaned[rows, toe], toes, share)
        _place_foot(
            out, joints, rows, leg, children, toes, _unit(directions) * foot[rows, None], share
        )
        edge = rows[0] if into_held else rows[-1]
        step = -1 if into_held else 1
        around = edge + step * np.arange(1, HELD_PLANT_RELEASE_FRAMES + 1)
        around = around[(around >= 0) & (around < len(joints))]
        around = around[~frozen[around]]
        if len(around):
            release = 1.0 - _smoothstep(np.abs(around - edge) / (HELD_PLANT_RELEASE_FRAMES + 1))
            toes = cleaned[around, toe] + release[:, None] * (out[edge, toe] - cleaned[edge, toe])
            directions = _mix(
                _unit(cleaned[around, ankle] - cleaned[around, toe]),
                np.repeat(_unit(out[edge, ankle] - out[edge, toe])[None], len(around), axis=0),
                release,
            )
            # the whole lean here (prior None): the step onto a kept toe moves the foot far from
            # the given leg, and a faded lean let 1% more knees bend backward before kept ends
            _place_foot(
                out, joints, around, leg, children, toes, _unit(directions) * foot[around, None]
            )
    return out


def leg_of(skeleton: SkeletonSpec, foot: int) -> tuple[int, int, int]:
    """(hip, knee, ankle) of the leg whose chain holds the contact joint ``foot``: the chain's
    three joints after the root. SMPL: the contact joint is the ankle (7 or 8); KIT-ML: it is
    below the ankle (the metatarsal, 14 or 19), so the ankle is not its parent's parent."""
    chain = next(c for c in skeleton.chains if foot in c)
    hip, knee, ankle = chain[1:4]
    return hip, knee, ankle


def _descendants(parents: Sequence[int], joint: int) -> list[int]:
    """Every joint below ``joint`` in the tree, in index order."""
    below: list[int] = []
    for j in range(len(parents)):
        p = parents[j]
        while p >= 0 and p != joint:
            p = parents[p]
        if p == joint:
            below.append(j)
    return below


def clean_joints(
    joints: np.ndarray,
    contacts: np.ndarray,
    skeleton: SkeletonSpec | None = None,
    held: np.ndarray | None = None,
) -> np.ndarray:
    """Cleaned copy of joints (T, J, 3) given contact channels (T, 4) (see the module docstring).

    ``held`` (T, J) bool: joints that must not move (an edit's kept joints). A leg is left exactly
    as given on the frames where its knee, ankle or foot joints are held; elsewhere its correction
    is faded in over :data:`HELD_BLEND_FRAMES` frames from those frames, and contact runs that
    reach them plant the foot at its mean over their free frames; contact runs that go on from
    held frames or start within the fade are planted outright (:func:`plant_near_held`). None:
    the plain clean-up.

    Raises ValueError for shapes that do not fit.
    """
    joints = np.asarray(joints, dtype=np.float64)
    if joints.ndim != 3 or joints.shape[-1] != 3 or len(joints) < 2:
        raise ValueError(f"joints must be (T >= 2, J, 3), got {joints.shape}")
    contacts = np.asarray(contacts, dtype=np.float64)
    if contacts.shape != (len(joints), 4):
        raise ValueError(f"contacts must be ({len(joints)}, 4), got {contacts.shape}")
    skeleton = skeleton or skeleton_for(joints.shape[1])
    parents = skeleton.parents
    if held is not None:
        held = np.asarray(held, dtype=bool)
        if held.shape != joints.shape[:2]:
            raise ValueError(f"held must be {joints.shape[:2]}, got {held.shape}")
    planted = contacts > CONTACT_THRESHOLD
    out = joints.copy()
    for side, (foot, toe) in enumerate((skeleton.feet_left, skeleton.feet_right)):
        hip, knee, ankle = leg_of(skeleton, foot)
        below = _descendants(parents, ankle)  # the foot: moves rigidly with the ankle
        contact = planted[:, 2 * side] | planted[:, 2 * side + 1]
        leg = sorted({knee, ankle, *below})
        frozen = None if held is None else held[:, leg].any(axis=1)
        if frozen is not None and frozen.all():
            continue
        offsets = foot_offsets(joints[:, ankle], joints[:, toe], contact, held=frozen)
        if frozen is not None and frozen.any():
            weights = _held_weights(frozen)
            offsets = offsets * weights[:, None]
        if np.any(offsets):
            new_knee, new_ankle = two_bone_knee(
                joints[:, hip],
                joints[:, knee],
                joints[:, ankle],
                joints[:, ankle] + offsets,
                joints[:, toe] - joints[:, ankle],
                None if frozen is None or not frozen.any() else weights,
            )
            out[:, knee] = new_knee
            out[:, ankle] = new_ankle
            # The toe (and anything below the ankle) moves with the ankle: the foot stays rigid.
            for joint in below:
                out[:, joint] = joints[:, joint] + (new_ankle - joints[:, ankle])
        if frozen is not None and frozen.any():
            children = [j for j in below if j != toe]
            leg_joints = (hip, knee, ankle, toe)
            out = plant_near_held(joints, out, contact, frozen, leg_joints, children, weights)
            out[np.ix_(frozen, leg)] = joints[np.ix_(frozen, leg)]  # exactly as given
    return out


def front_knees(
    joints: np.ndarray, skeleton: SkeletonSpec | None = None, free: np.ndarray | None = None
) -> np.ndarray:
    """Copy of joints (T, J, 3) whose knees bend to the front of the body.

    A knee's bend is where it sits off its hip-ankle line, as an angle about that line from the
    body's front (the direction square to the line and to the hips' left-right axis). A knee
    bent behind the line (more than 90 degrees from the front) is mirrored to the front across
    the plane of the line and the left-right axis: the angle a goes to 180 - a, a continuous map
    that leaves every other knee, the hips, ankles and feet exactly where they are, and keeps
    the thigh and shin lengths. Real knees never bend behind (0 of 128,132 leg-frames of the demo
    corpus' test clips bend 3 cm or more behind); a per-joint correction (an edit's seam easing)
    can put them there. ``free`` (T, J) bool: only knees free on a frame move (default all).
    """
    joints = np.asarray(joints, dtype=np.float64)
    skeleton = skeleton or skeleton_for(joints.shape[1])
    right_hip, left_hip = skeleton.face_joints[:2]
    lateral = joints[:, right_hip] - joints[:, left_hip]
    free = None if free is None else np.asarray(free, dtype=bool)
    out = joints.copy()
    for foot, _ in (skeleton.feet_left, skeleton.feet_right):
        hip, knee, ankle = leg_of(skeleton, foot)
        line = _unit(joints[:, ankle] - joints[:, hip])
        front = np.cross(lateral, line)
        norm = np.linalg.norm(front, axis=-1, keepdims=True)
        front = front / np.maximum(norm, 1e-12)
        offset = joints[:, knee] - joints[:, hip]
        bend = offset - np.sum(offset * line, -1, keepdims=True) * line
        ahead = np.sum(bend * front, -1)
        # behind the line (and a front that is defined: the leg not along the hips' axis)
        move = (ahead < 0) & (norm[:, 0] > 1e-6)
        if free is not None:
            move &= free[:, knee]
        out[move, knee] -= 2.0 * ahead[move, None] * front[move]
    return out


def features_with_joints(features: np.ndarray, joints: np.ndarray) -> np.ndarray:
    """Features (T, D) of ``joints`` (T, J, 3) that share the root of ``features`` (T, D):
    the root channels and the foot contacts are kept; joint positions (ric) and velocities are
    the joints' in the features' own facing frame (so ``recover_from_ric`` gives the joints
    back, to float32 rounding), the 6-D rotations come from inverse kinematics of the joints (the
    last frame's velocity from a linear extrapolation). Float32.
    """
    features = np.asarray(features)
    layout = FeatureLayout.for_dim(features.shape[-1])
    num_frames, num_joints = len(features), layout.num_joints
    if features.ndim != 2 or num_frames < 2:
        raise ValueError(f"features must be (T >= 2, {layout.dim}), got {features.shape}")
    joints = np.asarray(joints, dtype=np.float64)
    if joints.shape != (num_frames, num_joints, 3):
        raise ValueError(f"joints must be ({num_frames}, {num_joints}, 3), got {joints.shape}")
    skeleton = skeleton_for(num_joints)
    extended = np.concatenate([joints, 2 * joints[-1:] - joints[-2:-1]], axis=0)  # (T+1, J, 3)
    facing, root = recover_root(features.astype(np.float64))  # (T, 4) world -> facing
    facing_per_joint = np.broadcast_to(facing[:, None], (num_frames, num_joints, 4))
    ric = joints.copy()
    ric[..., [0, 2]] -= root[:, None, [0, 2]]
    ric = qrot(facing_per_joint, ric)  # (T, J, 3)
    velocity = qrot(facing_per_joint, extended[1:] - extended[:-1])  # (T, J, 3)
    out = features.astype(np.float64).copy()
    out[:, layout.ric] = ric[:, 1:].reshape(num_frames, -1)
    out[:, layout.local_velocity] = velocity.reshape(num_frames, -1)
    local = inverse_kinematics(extended, skeleton, smooth_sigma=FACING_SMOOTH_SIGMA, compat=True)
    out[:, layout.rot6d] = quat_to_6d(local[:-1, 1:]).reshape(num_frames, -1)
    return out.astype(np.float32)


def clean_features(features: np.ndarray) -> np.ndarray:
    """Raw generated features (T, D) -> features of the cleaned motion (T, D), float32.

    Joints are recovered and cleaned (:func:`clean_joints`, with the features' contact channels).
    The root features and the contact channels stay the model's; the joint positions (ric) and
    velocities are those of the cleaned joints in the model's own facing frame (so
    ``recover_from_ric`` gives exactly the cleaned joints), the 6-D rotations come from inverse
    kinematics of the cleaned joints (the last frame's velocity from a linear extrapolation).
    """
    features = np.asarray(features)
    layout = FeatureLayout.for_dim(features.shape[-1])
    if features.ndim != 2 or len(features) < 2:
        raise ValueError(f"features must be (T >= 2, {layout.dim}), got {features.shape}")
    skeleton = skeleton_for(layout.num_joints)
    joints = recover_from_ric(features.astype(np.float64), layout.num_joints)
    cleaned = clean_joints(joints, features[:, layout.foot_contact], skeleton)
    return features_with_joints(features, cleaned)


__all__ = [
    "features_with_joints",
    "BLEND_FRAMES",
    "CONTACT_THRESHOLD",
    "HELD_BLEND_FRAMES",
    "HELD_PLANT_RAMP_FRAMES",
    "HELD_PLANT_RELEASE_FRAMES",
    "MAX_PLANT_HEIGHT_M",
    "MIN_CONTACT_FRAMES",
    "PLANT_HEIGHT_M",
    "SOFT_REACH",
    "clean_features",
    "clean_joints",
    "contact_runs",
    "plant_near_held",
    "foot_offsets",
    "front_knees",
    "leg_of",
    "two_bone_knee",
]
