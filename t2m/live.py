"""Live generation: a figure that keeps moving and takes new prompts while it moves.

    pipe = TextToMotion.from_checkpoints("checkpoints/demo")
    stream = pipe.stream("a person walks forward", seed=0)      # == LiveStream(pipe, ...)
    for snippet in stream:                 # without end; 4 frames (0.2 s at 20 fps) at a time
        draw(snippet.joints)               # (4, 22, 3) world joints, metres, y-up
        if user_typed:
            stream.prompt("a person waves")  # takes over at the next snippet boundary

How it runs. The stream is a chain of *segments*. A segment is what the ``continue`` edit makes
(:mod:`t2m.edit`: the same plan as ``compose`` chains, :func:`t2m.edit.core.generate_plans`):
the last :data:`CONTEXT_SECONDS` made are read by the movement encoder and the temporal VAE's
posterior under the segment's prompt (the state the model would be in had it made them), the
rest is drawn from the prior snippet by snippet, and the hard keep eases the seam onto the frames
already shown. Its length comes from the text2length model unless the prompt fixes it; when a
segment ends and no new prompt came, the same prompt goes on with a new segment (a walk keeps
walking). A new prompt cuts the running segment at a snippet boundary and starts its own from
there. ``"stop"``, ``"stand still"`` and the like (:data:`SETTLE_COMMANDS`) become
:data:`SETTLE_TEXT`, which the model knows: the figure settles and stays. A prompt that names a
count ("jumps twice", "jumps twice, then waves") is done once: its first segment lasts what
the count needs (:meth:`t2m.pipeline.TextToMotion.count_parts`; the rest of a fixed length is
standing still), and the segments after it, until a new prompt, are :data:`SETTLE_TEXT`.

The recurrent state never runs longer than one segment: every segment starts from what was
*shown* (features, read afresh), not from a state carried for minutes, so nothing accumulates;
the world position and heading are integrated in float64 from the features' root velocities.

Finishing (:meth:`t2m.pipeline.TextToMotion.finish`: the foot clean-up and whatever else the
pipeline applies to a whole motion) runs per snippet on a window of the last
:data:`FINISH_LOOKBACK_FRAMES` frames plus the snippet (only frames already made: causal), and the
snippet's rows are kept. The chain continues from each segment's result as
:func:`t2m.edit.core.generate_plans` gives it (hard keep, seam smoothing, rigid fit, the foot
clean-up with the kept context held and knees bent behind the leg turned to the front:
:func:`t2m.edit.keep.finish_plan`), so what the model reads
next is a finished motion, not its raw output.

Reproducible: the stream is a function of its seed and its prompts' boundary frames (and fixed
lengths): segment n draws its length and latent noise from a generator seeded by (seed, n), and
every segment is made whole when it starts, so how far ahead a consumer pulled does not matter.
A consumer that pulled ahead (a web page buffering frames) may give a prompt at an earlier frame
than the last it pulled (``at=``, at most :data:`MAX_REWIND_SECONDS` back): the frames from the
boundary on are dropped and made again, exactly as a replay of the same prompts gives them
(:func:`replay`). :meth:`LiveStream.timeline` writes the prompts with their times as the lines of
a ``compose`` timeline (``text#start#end``); :func:`replay` reads them back.
"""

from __future__ import annotations

import logging
import math
import re
import threading
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from dataset_tools.command import UsageError
from dataset_tools.representation import recover_from_ric, recover_root
from dataset_tools.rotations import qinv, qrot
from t2m.clauses import SETTLE_TEXT
from t2m.edit import COMPOSE_CONTEXT_SECONDS, _continuation
from t2m.edit.core import EditPlan, SearchSettings, generate_plans
from t2m.edit.modes import read_timeline

logger = logging.getLogger(__name__)
_quiet = threading.local()  # set while a stream runs the edit search: its per-search log lines


class _QuietSearch(logging.Filter):
    """Drops the edit search's INFO lines logged for a stream's segments (one every few seconds
    per stream); an edit's own, on any other thread or call, pass."""

    def filter(self, record: logging.LogRecord) -> bool:
        return record.levelno > logging.INFO or not getattr(_quiet, "on", False)


