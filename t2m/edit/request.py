"""One edit request, declared once: :class:`EditRequest`.

Its typed fields are the whole schema. ``python -m t2m.edit`` makes its options from them
(:func:`dataset_tools.command.add_config_options`), ``--batch`` reads each JSON object with
:func:`dataset_tools.command.fields_from_dict` (file names relative to the batch file), and the
web app's ``POST /api/edit`` reads the same fields with the same reader (uploads and its size and
count limits on top, file names refused: :mod:`t2m.serve.editing`); both say a refusal in their
JSON keys (:func:`json_terms`). Python callers build it directly; a file field also takes an
array (``source``, ``keys``: (T, J, 3); ``path``: (K, 3)).
"""

from __future__ import annotations

import dataclasses
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from dataset_tools.command import UsageError, json_key, option
from t2m.edit.core import EditPlan
from t2m.edit.modes import (
    BODY_PARTS,
    MODES,
    ComposePlan,
    Mode,
    Part,
    check_seconds,
    plan_body,
    plan_compose,
    plan_continue,
    plan_inbetween,
    plan_keys,
    plan_path,
    read_path,
)
from t2m.edit.source import PreparedSource, load_source, prepare_source

NEEDS_SOURCE = ("continue", "inbetween", "body")
"""The modes that edit a source motion (the others make a new one)."""
TAKES_SOURCE = (*NEEDS_SOURCE, "compose")
"""The modes that take a source motion: compose may start from one."""

MAX_SOURCE_FPS = 1000.0
"""The highest ``source_fps`` taken (motion capture runs at up to a few hundred)."""


