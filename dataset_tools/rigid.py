"""Rigid skeletons: joints that keep their bone lengths, fitted to joints that do not.

A generated motion's joints come from the features' joint positions (``ric``), which the model
predicts joint by joint: nothing holds a bone at one length, and limbs grow and shrink from frame
to frame. :func:`rigid_joints` fits the fixed skeleton to such joints, in parent order from the
root:

* the root keeps its position;
* a joint with one child (a knee, an elbow, a neck) keeps the observed direction of the bone to
  that child, laid out at the skeleton's length from the already fitted joint;
* a joint with several children (SMPL's pelvis and spine3, KIT's root and BLN) carries them as
  one rigid piece, as a BVH or glTF joint carries its children's offsets: the children's rest
  directions are fitted to the motion (the average, over frames, of their observed directions in
  the piece's best frame, a generalised Procrustes fit), and per frame the piece takes the
  rotation that best lays them along the observed bones (Kabsch).

The result has every bone at its length in every frame and every branch rigid. The lengths are
the target skeleton's (:func:`model_bone_lengths`): every clip a dataset is built from is
retargeted to it, so it is the body the model learnt, one body for all its motions rather than
each motion's own estimate of it; and it is the body the BVH and glTF writers lay out
(:mod:`dataset_tools.bvh`, :mod:`dataset_tools.gltf`, which fit the hips and collars to the
motion's own rigid shape), so they reproduce the result exactly. Fitting it again returns it
unchanged (to float64 rounding). An edit holds the joints it keeps from its source
(``held``, see :func:`rigid_joints`).

:func:`finish_features` is the finishing step of every generated motion (``t2m.sample``,
``t2m.edit``, the web app, the evaluation's ``--clean``): the rigid fit, then the foot-contact
clean-up (:mod:`dataset_tools.cleanup`, whose leg IK keeps every per-frame bone length, so the
result stays rigid), written back into features (:func:`features_with_joints`).

Shapes: joints (T, J, 3) metres, y-up; lengths (J,) metres, the root's zero.
"""

from __future__ import annotations

import numpy as np

from dataset_tools.cleanup import clean_joints, features_with_joints
from dataset_tools.representation import (
    FeatureLayout,
    recover_from_ric,
)
from dataset_tools.skeleton import SMPL, SkeletonSpec, skeleton_for

PROCRUSTES_ITERATIONS = 2
"""Rounds of the rest-direction fit of a branch (each: per-frame rotations, then their mean
directions) after its start: on demo-corpus motions whose joints were moved by 1.5 cm of noise
per frame, two rounds put every joint within 0.03 mm of where eight put it."""
_EPS = 1e-9


def model_bone_lengths(skeleton: SkeletonSpec) -> np.ndarray | None:
    """The bone lengths (J,) every motion of a model on ``skeleton`` gets: SMPL's are the target
    skeleton every dataset this project builds is retargeted to (HumanML3D's example frame, which
    ``--target-skeleton`` usually gives, is within 0.05 mm of it) and the BVH / glTF writers'
    lengths; KIT-ML's in :mod:`dataset_tools.skeleton` are typical adult lengths, not its
    dataset's, so None there: each motion keeps its own median bone lengths."""
    return SMPL.bone_lengths.copy() if skeleton.name == SMPL.name else None


