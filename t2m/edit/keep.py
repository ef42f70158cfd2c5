"""Finishing an edit's result: the hard keep (the generated side of every seam smoothed, kept
features copied, every seam eased, the root's heading and floor path bent to meet kept stretches
and root targets), then the rigid fit on the model's skeleton that leaves kept joints where the
source has them, then the body's height near seams put back on the floor where the generated
motion stands (:func:`keep_floor`), then the foot-contact clean-up that never moves a kept or
targeted joint, then free knees bent behind the leg mirrored to the front
(:func:`knees_to_front`; steps 5-6 of :mod:`t2m.edit.core`)."""

from __future__ import annotations

import numpy as np
import torch
from scipy.ndimage import gaussian_filter1d

from dataset_tools.cleanup import features_with_joints, front_knees
from dataset_tools.representation import FeatureLayout, recover_from_ric
from dataset_tools.rigid import finish_features
from t2m.edit.plan import EditPlan
from t2m.edit.recover import yaw_rotate
from t2m.edit.source import half_yaw_of

SEAM_SMOOTH_SIGMA = 2.5
"""Standard deviation (frames) of the Gaussian that smooths the generated side of a seam: the
model's output is jerkiest for about ten frames after the kept start it continues from (its own
change from the read start to new motion): 1.4x the jerk of real motion over the 0.5 s around a
``continue`` seam without it, 0.9x with 1.5 frames over 8 (demo model, docs/editing.md). With the
clean-up's plant onto kept ends, inbetween with unrelated ends (seeds 3-5, 300 items each) was
1.38x real jerk at 1.5 frames over 8, 1.31x at 2.5 over 8, 1.26x at 2.5 over 9 (1.23x over 10,
where the source's own ends skated 0.0014 more); 3 frames did no better than 2.5 (seed 3)."""
SEAM_SMOOTH_FRAMES = 9
"""Frames over which that smoothing fades out into the free run (fully applied on the first)."""


FLOOR_CONTACT_M = 0.05
"""Height (m) of the generated motion's lowest foot joint under which :func:`keep_floor` takes
the foot as standing on the floor (the detectors' own contact height)."""
FLOOR_SMOOTH_SIGMA = 1.0
"""Standard deviation (frames) of the Gaussian over :func:`keep_floor`'s per-frame shift."""


def finish_plan(
    generated: np.ndarray, plan: EditPlan, blend: int = 16, clean: bool = True
) -> np.ndarray:
    """Features (T, D) of a finished result: :func:`hard_keep`, then rigid on the model's
    skeleton, the joints kept from the source left where they are, then :func:`keep_floor`
    (frames with no kept joint only), then (``clean``) the foot-contact clean-up
    (:func:`dataset_tools.cleanup.clean_joints`) with every kept or targeted joint held: kept
    joints stay exactly where the rigid fit leaves them; then :func:`knees_to_front` on the
    joints not kept or targeted."""
    rigid = finish_features(hard_keep(generated, plan, blend), False, held=plan.keep)
    grounded = keep_floor(rigid, smooth_seams(generated, plan.keep), plan.keep)
    finished = finish_features(grounded, clean, held=plan.keep, clean_held=plan.kept_mask())
    return knees_to_front(finished, ~plan.kept_mask())


def knees_to_front(features: np.ndarray, free: np.ndarray) -> np.ndarray:
    """Features (T, D) whose free knees (``free`` (T, J) bool) bent behind the hip-ankle line
    are mirrored to the front (:func:`dataset_tools.cleanup.front_knees`); the features as given
    where none is. The hard keep eases each joint into the kept side with its own rate of
    change, so hip, knee and ankle can overshoot apart and the knee end up behind the leg (about 1%
    of free leg-frames near seams, demo model, docs/editing.md); everything but those knees
    stays."""
    layout = FeatureLayout.for_dim(features.shape[-1])
    joints = recover_from_ric(features.astype(np.float64), layout.num_joints)
    fronted = front_knees(joints, free=free)
    if np.array_equal(fronted, joints):
        return features
    return features_with_joints(features, fronted)


