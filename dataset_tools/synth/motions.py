"""Action generators: each turns action parameters into joint-angle tracks over a number of frames.

A generator returns a ``Track``: poses (n, D) in radians (see ``body.DOF_NAMES``), the heading's
yaw rate, a flight height (> 0 only while airborne) and, for airborne frames, the horizontal
velocity in the heading frame. Generators never place the root: ``clip.assemble`` derives the root
from the feet (the stance foot stays planted), so stride length and root speed always agree.

Sided actions (kick, punch, wave, raise, hop, turning, sidestepping, circling) are generated for
the left side (or leftward turn) and mirrored for the right with ``body.mirror_dofs``, which makes
left and right exact mirror images by construction.

Every ACTIONS entry knows how to sample its parameters and duration and how to generate itself.
The gaits are :mod:`dataset_tools.synth.gaits`; the Track, the Style and the pose helpers every
generator uses, :mod:`dataset_tools.synth.track`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from dataset_tools.synth.body import DOF
from dataset_tools.synth.gaits import gait
from dataset_tools.synth.track import (
    Style,
    Track,
    both,
    keyframes,
    lead_in,
    pose_vector,
    smoothstep,
)

GRAVITY = 9.81
SPEEDS = ("slow", "normal", "fast")
# Target root speeds (m/s) per speed class; the ranges do not overlap so detectors can tell them
# apart. Sideways gaits are slower.
_WALK_SPEED = {"slow": (0.6, 0.8), "normal": (1.05, 1.3), "fast": (1.5, 1.75)}
_RUN_SPEED = {"slow": (2.25, 2.55), "normal": (2.8, 3.2), "fast": (3.5, 3.9)}
_SIDE_SPEED = {"slow": (0.25, 0.33), "normal": (0.42, 0.52), "fast": (0.62, 0.75)}


# --- in place ----------------------------------------------------------------------------------


def turn(params: dict, n: int, fps: float, rng: np.random.Generator, style: Style) -> Track:
    """Turn on the spot by stepping: each foot keeps its world yaw while planted (the hip rotates
    under it) and swings to the next yaw; the heading follows the feet."""
    angle = np.radians(params["angle"])
    steps = 2 if params["angle"] <= 90 else 4
    natural = 0.45 * steps + 0.3
    start = lead_in(n, fps, natural)
    t = np.arange(n) / fps
    step_time = (natural - 0.3) / steps
    foot_yaw = {"l": np.zeros(n), "r": np.zeros(n)}
    lift = {"l": np.zeros(n), "r": np.zeros(n)}
    for i in range(steps):
        leg = "l" if i % 2 == 0 else "r"
        target = angle * (i // 2 + 1) / (steps // 2)
        local = (t - start - 0.15 - i * step_time) / step_time
        previous = angle * (i // 2) / (steps // 2)
        active = (local > 0) & (local < 1)
        foot_yaw[leg] = np.where(
            local >= 1,
            target,
            np.where(active, previous + (target - previous) * smoothstep(local), foot_yaw[leg]),
        )
        lift[leg] = lift[leg] + np.where(active, np.sin(np.pi * np.clip(local, 0, 1)) ** 2, 0)
    heading = 0.5 * (foot_yaw["l"] + foot_yaw["r"])
    # The foot that is not stepping carries the body.
    stance = np.stack([1.0 - lift["l"] + lift["r"], 1.0 - lift["r"] + lift["l"]], axis=1)
    dofs = np.repeat(style.base_pose()[None], n, axis=0)
    for leg, sign in (("l", 1.0), ("r", -1.0)):
        # External hip rotation turns the left toe left and the right toe right.
        dofs[:, DOF[f"{leg}_hip_rot"]] = sign * (foot_yaw[leg] - heading)
        dofs[:, DOF[f"{leg}_hip_flex"]] += np.radians(18 * lift[leg])
        dofs[:, DOF[f"{leg}_knee"]] += np.radians(34 * lift[leg])
        dofs[:, DOF[f"{leg}_ankle"]] -= np.radians(8 * lift[leg])
    yaw_rate = np.diff(heading, prepend=0.0)
    return Track(dofs, yaw_rate, np.zeros(n), np.full((n, 2), np.nan), stance)


def jump(params: dict, n: int, fps: float, rng: np.random.Generator, style: Style) -> Track:
    """Jump ``count`` times in place or forward: crouch, push off, fly ballistically, land, absorb."""
    count = params["count"]
    height = params["height_m"]
    distance = params.get("distance_m", 0.0)
    air_time = 2 * np.sqrt(2 * height / GRAVITY)
    cycle = 0.32 + 0.12 + air_time
    natural = 0.35 + count * cycle + 0.45
    base = style.base_pose()
    lean = 12 if distance > 0 else 6
    crouch = pose_vector(
        base,
        pelvis_pitch=lean + 10,
        spine_flex=8,
        **both(hip_flex=45, knee=75, ankle=28, shoulder_flex=-35, elbow=20),
    )
    push = pose_vector(
        base,
        pelvis_pitch=lean,
        **both(hip_flex=lean + 2, knee=3, ankle=-28, shoulder_flex=110, elbow=15, shoulder_abd=15),
    )
    tuck = pose_vector(
        base,
        pelvis_pitch=lean,
        **both(hip_flex=lean + 35, knee=55, ankle=-12, shoulder_flex=80, elbow=25, shoulder_abd=15),
    )
    land = pose_vector(
        base,
        pelvis_pitch=lean * 0.5,
        # Legs under the body as at take-off, so an in-place jump lands where it started.
        **both(hip_flex=lean + 2, knee=10, ankle=-18, shoulder_flex=45, elbow=20, shoulder_abd=15),
    )
    absorb = pose_vector(
        base,
        pelvis_pitch=lean + 8,
        spine_flex=6,
        **both(hip_flex=40, knee=65, ankle=25, shoulder_flex=20, elbow=25),
    )
    t = lead_in(n, fps, natural)
    times, poses = [t], [base]
    flight = np.zeros(n)
    air = np.full((n, 2), np.nan)
    frames = np.arange(n) / fps
    for i in range(count):
        t += 0.3 if i == 0 else 0.12
        times.append(t)
        poses.append(crouch)
        t += 0.14
        times.append(t)
        poses.append(push)
        takeoff = t
        times += [t + 0.5 * air_time, t + air_time]
        poses += [tuck, land]
        t += air_time
        window = (frames >= takeoff) & (frames < t)
        tau = frames[window] - takeoff
        flight[window] = np.maximum(tau * (0.5 * GRAVITY * air_time) - 0.5 * GRAVITY * tau**2, 1e-4)
        air[window] = (0.0, distance / air_time / fps)
        t += 0.2
        times.append(t)
        poses.append(absorb)
    times.append(t + 0.45)
    poses.append(base)
    return Track(keyframes(times, poses, n, fps), np.zeros(n), flight, air)


def hop_left(params: dict, n: int, fps: float, rng: np.random.Generator, style: Style) -> Track:
    """Hop ``count`` times on the left foot with the right leg held up."""
    count = params["count"]
    air_time = 0.3
    cycle = 0.2 + 0.1 + air_time + 0.1
    natural = 0.5 + count * cycle + 0.5
    base = style.base_pose()
    held = dict(
        r_hip_flex=35,
        r_knee=80,
        r_ankle=-10,
        l_shoulder_abd=28,
        r_shoulder_abd=28,
        l_elbow=35,
        r_elbow=35,
        spine_lat=-3,
    )
    ready = pose_vector(base, l_knee=12, l_hip_flex=8, l_ankle=8, **held)
    crouch = pose_vector(base, pelvis_pitch=6, l_knee=35, l_hip_flex=25, l_ankle=18, **held)
    push = pose_vector(base, pelvis_pitch=3, l_knee=4, l_hip_flex=4, l_ankle=-25, **held)
    t = lead_in(n, fps, natural)
    times, poses = [t, t + 0.5], [base, ready]
    t += 0.5
    flight = np.zeros(n)
    air = np.full((n, 2), np.nan)
    frames = np.arange(n) / fps
    for _ in range(count):
        times += [t + 0.2, t + 0.3]
        poses += [crouch, push]
        takeoff = t + 0.3
        window = (frames >= takeoff) & (frames < takeoff + air_time)
        tau = frames[window] - takeoff
        flight[window] = np.maximum(tau * (0.5 * GRAVITY * air_time) - 0.5 * GRAVITY * tau**2, 1e-4)
        air[window] = 0.0
        t = takeoff + air_time + 0.1
        times.append(t)
        poses.append(crouch)
    times += [t + 0.2, t + 0.5]
    poses += [ready, base]
    return Track(keyframes(times, poses, n, fps), np.zeros(n), flight, air)


def kick_left(params: dict, n: int, fps: float, rng: np.random.Generator, style: Style) -> Track:
    """A front kick with the left leg: chamber the knee, snap the shank out, retract, step down."""
    base = style.base_pose()
    high = params.get("height_deg", 80)
    arms = dict(
        l_shoulder_abd=30,
        r_shoulder_abd=30,
        l_elbow=60,
        r_elbow=60,
        l_shoulder_flex=20,
        r_shoulder_flex=20,
    )
    chamber = pose_vector(
        base,
        pelvis_pitch=-6,
        r_knee=12,
        r_hip_flex=6,
        r_ankle=6,
        l_hip_flex=high - 20,
        l_knee=95,
        l_ankle=-10,
        **arms,
    )
    extend = pose_vector(
        base,
        pelvis_pitch=-12,
        r_knee=10,
        r_hip_flex=5,
        r_ankle=5,
        l_hip_flex=high,
        l_knee=6,
        l_ankle=-30,
        **arms,
    )
    natural = 1.15
    t = lead_in(n, fps, natural)
    times = [t, t + 0.35, t + 0.52, t + 0.72, t + 1.15]
    poses = [base, chamber, extend, chamber, base]
    return Track.still(keyframes(times, poses, n, fps))


def punch_left(params: dict, n: int, fps: float, rng: np.random.Generator, style: Style) -> Track:
    """Raise a guard, throw ``count`` straight left punches (torso rotating into them), lower."""
    count = params["count"]
    base = style.base_pose()
    guard_arms = both(shoulder_flex=35, shoulder_abd=18, elbow=125, shoulder_twist=10)
    guard = pose_vector(
        base, l_knee=12, r_knee=12, l_hip_flex=6, r_hip_flex=6, l_ankle=6, r_ankle=6, **guard_arms
    )
    strike = pose_vector(
        guard,
        spine_twist=-22,
        pelvis_twist=-6,
        l_shoulder_flex=86,
        l_shoulder_abd=12,
        l_elbow=4,
        l_shoulder_twist=0,
        r_shoulder_flex=30,
    )
    natural = 0.45 + count * 0.5 + 0.45
    t = lead_in(n, fps, natural)
    times, poses = [t, t + 0.45], [base, guard]
    t += 0.45
    for _ in range(count):
        times += [t + 0.15, t + 0.5]
        poses += [strike, guard]
        t += 0.5
    times.append(t + 0.45)
    poses.append(base)
    return Track.still(keyframes(times, poses, n, fps))


def _arm_pose(base: np.ndarray, sides: tuple[str, ...], **degrees: float) -> np.ndarray:
    return pose_vector(base, **{f"{s}_{k}": v for s in sides for k, v in degrees.items()})


def wave(params: dict, n: int, fps: float, rng: np.random.Generator, style: Style) -> Track:
    """Raise the hand(s) above the shoulder, forearm up, and swing the forearm side to side."""
    sides = ("l", "r") if params["side"] == "both" else ("l",)
    count = params["count"]
    rate = params["rate_hz"]
    base = style.base_pose()
    up = _arm_pose(base, sides, shoulder_abd=105, shoulder_flex=18, shoulder_twist=-80, elbow=85)
    natural = 0.5 + count / rate + 0.5
    t0 = lead_in(n, fps, natural)
    t1 = t0 + 0.5
    t2 = t1 + count / rate
    dofs = keyframes([t0, t1, t2, t2 + 0.5], [base, up, up, base], n, fps)
    t = np.arange(n) / fps
    inside = (t > t1) & (t < t2)
    swing = np.where(inside, np.sin(2 * np.pi * rate * (t - t1)), 0.0) * np.radians(32)
    for s in sides:
        dofs[:, DOF[f"{s}_elbow"]] += swing
    track = Track.still(dofs)
    return track.mirrored() if params["side"] == "right" else track


def raise_hands(params: dict, n: int, fps: float, rng: np.random.Generator, style: Style) -> Track:
    """Raise one or both arms straight up overhead, hold, and lower them."""
    sides = ("l", "r") if params["side"] == "both" else ("l",)
    base = style.base_pose()
    up = _arm_pose(base, sides, shoulder_flex=170, shoulder_abd=12, elbow=8, collar_elev=10)
    hold = params["hold_s"]
    natural = 0.7 + hold + 0.7
    t = lead_in(n, fps, natural)
    track = Track.still(
        keyframes([t, t + 0.7, t + 0.7 + hold, t + natural], [base, up, up, base], n, fps)
    )
    return track.mirrored() if params["side"] == "right" else track


def clap(params: dict, n: int, fps: float, rng: np.random.Generator, style: Style) -> Track:
    """Hold the forearms up in front of the chest and bring the palms together ``count`` times."""
    count = params["count"]
    rate = params["rate_hz"]
    base = style.base_pose()
    ready = pose_vector(
        base, **both(shoulder_flex=40, shoulder_abd=12, elbow=100, shoulder_twist=20)
    )
    natural = 0.5 + count / rate + 0.5
    t0 = lead_in(n, fps, natural)
    t1 = t0 + 0.5
    t2 = t1 + count / rate
    dofs = keyframes([t0, t1, t2, t2 + 0.5], [base, ready, ready, base], n, fps)
    t = np.arange(n) / fps
    inside = (t > t1) & (t < t2)
    # 0 with the hands apart, 1 at the clap (once per 1 / rate seconds).
    closing = np.where(inside, 0.5 - 0.5 * np.cos(2 * np.pi * rate * (t - t1)), 0.0)
    for s in ("l", "r"):
        dofs[:, DOF[f"{s}_shoulder_twist"]] += np.radians(42) * closing
    return Track.still(dofs)


def squat(params: dict, n: int, fps: float, rng: np.random.Generator, style: Style) -> Track:
    """Squat down (hips back, knees forward, arms forward for balance) and stand, ``count`` times."""
    count = params["count"]
    depth = params["depth_deg"]
    base = style.base_pose()
    down = pose_vector(
        base,
        pelvis_pitch=28,
        spine_flex=6,
        neck_flex=-10,
        **both(hip_flex=depth, knee=depth + 20, ankle=30, shoulder_flex=80, elbow=12),
    )
    period = params["period_s"]
    natural = count * period
    t = lead_in(n, fps, natural)
    times, poses = [t], [base]
    for _ in range(count):
        times += [t + 0.5 * period, t + period]
        poses += [down, base]
        t += period
    return Track.still(keyframes(times, poses, n, fps))


def sit(params: dict, n: int, fps: float, rng: np.random.Generator, style: Style) -> Track:
    """Lower to the ground (squat, then sit with the legs forward), stay, and stand back up."""
    base = style.base_pose()
    low = pose_vector(
        base,
        pelvis_pitch=30,
        spine_flex=10,
        **both(hip_flex=100, knee=125, ankle=32, shoulder_flex=55, elbow=20),
    )
    seated = pose_vector(
        base,
        pelvis_pitch=-14,
        spine_flex=12,
        neck_flex=-4,
        **both(
            hip_flex=105,
            knee=params["knee_deg"],
            ankle=-8,
            shoulder_flex=25,
            shoulder_abd=14,
            elbow=25,
        ),
    )
    hold = params["hold_s"]
    natural = 0.9 + 0.45 + 0.55 + hold + 0.55 + 0.45 + 0.9
    t = lead_in(n, fps, natural)
    # Halfway down the buttocks approach the floor before the legs slide out (the pelvis keeps
    # going down instead of rising as the knees straighten).
    lowering = pose_vector(
        base,
        pelvis_pitch=5,
        spine_flex=12,
        **both(hip_flex=110, knee=105, ankle=12, shoulder_flex=45, elbow=20),
    )
    times = np.cumsum([t, 0.9, 0.45, 0.55, hold, 0.55, 0.45, 0.9]).tolist()
    poses = [base, low, lowering, seated, seated, lowering, low, base]
    return Track.still(keyframes(times, poses, n, fps))


def bow(params: dict, n: int, fps: float, rng: np.random.Generator, style: Style) -> Track:
    """Bend forward at the hips with the arms hanging, hold, straighten."""
    base = style.base_pose()
    depth = params["depth_deg"]
    bent = pose_vector(
        base,
        pelvis_pitch=depth,
        spine_flex=10,
        neck_flex=12,
        **both(shoulder_flex=depth + 5, elbow=10, shoulder_abd=4),
    )
    hold = params["hold_s"]
    natural = 1.0 + hold + 1.0
    t = lead_in(n, fps, natural)
    return Track.still(
        keyframes([t, t + 1.0, t + 1.0 + hold, t + natural], [base, bent, bent, base], n, fps)
    )


def stand(params: dict, n: int, fps: float, rng: np.random.Generator, style: Style) -> Track:
    """Stand still: a slow weight shift and breathing sway."""
    base = style.base_pose()
    t = np.arange(n) / fps
    dofs = np.repeat(base[None], n, axis=0)
    sway = np.sin(2 * np.pi * 0.25 * t + rng.uniform(0, 2 * np.pi))
    dofs[:, DOF["spine_lat"]] += np.radians(1.0) * sway
    dofs[:, DOF["pelvis_roll"]] += np.radians(1.0) * sway
    dofs[:, DOF["spine_flex"]] += np.radians(0.8) * np.sin(2 * np.pi * 0.3 * t)
    dofs[:, DOF["neck_flex"]] += np.radians(2.0) * np.sin(2 * np.pi * 0.13 * t + rng.uniform(0, 6))
    return Track.still(dofs)


def _sided(generator: Callable) -> Callable:
    def run(params: dict, n: int, fps: float, rng: np.random.Generator, style: Style) -> Track:
        track = generator(params, n, fps, rng, style)
        return track.mirrored() if params["side"] == "right" else track

    run.__doc__ = generator.__doc__
    return run


# --- parameter sampling ------------------------------------------------------------------------


def _choice(rng: np.random.Generator, options) -> object:
    return options[int(rng.integers(len(options)))]


def _sample_gait(rng: np.random.Generator, gait_name: str) -> tuple[dict, float]:
    directions = ["forward"] * 3 + ["backward", "left", "right", "clockwise", "counterclockwise"]
    direction = _choice(rng, directions)
    speed = _choice(rng, SPEEDS)
    if direction in ("left", "right"):
        table = _SIDE_SPEED
    else:
        table = _RUN_SPEED if gait_name == "run" else _WALK_SPEED
    if direction == "backward":
        table = {k: tuple(0.75 * x for x in v) for k, v in table.items()}
    low, high = table[speed]
    params = {
        "gait": gait_name,
        "direction": direction,
        "speed": speed,
        "speed_mps": round(float(rng.uniform(low, high)), 3),
    }
    if direction in ("clockwise", "counterclockwise"):
        params["radius_m"] = round(
            float(rng.uniform(1.2, 2.2) * (1.6 if gait_name == "run" else 1.0)), 3
        )
        turn_deg = float(rng.uniform(240, 360))
        duration = np.radians(turn_deg) * params["radius_m"] / params["speed_mps"]
        duration = float(np.clip(duration, 3.0, 7.5))
        params["angle"] = round(
            float(np.degrees(duration * params["speed_mps"] / params["radius_m"])), 1
        )
        return params, duration
    return params, float(rng.uniform(2.5, 5.0))


@dataclass(frozen=True)
class ActionSpec:
    """An action: how to sample its parameters and duration, and its generator."""

    name: str
    sample: Callable[[np.random.Generator], tuple[dict, float]]
    generate: Callable[..., Track]
    sided: bool = field(default=False)


def _sample_turn(rng):
    angle = int(_choice(rng, (90, 180)))
    return {"direction": _choice(rng, ("left", "right")), "angle": angle}, (
        1.6 if angle == 90 else 2.4
    ) + float(rng.uniform(0, 0.4))


def _turn(params, n, fps, rng, style):
    track = turn(params, n, fps, rng, style)
    return track if params["direction"] == "left" else track.mirrored()


def _sample_jump(rng):
    count = int(rng.integers(1, 4))
    forward = bool(rng.uniform() < 0.5)
    height = float(rng.uniform(0.18, 0.32))
    air = 2 * np.sqrt(2 * height / GRAVITY)
    params = {
        "mode": "forward" if forward else "in_place",
        "count": count,
        "height_m": round(height, 3),
    }
    if forward:
        params["distance_m"] = round(float(rng.uniform(0.45, 0.9)), 3)
    return params, 0.35 + count * (0.44 + air) + 0.5 + float(rng.uniform(0, 0.3))


def _sample_wave(rng):
    count = int(rng.integers(2, 5))
    rate = float(rng.uniform(1.4, 2.2))
    return {
        "side": _choice(rng, ("left", "right", "both")),
        "count": count,
        "rate_hz": round(rate, 3),
    }, 1.1 + count / rate + float(rng.uniform(0, 0.4))


def _sample_raise(rng):
    hold = float(rng.uniform(0.6, 1.6))
    return {
        "side": _choice(rng, ("left", "right", "both")),
        "hold_s": round(hold, 3),
    }, 1.5 + hold + float(rng.uniform(0, 0.3))


def _sample_kick(rng):
    return {
        "side": _choice(rng, ("left", "right")),
        "height_deg": round(float(rng.uniform(65, 85)), 1),
    }, 1.3 + float(rng.uniform(0, 0.3))


def _sample_punch(rng):
    count = int(rng.integers(1, 4))
    return {"side": _choice(rng, ("left", "right")), "count": count}, 1.0 + 0.5 * count + float(
        rng.uniform(0, 0.3)
    )


def _sample_hop(rng):
    count = int(rng.integers(2, 5))
    return {"side": _choice(rng, ("left", "right")), "count": count}, 1.1 + 0.66 * count + float(
        rng.uniform(0, 0.3)
    )


def _sample_squat(rng):
    count = int(rng.integers(1, 4))
    period = float(rng.uniform(1.5, 2.1))
    return {
        "count": count,
        "depth_deg": round(float(rng.uniform(80, 100)), 1),
        "period_s": round(period, 3),
    }, count * period + float(rng.uniform(0.1, 0.4))


def _sample_sit(rng):
    hold = float(rng.uniform(0.8, 2.0))
    return {
        "hold_s": round(hold, 3),
        "knee_deg": round(float(rng.uniform(15, 40)), 1),
    }, 4.0 + hold + float(rng.uniform(0, 0.3))


def _sample_bow(rng):
    hold = float(rng.uniform(0.4, 1.0))
    return {
        "depth_deg": round(float(rng.uniform(35, 60)), 1),
        "hold_s": round(hold, 3),
    }, 2.0 + hold + float(rng.uniform(0, 0.3))


def _sample_clap(rng):
    count = int(rng.integers(3, 8))
    rate = float(rng.uniform(1.8, 2.6))
    return {"count": count, "rate_hz": round(rate, 3)}, 1.1 + count / rate + float(
        rng.uniform(0, 0.3)
    )


def _sample_stand(rng):
    return {}, float(rng.uniform(1.5, 3.0))


ACTIONS: dict[str, ActionSpec] = {
    spec.name: spec
    for spec in (
        ActionSpec("walk", lambda rng: _sample_gait(rng, "walk"), gait),
        ActionSpec("run", lambda rng: _sample_gait(rng, "run"), gait),
        ActionSpec("turn", _sample_turn, _turn, sided=True),
        ActionSpec("jump", _sample_jump, jump),
        ActionSpec("hop", _sample_hop, _sided(hop_left), sided=True),
        ActionSpec("wave", _sample_wave, wave, sided=True),
        ActionSpec("raise", _sample_raise, raise_hands, sided=True),
        ActionSpec("kick", _sample_kick, _sided(kick_left), sided=True),
        ActionSpec("punch", _sample_punch, _sided(punch_left), sided=True),
        ActionSpec("squat", _sample_squat, squat),
        ActionSpec("sit", _sample_sit, sit),
        ActionSpec("bow", _sample_bow, bow),
        ActionSpec("clap", _sample_clap, clap),
        ActionSpec("stand", _sample_stand, stand),
    )
}
