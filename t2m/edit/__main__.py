"""Command line: edit or compose motions (``python -m t2m.edit --help``).

Examples::

    python -m t2m.edit --source walk.npy --text "a person sits down" --mode continue --keep-seconds 2
    python -m t2m.edit --source take.bvh --text "a person jumps" --mode inbetween --keep-start 1 --keep-end 1
    python -m t2m.edit --source walk.npy --text "a person waves both hands" --mode body --part lower
    python -m t2m.edit --text "a person walks" --mode path --path path.csv
    python -m t2m.edit --text "a person raises the left hand" --mode keys --keys targets.npy
    python -m t2m.edit --mode compose --timeline "a person walks forward#0#4" "a person waves#4#7"
    python -m t2m.edit --mode compose --source take.bvh --keep-last 2 --timeline "a person sits down#3"
    python -m t2m.edit --batch edits.json --num-samples 3

Writes what ``python -m t2m.sample`` writes (``sampleNN_repRR.npy``, ``_feats.npy``, mp4/gif
with the kept joints in green, BVH with ``--bvh``, glTF binary with ``--glb``, ``results.npy``, ``results.json``), all or
nothing. Exit status 2 with a one-line message on bad input.
"""

from __future__ import annotations

import logging
import sys
from dataclasses import asdict, dataclass, field
from pathlib import Path

from dataset_tools.command import (
    CommandParser,
    UsageError,
    add_config_options,
    command,
    config_from_args,
    configure_logging,
    fields_from_dict,
    given_fields,
    option,
)
from dataset_tools.io import read_json
from t2m.config import check_seed
from t2m.edit.core import Method, SearchSettings
from t2m.edit.modes import MAX_SECONDS
from t2m.edit.request import EditRequest, json_terms
from t2m.options import OutputOptions
from t2m.outputs import write_motions

logger = logging.getLogger("t2m.edit")

MAX_CANDIDATES = 4096
"""The most noise draws per result (--candidates)."""
MAX_STEPS = 10_000
"""The most optimisation steps (--steps)."""
MAX_BATCH_EDITS = 10_000
"""The most edits of one --batch file."""
MAX_BATCH_BYTES = 256 * 2**20
"""The largest --batch file read."""
SEARCH_BYTES_PER_FRAME = 16 * 1024
"""Memory one candidate's frame takes during the search whatever the model's size (the decoded
features and joints, the targets), plus :data:`SEARCH_BYTES_PER_HIDDEN` per unit of the
generator's hidden size (the activations the optimisation keeps for its gradient). Measured
with ``tools/measure_edit_memory.py`` (a keys edit of 196 frames, ``--method optimize``, 20
steps; growth of peak resident memory per added candidate frame; 2026-12-05, AMD EPYC Zen 5,
AVX-512, 2 cores, loaded): 16.0 KiB at ``tiny`` (hidden 32), 28.3 KiB at ``demo`` (256), 66.4
KiB with the ``paper`` sizes (1024); the rule gives 18, 32 and 80 KiB."""
SEARCH_BYTES_PER_HIDDEN = 64
"""Memory per candidate frame per unit of the generator's hidden size (see above)."""
SEARCH_FIXED_BYTES = 128 * 2**20
"""Memory a search takes whatever its size (measured: 94 to 115 MiB with one candidate)."""