@dataclass(frozen=True)
class EditRequest:
    """One edit (see :mod:`t2m.edit` for the modes); seconds throughout."""

    mode: Mode = field(metadata=option(metavar="MODE"))
    """continue | inbetween | body | path | keys | compose (or --batch)"""
    text: str = ""
    """what the generated part does, e.g. "a person waves both hands" (not for compose)"""
    source: Path | np.ndarray | None = field(default=None, metadata=option(metavar="FILE"))
    """the motion to edit (compose: to start from): joints .npy (T, 22, 3) (a sampleNN_repRR.npy
    too) or .bvh"""
    seconds: float | None = field(default=None, metadata=option(metavar="S"))
    """length of the result (default: the source's, or up to the last path point)"""
    keep_seconds: float = field(default=2.0, metadata=option(metavar="S"))
    """continue: seconds of the source's start that are kept"""
    keep_start: float = field(default=1.0, metadata=option(metavar="S"))
    """inbetween: seconds of the source's start kept at the result's start (0.05: one pose)"""
    keep_end: float = field(default=1.0, metadata=option(metavar="S"))
    """inbetween: seconds of the source's end kept at the result's end"""
    keep_last: float | None = field(default=None, metadata=option(metavar="S"))
    """compose with a source: seconds of the source's end that start the result (default: the
    whole source)"""
    part: Part = "lower"
    """body: the part kept from the source (lower keeps the root path and the legs)"""
    path: Path | np.ndarray | None = field(default=None, metadata=option(metavar="FILE"))
    """path: CSV or JSON of floor points 'seconds,x,z' (metres; start at 0,0 facing +z)"""
    keys: Path | np.ndarray | None = field(default=None, metadata=option(metavar="NPY"))
    """keys: joint targets (T, 22, 3), NaN where free"""
    timeline: tuple[str, ...] | Path | None = field(default=None, metadata=option(metavar="LINE"))
    """compose: lines 'text#start#end' (seconds) or 'text#seconds', or one file of them"""
    mapping: str | None = field(default=None, metadata=option(metavar="NAME|FILE"))
    """BVH joint mapping (bandai, cmu_cc, smpl or a JSON file; default: detected)"""
    source_fps: float | None = field(default=None, metadata=option(metavar="F"))
    """frame rate of a .npy source (default: the model's, 20)"""

    def __post_init__(self) -> None:
        if self.mode not in MODES:
            raise UsageError(f"unknown mode {self.mode!r}; choose one of {', '.join(MODES)}")
        self._check_inputs()
        self._check_numbers()
        if self.mode == "body" and self.part not in BODY_PARTS:
            raise UsageError(f"unknown --part {self.part!r}; choose one of {', '.join(BODY_PARTS)}")

    def _check_inputs(self) -> None:
        """Each mode's inputs are there, and no source where a mode makes a new motion."""
        if self.mode in NEEDS_SOURCE and self.source is None:
            raise UsageError(f"--mode {self.mode} needs a --source motion")
        if self.mode not in TAKES_SOURCE and self.source is not None:
            raise UsageError(f"--mode {self.mode} takes no --source")
        if self.keep_last is not None and (self.mode != "compose" or self.source is None):
            raise UsageError("--keep-last is for --mode compose with a --source")
        if self.mode == "compose":
            if self.timeline is None:
                raise UsageError("--mode compose needs a --timeline")
        elif not self.text or not self.text.strip():
            raise UsageError("empty --text: give a sentence describing the motion")
        if self.mode == "path" and self.path is None:
            raise UsageError("--mode path needs --path (rows 'seconds,x,z')")
        if self.mode == "keys" and self.keys is None:
            raise UsageError("--mode keys needs --keys (a (T, 22, 3) .npy with NaN for free)")

    def _check_numbers(self) -> None:
        """Every time from 0 to :data:`t2m.edit.modes.MAX_SECONDS`, the frame rate above 0 (a source at 0 fps
        is not one at the model's rate) and at most :data:`MAX_SOURCE_FPS`."""
        for name in ("seconds", "keep_seconds", "keep_start", "keep_end", "keep_last"):
            value = getattr(self, name)
            if value is not None:
                check_seconds(value, "--" + name.replace("_", "-"))
        fps = self.source_fps
        if fps is not None and not (
            isinstance(fps, (int, float))
            and 0 < fps <= MAX_SOURCE_FPS
            and not isinstance(fps, bool)
        ):
            raise UsageError(
                f"--source-fps must be above 0 and at most {MAX_SOURCE_FPS:g} frames per second, "
                f"got {fps!r} (leave it out for the model's rate)"
            )

    def prepared_source(self, spec) -> PreparedSource:
        joints, name = self.source, "the source"
        if isinstance(joints, (str, Path)):
            joints, name = (
                load_source(joints, spec, self.mapping, self.source_fps),
                f"--source {joints}",
            )
        return prepare_source(np.asarray(joints), spec, name)

    def plan(self, spec) -> EditPlan:
        """This request as a plan (not for compose, which chains several)."""
        mode = self.mode
        if mode == "continue":
            source = self.prepared_source(spec)
            return plan_continue(self.text, source, spec, self.keep_seconds, self.seconds)
        if mode == "inbetween":
            source = self.prepared_source(spec)
            return plan_inbetween(
                self.text, source, spec, self.keep_start, self.keep_end, self.seconds
            )
        if mode == "body":
            return plan_body(self.text, self.prepared_source(spec), spec, self.part)
        if mode == "path":
            return plan_path(self.text, read_path(self.path), spec, self.seconds)
        if mode == "keys":
            keys, name = self.keys, "--keys"
            if isinstance(keys, (str, Path)):
                from dataset_tools.io import load_npy

                keys, name = load_npy(keys, finite=False), f"--keys {keys}"
            return plan_keys(self.text, keys, spec, name)
        raise ValueError(f"{mode} has no single plan")

    def compose_plan(
        self, spec, max_lines: int | None = None, max_seconds: float | None = None
    ) -> ComposePlan:
        """A compose request's timeline, after the kept stretch of its source when it has one
        (:func:`t2m.edit.modes.plan_compose`); ``max_lines`` / ``max_seconds`` as for
        :func:`t2m.edit.modes.read_timeline`."""
        if self.mode != "compose":
            raise ValueError(f"{self.mode} is not compose")
        source = None if self.source is None else self.prepared_source(spec)
        return plan_compose(self.timeline, spec, source, self.keep_last, max_lines, max_seconds)


_FLAG = re.compile(r"(?<![\w-])--[a-z][a-z0-9-]*")


def json_terms(message: str) -> str:
    """A message about an :class:`EditRequest` in the words of its JSON readers (``--batch``,
    the web): each command-line option of a request field (``--keep-seconds``) becomes the field's
    JSON key (``keep_seconds``); the command's own options (``--max-timeline-lines``) stay."""
    keys = {"--" + f.name.replace("_", "-"): json_key(f) for f in dataclasses.fields(EditRequest)}
    return _FLAG.sub(lambda match: keys.get(match[0], match[0]), message)
