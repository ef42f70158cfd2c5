"""Hostile and careless inputs to ``python -m t2m.export`` and to the original release's loader
(:mod:`t2m.release`). Each bad input ends in exit status 2 (or a UsageError) with one line naming
the option or file, before anything is written; nothing the user made is lost.

Export: 5 cases (an existing output file, frame rates, joints beyond a physical bound, bones of
no length, no traceback in a real process).
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from dataset_tools.bvh import read_bvh, write_bvh
from dataset_tools.gltf import write_glb
from dataset_tools.skeleton import SMPL
from t2m import export

ROOT = Path(__file__).resolve().parents[2]


def one_line(err: str, *needles: str) -> None:
    """``err`` is exactly one ``error: ...`` line holding every needle."""
    assert err.count("\n") == 1 and err.endswith("\n"), err
    assert err.startswith("error: ") and "Traceback" not in err, err
    assert all(needle in err for needle in needles), err


def walk(frames: int = 12) -> np.ndarray:
    """Joints (T, 22, 3): the template rest pose moving forward at 1 m/s (20 fps)."""
    pose = np.zeros((SMPL.num_joints, 3))
    pose[0] = (0.0, 0.95, 0.0)
    for joint, parent in enumerate(SMPL.parents):
        if parent >= 0:
            pose[joint] = pose[parent] + SMPL.offsets[joint]
    steps = np.arange(frames)[:, None, None] * np.array([0.0, 0.0, 0.05])
    return pose[None] + steps


def saved(folder: Path, joints: np.ndarray, name: str = "in.npy") -> Path:
    path = folder / name
    np.save(path, joints)
    return path


# ------------------------------------------------------------------------------------- export


def test_export_refuses_an_existing_output_file_without_overwrite(tmp_path, capsys):
    source = saved(tmp_path, walk())
    for name in ("mine.bvh", "mine.glb"):
        out = tmp_path / name
        out.write_text("the user's own file")
        assert export.main([str(source), str(out)]) == 2
        one_line(capsys.readouterr().err, str(out), "--overwrite")
        assert out.read_text() == "the user's own file"
        assert export.main([str(source), str(out), "--overwrite"]) == 0
        assert out.read_bytes() != b"the user's own file"
    assert read_bvh(tmp_path / "mine.bvh")[3].shape == (12, 22, 3)
    # the write stays atomic: nothing but the two files (no temporary left beside them)
    assert sorted(os.listdir(tmp_path)) == ["in.npy", "mine.bvh", "mine.glb"]


@pytest.mark.parametrize("fps", ["1e9", "1e300", "0.5", "1001", "inf"])
@pytest.mark.parametrize("suffix", [".bvh", ".glb"])
def test_export_refuses_a_frame_rate_outside_1_to_1000(tmp_path, capsys, fps, suffix):
    # 1e9 fps printed a BVH frame time of 0.00000000 (our reader refuses it); 1e300 fps put
    # every glTF key at time 0
    source = saved(tmp_path, walk())
    out = tmp_path / f"out{suffix}"
    assert export.main([str(source), str(out), "--fps", fps]) == 2
    one_line(capsys.readouterr().err, "--fps", "from 1 to 1000")
    assert not out.exists()
    with pytest.raises(ValueError, match="fps"):
        (write_bvh if suffix == ".bvh" else write_glb)(walk(), out, fps=float(fps))
    assert not out.exists()


def test_export_help_states_the_frame_rate_range(capsys):
    with pytest.raises(SystemExit):
        export.main(["--help"])
    assert "from 1 to 1000" in " ".join(capsys.readouterr().out.split())


@pytest.mark.parametrize("scale", [1e300, 1e5])
@pytest.mark.parametrize("suffix", [".bvh", ".glb"])
def test_export_refuses_joints_beyond_a_physical_bound(tmp_path, capsys, scale, suffix):
    # 1e300 gave a traceback (qbetween got a zero-length vector); 1e5 (millimetres read as
    # metres, 100 km away) wrote a file
    source = saved(tmp_path, walk() * scale)
    out = tmp_path / f"out{suffix}"
    assert export.main([str(source), str(out)]) == 2
    one_line(capsys.readouterr().err, str(source), "10000 m")
    assert not out.exists()
    with pytest.raises(ValueError, match="beyond"):
        write_bvh(walk() * scale, out)


@pytest.mark.parametrize("case", ["all_zero", "one_collapsed_knee"])
def test_export_refuses_bones_of_no_length(tmp_path, capsys, case):
    # all-zero joints exported a rest pose with exit 0
    joints = walk()
    if case == "all_zero":
        joints = np.zeros_like(joints)
    else:
        knee = SMPL.joint_names.index("left_knee")
        joints[5, SMPL.joint_names.index("left_ankle")] = joints[5, knee]
    source = saved(tmp_path, joints)
    for suffix in (".bvh", ".glb"):
        assert export.main([str(source), str(tmp_path / f"out{suffix}")]) == 2
        err = capsys.readouterr().err
        one_line(err, str(source), "bone", "under 1 mm")
        if case != "all_zero":
            assert "left_knee-left_ankle" in err and "frame 5" in err, err
    assert sorted(os.listdir(tmp_path)) == ["in.npy"]


def test_export_refusals_have_no_traceback_in_a_real_process(tmp_path):
    source = saved(tmp_path, walk() * 1e300)
    out = tmp_path / "out.bvh"
    done = subprocess.run(
        [sys.executable, "-m", "t2m.export", str(source), str(out)],
        capture_output=True,
        text=True,
        cwd=ROOT,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
        timeout=120,
    )
    assert done.returncode == 2
    one_line(done.stderr, str(source))
    assert not out.exists()
