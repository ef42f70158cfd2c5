"""Label detectors and plausibility figures computed from joint positions alone.

Input everywhere: joints (T, 22, 3) of the SMPL 22-joint body, y-up, metres, at any frame rate
(``fps``), for example a 20 fps HumanML3D-canonical motion (generated or real) or a corpus clip
turned y-up. Nothing here needs the generator: the detectors can judge any motion.

``detect_labels(joints, fps)`` returns a flat, JSON-ready dict of facts about the motion:

=========================  ===================================================================
key                        meaning
=========================  ===================================================================
duration_s                 length of the motion
forward_speed_mps          mean root velocity along the body's own facing (negative: backward)
left_speed_mps             mean root velocity towards the body's own left (negative: rightward)
path_speed_mps             mean horizontal root speed
speed_scale                REFERENCE_LEG_M / the motion's leg length: multiply a speed by it to
                           compare across body sizes (1 on the HumanML3D target skeleton, so on
                           built data); speed classes and walk/run are judged on scaled speeds
displacement_m             net horizontal root displacement
yaw_change_deg             net change of facing, positive = turned left (counterclockwise seen
                           from above), unwrapped (a full circle reads about +-360)
airborne_count             episodes >= 0.1 s with every foot joint off the ground
max_airborne_height_m      highest clearance of the lowest foot joint in those episodes
hop_side                   "left"/"right": hops with the other foot held up throughout; or None
pelvis_min_ratio           lowest pelvis height over leg length (standing about 1.1, squat
                           0.5-0.75, sitting on the ground below 0.4)
dip_count                  times the pelvis went below 0.85 leg lengths and came back up
sit                        the pelvis came down to sitting-on-the-ground height
trunk_max_deg              largest forward lean of the pelvis-to-neck line from the vertical
wave_left / wave_right     wrist held above the shoulder while swinging side to side
raise_left / raise_right   wrist held well above the head without swinging
kick_left / kick_right     ankle brought up in front of the body with the other foot planted
punch_left / punch_right   number of fast straight-arm extensions of that arm forward
clap_count                 number of times the hands came together in front of the body
limb_activity_mps          mean speed of wrists and ankles relative to the pelvis
=========================  ===================================================================

``MotionSignals(joints, fps)`` computes a motion's signals once; its ``facts(a, b)`` are the
facts of any window of it (:mod:`dataset_tools.synth.matching` judges them against labels).
``plausibility(joints, fps)`` measures foot skating, ground penetration, bone-length constancy,
knee and elbow angles, and jerk.
"""

from __future__ import annotations

import functools
from collections.abc import Callable

import numpy as np
from scipy.ndimage import binary_dilation, gaussian_filter1d

from dataset_tools.kinematics import across_vector
from dataset_tools.skeleton import SMPL

_UP = np.array([0.0, 1.0, 0.0])
_FOOT_JOINTS = (*SMPL.feet_left, *SMPL.feet_right)  # (ankle, toe) of each side
# Per side, the joints the detectors read, by their role ("toe" is SMPL's foot joint).
_SIDES = {
    side: {
        role: SMPL.joint(f"{side}_{name}")
        for role, name in (
            ("hip", "hip"),
            ("knee", "knee"),
            ("ankle", "ankle"),
            ("toe", "foot"),
            ("shoulder", "shoulder"),
            ("elbow", "elbow"),
            ("wrist", "wrist"),
        )
    }
    for side in ("left", "right")
}
_OTHER = {"left": "right", "right": "left"}

# Speed-class boundaries (m/s) per gait and direction, midway between the generator's ranges.
SPEED_BOUNDS = {
    ("walk", "forward"): (0.92, 1.4),
    ("walk", "backward"): (0.69, 1.05),
    ("walk", "sideways"): (0.375, 0.57),
    ("run", "forward"): (2.67, 3.35),
    ("run", "backward"): (2.0, 2.5),
    ("run", "sideways"): (0.375, 0.57),
}
RUN_SPEED_MPS = 1.95  # forward gaits faster than this are runs
# Hip-to-ankle length of the HumanML3D target skeleton (and of the generator's mean body); gait
# speeds are compared after scaling to it, since a longer-legged subject walks faster.
REFERENCE_LEG_M = 0.821


