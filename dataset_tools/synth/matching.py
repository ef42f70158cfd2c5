"""Whether a motion performs its labels: the facts of :mod:`dataset_tools.synth.detectors`
judged against ground-truth segment labels.

``label_matches(detected, label)`` says whether facts (``detect_labels``) agree with one segment
label (``{"action": ..., "params": {...}}`` as in ``labels.json``). A clip's segments are checked
two ways: ``clip_matches`` cuts the motion in proportion to the segments' frames (fixed timing);
``align_segments`` searches where the motion performs them, in their order (captions give order
and counts, never timing), and keeps events a segment counts out of the others. Both read one
``MotionSignals`` per motion, computed once, whose ``facts(a, b)`` are the facts of any window.
``mirror_label`` gives the label of a mirrored clip.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dataset_tools.synth.detectors import RUN_SPEED_MPS, SPEED_BOUNDS, MotionSignals

_OTHER = {"left": "right", "right": "left"}


def _speed_class(speed: float, gait: str, direction: str) -> str:
    key = "sideways" if direction in ("left", "right") else direction
    key = "forward" if key in ("clockwise", "counterclockwise") else key
    slow_max, fast_min = SPEED_BOUNDS[(gait, key)]
    return "slow" if speed < slow_max else "fast" if speed > fast_min else "normal"


def _gait_matches(d: dict, action: str, params: dict) -> bool:
    """:func:`label_matches` of a walk or run: moving the labelled way (forward, backward,
    sideways, or in a circle), walking or running as labelled, in its speed class if it has
    one."""
    direction = params["direction"]
    scale = d["speed_scale"]
    if direction in ("forward", "backward", "clockwise", "counterclockwise"):
        speed = abs(d["forward_speed_mps"]) * scale
        ok = (
            d["forward_speed_mps"] > 0.3
            if direction != "backward"
            else d["forward_speed_mps"] < -0.2
        )
        if direction in ("clockwise", "counterclockwise"):
            turned = (
                d["yaw_change_deg"] if direction == "counterclockwise" else -d["yaw_change_deg"]
            )
            ok = ok and turned > 90
        else:
            ok = ok and abs(d["yaw_change_deg"]) < 60
        if direction != "backward":
            is_run = d["path_speed_mps"] * scale > RUN_SPEED_MPS
            ok = ok and is_run == (action == "run")
        if action == "walk":
            ok = ok and d["airborne_count"] == 0
    else:
        sign = 1.0 if direction == "left" else -1.0
        speed = sign * d["left_speed_mps"] * scale
        ok = speed > 0.15 and abs(d["forward_speed_mps"]) < 0.5 * speed
    if "speed" in params:
        ok = ok and _speed_class(speed, action, direction) == params["speed"]
    return bool(ok)


def label_matches(detected: dict, label: dict) -> bool:
    """Whether facts from ``detect_labels`` agree with one segment label {"action", "params"}.

    Checks the action's defining property and its parameters (side, direction, count, speed
    class, angle). Mismatched extras (a wave detected during a walk) are not held against it.
    """
    action, params = label["action"], label.get("params", {})
    d = detected
    if action in ("walk", "run"):
        return _gait_matches(d, action, params)
    if action == "turn":
        turned = d["yaw_change_deg"] if params["direction"] == "left" else -d["yaw_change_deg"]
        angle = params.get("angle", 90)
        return bool(abs(turned - angle) < 35 and d["displacement_m"] < 0.6)
    if action == "jump":
        ok = (
            d["airborne_count"] == params.get("count", d["airborne_count"])
            and d["airborne_count"] > 0
        )
        ok = ok and d["hop_side"] is None
        if params.get("mode") == "forward":
            ok = ok and d["displacement_m"] > 0.3 and d["forward_speed_mps"] > 0
        elif params.get("mode") == "in_place":
            ok = ok and d["displacement_m"] < 0.3
        return bool(ok)
    if action == "hop":
        return bool(
            d["hop_side"] == params["side"]
            and d["airborne_count"] == params.get("count", d["airborne_count"])
        )
    if action in ("wave", "raise"):
        sides = {"left": (True, False), "right": (False, True), "both": (True, True)}[
            params["side"]
        ]
        seen = (d[f"{action}_left"], d[f"{action}_right"])
        return seen == sides
    if action == "kick":
        return bool(d[f"kick_{params['side']}"] and not d[f"kick_{_OTHER[params['side']]}"])
    if action == "punch":
        side = params["side"]
        count = params.get("count", d[f"punch_{side}"])
        return bool(
            d[f"punch_{side}"] == count
            and d[f"punch_{_OTHER[side]}"] == 0
            and count > 0
            and not d[f"raise_{side}"]
        )
    if action == "squat":
        count = params.get("count", d["dip_count"])
        return bool(
            d["dip_count"] == count and count > 0 and not d["sit"] and d["airborne_count"] == 0
        )
    if action == "sit":
        return bool(d["sit"])
    if action == "bow":
        return bool(
            d["trunk_max_deg"] > 25 and d["pelvis_min_ratio"] > 0.85 and d["displacement_m"] < 0.3
        )
    if action == "clap":
        count = params.get("count", d["clap_count"])
        return bool(d["clap_count"] == count and count > 0)
    if action == "stand":
        return bool(
            d["path_speed_mps"] < 0.15
            and abs(d["yaw_change_deg"]) < 20
            and d["airborne_count"] == 0
            and d["pelvis_min_ratio"] > 0.95
            and d["limb_activity_mps"] < 0.15
            and d["trunk_max_deg"] < 20
        )
    raise ValueError(f"unknown action {action!r}")


TRIM_S = 0.1
"""Seconds cut off each side of a boundary between segments, to skip the cross-fades."""


def _window(span: tuple[float, float], first: bool, last: bool, trim: float) -> tuple[int, int]:
    """The integer window [a, b) of a (start, end) span in frames; a side that borders another
    segment moves inwards by ``trim`` frames (at most a quarter of the span); >= 2 frames."""
    a, b = span
    margin = min(trim, 0.25 * (b - a))
    a2 = a if first else a + margin
    b2 = b if last else b - margin
    return int(round(a2)), max(int(round(b2)), int(round(a2)) + 2)


def _proportional_spans(
    segments: list[dict], total_frames: int, num_frames: int
) -> list[tuple[float, float]]:
    scale = num_frames / total_frames
    return [(seg["start"] * scale, seg["end"] * scale) for seg in segments]


def segment_windows(
    segments: list[dict], total_frames: int, num_frames: int, trim_frames: int = 0
) -> list[tuple[int, int]]:
    """Frame windows [a, b) in a motion of ``num_frames`` frames for the labelled segments of a
    clip of ``total_frames`` frames, scaled proportionally; boundaries between segments move
    inwards by ``trim_frames`` (at most a quarter of the segment) to skip the cross-fades."""
    spans = _proportional_spans(segments, total_frames, num_frames)
    last = len(spans) - 1
    return [_window(span, i == 0, i == last, trim_frames) for i, span in enumerate(spans)]


# Counted actions: the facts that count their events, the per-frame sign of being inside one
# (MotionSignals.busy), and the actions that make such events themselves with at most how many
# per fact (None: its own label counts them). Measured on the demo corpus' 4,000 real clips: a
# sit dips exactly once; no other action makes these events.
COUNTED_EVENTS: dict[str, tuple[tuple[str, ...], str, dict[str, int | None]]] = {
    "jump": (("airborne_count",), "flight", {"jump": None, "hop": None}),
    "hop": (("airborne_count",), "flight", {"jump": None, "hop": None}),
    "punch": (("punch_left", "punch_right"), "punch", {"punch": None}),
    "squat": (("dip_count",), "dip", {"squat": None, "sit": 1}),
    "clap": (("clap_count",), "clap", {"clap": None}),
}


class _WindowJudge:
    """Whether a window of a motion matches a segment label, each window's facts computed once.

    With ``exclusive``, the events a segment counts (jumps, punches, squats, claps) must all lie
    in its own stretch: another segment's stretch, widened over the trimmed frames on both
    sides, must not hold such an event unless its own action makes them (and then no more than
    it makes). An aligned segmentation may not hide a surplus jump in a neighbouring wave.
    """

    def __init__(self, signals: MotionSignals, segments: list[dict], exclusive: bool = False):
        self.signals, self.segments = signals, segments
        self.trim = round(TRIM_S * signals.fps)
        self.facts: dict[tuple[int, int], dict] = {}
        self.counted = sorted({s["action"] for s in segments if s["action"] in COUNTED_EVENTS})
        # Per segment: (fact, most allowed) for the other segments' counted events.
        self.limits: list[list[tuple[str, int]]] = []
        for seg in segments:
            limits = []
            for action in self.counted if exclusive else []:
                keys, _, makers = COUNTED_EVENTS[action]
                if makers.get(seg["action"], 0) is not None:
                    limits += [(key, makers.get(seg["action"], 0)) for key in keys]
            self.limits.append(limits)

    def _facts(self, a: int, b: int) -> dict:
        if (a, b) not in self.facts:
            self.facts[(a, b)] = self.signals.facts(a, b)
        return self.facts[(a, b)]

    def label_ok(self, index: int, span: tuple[float, float]) -> bool:
        """Whether segment ``index``'s label matches when it spans frames (start, end)."""
        last = len(self.segments) - 1
        a, b = _window(span, index == 0, index == last, self.trim)
        b = min(b, self.signals.num_frames)
        return b - a >= 2 and label_matches(self._facts(a, b), self.segments[index])

    def strays(self, index: int, span: tuple[float, float]) -> list[str]:
        """The counted actions (of other segments) with too many events in segment ``index``'s
        stretch widened over the trimmed frames."""
        if not self.limits[index]:
            return []
        T = self.signals.num_frames
        wide = self._facts(
            max(0, int(round(span[0] - self.trim))), min(T, int(round(span[1] + self.trim)))
        )
        over = {key for key, most in self.limits[index] if wide[key] > most}
        return [action for action in self.counted if over & set(COUNTED_EVENTS[action][0])]

    def boundary_ok(self, boundary: float, index: int) -> bool:
        """Whether a boundary between segments ``index - 1`` and ``index`` can sit at frame
        ``boundary``: no event either of them counts is under way within the trimmed frames
        around it (a boundary through a jump would let both sides count it)."""
        kinds = {
            COUNTED_EVENTS[self.segments[i]["action"]][1]
            for i in (index - 1, index)
            if self.segments[i]["action"] in COUNTED_EVENTS
        }
        around = slice(
            max(0, int(round(boundary - self.trim))), int(round(boundary + self.trim)) + 1
        )
        return not any(self.signals.busy(kind)[around].any() for kind in kinds)

    def __call__(self, index: int, span: tuple[float, float]) -> bool:
        """Whether segment ``index`` matches, and holds no other segment's counted event."""
        return self.label_ok(index, span) and not self.strays(index, span)

    def verdicts(self, spans: list[tuple[float, float]]) -> tuple[bool, ...]:
        """Per segment of a whole segmentation, whether it is right: its label matches and, if it
        counts events, none of them lies in another segment's stretch (a stray event fails the
        segment that counts it, not the one it strayed into)."""
        strayed = {action for i, span in enumerate(spans) for action in self.strays(i, span)}
        return tuple(
            self.label_ok(i, span) and self.segments[i]["action"] not in strayed
            for i, span in enumerate(spans)
        )


