"""Gaits: walking and running forward, backward, sideways and in a circle.

Hip, knee and foot angle curves over the gait cycle (:func:`forward_gait`) and a sidestep of its
own (:func:`sidestep_left`, mirrored for the right); :func:`gait` chooses among them from an
action's parameters. The root is not placed here: ``clip.assemble`` derives it from the planted
feet, so the stride is an outcome of the angles (the stride tables below are measured on it).
"""

from __future__ import annotations

import numpy as np

from dataset_tools.synth.body import DOF
from dataset_tools.synth.track import Style, Track, bump, smoothstep

# Stride length (m) of the mean body against the thigh amplitude of the gait tables, measured on
# the generated motion (the root follows the planted feet, so the stride is an outcome, not an
# input); tests check the resulting speeds.
_AMPLITUDES = np.arange(0.3, 1.81, 0.15)
_WALK_STRIDES = np.array(
    [0.484, 0.595, 0.765, 0.865, 1.01, 1.123, 1.224, 1.354, 1.493, 1.587, 1.698]
)
_RUN_STRIDES = np.array(
    [0.694, 0.92, 1.108, 1.338, 1.561, 1.743, 1.959, 2.155, 2.289, 2.452, 2.631]
)


def _periodic_curve(knots: list[tuple[float, float]], samples: int = 240) -> np.ndarray:
    """A smooth periodic table (samples,) through (phase, value) knots, phases in [0, 1)."""
    xp = np.array([k[0] for k in knots])
    fp = np.array([k[1] for k in knots])
    grid = np.arange(samples) / samples
    table = np.interp(grid, xp, fp, period=1.0)
    # Circular smoothing removes the corners of the piecewise-linear interpolation.
    kernel = np.exp(-0.5 * (np.arange(-12, 13) / 4.0) ** 2)
    kernel /= kernel.sum()
    padded = np.concatenate([table[-12:], table, table[:12]])
    return np.convolve(padded, kernel, mode="valid")


def _lookup(table: np.ndarray, phase: np.ndarray) -> np.ndarray:
    grid = np.arange(len(table) + 1) / len(table)
    return np.interp(phase % 1.0, grid, np.append(table, table[0]))


# Gait cycles, phase 0 = heel strike of the leg. Thigh angle from the vertical (not from the
# pelvis), knee flexion, and foot pitch (toe up positive; 0 = flat on the ground), degrees.
# The thigh keeps sweeping back at an even rate through stance, from heel strike on, so that the
# landing foot and the planted foot move alike relative to the pelvis (neither slides).
_WALK_THIGH = _periodic_curve(
    [(0, 19), (0.1, 12.5), (0.3, -1), (0.52, -15), (0.62, -9), (0.75, 10), (0.9, 22)]
)
_WALK_KNEE = _periodic_curve(
    [
        (0, 3),
        (0.12, 16),
        (0.25, 9),
        (0.42, 5),
        (0.52, 14),
        (0.62, 38),
        (0.72, 60),
        (0.85, 28),
        (0.95, 4),
    ]
)
_WALK_FOOT = _periodic_curve(
    [(0, 12), (0.07, 0), (0.43, 0), (0.52, -12), (0.62, -36), (0.72, -12), (0.85, 6), (0.95, 12)]
)
_RUN_THIGH = _periodic_curve(
    [(0, 22), (0.2, 0), (0.4, -22), (0.5, -14), (0.7, 25), (0.85, 34), (0.95, 27)]
)
_RUN_KNEE = _periodic_curve(
    [(0, 18), (0.15, 40), (0.3, 22), (0.4, 15), (0.55, 70), (0.68, 105), (0.82, 70), (0.95, 25)]
)
_RUN_FOOT = _periodic_curve(
    [(0, 6), (0.06, 0), (0.25, 0), (0.35, -15), (0.42, -38), (0.55, -20), (0.75, 6)]
)


