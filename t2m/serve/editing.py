"""The page's edit panel and ``POST /api/edit``: motion editing through :mod:`t2m.edit`
(continue, inbetween, body, path, keys, compose) on the server's one model thread.

A request names its source motion either as an upload (a BVH or a joints ``.npy``, base64 in the
JSON) or as a motion this server generated (a live request id and the motion's index). Every
value is checked here, and only arrays and lists reach ``t2m.edit`` (a string there would be read
as a file name): an upload is written to a private file under the server's work folder, read
by :func:`t2m.edit.load_source` (our BVH importer, the header-checked ``.npy`` reader) and
removed.

The request's fields are those of :class:`t2m.edit.EditRequest`, read by its schema's JSON reader
(:func:`dataset_tools.command.fields_from_dict`, file names refused, ``mapping`` and
``source_fps`` not taken); this module adds the uploads and its limits (sizes, counts, seconds).

Request (JSON): ``mode``; ``text`` (not for compose); ``source``: ``{"upload": {"name":
"walk.bvh", "base64": ...}}`` or ``{"result": id, "motion": index}`` (continue, inbetween,
body; compose may start from one); ``keep_seconds`` (continue), ``keep_start`` / ``keep_end``
(inbetween), ``keep_last`` (compose with a source), ``seconds`` (continue, inbetween, path: the
result's length), ``part`` (body), ``path``: ``[[seconds, x, z], ...]``, ``keys``: ``{"upload":
{"name": "targets.npy", "base64": ...}}`` ((T, 22, 3), NaN where free), ``timeline``:
``["text#start#end" or "text#seconds", ...]`` (compose; after a source, its first line starts
where the kept source ends); ``samples``, ``seed``, ``precision`` as for generate.
"""

from __future__ import annotations

import base64
import binascii
import importlib.util
import math
import queue
import re
import secrets
from pathlib import Path

import numpy as np

from dataset_tools.command import UsageError, fields_from_dict
from t2m.serve.api import check_text

UNAVAILABLE = "editing needs t2m.edit (the editing modes), which this build does not have"
RUN_KEYS = ("samples", "seed", "precision")
"""The keys of an edit request that are not fields of :class:`t2m.edit.EditRequest`."""
FILE_OPTIONS = ("mapping", "source_fps")
"""EditRequest fields about reading a source file, which the web does not take."""
SECONDS_FIELDS = ("seconds", "keep_seconds", "keep_start", "keep_end", "keep_last")
MAX_UPLOAD_BYTES = 4 * 2**20
"""bytes of an uploaded file (a 10 s BVH at 120 fps is about 1.5 MB)"""
MAX_PATH_POINTS = 100
MAX_TIMELINE_LINES = 8
MAX_TIMELINE_SECONDS = 30.0
MAX_EDIT_SECONDS = 30.0
"""keep / result lengths and path times given in seconds are at most this"""
MAX_PATH_METRES = 1000.0
"""path points lie at most this far from the start along x and z"""


def edit_available() -> bool:
    return importlib.util.find_spec("t2m.edit") is not None


def edit_info() -> dict:
    """What GET /api/info says about editing."""
    if not edit_available():
        return {"available": False, "reason": UNAVAILABLE}
    from dataset_tools.viz import RenderConfig
    from t2m.edit import BODY_PARTS, MODES, EditRequest

    defaults = EditRequest(mode="continue", text="x", source=np.zeros((1, 22, 3)))
    return {
        "available": True,
        "modes": list(MODES),
        "parts": list(BODY_PARTS),
        "defaults": {
            "keep_seconds": defaults.keep_seconds,
            "keep_start": defaults.keep_start,
            "keep_end": defaults.keep_end,
            "part": defaults.part,
        },
        "highlight_color": RenderConfig().highlight_color,
        "limits": {
            "max_upload_bytes": MAX_UPLOAD_BYTES,
            "max_path_points": MAX_PATH_POINTS,
            "max_timeline_lines": MAX_TIMELINE_LINES,
            "max_timeline_seconds": MAX_TIMELINE_SECONDS,
        },
    }