logging.getLogger("t2m.edit.core").addFilter(_QuietSearch())

CONTEXT_SECONDS = COMPOSE_CONTEXT_SECONDS
"""Each segment continues from this much of what was made before it (as ``compose`` does)."""
FINISH_LOOKBACK_FRAMES = 32
"""Frames before a snippet that its finishing window includes (a foot's contact run and its
lock see this far back)."""
MAX_REWIND_SECONDS = 5.0
"""How far before the last pulled frame a prompt may take over (a consumer's read-ahead)."""
SETTLE_COMMANDS = frozenset(
    {"stop", "halt", "freeze", "rest", "idle", "stand", "stand still", "stay still", "be still"}
)
"""Prompts (lower case, punctuation dropped) that mean "come to rest"."""
MAX_PROMPT_CHARS = 500
"""The longest prompt a stream takes."""
UNSIZED_SECONDS = 4.0
"""A segment's length when no text2length model is loaded and the prompt fixes none."""


def settle_text(text: str) -> str:
    """``text``, or :data:`SETTLE_TEXT` when it is a settle command ("Stop!", "stand still")."""
    words = " ".join(re.sub(r"[^a-z ]+", " ", text.lower()).split())
    return SETTLE_TEXT if words in SETTLE_COMMANDS else text


@dataclass(frozen=True)
class LivePrompt:
    """A prompt of a stream: the text it generates (``typed`` as given), the frame it took over
    at (a snippet boundary) and its fixed segment length in frames (None: drawn)."""

    text: str
    start: int
    frames: int | None = None
    typed: str = ""


@dataclass(frozen=True)
class Snippet:
    """One snippet of a stream.

    Attributes:
        start: the stream frame of its first row; below the end of what was pulled before when a
            prompt took over earlier (its rows replace those frames).
        joints: (F, J, 3) float32 world joints (metres, y-up), finished.
        features: (F, D) float32 finished features of those frames (root velocities in each
            frame's facing frame, as the representation stores them).
        prompt: index of its prompt in :attr:`LiveStream.prompts`.
        text: that prompt's text.
    """

    start: int
    joints: np.ndarray
    features: np.ndarray
    prompt: int
    text: str

    @property
    def stop(self) -> int:
        return self.start + len(self.joints)


@dataclass
class _Segment:
    index: int  # n: seeds its draws
    prompt: int
    start: int  # stream frame of its first new frame
    raw: np.ndarray  # (frames, D) its new raw features (hard-kept onto what came before)
    rest: int = 0  # frames its prompt's fixed length left to settle in (a counted prompt)


@dataclass
class _History:
    """What the stream made, snippet by snippet (lists of (4, .) arrays). The joints are kept
    for the downloads (:meth:`LiveStream.trim` bounds them); the model's features, the finished
    ones and the world root only as far back as a rewind and the next segment read."""

    raw: list[np.ndarray] = field(default_factory=list)  # model features, unfinished
    features: list[np.ndarray] = field(default_factory=list)  # finished
    root: list[np.ndarray] = field(default_factory=list)  # (4, 3) world half-yaw, x, z
    joints: list[np.ndarray] = field(default_factory=list)  # finished, world
    work_from: int = 0  # the snippet index of raw[0], features[0], root[0]
    joints_from: int = 0  # the snippet index of joints[0]

    def truncate(self, snippet: int) -> None:
        """Forget snippet ``snippet`` (an index from the stream's start) and all after it."""
        for rows in (self.raw, self.features, self.root):
            del rows[snippet - self.work_from :]
        del self.joints[snippet - self.joints_from :]

    def forget(self, keep_joints: int, keep_work: int) -> None:
        """Keep only the last ``keep_joints`` snippets of joints and ``keep_work`` of the rest."""
        drop = max(len(self.joints) - keep_joints, 0)
        del self.joints[:drop]
        self.joints_from += drop
        drop = max(len(self.raw) - keep_work, 0)
        for rows in (self.raw, self.features, self.root):
            del rows[:drop]
        self.work_from += drop


