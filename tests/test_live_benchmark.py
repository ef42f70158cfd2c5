"""The live benchmark's stand-in for a slower CPU: busy loops beside the measurement."""

from __future__ import annotations

import os
import time

import pytest

from t2m.benchmarks.live import contending, main


def _cpu_seconds(pid: int) -> float:
    """User + system CPU time of a running process, from /proc."""
    with open(f"/proc/{pid}/stat") as handle:
        fields = handle.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


@pytest.mark.skipif(not os.path.isdir("/proc/self"), reason="reads CPU time from /proc")
def test_contending_loops_burn_cpu_while_the_block_runs_and_are_killed_after():
    with contending(2) as spinners:
        assert len(spinners) == 2
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline:
            if all(_cpu_seconds(s.pid) >= 0.2 for s in spinners):
                break
            time.sleep(0.1)
        assert all(s.poll() is None for s in spinners)
        assert all(_cpu_seconds(s.pid) >= 0.2 for s in spinners)
    assert all(s.returncode is not None for s in spinners)


def test_contending_loops_are_killed_when_the_block_fails():
    with pytest.raises(RuntimeError), contending(1) as spinners:
        raise RuntimeError("the measurement failed")
    assert spinners[0].returncode is not None


def test_contend_refuses_a_negative_count(capsys):
    with pytest.raises(SystemExit) as stop:
        main(["stream", "--contend", "-1"])
    assert stop.value.code == 2
    assert "--contend must be 0 or more" in capsys.readouterr().err
