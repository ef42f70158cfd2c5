"""Atomic file writes (a reader never sees a half-written file, a crash leaves the old one), the
checks of output paths before long work, and the readers of arrays that a user names
(:func:`load_npy`, :func:`load_npz`).

This is the one atomic writer of the project (datasets, checkpoints, renders, exports all use it).
The temporary file is made beside the target (same file system, so the rename is atomic), named
``.<stem>.<8 random characters>.partial<suffix>`` (:func:`is_partial_file`; a run killed while
writing leaves one behind, which the next run removes with :func:`remove_partial_files`) and
given the permissions an ordinary ``open(path, "w")`` would: ``0o666`` less the process umask
(``tempfile.mkstemp`` alone makes 0600 files, unreadable by other users of a shared machine).

Arrays are checked from their header before a byte of data is read: a header that claims more
data than the file holds (or than the machine's memory), Python objects, strings and complex
numbers are refused with one line naming the file, so a hostile file cannot make a reader
allocate terabytes or run code.
"""

from __future__ import annotations

import contextlib
import io
import json
import math
import os
import pickle
import re
import tempfile
import zipfile
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import IO, Any

import numpy as np

from dataset_tools.command import UsageError


def _current_umask() -> int:
    # os.umask can only be read by setting it; set it back at once.
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


_PARTIAL_TAG = ".partial"
# ".<stem>.<mkstemp's 8 characters>.partial<suffix>": what atomic_output names its temporaries.
_PARTIAL_NAME = re.compile(r"\..*\.[a-z0-9_]{8}\.partial(\.[^.]*)?")


def is_partial_file(path: str | os.PathLike) -> bool:
    """Whether ``path`` is named like a temporary file of :func:`atomic_output`."""
    return _PARTIAL_NAME.fullmatch(Path(path).name) is not None


def remove_partial_files(folder: str | os.PathLike) -> list[Path]:
    """Remove the temporary files that killed writers left directly in ``folder`` (only names
    matching :func:`is_partial_file`, only plain files, no recursion); returns what was removed.

    Call it only while no other process writes into ``folder``.
    """
    folder = Path(folder)
    if not folder.is_dir():
        return []
    removed = []
    for entry in os.scandir(folder):
        if entry.is_file(follow_symlinks=False) and is_partial_file(entry.name):
            Path(entry.path).unlink(missing_ok=True)
            removed.append(Path(entry.path))
    return removed


@contextlib.contextmanager
def atomic_output(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary path beside ``path`` (same suffix) for a writer that wants a file name
    (a video encoder, ``torch.save``); when the block ends normally it is renamed onto ``path``.

    The parent folder is created. On any error (or interrupt) the temporary file is removed and
    ``path`` is left as it was. The new file gets mode ``0o666 & ~umask``.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    try:
        handle, temp = tempfile.mkstemp(
            dir=path.parent, prefix=f".{path.stem}.", suffix=f"{_PARTIAL_TAG}{path.suffix}"
        )
    except OSError as error:
        raise _naming(error, path) from None
    os.close(handle)
    try:
        os.chmod(temp, 0o666 & ~_current_umask())
        yield Path(temp)
        os.replace(temp, path)
    except BaseException as error:
        Path(temp).unlink(missing_ok=True)
        if isinstance(error, OSError) and str(error.filename) in (temp, str(path.parent)):
            raise _naming(error, path) from None
        raise


def _naming(error: OSError, path: Path) -> OSError:
    """``error`` about the temporary file (or its folder) as one about ``path``, the file the
    user asked for (the temporary name means nothing to them)."""
    if error.errno is None:
        return OSError(f"cannot write {path}: {error}")
    return OSError(error.errno, error.strerror, str(path))


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


# ----------------------------------------------------------------------------- output paths


def _check_writable_place(path: Path, folder: Path, what: str) -> None:
    """``folder`` (where ``path`` goes) exists as a writable folder or can be created: its
    nearest existing ancestor is a folder we may write in."""
    ancestor = folder
    while not os.path.lexists(ancestor) and ancestor != ancestor.parent:
        ancestor = ancestor.parent
    if not ancestor.is_dir():
        raise UsageError(f"{what} {path}: {ancestor} is a file, not a folder")
    if not os.access(ancestor, os.W_OK | os.X_OK):
        raise UsageError(f"{what} {path}: no permission to write in {ancestor}")


def check_output_file(path: str | os.PathLike, what: str = "output") -> Path:
    """Raise UsageError (one line) unless a file can be written at ``path``: it is not a folder
    and its folder is (or can be made) a writable folder. Call it before long work."""
    path = Path(path)
    if path.is_dir():
        raise UsageError(f"{what} {path} is a folder; give a file name")
    _check_writable_place(path, path.parent, what)
    return path


def check_output_folder(path: str | os.PathLike, what: str = "output folder") -> Path:
    """Raise UsageError (one line) unless ``path`` is, or can be made, a writable folder.
    Call it before long work."""
    path = Path(path)
    if os.path.lexists(path) and not path.is_dir():
        raise UsageError(f"{what} {path} exists and is not a folder")
    _check_writable_place(path, path, what)
    return path


# ----------------------------------------------------------------------------- reading arrays

_NPY_MAGIC = b"\x93NUMPY"  # the first bytes of every .npy file
_ZIP_MAGIC = b"PK\x03\x04"  # the first bytes of an .npz archive


def memory_bytes() -> int:
    """Physical memory of this machine in bytes (the bound on one array a reader will load)."""
    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError, AttributeError):  # not reported: no bound beyond the file size
        return 1 << 62


