"""The HTTP server of the web app: Python's standard ``http.server`` (ThreadingHTTPServer).

Why the standard library: the app has seven routes, JSON in and out, static files and downloads;
its one heavy part (the models) runs on one worker thread either way, so a framework would add
an install and an event loop and remove almost nothing from this file. Each connection gets a
thread; generate requests wait on the :class:`t2m.serve.worker.GenerationWorker` queue.

Routes (the table :data:`ROUTES` below the request handler; docs/webapp.md documents them):

    GET  /  and  /index.html        the page (static/index.html)
    GET  /favicon.ico               204: the page has no icon
    GET  /static/<name>             the page's ES modules and style (the fixed list STATIC_FILES)
    GET  /api/info                  the model, skeleton, limits, precisions, editing support
    POST /api/generate              prompts -> motions (joints) and download links
    POST /api/edit                  edit an uploaded or generated motion (t2m.serve.editing)
    GET  /api/results/<id>          a request's answer again (the page's history)
    GET  /api/files/<id>/<name>     a download: sampleNN_repRR.npy|bvh|glb|mp4|gif, results.npy|json
    POST /api/live                  start a live stream (t2m.serve.live; docs/live.md)
    GET  /api/live/<id>/events      its frames as server-sent events (one long-lived connection)
    POST /api/live/<id>/prompt      a new prompt for it
    POST /api/live/<id>/close       end it
    GET  /api/live/<id>/<name>      timeline.txt, motion.npy|bvh|glb: the live motion so far

HEAD is GET without the body. A path that only takes POST answers other methods with 405; any
other unmatched request is 404. Errors are JSON ``{"error": sentence}``: 400 for bad input, 404
for no such request or file, 410 for removed files, 503 when busy, 500 with the reason.

Requests whose Host header is not this machine's loopback name are refused while the server is
bound to a loopback address (a web page elsewhere cannot reach it through DNS rebinding).
"""

from __future__ import annotations

import ipaddress
import json
import logging
import queue
import re
import secrets
import shutil
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from http import HTTPStatus
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from urllib.parse import quote, urlsplit

from dataset_tools.command import UsageError
from dataset_tools.skeleton import skeleton_for
from dataset_tools.viz import RenderConfig, _chain_side  # the renderings' colours and sides
from t2m.pipeline import TextToMotion, offered_precisions
from t2m.serve import api
from t2m.serve.editing import edit, edit_info
from t2m.serve.live import WRITE_TIMEOUT_S, LiveHub
from t2m.serve.results import CONTENT_TYPES, DOWNLOAD_KINDS, Expired, ResultStore
from t2m.serve.worker import GenerationJob, GenerationWorker

logger = logging.getLogger("t2m.serve")

STATIC = Path(__file__).resolve().parent / "static"
STATIC_TYPES = {
    ".html": "text/html; charset=utf-8",
    ".css": "text/css; charset=utf-8",
    ".js": "text/javascript; charset=utf-8",  # ES modules load only with a JavaScript type
}
STATIC_FILES = {
    name: STATIC_TYPES[Path(name).suffix]
    for name in (
        "index.html",
        "style.css",
        "app.js",  # the page's entry module; it imports the others
        "api.js",
        "dom.js",
        "edit.js",
        "live.js",
        "player.js",
        "viewer.js",
    )
}
"""the files served under /static/ and their content types; nothing else in the folder is"""
LOOPBACK_NAMES = {"localhost", "127.0.0.1", "::1", "[::1]"}
SECURITY_HEADERS = {
    "X-Content-Type-Options": "nosniff",
    "Content-Security-Policy": "default-src 'self'; img-src 'self' data:; object-src 'none'",
    "Referrer-Policy": "no-referrer",
    "X-Frame-Options": "DENY",
}


def is_loopback(host: str) -> bool:
    """Whether ``host`` (a name or address) is this machine's loopback only."""
    if host.strip("[]").lower() == "localhost":
        return True
    try:
        return ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:
        return False


