import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

REFERENCE = Path(__file__).resolve().parents[1].parent / "shared" / "reference" / "humanml3d"


def _run(*args):
    return subprocess.run(
        [sys.executable, "-m", "dataset_tools", *args], capture_output=True, text=True
    )


@pytest.mark.skipif(not REFERENCE.is_dir(), reason="../shared/reference/humanml3d is absent")
def test_features_then_recover(tmp_path):
    features = tmp_path / "f.npy"
    joints = tmp_path / "j.npy"
    done = _run("features", str(REFERENCE / "new_joints" / "012314.npy"), str(features))
    assert done.returncode == 0, done.stderr
    assert np.load(features).shape == (169, 263)
    done = _run("recover", str(features), str(joints))
    assert done.returncode == 0, done.stderr
    assert np.load(joints).shape == (169, 22, 3)


def test_help_and_bad_inputs(tmp_path):
    for command in ("features", "recover"):
        done = _run(command, "--help")
        assert done.returncode == 0 and "usage" in done.stdout
    missing = _run("features", str(tmp_path / "nope.npy"), str(tmp_path / "out.npy"))
    assert missing.returncode == 2 and "no such file" in missing.stderr
    assert len(missing.stderr.strip().splitlines()) == 1
    np.save(tmp_path / "wrong.npy", np.zeros((10, 5, 3)))
    wrong = _run("features", str(tmp_path / "wrong.npy"), str(tmp_path / "out.npy"))
    assert wrong.returncode == 2 and "expected joints" in wrong.stderr
    nan = np.zeros((10, 263))
    nan[3, 3] = np.nan
    np.save(tmp_path / "nan.npy", nan)
    bad = _run("recover", str(tmp_path / "nan.npy"), str(tmp_path / "out.npy"))
    assert bad.returncode == 2 and "NaN" in bad.stderr
    np.save(tmp_path / "pickled.npy", np.array([{"joints": 1}], dtype=object), allow_pickle=True)
    pickled = _run("recover", str(tmp_path / "pickled.npy"), str(tmp_path / "out.npy"))
    assert pickled.returncode == 2 and pickled.stderr.startswith("error: cannot read")
    assert len(pickled.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "out.npy").exists()