def _lowest_foot(features: np.ndarray, layout: FeatureLayout) -> np.ndarray:
    """(T,) height of the lowest ankle or foot joint (SMPL 7, 8, 10, 11) of features (T, D)."""
    heights = features[:, layout.ric][:, 1::3]  # (T, J-1): ric stores heights as they are
    return heights[:, [7 - 1, 8 - 1, 10 - 1, 11 - 1]].min(axis=1)


def keep_floor(
    features: np.ndarray,
    generated: np.ndarray,
    keep: np.ndarray,
    contact: float = FLOOR_CONTACT_M,
    sigma: float = FLOOR_SMOOTH_SIGMA,
) -> np.ndarray:
    """Features (T, D) whose whole body is moved up or down, one amount per frame, on the
    frames where no joint is kept (``keep`` (T, J)): never below the floor (height 0), and on
    the free frames nearer a kept stretch before them than one after them, the lowest foot
    joint where ``generated`` (T, D: the model's output the seams were fitted to) has it
    whenever the model has a foot within ``contact`` of the floor. The shift is smoothed by a
    Gaussian of ``sigma`` frames (kept frames get none).

    A seam's offsets carry the kept side's heights and their rate of change into the generated
    side joint by joint, and the rigid fit then hangs the legs from the carried pelvis: a body
    that was rising or falling at the seam floated up to 20 cm over the floor, or sank through
    it, for most of a second, which reads as a jump (a walk or a stand not recognised; demo
    model, ``continue`` 0.490 -> 0.542 of the regenerated parts recognised, docs/editing.md).
    Before a kept stretch (an inbetween's kept end) the body is only lifted out of the floor:
    there the root path is bent and eased toward the kept end's, and feet put down on the floor
    slide (the edit benchmark's inbetween skating 0.172 against 0.155 and real motion's 0.158).
    Frames with a kept joint (body edits) are left alone: kept joints never move. SMPL-like
    skeletons of 22 joints only (others are returned unchanged)."""
    layout = FeatureLayout.for_dim(features.shape[1])
    free = ~keep.any(axis=1)
    if layout.num_joints != 22 or not free.any() or free.all():
        return features
    out = features.astype(np.float64)
    made, model = _lowest_foot(out, layout), _lowest_foot(generated, layout)
    rows = np.arange(len(free))
    kept_rows = np.flatnonzero(~free)
    after = np.searchsorted(kept_rows, rows)  # index of the first kept row at or after each row
    previous = np.where(after > 0, kept_rows[np.maximum(after - 1, 0)], -len(rows) - 1)
    following = np.where(
        after < len(kept_rows), kept_rows[np.minimum(after, len(kept_rows) - 1)], 2 * len(rows) + 1
    )
    after_start = rows - previous <= following - rows
    planted = (model < contact) & after_start
    wanted = np.where(planted, model, np.maximum(made, 0.0))
    shift = np.where(free, wanted - made, 0.0)
    if sigma > 0:
        shift = np.where(free, gaussian_filter1d(shift, sigma, mode="nearest"), 0.0)
    if not shift.any():
        return features
    out[:, layout.root_height] += shift[:, None]
    out[:, layout.ric.start + 1 : layout.ric.stop : 3] += shift[:, None]
    step = np.append(np.diff(shift), 0.0)  # velocities are y-up in every facing frame
    out[:, layout.local_velocity.start + 1 : layout.local_velocity.stop : 3] += step[:, None]
    return out.astype(features.dtype)


