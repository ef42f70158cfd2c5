"""AMASS source: SMPL-H parameters (.npz) to 52 joint positions, y-up metres.

Joint positions are the forward kinematics of the body model's rest joints: the shaped template
``v_template + shapedirs[..., :10] @ betas[:10]`` regressed by ``J_regressor`` gives the rest
joints (52, 3); each frame's axis-angle ``poses`` (52 x 3) rotate the bones, ``trans`` moves the
body. Joints do not depend on pose blend shapes or skinning, so ``posedirs`` and ``weights`` are
not needed. AMASS is z-up; the result is turned to y-up. (``smplx`` would do the same but pulls in
heavy dependencies for a dozen lines of numpy.)
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from dataset_tools.command import UsageError
from dataset_tools.io import load_npz
from dataset_tools.rotations import z_up_to_y_up
from dataset_tools.sources import ClipError, Motion

NUM_JOINTS = 52
NUM_BETAS = 10
GENDERS = ("male", "female", "neutral")
MODEL_KEYS = ("v_template", "shapedirs", "J_regressor", "kintree_table")


@dataclass(frozen=True)
class BodyModel:
    """The parts of an SMPL-H model that joint positions need.

    Attributes:
        v_template: (V, 3) template vertices.
        shapedirs: (V, 3, S) shape blend directions.
        j_regressor: (J, V) joint regressor.
        parents: (J,) parent index, -1 for the root; parents precede children.
    """

    v_template: np.ndarray
    shapedirs: np.ndarray
    j_regressor: np.ndarray
    parents: np.ndarray

    def rest_joints(self, betas: np.ndarray) -> np.ndarray:
        """Rest joints (J, 3) of the body shaped by the first ``NUM_BETAS`` of ``betas``."""
        betas = np.asarray(betas, dtype=np.float64).reshape(-1)[:NUM_BETAS]
        directions = self.shapedirs[..., : betas.shape[0]]
        vertices = self.v_template + directions @ betas  # (V, 3)
        return self.j_regressor @ vertices


def _npz(path: Path, keys: tuple[str, ...]) -> dict[str, np.ndarray]:
    """The members ``keys`` of an .npz file (those it has); ClipError when it is unreadable."""
    try:
        return load_npz(path, keys)
    except UsageError as error:
        raise ClipError(str(error)) from None


@functools.cache
def load_body_model(path: str) -> BodyModel:
    """Read an SMPL-H ``model.npz`` (cached per process). Raises ValueError for an unreadable
    file or missing keys."""
    data = _npz(Path(path), MODEL_KEYS)
    missing = [key for key in MODEL_KEYS if key not in data]
    if missing:
        raise ValueError(f"body model {path} lacks {missing}")
    template, directions = _numeric(data, "v_template"), _numeric(data, "shapedirs")
    regressor, tree = _numeric(data, "J_regressor"), _numeric(data, "kintree_table")
    vertices = template.shape[0] if template.ndim == 2 else -1
    if not (
        template.shape == (vertices, 3)
        and directions.ndim == 3
        and directions.shape[:2] == (vertices, 3)
        and regressor.ndim == 2
        and regressor.shape[1] == vertices
        and tree.ndim == 2
        and tree.shape[1] == regressor.shape[0]
    ):
        raise ValueError(
            f"body model {path}: expected v_template (V, 3), shapedirs (V, 3, S), J_regressor "
            f"(J, V) and kintree_table (2, J); got {template.shape}, {directions.shape}, "
            f"{regressor.shape}, {tree.shape}"
        )
    parents = tree[0].astype(np.int64)
    parents[0] = -1  # stored as 2**32 - 1 in the released files
    if np.any(parents[1:] >= np.arange(1, len(parents))) or np.any(parents[1:] < 0):
        raise ValueError(f"body model {path}: kintree_table parents must precede children")
    return BodyModel(
        v_template=template.astype(np.float64),
        shapedirs=directions.astype(np.float64),
        j_regressor=regressor.astype(np.float64),
        parents=parents,
    )


def _numeric(data: dict[str, np.ndarray], key: str) -> np.ndarray:
    """``data[key]`` when it holds numbers; ClipError naming the key otherwise."""
    value = data[key]
    if not np.issubdtype(value.dtype, np.number):
        raise ClipError(f"{key} holds {value.dtype} values, not numbers")
    return value


def axis_angle_to_matrix(axis_angle: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) from axis-angle vectors (..., 3) (Rodrigues; exact at 0)."""
    axis_angle = np.asarray(axis_angle, dtype=np.float64)
    angle = np.linalg.norm(axis_angle, axis=-1, keepdims=True)[..., None]  # (..., 1, 1)
    small = angle < 1e-8
    safe = np.where(small, 1.0, angle)
    x, y, z = np.moveaxis(axis_angle, -1, 0)
    zero = np.zeros_like(x)
    cross = np.stack([zero, -z, y, z, zero, -x, -y, x, zero], axis=-1).reshape(
        axis_angle.shape[:-1] + (3, 3)
    )
    # sin(a)/a and (1 - cos(a))/a^2 fall back to their limits 1 and 1/2 near zero.
    sin_term = np.where(small, 1.0, np.sin(safe) / safe)
    cos_term = np.where(small, 0.5, (1.0 - np.cos(safe)) / safe**2)
    return np.eye(3) + sin_term * cross + cos_term * (cross @ cross)


