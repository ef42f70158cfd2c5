"""Each edit mode as an :class:`t2m.edit.core.EditPlan`: what is kept, what is targeted.

All lengths are in frames of the models' dataset (``spec``), results are whole snippets and at
most ``spec.max_frames`` long (compose chains windows to go longer). Bad requests raise
UsageError with one line.
"""

from __future__ import annotations

import logging
import math
import re
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Literal, get_args

import numpy as np

from dataset_tools.command import UsageError
from dataset_tools.io import parse_json
from dataset_tools.spec import DatasetSpec
from t2m.edit.core import EditPlan
from t2m.edit.source import PreparedSource

logger = logging.getLogger(__name__)

Mode = Literal["continue", "inbetween", "body", "path", "keys", "compose"]
MODES: tuple[str, ...] = get_args(Mode)
Part = Literal["lower", "legs", "upper", "arms", "left_arm", "right_arm"]

# SMPL joint indices (dataset_tools.skeleton.SMPL_JOINT_NAMES).
_LEGS = (1, 2, 4, 5, 7, 8, 10, 11)
_LEFT_ARM = (13, 16, 18, 20)
_RIGHT_ARM = (14, 17, 19, 21)
BODY_PARTS: dict[str, tuple[int, ...]] = {
    "lower": (0, *_LEGS),
    "legs": _LEGS,
    "upper": (3, 6, 9, 12, 15, *_LEFT_ARM, *_RIGHT_ARM),
    "arms": (*_LEFT_ARM, *_RIGHT_ARM),
    "left_arm": _LEFT_ARM,
    "right_arm": _RIGHT_ARM,
}
"""Named groups of the 22-joint body. ``lower`` keeps the root's path and the legs; ``legs``
keeps the legs' pose relative to a regenerated root path; the others keep their joints relative
to the root (the pelvis), which keeps its source path only in ``lower``."""

MAX_ROOT_SPEED = 6.0
"""Metres per second between path points or kept poses beyond which the body cannot get there
in time (a sprint is about 10, the HumanML3D captures stay under 5)."""

MAX_SECONDS = 3600.0
"""The latest time any edit option, path point or timeline line may name (an hour): beyond it a
request is refused before any work (its frame counts would not fit in memory)."""

MAX_PATH_POINTS = 10_000
"""The most rows a path may hold."""

MAX_INPUT_BYTES = 64 * 2**20
"""The largest path or timeline file read."""


def check_seconds(seconds: float, what: str) -> float:
    """``seconds`` as a float from 0 to :data:`MAX_SECONDS`; UsageError (one line) otherwise."""
    if isinstance(seconds, bool) or not isinstance(seconds, (int, float, np.floating, np.integer)):
        raise UsageError(f"{what} must be a number of seconds, got {seconds!r}")
    try:
        value = float(seconds)
    except OverflowError:
        value = math.inf
    if not (math.isfinite(value) and 0 <= value <= MAX_SECONDS):
        shown = (
            f"{seconds:g}"
            if math.isfinite(value) or isinstance(seconds, float)
            else "a huge number"
        )
        raise UsageError(f"{what} must be from 0 to {MAX_SECONDS:g} seconds, got {shown}")
    return value


def _frames(seconds: float, spec: DatasetSpec, what: str) -> int:
    return int(round(check_seconds(seconds, what) * spec.fps))


def _read_text(file: Path, what: str) -> str:
    """A path or timeline file's text: UsageError (one line) when it is missing, unreadable, not
    UTF-8 or larger than :data:`MAX_INPUT_BYTES`."""
    try:
        if file.stat().st_size > MAX_INPUT_BYTES:
            raise UsageError(f"{what} {file} is larger than {MAX_INPUT_BYTES // 2**20} MiB")
        return file.read_text(encoding="utf-8-sig")
    except (OSError, UnicodeDecodeError) as error:
        raise UsageError(f"cannot read {what} {file}: {error}") from None


def _whole_snippets(frames: int, spec: DatasetSpec, what: str) -> int:
    """``frames`` rounded down to whole snippets, refused outside 1 snippet .. max_frames."""
    unit = spec.snippet_length
    rounded = frames // unit * unit
    if rounded < unit:
        raise UsageError(f"{what} is shorter than one snippet ({unit / spec.fps:.2f} s)")
    if rounded > spec.max_frames:
        raise UsageError(
            f"{what} is {rounded / spec.fps:.1f} s; one edit makes at most "
            f"{spec.max_frames / spec.fps:.1f} s (use --mode compose for longer motions)"
        )
    return rounded