def _check(joints: np.ndarray, fps: float) -> np.ndarray:
    joints = np.asarray(joints, dtype=np.float64)
    if joints.ndim != 3 or joints.shape[1:] != (22, 3):
        raise ValueError(f"expected joints of shape (T, 22, 3), got {joints.shape}")
    if joints.shape[0] < 2:
        raise ValueError("need at least 2 frames")
    if not np.all(np.isfinite(joints)):
        raise ValueError("joints contain NaN or infinity")
    if fps <= 0:
        raise ValueError(f"fps must be positive, got {fps}")
    return joints


def _facing(joints: np.ndarray, fps: float) -> np.ndarray:
    """Unit horizontal facing directions (T, 3), lightly smoothed (0.05 s)."""
    forward = np.cross(_UP, across_vector(joints, SMPL, compat=False))
    forward = gaussian_filter1d(forward, max(0.05 * fps, 0.5), axis=0, mode="nearest")
    forward[:, 1] = 0.0
    norm = np.linalg.norm(forward, axis=1, keepdims=True)
    return forward / np.maximum(norm, 1e-9)


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    edges = np.diff(np.concatenate([[0], mask.astype(np.int8), [0]]))
    return list(zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)))


def count_dips(signal: np.ndarray, low: float, high: float) -> int:
    """Episodes of ``signal`` below ``low``; two count as one unless it rose above ``high``
    between them (hysteresis), so a dip cut by the window's edge still counts."""
    state = np.where(signal < low, -1, np.where(signal > high, 1, 0))
    state = state[state != 0]  # the frames that arm (+1) or fire (-1) the counter
    previous = np.concatenate([[1], state[:-1]])  # armed at the start
    return int(np.sum((state == -1) & (previous == 1)))


def _count_above(signal: np.ndarray, high: float, low: float) -> int:
    """Episodes of ``signal`` rising above ``high`` (re-armed once it falls below ``low``)."""
    return count_dips(-signal, -high, -low)


def swing(signal: np.ndarray, fps: float, min_speed_mps: float = 0.6) -> tuple[float, int]:
    """Peak-to-peak range and number of direction reversals of a (T,) signal in metres (after
    0.04 s smoothing); movement slower than ``min_speed_mps`` is tremble and ignored."""
    smooth = gaussian_filter1d(signal, max(0.04 * fps, 0.5))
    velocity = np.diff(smooth) * fps
    moving = velocity[np.abs(velocity) > min_speed_mps]
    reversals = int(np.sum(np.diff(np.sign(moving)) != 0)) if len(moving) > 1 else 0
    return float(np.ptp(smooth)), reversals


