"""The web app's generated files: one folder per request under the server's work folder, named
by an unguessable token, written by the writers of :mod:`t2m.outputs`, removed after a set time
or when the folder grows past a set size.

* A request's id is ``secrets.token_urlsafe(16)`` (128 random bits): knowing one request's links
  tells nothing about another's. Nothing lists the ids; the page keeps its own history.
* A download names a file by (id, file name); both are matched against fixed patterns and the id
  must be a live request of this server before any path is made, so ``..``, slashes, absolute
  paths or another folder's names never reach the file system.
* The joints ``.npy`` of every motion and ``results.npy`` / ``results.json`` are written when the
  motions are made; BVH, glTF and the mp4 / gif animation on the first download (they take
  longer: BVH and glTF ~0.1 s, a video seconds), once, under the request's lock.
* Cleanup: requests older than ``keep_seconds`` are removed, then the oldest ones until the
  files take at most ``max_bytes`` (never the newest request, and never one still *held*: added
  with ``held=True`` by the server, whose answer has not been sent yet; :meth:`release` ends
  the hold). The server asks :meth:`ResultStore.full` before any work and refuses a request
  while held requests alone fill ``max_bytes``, rather than removing fresh results after.
"""

from __future__ import annotations

import logging
import re
import secrets
import shutil
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

from t2m.motion import GeneratedMotion
from t2m.outputs import motion_file_name, write_motion_file, write_summaries

logger = logging.getLogger(__name__)

ID_PATTERN = re.compile(r"[A-Za-z0-9_-]{22}")
FILE_PATTERN = re.compile(
    r"(?:sample(?P<prompt>\d{2})_rep(?P<sample>\d{2})\.(?P<kind>npy|bvh|glb|mp4|gif))"
    r"|results\.(?:npy|json)"
)
DOWNLOAD_KINDS = ("npy", "bvh", "glb", "mp4", "gif")
ROOM_WAIT_S = 5.0
"""How long a new request waits for held answers to go out when they fill the disk cap (they go
out moments after they are stored) before it is refused."""
ROOM_POLL_S = 0.02
CONTENT_TYPES = {
    ".npy": "application/octet-stream",
    ".bvh": "text/plain; charset=utf-8",
    ".glb": "model/gltf-binary",
    ".mp4": "video/mp4",
    ".gif": "image/gif",
    ".json": "application/json",
}


class Expired(LookupError):
    """The request's files were removed (too old, or the folder was full)."""


@dataclass
class StoredResult:
    """One request's motions and its folder."""

    id: str
    folder: Path
    motions: list[list[GeneratedMotion]]
    summary: dict
    prompts: list[dict] = field(default_factory=list)  # what the model made of each prompt
    created: float = field(default_factory=time.time)
    lock: threading.Lock = field(default_factory=threading.Lock)
    held: bool = False  # made for a request whose answer is not sent yet: never cleaned for size

    def size(self) -> int:
        return sum(p.stat().st_size for p in self.folder.iterdir() if p.is_file())