def segment_seed(seed: int, index: int) -> int:
    """The seed of segment ``index``'s generator (its length draw, then its latent draws)."""
    return int(np.random.SeedSequence([seed & 0xFFFFFFFF, index]).generate_state(1)[0])


class LiveStream:
    """A stream of snippets from a running state that takes new prompts at snippet boundaries.

    Args:
        pipe: a :class:`t2m.pipeline.TextToMotion` (its movement encoder reads each segment's
            context; without one segments start from the prompt alone, seams still eased).
        text: the first prompt.
        seed: seeds every draw (:func:`segment_seed`).
        seconds: the first prompt's segment length (None: the text2length model's draw).
        finish: finish each snippet (:meth:`~t2m.pipeline.TextToMotion.finish`); False: the
            model's raw output.
        clean: the finishing's foot-contact clean-up.
        settings: the search of each segment (default: one draw, read by the posterior, no
            optimisation: what a ``continue`` edit without targets past the seam runs).
        context_seconds: how much of what was made each segment continues from.

    Iterate for :class:`Snippet` s (without end), or call :meth:`next_snippet`. Not thread-safe:
    a server holds one lock per stream.
    """

    def __init__(
        self,
        pipe,
        text: str,
        seed: int = 0,
        *,
        seconds: float | None = None,
        finish: bool = True,
        clean: bool = True,
        settings: SearchSettings | None = None,
        context_seconds: float = CONTEXT_SECONDS,
    ) -> None:
        self.pipe = pipe
        self.spec = pipe.spec
        self.seed = int(seed)
        self.finish, self.clean = finish, clean
        self.settings = settings or SearchSettings(method="posterior", candidates=1)
        unit = self.spec.snippet_length
        if not (0 <= context_seconds < math.inf):
            raise ValueError(f"context_seconds must be >= 0, got {context_seconds}")
        self.context_frames = int(round(context_seconds * self.spec.fps)) // unit * unit
        self.prompts: list[LivePrompt] = []
        self._pending: list[LivePrompt] = []  # given, not yet started (start > frame)
        self._segments: list[_Segment] = []
        self._history = _History()
        self.frame = 0  # frames pulled so far
        self._prepared: dict = {}  # text -> its prepare(): tagged once
        self.prompt(text, at=0, seconds=seconds)

    # -- prompts -------------------------------------------------------------------------------

    def boundary(self, at: int | None = None) -> int:
        """The snippet boundary a prompt given at frame ``at`` (default: the frames pulled so
        far) takes over at: the first at or after it."""
        unit = self.spec.snippet_length
        at = self.frame if at is None else int(at)
        return -(-at // unit) * unit

    def prompt(self, text: str, at: int | None = None, seconds: float | None = None) -> int:
        """Take ``text`` over at the first snippet boundary at or after frame ``at`` (default:
        the frames pulled so far; earlier than that by at most :data:`MAX_REWIND_SECONDS`,
        which drops what was pulled from there; later: queued). ``seconds`` fixes its segments'
        length (None: drawn by the text2length model; without one, :data:`UNSIZED_SECONDS`).
        Returns the boundary frame.

        Raises UsageError (one line; the stream goes on unchanged) for an empty or too long
        prompt, one with no word the model knows, or a boundary too far back."""
        typed = text
        if not isinstance(text, str) or not text.strip():
            raise UsageError("type a prompt (it is empty)")
        if len(text) > MAX_PROMPT_CHARS:
            raise UsageError(f"the prompt has {len(text)} characters; at most {MAX_PROMPT_CHARS}")
        text = settle_text(" ".join(text.split()))
        self._prepare(text)  # no known word: UsageError now, not at its boundary
        frames = None
        if seconds is None and self.pipe.length_model is None:
            seconds = UNSIZED_SECONDS
        if seconds is not None:
            try:
                frames = self.pipe._clamp(float(seconds) * self.spec.fps)
            except (TypeError, ValueError) as error:
                raise UsageError(f"segment length: {error}") from None
            self.pipe.warn_short_counts(self._prepare(text), [frames])
        start = self.boundary(at)
        earliest = self.frame - int(MAX_REWIND_SECONDS * self.spec.fps)
        if start < max(earliest, 0):
            raise UsageError(
                f"a prompt can take over at most {MAX_REWIND_SECONDS:g} s before the last frame "
                f"made (frame {self.frame}); frame {start} is earlier"
            )
        prompt = LivePrompt(text, start, frames, typed)
        # a later prompt at the same or an earlier boundary replaces what was queued after it
        self._pending = [p for p in self._pending if p.start < start] + [prompt]
        if start < self.frame:
            self._rewind(start)
        return start

    def _rewind(self, frame: int) -> None:
        """Drop what was pulled from ``frame`` (a snippet boundary) on."""
        unit = self.spec.snippet_length
        self._history.truncate(frame // unit)
        while self._segments and self._segments[-1].start >= frame:
            self._segments.pop()
        self.prompts = [p for p in self.prompts if p.start < frame]
        self.frame = frame

    # -- snippets ------------------------------------------------------------------------------

    def __iter__(self) -> Iterator[Snippet]:
        while True:
            yield self.next_snippet()

    def next_snippet(self) -> Snippet:
        """Make and return the next snippet (starting a segment first where one is due)."""
        unit = self.spec.snippet_length
        frame = self.frame
        if self._pending and self._pending[0].start <= frame:
            prompt = self._pending.pop(0)
            self.prompts.append(LivePrompt(prompt.text, frame, prompt.frames, prompt.typed))
            self._start_segment(frame)
        elif not self._segments or frame >= self._segments[-1].start + len(self._segments[-1].raw):
            self._start_segment(frame)  # the segment ended: the prompt goes on
        segment = self._segments[-1]
        raw = segment.raw[frame - segment.start : frame - segment.start + unit]
        features, joints, root = self._finish(raw)
        history = self._history
        history.raw.append(raw)
        history.features.append(features)
        history.joints.append(joints)
        history.root.append(root)
        self.frame = frame + unit
        return Snippet(frame, joints, features, segment.prompt, self.prompts[segment.prompt].text)

    def _start_segment(self, frame: int) -> None:
        """Segment n from ``frame``: continue (the ``continue`` edit's plan) from the last
        ``context_frames`` made, under the current prompt."""
        spec, unit = self.spec, self.spec.snippet_length
        prompt_index = len(self.prompts) - 1
        prompt = self.prompts[prompt_index]
        index = len(self._segments)
        generator = torch.Generator(self.pipe.device).manual_seed(segment_seed(self.seed, index))
        prepared = self._prepare(prompt.text)
        # A prompt that names a count ("jumps twice") does it once, in the time it needs
        # (TextToMotion.count_parts); the rest of its fixed length, and every segment after it
        # until a new prompt, is standing still.
        counted = prepared[0].encoded.count > 0 or any(c.count for c in prepared[0].clauses)
        last = self._segments[-1] if self._segments else None
        earlier = last if last is not None and last.prompt == prompt_index else None
        text = SETTLE_TEXT if counted and earlier else prompt.text
        if counted and earlier and earlier.rest:
            frames = earlier.rest
        elif prompt.frames is None:
            frames = self.pipe.sample_lengths(self._prepare(text), generator)[0]
        else:
            frames = prompt.frames
        tail = self._raw_tail(frame)
        frames = max(unit, min(frames, (spec.max_frames - len(tail)) // unit * unit))
        rest = 0
        if counted and not earlier:
            parts = self.pipe.count_parts(prepared[0], frames)
            frames, rest = parts[0][1], sum(n for _, n in parts[1:])
        if len(tail):
            plan = _continuation(text, tail, frames, spec)
        else:
            target = np.full((frames, spec.num_joints, 3), np.nan)
            plan = EditPlan(text, frames, target, np.zeros(target.shape[:2], bool))
        _quiet.on = True
        try:
            (result,) = generate_plans(self.pipe, [plan], generator, self.settings)
        finally:
            _quiet.on = False
        raw = result.features[len(tail) :].astype(np.float32)
        if self._segments:  # only the running segment is read on: free the others' frames
            self._segments[-1].raw = raw[:0]
        self._segments.append(_Segment(index, prompt_index, frame, raw, rest))

    def _prepare(self, text: str) -> list:
        """``pipe.prepare([text])``, tagged once per stream."""
        if text not in self._prepared:
            if len(self._prepared) > 256:
                self._prepared.clear()
            self._prepared[text] = self.pipe.prepare([text])
        return self._prepared[text]

    def _raw_tail(self, frame: int) -> np.ndarray:
        """The raw features of the ``context_frames`` before ``frame`` (fewer at the start)."""
        unit = self.spec.snippet_length
        offset = self._history.work_from
        first = max(frame - self.context_frames, offset * unit)
        rows = self._history.raw[first // unit - offset : frame // unit - offset]
        if not rows:
            return np.zeros((0, self.spec.feature_dim), np.float32)
        return np.concatenate(rows)

    def _finish(self, raw: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """A snippet's raw features (F, D) -> its finished features, world joints (F, J, 3)
        and world root (F, 3: half-yaw, x, z), from a window of the frames before it."""
        unit = self.spec.snippet_length
        history = self._history
        back = min(FINISH_LOOKBACK_FRAMES // unit, len(history.raw))
        window = np.concatenate([*history.raw[len(history.raw) - back :], raw])  # (W, D)
        # the world root (half-yaw, x, z) of the window's first frame
        first = history.root[len(history.root) - back][0] if back else np.zeros(3)
        rows = slice(len(window) - len(raw), len(window))
        if self.finish and len(window) >= 2:
            joints, features = self.pipe.finish(window, self.clean)
        else:
            joints, features = recover_from_ric(window, self.spec.num_joints), window
        _, root = recover_root(window)  # window-local: frame 0 at the origin facing +Z
        half_yaw = np.concatenate([[0.0], np.cumsum(window[:-1, 0], dtype=np.float64)])
        world = np.empty((len(raw), 3))
        world[:, 0] = first[0] + half_yaw[rows]
        world[:, 1:] = _turn(root[rows], first[0])[:, [0, 2]] + first[1:]
        joints = _turn(joints[rows], first[0])
        joints[..., 0] += first[1]
        joints[..., 2] += first[2]
        return features[rows].astype(np.float32), joints.astype(np.float32), world

    # -- what was made -------------------------------------------------------------------------

    def joints(self) -> np.ndarray:
        """(T, J, 3) float32 world joints of every frame pulled (kept: see :meth:`trim`)."""
        return _stack(self._history.joints, (0, self.spec.num_joints, 3))

    def features(self, raw: bool = False) -> np.ndarray:
        """(T, D) float32 finished features of every frame pulled (``raw``: the model's); after
        :meth:`trim`, of the last few seconds only (what a rewind and the next segment read)."""
        rows = self._history.raw if raw else self._history.features
        return _stack(rows, (0, self.spec.feature_dim))

    @property
    def first_frame(self) -> int:
        """The stream frame of :meth:`joints`' first row (0 unless trimmed)."""
        return self._history.joints_from * self.spec.snippet_length

    def trim(self, keep_seconds: float) -> None:
        """Forget the joints of all but the last ``keep_seconds`` pulled (at least
        :data:`MAX_REWIND_SECONDS`), and the features of all but what a rewind and the next
        segment read: a stream that runs for hours keeps bounded memory. What is forgotten can
        no longer be downloaded."""
        unit, fps = self.spec.snippet_length, self.spec.fps
        rewind = int(MAX_REWIND_SECONDS * fps)
        keep_joints = max(int(keep_seconds * fps), rewind)
        keep_work = rewind + max(self.context_frames, FINISH_LOOKBACK_FRAMES) + unit
        self._history.forget(-(-keep_joints // unit), -(-keep_work // unit))

    def timeline(self) -> list[str]:
        """The prompts with their times as ``compose`` timeline lines ``text#start#end``
        (seconds; the last ends at the last frame pulled). :func:`replay` of them (same seed)
        gives this stream's frames again."""
        fps = self.spec.fps
        lines = []
        for index, prompt in enumerate(self.prompts):
            stop = self.prompts[index + 1].start if index + 1 < len(self.prompts) else self.frame
            if stop > prompt.start:
                text = prompt.text.replace("#", " ")
                lines.append(f"{text}#{prompt.start / fps:g}#{stop / fps:g}")
        return lines


def _turn(points: np.ndarray, half_yaw: float) -> np.ndarray:
    """Points (..., 3) of a window whose frame 0 faces +Z into a world where that frame's
    heading is ``half_yaw`` (the rotation :func:`recover_root` applies: ``qinv(facing)``)."""
    facing = np.array([math.cos(half_yaw), 0.0, math.sin(half_yaw), 0.0])
    points = np.asarray(points, dtype=np.float64)
    return qrot(np.broadcast_to(qinv(facing), points.shape[:-1] + (4,)), points)


def _stack(rows: list[np.ndarray], empty: tuple[int, ...]) -> np.ndarray:
    return np.concatenate(rows) if rows else np.zeros(empty, np.float32)


def replay(
    pipe,
    timeline: str | Path | Sequence[str],
    seed: int = 0,
    *,
    finish: bool = True,
    clean: bool = True,
    settings: SearchSettings | None = None,
) -> LiveStream:
    """The stream of a timeline's prompts (``compose`` lines, as :meth:`LiveStream.timeline`
    writes them), each taking over at its start, pulled to the timeline's end: with the
    stream's seed it makes the same frames (:meth:`LiveStream.joints`)."""
    segments = read_timeline(timeline, pipe.spec)
    stream = LiveStream(pipe, segments[0].text, seed, finish=finish, clean=clean, settings=settings)
    for segment in segments[1:]:
        stream.prompt(segment.text, at=segment.start)
    while stream.frame < segments[-1].stop:
        stream.next_snippet()
    return stream


def drift_report(joints: np.ndarray, fps: float, window_seconds: float = 30.0) -> list[dict]:
    """How a long stream holds up, per window of ``window_seconds`` of world joints (T, J, 3)
    (SMPL or KIT numbering, y-up metres): ``floor_m`` (median over frames of the lowest foot
    joint's height: the figure stands on the floor near 0), ``upright_deg`` (median angle of the
    pelvis-to-neck line from vertical), ``speed_p95_mps`` (95th percentile of the root's
    horizontal speed), ``jerk_mean`` (mean of :func:`dataset_tools.physical.jerk_curve`,
    m/s^3). A stream that drifts shows a trend across the windows."""
    from dataset_tools.physical import jerk_curve
    from dataset_tools.skeleton import skeleton_for

    joints = np.asarray(joints, dtype=np.float64)
    skeleton = skeleton_for(joints.shape[1])
    feet = [*skeleton.feet_left, *skeleton.feet_right]
    neck = skeleton.joint_names.index("neck")
    size = max(4, int(window_seconds * fps))
    report = []
    for start in range(0, len(joints) - 3, size):
        part = joints[start : start + size]
        if len(part) < 4:
            break
        spine = part[:, neck] - part[:, 0]
        cosine = spine[:, 1] / np.maximum(np.linalg.norm(spine, axis=-1), 1e-9)
        speed = np.linalg.norm(np.diff(part[:, 0, [0, 2]], axis=0), axis=-1) * fps
        report.append(
            {
                "start_s": start / fps,
                "floor_m": float(np.median(part[:, feet, 1].min(axis=1))),
                "upright_deg": float(np.degrees(np.median(np.arccos(np.clip(cosine, -1, 1))))),
                "speed_p95_mps": float(np.percentile(speed, 95)),
                "jerk_mean": float(jerk_curve(part, fps).mean()),
            }
        )
    return report


__all__ = [
    "CONTEXT_SECONDS",
    "FINISH_LOOKBACK_FRAMES",
    "MAX_REWIND_SECONDS",
    "SETTLE_COMMANDS",
    "SETTLE_TEXT",
    "UNSIZED_SECONDS",
    "LivePrompt",
    "LiveStream",
    "Snippet",
    "drift_report",
    "replay",
    "segment_seed",
]