def _gait_angles(phase: np.ndarray, run: bool, amplitude: float) -> dict:
    """Leg angles (degrees) of one leg over gait phases (n,); ``amplitude`` scales the thigh swing.

    The ankle is solved so the foot has the pitch of the foot curve: flat during stance.
    """
    thigh = amplitude * _lookup(_RUN_THIGH if run else _WALK_THIGH, phase)
    knee = _lookup(_RUN_KNEE if run else _WALK_KNEE, phase) * (0.8 + 0.2 * amplitude)
    foot = _lookup(_RUN_FOOT if run else _WALK_FOOT, phase)
    ankle = np.clip(foot - thigh + knee, -40, 30)
    abd = 1.0 - 2.0 * bump(phase, 0.3, 0.12)
    return {"hip_flex": thigh, "knee": knee, "ankle": ankle, "hip_abd": abd}


def forward_gait(
    n: int,
    fps: float,
    rng: np.random.Generator,
    style: Style,
    speed: float,
    run: bool,
    backward: bool = False,
    yaw_rate_s: float = 0.0,
) -> Track:
    """Walk or run along the heading at about ``speed`` m/s; backward = the cycle played in reverse.

    Cadence and stride length both grow with speed (stride = speed / cadence); the hip amplitude
    is set from the stride so the planted foot, not a root velocity, moves the body.
    """
    # Strides per second; a subject's tempo changes cadence, and the stride makes up for it.
    cadence = (1.15 + 0.13 * speed if run else 0.55 + 0.36 * speed) * style.tempo
    strides = _RUN_STRIDES if run else _WALK_STRIDES
    # Speeds are for the mean body: with the same joint angles a longer-legged subject takes
    # longer strides and goes proportionally faster, as people do.
    amplitude = float(np.interp(speed / cadence, strides, _AMPLITUDES))
    t = np.arange(n) / fps
    direction = -1.0 if backward else 1.0
    phase_left = rng.uniform() + direction * cadence * t
    phase_right = phase_left + 0.5
    dofs = np.repeat(style.base_pose()[None], n, axis=0)
    legs = {}
    for side, phase in (("l", phase_left), ("r", phase_right)):
        legs[side] = _gait_angles(phase % 1.0, run, amplitude)
        legs[side]["hip_abd"] = legs[side]["hip_abd"] + style.stance_width - 2.0
        for name, value in legs[side].items():
            dofs[:, DOF[f"{side}_{name}"]] = np.radians(value)
    mean_hip = 0.0
    swing = style.arm_swing * (1.4 if run else 0.9)
    for side, other in (("l", "r"), ("r", "l")):
        # An arm swings with the opposite leg.
        flex = swing * (legs[other]["hip_flex"] - mean_hip)
        dofs[:, DOF[f"{side}_shoulder_flex"]] = np.radians(flex)
        elbow = (85.0 if run else style.elbow + 4 * speed) + 0.3 * np.maximum(flex, 0)
        dofs[:, DOF[f"{side}_elbow"]] = np.radians(elbow)
        dofs[:, DOF[f"{side}_shoulder_abd"]] = np.radians(style.arm_abd + (6 if run else 0))
    lean = style.lean + (6 + 2 * speed if run else 1.5 * speed) * direction
    dofs[:, DOF["spine_flex"]] = np.radians(lean)
    dofs[:, DOF["neck_flex"]] = np.radians(style.head - 0.5 * lean)
    twist = (5 if run else 4) * np.cos(2 * np.pi * phase_left)
    dofs[:, DOF["pelvis_twist"]] = np.radians(-twist)
    dofs[:, DOF["spine_twist"]] = np.radians(1.6 * twist)
    dofs[:, DOF["pelvis_roll"]] = np.radians(3.0 * np.cos(2 * np.pi * (phase_left - 0.3)))
    flight = np.zeros(n)
    if run:
        # Both feet are off the ground between one foot's toe-off and the other's heel strike.
        height = 0.02 + 0.01 * speed
        for phase in (phase_left % 1.0, phase_right % 1.0):
            window = (phase >= 0.4) & (phase < 0.5)
            flight[window] = height * np.sin(np.pi * (phase[window] - 0.4) / 0.1)
    yaw_rate = np.full(n, yaw_rate_s / fps)
    end = 0.4 if run else 0.5
    stance = np.stack([_stance_weight(p % 1.0, end) for p in (phase_left, phase_right)], axis=1)
    return Track(dofs, yaw_rate, flight, np.full((n, 2), np.nan), stance)


