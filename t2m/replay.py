"""``python -m t2m.replay --timeline FILE --seed S``: make a live stream's motion again, frame for
frame, from its timeline (the web app's live ``timeline.txt`` download, or
:meth:`t2m.live.LiveStream.timeline`) and its seed (:func:`t2m.live.replay`), and write what
``python -m t2m.sample`` writes: ``sample00_rep00.npy`` (joints), ``_feats.npy``, the animation,
``--bvh`` / ``--glb``, ``results.npy`` / ``results.json``.

The frames are the stream's on the same machine, checkpoints and precision (the stream runs on
the web server's device and precision, float32 by default).
"""

from __future__ import annotations

import logging
import sys
from dataclasses import dataclass, field
from pathlib import Path

from dataset_tools.command import (
    CommandParser,
    UsageError,
    add_config_options,
    command,
    config_from_args,
    configure_logging,
    option,
)
from t2m.options import OutputOptions
from t2m.outputs import Render

logger = logging.getLogger(__name__)


@dataclass
class ReplayConfig(OutputOptions):
    """``python -m t2m.replay``."""

    timeline: Path | None = field(default=None, metadata=option(metavar="FILE"))
    """the live stream's prompts: lines text#start#end (seconds), as the web app's live mode
    downloads them (required)"""
    seed: int = 0
    """the live stream's seed (the web app names its download live_seed<S>.txt)"""
    render: Render = "none"
    """stick-figure animation format, or none"""

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.timeline is None:
            raise UsageError("give the live stream's timeline: --timeline FILE")


@command
def main(argv: list[str] | None = None) -> int:
    from t2m.edit.modes import read_timeline
    from t2m.live import UNSIZED_SECONDS, replay
    from t2m.motion import GeneratedMotion
    from t2m.outputs import write_motions

    parser = CommandParser(
        prog="python -m t2m.replay",
        description="Make a live stream's motion again from its timeline and seed, and write "
        "it as python -m t2m.sample does.",
    )
    add_config_options(parser, ReplayConfig)
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    arguments = parser.parse_args(sys.argv[1:] if argv is None else argv)
    configure_logging(arguments.verbose)
    config = config_from_args(ReplayConfig, arguments)
    # 1. the timeline and the folder, checked before any model is loaded
    from dataset_tools.spec import HUMANML3D

    read_timeline(config.timeline, HUMANML3D)
    out = config.output_folder()
    # 2. the models, then the timeline again in frames of their dataset
    try:  # the stream drew its segments' lengths with the text2length model when it had one
        pipe = config.load_pipeline(need_length_model=True)
    except UsageError as error:
        pipe = config.load_pipeline(need_length_model=False)
        logger.warning("%s; segments last %g s, as the stream's did", error, UNSIZED_SECONDS)
    segments = read_timeline(config.timeline, pipe.spec)
    logging.getLogger("t2m.edit").setLevel(logging.WARNING)  # one line per segment otherwise

    def make() -> list[list[GeneratedMotion]]:
        try:
            stream = replay(pipe, config.timeline, config.seed)
        except ValueError as error:  # a prompt with no known word
            raise UsageError(str(error)) from None
        text = " / ".join(prompt.text for prompt in stream.prompts)
        return [[GeneratedMotion(text, 0, 0, stream.joints(), stream.features())]]

    # 3. make and write
    write_motions(
        make,
        pipe.spec,
        out,
        frames=[segments[-1].stop],
        seed=config.seed,
        **config.file_options(),
        extra_info={
            "checkpoints": str(config.checkpoints),
            "precision": config.precision,
            "timeline": [
                f"{s.text}#{s.start / pipe.spec.fps:g}#{s.stop / pipe.spec.fps:g}" for s in segments
            ],
        },
    )
    logger.info("wrote %s", out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
