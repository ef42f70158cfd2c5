"""Stick-figure rendering: files, frame counts, orientation on screen, determinism, errors."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import imageio_ffmpeg
import numpy as np
import pytest
from PIL import Image

from dataset_tools.rotations import y_up_to_z_up
from dataset_tools.skeleton import SMPL
from dataset_tools.viz import (
    RenderConfig,
    render_animation,
    render_contact_sheet,
    render_frames,
    render_keyframes,
)

SHARED = Path(__file__).resolve().parents[1].parent / "shared"
REFERENCE_JOINTS = SHARED / "reference" / "humanml3d" / "new_joints" / "012314.npy"


def _standing(num_frames: int = 6) -> np.ndarray:
    """A person standing in the SMPL rest directions, facing +Z, feet on the floor, walking
    slowly forwards: (T, 22, 3)."""
    pose = np.zeros((22, 3))
    # Arms out sideways (T-pose) rather than SMPL's hanging rest, so the arms are easy to find.
    directions = SMPL.rest_directions.copy()
    directions[[16, 18, 20]] = (1.0, 0.0, 0.0)
    directions[[17, 19, 21]] = (-1.0, 0.0, 0.0)
    for joint in range(1, 22):
        pose[joint] = pose[SMPL.parents[joint]] + SMPL.bone_lengths[joint] * directions[joint]
    pose[:, 1] -= pose[:, 1].min()
    steps = np.linspace(0.0, 0.2, num_frames)
    return pose[None] + np.stack([np.zeros_like(steps), np.zeros_like(steps), steps], -1)[:, None]


def _mask(image: np.ndarray, color: str) -> np.ndarray:
    rgb = np.array([int(color[i : i + 2], 16) for i in (1, 3, 5)])
    return np.abs(image.astype(int) - rgb).sum(-1) < 40


def test_front_view_puts_left_on_the_right_and_head_up():
    config = RenderConfig(azimuth=-90.0, elevation=0.0, size_px=240)
    image = next(iter(render_frames(_standing(1), config=config)))
    assert image.shape == (240, 240, 3) and image.dtype == np.uint8
    left = np.argwhere(_mask(image, config.left_color))
    right = np.argwhere(_mask(image, config.right_color))
    center = np.argwhere(_mask(image, config.center_color))
    assert len(left) > 50 and len(right) > 50 and len(center) > 20
    # Facing the camera, the person's left side is on the viewer's right.
    assert left[:, 1].mean() > right[:, 1].mean() + 30
    # y is up: the head (middle chain) is the highest thing drawn, the feet the lowest.
    assert center[:, 0].min() < min(left[:, 0].min(), right[:, 0].min())
    assert max(left[:, 0].max(), right[:, 0].max()) > center[:, 0].max()


def test_world_to_plot_axes_is_a_rotation_not_a_mirror():
    # A mirror would swap the sides and then a back view would look like a front view.
    mapping = y_up_to_z_up(np.eye(3))
    assert np.linalg.det(mapping) == pytest.approx(1.0)
    assert tuple(y_up_to_z_up(np.array([0.0, 1.0, 0.0]))) == (0.0, 0.0, 1.0)  # y-up is drawn up


def test_mp4_has_every_frame_at_20_fps(tmp_path):
    joints = _standing(9)
    path = render_animation(joints, tmp_path / "walk.mp4", caption="a person walks forward")
    reader = imageio_ffmpeg.read_frames(str(path))
    meta = next(reader)
    frames = list(reader)
    assert meta["fps"] == pytest.approx(20.0)
    assert tuple(meta["size"]) == (480, 480)
    assert len(frames) == 9
    assert os.listdir(tmp_path) == ["walk.mp4"]  # no temp file left behind


def test_gif_has_every_frame_and_duration(tmp_path):
    path = render_animation(_standing(5), tmp_path / "walk.gif", caption="walks", fps=20)
    with Image.open(path) as gif:
        assert gif.n_frames == 5
        assert gif.info["duration"] == 50
        assert gif.size == (480, 480)


def test_same_motion_same_bytes(tmp_path):
    joints = _standing(4)
    config = RenderConfig(size_px=160)
    for suffix in ("mp4", "gif"):
        a = render_animation(joints, tmp_path / f"a.{suffix}", caption="x", config=config)
        b = render_animation(joints, tmp_path / f"b.{suffix}", caption="x", config=config)
        assert a.read_bytes() == b.read_bytes()


def test_keyframe_strip_of_the_reference_clip(tmp_path):
    if not REFERENCE_JOINTS.exists():
        pytest.skip(f"real reference clip not found at {REFERENCE_JOINTS} (../shared is absent)")
    joints = np.load(REFERENCE_JOINTS)
    path = render_keyframes(
        joints, tmp_path / "strip.png", caption="a tennis serve", num_keyframes=5
    )
    with Image.open(path) as strip:
        width, height = strip.size
        pixels = np.asarray(strip.convert("RGB"))
    assert width == 5 * 240 and height > 200
    config = RenderConfig()
    # Every panel shows both sides of the body.
    for panel in np.split(pixels, 5, axis=1):
        assert _mask(panel, config.left_color).sum() > 30
        assert _mask(panel, config.right_color).sum() > 30


def test_long_walk_stays_in_view():
    # Follow camera: a 6 m walk keeps the body in the middle of every frame.
    joints = _standing(3)
    joints = joints + np.array([[[0.0, 0.0, 0.0]], [[0.0, 0.0, 3.0]], [[0.0, 0.0, 6.0]]])
    config = RenderConfig(size_px=160)
    for image in render_frames(joints, config=config):
        drawn = np.argwhere(_mask(image, config.left_color) | _mask(image, config.right_color))
        assert len(drawn) > 20
        assert 30 < drawn[:, 1].mean() < 130


@pytest.mark.parametrize(
    ("joints", "name", "match"),
    [
        (np.zeros((5, 22, 2)), "x.mp4", "shape"),
        (np.full((5, 22, 3), np.nan), "x.mp4", "NaN"),
        (np.zeros((5, 22, 3)), "x.avi", "format"),
        (np.zeros((5, 23, 3)), "x.gif", "joints"),
    ],
)
def test_bad_input_is_a_value_error_and_writes_nothing(tmp_path, joints, name, match):
    with pytest.raises(ValueError, match=match):
        render_animation(joints, tmp_path / name)
    assert not list(tmp_path.iterdir())


def test_cli_renders_joints_and_features_files(tmp_path, capsys):
    from dataset_tools.representation import process_motion
    from t2m.render import main

    joints = _standing(45)
    features, _ = process_motion(joints)
    np.save(tmp_path / "joints.npy", joints)
    np.save(tmp_path / "feats.npy", features)
    assert main([str(tmp_path / "joints.npy"), str(tmp_path / "walk.gif")]) == 0
    assert main([str(tmp_path / "feats.npy"), str(tmp_path / "strip.png"), "--keyframes", "3"]) == 0
    with Image.open(tmp_path / "walk.gif") as gif:
        assert gif.n_frames == 45
    with Image.open(tmp_path / "strip.png") as strip:
        assert strip.size[0] == 3 * 240
    assert capsys.readouterr().err == ""


def test_cli_help_lists_the_documented_options_with_their_docstrings(capsys):
    from t2m.render import main

    with pytest.raises(SystemExit) as exit_info:
        main(["--help"])
    assert exit_info.value.code == 0
    text = " ".join(capsys.readouterr().out.split())
    for expected in (
        "input output",
        "--caption CAPTION title shown above the figure",
        "--fps FPS frames per second of the motion (and of the animation); default: the "
        "dataset's rate for the joint count (20 for HumanML3D's 22 joints, 12.5 for KIT-ML's 21)",
        "--keyframes KEYFRAMES panels of a PNG strip (default: 6)",
        "or .png (a strip of key frames)",
    ):
        assert expected in text, expected


def bad_motion_files(folder: Path) -> dict[str, tuple[Path, str]]:
    """Unusable input files for the render and export commands: name -> (file, expected words)."""
    files = {}

    def save(name: str, array: np.ndarray, expected: str, **keywords) -> None:
        np.save(folder / f"{name}.npy", array, **keywords)
        files[name] = (folder / f"{name}.npy", expected)

    files["missing"] = (folder / "missing.npy", "no such file")
    save("pickled", np.array([{"joints": 1}], dtype=object), "cannot read", allow_pickle=True)
    save("joint_count", np.zeros((5, 23, 3)), "expected joints (T, 22 or 21, 3)")
    save("feature_width", np.zeros((5, 100)), "or features (T, 263 or 251)")
    save("scalar", np.float32(1.0), "got shape ()")
    save("no_frames", np.zeros((0, 22, 3)), "T >= 1")
    save("strings", np.array(["a", "b"]), "not real numbers")
    nan = _standing(5)
    nan[2, 3, 1] = np.nan
    save("nan", nan, "NaN")
    (folder / "text.npy").write_text("0.1 0.2 0.3\n")
    files["text"] = (folder / "text.npy", "not a .npy file")
    np.savez(folder / "archive.npz", joints=_standing(5))
    files["archive"] = (folder / "archive.npz", "not a .npy file")
    return files


BAD_FILES = "missing pickled joint_count feature_width scalar no_frames strings nan text archive"


@pytest.mark.parametrize("bad", BAD_FILES.split())
def test_cli_bad_input_is_one_error_line_exit_2_and_writes_nothing(tmp_path, capsys, bad):
    from t2m.render import main

    path, expected = bad_motion_files(tmp_path)[bad]
    assert main([str(path), str(tmp_path / "out" / "x.mp4")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and err.count("\n") == 1 and expected in err, err
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize(
    ("argv", "expected"),
    [
        (["x.avi"], "output must end in .mp4, .gif, .png"),
        (["x.gif", "--fps", "0"], "--fps must be positive"),
        (["x.png", "--keyframes", "0"], "--keyframes must be at least 1"),
        (["x.gif", "--fps", "fast"], "invalid float value"),
    ],
)
def test_cli_bad_options_are_one_error_line_exit_2(tmp_path, capsys, argv, expected):
    from t2m.render import main

    np.save(tmp_path / "joints.npy", _standing(5))
    assert main([str(tmp_path / "joints.npy"), str(tmp_path / argv[0]), *argv[1:]]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and err.count("\n") == 1 and expected in err, err
    assert sorted(path.name for path in tmp_path.iterdir()) == ["joints.npy"]


def test_cli_error_has_no_traceback_in_a_real_process(tmp_path):
    np.save(tmp_path / "pickled.npy", np.array([object()], dtype=object), allow_pickle=True)
    done = subprocess.run(
        [
            sys.executable,
            "-m",
            "t2m.render",
            str(tmp_path / "pickled.npy"),
            str(tmp_path / "x.gif"),
        ],
        capture_output=True,
        text=True,
    )
    assert done.returncode == 2
    assert done.stderr.startswith("error: cannot read") and "Traceback" not in done.stderr
    assert len(done.stderr.strip().splitlines()) == 1


def test_contact_sheet_has_a_row_per_clip_and_is_deterministic(tmp_path):
    clips = [(_standing(8), "a person stands"), (_standing(5)[:, :, [0, 1, 2]], "and again")]
    first = render_contact_sheet(clips, tmp_path / "a.png", frames_per_clip=3)
    second = render_contact_sheet(clips, tmp_path / "b.png", frames_per_clip=3)
    assert first.read_bytes() == second.read_bytes()
    with Image.open(first) as image:
        one_row = render_contact_sheet(clips[:1], tmp_path / "c.png", frames_per_clip=3)
        with Image.open(one_row) as single:
            assert image.size[0] == single.size[0] and image.size[1] == 2 * single.size[1]
    with pytest.raises(ValueError, match="no clips"):
        render_contact_sheet([], tmp_path / "d.png")
    with pytest.raises(ValueError, match="PNG"):
        render_contact_sheet(clips, tmp_path / "d.gif")


@pytest.mark.parametrize("num_joints,frame_ms", [(22, 50), (21, 80)])
def test_cli_animation_rate_follows_the_dataset_of_the_joint_count(tmp_path, num_joints, frame_ms):
    from PIL import Image

    from t2m.render import main

    joints = np.zeros((4, num_joints, 3), np.float32)
    joints[:, :, 1] = np.linspace(0.0, 1.7, num_joints)  # a vertical stick, visible
    np.save(tmp_path / "joints.npy", joints)
    assert main([str(tmp_path / "joints.npy"), str(tmp_path / "out.gif")]) == 0
    assert Image.open(tmp_path / "out.gif").info["duration"] == frame_ms