def _stance_weight(phase: np.ndarray, end: float, ramp: float = 0.07) -> np.ndarray:
    """Weight (n,) of a leg as the planted one: rises after heel strike, falls at ``end``."""
    return smoothstep(phase / ramp) * (1 - smoothstep((phase - end) / ramp))


def sidestep_left(
    n: int, fps: float, rng: np.random.Generator, style: Style, speed: float, run: bool
) -> Track:
    """Step sideways to the left: the left leg swings out while the right leg, planted, abducts;
    then the right leg swings in while the left, planted, comes back under the body."""
    reach = 2 * 0.88  # the mean body's leg, hip to sole
    cadence = (1.5 if run else 1.0) * (0.8 + 0.4 * speed)
    abduction = np.degrees(np.arcsin(np.clip(speed / cadence / reach, 0, 0.6)))
    t = np.arange(n) / fps
    phase = (rng.uniform() + cadence * t) % 1.0
    first = phase < 0.5
    local = (2 * phase) % 1.0
    # The swinging foot rises first, then moves out (or in), then comes down.
    progress = smoothstep((local - 0.12) / 0.76)
    abd = np.where(first, progress, 1 - progress) * abduction
    lift = np.sin(np.pi * local) ** 2
    dofs = np.repeat(style.base_pose()[None], n, axis=0)
    for side, swinging in (("l", first), ("r", ~first)):
        dofs[:, DOF[f"{side}_hip_abd"]] = np.radians(abd + 1.0)
        knee = style.knee_bend + (14 if run else 8) + np.where(swinging, 30 * lift, 0)
        hip = 6 + np.where(swinging, 14 * lift, 0)
        dofs[:, DOF[f"{side}_knee"]] = np.radians(knee)
        dofs[:, DOF[f"{side}_hip_flex"]] = np.radians(hip)
        # Foot flat (pitch = thigh - knee + ankle = 0) while planted, toes a little down in swing.
        dofs[:, DOF[f"{side}_ankle"]] = np.radians(knee - hip - np.where(swinging, 10 * lift, 0))
        dofs[:, DOF[f"{side}_shoulder_abd"]] = np.radians(style.arm_abd + 0.5 * abd)
        dofs[:, DOF[f"{side}_elbow"]] = np.radians(style.elbow + (50 if run else 10))
    dofs[:, DOF["spine_lat"]] = np.radians(2.0 * np.sin(2 * np.pi * phase))
    flight = np.zeros(n)
    if run:
        # A shuffle: a small hop as the feet cross the widest stance.
        window = (phase > 0.45) & (phase < 0.55)
        flight[window] = 0.025 * np.sin(np.pi * (phase[window] - 0.45) / 0.1)
    stance = np.stack([(~first).astype(float), first.astype(float)], axis=1)
    return Track(dofs, np.zeros(n), flight, np.full((n, 2), np.nan), stance)


def gait(params: dict, n: int, fps: float, rng: np.random.Generator, style: Style) -> Track:
    """Walk or run (``params["speed_mps"]``) forward, backward, sideways or in a circle."""
    run = params["gait"] == "run"
    speed = params["speed_mps"]
    direction = params["direction"]
    if direction in ("forward", "backward"):
        return forward_gait(n, fps, rng, style, speed, run, backward=direction == "backward")
    if direction in ("left", "right"):
        track = sidestep_left(n, fps, rng, style, speed, run)
        return track if direction == "left" else track.mirrored()
    yaw_rate = speed / params["radius_m"]
    track = forward_gait(n, fps, rng, style, speed, run, yaw_rate_s=yaw_rate)
    # Counterclockwise seen from above is a continuous left turn.
    return track if direction == "counterclockwise" else track.mirrored()