def _format_bytes(count: int) -> str:
    for unit in ("bytes", "KiB", "MiB", "GiB", "TiB", "PiB"):
        if count < 1024 or unit == "PiB":
            return f"{count:.0f} {unit}" if unit == "bytes" else f"{count:.1f} {unit}"
        count /= 1024
    raise AssertionError("unreachable")


def _read_header(file: IO[bytes]) -> tuple[tuple[int, ...], np.dtype]:
    """(shape, dtype) from the header of the .npy stream ``file``, positioned after it.

    Raises ValueError for a malformed header or a format version this reader does not take.
    """
    version = np.lib.format.read_magic(file)
    if version == (1, 0):
        shape, _, dtype = np.lib.format.read_array_header_1_0(file)
    elif version == (2, 0):
        shape, _, dtype = np.lib.format.read_array_header_2_0(file)
    else:
        raise ValueError(f"unsupported .npy format version {version[0]}.{version[1]}")
    return tuple(int(size) for size in shape), dtype


def _check_header(
    shape: tuple[int, ...], dtype: np.dtype, data_bytes: int, strings: bool = False
) -> str | None:
    """What is wrong with an array of ``shape`` and ``dtype`` stored in ``data_bytes`` bytes, or
    None. Allowed: real numbers (and text, with ``strings``); never Python objects."""
    if dtype.hasobject:
        return "it holds Python objects (a pickle), which are never loaded"
    numeric = np.issubdtype(dtype, np.number) and not np.issubdtype(dtype, np.complexfloating)
    if not (numeric or (strings and dtype.kind in "US")):
        return f"it holds {dtype} values, not real numbers"
    claimed = math.prod(shape) * dtype.itemsize
    if claimed != data_bytes:
        return (
            f"its header promises a {'x'.join(map(str, shape)) or 'scalar'} {dtype} array "
            f"({_format_bytes(claimed)}) but the file holds {_format_bytes(data_bytes)}"
        )
    if claimed > memory_bytes():
        return f"its {_format_bytes(claimed)} array is larger than this machine's memory"
    return None


def load_npy(path: str | os.PathLike, finite: bool = True) -> np.ndarray:
    """The array of a .npy file that a user named: real numbers (all finite unless ``finite`` is
    False); pickles are never loaded, and nothing is allocated before the header is checked
    against the file's size.

    Raises UsageError (one line naming the file) for a missing or empty file, a file that is not
    a .npy array (a text file, an .npz archive), a header that does not match the file's size
    or claims more than the machine's memory, Python objects, strings, complex numbers, and
    (with ``finite``) NaN or infinity.
    """
    path = Path(path)
    if not path.is_file():
        raise UsageError(f"no such file: {path}")
    try:
        with open(path, "rb") as file:
            start = file.read(len(_NPY_MAGIC))
            if not start:
                raise UsageError(f"cannot read {path}: the file is empty")
            if start.startswith(_ZIP_MAGIC):
                raise UsageError(f"cannot read {path}: not a .npy file (an .npz archive)")
            if start != _NPY_MAGIC:
                raise UsageError(f"cannot read {path}: not a .npy file (no numpy header)")
            file.seek(0)
            shape, dtype = _read_header(file)
            problem = _check_header(shape, dtype, os.fstat(file.fileno()).st_size - file.tell())
            if problem is not None:
                raise UsageError(f"cannot read {path}: {problem}")
        array = np.load(path, allow_pickle=False)
    except (OSError, ValueError, EOFError) as error:
        if isinstance(error, UsageError):
            raise
        reason = str(error).splitlines()[0] if str(error) else type(error).__name__
        raise UsageError(f"cannot read {path} as a .npy array ({reason})") from None
    if finite and not np.all(np.isfinite(array)):
        raise UsageError(f"{path} contains NaN or infinite values")
    return array