def _round_up(frames: int, spec: DatasetSpec) -> int:
    """``frames`` rounded up to whole snippets."""
    unit = spec.snippet_length
    return -(-frames // unit) * unit


def _empty(frames: int, spec: DatasetSpec) -> tuple[np.ndarray, np.ndarray]:
    return (
        np.full((frames, spec.num_joints, 3), np.nan),
        np.zeros((frames, spec.num_joints), dtype=bool),
    )


def _on_timeline(values: np.ndarray, rows: np.ndarray, source_rows: np.ndarray, frames: int):
    out = np.full((frames,) + values.shape[1:], np.nan)
    out[rows] = values[source_rows]
    return out


def check_reachable(times: np.ndarray, points: np.ndarray, what: str) -> None:
    """UsageError when consecutive floor points (K, 2) at ``times`` (K,) seconds ask for more
    than :data:`MAX_ROOT_SPEED`."""
    if len(times) < 2:
        return
    with np.errstate(over="ignore", invalid="ignore"):  # 1e308 metres: an infinite speed
        gaps = np.diff(times)
        distances = np.linalg.norm(np.diff(points, axis=0), axis=-1)
        speeds = np.nan_to_num(distances / np.maximum(gaps, 1e-9), nan=np.inf, posinf=np.inf)
    worst = int(np.argmax(speeds))
    if speeds[worst] > MAX_ROOT_SPEED:
        raise UsageError(
            f"{what}: {distances[worst]:.2f} m in {gaps[worst]:.2f} s at {times[worst + 1]:.2f} s "
            f"needs {speeds[worst]:.1f} m/s; the body cannot get there in time "
            f"(at most {MAX_ROOT_SPEED:g} m/s)"
        )


def plan_continue(
    text: str, source: PreparedSource, spec: DatasetSpec, keep_seconds: float, seconds: float | None
) -> EditPlan:
    """Keep the first ``keep_seconds`` of the source; the result lasts ``seconds`` (default: as
    long as the source)."""
    kept = _frames(keep_seconds, spec, "--keep-seconds")
    if kept < 1:
        raise UsageError("--keep-seconds keeps nothing of the source (give more than one frame)")
    if kept > source.num_frames:
        raise UsageError(
            f"--keep-seconds {keep_seconds:g} is past the source's end "
            f"({source.num_frames / spec.fps:.2f} s)"
        )
    total = source.num_frames if seconds is None else _frames(seconds, spec, "--seconds")
    frames = _whole_snippets(
        min(total, spec.max_frames) if seconds is None else total, spec, "the result"
    )
    if kept >= frames:
        raise UsageError(
            f"--keep-seconds {keep_seconds:g} keeps the whole {frames / spec.fps:.2f} s result: "
            "nothing is left to generate (lengthen it with --seconds)"
        )
    rows = np.arange(kept)
    target, keep = _empty(frames, spec)
    target[rows] = source.joints[rows]
    keep[rows] = True
    return EditPlan(
        text,
        frames,
        target,
        keep,
        _on_timeline(source.features, rows, rows, frames),
        _on_timeline(source.half_yaw, rows, rows, frames),
    )


def plan_inbetween(
    text: str,
    source: PreparedSource,
    spec: DatasetSpec,
    keep_start: float,
    keep_end: float,
    seconds: float | None,
) -> EditPlan:
    """Keep the source's first ``keep_start`` and last ``keep_end`` seconds (one frame each for
    single key poses) at the result's start and end; generate the middle. The result lasts
    ``seconds`` (default: as long as the source)."""
    start = _frames(keep_start, spec, "--keep-start")
    end = _frames(keep_end, spec, "--keep-end")
    if start < 1 or end < 1:
        raise UsageError("inbetween keeps a start and an end: --keep-start and --keep-end > 0")
    if start + end > source.num_frames:
        raise UsageError(
            f"--keep-start {keep_start:g} + --keep-end {keep_end:g} s is more than the source "
            f"({source.num_frames / spec.fps:.2f} s)"
        )
    total = source.num_frames if seconds is None else _frames(seconds, spec, "--seconds")
    frames = _whole_snippets(total, spec, "the result")
    if start + end >= frames:
        raise UsageError(
            f"the kept {(start + end) / spec.fps:.2f} s fill the {frames / spec.fps:.2f} s "
            "result: nothing is left to generate (lengthen it with --seconds)"
        )
    head = np.arange(start)
    tail_rows = np.arange(frames - end, frames)
    tail_source = np.arange(source.num_frames - end, source.num_frames)
    rows = np.concatenate([head, tail_rows])
    source_rows = np.concatenate([head, tail_source])
    target, keep = _empty(frames, spec)
    target[rows] = source.joints[source_rows]
    keep[rows] = True
    gap = (frames - end - (start - 1)) / spec.fps
    check_reachable(
        np.array([0.0, gap]),
        source.joints[[start - 1, source.num_frames - end], 0][:, [0, 2]],
        "inbetween",
    )
    return EditPlan(
        text,
        frames,
        target,
        keep,
        _on_timeline(source.features, rows, source_rows, frames),
        _on_timeline(source.half_yaw, rows, source_rows, frames),
    )


def plan_body(text: str, source: PreparedSource, spec: DatasetSpec, part: str) -> EditPlan:
    """Keep the joints of ``part`` (:data:`BODY_PARTS`) on every frame; regenerate the rest.

    Targets, which the search judges its candidates by (and ``--method optimize`` optimises
    towards): ``lower``, which keeps the root path, the source's positions of its joints; the
    other parts hang from a regenerated body that the finishing fits them to (they keep their
    pose and follow that body, its floor position and facing the new motion's), so their
    targets are the source's heights of their joints: where the part ends up depends on how
    the body under it is made."""
    if spec.num_joints != 22:
        raise UsageError("body edits name SMPL joints: they need a 22-joint (HumanML3D) model")
    if part not in BODY_PARTS:
        raise UsageError(f"unknown --part {part!r}; choose one of {', '.join(BODY_PARTS)}")
    frames = source.num_frames
    if frames > spec.max_frames:
        logger.warning(
            "the source is %.1f s; body edits keep its first %.1f s",
            frames / spec.fps,
            spec.max_frames / spec.fps,
        )
        frames = spec.max_frames
    frames = _whole_snippets(frames, spec, "the source")
    joints = list(BODY_PARTS[part])
    target, keep = _empty(frames, spec)
    keep[:, joints] = True
    if 0 in joints:  # absolute positions are targets only where the root path is kept
        target[:, joints] = source.joints[:frames, joints]
    else:  # heights, which neither the floor path nor the facing changes
        target[:, joints, 1] = source.joints[:frames, joints, 1]
    rows = np.arange(frames)
    return EditPlan(
        text,
        frames,
        target,
        keep,
        _on_timeline(source.features, rows, rows, frames),
        _on_timeline(source.half_yaw, rows, rows, frames),
    )


def read_path(path: str | Path | np.ndarray | Sequence) -> np.ndarray:
    """Path points (K, 3) rows ``seconds, x, z`` (floor coordinates in metres, the model's frame:
    the motion starts at the origin facing +Z) from an array, a CSV file (optional header line)
    or a JSON file (a list of ``[seconds, x, z]`` or of ``{"t": .., "x": .., "z": ..}``)."""
    name = "the path"
    if isinstance(path, (str, Path)):
        file = Path(path)
        name = f"--path {file}"
        text = _read_text(file, "--path")
        try:
            if file.suffix.lower() == ".json":
                data = parse_json(text, f"--path {file}")
                data = data.get("points", data) if isinstance(data, dict) else data
                rows = [[p["t"], p["x"], p["z"]] if isinstance(p, dict) else p for p in data]
            else:
                lines = [ln for ln in text.splitlines() if ln.strip()]
                if len(lines) > MAX_PATH_POINTS + 1:
                    raise UsageError(
                        f"--path {file} has {len(lines)} rows; at most {MAX_PATH_POINTS}"
                    )
                rows = [[float(v) for v in re.split(r"[,;\s]+", ln.strip())] for ln in lines[1:]]
                try:
                    rows.insert(0, [float(v) for v in re.split(r"[,;\s]+", lines[0].strip())])
                except (ValueError, IndexError):  # a header ("t,x,z"), not a row like "1e-2,0,0"
                    pass
            if len(rows) > MAX_PATH_POINTS:
                raise UsageError(f"--path {file} has {len(rows)} rows; at most {MAX_PATH_POINTS}")
            points = np.asarray(rows, dtype=np.float64)
        except UsageError:
            raise
        except (ValueError, KeyError, TypeError, OverflowError, AttributeError):
            raise UsageError(f"--path {file}: give rows 'seconds,x,z'") from None
    else:
        try:
            points = np.asarray(path, dtype=np.float64)
        except (ValueError, TypeError, OverflowError):
            raise UsageError("a path is rows of (seconds, x, z) numbers") from None
    if points.ndim != 2 or points.shape[1] != 3 or len(points) == 0:
        raise UsageError(f"{name}: give rows of (seconds, x, z), got shape {points.shape}")
    if len(points) > MAX_PATH_POINTS:
        raise UsageError(f"{name} has {len(points)} rows; at most {MAX_PATH_POINTS}")
    if not np.all(np.isfinite(points)):
        raise UsageError(f"{name} contains NaN or infinite values")
    if np.any(np.diff(points[:, 0]) <= 0) or points[0, 0] < 0:
        raise UsageError(f"{name}: times must be >= 0 and increasing")
    if points[-1, 0] > MAX_SECONDS:
        raise UsageError(f"{name}: times must be at most {MAX_SECONDS:g} s, got {points[-1, 0]:g}")
    return points


def plan_path(text: str, points: np.ndarray, spec: DatasetSpec, seconds: float | None) -> EditPlan:
    """The root passes through the floor points (``seconds, x, z`` rows) at their times; the
    result lasts ``seconds`` (default: up to the last point)."""
    last = float(points[-1, 0])
    total = _frames(seconds if seconds is not None else last, spec, "--seconds")
    last_frame = int(round(last * spec.fps))
    frames = _whole_snippets(_round_up(max(total, last_frame + 1), spec), spec, "the path")
    times = np.concatenate([[0.0], points[:, 0]])
    floor = np.concatenate([[[0.0, 0.0]], points[:, 1:]])
    check_reachable(times, floor, "--path")
    target, keep = _empty(frames, spec)
    for t, x, z in points:
        row = min(int(round(t * spec.fps)), frames - 1)
        target[row, 0, 0], target[row, 0, 2] = x, z
    if np.isfinite(target[0, 0]).any() and np.abs(np.nan_to_num(target[0, 0])).max() > 1e-6:
        raise UsageError("the path's point at 0 s must be (0, 0): every motion starts there")
    return EditPlan(text, frames, target, keep)


def plan_keys(text: str, keys: np.ndarray, spec: DatasetSpec, name: str = "--keys") -> EditPlan:
    """Joint targets (T, J, 3), NaN where free, in the model's frame; the root's floor position
    is met exactly, other targets as closely as the search gets. ``name`` names them in messages
    (``--keys FILE`` when read from one)."""
    keys = np.asarray(keys, dtype=np.float64)
    if keys.ndim != 3 or keys.shape[1:] != (spec.num_joints, 3):
        raise UsageError(
            f"{name} must be (T, {spec.num_joints}, 3) with NaN for free, got {keys.shape}"
        )
    finite = np.isfinite(keys)
    if not finite.any():
        raise UsageError(f"{name} constrains nothing (all NaN)")
    if np.isinf(keys).any():
        raise UsageError(f"{name} contains infinite values (use NaN for free)")
    frames = _whole_snippets(_round_up(len(keys), spec), spec, name)
    target, keep = _empty(frames, spec)
    target[: len(keys)] = keys
    rows = np.flatnonzero(np.isfinite(target[:, 0, [0, 2]]).all(-1))
    if len(rows):
        check_reachable(
            np.concatenate([[0.0], rows / spec.fps]),
            np.concatenate([[[0.0, 0.0]], target[rows, 0][:, [0, 2]]]),
            name,
        )
    return EditPlan(text, frames, target, keep)


@dataclass(frozen=True)
class Segment:
    """One timeline entry: its prompt and its frames on the result's timeline."""

    text: str
    start: int
    stop: int


def read_timeline(
    lines: str | Path | Sequence[str],
    spec: DatasetSpec,
    max_lines: int | None = None,
    max_seconds: float | None = None,
    start: int = 0,
) -> list[Segment]:
    """Timeline lines ``text#start#end`` (seconds) or ``text#seconds`` (starting where the
    previous one ends), or a file of them; blank lines skipped. Segments must follow each other
    without gaps or overlaps (within half a frame) from ``start`` (frames: 0, or the end of a
    kept source the timeline follows); boundaries are rounded to whole snippets from there.
    ``max_lines`` / ``max_seconds``: the most segments and the longest timeline (after
    ``start``) accepted (None: :data:`MAX_SECONDS` only); the message names the command's
    options that raise them (``--max-timeline-lines``, ``--max-timeline-seconds``)."""
    whole, line_name = "the timeline", "timeline line"  # how messages name it
    if isinstance(lines, Path) or (
        isinstance(lines, str) and "\n" not in lines and "#" not in lines
    ):
        whole = f"--timeline {lines}"
        line_name = f"{whole} line"
        lines = _read_text(Path(lines), "--timeline").splitlines()
    elif isinstance(lines, str):
        lines = lines.splitlines()
    if max_lines is not None:
        count = sum(1 for line in lines if line.strip())
        if count > max_lines:
            raise UsageError(
                f"{whole} has {count} lines, more than the {max_lines} allowed "
                "(--max-timeline-lines raises the limit)"
            )
    entries: list[tuple[str, float, float]] = []
    origin = start / spec.fps
    cursor = origin
    for number, line in enumerate(lines, start=1):
        if not line.strip():
            continue
        parts = [p.strip() for p in line.split("#")]
        try:
            if len(parts) == 3:
                text, begin, end = parts[0], float(parts[1]), float(parts[2])
            elif len(parts) == 2:
                text, begin = parts[0], cursor
                end = begin + float(parts[1])
            else:
                raise ValueError
        except ValueError:
            raise UsageError(
                f"{line_name} {number}: give 'text#start#end' or 'text#seconds'"
            ) from None
        if not text or not (math.isfinite(begin) and math.isfinite(end)) or end <= begin:
            raise UsageError(f"{line_name} {number}: an empty prompt or end <= start")
        if end > MAX_SECONDS:
            raise UsageError(
                f"{line_name} {number}: ends at {end:g} s; a timeline ends by {MAX_SECONDS:g} s"
            )
        half = 0.5 / spec.fps
        if abs(begin - cursor) > half:
            if not entries and origin:
                raise UsageError(
                    f"{line_name} {number}: starts at {begin:g} s; the timeline follows the "
                    f"kept source, which ends at {origin:.2f} s (start the first line there, "
                    "or give lines 'text#seconds')"
                )
            kind = "a gap" if begin > cursor else "an overlap"
            raise UsageError(
                f"{line_name} {number}: starts at {begin:g} s, the previous ends at "
                f"{cursor:g} s ({kind}); segments must follow each other"
            )
        if max_seconds is not None and end - origin > max_seconds:
            after = f" ({end - origin:g} s after the kept source)" if origin else ""
            raise UsageError(
                f"{line_name} {number}: ends at {end:g} s{after}, past the {max_seconds:g} s "
                "allowed (--max-timeline-seconds raises the limit)"
            )
        entries.append((text, begin, end))
        cursor = end
    if not entries:
        raise UsageError(f"{whole} holds no segment")
    unit = spec.snippet_length
    segments = []
    for number, (text, begin, end) in enumerate(entries, start=1):
        first = start + int(round((begin - origin) * spec.fps / unit)) * unit
        last = start + int(round((end - origin) * spec.fps / unit)) * unit
        if last <= first:
            raise UsageError(f"{whole}: segment {number} is shorter than one snippet")
        segments.append(Segment(text, first, last))
    return segments


@dataclass(frozen=True)
class ComposePlan:
    """A compose request: the segments (frames on the result's timeline) and the features
    (K, D) of the kept stretch of a source that starts the result (None: the result starts
    from nothing); the segments then begin at frame K."""

    segments: list[Segment]
    start: np.ndarray | None = None

    @property
    def num_frames(self) -> int:
        return self.segments[-1].stop


def plan_compose(
    timeline: str | Path | Sequence[str],
    spec: DatasetSpec,
    source: PreparedSource | None = None,
    keep_last: float | None = None,
    max_lines: int | None = None,
    max_seconds: float | None = None,
) -> ComposePlan:
    """The timeline's segments, after the source's last ``keep_last`` seconds (None: the whole
    source) when there is a source: those frames are kept exactly (the dataset's features, as
    in the source; the stretch's first frame at the origin facing +Z) and the timeline's lines
    begin where they end (its first line must start there; ``text#seconds`` lines do)."""
    if source is None:
        return ComposePlan(read_timeline(timeline, spec, max_lines, max_seconds))
    kept = source.num_frames
    if keep_last is not None:
        kept = _frames(keep_last, spec, "--keep-last")
        if kept > source.num_frames:
            raise UsageError(
                f"--keep-last {keep_last:g} is more than the source "
                f"({source.num_frames / spec.fps:.2f} s)"
            )
    if kept < spec.snippet_length:
        raise UsageError(
            f"compose keeps {kept / spec.fps:.2f} s of the source: at least one snippet "
            f"({spec.snippet_length / spec.fps:.2f} s) is needed to continue from"
        )
    segments = read_timeline(timeline, spec, max_lines, max_seconds, start=kept)
    return ComposePlan(segments, source.features[source.num_frames - kept :])