class MotionSignals:
    """The per-frame signals the detectors read, computed once per motion, and the facts
    (:func:`detect_labels`) of any window of it.

    ``MotionSignals(joints, fps).facts()`` is ``detect_labels(joints, fps)``. For a window,
    ``facts(a, b)`` reads signals computed on the whole motion where they depend on neighbouring
    frames (the smoothed facing, root velocities), and the window's own statistics elsewhere
    (ground height, leg and arm lengths), so that scoring many windows of one motion (the
    alignment of :func:`align_segments`) costs a fraction of a millisecond per window.

    Args:
        joints: (T, 22, 3) y-up metres.
        fps: frame rate.
    """

    def __init__(self, joints: np.ndarray, fps: float):
        joints = _check(joints, fps)
        self.fps = float(fps)
        self.num_frames = len(joints)
        self.height = joints[..., 1]  # (T, 22)
        self.lowest_foot = self.height[:, list(_FOOT_JOINTS)].min(axis=1)  # (T,)
        forward = _facing(joints, fps)
        left = np.cross(_UP, forward)
        self.root = joints[:, 0] * np.array([1.0, 0.0, 1.0])  # (T, 3) horizontal
        velocity = np.gradient(self.root, axis=0) * fps
        self.forward_speed = np.sum(velocity * forward, axis=1)  # (T,)
        self.left_speed = np.sum(velocity * left, axis=1)
        self.path_speed = np.linalg.norm(velocity, axis=1)
        self.forward = forward  # (T, 3) unit horizontal facing
        self.yaw = np.unwrap(np.arctan2(forward[:, 0], forward[:, 2]))  # (T,) radians
        lengths = SMPL.bone_lengths_of(joints)  # (T, J): the bone ending at each joint
        lft, rgt = _SIDES["left"], _SIDES["right"]
        thighs = lengths[:, lft["knee"]] + lengths[:, rgt["knee"]]
        self.leg = 0.5 * (thighs + lengths[:, lft["ankle"]] + lengths[:, rgt["ankle"]])  # (T,)
        trunk = joints[:, 12] - joints[:, 0]
        self.lean_deg = np.degrees(np.arctan2(np.sum(trunk * forward, axis=1), trunk[:, 1]))
        self.side: dict[str, dict[str, np.ndarray]] = {}
        for side, ids in _SIDES.items():
            wrist, shoulder, elbow = (joints[:, ids[k]] for k in ("wrist", "shoulder", "elbow"))
            self.side[side] = {
                "above_shoulder": wrist[:, 1] - shoulder[:, 1],
                "above_head": wrist[:, 1] - joints[:, 15, 1],
                "lateral": np.sum((wrist - elbow) * left, axis=1),
                # ankle ahead of the pelvis along the facing
                "ahead": np.sum((joints[:, ids["ankle"]] - joints[:, 0]) * forward, axis=1),
                "arm": np.linalg.norm(elbow - shoulder, axis=1)
                + np.linalg.norm(wrist - elbow, axis=1),
                "reach": np.sum((wrist - shoulder) * forward, axis=1),  # metres, not yet / arm
            }
            # A raised arm passes through a punch's reach on its way up and down: frames within
            # 0.5 s of the wrist above the head are no punch (real punches keep the wrist 0.10 m
            # or more below the head, real raises take it 0.38 m above).
            overhead = self.side[side]["above_head"] > 0.0
            self.side[side]["raising"] = binary_dilation(
                overhead, iterations=max(1, round(0.5 * fps))
            )
        self.hands = np.linalg.norm(joints[:, 20] - joints[:, 21], axis=1)
        self.hands_in_front = (
            np.sum((0.5 * (joints[:, 20] + joints[:, 21]) - joints[:, 0]) * forward, axis=1) > 0.15
        )
        relative = joints[:, [7, 8, 20, 21]] - joints[:, :1]
        self.limb_speed = np.linalg.norm(np.diff(relative, axis=0), axis=-1).mean(axis=1) * fps
        self._busy: dict[str, np.ndarray] = {}

    def busy(self, kind: str) -> np.ndarray:
        """(T,) bool: frames inside an event of ``kind`` ("flight", "dip", "punch", "clap") as
        the counting facts define it, judged on the whole motion (its floor and leg length)."""
        if kind not in self._busy:
            whole = self.facts()
            lowest_foot = self.lowest_foot - whole.ground
            pelvis = self.height[:, 0] - whole.ground
            if kind == "flight":
                mask = (lowest_foot > 0.05) & (pelvis > 0.8 * whole.leg)
            elif kind == "dip":
                mask = pelvis < 0.85 * whole.leg
            elif kind == "punch":
                mask = np.zeros(self.num_frames, dtype=bool)
                for arm in self.side.values():
                    length = np.median(arm["arm"])
                    level = (np.abs(arm["above_shoulder"]) < 0.35 * length) & ~arm["raising"]
                    mask |= level & (arm["reach"] > 0.8 * length)
            elif kind == "clap":
                mask = self.hands_in_front & (self.hands < 0.12)
            else:
                raise ValueError(f"unknown kind of event {kind!r}")
            self._busy[kind] = mask
        return self._busy[kind]

    def facts(self, start: int = 0, end: int | None = None) -> WindowFacts:
        """The facts of frames [start, end) (see the module docstring); at least 2 frames.
        Each group of facts is computed when one of its keys is first read."""
        end = self.num_frames if end is None else end
        if not 0 <= start < end - 1 < self.num_frames:
            raise ValueError(f"window [{start}, {end}) of a {self.num_frames}-frame motion")
        return WindowFacts(self, start, end)