@dataclass
class App:
    """Everything the handlers share: the models' worker, the files, the limits."""

    pipe: TextToMotion
    worker: GenerationWorker
    store: ResultStore
    limits: api.Limits
    checkpoints: str
    loopback_only: bool
    generate_timeout: float = 600.0
    boot: str = ""
    live: LiveHub | None = None

    def __post_init__(self) -> None:
        self.boot = self.boot or secrets.token_urlsafe(8)
        self.live = self.live or LiveHub(self.pipe)

    def info(self) -> dict:
        """GET /api/info."""
        spec = self.pipe.spec
        skeleton = skeleton_for(spec.num_joints)
        colors = RenderConfig()
        sides = [_chain_side(chain, skeleton) for chain in skeleton.chains]

        return {
            "boot": self.boot,
            "checkpoints": Path(self.checkpoints).name,
            "dataset": spec.name,
            "fps": spec.fps,
            "min_frames": spec.min_frames,
            "max_frames": spec.max_frames,
            "snippet_frames": spec.snippet_length,
            "automatic_length": self.pipe.length_model is not None,
            "precisions": offered_precisions(self.pipe.device),
            "downloads": list(self.store.kinds),
            "skeleton": {
                "joint_names": list(skeleton.joint_names),
                "parents": list(skeleton.parents),
                "chains": [list(c) for c in skeleton.chains],
                "sides": sides,
                "colors": {
                    "left": colors.left_color,
                    "right": colors.right_color,
                    "center": colors.center_color,
                },
            },
            "limits": api.limits_json(self.limits),
            "edit": edit_info(),
            "live": self.live.info(),
        }

    def generate(self, payload: object) -> dict:
        """POST /api/generate: check, queue, wait, store, answer."""
        started = time.perf_counter()
        checked = api.parse_generate(
            payload,
            self.pipe.spec,
            self.pipe.length_model is not None,
            self.limits,
            self.pipe.device.type,
        )
        if not self.store.wait_for_room():
            raise api.Busy(api.RESULTS_FULL)
        job = GenerationJob(
            texts=[p.text for p in checked.prompts],
            frames=[p.frames for p in checked.prompts],
            num_samples=checked.request.num_samples,
            seed=checked.request.seed,
            precision=checked.precision,
        )
        try:
            self.worker.submit(job)
        except queue.Full:
            raise api.Busy(
                "the server is busy with other requests; try again in a moment"
            ) from None
        if not job.done.wait(self.generate_timeout):
            raise api.Busy("generation took too long; try fewer motions")
        if job.error is not None:
            if isinstance(job.error, ValueError):
                raise UsageError(str(job.error)) from None
            raise job.error
        motions, prepared = job.result
        generated = time.perf_counter()
        extra = {"precision": checked.precision, "checkpoints": Path(self.checkpoints).name}
        stored = self.store.add(motions, checked.request.seed, extra, held=True)
        stored.prompts = [
            api.prompt_json(item, prompt.frames) for item, prompt in zip(prepared, checked.prompts)
        ]
        try:
            answer = self.answer(stored.id)
        except BaseException:
            self.store.release(stored.id)
            raise
        answer["timing"] = {
            "queued_and_generated_s": round(generated - started, 4),
            "total_s": round(time.perf_counter() - started, 4),
        }
        return answer

    def answer(self, request_id: str) -> dict:
        """A stored request as the generate answer (joints and links); GET /api/results/<id>."""
        stored = self.store.get(request_id)
        base = f"/api/files/{request_id}"
        motions = []
        for row in stored.motions:
            for motion in row:
                name = f"sample{motion.prompt_index:02d}_rep{motion.repetition:02d}"
                links = {kind: f"{base}/{name}.{kind}" for kind in self.store.kinds}
                motions.append(api.motion_json(motion, links))
        return {
            "id": request_id,
            "created": stored.created,
            "fps": self.pipe.spec.fps,
            "seed": stored.summary["seed"],
            "precision": stored.summary.get("precision"),
            "samples": stored.summary["num_samples"],
            "texts": stored.summary["texts"],
            "prompts": stored.prompts,
            "motions": motions,
            "files": {name: f"{base}/{name}" for name in ("results.npy", "results.json")},
        }


