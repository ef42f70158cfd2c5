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


def test_load_npy_reads_numbers_and_refuses_everything_else(tmp_path):
    from dataset_tools.command import UsageError
    from dataset_tools.io import load_npy

    good = save_npy_atomic(tmp_path / "good.npy", np.arange(6, dtype=np.float32).reshape(2, 3))
    np.testing.assert_array_equal(load_npy(good), np.arange(6).reshape(2, 3))
    pickled = tmp_path / "pickled.npy"
    np.save(pickled, np.array([{"a": 1}], dtype=object), allow_pickle=True)
    (tmp_path / "text.npy").write_text("not an array")
    np.save(tmp_path / "nan.npy", np.array([1.0, np.nan]))
    np.save(tmp_path / "strings.npy", np.array(["a", "b"]))
    cases = {
        tmp_path / "missing.npy": "no such file",
        pickled: "cannot read",
        tmp_path / "text.npy": "no numpy header",
        tmp_path / "nan.npy": "NaN",
        tmp_path / "strings.npy": "not real numbers",
    }
    for path, message in cases.items():
        with pytest.raises(UsageError, match=message) as caught:
            load_npy(path)
        assert "\n" not in str(caught.value)


def test_read_plain_pickle_reads_data_and_never_runs_code(tmp_path):
    import pickle

    from dataset_tools.command import UsageError
    from dataset_tools.io import read_plain_pickle

    words = ["sos", "eos", "unk", "walk"]
    (tmp_path / "words.pkl").write_bytes(pickle.dumps(words))
    (tmp_path / "idx.pkl").write_bytes(pickle.dumps({w: i for i, w in enumerate(words)}, 2))
    assert read_plain_pickle(tmp_path / "words.pkl") == words
    assert read_plain_pickle(tmp_path / "idx.pkl")["walk"] == 3

    marker = tmp_path / "ran"

    class Payload:
        def __reduce__(self):
            return (open, (str(marker), "w"))

    (tmp_path / "evil.pkl").write_bytes(pickle.dumps(Payload()))
    (tmp_path / "torn.pkl").write_bytes(pickle.dumps(words)[:-3])
    for name, message in (("evil", "refusing to load the global"), ("torn", "not a plain")):
        with pytest.raises(UsageError, match=message):
            read_plain_pickle(tmp_path / f"{name}.pkl")
    assert not marker.exists()
    with pytest.raises(UsageError, match="no such file"):
        read_plain_pickle(tmp_path / "missing.pkl")
