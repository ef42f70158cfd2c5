"""One synthetic clip: plan 1-3 actions, cross-fade their joint angles, pose the body, place the root.

The root is never animated directly. Its height puts the lowest contact point (heel, toe or seat)
on the ground, except in flight, where it follows a ballistic arc between take-off and landing; its
horizontal motion keeps whichever contact points are on the ground fixed in the world (a soft
minimum over contact heights picks them), so a planted foot does not slide and the stride decides
the speed.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dataset_tools.synth.body import (
    Body,
    contact_points,
    forward_kinematics,
    local_rotations,
    make_body,
    sample_body,
)
from dataset_tools.synth.motions import ACTIONS
from dataset_tools.synth.track import Style, Track

FPS = 60.0
MIN_SECONDS = 2.0
MAX_SECONDS = 10.0
BLEND_SECONDS = 0.4  # cross-fade between consecutive actions
_CONTACT_SOFTNESS = 0.004  # metres: contact points this much above the lowest one barely count
_ACTION_WEIGHTS = {"walk": 3.0, "run": 1.5}
_COUNT_PROBS = (0.35, 0.4, 0.25)  # 1, 2 or 3 actions per clip


@dataclass(frozen=True)
class Segment:
    """One action of a clip: name, parameters, and its frames [start, end) at the clip's fps."""

    action: str
    params: dict
    start: int
    end: int

    def label(self) -> dict:
        return {"action": self.action, "params": self.params, "start": self.start, "end": self.end}


@dataclass
class Clip:
    """A generated clip: joints (T, 22, 3) y-up metres at ``fps``, its segments and subject."""

    joints: np.ndarray
    fps: float
    segments: list[Segment]
    body: Body
    style: Style


def plan_clip(rng: np.random.Generator) -> list[tuple[str, dict, float]]:
    """1-3 (action, params, seconds) with a total of 2-10 s and no action twice in a row."""
    names = list(ACTIONS)
    weights = np.array([_ACTION_WEIGHTS.get(n, 1.0) for n in names])
    weights /= weights.sum()
    while True:
        count = int(rng.choice(3, p=_COUNT_PROBS)) + 1
        plan: list[tuple[str, dict, float]] = []
        while len(plan) < count:
            name = names[int(rng.choice(len(names), p=weights))]
            if plan and plan[-1][0] == name:
                continue
            params, seconds = ACTIONS[name].sample(rng)
            plan.append((name, params, seconds))
        total = sum(seconds for _, _, seconds in plan)
        if total <= MAX_SECONDS:
            break
    if total < MIN_SECONDS:
        # Stretch the only action; generators centre their motion in the frames they are given.
        name, params, seconds = plan[-1]
        plan[-1] = (name, params, seconds + MIN_SECONDS - total + 0.05)
    return plan


def _smoothstep(x: np.ndarray) -> np.ndarray:
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3 - 2 * x)


def _blend_tracks(plan, rng, style, fps) -> tuple[Track, list[Segment]]:
    """Generate each action with a margin and cross-fade consecutive ones."""
    frames = [int(round(seconds * fps)) for _, _, seconds in plan]
    bounds = np.concatenate([[0], np.cumsum(frames)])
    total = int(bounds[-1])
    pad = int(round(0.5 * BLEND_SECONDS * fps))
    t = np.arange(total)
    acc = Track(
        np.zeros((total, len(style.base_pose()))),
        np.zeros(total),
        np.zeros(total),
        np.zeros((total, 2)),
        np.zeros((total, 3)),
    )
    air_weight = np.zeros(total)
    segments = []
    for i, (name, params, _) in enumerate(plan):
        start, end = int(bounds[i]), int(bounds[i + 1])
        lo = start - pad if i > 0 else 0
        hi = end + pad if i < len(plan) - 1 else total
        track = ACTIONS[name].generate(params, hi - lo, fps, rng, style)
        weight = np.ones(hi - lo)
        local = t[lo:hi]
        if i > 0:
            weight *= _smoothstep((local - (start - pad)) / (2 * pad))
        if i < len(plan) - 1:
            weight *= 1 - _smoothstep((local - (end - pad)) / (2 * pad))
        acc.dofs[lo:hi] += weight[:, None] * track.dofs
        acc.yaw_rate[lo:hi] += weight * track.yaw_rate
        acc.flight[lo:hi] += weight * track.flight
        known = np.isfinite(track.air_velocity[:, 0])
        acc.air_velocity[lo:hi][known] += weight[known, None] * track.air_velocity[known]
        air_weight[lo:hi] += np.where(known, weight, 0.0)
        if track.stance is not None:
            acc.stance[lo:hi, :2] += weight[:, None] * track.stance
            acc.stance[lo:hi, 2] += weight
        segments.append(Segment(name, params, start, end))
    with np.errstate(invalid="ignore", divide="ignore"):
        acc.air_velocity = np.where(
            air_weight[:, None] > 0.5, acc.air_velocity / air_weight[:, None], np.nan
        )
    return acc, segments


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """[start, end) of each run of True in a boolean mask."""
    edges = np.diff(np.concatenate([[0], mask.astype(np.int8), [0]]))
    return list(zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)))