class Handler(BaseHTTPRequestHandler):
    server_version = "t2m-serve"
    # a request line without a version (HTTP/0.9, or malformed) is answered with a status line and
    # headers too: an HTTP/0.9 answer is a bare body, without the security headers
    default_request_version = "HTTP/1.0"
    timeout = 60  # seconds a connection may sit idle or trickle (each holds a thread)
    app: App  # set on the subclass made by make_server

    def log_message(self, format: str, *args) -> None:  # "format": the base class's name
        logger.debug("%s %s", self.address_string(), format % args)

    # -- answers -----------------------------------------------------------------------------

    def _send(self, status: int, body: bytes, content_type: str, extra: dict | None = None):
        self.send_response(status)
        self.send_header("Content-Type", content_type)
        self.send_header("Content-Length", str(len(body)))
        self.send_header("Cache-Control", "no-store")
        for key, value in {**SECURITY_HEADERS, **(extra or {})}.items():
            self.send_header(key, value)
        self.end_headers()
        if self.command != "HEAD":
            self.wfile.write(body)

    def _json(self, status: int, data: dict) -> None:
        body = json.dumps(data, separators=(",", ":"), allow_nan=False).encode("utf-8")
        self._send(status, body, "application/json")

    def _error(self, status: int, message: str) -> None:
        self._json(status, {"error": message})

    def _file(self, path: Path, content_type: str, download_name: str | None = None) -> None:
        extra = {}
        if download_name:
            extra["Content-Disposition"] = f"attachment; filename*=UTF-8''{quote(download_name)}"
        size = path.stat().st_size
        self.send_response(HTTPStatus.OK)
        self.send_header("Content-Type", content_type)
        self.send_header("Content-Length", str(size))
        self.send_header("Cache-Control", "no-store")
        for key, value in {**SECURITY_HEADERS, **extra}.items():
            self.send_header(key, value)
        self.end_headers()
        if self.command != "HEAD":
            with open(path, "rb") as handle:
                shutil.copyfileobj(handle, self.wfile)

    # -- routing -----------------------------------------------------------------------------

    def _host_allowed(self) -> bool:
        if not self.app.loopback_only:
            return True
        host = self.headers.get("Host", "")
        try:
            name = urlsplit(f"//{host}").hostname or ""
        except ValueError:  # "[::1" and other names no URL has
            return False
        return name in LOOPBACK_NAMES or is_loopback(name)

    def _route(self, method: str) -> None:
        if (
            len(self.headers.get_all("Host", [])) > 1
        ):  # which one a proxy or the page meant is unknown
            self._error(HTTPStatus.BAD_REQUEST, "the request has more than one Host header")
            return
        if not self._host_allowed():
            self._error(HTTPStatus.FORBIDDEN, "this server answers requests to localhost only")
            return
        path = urlsplit(self.path).path
        try:
            route, params = find_route(method, path)
            if route is None:
                self._unrouted(path)
            else:
                route.handler(self, **params)
        except UsageError as error:
            self._error(HTTPStatus.BAD_REQUEST, str(error))
        except Expired:
            self._error(
                HTTPStatus.GONE,
                "these files were removed (requests are kept for a limited time); generate again",
            )
        except KeyError:
            self._error(HTTPStatus.NOT_FOUND, "no such request or file")
        except api.Busy as error:
            self._error(HTTPStatus.SERVICE_UNAVAILABLE, str(error))
        except (BrokenPipeError, ConnectionResetError):
            pass
        except Exception as error:  # the page hears a sentence; the log has the trace
            logger.exception("request %s %s failed", method, path)
            self._error(HTTPStatus.INTERNAL_SERVER_ERROR, f"the server failed: {error}")

    def _unrouted(self, path: str) -> None:
        methods = {route.method for route in ROUTES if route.pattern.fullmatch(path)}
        if methods == {"POST"}:
            self._error(HTTPStatus.METHOD_NOT_ALLOWED, f"{path} takes POST")
        else:
            self._error(HTTPStatus.NOT_FOUND, f"no such page or file: {path[:100]}")

    # -- the routes' handlers (the table ROUTES below says which answers what) ----------------

    def get_page(self) -> None:
        self.get_static("index.html")

    def get_no_icon(self) -> None:
        self._send(HTTPStatus.NO_CONTENT, b"", "image/x-icon")

    def get_static(self, name: str) -> None:
        if name not in STATIC_FILES:
            raise KeyError(name)
        self._file(STATIC / name, STATIC_FILES[name])

    def get_info(self) -> None:
        self._json(HTTPStatus.OK, self.app.info())

    def post_generate(self) -> None:
        self._answer_held(self.app.generate(self._read_json()))

    def post_edit(self) -> None:
        payload = self._read_json(self.app.limits.max_edit_body_bytes)
        self._answer_held(edit(self.app, payload))

    def _answer_held(self, answer: dict) -> None:
        """Send the answer of a request whose files are held in the store, then release them
        to the clean-up (sent or not: a client that left does not hold the disk)."""
        try:
            self._json(HTTPStatus.OK, answer)
        finally:
            self.app.store.release(answer["id"])

    def post_live_open(self) -> None:
        self._json(HTTPStatus.OK, self.app.live.open(self._read_json(), self.app.limits))

    def post_live_prompt(self, session: str) -> None:
        self._json(HTTPStatus.OK, self.app.live.prompt(session, self._read_json()))

    def post_live_close(self, session: str) -> None:
        self.app.live.close(session)
        self._json(HTTPStatus.OK, {"closed": session})

    def get_live_events(self, session: str) -> None:
        """Server-sent events until the stream ends or the viewer goes (t2m.serve.live)."""
        if self.command == "HEAD":  # the headers only: no viewer attaches
            self.app.live.get(session)
        else:
            live = self.app.live.attach(session)  # 404 (or 400) before any header
        self.close_connection = True
        self.send_response(HTTPStatus.OK)
        self.send_header("Content-Type", "text/event-stream; charset=utf-8")
        self.send_header("Cache-Control", "no-store")
        self.send_header("Connection", "close")
        for key, value in SECURITY_HEADERS.items():
            self.send_header(key, value)
        self.end_headers()
        if self.command == "HEAD":
            return
        self.connection.settimeout(WRITE_TIMEOUT_S)

        def write(data: bytes) -> None:
            self.wfile.write(data)
            self.wfile.flush()

        self.app.live.run_events(live, write)

    def get_live_download(self, session: str, name: str) -> None:
        body, content_type, filename = self.app.live.download(session, name)
        extra = {"Content-Disposition": f"attachment; filename*=UTF-8''{quote(filename)}"}
        self._send(HTTPStatus.OK, body, content_type, extra)

    def get_result(self, request_id: str) -> None:
        self._json(HTTPStatus.OK, self.app.answer(request_id))

    def get_download(self, request_id: str, name: str) -> None:
        path = self.app.store.file(request_id, name)
        self._file(path, CONTENT_TYPES[path.suffix], download_name=path.name)

    def _read_json(self, limit: int | None = None) -> object:
        limit = limit or self.app.limits.max_body_bytes
        length = self.headers.get("Content-Length")
        if length is None or not (length.isascii() and length.isdigit()):  # not '²' nor '١٢'
            raise UsageError("the request needs a Content-Length (a number of bytes in 0-9)")
        if len(length) > 15 or int(length) > limit:  # 5,000 digits are no int() for Python
            raise UsageError(f"the request is {length[:15]} bytes; at most {limit}")
        content_type = self.headers.get("Content-Type", "").split(";")[0].strip()
        if content_type != "application/json":
            raise UsageError("send the request as JSON (Content-Type: application/json)")
        body = self.rfile.read(int(length))
        try:
            text = body.decode("utf-8")
        except UnicodeDecodeError:
            raise UsageError("the request body is not valid JSON (UTF-8)") from None
        return api.read_json(text)

    def send_error(self, code: int, message: str | None = None, explain: str | None = None):
        """http.server's own errors (a malformed request line or header, an unsupported method,
        a request line too long) as this server's: JSON with the security headers; the
        connection closes, since what follows the bad request cannot be trusted."""
        self.close_connection = True
        try:
            short, _ = self.responses[code]
        except KeyError:
            short = "error"
        if code == HTTPStatus.NOT_IMPLEMENTED and self.command:
            message = f"{self.command[:20]} is not a method of this server (GET, HEAD, POST)"
        message = " ".join((message or short).split())[:200]  # one line
        self.log_error("code %d, message %s", code, message)
        body = json.dumps({"error": message}, separators=(",", ":")).encode("utf-8")
        self.send_response(code)
        self.send_header("Content-Type", "application/json")
        self.send_header("Content-Length", str(len(body)))
        self.send_header("Cache-Control", "no-store")
        self.send_header("Connection", "close")
        for key, value in SECURITY_HEADERS.items():
            self.send_header(key, value)
        self.end_headers()
        if self.command != "HEAD" and code >= 200 and code not in (204, 304):
            self.wfile.write(body)

    def do_GET(self) -> None:  # http.server's names
        self._route("GET")

    def do_HEAD(self) -> None:
        self._route("HEAD")

    def do_POST(self) -> None:
        self._route("POST")