@dataclass
class EditConfig(OutputOptions):
    """``python -m t2m.edit``: how many results, how to search, from which checkpoints, into
    which folder; the edit itself is a :class:`t2m.edit.EditRequest` (its fields are options)."""

    batch: Path | None = field(default=None, metadata=option(metavar="JSON"))
    """many edits: a JSON list of objects with the edit options (mode, text, source, keep_seconds,
    ..., timeline as a list; paths relative to the file); edit i writes sampleNN_repRR with NN = i"""
    num_samples: int = field(default=1, metadata=option(metavar="N"))
    """different results of the edit"""
    seed: int = 0
    """random seed: same seed, same bytes"""
    method: Method = "auto"
    """auto (optimize where targets cannot be kept exactly: keys; posterior elsewhere),
    optimize (continue from the kept start, optimise the noise against the constraints past
    it: slower, the model reaches them itself), posterior (no optimisation)
    or best_of_n (the baseline)"""
    candidates: int = field(default=8, metadata=option(metavar="N"))
    """noise draws per result, the closest to the constraints kept (an inbetween draws three
    times as many)"""
    steps: int = field(default=20, metadata=option(metavar="N"))
    """optimisation steps of --method optimize (and auto)"""
    max_timeline_lines: int = field(default=100, metadata=option(metavar="N"))
    """compose: the most timeline lines taken (each is at least one generation pass)"""
    max_timeline_seconds: float = field(default=600.0, metadata=option(metavar="S"))
    """compose: the longest timeline taken (a pass per 7.8 s window)"""
    out: Path | None = field(default=None, metadata=option(metavar="DIR"))
    """output folder (default outputs/edit-<timestamp>/)"""

    def __post_init__(self) -> None:
        if self.num_samples < 1 or self.candidates < 1 or self.steps < 0:
            raise UsageError("--num-samples and --candidates must be >= 1, --steps >= 0")
        if self.candidates > MAX_CANDIDATES:
            raise UsageError(
                f"--candidates {self.candidates}: at most {MAX_CANDIDATES} noise draws per result"
            )
        if self.steps > MAX_STEPS:
            raise UsageError(f"--steps {self.steps}: at most {MAX_STEPS} optimisation steps")
        if self.max_timeline_lines < 1 or not 0 < self.max_timeline_seconds <= MAX_SECONDS:
            raise UsageError(
                "--max-timeline-lines must be >= 1, --max-timeline-seconds from 0 to "
                f"{MAX_SECONDS:g}"
            )
        check_seed(self.seed)
        super().__post_init__()

    def requests(self, given: dict) -> list[EditRequest]:
        """The edits: one of the request options ``given`` (fields of :class:`EditRequest`), or
        those of ``--batch`` (checked: missing or extra inputs per mode)."""
        if ("mode" in given) == (self.batch is not None):
            raise UsageError("give one of --mode and --batch")
        if self.batch is not None:
            if given:
                options = ", ".join("--" + name.replace("_", "-") for name in given)
                raise UsageError(f"--batch holds every edit's options; drop {options}")
            return read_batch(self.batch)
        timeline = given.get("timeline")
        if timeline is not None and len(timeline) == 1 and "#" not in timeline[0]:
            given = {**given, "timeline": Path(timeline[0])}  # one file of lines
        return [EditRequest(**given)]


def read_batch(path: Path) -> list[EditRequest]:
    """Edits of a ``--batch`` JSON file: a list of objects with the fields of
    :class:`EditRequest`, read by the schema's JSON reader; relative file names are taken from
    the file's folder, arrays may be given inline. UsageError (one line) for anything else."""
    entries = read_json(path, "--batch", max_bytes=MAX_BATCH_BYTES)
    if not isinstance(entries, list) or not entries:
        raise UsageError(f"--batch {path}: give a non-empty JSON list of edits")
    if len(entries) > MAX_BATCH_EDITS:
        raise UsageError(
            f"--batch {path} holds {len(entries)} edits; at most {MAX_BATCH_EDITS} a run "
            "(split the file)"
        )
    requests = []
    for number, entry in enumerate(entries):
        try:
            values = fields_from_dict(EditRequest, entry, f"edits[{number}]", path.parent)
            requests.append(EditRequest(**values))
        except UsageError as error:
            raise batch_error(path, number, error) from None
    return requests


def batch_error(path: Path, number: int, error: ValueError) -> UsageError:
    """A refusal of edit ``number`` of the ``--batch`` file ``path``, naming the file, the edit
    and the JSON keys (not the command's options) of what it refuses."""
    where = f"edits[{number}]"
    message = str(error) if str(error).startswith(where) else f"{where}: {error}"
    return UsageError(f"--batch {path}: {json_terms(message)}")


