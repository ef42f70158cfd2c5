"""The JSON API of the web app: the checks of every request's values and the answers' layout.

Every value of a request is checked here before any work, against :class:`Limits` (stated in
the README); a bad one raises ``UsageError`` with one sentence the page shows as it is.
"""

from __future__ import annotations

import math
import unicodedata
from dataclasses import asdict, dataclass

import numpy as np

from dataset_tools.command import UsageError
from dataset_tools.spec import DatasetSpec
from t2m.motion import GeneratedMotion
from t2m.pipeline import PRECISIONS, PreparedText, frames_for
from t2m.prompts import Prompt, parse_prompt_line

GENERATE_KEYS = {"prompts", "seconds", "samples", "seed", "precision"}


@dataclass(frozen=True)
class Limits:
    """What one request may ask for."""

    max_body_bytes: int = 64 * 1024
    """bytes of one request's JSON body"""
    max_prompts: int = 8
    """prompts in one request"""
    max_prompt_chars: int = 300
    """characters of one prompt"""
    max_samples: int = 8
    """motions per prompt"""
    max_motions: int = 32
    """prompts times samples"""
    max_seed: int = 2**31 - 1
    """seeds are 0 .. this"""
    max_edit_body_bytes: int = 6 * 2**20
    """bytes of one edit request's JSON body (it may carry an uploaded motion)"""


class Busy(RuntimeError):
    """The queue is full or the wait too long (HTTP 503)."""


@dataclass(frozen=True)
class GenerateRequest:
    """A checked generate request: prompts with lengths in frames (None: drawn by the model)."""

    prompts: tuple[Prompt, ...]
    samples: int
    seed: int
    precision: str


def integer_field(payload: dict, key: str, default: int, low: int, high: int) -> int:
    value = payload.get(key, default)
    if isinstance(value, bool) or not isinstance(value, int):
        raise UsageError(f"{key} must be a whole number from {low} to {high}, got {value!r}")
    if not low <= value <= high:
        raise UsageError(f"{key} must be from {low} to {high}, got {value}")
    return value


def check_text(value: object, what: str, limit: int) -> str:
    """A prompt-like text: a non-empty string of at most ``limit`` characters, no control
    characters; returned stripped."""
    if not isinstance(value, str) or not value.strip():
        raise UsageError(f"empty {what}: type a sentence describing the motion")
    if len(value) > limit:
        raise UsageError(f"{what} has {len(value)} characters; at most {limit}")
    if any(unicodedata.category(c).startswith("C") for c in value):
        raise UsageError(f"{what} contains control characters")
    return value.strip()


def _check_frames(frames: float, spec: DatasetSpec, what: str) -> int:
    """A length in frames inside the model's limits, rounded to whole snippets."""
    if not spec.min_frames <= frames <= spec.max_frames:
        raise UsageError(
            f"{what} is out of range: this model makes {spec.min_frames} to {spec.max_frames} "
            f"frames ({spec.min_frames / spec.fps:g} to {spec.max_frames / spec.fps:g} s at "
            f"{spec.fps:g} fps)"
        )
    return frames_for(frames, spec)


