"""``python -m t2m.serve [--checkpoints DIR] [--host 127.0.0.1] [--port 8000]``: load the models
once and serve the web app until Ctrl-C."""

from __future__ import annotations

import logging
import math
import signal
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

from dataset_tools.command import CommandParser, UsageError, command, option, parse_config
from t2m.config import check_threads

logger = logging.getLogger("t2m.serve")


@dataclass
class ServeConfig:
    """``python -m t2m.serve``."""

    checkpoints: Path = field(default=Path("checkpoints/demo"), metadata=option(metavar="DIR"))
    """run folder with the length/ and generator/ stages, or the original T2M release's folder"""
    glove: Path | None = field(default=None, metadata=option(metavar="DIR"))
    """the release's GloVe subset (default: glove/ beside the release's checkpoints/)"""
    host: str = "127.0.0.1"
    """address to listen on; anything but a loopback address exposes the app to the network"""
    port: int = 8000
    """port to listen on (0: a free one)"""
    device: str = "auto"
    """auto, cpu, cuda or cuda:N (auto: CUDA when present)"""
    threads: int = field(default=0, metadata=option(metavar="N"))
    """torch CPU threads (0: torch's choice)"""
    keep_minutes: float = field(default=60.0, metadata=option(metavar="M"))
    """generated files are removed this long after their request"""
    max_disk_mb: float = field(default=1024.0, metadata=option(metavar="MIB"))
    """the generated files take at most this much; the oldest requests go first"""
    batch_motions: int = field(default=32, metadata=option(metavar="N"))
    """requests waiting together are generated in one batch of at most N motions (1: one
    request at a time)"""
    queue: int = field(default=16, metadata=option(metavar="N"))
    """requests waiting at most; more are answered 'busy' (HTTP 503)"""
    live_streams: int = field(default=8, metadata=option(metavar="N"))
    """live-mode streams at once (each a viewer's own generation thread, about 7 MB; one more
    is refused with a sentence, HTTP 503); 0 turns live mode off"""
    work_dir: Path | None = field(default=None, metadata=option(metavar="DIR"))
    """where the generated files go (default: a new temporary folder, removed on exit)"""
    log_level: Literal["info", "debug"] = "info"
    """debug also logs every HTTP request"""

    def __post_init__(self) -> None:
        if not 0 <= self.port <= 65535:
            raise UsageError(f"--port must be from 0 to 65535, got {self.port}")
        for name in ("keep_minutes", "max_disk_mb"):
            value = getattr(self, name)
            if not (0 < value < math.inf):
                raise UsageError(f"--{name.replace('_', '-')} must be positive, got {value}")
        if self.batch_motions < 1 or self.queue < 1:
            raise UsageError("--batch-motions and --queue must be at least 1")
        if not 0 <= self.live_streams <= 256:
            raise UsageError(f"--live-streams must be from 0 to 256, got {self.live_streams}")
        check_threads(self.threads)


def _stop_on_signals() -> None:
    """SIGINT and SIGTERM stop the server the same way (its generated files removed). Python
    leaves SIGINT ignored when it starts with it ignored, as a shell does for a command it
    starts in the background (``&``): ``kill -INT`` then did nothing and the server never
    stopped."""

    def stop(signum, frame):
        raise KeyboardInterrupt

    for signum in (signal.SIGINT, signal.SIGTERM):
        signal.signal(signum, stop)


@command
def main(argv: list[str] | None = None) -> int:
    from t2m.pipeline import TextToMotion
    from t2m.serve.server import is_loopback, make_server
    from t2m.train.runtime import inference_device

    parser = CommandParser(
        prog="python -m t2m.serve",
        description="Serve the local web app: type a sentence, watch the motions in 3D in the "
        "browser, download them.",
    )
    config = parse_config(parser, ServeConfig, argv)
    if config.log_level == "debug":
        logging.getLogger("t2m").setLevel(logging.DEBUG)
    if config.threads:
        import torch

        torch.set_num_threads(config.threads)
    # 1. the models, once (the text2length stage is optional: without it lengths must be given)
    device = inference_device(config.device, "fp32")
    try:
        pipe = TextToMotion.from_checkpoints(
            config.checkpoints, device=device, glove_dir=config.glove
        )
    except ValueError as first:
        try:
            pipe = TextToMotion.from_checkpoints(
                config.checkpoints, device=device, glove_dir=config.glove, need_length_model=False
            )
        except ValueError:
            raise UsageError(str(first)) from None
        logger.warning("%s; lengths must be given in the page", first)
    pipe.prepare(["a person walks"])  # load the tagger now, not on the first request
    # 2. the server
    if not is_loopback(config.host):
        logger.warning(
            "listening on %s: anyone who can reach this machine can use the app and read what it "
            "generates (use --host 127.0.0.1 to keep it local)",
            config.host,
        )
    try:
        server = make_server(
            pipe,
            str(config.checkpoints),
            host=config.host,
            port=config.port,
            work_dir=config.work_dir,
            keep_seconds=config.keep_minutes * 60,
            max_bytes=int(config.max_disk_mb * 2**20),
            max_batch_motions=config.batch_motions,
            max_queue=config.queue,
            live_streams=config.live_streams,
        )
    except OSError as error:
        raise UsageError(
            f"cannot listen on {config.host}:{config.port}: {error.strerror}"
        ) from None
    logger.info("serving %s on %s (Ctrl-C to stop)", config.checkpoints, server.url)
    _stop_on_signals()
    try:
        server.serve_forever()
    except KeyboardInterrupt:
        logger.info("stopping")
    finally:
        server.shutdown_app()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
