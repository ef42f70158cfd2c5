"""The JSON API of the web app: the checks of every request's values and the answers' layout.

A generate request is a :class:`t2m.request.GenerationRequest` read by its schema's JSON reader
(:func:`dataset_tools.command.fields_from_dict`: the fields :data:`WEB_FIELDS`, file names
refused) plus the precision it runs at (the type of :class:`t2m.options.OutputOptions`'s field);
this module adds only the web's limits (:class:`Limits`, stated in docs/webapp.md) and the model's
length range, checked before any work. A bad value raises ``UsageError`` with one sentence
naming the field, which the page shows as it is.
"""

from __future__ import annotations

import dataclasses
import unicodedata
from dataclasses import asdict, dataclass

import numpy as np

from dataset_tools.command import UsageError, fields_from_dict, json_key
from dataset_tools.io import parse_json
from dataset_tools.spec import DatasetSpec
from t2m.motion import GeneratedMotion
from t2m.options import OutputOptions
from t2m.pipeline import PreparedText, frames_for
from t2m.prompts import Prompt
from t2m.request import GenerationRequest

WEB_FIELDS = ("prompts", "seconds", "num_samples", "seed")
"""The fields of :class:`GenerationRequest` a generate request takes, as JSON ``prompts`` (a
list of lines ``text`` or ``text#FRAMES``, or one text of them), ``seconds``, ``samples`` and
``seed``; the others (one literal ``--text``, ``--length`` in frames, ``--batch-size``,
``--clean``, ``--plan``, ``--no-settle``) are the command line's."""
RUN_FIELDS = ("precision",)
"""The field of :class:`OutputOptions` a generate or edit request takes: the precision it runs
at (the command line loads its models at one)."""


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
    max_source_frames: int = 1200
    """frames of an edit's uploaded source at the model's frame rate (60 s at 20 fps), checked
    before it is read: a BVH is resampled from its frame time, so a few KB can imply hours"""


class Busy(RuntimeError):
    """The queue is full or the wait too long (HTTP 503)."""


RESULTS_FULL = (
    "the server's space for results is full of motions not yet sent; try again in a moment"
)
"""Busy's sentence when requests whose answers are not sent yet fill the results' disk cap."""


@dataclass(frozen=True)
class CheckedGeneration:
    """A generate request checked against the web's limits and the model: the request, its
    prompts with lengths in frames of the model (None: drawn by text2length), the precision."""

    request: GenerationRequest
    prompts: tuple[Prompt, ...]
    precision: str


def read_json(text: str) -> object:
    """A request body's JSON, read by the project's one strict reader
    (:func:`dataset_tools.io.parse_json`: nesting, digits of a number, finite floats, no key
    twice). UsageError (one line naming "the request body") for anything else."""
    return parse_json(text, "the request body")


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
) -> CheckedGeneration:
    """Check a generate request's JSON object (keys: prompts, seconds, samples, seed,
    precision; see docs/webapp.md) and return it with lengths in frames."""
    if not isinstance(payload, dict):
        raise UsageError("the request must be a JSON object")
    if isinstance(payload.get("prompts"), str):  # one text, one prompt a line
        payload = {**payload, "prompts": payload["prompts"].splitlines()}
    # 1. the schema: known keys, each value of its field's type
    values = fields_from_dict(GenerationRequest, payload, "", only=WEB_FIELDS, others=RUN_FIELDS)
    # 2. the web's limits: prompts, samples, seed, precision
    if values.get("prompts") is None:
        raise UsageError("prompts must be a list of sentences (or one text, one prompt a line)")
    lines = [line for line in values["prompts"] if line.strip()]
    if not lines:
        raise UsageError("empty prompt: type a sentence describing the motion")
    if len(lines) > limits.max_prompts:
        raise UsageError(f"{len(lines)} prompts; at most {limits.max_prompts} in one request")
    for number, line in enumerate(lines, start=1):
        check_text(line, f"prompt {number}", limits.max_prompt_chars)
    _check_run_limits(values, limits)
    precision = _precision(payload, device_type)
    request = GenerationRequest(**{**values, "prompts": tuple(lines)})
    # 3. lengths: "#FRAMES" per prompt, else "seconds" for all, else drawn by text2length; out
    # of the model's range is refused (the command line clamps with a warning)
    prompts = request.read_prompts()
    default_frames = None
    if request.seconds is not None:
        seconds = request.seconds
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
    motions = len(checked) * request.num_samples
    if motions > limits.max_motions:
        raise UsageError(
            f"{len(checked)} prompts x {request.num_samples} samples = {motions} motions; at "
            f"most {limits.max_motions} in one request"
        )
    return CheckedGeneration(request, tuple(checked), precision)


def _read(cls: type, payload: dict, names: tuple[str, ...]) -> dict:
    """The fields ``names`` of the dataclass ``cls`` from their JSON keys in ``payload`` (the
    schema's reader; the payload's other keys are other readers')."""
    keys = {json_key(f) for f in dataclasses.fields(cls) if f.name in names}
    given = {key: value for key, value in payload.items() if key in keys}
    return fields_from_dict(cls, given, "", only=names)


def _check_run_limits(values: dict, limits: Limits) -> None:
    """The web's ranges of a request's samples and seed (fields read by the schema)."""
    samples = values.get("num_samples", GenerationRequest.num_samples)
    seed = values.get("seed", GenerationRequest.seed)
    if not 1 <= samples <= limits.max_samples:
        raise UsageError(f"samples must be from 1 to {limits.max_samples}, got {samples}")
    if not 0 <= seed <= limits.max_seed:
        raise UsageError(f"seed must be from 0 to {limits.max_seed}, got {seed}")


def _precision(payload: dict, device_type: str) -> str:
    """A request's ``precision``, read with the type of :class:`OutputOptions`' field; int8 only
    on a CPU server."""
    precision = _read(OutputOptions, payload, RUN_FIELDS).get("precision", OutputOptions.precision)
    if precision == "int8" and device_type != "cpu":
        raise UsageError("int8 runs on the CPU only; this server runs on a GPU (use bf16)")
    return precision


def run_options(payload: dict, limits: Limits, device_type: str) -> tuple[int, int, str]:
    """The ``samples``, ``seed`` and ``precision`` of an edit request, read with the types of
    :class:`GenerationRequest` and :class:`OutputOptions` and checked against the web's limits."""
    values = _read(GenerationRequest, payload, ("num_samples", "seed"))
    _check_run_limits(values, limits)
    samples = values.get("num_samples", GenerationRequest.num_samples)
    seed = values.get("seed", GenerationRequest.seed)
    return samples, seed, _precision(payload, device_type)


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