def joint_columns(num_joints: int) -> list[np.ndarray]:
    """Feature columns that belong to each joint: the root owns the four root dimensions and
    its velocity; joint j its ric, 6-D rotation and velocity; the feet their contact flags."""
    layout = FeatureLayout(num_joints)
    columns = []
    for joint in range(num_joints):
        lv = layout.local_velocity.start + 3 * joint
        if joint == 0:
            own = [*range(layout.root.start, layout.root.stop), lv, lv + 1, lv + 2]
        else:
            ric = layout.ric.start + 3 * (joint - 1)
            rot = layout.rot6d.start + 6 * (joint - 1)
            own = [*range(ric, ric + 3), *range(rot, rot + 6), lv, lv + 1, lv + 2]
        columns.append(np.array(own))
    if num_joints == 22:  # SMPL: ankles and feet carry the contact flags (left pair, right pair)
        contact = layout.foot_contact.start
        for joint, flag in ((7, 0), (10, 1), (8, 2), (11, 3)):
            columns[joint] = np.append(columns[joint], contact + flag)
    return columns


def _ease(x: np.ndarray) -> np.ndarray:
    """Smoothstep 3x^2 - 2x^3 on [0, 1] (zero slope at both ends), clipped outside."""
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


def _runs(flags: np.ndarray) -> list[tuple[int, int]]:
    """[start, stop) of every run of False in a 1-D bool array."""
    padded = np.concatenate([[True], flags, [True]])
    change = np.flatnonzero(padded[1:] != padded[:-1])
    return list(zip(change[::2], change[1::2]))


def _seam_weights(start: int, stop: int, frames: int, blend: int) -> tuple[np.ndarray, np.ndarray]:
    """Weights (stop-start,) of the offsets from the kept frame before (``start - 1``) and after
    (``stop``) a free run: 1 at the kept frame, eased to 0 over ``blend`` frames; a run too
    short for both ends to fade hands one offset over to the other."""
    t = np.arange(start, stop, dtype=np.float64)
    has_before, has_after = start > 0, stop < frames
    span = stop - start + 1
    if has_before and has_after and span <= 2 * blend:
        rise = _ease((t - (start - 1)) / span)
        return 1.0 - rise, rise
    before = 1.0 - _ease((t - (start - 1)) / blend) if has_before else np.zeros_like(t)
    after = 1.0 - _ease((stop - t) / blend) if has_after else np.zeros_like(t)
    return before, after


def smooth_seams(
    generated: np.ndarray,
    keep: np.ndarray,
    sigma: float = SEAM_SMOOTH_SIGMA,
    frames: int = SEAM_SMOOTH_FRAMES,
) -> np.ndarray:
    """Generated features (T, D) smoothed next to seams: per joint with kept (``keep`` (T, J))
    and free frames, its columns (not the contact flags) take a Gaussian of ``sigma`` frames of
    themselves on kept frames and the first free one, eased back to the generated values over
    ``frames`` more (smoothstep of the distance to the nearest kept frame). Joints kept on every
    frame or none are unchanged."""
    num_frames, num_joints = keep.shape
    weights = np.zeros(generated.shape)
    rows = np.arange(num_frames)
    for joint, columns in enumerate(joint_columns(num_joints)):
        kept = keep[:, joint]
        if not kept.any() or kept.all():
            continue
        distance = np.abs(rows[:, None] - np.flatnonzero(kept)[None, :]).min(axis=1)
        weights[:, columns] = 1.0 - _ease((distance[:, None] - 1.0) / frames)
    if not weights.any():
        return generated
    weights[:, FeatureLayout(num_joints).foot_contact] = 0.0
    values = generated.astype(np.float64)
    smoothed = gaussian_filter1d(values, sigma, axis=0, mode="nearest")
    return (values + weights * (smoothed - values)).astype(generated.dtype)