def _upload(value: object, what: str, suffixes: tuple[str, ...], folder: Path) -> tuple[Path, str]:
    """An uploaded file written to a private file in ``folder``: (its path, the name given)."""
    if not isinstance(value, dict) or not isinstance(value.get("upload"), dict):
        raise UsageError(f"{what} must be an uploaded file")
    upload = value["upload"]
    name, data = upload.get("name"), upload.get("base64")
    if not isinstance(name, str) or not isinstance(data, str):
        raise UsageError(f"{what}: the upload needs a name and base64 data")
    name = "".join(c for c in name if c.isprintable())[:80]  # it is shown in messages
    suffix = Path(name).suffix.lower()
    if suffix not in suffixes:
        raise UsageError(f"{what} must be a {' or '.join(suffixes)} file, got {name!r}")
    if len(data) > MAX_UPLOAD_BYTES * 4 // 3 + 4:
        raise UsageError(f"{what} is larger than {MAX_UPLOAD_BYTES // 2**20} MiB")
    try:
        content = base64.b64decode(data, validate=True)
    except (binascii.Error, ValueError):
        raise UsageError(f"{what}: the upload is not valid base64") from None
    path = folder / f".upload-{secrets.token_urlsafe(12)}{suffix}"
    path.write_bytes(content)
    return path, name


def _named(message: str, path: Path, name: str) -> str:
    """A reader's message about the private copy of an upload, naming the upload instead."""
    for private in (f"--source {path}", str(path), f"{path.name}: ", path.name):
        message = message.replace(private, "" if private.endswith(": ") else f"the uploaded {name}")
    return message


def _source(app, value: object, folder: Path) -> tuple[np.ndarray, str]:
    """The source joints (T, J, 3) at the model's frame rate, and how to name it."""
    from t2m.edit import load_source

    if isinstance(value, dict) and "result" in value:
        request_id, index = value.get("result"), value.get("motion")
        if not isinstance(request_id, str) or isinstance(index, bool) or not isinstance(index, int):
            raise UsageError("source: give a request id and a motion index")
        try:
            stored = app.store.get(request_id)
        except KeyError:
            raise UsageError("source: no such generated motion on this server") from None
        flat = [motion for row in stored.motions for motion in row]
        if not 0 <= index < len(flat):
            raise UsageError(f"source: that request has motions 0 to {len(flat) - 1}")
        return flat[index].joints, f"motion {index + 1} of an earlier request"
    path, name = _upload(value, "source", (".bvh", ".npy"), folder)
    try:
        limit, fps = app.limits.max_source_frames, app.pipe.spec.fps
        if path.suffix == ".bvh" and _bvh_seconds(path) * fps + 1 > limit:  # resampled to fps
            raise UsageError(
                f"source: the uploaded {name} lasts {_bvh_seconds(path):.4g} s by its Frames and "
                f"Frame Time; at most {limit} frames ({limit / fps:g} s at {fps:g} fps)"
            )
        joints = load_source(path, app.pipe.spec)
        if len(joints) > limit:
            raise UsageError(
                f"source: the uploaded {name} has {len(joints)} frames; at most {limit}"
            )
        shortest = app.pipe.spec.snippet_length + 1  # an edit's plan checks it, naming no file
        if len(joints) < shortest:
            raise UsageError(
                f"source: the uploaded {name} has {len(joints)} frames at {fps:g} fps; an edit "
                f"needs at least {shortest}"
            )
        return joints, name
    except UsageError as error:
        raise UsageError(_named(str(error), path, name)) from None
    finally:
        path.unlink(missing_ok=True)


def _bvh_seconds(path: Path) -> float:
    """How long a BVH file lasts by its MOTION header (``Frames: T``, ``Frame Time: dt``), read
    before the file is; 0 when the header is malformed (the importer then says so)."""
    header = re.search(rb"Frames:\s*(\d{1,12})\s+Frame\s+Time:\s*(\S{1,40})", path.read_bytes())
    if header is None:
        return 0.0
    try:
        frames, frame_time = int(header[1]), float(header[2])
    except ValueError:
        return 0.0
    if not (math.isfinite(frame_time) and frame_time > 0):
        return 0.0
    return (frames - 1) * frame_time  # a float: 1e300 s is inf, never an OverflowError


