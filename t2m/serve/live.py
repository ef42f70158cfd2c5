"""The web app's live mode: one :class:`t2m.live.LiveStream` per viewer, its frames sent over
one long-lived connection as server-sent events (the standard library's ``http.server``; the
page reads them with ``EventSource``).

Routes (:data:`t2m.serve.server.ROUTES`; docs/live.md documents them):

    POST /api/live                         {"text", "seed"?, "precision"?} -> a session
    GET  /api/live/<session>/events        its frames, as server-sent events
    POST /api/live/<session>/prompt        {"text", "frame"?}: a new prompt -> its boundary
    POST /api/live/<session>/close         end it now (a closed tab ends it too)
    GET  /api/live/<session>/<name>        timeline.txt (the ``compose`` timeline), motion.npy,
                                           motion.bvh, motion.glb (the motion so far)

How a session runs. The events connection's own thread makes snippets as the viewer's clock
needs them, :data:`LEAD_SECONDS` ahead of it (so a slow snippet never starves the page), and
sleeps otherwise; a prompt wakes it. The page plays frame ``f`` at ``f / fps`` seconds after the
first arrived; a prompt carries the frame the page shows, and takes over at the first snippet
boundary at least :data:`PROMPT_MARGIN_FRAMES` after it: frames the page holds from there on are
replaced (the stream rewinds, :meth:`t2m.live.LiveStream.prompt`), so a new prompt shows within
one snippet (0.2 s) plus the time to make it, not after what was sent ahead.

Isolation. Live streams never use the generate queue's worker (a long generate never stalls
them, and a stream never holds up a generate request); each has its own thread and lock, so a
slow viewer (a full socket: its writes time out after :data:`WRITE_TIMEOUT_S`) or a vanished
one (its connection errors) stops only its own stream, which is then closed and freed. At most
``max_streams`` run at once; one more is refused with a sentence saying so (HTTP 503).
"""

from __future__ import annotations

import json
import logging
import math
import secrets
import tempfile
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from dataset_tools.command import UsageError
from t2m.live import MAX_PROMPT_CHARS, LiveStream, settle_text
from t2m.serve import api

logger = logging.getLogger("t2m.serve")

LEAD_SECONDS = 0.4
"""How far ahead of the viewer's clock a session makes and sends frames."""
PROMPT_MARGIN_FRAMES = 1
"""A prompt takes over at the first snippet boundary at least this many frames after the frame
the page showed when it was sent (the time the request and the new segment take)."""
WRITE_TIMEOUT_S = 10.0
"""A viewer that takes no frames for this long is gone: its stream ends."""
CONNECT_TIMEOUT_S = 20.0
"""A session whose events connection has not come this long after it was opened is dropped."""
KEEP_SECONDS = 600.0
"""The motion so far (downloads, timeline) holds at most this much; older frames are forgotten
(the stream itself goes on)."""
DOWNLOADS = {
    "timeline.txt": "text/plain; charset=utf-8",
    "motion.npy": "application/octet-stream",
    "motion.bvh": "text/plain; charset=utf-8",
    "motion.glb": "model/gltf-binary",
}
"""What a session offers for download, and its content type."""


@dataclass
class LiveSession:
    """One viewer's stream and what its threads share."""

    id: str
    stream: LiveStream
    seed: int
    precision: str
    lock: threading.Lock = field(default_factory=threading.Lock)
    wake: threading.Event = field(default_factory=threading.Event)
    closed: threading.Event = field(default_factory=threading.Event)
    opened_at: float = field(default_factory=time.monotonic)
    connected: bool = False
    clock_start: float | None = None  # monotonic time of frame 0 on the viewer's clock
    last_write: float = 0.0  # monotonic time of the last event sent
    trimmed_at: int = 0  # the stream's frame at its last trim

    def clock_frame(self) -> float:
        """The frame the viewer shows now (by the server's clock)."""
        if self.clock_start is None:
            return 0.0
        return (time.monotonic() - self.clock_start) * self.stream.spec.fps


