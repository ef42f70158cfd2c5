"""Atomic file writes (a reader never sees a half-written file, a crash leaves the old one), and
the one reader of arrays that a user names on a command line (:func:`load_npy`).

This is the one atomic writer of the project (datasets, checkpoints, renders, exports all use it).
The temporary file is made beside the target (same file system, so the rename is atomic) and
given the permissions an ordinary ``open(path, "w")`` would: ``0o666`` less the process umask
(``tempfile.mkstemp`` alone makes 0600 files, unreadable by other users of a shared machine).
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import pickle
import tempfile
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import IO, Any

import numpy as np

from dataset_tools.command import UsageError


def _current_umask() -> int:
    # os.umask can only be read by setting it; set it back at once.
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


@contextlib.contextmanager
def atomic_output(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary path beside ``path`` (same suffix) for a writer that wants a file name
    (a video encoder, ``torch.save``); when the block ends normally it is renamed onto ``path``.

    The parent folder is created. On any error (or interrupt) the temporary file is removed and
    ``path`` is left as it was. The new file gets mode ``0o666 & ~umask``.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    handle, temp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.stem}.", suffix=path.suffix)
    os.close(handle)
    try:
        os.chmod(temp, 0o666 & ~_current_umask())
        yield Path(temp)
        os.replace(temp, path)
    except BaseException:
        Path(temp).unlink(missing_ok=True)
        raise


def atomic_write(path: str | os.PathLike, write: Callable[[IO[bytes]], Any]) -> Path:
    """Call ``write(file)`` on a temporary binary file beside ``path``, then rename it onto
    ``path`` (see :func:`atomic_output`)."""
    with atomic_output(path) as temp, open(temp, "wb") as file:
        write(file)
    return Path(path)


def write_bytes_atomic(path: str | os.PathLike, data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically."""
    return atomic_write(path, lambda file: file.write(data))


def save_npy_atomic(path: str | os.PathLike, array: np.ndarray) -> Path:
    """Write ``array`` to ``path`` (.npy) atomically."""
    return atomic_write(path, lambda file: np.save(file, np.asarray(array), allow_pickle=False))


def write_text_atomic(path: str | os.PathLike, text: str) -> Path:
    """Write UTF-8 ``text`` to ``path`` atomically."""
    return write_bytes_atomic(path, text.encode("utf-8"))


def write_json_atomic(path: str | os.PathLike, data: Any) -> Path:
    """Write ``data`` as indented JSON to ``path`` atomically."""
    return write_text_atomic(path, json.dumps(data, indent=2, sort_keys=False) + "\n")


_NPY_MAGIC = b"\x93NUMPY"  # the first bytes of every .npy file


def load_npy(path: str | os.PathLike) -> np.ndarray:
    """The array of a .npy file that a user named: numbers, all finite; pickles are never loaded.

    Raises UsageError (one line naming the file) for a missing file, a file that is not a .npy
    array (a text file, an .npz archive) or holds Python objects, non-numeric values, NaN or
    infinity.
    """
    path = Path(path)
    if not path.is_file():
        raise UsageError(f"no such file: {path}")
    try:
        with open(path, "rb") as file:
            is_npy = file.read(len(_NPY_MAGIC)) == _NPY_MAGIC
        array = np.load(path, allow_pickle=False) if is_npy else None
    except (OSError, ValueError) as error:
        reason = str(error).splitlines()[0] if str(error) else type(error).__name__
        raise UsageError(f"cannot read {path} as a .npy array ({reason})") from error
    if array is None:
        raise UsageError(f"{path} is not a .npy file (no numpy header)")
    if not np.issubdtype(array.dtype, np.number) or np.issubdtype(array.dtype, np.complexfloating):
        raise UsageError(f"{path} holds {array.dtype} values, not real numbers")
    if not np.all(np.isfinite(array)):
        raise UsageError(f"{path} contains NaN or infinite values")
    return array


class _PlainUnpickler(pickle.Unpickler):
    """An unpickler that refuses every global: only plain containers and scalars come back."""

    def find_class(self, module: str, name: str) -> Any:
        raise pickle.UnpicklingError(f"refusing to load the global {module}.{name}")


def read_plain_pickle(path: str | os.PathLike) -> Any:
    """The content of a pickle that holds only plain data (lists, dicts, tuples, str, numbers,
    bool, None), such as the original T2M release's vocabulary files; nothing in the file can run.

    Raises UsageError (one line naming the file) for a missing file or a pickle that needs any
    class or function (which is how pickle payloads run code) or is malformed.
    """
    path = Path(path)
    if not path.is_file():
        raise UsageError(f"no such file: {path}")
    try:
        return _PlainUnpickler(io.BytesIO(path.read_bytes())).load()
    except (pickle.UnpicklingError, EOFError, ValueError, TypeError, IndexError) as error:
        raise UsageError(
            f"{path}: not a plain-data pickle, refused without running it ({error})"
        ) from None