class WindowFacts(dict):
    """The facts of one window of a motion (:meth:`MotionSignals.facts`): a dict whose groups
    of keys (gait, flight, pelvis, arms, ...) are computed on first read, so that checking one
    label costs only what the label reads. :meth:`complete` computes them all."""

    def __init__(self, signals: MotionSignals, start: int, end: int):
        super().__init__()
        self.signals, self.start, self.end = signals, start, end
        self.window = slice(start, end)

    def __missing__(self, key: str):
        group = _FACT_GROUPS.get(key)
        if group is None:
            raise KeyError(key)
        self.update(group(self))
        return super().__getitem__(key)

    def get(self, key: str, default=None):
        return self[key] if key in self or key in _FACT_GROUPS else default

    def complete(self) -> dict:
        """Every fact, as a plain dict."""
        return {key: self[key] for key in _FACT_GROUPS}

    @functools.cached_property
    def ground(self) -> float:
        """Floor height: the 2nd percentile of the lowest foot joint's height."""
        return float(np.percentile(self.signals.lowest_foot[self.window], 2))

    @functools.cached_property
    def heights(self) -> np.ndarray:
        """(T, 22) joint heights above the floor."""
        return self.signals.height[self.window] - self.ground

    @functools.cached_property
    def leg(self) -> float:
        return float(np.median(self.signals.leg[self.window]))

    def _gait(self) -> dict:
        s, w, a, b = self.signals, self.window, self.start, self.end - 1
        return {
            "duration_s": (self.end - self.start) / s.fps,
            "forward_speed_mps": float(np.mean(s.forward_speed[w])),
            "left_speed_mps": float(np.mean(s.left_speed[w])),
            "path_speed_mps": float(np.mean(s.path_speed[w])),
            "displacement_m": float(np.linalg.norm(s.root[b] - s.root[a])),
            "yaw_change_deg": float(np.degrees(s.yaw[b] - s.yaw[a])),
            "leg_length_m": self.leg,
            "speed_scale": REFERENCE_LEG_M / self.leg,
        }

    def _flight(self) -> dict:
        """Flight: every foot joint clear of the ground."""
        heights, fps = self.heights, self.signals.fps
        lowest_foot = self.signals.lowest_foot[self.window] - self.ground
        # Sitting with the feet raised is not flight: the pelvis must be well off the ground.
        off = (lowest_foot > 0.05) & (heights[:, 0] > 0.8 * self.leg)
        airborne = [(a, b) for a, b in _runs(off) if (b - a) / fps >= 0.1]
        facts = {
            "airborne_count": len(airborne),
            "max_airborne_height_m": float(
                max((lowest_foot[a:b].max() for a, b in airborne), default=0.0)
            ),
            "hop_side": None,
        }
        if airborne:
            first, last = airborne[0][0], airborne[-1][1]
            for side in ("left", "right"):
                held = (
                    heights[:, _SIDES[_OTHER[side]]["ankle"]]
                    > heights[:, _SIDES[side]["ankle"]] + 0.12
                )
                if held[first:last].mean() > 0.9:
                    facts["hop_side"] = side
        return facts

    def _pelvis(self) -> dict:
        pelvis = self.heights[:, 0] / self.leg
        return {
            "pelvis_min_ratio": float(pelvis.min()),
            "dip_count": count_dips(pelvis, 0.85, 0.98),
            "sit": bool(pelvis.min() < 0.4),
        }

    def _trunk(self) -> dict:
        return {"trunk_max_deg": float(self.signals.lean_deg[self.window].max())}

    def _arms(self) -> dict:
        """Waving and raised arms."""
        facts = {}
        for side in _SIDES:
            signals = self.signals.side[side]
            up = signals["above_shoulder"][self.window] > 0.1
            swing_extent, swing_reversals = (
                swing(signals["lateral"][self.window][up], self.signals.fps)
                if up.sum() > 2
                else (0.0, 0)
            )
            wave = bool(up.mean() > 0.25 and swing_extent > 0.12 and swing_reversals >= 2)
            above_head = signals["above_head"][self.window] > 0.2
            facts[f"wave_{side}"] = wave
            facts[f"raise_{side}"] = bool(np.sum(above_head) / self.signals.fps >= 0.3) and not wave
        return facts

    def _kicks(self) -> dict:
        """Kick: the ankle high and in front of the pelvis while the other foot is planted."""
        facts, heights = {}, self.heights
        for side, ids in _SIDES.items():
            other = _SIDES[_OTHER[side]]
            planted = heights[:, [other["ankle"], other["toe"]]].min(axis=1) < 0.05
            ahead = self.signals.side[side]["ahead"][self.window]
            kicking = (heights[:, ids["ankle"]] > 0.35) & (ahead > 0.3) & planted
            facts[f"kick_{side}"] = bool(kicking.sum() >= max(1, round(0.05 * self.signals.fps)))
        return facts

    def _punches(self) -> dict:
        """Punch: the wrist far in front of the shoulder at chest height, the arm nearly
        straight; counted per arm."""
        reaches = {}
        for side in _SIDES:
            signals = {
                name: values[self.window] for name, values in self.signals.side[side].items()
            }
            arm = np.median(signals["arm"])
            level = np.abs(signals["above_shoulder"]) < 0.35 * arm
            reaches[side] = np.where(level, signals["reach"] / arm, 0.0)
        facts = {}
        for side in _SIDES:
            # A punch extends one arm; both arms swinging forward together (a jump) is no punch,
            # nor is an arm on its way up to or down from overhead.
            alone = reaches[_OTHER[side]] < 0.55
            alone &= ~self.signals.side[side]["raising"][self.window]
            facts[f"punch_{side}"] = _count_above(np.where(alone, reaches[side], 0.0), 0.8, 0.55)
        return facts

    def _claps(self) -> dict:
        s = self.signals
        hands = np.where(s.hands_in_front[self.window], s.hands[self.window], 1.0)
        return {"clap_count": count_dips(hands, 0.12, 0.22)}

    def _limbs(self) -> dict:
        speeds = self.signals.limb_speed[self.start : self.end - 1]
        return {"limb_activity_mps": float(np.mean(speeds))}