def check_search_memory(
    requests: list[EditRequest],
    frames: list[int],
    config: EditConfig,
    window: int,
    hidden_size: int = 1024,
) -> None:
    """Refuse, before generating, a search that cannot fit in memory: at worst every plain edit's
    results are searched in one batch of ``--candidates`` draws each (an inbetween's
    :attr:`t2m.edit.SearchSettings.end_draws` times as many), every frame taking
    :data:`SEARCH_BYTES_PER_FRAME` plus :data:`SEARCH_BYTES_PER_HIDDEN` per unit of the
    generator's ``hidden_size``, on top of :data:`SEARCH_FIXED_BYTES`; compose searches one
    ``window`` (the model's longest motion) at a time."""
    from t2m.edit.core import SearchSettings
    from t2m.train.runtime import available_memory

    ends = SearchSettings.end_draws  # an inbetween draws this many times --candidates
    plain = [
        f * (ends if r.mode == "inbetween" else 1)
        for r, f in zip(requests, frames)
        if r.mode != "compose"
    ]
    composed = [f for r, f in zip(requests, frames) if r.mode == "compose"]
    window = max([sum(plain)] + [min(f, window) for f in composed])
    per_frame = SEARCH_BYTES_PER_FRAME + SEARCH_BYTES_PER_HIDDEN * hidden_size
    need = SEARCH_FIXED_BYTES + config.num_samples * config.candidates * window * per_frame
    available = available_memory()
    if available is not None and need > available:
        raise UsageError(
            f"the search holds {config.num_samples} results x {config.candidates} candidates of "
            f"{window} frames, about {need / 2**30:.1f} GiB of memory; {available / 2**30:.1f} GiB "
            "is available: lower --candidates or --num-samples, or give fewer edits per run"
        )


@command(interrupted="interrupted; nothing was written")
def main(argv: list[str] | None = None) -> int:
    from t2m.edit import edit_batch

    parser = CommandParser(
        prog="python -m t2m.edit",
        description="Edit a motion or compose several prompts with trained T2M checkpoints.",
    )
    add_config_options(parser, EditConfig)
    add_config_options(parser, EditRequest, unset=True)  # one edit's fields, or --batch
    arguments = parser.parse_args(sys.argv[1:] if argv is None else argv)
    configure_logging()
    config = config_from_args(EditConfig, arguments)
    # 1. everything the user gave, checked before any model is loaded
    requests = config.requests(given_fields(EditRequest, arguments))
    settings = SearchSettings(
        method=config.method, candidates=config.candidates, steps=config.steps
    )
    out = config.output_folder("edit-")
    # 2. the models
    # the length model where trained: compose's counted prompts keep the time their count needs
    try:
        pipe = config.load_pipeline(need_length_model=True)
    except UsageError:
        pipe = config.load_pipeline(need_length_model=False)
    limits = config.max_timeline_lines, config.max_timeline_seconds
    frames = []
    for number, r in enumerate(requests):
        try:
            frames.append(
                r.compose_plan(pipe.spec, *limits).num_frames
                if r.mode == "compose"
                else r.plan(pipe.spec).num_frames
            )
        except ValueError as error:
            if config.batch is not None:
                raise batch_error(config.batch, number, error) from None
            raise UsageError(str(error)) from None
    hidden_size = pipe.vae.config.hidden_size
    check_search_memory(requests, frames, config, pipe.spec.max_frames, hidden_size)
    # 3. edit and write
    write_motions(
        lambda: edit_batch(pipe, requests, config.num_samples, config.seed, settings),
        pipe.spec,
        out,
        frames=frames,
        num_samples=config.num_samples,
        seed=config.seed,
        **config.file_options(),
        extra_info={
            "modes": [r.mode for r in requests],
            "checkpoints": str(config.checkpoints),
            "precision": config.precision,
            "search": asdict(settings),
        },
    )
    logger.info("wrote %s", out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
