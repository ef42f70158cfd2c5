"""The one atomic writer: content, permissions (umask respected), nothing left behind on error."""

import os
import stat

import numpy as np
import pytest

from dataset_tools.io import (
    atomic_output,
    atomic_write,
    save_npy_atomic,
    write_json_atomic,
    write_text_atomic,
)


def _mode(path):
    return stat.S_IMODE(os.stat(path).st_mode)


@pytest.mark.parametrize("umask", [0o022, 0o077, 0o002])
def test_files_get_the_usual_permissions(tmp_path, umask):
    old = os.umask(umask)
    try:
        paths = [
            write_text_atomic(tmp_path / "a.txt", "x"),
            save_npy_atomic(tmp_path / "b.npy", np.zeros(3)),
            write_json_atomic(tmp_path / "c.json", {"a": 1}),
        ]
        with atomic_output(tmp_path / "d.bin") as temp:
            temp.write_bytes(b"d")
        paths.append(tmp_path / "d.bin")
        with open(tmp_path / "plain.txt", "w") as file:  # what open() does, for comparison
            file.write("x")
    finally:
        os.umask(old)
    for path in paths:
        assert _mode(path) == 0o666 & ~umask == _mode(tmp_path / "plain.txt"), path


def test_content_round_trips(tmp_path):
    assert write_text_atomic(tmp_path / "sub" / "t.txt", "héllo").read_text("utf-8") == "héllo"
    array = np.arange(6.0).reshape(2, 3)
    np.testing.assert_array_equal(np.load(save_npy_atomic(tmp_path / "a.npy", array)), array)


def test_error_keeps_the_old_file_and_leaves_no_temporary(tmp_path):
    target = write_text_atomic(tmp_path / "keep.txt", "old")

    def failing(file):
        file.write(b"half")
        raise RuntimeError("disk full")

    with pytest.raises(RuntimeError, match="disk full"):
        atomic_write(target, failing)
    with pytest.raises(KeyboardInterrupt), atomic_output(target) as temp:
        temp.write_bytes(b"half")
        raise KeyboardInterrupt
    assert target.read_text() == "old"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["keep.txt"]
