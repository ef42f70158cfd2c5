"""Motion sources: BVH parsing and mappings (with the real files), SMPL-H FK, joint arrays.

Float64 bounds here carry about 10x more than the rounding counts beside them give: numpy's
AVX-512 builds compute float64 sin, cos and arccos with kernels of up to 4 ulp (not 1), and
other CPUs sum in another order.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from dataset_tools.bvh import (
    euler_to_matrix,
    forward_kinematics,
    local_transforms,
    parse_bvh,
    read_bvh,
)
from dataset_tools.rotations import to_y_up, z_up_to_y_up
from dataset_tools.skeleton import SMPL
from dataset_tools.sources import ClipError
from dataset_tools.sources.amass import axis_angle_to_matrix, load_amass, smplh_joints
from dataset_tools.sources.bvh import BvhOptions, detect_mapping, load_bvh_motion, load_mapping
from dataset_tools.sources.joints import JointsOptions, load_joints

SHARED = Path(__file__).resolve().parents[1].parent / "shared"
MOCAP = SHARED / "mocap"
needs_mocap = pytest.mark.skipif(not MOCAP.is_dir(), reason=f"real mocap files absent ({MOCAP})")

# SMPL-H: 22 body joints, then 15 left-hand joints (under the left wrist, 20) and 15 right (21);
# each hand is 5 fingers of 3 joints.
SMPLH_PARENTS = np.array(
    list(SMPL.parents)
    + [
        p
        for wrist in (20, 21)
        for base in range(22 if wrist == 20 else 37, 37 if wrist == 20 else 52, 3)
        for p in (wrist, base, base + 1)
    ]
)


def smplh_rest_joints_y_up() -> np.ndarray:
    """(52, 3) SMPL-H-like rest joints, y-up: the SMPL target body plus short finger chains."""
    joints = np.zeros((52, 3))
    offsets = SMPL.offsets
    for joint in range(1, 22):
        joints[joint] = joints[SMPL.parents[joint]] + offsets[joint]
    for joint in range(22, 52):
        side = 1.0 if joint < 37 else -1.0
        finger = ((joint - 22) % 15) // 3
        step = np.array([side * 0.03, 0.0, 0.01 * (finger - 2)])
        joints[joint] = joints[SMPLH_PARENTS[joint]] + step
    joints[:, 1] += 0.95
    return joints


def make_body_model(folder: Path, seed: int = 0, genders=("neutral",)) -> Path:
    """A tiny SMPL-H-style model folder: 52 joints regressed from 60 vertices, random shapes."""
    rng = np.random.default_rng(seed)
    rest = smplh_rest_joints_y_up()
    rest_z_up = np.stack([rest[:, 0], -rest[:, 2], rest[:, 1]], axis=-1)
    num_vertices = 60
    v_template = np.concatenate([rest_z_up, rng.normal(0, 0.3, (num_vertices - 52, 3))])
    j_regressor = np.zeros((52, num_vertices))
    j_regressor[:, :52] = np.eye(52) * 0.9
    j_regressor[:, 52:] = 0.1 / (num_vertices - 52)  # rows sum to 1, like the real regressor
    v_template[:52] = (rest_z_up - j_regressor[:, 52:] @ v_template[52:]) / 0.9
    kintree = np.stack([SMPLH_PARENTS, np.arange(52)]).astype(np.int64)
    kintree[0, 0] = 2**32 - 1
    for gender in genders:
        (folder / gender).mkdir(parents=True, exist_ok=True)
        np.savez(
            folder / gender / "model.npz",
            v_template=v_template,
            shapedirs=rng.normal(0, 0.002, (num_vertices, 3, 16)),
            J_regressor=j_regressor,
            kintree_table=kintree,
            weights=rng.dirichlet(np.ones(52), num_vertices),
            posedirs=np.zeros((num_vertices, 3, 207)),
            f=np.zeros((1, 3), dtype=np.int64),
        )
    return folder


def make_amass_npz(
    path: Path, num_frames: int = 120, fps: float = 60.0, seed: int = 0, **extra
) -> Path:
    """An AMASS-style walk-ish clip: swinging legs and arms, moving forward (z-up, facing -y)."""
    rng = np.random.default_rng(seed)
    time = np.arange(num_frames) / fps
    poses = np.zeros((num_frames, 156))
    swing = 0.5 * np.sin(2 * np.pi * 1.2 * time)
    poses[:, 3 * 1] = swing  # left hip about x
    poses[:, 3 * 2] = -swing
    poses[:, 3 * 4] = 0.4 + 0.4 * np.sin(2 * np.pi * 1.2 * time + 1.0)  # knees
    poses[:, 3 * 5] = 0.4 + 0.4 * np.sin(2 * np.pi * 1.2 * time + 4.0)
    poses[:, 3 * 16 + 2] = -1.2  # arms down-ish
    poses[:, 3 * 17 + 2] = 1.2
    poses += rng.normal(0, 0.01, poses.shape)
    trans = np.stack([0.02 * time, -1.1 * time, np.zeros_like(time)], axis=-1)  # forward is -y
    fields = dict(
        poses=poses,
        trans=trans,
        betas=rng.normal(0, 1, 16),
        gender=np.array("male"),
        mocap_framerate=np.array(fps),
        dmpls=np.zeros((num_frames, 8)),
    )
    fields.update(extra)
    fields = {key: value for key, value in fields.items() if value is not None}
    np.savez(path, **fields)
    return path


# ----------------------------------------------------------------------------- axes


def test_z_up_to_y_up_is_a_proper_rotation():
    points = np.random.default_rng(0).normal(size=(5, 3))
    rotated = z_up_to_y_up(points)
    np.testing.assert_array_equal(rotated[:, 1], points[:, 2])  # products with 0 and 1: exact
    matrix = z_up_to_y_up(np.eye(3))
    assert np.linalg.det(matrix) == 1.0  # a signed permutation: LU is exact
    with pytest.raises(ValueError, match="up axis"):
        to_y_up(points, "x")


# ----------------------------------------------------------------------------- BVH

TINY_BVH = """HIERARCHY
ROOT Hips
{
  OFFSET 0 0 0
  CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation
  JOINT Chest
  {
    OFFSET 0 10 0
    CHANNELS 3 Xrotation Yrotation Zrotation
    JOINT Arm
    {
      OFFSET 5 0 0
      CHANNELS 3 Zrotation Yrotation Xrotation
      End Site
      {
        OFFSET 4 0 0
      }
    }
  }
}
MOTION
Frames: 2
Frame Time: 0.05
1 2 3 0 0 0 0 0 0 0 0 0
0 0 0 90 0 0 0 0 0 0 0 90
"""


def test_parse_tiny_bvh_and_forward_kinematics():
    bvh = parse_bvh(TINY_BVH)
    assert bvh.names == ["Hips", "Chest", "Arm"]
    assert bvh.parents == [-1, 0, 1]
    assert bvh.channels[2] == ["Zrotation", "Yrotation", "Xrotation"]
    assert bvh.motion.shape == (2, 12) and bvh.fps == 20.0  # 1 / 0.05 rounds to 20
    positions = forward_kinematics(bvh.parents, *local_transforms(bvh))
    # Zero angles: cos 0 = 1 and sin 0 = 0, small integers: exact.
    np.testing.assert_array_equal(positions[0], [[1, 2, 3], [1, 12, 3], [6, 12, 3]])
    # Frame 1: the root turns 90 degrees about z, so the chest (0, 10, 0) goes to (-10, 0, 0) and
    # the arm's +x offset to +y; the arm's own x rotation does not move its joint.
    # cos(fl(pi / 2)) = 6e-17 times offsets <= 10, and a few 2^-53 roundings at 10 (observed
    # 8.9e-16); 1e-13 leaves 110x; a wrong channel order puts the arm 5 away.
    np.testing.assert_allclose(
        positions[1], [[0, 0, 0], [-10, 0, 0], [-10, 5, 0]], rtol=0, atol=1e-13
    )


def test_euler_order_matches_scipy_intrinsic():
    rng = np.random.default_rng(1)
    angles = rng.uniform(-180, 180, size=(20, 3))
    for order in ("ZXY", "XYZ", "ZYX", "YXZ"):
        expected = Rotation.from_euler(order, angles, degrees=True).as_matrix()
        # float64, unit entries: fl(radians), sin / cos (1 ulp) and two 3x3 products, ~2e-15
        # each side (observed 4.4e-16); 1e-13 leaves 25x; a wrong order is off by O(1).
        np.testing.assert_allclose(euler_to_matrix(angles, order), expected, rtol=0, atol=1e-13)


@pytest.mark.parametrize(
    "text, message",
    [
        ("MOTION\n", "not a BVH file"),
        (TINY_BVH.replace("0 0 0 90 0 0 0 0 0 0 0 90\n", "0 0 0 90\n"), "truncated"),
        (TINY_BVH.replace("Frame Time: 0.05", "Frame Time: 0"), "frame time"),
        (
            TINY_BVH.replace("Zrotation Yrotation Xrotation", "Zrotation Yrotation Wrotation"),
            "channel",
        ),
        (TINY_BVH.split("MOTION")[0][:-20], "end of file|incomplete"),
        (TINY_BVH.replace("1 2 3", "1 x 3"), "non-numeric"),
    ],
)
def test_parse_bvh_rejects_bad_files(text, message, tmp_path):
    with pytest.raises(ValueError, match=message):
        parse_bvh(text, "bad.bvh")
    # The BVH source reports the same problem as a clip error (the build skips the clip).
    (tmp_path / "bad.bvh").write_text(text)
    with pytest.raises(ClipError, match=message):
        load_bvh_motion(tmp_path / "bad.bvh")


def test_user_mapping_file_and_unknown_joint(tmp_path):
    mapping = {name: "Hips" for name in SMPL.joint_names}
    mapping["spine2"] = ["Hips", "Chest", 0.5]
    (tmp_path / "map.json").write_text(__import__("json").dumps(mapping))
    loaded = load_mapping(str(tmp_path / "map.json"))
    assert loaded.joints["spine2"] == ["Hips", "Chest", 0.5] and not loaded.drop_first_frame
    (tmp_path / "tiny.bvh").write_text(TINY_BVH)
    motion = load_bvh_motion(
        tmp_path / "tiny.bvh", BvhOptions(mapping=str(tmp_path / "map.json"), scale=0.01)
    )
    assert motion.joints.shape == (2, 22, 3)
    # Halfway Hips-Chest, scaled by 0.01: a midpoint and a product, <= 2 roundings (observed
    # exact); a wrong fraction or scale is off by 1% or more.
    np.testing.assert_allclose(motion.joints[0, 6], [0.01, 0.07, 0.03], rtol=2 * 2.0**-52)
    mapping["head"] = "Skull"
    (tmp_path / "bad.json").write_text(__import__("json").dumps(mapping))
    with pytest.raises(ValueError, match="Skull"):
        load_bvh_motion(
            tmp_path / "tiny.bvh", BvhOptions(mapping=str(tmp_path / "bad.json"), scale=1)
        )
    del mapping["head"]
    (tmp_path / "short.json").write_text(__import__("json").dumps(mapping))
    with pytest.raises(ValueError, match="lacks"):
        load_mapping(str(tmp_path / "short.json"))
    with pytest.raises(ValueError, match="unknown mapping"):
        load_mapping("no-such-mapping")
    with pytest.raises(ValueError, match="no built-in mapping"):
        detect_mapping(["Hips", "Chest", "Arm"])


def _facing(joints: np.ndarray) -> np.ndarray:
    """(T, 3) unit forward direction: across (right hip -> left hip) x up."""
    forward = np.cross(joints[:, 1] - joints[:, 2], [0.0, 1.0, 0.0])
    return forward / np.linalg.norm(forward, axis=-1, keepdims=True)


@needs_mocap
@pytest.mark.parametrize(
    "relative, mapping, fps, first_frame_dropped",
    [
        ("bandai-namco-2/data/dataset-2_walk_normal_001.bvh", "bandai", 30.0, False),
        ("bandai-namco-2/data/dataset-2_raise-up-left-hand_normal_001.bvh", "bandai", 30.0, False),
        ("cmu/002_01.bvh", "cmu_cc", 60.0, True),
    ],
)
def test_real_bvh_files_are_upright_face_forward_and_sided(
    relative, mapping, fps, first_frame_dropped
):
    path = MOCAP / relative
    names, parents, offsets, positions, file_fps = read_bvh(path)
    # Frame times printed to 6 or 7 decimals (0.016667, 0.0333333): half a last digit over 1/60 s
    # is 3.0e-5 relative (observed 2.0e-5 for CMU, 1e-6 for Bandai); a wrong rate is 50%+ off.
    assert len(names) == {"bandai": 22, "cmu_cc": 101}[mapping]
    assert file_fps == pytest.approx(fps, rel=3e-5, abs=0)
    motion = load_bvh_motion(path)
    joints = motion.joints
    assert motion.metadata["mapping"] == mapping and motion.metadata["scale"] == 0.01
    assert len(joints) == len(positions) - first_frame_dropped
    # Upright: head well above the pelvis, feet near the floor, a person 1.3-1.9 m to the head.
    assert (joints[:, 15, 1] - joints[:, 0, 1] > 0.4).all()
    height = joints[:, 15, 1].mean() - joints[..., 1].min()
    assert 1.3 < height < 1.9  # adult head heights; a wrong scale (cm as m) is 100x off
    # Faces forward: the toes point the way the hips face.
    toes = np.einsum("ti,ti->t", joints[:, 10] - joints[:, 7], _facing(joints))
    assert toes.mean() > 0.03
    if "walk" in relative or "cmu" in relative:
        travel = joints[-1, 0] - joints[0, 0]
        assert travel @ _facing(joints).mean(axis=0) > 1.0  # walks forward, metres
    if "left-hand" in relative:
        # Left is the person's left: the raised wrist is joint 20 (left_wrist).
        assert (joints[:, 20, 1] - joints[:, 21, 1]).max() > 0.4


@needs_mocap
def test_bandai_turn_left_turns_left():
    joints = load_bvh_motion(
        MOCAP / "bandai-namco-2/data/dataset-2_walk-turn-left_normal_001.bvh"
    ).joints
    facing = _facing(joints)
    yaw = np.unwrap(np.arctan2(facing[:, 0], facing[:, 2]))
    # Positive yaw about +y turns +z towards +x, the person's left.
    assert np.degrees(yaw[-1] - yaw[0]) > 45


# ----------------------------------------------------------------------------- AMASS


def test_axis_angle_to_matrix_matches_scipy_and_is_exact_at_zero():
    rotvecs = np.random.default_rng(2).normal(size=(50, 3))
    rotvecs[0] = 0.0
    rotvecs[1] = 1e-10
    expected = Rotation.from_rotvec(rotvecs).as_matrix()
    # float64 Rodrigues against scipy's quaternion path, unit entries, angles <= 3.2: ~10
    # roundings each side (observed 4.4e-16); 1e-13 leaves 50x; a sign or transpose is O(1).
    np.testing.assert_allclose(axis_angle_to_matrix(rotvecs), expected, rtol=0, atol=1e-13)


def test_smplh_fk_matches_a_per_frame_reference():
    rng = np.random.default_rng(3)
    rest = smplh_rest_joints_y_up()
    poses = rng.normal(0, 0.5, (4, 156))
    trans = rng.normal(size=(4, 3))
    joints = smplh_joints(poses, trans, rest, SMPLH_PARENTS)
    for frame in range(4):
        world = [None] * 52
        expected = np.zeros((52, 3))
        for joint, parent in enumerate(SMPLH_PARENTS):
            local = Rotation.from_rotvec(poses[frame, 3 * joint : 3 * joint + 3])
            if parent < 0:
                world[joint], expected[joint] = local, rest[joint]
            else:
                world[joint] = world[parent] * local
                expected[joint] = expected[parent] + world[parent].apply(rest[joint] - rest[parent])
        # float64 chains of depth <= 10 at |x| <= 2.6: per level a 3x3 product and a sum, ~1e-15
        # (observed 4.4e-16); 1e-12 leaves 100x over 10 levels; a wrong parent is off by cm.
        np.testing.assert_allclose(joints[frame], expected + trans[frame], rtol=0, atol=1e-12)
    # Bone lengths are those of the rest pose in every frame (float64, observed 3.7e-16).
    lengths = np.linalg.norm(joints[:, 1:] - joints[:, SMPLH_PARENTS[1:]], axis=-1)
    np.testing.assert_allclose(
        lengths,
        np.broadcast_to(np.linalg.norm(rest[1:] - rest[SMPLH_PARENTS[1:]], axis=-1), lengths.shape),
        rtol=0,
        atol=1e-12,
    )


def test_load_amass_rest_pose_is_the_shaped_rest_joints_y_up(tmp_path):
    models = make_body_model(tmp_path / "models", genders=("male", "neutral"))
    path = make_amass_npz(tmp_path / "clip.npz", num_frames=3, betas=np.zeros(16))
    data = dict(np.load(path))
    data["poses"] = np.zeros_like(data["poses"])
    data["trans"] = np.zeros_like(data["trans"])
    np.savez(path, **data)
    motion = load_amass(path, models)
    assert motion.joints.shape == (3, 52, 3) and motion.fps == 60.0
    assert motion.metadata["gender"] == "male"
    # float64: the regressor's 9-term rows undo the fixture's solve, then FK subtracts and adds
    # back, ~12 roundings at <= 1.7 m, 5e-15 (observed 4.4e-16); an axis swap is off by metres.
    np.testing.assert_allclose(motion.joints[0], smplh_rest_joints_y_up(), rtol=0, atol=1e-13)


def test_load_amass_gender_bytes_fallback_and_errors(tmp_path):
    models = make_body_model(tmp_path / "models")  # neutral only
    path = make_amass_npz(tmp_path / "a.npz", num_frames=5, gender=np.array(b"female"))
    motion = load_amass(path, models)
    assert motion.metadata["gender"] == "female" and motion.metadata["body_model"].endswith(
        "neutral/model.npz"
    )
    with pytest.raises(ValueError, match="mocap_framerate"):
        load_amass(make_amass_npz(tmp_path / "b.npz", mocap_framerate=None), models)
    with pytest.raises(ValueError, match="poses"):
        load_amass(make_amass_npz(tmp_path / "c.npz", poses=None), models)
    (tmp_path / "d.npz").write_bytes(path.read_bytes()[:200])
    with pytest.raises(ValueError, match="cannot read"):
        load_amass(tmp_path / "d.npz", models)
    with pytest.raises(ValueError, match="no body model"):
        load_amass(path, tmp_path / "nowhere")


# ----------------------------------------------------------------------------- joint arrays


def test_load_joints_axes_and_widths(tmp_path):
    rng = np.random.default_rng(4)
    array = rng.normal(size=(10, 24, 3)).astype(np.float32)
    np.save(tmp_path / "a.npy", array)
    motion = load_joints(tmp_path / "a.npy", JointsOptions(fps=30, up="z"))
    assert motion.joints.shape == (10, 22, 3) and motion.fps == 30.0
    np.testing.assert_array_equal(motion.joints[..., 1], array[:, :22, 2])  # a copy: exact
    np.save(tmp_path / "h.npy", rng.normal(size=(4, 52, 3)))
    assert load_joints(tmp_path / "h.npy", JointsOptions()).joints.shape == (4, 52, 3)
    np.save(tmp_path / "bad.npy", rng.normal(size=(4, 10, 3)))
    with pytest.raises(ValueError, match=r"\(T, >=22, 3\)"):
        load_joints(tmp_path / "bad.npy", JointsOptions())
    (tmp_path / "trunc.npy").write_bytes((tmp_path / "a.npy").read_bytes()[:100])
    with pytest.raises(ValueError, match="cannot read"):
        load_joints(tmp_path / "trunc.npy", JointsOptions())
