"""What keeps a dataset folder safe while ``dataset_tools.build`` writes into it.

- ``build_options.json`` (:data:`dataset_tools.humanml3d.OPTIONS_FILE`), written before the
  first clip, records the options that shape a clip
  (:meth:`dataset_tools.build.BuildConfig.content_options`); a re-run with
  other options, or into a non-empty folder that no build wrote, is refused
  (:func:`claim_output`; ``--force`` rebuilds every clip of an earlier build with the new ones);
- one build at a time writes into a folder (:func:`exclusive`, a lock on the folder);
- clip names that would collide on disk (equal up to case, or equal to another clip's mirror
  name ``M<name>``) or cannot be stored (hidden, control characters, too long) are refused and
  reported, so no clip overwrites another or appears in two splits (:func:`refuse_unsafe_names`).
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import os
import unicodedata
from collections.abc import Iterator, Sequence
from pathlib import Path

from dataset_tools import humanml3d
from dataset_tools.command import UsageError
from dataset_tools.humanml3d import OPTIONS_FILE, mirror_name
from dataset_tools.io import write_json_atomic
from dataset_tools.sources import ClipTask

OPTIONS_FORMAT = 1
# The longest file name most file systems take; a clip's longest is its mirror's temporary file.
MAX_FILE_NAME_BYTES = 255
_TEMPORARY_NAME_OVERHEAD = len("..abcdefgh.partial.npy")


def _name_problem(name: str) -> str | None:
    """Why ``name`` cannot name a clip's files and split lines, or None."""
    if not name:
        return "empty clip name"
    try:
        name.encode("utf-8")
    except UnicodeEncodeError:
        return "the file name is not valid UTF-8"
    if name.startswith("."):
        return "clip names starting with '.' would be hidden files"
    if not name.isprintable() or name != name.strip() or "\\" in name:
        return "clip names must not hold control characters, a backslash or outer spaces"
    longest = len(mirror_name(name).encode("utf-8")) + _TEMPORARY_NAME_OVERHEAD
    if longest > MAX_FILE_NAME_BYTES:
        return f"clip name too long ({len(name.encode('utf-8'))} bytes)"
    return None


def _name_key(name: str) -> str:
    """Names equal under this key are one file on a case-insensitive (or normalising) disk."""
    return unicodedata.normalize("NFC", name).casefold()


def refuse_unsafe_names(tasks: Sequence[ClipTask]) -> tuple[list[ClipTask], list[dict]]:
    """Split ``tasks`` into those safe to build and refusals (``{name, path, reason}``).

    Refused: names that cannot be stored (:func:`_name_problem`); names equal to another task's
    up to case or Unicode normalisation (all of them: none may overwrite another, and which one
    wins must not depend on the order of files); names equal to another task's mirror name
    (``walk`` and ``Mwalk``: the mirror keeps its name, the source file named like it is
    refused). So no two clips share a file or a split line.
    """
    refused: dict[int, str] = {}
    for index, task in enumerate(tasks):
        if (problem := _name_problem(task.name)) is not None:
            refused[index] = problem
    by_key: dict[str, list[int]] = {}
    for index, task in enumerate(tasks):
        if index not in refused:
            by_key.setdefault(_name_key(task.name), []).append(index)
    for indices in by_key.values():
        for index in indices if len(indices) > 1 else ():
            others = [tasks[other].path for other in indices if other != index]
            refused[index] = (
                f"clip name {tasks[index].name!r} collides with the clip of {others[0]}"
                f"{f' and {len(others) - 1} more' if len(others) > 1 else ''} "
                "(names must differ in more than case); rename one of the files"
            )
    mirrors = {_name_key(mirror_name(name)): name for name in (task.name for task in tasks)}
    for index, task in enumerate(tasks):
        original = mirrors.get(_name_key(task.name))
        if index not in refused and original is not None:
            refused[index] = (
                f"clip name {task.name!r} is the mirror name of clip {original!r} "
                f"({humanml3d.MIRROR_PREFIX} + name); rename the file"
            )
    kept = [task for index, task in enumerate(tasks) if index not in refused]
    refusals = [
        {"name": tasks[index].name, "path": tasks[index].path, "reason": reason}
        for index, reason in sorted(refused.items())
    ]
    return kept, refusals


def _read_options_record(out_dir: Path) -> dict | None:
    """The ``options`` recorded in ``out_dir/build_options.json`` (None when absent)."""
    path = out_dir / OPTIONS_FILE
    if not path.is_file():
        return None
    try:
        record = json.loads(path.read_text(encoding="utf-8"))
        return dict(record["options"])
    except (OSError, ValueError, KeyError, TypeError) as error:
        raise UsageError(
            f"{path} is unreadable ({type(error).__name__}); delete it and pass --force to "
            "rebuild every clip"
        ) from None


def claim_output(out_dir: Path, record: dict, names: Sequence[str], force: bool) -> None:
    """Make ``out_dir`` a folder of this build's options, or refuse (UsageError).

    A new or empty folder is claimed. A folder built with the same options is resumed; with
    ``force`` its clips ``names`` are marked unfinished (their ``texts/`` files, written last,
    are removed) so that every one is rebuilt, even if this run is killed half-way. A folder
    built with other options needs ``force``; a non-empty folder that no build wrote is refused.
    """
    recorded = _read_options_record(out_dir)
    ours = recorded is not None or (out_dir / humanml3d.REPORT_FILE).is_file()
    if not ours and out_dir.is_dir() and any(out_dir.iterdir()):
        raise UsageError(
            f"--out {out_dir} is not empty and holds no dataset built by this tool; "
            "choose a new or empty folder"
        )
    if ours and recorded != record and not force:
        changed = sorted(key for key in record if (recorded or {}).get(key) != record[key])
        what = f"other options ({', '.join(changed)})" if recorded else "unrecorded options"
        raise UsageError(
            f"{out_dir} was built with {what}; pass --force to rebuild every clip with these "
            "options, or choose another --out"
        )
    if ours and force:
        for name in names:
            for clip in (name, mirror_name(name)):
                humanml3d.texts_path(out_dir, clip).unlink(missing_ok=True)
    write_json_atomic(out_dir / OPTIONS_FILE, {"format": OPTIONS_FORMAT, "options": record})


@contextlib.contextmanager
def exclusive(out_dir: Path) -> Iterator[int]:
    """Hold a lock on ``out_dir`` (created) while one build writes into it; yields the lock's
    file descriptor (worker processes close their inherited copy, so that a killed build's
    workers never keep the folder locked). UsageError when another build holds it."""
    out_dir.mkdir(parents=True, exist_ok=True)
    descriptor = os.open(out_dir, os.O_RDONLY)
    try:
        try:
            fcntl.flock(descriptor, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise UsageError(f"another build is writing into {out_dir}; wait for it") from None
        yield descriptor
    finally:
        os.close(descriptor)