class ResultStore:
    """The work folder of the server and the requests whose files live there.

    Args:
        root: the folder (created); each request gets ``root/<id>/``.
        fps: frames per second of the motions (the models' dataset).
        keep_seconds: a request's files are removed this long after it was made.
        max_bytes: above this total, the oldest requests are removed first.
        remove_root: remove ``root`` itself on :meth:`close` (a folder made for the server).
        kinds: the per-motion downloads offered (BVH and glTF need the SMPL skeleton).
    """

    def __init__(
        self,
        root: Path,
        fps: float,
        keep_seconds: float,
        max_bytes: int,
        remove_root: bool = False,
        kinds: tuple[str, ...] = DOWNLOAD_KINDS,
    ) -> None:
        self.root = Path(root)
        self.root.mkdir(parents=True, exist_ok=True)
        self.remove_root = remove_root
        self.kinds = kinds
        self._closed = threading.Event()
        self.fps = fps
        self.keep_seconds = keep_seconds
        self.max_bytes = max_bytes
        self.room_wait_s = ROOM_WAIT_S
        self._results: dict[str, StoredResult] = {}
        self._expired: set[str] = set()
        self._lock = threading.Lock()

    def add(
        self, motions: list[list[GeneratedMotion]], seed: int, extra: dict, held: bool = False
    ) -> StoredResult:
        """Write the request's joints and summaries into a new folder; returns its record.
        ``held``: the size clean-up leaves it until :meth:`release` (its answer is not sent)."""
        request_id = secrets.token_urlsafe(16)
        folder = self.root / request_id
        folder.mkdir()
        files = [write_motion_file(m, folder, "npy", self.fps) for row in motions for m in row]
        summary = write_summaries(motions, folder, seed, self.fps, files, extra)
        result = StoredResult(request_id, folder, motions, summary, held=held)
        with self._lock:
            self._results[request_id] = result
        self.clean()
        return result

    def release(self, request_id: str) -> None:
        """End the hold of :meth:`add` (the request's answer was sent, or could not be)."""
        with self._lock:
            result = self._results.get(request_id)
            if result is not None:
                result.held = False

    def full(self) -> bool:
        """Whether requests still held fill ``max_bytes`` by themselves: the clean-up could make
        no room, so new work is refused until their answers go out."""
        with self._lock:
            held = [r for r in self._results.values() if r.held]
        return sum(r.size() for r in held) >= self.max_bytes

    def wait_for_room(self) -> bool:
        """Whether the store has room (:meth:`full` false) within :attr:`room_wait_s`: a held
        request's answer goes out moments after it is stored, so a request that arrives in
        between waits for that instead of being refused."""
        deadline = time.monotonic() + self.room_wait_s
        while self.full():
            left = deadline - time.monotonic()
            if left <= 0 or self._closed.wait(min(ROOM_POLL_S, left)):
                return False
        return True

    def get(self, request_id: str) -> StoredResult:
        """The live request ``request_id``; KeyError when unknown, Expired when removed."""
        if not ID_PATTERN.fullmatch(request_id):
            raise KeyError(request_id)
        with self._lock:
            if request_id in self._expired:
                raise Expired(request_id)
            result = self._results[request_id]
        if time.time() - result.created > self.keep_seconds:  # before the next cleaning round
            self.clean()
            raise Expired(request_id)
        return result

    def file(self, request_id: str, name: str) -> Path:
        """The path of a download, written first if it is made on demand. KeyError for an
        unknown id or a file name that is not one of the request's; Expired when removed."""
        result = self.get(request_id)
        match = FILE_PATTERN.fullmatch(name)
        if match is None:
            raise KeyError(name)
        if match["kind"] is None:  # results.npy / results.json
            return self._existing(result, name)
        prompt, sample = int(match["prompt"]), int(match["sample"])
        if prompt >= len(result.motions) or sample >= len(result.motions[prompt]):
            raise KeyError(name)
        kind = match["kind"]
        if kind not in self.kinds:
            raise KeyError(name)
        with result.lock:
            path = result.folder / motion_file_name(prompt, sample, kind)
            if not path.exists():
                if not result.folder.is_dir():
                    raise Expired(request_id)
                write_motion_file(result.motions[prompt][sample], result.folder, kind, self.fps)
        self.clean()
        return self._existing(result, path.name)

    def _existing(self, result: StoredResult, name: str) -> Path:
        path = result.folder / name
        if not path.is_file():
            raise Expired(result.id)
        return path

    def clean(self) -> list[str]:
        """Remove requests past their time, then the oldest while the files take more than
        ``max_bytes`` (the newest request and held ones stay); returns the removed ids."""
        now = time.time()
        removed = []
        with self._lock:
            ordered = sorted(self._results.values(), key=lambda r: r.created)
            sizes = {r.id: r.size() for r in ordered}
            total = sum(sizes.values())
            for result in ordered:
                too_old = now - result.created > self.keep_seconds
                too_big = total > self.max_bytes and not (result.held or result is ordered[-1])
                if not (too_old or too_big):
                    continue
                total -= sizes[result.id]
                del self._results[result.id]
                self._expired.add(result.id)
                removed.append(result)
        for result in removed:
            with result.lock:  # not while a download of it is being written
                shutil.rmtree(result.folder, ignore_errors=True)
            logger.info("removed the files of request %s", result.id[:6])
        return [r.id for r in removed]

    def clean_every(self, seconds: float) -> threading.Thread:
        """Start a thread that runs :meth:`clean` every ``seconds`` until :meth:`close`."""

        def run() -> None:
            while not self._closed.wait(seconds):
                self.clean()

        thread = threading.Thread(target=run, name="t2m-serve-cleanup", daemon=True)
        thread.start()
        return thread

    def close(self) -> None:
        """Remove every request's files, and the work folder when it is ours (the server
        stops)."""
        self._closed.set()
        with self._lock:
            results = list(self._results.values())
            self._results.clear()
        for result in results:
            shutil.rmtree(result.folder, ignore_errors=True)
        if self.remove_root:
            shutil.rmtree(self.root, ignore_errors=True)