JOIN_SMOOTH_SIGMA = 0.6
"""Standard deviation (frames) of the Gaussian over both sides of a join of two generated
stretches (:func:`smooth_join`): compose's windows. Each side is the model's own motion,
about 1.4x the jerk of the calmer real clips (plain generation at random frames); without it
a compose seam was 1.57x real motion's jerk over the 0.5 s around it, with sigma 0.5 1.18x,
0.6 0.97x (acceleration 1.07x), 1.0 0.47x (a blur: acceleration 0.66x; seed 0), the
segments' semantic accuracy the same (demo model, docs/editing.md)."""
JOIN_REACH_SECONDS = 0.25
"""How far the join's smoothing reaches on each side at full weight (then it fades out over
:data:`SEAM_SMOOTH_FRAMES`): the half-second around a seam that the edit benchmark judges."""


def smooth_join(
    features: np.ndarray,
    join: int,
    fps: float,
    fixed: int = 0,
    sigma: float = JOIN_SMOOTH_SIGMA,
) -> np.ndarray:
    """Features (T, D) of two generated stretches joined at frame ``join`` smoothed on both
    sides: within :data:`JOIN_REACH_SECONDS` of the join every joint's columns (not the foot
    contacts) take a Gaussian of ``sigma`` frames of themselves, eased back to the features
    over :data:`SEAM_SMOOTH_FRAMES` more (:func:`smooth_seams`'s weights). The first ``fixed``
    frames (a kept source) are left exactly as they are."""
    reach = max(1, int(round(JOIN_REACH_SECONDS * fps)))
    zone = np.zeros((len(features), FeatureLayout.for_dim(features.shape[1]).num_joints), bool)
    zone[max(join - reach, 0) : join + reach] = True
    out = smooth_seams(features, zone, sigma)
    out[:fixed] = features[:fixed]
    return out


def hard_keep(generated: np.ndarray, plan: EditPlan, blend: int = 16) -> np.ndarray:
    """Features (T, D) that copy the plan's kept features and meet its root targets exactly.

    0. the generated side of every seam is smoothed (:func:`smooth_seams`);
    1. per joint, kept frames take the source's features; every free run's generated features
       are offset by the kept-minus-generated difference at the kept frame before and after it,
       eased to nothing over ``blend`` frames (so the generated velocities carry on across);
    2. the heading (integrated yaw) is bent smoothly so that frames whose root is kept face as
       the source does;
    3. the floor position of the root is bent smoothly so that frames whose root is kept stand
       where the source does and root targets (x, z) are met; the root velocities are rewritten
       from the bent path (in each frame's facing frame, as the representation stores them).
    """
    frames, num_joints = plan.keep.shape
    features = generated.copy()
    if plan.source_features is not None and plan.keep.any():
        generated = smooth_seams(generated, plan.keep)
        features = generated.copy()
        source = plan.source_features.astype(np.float64)
        trend = trend_columns(FeatureLayout(num_joints))
        for joint, columns in enumerate(joint_columns(num_joints)):
            kept = plan.keep[:, joint]
            if not kept.any():
                continue
            features[np.ix_(kept, columns)] = source[np.ix_(kept, columns)]
            for start, stop in _runs(kept):
                before, after = _seam_weights(start, stop, frames, blend)
                rows = np.arange(start, stop)
                if start > 0:  # the kept frame before: meet its value and its rate of change
                    correction = _seam_correction(
                        source, generated, columns, start - 1, kept, +1, trend[columns]
                    )
                    features[np.ix_(rows, columns)] += before[:, None] * correction(rows)
                if stop < frames:  # the kept frame after
                    correction = _seam_correction(
                        source, generated, columns, stop, kept, -1, trend[columns]
                    )
                    features[np.ix_(rows, columns)] += after[:, None] * correction(rows)
    # 2.-3. the root's heading and floor path
    anchors_yaw = plan.keep[:, 0] if plan.source_half_yaw is not None else np.zeros(frames, bool)
    root_xz = np.full((frames, 2), np.nan)
    if plan.keep[:, 0].any():
        root_xz[plan.keep[:, 0]] = plan.target[plan.keep[:, 0], 0][:, [0, 2]]
    given = np.isfinite(plan.target[:, 0, [0, 2]]).all(-1) & ~plan.keep[:, 0]
    root_xz[given] = plan.target[given, 0][:, [0, 2]]
    if anchors_yaw[1:].any():
        half_yaw = half_yaw_of(features)
        residual = _bend(np.where(anchors_yaw, plan.source_half_yaw - half_yaw, np.nan))
        bent = half_yaw + residual
        features[:-1, 0] = np.diff(bent)
    if np.isfinite(root_xz[1:]).all(-1).any():
        half_yaw = half_yaw_of(features)
        path = recover_from_ric(features, num_joints)[:, 0][:, [0, 2]]
        residual = np.stack([_bend(root_xz[:, axis] - path[:, axis]) for axis in range(2)], axis=-1)
        bent = path + residual  # (T, 2)
        step = np.zeros((frames - 1, 3))
        step[:, [0, 2]] = np.diff(bent, axis=0)
        local = yaw_rotate(torch.from_numpy(step), torch.from_numpy(2.0 * half_yaw[1:])).numpy()
        features[:-1, 1:3] = local[:, [0, 2]]
    return features


