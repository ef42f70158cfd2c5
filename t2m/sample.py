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
from dataclasses import dataclass

from dataset_tools.command import (
    CommandParser,
    UsageError,
    add_config_options,
    command,
    config_from_args,
    configure_logging,
)
from t2m.options import OutputOptions
from t2m.outputs import sample_to_folder
from t2m.request import GenerationRequest

logger = logging.getLogger("t2m.sample")


@dataclass
class SampleConfig(GenerationRequest, OutputOptions):
    """``python -m t2m.sample``: what to generate (a :class:`t2m.request.GenerationRequest`,
    whose fields are the last options), from which checkpoints, into which folder."""

    def __post_init__(self) -> None:
        GenerationRequest.__post_init__(self)
        OutputOptions.__post_init__(self)


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
    prompts = config.prompts_for()
    out = config.output_folder()
    # 2. the models
    # (the length model also where every length is given, when trained: a counted clause
    # keeps the time its count needs, TextToMotion.settle_plan)
    try:
        pipe = config.load_pipeline(need_length_model=True)
    except UsageError:
        if any(p.frames is None for p in prompts):
            raise
        pipe = config.load_pipeline(need_length_model=False)
    try:
        pipe.prepare([p.text for p in prompts], quiet=True)  # refuses one with no known word
    except ValueError as error:
        raise UsageError(str(error)) from None
    prompts = config.prompts_for(pipe.spec)
    # 3. generate and write
    sample_to_folder(
        pipe,
        prompts,
        out,
        **config.generate_options(),
        **config.file_options(),
        extra_info={
            "checkpoints": str(config.checkpoints),
            "precision": config.precision,
            "batch_size": config.batch_size,
            "clean": config.clean,
            "plan": config.plan,
            "settle": config.settle,
        },
    )
    logger.info("wrote %s", out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