def parse_generate(
    payload: object, spec: DatasetSpec, has_length_model: bool, limits: Limits, device_type: str
) -> GenerateRequest:
    """Check a generate request's JSON object (keys: prompts, seconds, samples, seed,
    precision; see the README) and return it with lengths in frames."""
    if not isinstance(payload, dict):
        raise UsageError("the request must be a JSON object")
    unknown = sorted(set(payload) - GENERATE_KEYS)
    if unknown:
        raise UsageError(f"unknown field {unknown[0]!r}; use {', '.join(sorted(GENERATE_KEYS))}")
    # 1. prompts, one a line, "text#FRAMES" fixing that prompt's length
    lines = payload.get("prompts")
    if isinstance(lines, str):
        lines = lines.splitlines()
    if not isinstance(lines, list) or not all(isinstance(line, str) for line in lines):
        raise UsageError("prompts must be a list of sentences (or one text, one prompt a line)")
    lines = [line for line in lines if line.strip()]
    if not lines:
        raise UsageError("empty prompt: type a sentence describing the motion")
    if len(lines) > limits.max_prompts:
        raise UsageError(f"{len(lines)} prompts; at most {limits.max_prompts} in one request")
    prompts = []
    for number, line in enumerate(lines, start=1):
        where = f"prompt {number}"
        prompts.append(parse_prompt_line(check_text(line, where, limits.max_prompt_chars), where))
    # 2. lengths: "#FRAMES" per prompt, else "seconds" for all, else drawn by text2length
    seconds = payload.get("seconds")
    default_frames = None
    if seconds is not None:
        if isinstance(seconds, bool) or not isinstance(seconds, (int, float)):
            raise UsageError(f"seconds must be a number or null (automatic), got {seconds!r}")
        if not math.isfinite(seconds):
            raise UsageError("seconds must be a finite number")
        default_frames = _check_frames(seconds * spec.fps, spec, f"length {seconds:g} s")
    checked = []
    for number, prompt in enumerate(prompts, start=1):
        frames = default_frames
        if prompt.frames is not None:
            frames = _check_frames(
                prompt.frames, spec, f"length #{prompt.frames} of prompt {number}"
            )
        if frames is None and not has_length_model:
            raise UsageError(
                "these checkpoints have no text2length stage: give a length in seconds or "
                "'#FRAMES' after the prompt"
            )
        checked.append(Prompt(prompt.text, frames))
    # 3. samples, seed, precision
    samples, seed, precision = run_options(payload, limits, device_type)
    if len(checked) * samples > limits.max_motions:
        raise UsageError(
            f"{len(checked)} prompts x {samples} samples = {len(checked) * samples} motions; at "
            f"most {limits.max_motions} in one request"
        )
    return GenerateRequest(tuple(checked), samples, seed, precision)


def run_options(payload: dict, limits: Limits, device_type: str) -> tuple[int, int, str]:
    """The ``samples``, ``seed`` and ``precision`` of a generate or edit request, checked."""
    samples = integer_field(payload, "samples", 1, 1, limits.max_samples)
    seed = integer_field(payload, "seed", 0, 0, limits.max_seed)
    precision = payload.get("precision", "fp32")
    if precision not in PRECISIONS:
        raise UsageError(f"precision must be one of {', '.join(PRECISIONS)}, got {precision!r}")
    if precision == "int8" and device_type != "cpu":
        raise UsageError("int8 runs on the CPU only; this server runs on a GPU (use bf16)")
    return samples, seed, precision


def motion_json(motion: GeneratedMotion, links: dict[str, str], decimals: int = 4) -> dict:
    """One motion in an answer: its joints (T frames of J * 3 numbers, metres, y-up), links and,
    for an edit, ``kept``: per frame a string of J '0' / '1' (the joint came from the source)."""
    joints = motion.joints.reshape(motion.num_frames, -1).astype(np.float64).round(decimals)
    answer = {
        "prompt": motion.prompt_index,
        "sample": motion.repetition,
        "text": motion.text,
        "frames": motion.num_frames,
        "joints": joints.tolist(),
        "files": links,
    }
    kept = getattr(motion, "kept", None)  # an edit's: (T, J) bool, from the source or targets
    if kept is not None and kept.shape == motion.joints.shape[:2]:
        answer["kept"] = ["".join("1" if k else "0" for k in row) for row in kept]
    return answer


def prompt_json(prepared: PreparedText, frames: int | None) -> dict:
    """What the model made of one prompt: the words it was not trained on, the words cut off."""
    return {
        "text": prepared.text,
        "frames_requested": frames,
        "unknown_words": list(prepared.unknown_words),
        "dropped_words": list(prepared.dropped_words),
    }


def limits_json(limits: Limits) -> dict:
    return asdict(limits)
