"""Command line: prompts in, motion files out (``python -m t2m.sample --help``).

Examples::

    python -m t2m.sample --text "a person walks forward and waves"
    python -m t2m.sample --text-file prompts.txt --num-samples 3 --seconds 6 --bvh --out out/
    python -m t2m.sample --text "a person jumps" --precision int8 --render none

Writes into ``--out`` (default ``outputs/<timestamp>/``), per prompt NN and sample RR:
``sampleNN_repRR.npy`` (joints (T, 22, 3), metres, y-up, at the dataset's fps: 20 for HumanML3D), ``sampleNN_repRR_feats.npy``
(de-normalised features (T, 263)), ``sampleNN_repRR.mp4|gif`` unless ``--render none``,
``sampleNN_repRR.bvh`` with ``--bvh``, ``sampleNN_repRR.glb`` (animated glTF binary) with
``--glb``; plus ``results.npy`` (the MDM layout: a dict with
``motion`` (N, 22, 3, T_max), ``text``, ``lengths``, ``num_samples``, ``num_repetitions``; motion
``i = rep * num_samples + prompt``, padded past its length with its last pose) and
``results.json``. Everything is written into a hidden folder beside ``--out`` and renamed at the
end, so an error leaves nothing half-written; the hidden folder of a killed run is removed by the
next run into the same ``--out``. Every output folder holds ``.t2m-sample.json``, the list of the
files written there: ``--overwrite`` replaces only such a folder, and only while it holds nothing
else. Before generating, the memory and disk the request needs are estimated (``results.npy``
holds every motion) and a request that cannot fit is refused; motions with NaN or infinite values
are refused before anything is written. Exit status 2 with a one-line message on bad input.
"""

from __future__ import annotations

import logging
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

from dataset_tools.command import (
    CommandParser,
    UsageError,
    add_config_options,
    command,
    config_from_args,
    configure_logging,
    option,
)
from dataset_tools.spec import HUMANML3D, DatasetSpec
from t2m.config import check_seed
from t2m.options import OutputOptions
from t2m.outputs import sample_to_folder
from t2m.prompts import Prompt, read_prompt_file, with_lengths

logger = logging.getLogger("t2m.sample")


@dataclass
class SampleConfig(OutputOptions):
    """``python -m t2m.sample``: what to generate, from which checkpoints, into which folder."""

    text: str | None = None
    """one prompt, e.g. "a person walks forward and waves" (or --text-file)"""
    text_file: Path | None = field(default=None, metadata=option(metavar="FILE"))
    """prompts one a line; 'prompt#FRAMES' fixes that prompt's length"""
    num_samples: int = field(default=1, metadata=option(metavar="N"))
    """different motions per prompt"""
    length: int | None = field(default=None, metadata=option(metavar="FRAMES"))
    """frames (HumanML3D: at 20 fps, rounded to 4, clamped to 40..196; a KIT-ML model: 12.5 fps,
    24..196); default: drawn from the text2length model"""
    seconds: float | None = field(default=None, metadata=option(metavar="S"))
    """length in seconds instead of frames"""
    seed: int = 0
    """random seed: same seed, same bytes"""
    batch_size: int = field(default=32, metadata=option(metavar="N"))
    """motions generated together"""
    clean: bool = True
    """foot-contact clean-up: planted feet held still on the floor, legs fixed by IK
    (--no-clean: the model's raw output)"""
    plan: Literal["clauses", "whole"] = "clauses"
    """clauses: a prompt of several clauses ("jumps twice, then waves") is generated clause by
    clause, each with its share of the length; whole: the whole prompt in one pass (the paper)"""

    def __post_init__(self) -> None:
        if (self.text is None) == (self.text_file is None):
            raise UsageError("give one of --text and --text-file")
        if self.text is not None and not self.text.strip():
            raise UsageError("empty --text: give a sentence describing the motion")
        if self.length is not None and self.seconds is not None:
            raise UsageError("give one of --length and --seconds")
        if self.num_samples < 1 or self.batch_size < 1:
            raise UsageError("--num-samples and --batch-size must be at least 1")
        super().__post_init__()
        if self.text_file is not None and not self.text_file.is_file():
            raise UsageError(f"--text-file {self.text_file} is not a file")
        check_seed(self.seed)

    def prompts(self, spec: DatasetSpec = HUMANML3D) -> list[Prompt]:
        """The prompts with their lengths in frames of ``spec`` (the loaded models' dataset;
        None: drawn by the text2length model)."""
        prompts = [Prompt(self.text.strip())] if self.text else read_prompt_file(self.text_file)
        return with_lengths(prompts, spec, self.length, self.seconds)


@command(interrupted="interrupted; nothing was written")
def main(argv: list[str] | None = None) -> int:
    parser = CommandParser(
        prog="python -m t2m.sample",
        description="Generate 3D human motions from text with trained T2M checkpoints.",
    )
    add_config_options(parser, SampleConfig)
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    arguments = parser.parse_args(sys.argv[1:] if argv is None else argv)
    configure_logging(arguments.verbose)
    config = config_from_args(SampleConfig, arguments)
    # 1. everything the user gave, checked before any model is loaded (the lengths are made
    # again in frames of the models' dataset once they are)
    prompts = config.prompts()
    out = config.output_folder()
    # 2. the models
    pipe = config.load_pipeline(need_length_model=any(p.frames is None for p in prompts))
    try:
        pipe.prepare([p.text for p in prompts])  # refuses a prompt with no known word
    except ValueError as error:
        raise UsageError(str(error)) from None
    prompts = config.prompts(pipe.spec)
    # 3. generate and write
    sample_to_folder(
        pipe,
        prompts,
        out,
        num_samples=config.num_samples,
        seed=config.seed,
        batch_size=config.batch_size,
        render=config.render,
        bvh=config.bvh,
        glb=config.glb,
        overwrite=config.overwrite,
        extra_info={
            "checkpoints": str(config.checkpoints),
            "precision": config.precision,
            "batch_size": config.batch_size,
            "clean": config.clean,
            "plan": config.plan,
        },
        clean=config.clean,
        plan=config.plan,
    )
    logger.info("wrote %s", out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