def clip_matches(
    joints: np.ndarray | MotionSignals,
    fps: float,
    segments: list[dict],
    total_frames: int | None = None,
) -> list[bool]:
    """Per labelled segment, whether the motion's corresponding stretch matches it, the motion
    cut in the proportions of the labelled clip (fixed timing; see :func:`align_segments` for
    the timing-free check).

    Args:
        joints: (T, 22, 3) y-up metres at ``fps``, or their :class:`MotionSignals`.
        segments: the clip's segment labels (``labels.json``: action, params, start, end).
        total_frames: frame count the segments' start/end refer to (default: the last segment's
            end); the motion is cut in the same proportions, whatever its own length.
    """
    signals = joints if isinstance(joints, MotionSignals) else MotionSignals(joints, fps)
    total = total_frames or segments[-1]["end"]
    spans = _proportional_spans(segments, total, signals.num_frames)
    judge = _WindowJudge(signals, segments)
    return [judge.label_ok(i, span) for i, span in enumerate(spans)]


@dataclass(frozen=True)
class AlignmentBounds:
    """How far :func:`align_segments` may move the boundaries between a clip's segments.

    Calibrated on the demo corpus' test split (600 real motions, 1,200 demo-model motions): the
    defaults sit on the plateau of the generated motions' accuracy (a finer 0.1 s grid, shifts
    of 0.35 or 0.5, or segments down to a quarter of their length each gain at most 0.003 of
    items) while the false positives of real motions scored against wrong labels (other clips',
    reversed order, a count one lower) stay those of fixed timing for every setting tried
    (mirrored sides and a count one higher, measured at the defaults: none, as with fixed
    timing); the corpus' shortest segment is 1.3 s and a jump about 0.45 s, so 0.25 s steps
    cannot skip an event.
    """

    step_s: float = 0.25
    """spacing of the candidate boundary positions, seconds"""
    max_shift: float = 0.25
    """each boundary stays within this fraction of the motion's length of its proportional place"""
    min_fraction: float = 0.5
    """each segment keeps at least this fraction of its proportional length ..."""
    min_s: float = 0.5
    """... and at least this many seconds (or its proportional length, when shorter)"""