def trend_columns(layout: FeatureLayout) -> np.ndarray:
    """(D,) bool: the feature columns that are per-frame positions or rotations (the root's
    height, joint positions, 6-D rotations), whose seam offset carries the kept side's rate of
    change (:func:`_seam_correction`). Not the velocities (the root's rotational and linear
    velocities, the joints' local velocities), for which that rate is an acceleration mismatch
    that drifts over the blend, nor the foot contacts: edits followed their text less with it
    (demo model, ``continue`` semantic accuracy 0.43 with the term on velocities, 0.50 without;
    seam jerk the same)."""
    trend = np.zeros(layout.dim, bool)
    for part in (layout.root_height, layout.ric, layout.rot6d):
        trend[part] = True
    return trend


def _seam_correction(
    source: np.ndarray,
    generated: np.ndarray,
    columns: np.ndarray,
    frame: int,
    kept: np.ndarray,
    direction: int,
    trend: np.ndarray,
):
    """The offset that makes the generated side of a seam meet kept ``frame`` in value and, on
    the ``trend`` columns (bool, one per column, :func:`trend_columns`), in per-frame change:
    ``offset + change * (t - frame)`` for rows t on the free side (``direction`` +1: after
    ``frame``, -1: before it), to be eased out by the seam weights. The change is the kept side's
    step next to the seam minus the generated one (zero when the kept side has one frame only,
    and on the other columns)."""
    offset = source[frame, columns] - generated[frame, columns]
    inner = frame - direction  # the kept neighbour on the far side of the seam
    change = np.zeros_like(offset)
    if 0 <= inner < len(kept) and kept[inner]:
        kept_step = (source[frame, columns] - source[inner, columns]) * direction
        generated_step = (
            generated[frame + direction, columns] - generated[frame, columns]
        ) * direction
        change = (kept_step - generated_step) * trend

    def correction(rows: np.ndarray) -> np.ndarray:
        return offset + change * (rows - frame)[:, None]

    return correction


def _bend(residual: np.ndarray) -> np.ndarray:
    """(T,) correction that equals ``residual`` where it is finite, 0 at frame 0 when that is not
    given (the representation starts every motion at the origin, facing +Z), eased between given
    frames and held after the last."""
    values = residual.copy()
    if not np.isfinite(values[0]):
        values[0] = 0.0
    given = np.flatnonzero(np.isfinite(values))
    out = np.empty_like(values)
    for left, right in zip(given[:-1], given[1:]):
        x = _ease((np.arange(left, right + 1) - left) / (right - left))
        out[left : right + 1] = values[left] + (values[right] - values[left]) * x
    out[given[-1] :] = values[given[-1]]
    return out