@dataclass(frozen=True)
class Route:
    """One row of the route table: ``method`` on ``path`` is answered by ``handler``; a
    ``<name>`` in the path matches one non-empty segment and reaches the handler as ``name``."""

    method: str
    path: str
    handler: Callable[..., None]
    pattern: re.Pattern = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        parts = re.split(r"<(\w+)>", self.path)  # literal, name, literal, name, ..., literal
        regex = "".join(
            re.escape(part) if index % 2 == 0 else f"(?P<{part}>[^/]+)"
            for index, part in enumerate(parts)
        )
        object.__setattr__(self, "pattern", re.compile(regex))


ROUTES: tuple[Route, ...] = (
    Route("GET", "/", Handler.get_page),
    Route("GET", "/index.html", Handler.get_page),
    Route("GET", "/favicon.ico", Handler.get_no_icon),
    Route("GET", "/static/<name>", Handler.get_static),
    Route("GET", "/api/info", Handler.get_info),
    Route("POST", "/api/generate", Handler.post_generate),
    Route("POST", "/api/edit", Handler.post_edit),
    Route("GET", "/api/results/<request_id>", Handler.get_result),
    Route("GET", "/api/files/<request_id>/<name>", Handler.get_download),
    Route("POST", "/api/live", Handler.post_live_open),
    Route("GET", "/api/live/<session>/events", Handler.get_live_events),
    Route("POST", "/api/live/<session>/prompt", Handler.post_live_prompt),
    Route("POST", "/api/live/<session>/close", Handler.post_live_close),
    Route("GET", "/api/live/<session>/<name>", Handler.get_live_download),
)
"""method + path -> handler, in the order they are tried"""