@dataclass(frozen=True)
class Alignment:
    """The best in-order segmentation of a motion for a clip's labels (:func:`align_segments`).

    Attributes:
        matches: per segment, whether it is right in the best segmentation: its label matches
            and, if it counts events (jumps, punches, ...), none of them lies in another
            segment's stretch.
        fixed: per segment, whether it matches with the clip's own proportions
            (:func:`clip_matches`).
        spans: per segment, its (start, end) frames in the best segmentation (before trimming).
    """

    matches: tuple[bool, ...]
    fixed: tuple[bool, ...]
    spans: tuple[tuple[float, float], ...]


def align_segments(
    joints: np.ndarray | MotionSignals,
    fps: float,
    segments: list[dict],
    total_frames: int | None = None,
    bounds: AlignmentBounds = AlignmentBounds(),
) -> Alignment:
    """Find where a motion performs a clip's labelled segments, in their order, whatever their
    timing: captions give the order and the counts of the actions, never their durations.

    The boundaries between segments move over a grid (``bounds``) around their proportional
    places; the segmentation with the most segments matching wins (ties: the least moved,
    so the proportional one when it is as good). A segment that counts events (a jump, punch,
    squat or clap) owns them all: such an event in another segment's stretch (widened over the
    trimmed frames) fails the item, so "jumps once, then waves" does not pass a motion that
    jumps twice by hiding a jump in the wave. Dynamic programming over the boundaries, each
    window's facts computed once.

    Args:
        joints: (T, 22, 3) y-up metres at ``fps``, or their :class:`MotionSignals`.
        segments: the clip's segment labels (action, params, start, end).
        total_frames: frame count the segments' start/end refer to (default: the last end).
        bounds: the search's limits.
    """
    signals = joints if isinstance(joints, MotionSignals) else MotionSignals(joints, fps)
    total = total_frames or segments[-1]["end"]
    T, k = signals.num_frames, len(segments)
    spans = _proportional_spans(segments, total, T)
    fixed = _WindowJudge(signals, segments).verdicts(spans)
    judge = _WindowJudge(signals, segments, exclusive=True)
    proportional = judge.verdicts(spans)
    if all(proportional) or k == 1:
        return Alignment(proportional, fixed, tuple(spans))
    # Candidate positions of each boundary (the proportional one included), and the shortest
    # length of each segment.
    step = max(bounds.step_s * signals.fps, 1.0)
    reach = int(bounds.max_shift * T / step)
    places = [spans[0][0]] + [end for _, end in spans]
    layers = [[places[0]]]
    for i, place in enumerate(places[1:-1], start=1):
        layers.append(
            [
                place + j * step
                for j in range(-reach, reach + 1)
                if 0 < place + j * step < T and (j == 0 or judge.boundary_ok(place + j * step, i))
            ]
        )
    layers.append([places[-1]])
    shortest = [
        min(b - a, max(bounds.min_s * signals.fps, bounds.min_fraction * (b - a))) for a, b in spans
    ]
    # best[i][c]: (segments matched, -frames moved) of the best way to place segments 0..i-1
    # with boundary i at layers[i][c], and the candidate of boundary i-1 it came from.
    best: list[list[tuple[tuple[int, float], int] | None]] = [[((0, 0.0), -1)]]
    for i in range(1, k + 1):
        row: list[tuple[tuple[int, float], int] | None] = []
        for end in layers[i]:
            moved = abs(end - places[i])
            choice = None
            for c, start in enumerate(layers[i - 1]):
                if best[i - 1][c] is None or end - start < shortest[i - 1] - 1e-9:
                    continue
                (matched, score), _ = best[i - 1][c]
                candidate = ((matched + judge(i - 1, (start, end)), score - moved), c)
                if choice is None or candidate[0] > choice[0]:
                    choice = candidate
            row.append(choice)
        best.append(row)
    # Walk back from the end.
    chosen, c = [places[-1]], 0
    for i in range(k, 0, -1):
        c = best[i][c][1]
        chosen.append(layers[i - 1][c])
    chosen.reverse()
    found = [(chosen[i], chosen[i + 1]) for i in range(k)]
    return Alignment(judge.verdicts(found), fixed, tuple(found))


def mirror_label(label: dict) -> dict:
    """The label of the mirrored motion: sides, sideways directions and turning senses swap."""
    swap = {
        "left": "right",
        "right": "left",
        "clockwise": "counterclockwise",
        "counterclockwise": "clockwise",
    }
    params = dict(label.get("params", {}))
    for key in ("side", "direction"):
        if key in params:
            params[key] = swap.get(params[key], params[key])
    return {**label, "params": params}
