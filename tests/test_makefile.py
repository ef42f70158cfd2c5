"""The Makefile's install step refuses a linked environment (installing this checkout editable
into another checkout's environment would point that checkout's commands at this code)."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.skipif(shutil.which("make") is None, reason="make is not installed")
def test_install_refuses_a_linked_environment(tmp_path):
    for name in ("Makefile", "setup.cfg", "pyproject.toml"):
        shutil.copy(ROOT / name, tmp_path / name)
    other = tmp_path / "other_env"
    (other / "bin").mkdir(parents=True)
    python = other / "bin" / "python"
    python.write_text('#!/bin/sh\necho ran >> "$(dirname "$0")/../calls"\n')
    python.chmod(0o755)
    (tmp_path / ".venv").symlink_to(other)
    done = subprocess.run(
        ["make", "-C", str(tmp_path), "install"], capture_output=True, text=True, timeout=60
    )
    assert done.returncode != 0
    assert "symbolic link" in done.stderr and ".venv" in done.stderr
    assert not (other / "calls").exists()  # nothing was run with the linked environment
    assert not (other / ".installed").exists()
