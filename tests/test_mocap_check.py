"""The real-motion-capture check (t2m.evaluate.mocap): content detectors and a tiny end to end."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from t2m.evaluate import mocap

MOCAP = Path(__file__).resolve().parents[1].parent / "shared" / "mocap" / "bandai-namco-2"


def facts(**changes) -> dict:
    base = {
        "forward_speed_mps": 1.2, "path_speed_mps": 1.2, "speed_scale": 1.0,
        "yaw_change_deg": 0.0, "airborne_count": 0,
        "wave_left": False, "wave_right": False, "raise_left": False, "raise_right": False,
    }  # fmt: skip
    return {**base, **changes}


def test_content_checks_tell_the_contents_apart():
    checks = mocap.CONTENT_CHECKS
    assert checks["a person walks forward."](facts())
    assert not checks["a person walks forward."](facts(forward_speed_mps=0.1, path_speed_mps=0.1))
    assert not checks["a person walks forward."](facts(yaw_change_deg=90.0))
    assert checks["a person walks forward and turns left."](facts(yaw_change_deg=90.0))
    assert not checks["a person walks forward and turns right."](facts(yaw_change_deg=90.0))
    assert checks["a person runs forward."](facts(path_speed_mps=2.8, forward_speed_mps=2.8))
    assert not checks["a person runs forward."](facts())
    assert checks["a person waves the left hand."](facts(wave_left=True))
    assert not checks["a person waves the left hand."](facts(wave_left=True, wave_right=True))
    assert checks["a person raises both hands."](facts(raise_left=True, raise_right=True))


@pytest.mark.skipif(not MOCAP.is_dir(), reason="needs ../shared/mocap")
def test_tiny_check_end_to_end(tmp_path):
    data = tmp_path / "bandai" / "data"
    data.mkdir(parents=True)
    shutil.copytree(MOCAP / "cfg", tmp_path / "bandai" / "cfg")
    for bvh in sorted((MOCAP / "data").glob("*_001.bvh")):  # one clip of every content
        for suffix in (".bvh", ".json"):
            shutil.copy(bvh.with_suffix(suffix), data / bvh.with_suffix(suffix).name)
    config = mocap.MocapCheckConfig(
        mocap=data,
        dataset=tmp_path / "dataset",
        checkpoints=tmp_path / "run",
        out=tmp_path / "out",
        preset="tiny",
        samples=1,
        workers=1,
    )
    results = mocap.run_check(config)
    assert set(results["contents"]) == set(mocap.CONTENT_CHECKS)
    for row in results["contents"].values():
        assert row["generated"]["motions"] == 1 and row["real"]["motions"] >= 1
    walk = results["contents"]["a person walks forward."]["real"]
    assert walk["recognised"] > 0.5 and walk["speed_mps"] > 0.7  # real walks walk
    written = json.loads((tmp_path / "out" / "results.json").read_text())
    assert written["overall"] == results["overall"]
    assert "| **overall** |" in (tmp_path / "out" / "results.md").read_text()