# Every fact, in the order detect_labels lists them, and the method of WindowFacts computing it.
_FACT_GROUPS: dict[str, Callable[[WindowFacts], dict]] = {
    key: group
    for group, keys in (
        (WindowFacts._gait, ("duration_s", "forward_speed_mps", "left_speed_mps",
                             "path_speed_mps", "displacement_m", "yaw_change_deg")),
        (WindowFacts._flight, ("airborne_count", "max_airborne_height_m", "hop_side")),
        (WindowFacts._pelvis, ("pelvis_min_ratio", "dip_count", "sit")),
        (WindowFacts._trunk, ("trunk_max_deg",)),
        (WindowFacts._arms, ("wave_left", "raise_left", "wave_right", "raise_right")),
        (WindowFacts._kicks, ("kick_left", "kick_right")),
        (WindowFacts._punches, ("punch_left", "punch_right")),
        (WindowFacts._claps, ("clap_count",)),
        (WindowFacts._limbs, ("limb_activity_mps",)),
        (WindowFacts._gait, ("leg_length_m", "speed_scale")),
    )
    for key in keys
}  # fmt: skip


def detect_labels(joints: np.ndarray, fps: float) -> dict:
    """Facts about a motion (see the module docstring) from joints (T, 22, 3), y-up metres."""
    return MotionSignals(joints, fps).facts().complete()