def parse_edit(app, payload: object, folder: Path) -> tuple:
    """Check an edit request; returns (:class:`t2m.edit.EditRequest`, the source's name, samples,
    seed, precision). The request's fields are read by the schema's JSON reader with file names
    refused; uploads take the place of files (read, and their files removed, here); the web's
    limits come on top."""
    from t2m.edit import EditRequest
    from t2m.edit.request import json_terms
    from t2m.serve.api import run_options

    if not isinstance(payload, dict):
        raise UsageError("the request must be a JSON object")
    fields = {key: value for key, value in payload.items() if key not in RUN_KEYS}
    uploads = {key: fields.pop(key) for key in ("source", "keys") if key in fields}
    values = fields_from_dict(EditRequest, _web_shapes(fields), "edit", exclude=FILE_OPTIONS)
    source_name = _read_uploads(app, values, uploads, folder)
    _check_limits(app, values)
    samples, seed, precision = run_options(payload, app.limits, app.pipe.device.type)
    try:
        request = EditRequest(**values)
        if request.mode == "compose":  # the timeline, after the kept source when there is one
            plan = request.compose_plan(app.pipe.spec)
            kept = 0 if plan.start is None else len(plan.start)
            if plan.num_frames - kept > MAX_TIMELINE_SECONDS * app.pipe.spec.fps:
                raise UsageError(f"the timeline is longer than {MAX_TIMELINE_SECONDS:g} s")
    except UsageError as error:  # its checks name options; a request's keys are named here
        raise UsageError(json_terms(str(error))) from None
    return request, source_name, samples, seed, precision


def _web_shapes(fields: dict) -> dict:
    """The web's counts on a path's rows and a timeline's lines (a timeline may be one text of
    lines), checked before the schema reads them."""
    mode = fields.get("mode")
    if mode == "path" or "path" in fields:
        points = fields.get("path")
        if not isinstance(points, list) or not 0 < len(points) <= MAX_PATH_POINTS:
            raise UsageError(f"path must be 1 to {MAX_PATH_POINTS} rows [seconds, x, z]")
        if not all(
            isinstance(row, list)
            and len(row) == 3
            and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in row)
            for row in points
        ):
            raise UsageError("path must be rows of three numbers [seconds, x, z]")
        for number, (seconds, x, z) in enumerate(points, start=1):
            if not (_within(seconds, MAX_EDIT_SECONDS) and seconds >= 0):
                raise UsageError(
                    f"path row {number}: the time must be from 0 to {MAX_EDIT_SECONDS:g} seconds"
                )
            if not (_within(x, MAX_PATH_METRES) and _within(z, MAX_PATH_METRES)):
                raise UsageError(
                    f"path row {number}: x and z must be from -{MAX_PATH_METRES:g} to "
                    f"{MAX_PATH_METRES:g} metres"
                )
    if mode == "compose" or "timeline" in fields:
        lines = fields.get("timeline")
        if isinstance(lines, str):
            lines = lines.splitlines()
        if not isinstance(lines, list) or not all(isinstance(line, str) for line in lines):
            raise UsageError("timeline must be lines 'text#start#end' or 'text#seconds'")
        lines = [line for line in lines if line.strip()]
        if not 0 < len(lines) <= MAX_TIMELINE_LINES:
            raise UsageError(f"the timeline needs 1 to {MAX_TIMELINE_LINES} lines")
        fields = {**fields, "timeline": lines}  # a list: never read as a file
    return fields


def _within(value: int | float, bound: float) -> bool:
    """Whether a JSON number lies in [-bound, bound] (a 400-digit integer does not: it has no
    float, and NaN or infinity never do)."""
    try:
        return abs(float(value)) <= bound
    except OverflowError:
        return False