class LiveHub:
    """The live sessions of a server.

    Args:
        pipe: the server's float32 pipeline (other precisions are made from it on first use,
            apart from the generate worker's).
        max_streams: sessions at once.
        keep_seconds: the motion so far that a session keeps (:data:`KEEP_SECONDS`).
    """

    def __init__(self, pipe, max_streams: int = 8, keep_seconds: float = KEEP_SECONDS):
        self.pipes = {pipe.precision: pipe}
        self.max_streams = max_streams
        self.keep_seconds = keep_seconds
        self.sessions: dict[str, LiveSession] = {}
        self._lock = threading.Lock()

    def info(self) -> dict:
        """The live part of GET /api/info."""
        return {
            "max_streams": self.max_streams,
            "running": len(self.sessions),
            "lead_seconds": LEAD_SECONDS,
            "max_prompt_chars": MAX_PROMPT_CHARS,
            "downloads": list(DOWNLOADS),
        }

    def _pipe(self, precision: str):
        with self._lock:
            if precision not in self.pipes:
                self.pipes[precision] = self.pipes["fp32"].with_precision(precision)
            return self.pipes[precision]

    # -- sessions ------------------------------------------------------------------------------

    def open(self, payload: object, limits: api.Limits) -> dict:
        """POST /api/live: check, make room, start a session (its first segment is made when
        the events connection asks for frames)."""
        if self.max_streams == 0:
            raise api.Busy("live mode is off on this server (started with --live-streams 0)")
        if not isinstance(payload, dict):
            raise UsageError('send a JSON object: {"text": ..., "seed": ...}')
        unknown = sorted(set(payload) - {"text", "seed", "precision"})
        if unknown:
            raise UsageError(
                f"unknown field {unknown[0]!r}; a live request takes text, seed, precision"
            )
        text = api.check_text(payload.get("text"), "prompt", MAX_PROMPT_CHARS)
        seed = payload.get("seed", 0)
        if isinstance(seed, bool) or not isinstance(seed, int) or not 0 <= seed <= limits.max_seed:
            raise UsageError(f"seed must be a whole number from 0 to {limits.max_seed}")
        pipe = self.pipes["fp32"]
        from t2m.pipeline import offered_precisions

        precision = payload.get("precision", "fp32")
        offered = offered_precisions(pipe.device)
        if precision not in offered:
            raise UsageError(f"precision must be one of {', '.join(offered)}, got {precision!r}")
        self._drop_unconnected()
        with self._lock:
            if len(self.sessions) >= self.max_streams:
                raise api.Busy(
                    f"{len(self.sessions)} live streams are running, the most this server runs "
                    "at once; try again when one ends"
                )
            session_id = secrets.token_urlsafe(12)
            # reserve the place before the (slower) stream is made
            self.sessions[session_id] = None  # type: ignore[assignment]
        try:
            stream = LiveStream(self._pipe(precision), text, seed)
        except BaseException:
            with self._lock:
                self.sessions.pop(session_id, None)
            raise
        session = LiveSession(session_id, stream, seed, precision)
        with self._lock:
            self.sessions[session_id] = session
        base = f"/api/live/{session_id}"
        return {
            "id": session_id,
            "fps": stream.spec.fps,
            "seed": seed,
            "precision": precision,
            "text": stream.prompts[-1].text if stream.prompts else text,
            "events": f"{base}/events",
            "prompt": f"{base}/prompt",
            "close": f"{base}/close",
            "files": {name: f"{base}/{name}" for name in DOWNLOADS},
        }

    def get(self, session_id: str) -> LiveSession:
        """The running session (KeyError: none such, or it ended)."""
        session = self.sessions.get(session_id)
        if session is None or session.closed.is_set():
            raise KeyError(session_id)
        return session

    def close(self, session_id: str) -> None:
        """End a session and free its stream."""
        with self._lock:
            session = self.sessions.pop(session_id, None)
        if session is not None:
            session.closed.set()
            session.wake.set()

    def close_all(self) -> None:
        for session_id in list(self.sessions):
            self.close(session_id)

    def _drop_unconnected(self) -> None:
        now = time.monotonic()
        stale = [
            sid
            for sid, s in list(self.sessions.items())
            if s is not None and not s.connected and now - s.opened_at > CONNECT_TIMEOUT_S
        ]
        for session_id in stale:
            self.close(session_id)

    # -- prompts -------------------------------------------------------------------------------

    def prompt(self, session_id: str, payload: object) -> dict:
        """POST /api/live/<session>/prompt: the prompt takes over at the first snippet boundary
        :data:`PROMPT_MARGIN_FRAMES` after the frame the page shows (``frame``; default: the
        server's clock). A refused prompt changes nothing."""
        session = self.get(session_id)
        if not isinstance(payload, dict):
            raise UsageError('send a JSON object: {"text": ..., "frame": ...}')
        unknown = sorted(set(payload) - {"text", "frame"})
        if unknown:
            raise UsageError(f"unknown field {unknown[0]!r}; a prompt takes text and frame")
        text = api.check_text(payload.get("text"), "prompt", MAX_PROMPT_CHARS)
        frame = payload.get("frame")
        if frame is not None and (
            isinstance(frame, bool)
            or not isinstance(frame, (int, float))
            or not math.isfinite(frame)
            or frame < 0
        ):
            raise UsageError("frame must be the number of the frame the page shows (>= 0)")
        stream = session.stream
        with session.lock:
            shown = session.clock_frame() if frame is None else float(frame)
            # never before what the stream may rewind to, never far past what it made
            rewind = int(LEAD_SECONDS * stream.spec.fps) + 2 * stream.spec.snippet_length
            shown = min(max(shown, stream.frame - rewind), stream.frame + stream.spec.fps)
            boundary = stream.prompt(text, at=math.ceil(shown) + PROMPT_MARGIN_FRAMES)
            index = len(stream.prompts)  # the new prompt's, once it starts
        session.wake.set()
        fps = stream.spec.fps
        return {
            "boundary": boundary,
            "seconds": boundary / fps,
            "prompt": index,
            "text": settle_text(text),
        }

    # -- frames --------------------------------------------------------------------------------

    def attach(self, session_id: str) -> LiveSession:
        """The session an events connection is for (KeyError: none; UsageError: it has one)."""
        with self._lock:
            session = self.get(session_id)
            if session.connected:
                raise UsageError("this live session already has a viewer; start a new one")
            session.connected = True
        return session

    def run_events(self, session: LiveSession, write) -> None:
        """The events connection of a session (:meth:`attach`): ``write(bytes)`` each event
        until the session closes or the viewer goes (a write error); then it is freed."""
        stream, fps = session.stream, session.stream.spec.fps
        lead = LEAD_SECONDS * fps
        try:
            write(_event("hello", {"id": session.id, "fps": fps, "seed": session.seed}))
            while not session.closed.is_set():
                session.wake.clear()
                event = None
                with session.lock:  # one snippet at a time: a new prompt's first goes at once
                    if session.clock_start is None:
                        session.clock_start = time.monotonic()
                    if stream.frame < session.clock_frame() + lead:
                        event = _snippet_event(stream.next_snippet())
                    elif stream.frame - session.trimmed_at > 10 * fps:  # memory stays bounded
                        stream.trim(self.keep_seconds)
                        session.trimmed_at = stream.frame
                if event is None and time.monotonic() - session.last_write > 5.0:
                    event = b": keep-alive\n\n"  # a comment: the page ignores it
                if event is not None:
                    write(event)
                    session.last_write = time.monotonic()
                    continue
                wait = (stream.frame - lead - session.clock_frame()) / fps
                session.wake.wait(timeout=min(max(wait, 0.005), 0.25))
        except OSError as error:  # the viewer went (or its socket timed out)
            logger.debug("live session %s ended: %s", session.id, error)
        except Exception as error:  # the stream failed: the page hears why, the log has the trace
            logger.exception("live session %s failed", session.id)
            try:
                write(_event("failure", {"error": f"the live stream failed: {error}"}))
            except OSError:
                pass
        finally:
            self.close(session.id)

    # -- downloads -----------------------------------------------------------------------------

    def download(self, session_id: str, name: str) -> tuple[bytes, str, str]:
        """(body, content type, file name) of one of :data:`DOWNLOADS`."""
        if name not in DOWNLOADS:
            raise KeyError(name)
        session = self.get(session_id)
        stream = session.stream
        with session.lock:
            if name == "timeline.txt":
                body = "\n".join(stream.timeline()) + "\n"
                return body.encode("utf-8"), DOWNLOADS[name], f"live_seed{session.seed}.txt"
            joints = stream.joints()
        if len(joints) < 2:
            raise UsageError("the stream has made no motion yet")
        from t2m.motion import GeneratedMotion
        from t2m.outputs import write_motion_file

        kind = name.split(".")[1]
        text = " / ".join(prompt.text for prompt in stream.prompts)
        # the writers used here read joints only; a long stream keeps features of its last
        # seconds only (LiveStream.trim), so none are handed over
        motion = GeneratedMotion(text, 0, 0, joints, np.zeros((len(joints), 0), np.float32))
        with tempfile.TemporaryDirectory(prefix="t2m-live-") as folder:
            written = write_motion_file(motion, Path(folder), kind, stream.spec.fps)
            body = (Path(folder) / written).read_bytes()
        return body, DOWNLOADS[name], f"live_seed{session.seed}.{kind}"


def _event(kind: str, data: dict) -> bytes:
    body = json.dumps(data, separators=(",", ":"), allow_nan=False)
    return f"event: {kind}\ndata: {body}\n\n".encode()


def _snippet_event(snippet) -> bytes:
    """A snippet as an event: its first frame, prompt and joints (F, J, 3) rounded to 0.1 mm."""
    joints = np.round(snippet.joints.astype(np.float64), 4)
    return _event(
        "snippet",
        {
            "start": snippet.start,
            "prompt": snippet.prompt,
            "text": snippet.text,
            "joints": joints.reshape(len(joints), -1).tolist(),
        },
    )