def place_root(track: Track, body: Body, yaw0: float, start_xz: np.ndarray) -> np.ndarray:
    """Joint positions (T, 22, 3), y-up, for tracks whose root is found from ground contacts."""
    yaw = yaw0 + np.cumsum(track.yaw_rate)
    pos, glob = forward_kinematics(local_rotations(track.dofs, yaw), body.offsets)
    contacts = contact_points(body, pos, glob)  # (T, 5, 3), root at the origin
    heights = contacts[..., 1]
    lowest = heights.min(axis=1)
    root_y = -lowest
    airborne = track.flight > 0
    for a, b in _runs(airborne):
        ya = root_y[a - 1] if a > 0 else root_y[a]
        yb = root_y[b] if b < len(root_y) else root_y[b - 1]
        root_y[a:b] = ya + (yb - ya) * (np.arange(a, b) - a + 1) / (b - a + 1) + track.flight[a:b]

    # Horizontal: keep the grounded contact points fixed in the world. Where a gait says which
    # foot is planted, that foot's lowest point anchors; elsewhere the lowest points do.
    above = heights - lowest[:, None]
    weights = np.exp(-above / _CONTACT_SOFTNESS)
    weights /= weights.sum(axis=1, keepdims=True)
    stance = track.stance
    if stance is not None and stance.shape[1] == 2:
        stance = np.concatenate([stance, np.ones((len(stance), 1))], axis=1)
    if stance is not None and stance[:, 2].any():
        per_foot = np.exp(
            -(heights[:, :4] - heights[:, :4].reshape(-1, 2, 2).min(axis=2).repeat(2, axis=1))
            / _CONTACT_SOFTNESS
        )
        per_foot = per_foot.reshape(-1, 2, 2)
        per_foot /= per_foot.sum(axis=2, keepdims=True)
        feet = stance[:, :2] / np.maximum(stance[:, :2].sum(axis=1, keepdims=True), 1e-9)
        gait_weights = np.concatenate(
            [(per_foot * feet[:, :, None]).reshape(-1, 4), np.zeros((len(feet), 1))], axis=1
        )
        share = np.clip(stance[:, 2:3], 0.0, 1.0)
        weights = share * gait_weights + (1 - share) * weights
    step_weights = 0.5 * (weights[1:] + weights[:-1])
    moved = contacts[1:, :, [0, 2]] - contacts[:-1, :, [0, 2]]
    velocity = -np.einsum("tk,tkc->tc", step_weights, moved)  # (T-1, 2) world x, z
    in_air = airborne[1:] | airborne[:-1]
    forward = np.stack([np.sin(yaw), np.cos(yaw)], axis=1)[1:]
    left = np.stack([np.cos(yaw), -np.sin(yaw)], axis=1)[1:]
    air = track.air_velocity[1:]
    air_world = air[:, :1] * left + air[:, 1:] * forward
    velocity = np.where(in_air[:, None], air_world, velocity)
    unknown = ~np.isfinite(velocity[:, 0])
    if unknown.any() and (~unknown).any():
        index = np.arange(len(velocity))
        for c in range(2):
            velocity[unknown, c] = np.interp(index[unknown], index[~unknown], velocity[~unknown, c])
    velocity[~np.isfinite(velocity)] = 0.0
    root_xz = start_xz + np.concatenate([np.zeros((1, 2)), np.cumsum(velocity, axis=0)])
    # Nothing may go below the ground, in flight included (a landing leg can reach down).
    root_y = np.maximum(root_y, -pos[..., 1].min(axis=1))
    root = np.stack([root_xz[:, 0], root_y, root_xz[:, 1]], axis=1)
    return pos + root[:, None, :]


def synthesize_clip(seed: int, index: int, fps: float = FPS) -> Clip:
    """Clip number ``index`` of the corpus with seed ``seed`` (independent of any other clip)."""
    rng = np.random.default_rng([seed, index])
    body = sample_body(rng)
    style = Style.sample(rng)
    plan = plan_clip(rng)
    track, segments = _blend_tracks(plan, rng, style, fps)
    yaw0 = float(rng.uniform(0, 2 * np.pi))
    start = rng.uniform(-1.0, 1.0, size=2)
    joints = place_root(track, body, yaw0, start)
    return Clip(joints.astype(np.float32), fps, segments, body, style)


def synthesize_action(
    action: str, params: dict, seconds: float, seed: int = 0, fps: float = FPS
) -> Clip:
    """A clip of one given action (tests, pictures): average body and style, heading +Z."""
    if action not in ACTIONS:
        raise ValueError(f"unknown action {action!r}; known: {', '.join(ACTIONS)}")
    rng = np.random.default_rng(seed)
    style = Style()
    track, segments = _blend_tracks([(action, params, seconds)], rng, style, fps)
    joints = place_root(track, make_body(), 0.0, np.zeros(2))
    return Clip(joints.astype(np.float32), fps, segments, make_body(), style)