def plausibility(joints: np.ndarray, fps: float, floor: float = 0.0) -> dict:
    """Physical plausibility figures of joints (T, 22, 3), y-up metres, ground at ``floor``.

    Returns:
        foot_skate_mps: mean horizontal speed of foot joints while touching the ground (within 5 mm
            of the joint's lowest height in the clip; for an ankle, with its toe below 3 cm).
        penetration_m: deepest any joint goes below the floor (0 if none).
        bone_length_cv: largest relative standard deviation of a bone's length over time.
        knee_flexion_min_deg / knee_flexion_max_deg: signed knee flexion (negative =
            hyperextension, bending the wrong way).
        elbow_flexion_max_deg: largest elbow flexion (180 - the shoulder-elbow-wrist angle).
        root_jerk_mps3: 95th percentile of the pelvis' jerk magnitude (after 0.05 s smoothing).
    """
    joints = _check(joints, fps)
    heights = joints[..., 1] - floor
    horizontal = np.linalg.norm(np.diff(joints[..., [0, 2]], axis=0), axis=-1) * fps  # (T-1, J)
    speeds = []
    for ankle, toe in (SMPL.feet_left, SMPL.feet_right):
        # Contact means within 5 mm of the joint's lowest height in the clip: a foot passing low
        # (a centimetre of clearance is normal in swing) does not count.
        toe_low = heights[:, toe] < heights[:, toe].min() + 0.005
        ankle_low = (heights[:, ankle] < heights[:, ankle].min() + 0.005) & (heights[:, toe] < 0.03)
        toe_contact = toe_low[1:] & toe_low[:-1]
        ankle_contact = ankle_low[1:] & ankle_low[:-1]
        speeds += [horizontal[toe_contact, toe], horizontal[ankle_contact, ankle]]
    speeds = np.concatenate(speeds)
    lengths = SMPL.bone_lengths_of(joints)[:, 1:]
    cv = lengths.std(axis=0) / np.maximum(lengths.mean(axis=0), 1e-9)
    knees = []
    across = joints[:, 1] - joints[:, 2]
    across /= np.maximum(np.linalg.norm(across, axis=1, keepdims=True), 1e-9)
    for hip, knee, ankle in ((1, 4, 7), (2, 5, 8)):
        thigh = joints[:, knee] - joints[:, hip]
        shank = joints[:, ankle] - joints[:, knee]
        cos = np.sum(thigh * shank, axis=1) / (
            np.linalg.norm(thigh, axis=1) * np.linalg.norm(shank, axis=1)
        )
        angle = np.degrees(np.arccos(np.clip(cos, -1, 1)))
        sign = np.sign(np.sum(np.cross(thigh, shank) * across, axis=1))
        knees.append(np.where(angle > 3, sign * angle, angle))
    knees = np.concatenate(knees)
    elbows = []
    for shoulder, elbow, wrist in ((16, 18, 20), (17, 19, 21)):
        upper = joints[:, elbow] - joints[:, shoulder]
        fore = joints[:, wrist] - joints[:, elbow]
        cos = np.sum(upper * fore, axis=1) / (
            np.linalg.norm(upper, axis=1) * np.linalg.norm(fore, axis=1)
        )
        elbows.append(np.degrees(np.arccos(np.clip(cos, -1, 1))))
    root = gaussian_filter1d(joints[:, 0], max(0.05 * fps, 0.5), axis=0, mode="nearest")
    jerk = (
        np.linalg.norm(np.diff(root, 3, axis=0), axis=1) * fps**3 if len(root) > 3 else np.zeros(1)
    )
    return {
        "foot_skate_mps": float(speeds.mean()) if speeds.size else 0.0,
        "penetration_m": float(max(0.0, -heights.min())),
        "bone_length_cv": float(cv.max()),
        "knee_flexion_min_deg": float(knees.min()),
        "knee_flexion_max_deg": float(knees.max()),
        "elbow_flexion_max_deg": float(np.concatenate(elbows).max()),
        "root_jerk_mps3": float(np.percentile(jerk, 95)),
    }
