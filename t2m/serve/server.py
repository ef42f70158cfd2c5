"""The HTTP server of the web app: Python's standard ``http.server`` (ThreadingHTTPServer).

Why the standard library: the app has seven routes, JSON in and out, static files and downloads;
its one heavy part (the models) runs on one worker thread either way, so a framework would add
an install and an event loop and remove almost nothing from this file. Each connection gets a
thread; generate requests wait on the :class:`t2m.serve.worker.GenerationWorker` queue.

Routes (the README documents them):

    GET  /                          the page (static/index.html)
    GET  /static/<file>             the page's script and style (a fixed list of files)
    GET  /api/info                  the model, skeleton, limits, precisions, editing support
    POST /api/generate              prompts -> motions (joints) and download links
    GET  /api/results/<id>          a request's answer again (the page's history)
    GET  /api/files/<id>/<name>     a download: sampleNN_repRR.npy|bvh|glb|mp4|gif, results.npy|json
    POST /api/edit                  edit an uploaded motion (t2m.serve.editing)

Requests whose Host header is not this machine's loopback name are refused while the server is
bound to a loopback address (a web page elsewhere cannot reach it through DNS rebinding).
"""

from __future__ import annotations

import ipaddress
import json
import logging
import queue
import secrets
import shutil
import threading
import time
from dataclasses import dataclass
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
from t2m.serve.results import CONTENT_TYPES, DOWNLOAD_KINDS, Expired, ResultStore
from t2m.serve.worker import GenerationJob, GenerationWorker

logger = logging.getLogger("t2m.serve")

STATIC = Path(__file__).resolve().parent / "static"
STATIC_FILES = {
    "index.html": "text/html; charset=utf-8",
    "style.css": "text/css; charset=utf-8",
    "app.js": "text/javascript; charset=utf-8",
    "viewer.js": "text/javascript; charset=utf-8",
    "edit.js": "text/javascript; charset=utf-8",
}
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

    def __post_init__(self) -> None:
        self.boot = self.boot or secrets.token_urlsafe(8)

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
        }

    def generate(self, payload: object) -> dict:
        """POST /api/generate: check, queue, wait, store, answer."""
        started = time.perf_counter()
        request = api.parse_generate(
            payload,
            self.pipe.spec,
            self.pipe.length_model is not None,
            self.limits,
            self.pipe.device.type,
        )
        job = GenerationJob(
            texts=[p.text for p in request.prompts],
            frames=[p.frames for p in request.prompts],
            num_samples=request.samples,
            seed=request.seed,
            precision=request.precision,
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
        extra = {"precision": request.precision, "checkpoints": Path(self.checkpoints).name}
        stored = self.store.add(motions, request.seed, extra)
        stored.prompts = [
            api.prompt_json(item, prompt.frames) for item, prompt in zip(prepared, request.prompts)
        ]
        answer = self.answer(stored.id)
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
    timeout = 60  # seconds a connection may sit idle or trickle (each holds a thread)
    app: App  # set on the subclass made by make_server

    def log_message(self, format: str, *args) -> None:  # noqa: A002 (the base class's name)
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
        name = urlsplit(f"//{host}").hostname or ""
        return name in LOOPBACK_NAMES or is_loopback(name)

    def _route(self, method: str) -> None:
        if not self._host_allowed():
            self._error(HTTPStatus.FORBIDDEN, "this server answers requests to localhost only")
            return
        path = urlsplit(self.path).path
        parts = path.strip("/").split("/")
        try:
            if method == "GET" and path in ("/", "/index.html"):
                self._static("index.html")
            elif method == "GET" and path == "/favicon.ico":  # none: say so without an error
                self._send(HTTPStatus.NO_CONTENT, b"", "image/x-icon")
            elif method == "GET" and len(parts) == 2 and parts[0] == "static":
                self._static(parts[1])
            elif method == "GET" and path == "/api/info":
                self._json(HTTPStatus.OK, self.app.info())
            elif method == "POST" and path == "/api/generate":
                self._json(HTTPStatus.OK, self.app.generate(self._read_json()))
            elif method == "POST" and path == "/api/edit":
                limit = self.app.limits.max_edit_body_bytes
                self._json(HTTPStatus.OK, edit(self.app, self._read_json(limit)))
            elif method == "GET" and len(parts) == 3 and parts[:2] == ["api", "results"]:
                self._json(HTTPStatus.OK, self.app.answer(parts[2]))
            elif method == "GET" and len(parts) == 4 and parts[:2] == ["api", "files"]:
                path = self.app.store.file(parts[2], parts[3])
                self._file(path, CONTENT_TYPES[path.suffix], download_name=path.name)
            elif path in ("/api/generate", "/api/edit"):
                self._error(HTTPStatus.METHOD_NOT_ALLOWED, f"{path} takes POST")
            else:
                self._error(HTTPStatus.NOT_FOUND, f"no such page or file: {path[:100]}")
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

    def _static(self, name: str) -> None:
        if name not in STATIC_FILES:
            raise KeyError(name)
        self._file(STATIC / name, STATIC_FILES[name])

    def _read_json(self, limit: int | None = None) -> object:
        limit = limit or self.app.limits.max_body_bytes
        length = self.headers.get("Content-Length")
        if length is None or not length.isdigit():
            raise UsageError("the request needs a Content-Length")
        if int(length) > limit:
            raise UsageError(f"the request is {int(length)} bytes; at most {limit}")
        content_type = self.headers.get("Content-Type", "").split(";")[0].strip()
        if content_type != "application/json":
            raise UsageError("send the request as JSON (Content-Type: application/json)")
        body = self.rfile.read(int(length))
        try:
            return json.loads(body.decode("utf-8"))
        except (UnicodeDecodeError, ValueError):
            raise UsageError("the request body is not valid JSON") from None

    def do_GET(self) -> None:  # noqa: N802 (http.server's names)
        self._route("GET")

    def do_HEAD(self) -> None:  # noqa: N802
        self._route("GET")

    def do_POST(self) -> None:  # noqa: N802
        self._route("POST")


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
) -> Server:
    """A server bound to (host, port) (port 0: a free one; ``server.url``), not yet serving:
    call ``serve_forever()`` (in a thread) and ``shutdown_app()``. ``work_dir``: where the
    generated files go (default: a new temporary folder)."""
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
