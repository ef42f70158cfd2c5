"""Prompt lines: ``text`` or ``text#frames``, typed in a command, a file or the web app.

A prompt line's optional ``#frames`` suffix fixes that prompt's length in frames; without it the
length comes from the request (``--length`` / ``--seconds``, the web's ``seconds``) or is drawn by
the text2length model. Errors are one-line :class:`dataset_tools.command.UsageError`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from dataset_tools.command import UsageError

if TYPE_CHECKING:
    from dataset_tools.spec import DatasetSpec


@dataclass(frozen=True)
class Prompt:
    """One prompt and its requested length in frames (None: sample it)."""

    text: str
    frames: int | None = None


def parse_prompt_line(line: str, where: str) -> Prompt:
    """One prompt line, ``text`` or ``text#frames``; ``where`` starts the one-line UsageError."""
    text, sep, suffix = line.rpartition("#")
    if not sep:
        return Prompt(line.strip())
    try:
        frames = int(suffix.strip())
    except ValueError:
        raise UsageError(
            f"{where}: after '#' give a length in frames, got {suffix.strip()!r}"
        ) from None
    if not text.strip():
        raise UsageError(f"{where}: empty prompt before '#{suffix.strip()}'")
    return Prompt(text.strip(), frames)


def read_prompt_file(path: str | Path) -> list[Prompt]:
    """Prompts, one a line; ``text#frames`` fixes that prompt's length. Blank lines are skipped."""
    path = Path(path)
    try:
        lines = path.read_text(encoding="utf-8-sig").splitlines()  # a BOM is no prompt
    except OSError as error:
        raise UsageError(f"cannot read --text-file {path}: {error.strerror or error}") from None
    except UnicodeDecodeError:
        raise UsageError(f"--text-file {path} is not UTF-8 text") from None
    prompts = [
        parse_prompt_line(line, f"{path.name}:{number}")
        for number, line in enumerate(lines, start=1)
        if line.strip()
    ]
    if not prompts:
        raise UsageError(f"--text-file {path} holds no prompt")
    return prompts


def with_lengths(
    prompts: Sequence[Prompt],
    spec: DatasetSpec,
    length: int | None = None,
    seconds: float | None = None,
) -> list[Prompt]:
    """``prompts`` with their lengths in frames of ``spec``: a prompt's own ``#frames``, else
    ``length`` frames, else ``seconds``, else None (drawn by the text2length model). Every
    length is rounded and clamped as :func:`t2m.pipeline.frames_for` does."""
    from t2m.pipeline import frames_for, frames_for_seconds

    try:
        if length is not None:
            default_frames = frames_for(length, spec)
        elif seconds is not None:
            default_frames = frames_for_seconds(seconds, spec)
        else:
            default_frames = None
        return [
            Prompt(p.text, default_frames if p.frames is None else frames_for(p.frames, spec))
            for p in prompts
        ]
    except ValueError as error:  # frames_for refuses a non-positive length: the user's
        raise UsageError(str(error)) from None