def find_route(method: str, path: str) -> tuple[Route | None, dict[str, str]]:
    """The route answering ``method`` (HEAD as GET) on ``path`` and its path parameters, or
    ``(None, {})``."""
    method = "GET" if method == "HEAD" else method
    for route in ROUTES:
        if route.method == method:
            match = route.pattern.fullmatch(path)
            if match:
                return route, match.groupdict()
    return None, {}


class Server(ThreadingHTTPServer):
    daemon_threads = True
    app: App

    @property
    def url(self) -> str:
        host, port = self.server_address[:2]
        shown = "127.0.0.1" if host in ("0.0.0.0", "") else host
        return f"http://{'[' + shown + ']' if ':' in shown else shown}:{port}/"

    def start_in_thread(self) -> threading.Thread:
        """Serve from a daemon thread (tests, notebooks); stop with :meth:`shutdown_app`."""
        thread = threading.Thread(target=self.serve_forever, name="t2m-serve", daemon=True)
        thread.start()
        return thread

    def shutdown_app(self) -> None:
        """Stop serving, stop the worker and remove the generated files."""
        self.shutdown()
        self.server_close()
        self.app.live.close_all()
        self.app.worker.stop()
        self.app.store.close()


def make_server(
    pipe: TextToMotion,
    checkpoints: str,
    host: str = "127.0.0.1",
    port: int = 8000,
    work_dir: Path | None = None,
    keep_seconds: float = 3600.0,
    max_bytes: int = 2**30,
    max_batch_motions: int = 32,
    max_queue: int = 16,
    limits: api.Limits | None = None,
    live_streams: int = 8,
) -> Server:
    """A server bound to (host, port) (port 0: a free one; ``server.url``), not yet serving:
    call ``serve_forever()`` (in a thread) and ``shutdown_app()``. ``work_dir``: where the
    generated files go (default: a new temporary folder). ``live_streams``: live-mode streams
    at once (:mod:`t2m.serve.live`)."""
    import tempfile

    limits = limits or api.Limits()
    own_folder = work_dir is None
    if own_folder:
        work_dir = Path(tempfile.mkdtemp(prefix="t2m-serve-"))
    # BVH and glTF are written for the 22-joint SMPL skeleton only
    kinds = DOWNLOAD_KINDS if pipe.spec.num_joints == 22 else ("npy", "mp4", "gif")
    store = ResultStore(work_dir, pipe.spec.fps, keep_seconds, max_bytes, own_folder, kinds)
    worker = GenerationWorker(pipe, max_batch_motions=max_batch_motions, max_queue=max_queue)
    app = App(pipe, worker, store, limits, str(checkpoints), loopback_only=is_loopback(host))
    app.live = LiveHub(pipe, max_streams=live_streams)
    handler = type("BoundHandler", (Handler,), {"app": app})
    family_host = host.strip("[]")
    server_class = Server
    if ":" in family_host:
        import socket

        server_class = type("Server6", (Server,), {"address_family": socket.AF_INET6})
    server = server_class((family_host, port), handler)
    server.app = app
    store.clean_every(min(30.0, keep_seconds / 4))
    return server