def _unit(vectors: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    norm = np.linalg.norm(vectors, axis=-1)
    return vectors / np.maximum(norm, _EPS)[..., None], norm


def _fill_degenerate(directions: np.ndarray, norms: np.ndarray, rest: np.ndarray) -> np.ndarray:
    """Unit directions (T, 3) where ``norms`` (T,) vanish replaced by the previous frame's (the
    rest direction ``rest`` (3,) before the first defined one): a zero-length bone has none."""
    degenerate = np.flatnonzero(norms < _EPS)
    if degenerate.size == 0:
        return directions
    directions = directions.copy()
    for frame in degenerate:
        directions[frame] = directions[frame - 1] if frame > 0 else rest
    return directions


def _kabsch(
    rest: np.ndarray, observed: np.ndarray, weights: np.ndarray | None = None
) -> np.ndarray:
    """Rotations (T, 3, 3) that best carry unit rest directions (K, 3) onto observed (T, K, 3),
    each pair weighted by ``weights`` (T, K) (default: equally)."""
    if weights is not None:
        observed = observed * weights[..., None]
    covariance = np.einsum("tki,kj->tij", observed, rest)  # sum_k w_k observed_k rest_k^T
    u, _, vt = np.linalg.svd(covariance)
    det = np.linalg.det(u @ vt)
    fix = np.ones((len(det), 3))
    fix[:, 2] = np.sign(det + (det == 0))  # a proper rotation, never a reflection
    return (u * fix[:, None, :]) @ vt


def branch_rest_directions(
    observed: np.ndarray, weights: np.ndarray | None = None, frames: np.ndarray | None = None
) -> np.ndarray:
    """Unit rest directions (K, 3) of the children of a rigid branch, from their observed unit
    directions (T, K, 3): starting from their mean in each frame's basis of the first two,
    alternately the per-frame best rotations
    (Kabsch, with ``weights`` (T, K)) and the mean of the observed directions turned back by them
    (:data:`PROCRUSTES_ITERATIONS` rounds), each child's over its ``frames`` (T, K) bool
    (default: every frame). Defined up to one rotation, which the per-frame rotations absorb."""
    frames = np.ones(observed.shape[:2], bool) if frames is None else frames
    # a start near the answer: the mean directions in each frame's basis of the first two
    first, _ = _unit(observed[:, 0])
    second, _ = _unit(observed[:, 1] - np.sum(observed[:, 1] * first, -1, keepdims=True) * first)
    basis = np.stack([first, second, np.cross(first, second)], axis=-1)  # (T, 3, 3) columns
    rest, _ = _unit((np.einsum("tji,tkj->tki", basis, observed) * frames[..., None]).sum(axis=0))
    for _ in range(PROCRUSTES_ITERATIONS):
        rotations = _kabsch(rest, observed, weights)  # (T, 3, 3)
        back = np.einsum("tji,tkj->tki", rotations, observed)  # R^T observed
        rest, _ = _unit((back * frames[..., None]).sum(axis=0))
    return rest


HELD_WEIGHT = 1e6
"""Weight of a child that stays where it is given against one that is fitted, in the rotation of
a branch: the staying ones decide it (to about a micrometre)."""


def rigid_joints(
    joints: np.ndarray,
    skeleton: SkeletonSpec | None = None,
    lengths: np.ndarray | None = None,
    held: np.ndarray | None = None,
) -> np.ndarray:
    """The skeleton with fixed bone ``lengths`` (J,) fitted to joints (T, J, 3) (see the module
    docstring); default lengths: :func:`model_bone_lengths`, else the median of each bone's
    length over the motion. Returns a new float64 array (T, J, 3).

    ``held`` (T, J) bool: joints to keep where they are given (an edit's joints kept from a
    source on the same skeleton). A held joint stays exactly where it is when its parent does
    (the root: when it is held itself); a held joint that hangs from a fitted one is fitted too,
    so a kept part attached to a regenerated body keeps its pose (its bone directions) and
    follows that body. A branch's rotation is decided by its staying children, and a child's
    rest direction is its direction on the frames where it stays, if there are any (one rigid
    piece throughout: the source's).

    Raises ValueError for shapes that do not fit the skeleton or non-finite joints.
    """
    joints = np.asarray(joints, dtype=np.float64)
    skeleton = skeleton or skeleton_for(joints.shape[1] if joints.ndim == 3 else 0)
    if joints.ndim != 3 or joints.shape[1:] != (skeleton.num_joints, 3) or len(joints) < 1:
        raise ValueError(f"joints must be (T >= 1, {skeleton.num_joints}, 3), got {joints.shape}")
    if not np.isfinite(joints).all():
        raise ValueError("joints contain NaN or infinite values")
    if lengths is None:
        lengths = model_bone_lengths(skeleton)
    if lengths is None:
        lengths = np.median(skeleton.bone_lengths_of(joints), axis=0)
    lengths = np.asarray(lengths, dtype=np.float64)
    if lengths.shape != (skeleton.num_joints,):
        raise ValueError(f"lengths must be ({skeleton.num_joints},), got {lengths.shape}")
    held = np.zeros(joints.shape[:2], bool) if held is None else np.asarray(held, dtype=bool)
    if held.shape != joints.shape[:2]:
        raise ValueError(f"held must be {joints.shape[:2]}, got {held.shape}")
    parents = skeleton.parents
    staying = held.copy()  # held, and so is everything up to the root
    for joint, parent in enumerate(parents):
        if parent >= 0:
            staying[:, joint] &= staying[:, parent]
    children: dict[int, list[int]] = {joint: [] for joint in range(skeleton.num_joints)}
    for joint, parent in enumerate(parents):
        if parent >= 0:
            children[parent].append(joint)
    fitted = np.empty_like(joints)
    fitted[:, 0] = joints[:, 0]
    for joint in range(skeleton.num_joints):  # parents precede children
        kids = children[joint]
        if not kids:
            continue
        directions = np.empty((len(joints), len(kids), 3))
        for k, kid in enumerate(kids):
            unit, norm = _unit(joints[:, kid] - joints[:, joint])
            directions[:, k] = _fill_degenerate(unit, norm, skeleton.rest_directions[kid])
        stays = staying[:, kids]  # (T, K)
        if len(kids) > 1:
            weights = 1.0 + HELD_WEIGHT * stays
            frames = np.where(stays.any(axis=0), stays, True)
            rest = branch_rest_directions(directions, weights, frames)
            rotations = _kabsch(rest, directions, weights)
            directions = np.einsum("tij,kj->tki", rotations, rest)
        fitted[:, kids] = fitted[:, joint : joint + 1] + directions * lengths[kids, None]
        fitted[:, kids] = np.where(stays[..., None], joints[:, kids], fitted[:, kids])
    return fitted


def finish_features(
    features: np.ndarray,
    clean: bool = True,
    lengths: np.ndarray | None = None,
    held: np.ndarray | None = None,
    clean_held: np.ndarray | None = None,
) -> np.ndarray:
    """Raw generated features (T, D) -> features (T, D) of the finished motion, float32: the
    joints made rigid (:func:`rigid_joints` with ``lengths``, default :func:`model_bone_lengths`,
    and ``held`` (T, J) joints left where they are), then, when ``clean``, the foot-contact
    clean-up (:func:`dataset_tools.cleanup.clean_joints`, with the features' contact channels,
    ``clean_held`` (T, J) joints left where the fit put them; default ``held``), written back by
    :func:`features_with_joints`. ``recover_from_ric`` of the result is the finished motion's
    joints.

    Raises ValueError for features that are not (T >= 2, D).
    """
    features = np.asarray(features)
    layout = FeatureLayout.for_dim(features.shape[-1])
    if features.ndim != 2 or len(features) < 2:
        raise ValueError(f"features must be (T >= 2, {layout.dim}), got {features.shape}")
    skeleton = skeleton_for(layout.num_joints)
    joints = rigid_joints(
        recover_from_ric(features.astype(np.float64), layout.num_joints), skeleton, lengths, held
    )
    if clean:
        clean_held = held if clean_held is None else clean_held
        joints = clean_joints(joints, features[:, layout.foot_contact], skeleton, clean_held)
    return features_with_joints(features, joints)


__all__ = [
    "HELD_WEIGHT",
    "PROCRUSTES_ITERATIONS",
    "branch_rest_directions",
    "features_with_joints",
    "finish_features",
    "model_bone_lengths",
    "rigid_joints",
]