def _read_uploads(app, values: dict, uploads: dict, folder: Path) -> str | None:
    """Put the uploaded source motion and key targets into ``values`` as arrays; returns how to
    name the source (None without one)."""
    from dataset_tools.io import load_npy
    from t2m.edit.request import NEEDS_SOURCE

    mode = values["mode"]
    source_name = None
    if mode in NEEDS_SOURCE:
        if uploads.get("source") is None:
            raise UsageError(f"{mode} edits a motion: upload a BVH or .npy, or pick a motion")
        values["source"], source_name = _source(app, uploads["source"], folder)
    elif mode == "compose" and uploads.get("source") is not None:  # starts from it
        values["source"], source_name = _source(app, uploads["source"], folder)
    elif uploads.get("source") is not None:
        raise UsageError(f"{mode} makes a new motion and takes no source")
    if mode == "keys":
        path, name = _upload(uploads.get("keys"), "keys", (".npy",), folder)
        try:
            values["keys"] = load_npy(path, finite=False)
            shape, joints = values["keys"].shape, app.pipe.spec.num_joints
            if len(shape) != 3 or shape[1:] != (joints, 3):  # the plan's check names no file
                raise UsageError(
                    f"keys: the uploaded {name} must be (T, {joints}, 3) with NaN for free, "
                    f"got {shape}"
                )
        except UsageError as error:
            raise UsageError(_named(str(error), path, name)) from None
        finally:
            path.unlink(missing_ok=True)
    return source_name


def _check_limits(app, values: dict) -> None:
    """The web's limits on checked fields: the text's characters, lengths in seconds, the
    timeline's lines (its whole length is checked with the request, after the source)."""
    limits = app.limits
    if values["mode"] == "compose":
        values["text"] = ""
        for number, line in enumerate(values["timeline"], start=1):
            check_text(line, f"timeline line {number}", limits.max_prompt_chars)
    else:
        values["text"] = check_text(values.get("text"), "edit text", limits.max_prompt_chars)
    for key in SECONDS_FIELDS:
        value = values.get(key)
        if value is not None and not 0 <= value <= MAX_EDIT_SECONDS:
            raise UsageError(f"{key} must be from 0 to {MAX_EDIT_SECONDS:g} seconds, got {value:g}")


def edit(app, payload: object) -> dict:
    """POST /api/edit: check, run on the model thread, store, answer as generate does."""
    if not edit_available():
        raise UsageError(UNAVAILABLE)
    from t2m.edit import edit_batch
    from t2m.serve.api import RESULTS_FULL, Busy, prompt_json
    from t2m.serve.worker import ModelCall

    request, source_name, samples, seed, precision = parse_edit(app, payload, app.store.root)
    mode = request.mode

    def work(pipe) -> tuple[list, list]:
        # the words first: a prompt with no known word is refused, unknown ones are named
        prepared = pipe.prepare([request.text]) if request.text else []
        motions = edit_batch(pipe, [request], num_samples=samples, seed=seed)[0]
        return motions, prepared

    if not app.store.wait_for_room():
        raise Busy(RESULTS_FULL)
    call = ModelCall(work, precision)
    try:
        app.worker.submit(call)
    except queue.Full:
        raise Busy("the server is busy with other requests; try again in a moment") from None
    if not call.done.wait(app.generate_timeout):
        raise Busy("the edit took too long; try fewer samples")
    if call.error is not None:
        if isinstance(call.error, ValueError):  # a plan's refusal, in the request's keys
            from t2m.edit.request import json_terms

            raise UsageError(json_terms(str(call.error))) from None
        raise call.error
    motions, prepared = call.result
    extra = {"precision": precision, "mode": mode, "source": source_name}
    stored = app.store.add([list(motions)], seed, extra, held=True)
    stored.prompts = [prompt_json(item, None) for item in prepared] or [
        {
            "text": motions[0].text,
            "frames_requested": None,
            "unknown_words": [],
            "dropped_words": [],
        }
    ]
    try:
        answer = app.answer(stored.id)
    except BaseException:
        app.store.release(stored.id)
        raise
    answer["edit"] = {"mode": mode, "source": source_name}
    return answer
