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
        "yaw_change_deg": 0.0, "heading_change_deg": 0.0, "airborne_count": 0,
        "cadence_hz": 1.9, "arm_up_left": 0.0, "arm_up_right": 0.0, "arm_swings_left": 0,
        "arm_swings_right": 0, "travel_angle_deg": 0.0, "bow_depth_deg": 0.0,
    }  # fmt: skip
    return {**base, **changes}


def arm(side: str, swings: int, **changes) -> dict:
    """Facts of a motion in place with the ``side`` arm up (both: both arms)."""
    sides = ("left", "right") if side == "both" else (side,)
    up = {f"arm_up_{s}": 0.8 for s in sides} | {f"arm_swings_{s}": swings for s in sides}
    return facts(forward_speed_mps=0.0, path_speed_mps=0.03, **up, **changes)


def test_content_checks_tell_the_contents_apart():
    checks = mocap.CONTENT_CHECKS
    assert checks["a person walks forward."](facts())
    assert not checks["a person walks forward."](facts(forward_speed_mps=0.1, path_speed_mps=0.1))
    assert not checks["a person walks forward."](facts(heading_change_deg=90.0))
    assert checks["a person walks forward and turns left."](facts(heading_change_deg=90.0))
    assert not checks["a person walks forward and turns right."](facts(heading_change_deg=90.0))
    assert checks["a person runs forward."](facts(path_speed_mps=2.8, forward_speed_mps=2.8))
    assert not checks["a person runs forward."](facts())
    # A run without flight: running step rate at 1.6 m/s or more (a fast walk's rate is lower).
    assert checks["a person runs forward."](facts(path_speed_mps=1.8, cadence_hz=2.6))
    assert not checks["a person runs forward."](facts(path_speed_mps=1.4, cadence_hz=2.6))
    assert checks["a person waves the left hand."](arm("left", swings=9))
    assert not checks["a person waves the left hand."](arm("left", swings=2))  # a raised arm
    assert checks["a person raises the left hand."](arm("left", swings=2))
    assert not checks["a person waves the left hand."](arm("both", swings=9))
    assert not checks["a person waves the left hand."](arm("right", swings=9))
    assert checks["a person raises both hands."](arm("both", swings=0))
    assert checks["a person waves both hands."](arm("both", swings=12))
    # Arms swinging up while walking are neither waves nor raises.
    walking = facts(arm_up_left=0.4, arm_up_right=0.4, arm_swings_left=9, arm_swings_right=9)
    assert not any(checks[c](walking) for c in checks if "hand" in c)


def test_bandai_namco_1_checks_tell_directions_dashes_and_bows_apart():
    checks = mocap.CONTENT_CHECKS
    back = facts(forward_speed_mps=-0.9, path_speed_mps=0.9, travel_angle_deg=178.0)
    left = facts(forward_speed_mps=0.8, path_speed_mps=1.0, travel_angle_deg=30.0)
    right = facts(forward_speed_mps=0.8, path_speed_mps=1.0, travel_angle_deg=-30.0)
    ahead = facts()
    walks = {
        "a person walks backward.": back,
        "a person walks to the left.": left,
        "a person walks to the right.": right,
        "a person walks forward.": ahead,
    }
    for caption, motion in walks.items():  # each direction passes its own check only
        assert [checks[c](motion) for c in walks] == [c == caption for c in walks], caption
    assert checks["a person walks backward."](facts(path_speed_mps=0.9, travel_angle_deg=-170.0))
    assert not checks["a person walks backward."](facts(path_speed_mps=0.1, travel_angle_deg=180))
    assert not checks["a person walks to the left."]({**left, "airborne_count": 3})  # a run
    # A dash is a fast run; a slower run is no dash, nor is a fast walk.
    assert checks["a person dashes forward."](facts(path_speed_mps=3.2, airborne_count=4))
    assert not checks["a person dashes forward."](facts(path_speed_mps=2.0, airborne_count=4))
    assert not checks["a person dashes forward."](facts())
    # A bow: the trunk pitches forward and back, in place.
    bow = facts(forward_speed_mps=0.0, path_speed_mps=0.05, bow_depth_deg=40.0)
    assert checks["a person bows."](bow)
    assert not checks["a person bows."]({**bow, "bow_depth_deg": 10.0})
    assert not checks["a person bows."]({**bow, "path_speed_mps": 1.2})


def test_mocap_facts_measure_arms_steps_and_heading():
    from dataset_tools.synth.clip import synthesize_action

    def at_20_fps(action: str, params: dict, seconds: float):
        return synthesize_action(action, params, seconds).joints[::3].astype(float)

    wave = mocap.mocap_facts(
        at_20_fps("wave", {"side": "right", "count": 3, "rate_hz": 1.8}, 3), 20
    )
    assert wave["arm_up_right"] > 0.5 and wave["arm_swings_right"] >= mocap.WAVE_SWINGS
    assert wave["arm_up_left"] == 0.0
    raised = mocap.mocap_facts(at_20_fps("raise", {"side": "left", "hold_s": 1.0}, 3), 20)
    assert raised["arm_up_left"] > 0.3 and raised["arm_swings_left"] < mocap.WAVE_SWINGS
    walk = {"gait": "walk", "direction": "forward", "speed": "normal", "speed_mps": 1.2}
    walking = mocap.mocap_facts(at_20_fps("walk", walk, 4), 20)
    assert 1.4 < walking["cadence_hz"] < mocap.RUN_CADENCE_HZ
    turn = mocap.mocap_facts(at_20_fps("turn", {"direction": "right", "angle": 90}, 2), 20)
    assert -120 < turn["heading_change_deg"] < -60
    assert abs(walking["travel_angle_deg"]) < 5 and walking["bow_depth_deg"] < 5
    for direction, angle in (("backward", 180), ("left", 90), ("right", -90)):
        params = {**walk, "direction": direction}
        moved = mocap.mocap_facts(at_20_fps("walk", params, 4), 20)["travel_angle_deg"]
        assert abs((moved - angle + 180) % 360 - 180) < 15, direction
    bow = mocap.mocap_facts(at_20_fps("bow", {"depth_deg": 45, "hold_s": 0.5}, 3), 20)
    assert 35 < bow["bow_depth_deg"] < 55


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
        final_epochs=0,  # the tiny preset's own
        samples=1,
        workers=1,
    )
    results = mocap.run_check(config)
    bn2 = (
        "walk", "walk-turn-left", "walk-turn-right", "run", "wave-both-hands", "wave-left-hand",
        "wave-right-hand", "raise-up-both-hands", "raise-up-left-hand", "raise-up-right-hand",
    )  # fmt: skip
    # the contents the dataset holds (not Bandai-Namco-1's, which the check has no clips of)
    assert set(results["contents"]) == {mocap.CONTENT_LABELS[content] for content in bn2}
    for row in results["contents"].values():
        assert row["generated"]["motions"] == 1 and row["real"]["motions"] >= 1
    walk = results["contents"]["a person walks forward."]["real"]
    assert walk["recognised"] > 0.5 and walk["speed_mps"] > 0.7  # real walks walk
    # The content checks are calibrated on the real clips (all styles): 0.69 on these with the
    # previous checks.
    assert results["overall"]["real"] >= 0.9
    written = json.loads((tmp_path / "out" / "results.json").read_text())
    assert written["overall"] == results["overall"]
    assert "| **overall** |" in (tmp_path / "out" / "results.md").read_text()
