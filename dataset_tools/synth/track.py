"""What an action generator returns and the pieces every generator builds it from.

A :class:`Track` holds the joint-angle tracks of one action over n frames (poses (n, D) in
radians, see ``body.DOF_NAMES``; the heading's yaw rate; flight height and velocity while
airborne; which foot stands); a :class:`Style` holds the per-clip mannerisms applied to every
action. :func:`pose_vector`, :func:`both` and :func:`keyframes` make poses and interpolate key
poses; :func:`bump`, :func:`smoothstep` and :func:`lead_in` shape and place an action in time.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.interpolate import PchipInterpolator

from dataset_tools.synth.body import DOF, NUM_DOFS, mirror_dofs


@dataclass
class Track:
    """Joint-angle tracks of one action over n frames.

    Attributes:
        dofs: (n, D) joint angles, radians.
        yaw_rate: (n,) heading change per frame, radians (positive = turning left).
        flight: (n,) height of the airborne root above its ground-supported path, metres.
        air_velocity: (n, 2) heading-frame (left, forward) velocity in metres per frame while
            airborne; NaN lets the assembler interpolate between the neighbouring ground frames.
        stance: optional (n, 2) weights of the left and right foot as the planted one (gaits,
            where the phase says which foot carries the body); None lets the lowest foot decide.
    """

    dofs: np.ndarray
    yaw_rate: np.ndarray
    flight: np.ndarray
    air_velocity: np.ndarray
    stance: np.ndarray | None = None

    @classmethod
    def still(cls, dofs: np.ndarray) -> Track:
        n = dofs.shape[0]
        return cls(dofs, np.zeros(n), np.zeros(n), np.full((n, 2), np.nan))

    def mirrored(self) -> Track:
        air = self.air_velocity.copy()
        air[:, 0] *= -1
        stance = None if self.stance is None else self.stance[:, ::-1].copy()
        return Track(mirror_dofs(self.dofs), -self.yaw_rate, self.flight.copy(), air, stance)


@dataclass
class Style:
    """Per-clip mannerisms applied to every action (degrees and factors)."""

    stance_width: float = 3.0
    knee_bend: float = 4.0
    arm_abd: float = 8.0
    elbow: float = 14.0
    lean: float = 2.0
    head: float = 0.0
    arm_swing: float = 1.0
    tempo: float = 1.0

    @classmethod
    def sample(cls, rng: np.random.Generator) -> Style:
        return cls(
            stance_width=float(rng.uniform(1.5, 5.0)),
            knee_bend=float(rng.uniform(2.0, 7.0)),
            arm_abd=float(rng.uniform(5.0, 12.0)),
            elbow=float(rng.uniform(8.0, 22.0)),
            lean=float(rng.uniform(0.0, 5.0)),
            head=float(rng.uniform(-6.0, 6.0)),
            arm_swing=float(rng.uniform(0.75, 1.25)),
            tempo=float(rng.uniform(0.9, 1.1)),
        )

    def base_pose(self) -> np.ndarray:
        """The relaxed standing pose (D,), radians."""
        return pose_vector(
            None,
            spine_flex=self.lean,
            neck_flex=self.head,
            l_hip_abd=self.stance_width,
            r_hip_abd=self.stance_width,
            l_knee=self.knee_bend,
            r_knee=self.knee_bend,
            l_hip_flex=0.5 * self.knee_bend,
            r_hip_flex=0.5 * self.knee_bend,
            l_ankle=0.5 * self.knee_bend,
            r_ankle=0.5 * self.knee_bend,
            l_shoulder_abd=self.arm_abd,
            r_shoulder_abd=self.arm_abd,
            l_elbow=self.elbow,
            r_elbow=self.elbow,
        )


def pose_vector(base: np.ndarray | None, **degrees: float) -> np.ndarray:
    """A pose (D,) in radians: ``base`` (or zeros) with the named angles set, given in degrees."""
    pose = np.zeros(NUM_DOFS) if base is None else base.copy()
    for name, value in degrees.items():
        pose[DOF[name]] = np.radians(value)
    return pose


def both(**degrees: float) -> dict[str, float]:
    """Expand ``hip_flex=10`` to ``l_hip_flex=10, r_hip_flex=10``."""
    return {f"{s}_{k}": v for k, v in degrees.items() for s in ("l", "r")}


def keyframes(times: list[float], poses: list[np.ndarray], n: int, fps: float) -> np.ndarray:
    """Shape-preserving cubic interpolation of key poses (K, D) at times (K,) seconds to (n, D)."""
    times_arr = np.asarray(times, dtype=np.float64)
    if np.any(np.diff(times_arr) <= 0):
        raise ValueError("key times must increase")
    t = np.clip(np.arange(n) / fps, times_arr[0], times_arr[-1])
    return PchipInterpolator(times_arr, np.stack(poses), axis=0)(t)


def bump(phase: np.ndarray, centre: float, width: float) -> np.ndarray:
    """Periodic bump in [0, 1] peaking at ``centre`` (cycles) with about ``width`` cycles spread."""
    return np.exp((np.cos(2 * np.pi * (phase - centre)) - 1.0) / (2 * np.pi * width) ** 2)


def smoothstep(x: np.ndarray) -> np.ndarray:
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3 - 2 * x)


def lead_in(n: int, fps: float, natural: float) -> float:
    """Start time (s) that centres an action of ``natural`` seconds in n frames."""
    return max(0.0, 0.5 * (n / fps - natural))