def load_npz(path: str | os.PathLike, keys: Sequence[str] | None = None) -> dict[str, np.ndarray]:
    """The arrays of an .npz archive (all, or only ``keys`` that it holds): real numbers or text;
    nothing is allocated before each member's header is checked against its stored size.

    Raises UsageError (one line naming the file) for a missing file, a file that is not an .npz
    archive, a member holding Python objects or complex numbers, or a member whose header does
    not match its size or claims more than the machine's memory.
    """
    path = Path(path)
    if not path.is_file():
        raise UsageError(f"no such file: {path}")
    arrays = {}
    try:
        with zipfile.ZipFile(path) as archive:
            for info in archive.infolist():
                key = info.filename.removesuffix(".npy")
                if keys is not None and key not in keys:
                    continue
                with archive.open(info) as member:
                    shape, dtype = _read_header(member)
                    header_bytes = member.tell()
                    problem = _check_header(
                        shape, dtype, info.file_size - header_bytes, strings=True
                    )
                    if problem is not None:
                        raise UsageError(f"cannot read {path}: member {key!r}: {problem}")
                with archive.open(info) as member:
                    arrays[key] = np.lib.format.read_array(member, allow_pickle=False)
    except (OSError, ValueError, EOFError, zipfile.BadZipFile) as error:
        if isinstance(error, UsageError):
            raise
        reason = str(error).splitlines()[0] if str(error) else type(error).__name__
        raise UsageError(f"cannot read {path} as an .npz archive ({reason})") from None
    return arrays


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


# ----------------------------------------------------------------------------- reading JSON

MAX_JSON_DEPTH = 32
"""Arrays and objects nested in one another in a JSON input we read (a batch edit with inline
key targets needs 5)."""
MAX_JSON_DIGITS = 30
"""Digits of one number in a JSON input we read (a float64 prints with at most 17, and the
largest whole number any field takes has 10)."""
MAX_JSON_BYTES = 64 * 2**20
"""The largest JSON file :func:`read_json` reads unless told otherwise."""

_BRACKET_STEP = np.zeros(256, dtype=np.int64)  # +1 for [ and {, -1 for ] and }
_BRACKET_STEP[[ord("["), ord("{")]] = 1
_BRACKET_STEP[[ord("]"), ord("}")]] = -1
_QUOTE, _BACKSLASH = ord('"'), ord("\\")
_DEPTH_CHUNK = 1 << 20


def json_depth(text: str) -> int:
    """How deep arrays and objects nest in the JSON ``text`` (brackets inside strings do not
    count), found without parsing it, in time linear in its length and memory bounded per chunk
    of a MiB: a quote ends a string unless an odd number of backslashes precedes it (a regular
    expression for strings takes quadratic time on a text of unterminated escaped quotes)."""
    data = text.encode("utf-8", "surrogatepass")  # ASCII bytes never occur inside a UTF-8 character
    deepest = level = 0
    inside, run = False, 0  # in a string at the chunk's start; backslashes that ended the last
    for start in range(0, len(data), _DEPTH_CHUNK):
        codes = np.frombuffer(data, np.uint8, min(_DEPTH_CHUNK, len(data) - start), start)
        index = np.arange(len(codes))
        # the last position at or before each one that is not a backslash (-1: none in the chunk)
        plain = np.maximum.accumulate(np.where(codes == _BACKSLASH, -1, index))
        before = np.empty(len(codes), dtype=np.int64)  # backslashes right before each position
        before[0] = run
        before[1:] = np.where(plain[:-1] >= 0, index[:-1] - plain[:-1], index[:-1] + 1 + run)
        quotes = np.cumsum((codes == _QUOTE) & (before % 2 == 0)) + inside
        steps = np.where(quotes % 2 == 1, 0, _BRACKET_STEP[codes])
        levels = np.cumsum(steps) + level
        deepest, level = max(deepest, int(levels.max())), int(levels[-1])
        inside = bool(quotes[-1] % 2)
        run = len(codes) - 1 - int(plain[-1]) if plain[-1] >= 0 else len(codes) + run
    return deepest


