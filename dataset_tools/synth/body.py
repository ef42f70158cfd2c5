"""The synthetic subject: SMPL 22-joint proportions, joint-angle degrees of freedom and posing.

Conventions: y-up, metres, the subject faces +Z with its left side at +X when its heading yaw is 0.
A pose is a vector of named joint angles in radians (``DOF_NAMES``); ``pose_joints`` turns a
sequence of poses (T, D) plus heading yaws (T,) into joint positions (T, 22, 3) by forward
kinematics down the SMPL tree, so bone lengths are constant by construction.

Angles are anatomical and side-symmetric: ``l_hip_abd`` and ``r_hip_abd`` both move a foot away
from the midline for positive values. Rotations about the vertical (y) and sagittal (z) axes flip
sign between the sides; rotations about the left-right (x) axis do not. That makes mirroring a pose
a swap of the ``l_``/``r_`` entries plus a sign flip of the central twist/roll/lateral entries
(``mirror_dofs``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dataset_tools.skeleton import SMPL

CENTRAL_DOFS: tuple[str, ...] = (
    "pelvis_pitch",
    "pelvis_roll",
    "pelvis_twist",
    "spine_flex",
    "spine_lat",
    "spine_twist",
    "neck_flex",
    "head_flex",
)
SIDE_DOFS: tuple[str, ...] = (
    "hip_flex",
    "hip_abd",
    "hip_rot",
    "knee",
    "ankle",
    "collar_elev",
    "shoulder_flex",
    "shoulder_abd",
    "shoulder_twist",
    "elbow",
)
DOF_NAMES: tuple[str, ...] = (
    CENTRAL_DOFS + tuple(f"l_{n}" for n in SIDE_DOFS) + tuple(f"r_{n}" for n in SIDE_DOFS)
)
DOF: dict[str, int] = {name: i for i, name in enumerate(DOF_NAMES)}
NUM_DOFS = len(DOF_NAMES)

# Central rotations about y or z change sign under mirroring (x -> -x).
_MIRROR_NEGATE = np.array(
    [DOF[n] for n in ("pelvis_roll", "pelvis_twist", "spine_lat", "spine_twist")]
)
_MIRROR_PERM = np.array(
    [DOF[n] for n in CENTRAL_DOFS]
    + [DOF[f"r_{n}"] for n in SIDE_DOFS]
    + [DOF[f"l_{n}"] for n in SIDE_DOFS]
)

# Rest (T-pose, arms out) bone directions of a mean SMPL body, left/right symmetrised; the
# HumanML3D canonical directions in ``SMPL.rest_directions`` are not an anatomical pose.
_REST_DIRECTIONS = np.array([
    [0.0, 0.0, 0.0],
    [0.059, -0.087, -0.016], [-0.059, -0.087, -0.016],  # hips
    [0.0, 0.124, -0.038],  # spine1
    [0.0, -0.385, 0.0], [0.0, -0.385, 0.0],  # knees
    [0.0, 0.138, 0.027],  # spine2
    [0.0, -0.424, -0.036], [0.0, -0.424, -0.036],  # ankles
    [0.0, 0.056, 0.002],  # spine3
    [0.038, -0.062, 0.126], [-0.038, -0.062, 0.126],  # feet (toes)
    [0.0, 0.212, -0.034],  # neck
    [0.078, 0.113, -0.022], [-0.078, 0.113, -0.022],  # collars
    [0.0, 0.089, 0.050],  # head
    [0.118, 0.046, -0.010], [-0.118, 0.046, -0.010],  # shoulders
    [0.258, -0.015, -0.025], [-0.258, -0.015, -0.025],  # elbows
    [0.268, 0.008, -0.007], [-0.268, 0.008, -0.007],  # wrists
])  # fmt: skip
_REST_DIRECTIONS[1:] /= np.linalg.norm(_REST_DIRECTIONS[1:], axis=1, keepdims=True)

# Body parts whose bones share one per-subject scale factor (left and right together).
_SCALE_GROUPS: dict[str, tuple[int, ...]] = {
    "hips": (1, 2),
    "thigh": (4, 5),
    "shank": (7, 8),
    "foot": (10, 11),
    "spine": (3, 6, 9),
    "neck_head": (12, 15),
    "shoulder_girdle": (13, 14, 16, 17),
    "upper_arm": (18, 19),
    "forearm": (20, 21),
}
SEAT_DROP = 0.07  # metres from the pelvis joint down to the seat (buttocks) when sitting
_HEEL_BACK = 0.35  # heel point behind the ankle, as a fraction of the foot bone length


def _symmetric_lengths() -> np.ndarray:
    lengths = SMPL.bone_lengths.copy()
    for left, right in SMPL.left_right:
        lengths[left] = lengths[right] = 0.5 * (lengths[left] + lengths[right])
    return lengths


_BASE_LENGTHS = _symmetric_lengths()
_PARENTS = np.array(SMPL.parents)


@dataclass(frozen=True)
class Body:
    """One subject: bone offsets (22, 3) in the rest T-pose and the scales that produced them.

    Attributes:
        offsets: (22, 3) rest offsets of every joint from its parent, metres, y-up.
        overall_scale: the global size factor.
        part_scales: scale per body part (see ``_SCALE_GROUPS``), overall scale included.
    """

    offsets: np.ndarray
    overall_scale: float
    part_scales: dict[str, float]

    @property
    def bone_lengths(self) -> np.ndarray:
        """(22,) bone lengths, zero at the root."""
        return np.linalg.norm(self.offsets, axis=1)

    def label(self) -> dict:
        """JSON-ready description for ``labels.json``."""
        return {
            "overall_scale": round(self.overall_scale, 4),
            "part_scales": {k: round(v, 4) for k, v in self.part_scales.items()},
            "bone_lengths": [round(float(x), 4) for x in self.bone_lengths],
        }


def make_body(overall_scale: float = 1.0, part_scales: dict[str, float] | None = None) -> Body:
    """A body with the mean SMPL proportions times ``overall_scale`` times per-part factors."""
    part_scales = dict(part_scales or {})
    unknown = set(part_scales) - set(_SCALE_GROUPS)
    if unknown:
        raise ValueError(f"unknown body parts {sorted(unknown)}; known: {sorted(_SCALE_GROUPS)}")
    scales = np.full(SMPL.num_joints, overall_scale)
    full = {}
    for part, joints in _SCALE_GROUPS.items():
        factor = part_scales.get(part, 1.0)
        scales[list(joints)] *= factor
        full[part] = overall_scale * factor
    offsets = _REST_DIRECTIONS * (_BASE_LENGTHS * scales)[:, None]
    return Body(offsets=offsets, overall_scale=float(overall_scale), part_scales=full)


def sample_body(rng: np.random.Generator) -> Body:
    """A random subject: overall size +-8 %, each part a further +-5 % (left = right)."""
    overall = float(rng.uniform(0.92, 1.08))
    parts = {part: float(rng.uniform(0.95, 1.05)) for part in _SCALE_GROUPS}
    return make_body(overall, parts)


def mirror_dofs(dofs: np.ndarray) -> np.ndarray:
    """Mirror image (..., D) of poses (..., D): left and right swapped, central twists negated."""
    mirrored = np.asarray(dofs)[..., _MIRROR_PERM].copy()
    mirrored[..., _MIRROR_NEGATE] *= -1
    return mirrored


def _rot(axis: int, angle: np.ndarray) -> np.ndarray:
    """Rotation matrices (T, 3, 3) about coordinate axis 0/1/2 by angles (T,) (right-handed)."""
    c, s = np.cos(angle), np.sin(angle)
    out = np.zeros(angle.shape + (3, 3))
    i, j = [(1, 2), (2, 0), (0, 1)][axis]
    out[..., axis, axis] = 1.0
    out[..., i, i] = c
    out[..., j, j] = c
    out[..., i, j] = -s
    out[..., j, i] = s
    return out


def _euler(*factors: tuple[int, np.ndarray]) -> np.ndarray:
    result = _rot(*factors[0])
    for axis, angle in factors[1:]:
        result = result @ _rot(axis, angle)
    return result


def local_rotations(dofs: np.ndarray, yaw: np.ndarray) -> np.ndarray:
    """Local rotation matrices (T, 22, 3, 3) of poses (T, D) (radians) with heading yaws (T,).

    The local rotation of joint j turns the bones of j's children (the bone from the hip to the
    knee is turned by the hip's rotation). ``hip_flex`` is the thigh's flexion relative to the
    vertical of the heading frame: the pelvis pitch is compensated so that bowing (pitching the
    pelvis) leaves the legs where they are.
    """
    T = dofs.shape[0]
    d = {name: dofs[:, i] for i, name in enumerate(DOF_NAMES)}
    X, Y, Z = 0, 1, 2
    rots = np.broadcast_to(np.eye(3), (T, SMPL.num_joints, 3, 3)).copy()
    rots[:, 0] = _euler((Y, yaw + d["pelvis_twist"]), (X, d["pelvis_pitch"]), (Z, d["pelvis_roll"]))
    spine = _euler((X, d["spine_flex"] / 3), (Z, d["spine_lat"] / 3), (Y, d["spine_twist"] / 3))
    rots[:, 3] = rots[:, 6] = rots[:, 9] = spine
    rots[:, 12] = _rot(X, d["neck_flex"])
    for prefix, side, hip, knee, ankle, collar, shoulder, elbow in (
        ("l_", 1.0, 1, 4, 7, 13, 16, 18),
        ("r_", -1.0, 2, 5, 8, 14, 17, 19),
    ):
        s = {name: d[prefix + name] for name in SIDE_DOFS}
        rots[:, hip] = _euler(
            (X, -(s["hip_flex"] + d["pelvis_pitch"])),
            (Z, side * s["hip_abd"]),
            (Y, side * s["hip_rot"]),
        )
        rots[:, knee] = _rot(X, s["knee"])
        rots[:, ankle] = _rot(X, -s["ankle"])
        rots[:, collar] = _rot(Z, side * s["collar_elev"])
        rots[:, shoulder] = _euler(
            (X, -s["shoulder_flex"]),
            (Z, side * (s["shoulder_abd"] - np.pi / 2)),
            (X, s["shoulder_twist"]),
        )
        rots[:, elbow] = _rot(Y, -side * s["elbow"])
    # The head joint is a leaf; its flexion tilts nothing in a 22-joint body, so it rides on the
    # neck (the head bone hangs off the neck joint).
    rots[:, 12] = rots[:, 12] @ _rot(X, d["head_flex"])
    return rots


def forward_kinematics(local: np.ndarray, offsets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Joint positions (T, 22, 3) with the root at the origin, and global rotations (T, 22, 3, 3).

    Args:
        local: (T, 22, 3, 3) local rotations (``local_rotations``).
        offsets: (22, 3) rest offsets of the subject.
    """
    T = local.shape[0]
    glob = np.empty_like(local)
    pos = np.zeros((T, SMPL.num_joints, 3))
    glob[:, 0] = local[:, 0]
    for j in range(1, SMPL.num_joints):
        p = _PARENTS[j]
        pos[:, j] = pos[:, p] + glob[:, p] @ offsets[j]
        glob[:, j] = glob[:, p] @ local[:, j]
    return pos, glob


def contact_points(body: Body, pos: np.ndarray, glob: np.ndarray) -> np.ndarray:
    """Ground-contact candidates (T, 5, 3): left heel, left toe, right heel, right toe, seat.

    The toe is the SMPL foot joint; the heel is a point fixed to the foot at the toe's depth below
    the ankle and a little behind it, so a flat foot touches the ground at both; the seat lies
    ``SEAT_DROP`` below the pelvis joint (it only touches the ground when sitting).
    """
    out = np.empty(pos.shape[:1] + (5, 3))
    for k, (ankle, toe) in enumerate((SMPL.feet_left, SMPL.feet_right)):
        foot = body.offsets[toe]
        heel_local = np.array([0.0, foot[1], -_HEEL_BACK * np.linalg.norm(foot)])
        out[:, 2 * k] = pos[:, ankle] + glob[:, ankle] @ heel_local
        out[:, 2 * k + 1] = pos[:, toe]
    out[:, 4] = pos[:, 0] - np.array([0.0, SEAT_DROP, 0.0])
    return out