def smplh_joints(
    poses: np.ndarray, trans: np.ndarray, rest_joints: np.ndarray, parents: np.ndarray
) -> np.ndarray:
    """Posed joint positions (T, J, 3) in the model's frame.

    Args:
        poses: (T, 3J) axis-angle rotation of every joint relative to its parent.
        trans: (T, 3) root translation.
        rest_joints: (J, 3) rest joints of the shaped body.
        parents: (J,) parents, -1 for the root.
    """
    num_frames, num_joints = poses.shape[0], len(parents)
    rotations = axis_angle_to_matrix(poses.reshape(num_frames, num_joints, 3))  # (T, J, 3, 3)
    bones = rest_joints - np.where(parents[:, None] >= 0, rest_joints[np.maximum(parents, 0)], 0.0)
    global_rotations = np.empty_like(rotations)
    positions = np.empty((num_frames, num_joints, 3))
    for joint, parent in enumerate(parents):
        if parent < 0:
            global_rotations[:, joint] = rotations[:, joint]
            positions[:, joint] = rest_joints[joint]
        else:
            global_rotations[:, joint] = global_rotations[:, parent] @ rotations[:, joint]
            positions[:, joint] = positions[:, parent] + global_rotations[:, parent] @ bones[joint]
    return positions + np.asarray(trans, dtype=np.float64)[:, None, :]


def _gender(data: dict[str, np.ndarray]) -> str:
    if "gender" not in data:
        return "neutral"
    value = data["gender"]
    value = value.item() if isinstance(value, np.ndarray) else value
    if isinstance(value, bytes):
        value = value.decode("utf-8", errors="replace")
    return str(value).strip().lower()


def load_amass(path: str | Path, body_model_dir: str | Path) -> Motion:
    """Read one AMASS ``.npz`` as 52 joints (T, 52, 3), y-up metres, at its mocap frame rate.

    ``body_model_dir`` holds ``male|female|neutral/model.npz``; the file's gender picks one,
    falling back to neutral. Raises ClipError for missing keys (``mocap_framerate`` included),
    wrong shapes or a missing body model.
    """
    path = Path(path)
    data = _npz(path, ("mocap_framerate", "poses", "trans", "betas", "gender"))
    if "mocap_framerate" not in data:
        raise ClipError("no mocap_framerate (not a motion file)")
    missing = [key for key in ("poses", "trans", "betas") if key not in data]
    if missing:
        raise ClipError(f"missing key(s) {missing}")
    poses = _numeric(data, "poses").astype(np.float64)
    trans = _numeric(data, "trans").astype(np.float64)
    if poses.ndim != 2 or poses.shape[1] < 3 * NUM_JOINTS or trans.shape != (poses.shape[0], 3):
        raise ClipError(
            f"poses (T, 156) and trans (T, 3) expected, got {poses.shape}, {trans.shape}"
        )
    gender = _gender(data)
    folder = Path(body_model_dir)
    candidates = [folder / gender / "model.npz", folder / "neutral" / "model.npz"]
    model_path = next((candidate for candidate in candidates if candidate.is_file()), None)
    if model_path is None:
        raise ClipError(f"no body model for gender {gender!r} under {folder}")
    model = load_body_model(str(model_path))
    if len(model.parents) != NUM_JOINTS:
        raise ValueError(f"body model has {len(model.parents)} joints, SMPL-H has {NUM_JOINTS}")
    rest = model.rest_joints(_numeric(data, "betas"))
    joints = smplh_joints(poses[:, : 3 * NUM_JOINTS], trans, rest, model.parents)
    framerate = _numeric(data, "mocap_framerate").reshape(-1)
    if framerate.size != 1:
        raise ClipError(f"mocap_framerate must be one number, got {framerate.size}")
    fps = float(framerate[0])
    metadata = {"gender": gender, "body_model": str(model_path)}
    return Motion(joints=z_up_to_y_up(joints), fps=fps, metadata=metadata)