def parse_json(
    text: str, name: str, max_depth: int = MAX_JSON_DEPTH, max_digits: int = MAX_JSON_DIGITS
) -> Any:
    """The value of the JSON ``text`` a user gave, read strictly: arrays and objects nested at
    most ``max_depth`` deep (checked before parsing), numbers of at most ``max_digits`` digits,
    finite floats only (``1e400``, ``NaN`` and ``Infinity``, which Python's reader takes, are
    refused), no key twice in one object (which of the two would count is a guess).

    ``name`` says what the text is in messages ("the request body", "--batch edits.json").
    Raises UsageError (one line naming it) for anything else.
    """
    depth = json_depth(text)
    if depth > max_depth:
        raise UsageError(
            f"{name} is nested too deep for a JSON input: {depth} levels; at most {max_depth}"
        )

    def digits_of(literal: str) -> int:
        mantissa = re.split("[eE]", literal)[0]
        return sum(c.isdigit() for c in mantissa)

    def integer(literal: str) -> int:
        if digits_of(literal) > max_digits:
            raise UsageError(
                f"a number in {name} has {digits_of(literal)} digits; at most {max_digits}"
            )
        return int(literal)

    def real(literal: str) -> float:
        if digits_of(literal) > max_digits:
            raise UsageError(
                f"a number in {name} has {digits_of(literal)} digits; at most {max_digits}"
            )
        value = float(literal)
        if not math.isfinite(value):
            raise UsageError(f"the number {literal[:40]} in {name} is too large for a float")
        return value

    def constant(literal: str) -> float:
        raise UsageError(f"{literal} in {name} is not a JSON number: give a finite number")

    def unique(pairs: list[tuple[str, Any]]) -> dict:
        result = dict(pairs)
        if len(result) < len(pairs):
            seen = set()
            twice = next(key for key, _ in pairs if key in seen or seen.add(key))
            shown = repr(twice) if len(twice) <= 40 else repr(twice[:37]) + "..."
            raise UsageError(f"{name}: the key {shown} appears twice in one object")
        return result

    try:
        return json.loads(
            text,
            parse_int=integer,
            parse_float=real,
            parse_constant=constant,
            object_pairs_hook=unique,
        )
    except UsageError:
        raise
    except json.JSONDecodeError as error:
        where = f"line {error.lineno}, column {error.colno}: {error.msg}"
        raise UsageError(f"{name} is not valid JSON ({where})") from None
    except (ValueError, RecursionError) as error:  # RecursionError: never past the depth check
        raise UsageError(f"{name} is not valid JSON ({type(error).__name__})") from None


def read_json(
    path: str | os.PathLike,
    what: str = "",
    max_bytes: int = MAX_JSON_BYTES,
    max_depth: int = MAX_JSON_DEPTH,
) -> Any:
    """The value of a JSON file that a user named, read by :func:`parse_json` (UTF-8, a
    byte-order mark dropped) after its size is checked against ``max_bytes``.

    ``what`` names the file's role in messages (``--batch``: "--batch edits.json is not valid
    JSON ..."). Raises UsageError (one line naming the file) for a missing, unreadable, too large
    or not UTF-8 file and for every refusal of :func:`parse_json`.
    """
    path = Path(path)
    name = f"{what} {path}" if what else str(path)
    if path.is_dir():
        raise UsageError(f"{name} is a folder, not a JSON file")
    if not path.is_file():
        raise UsageError(f"{name}: no such file")
    try:
        size = path.stat().st_size
        if size > max_bytes:
            raise UsageError(
                f"{name} is {_format_bytes(size)}; a JSON input here is at most "
                f"{_format_bytes(max_bytes)}"
            )
        text = path.read_bytes().decode("utf-8-sig")
    except OSError as error:
        raise UsageError(f"cannot read {name}: {error.strerror or error}") from None
    except UnicodeDecodeError:
        raise UsageError(f"{name} is not UTF-8 text") from None
    return parse_json(text, name, max_depth=max_depth)
