"""Command line: edit or compose motions (``python -m t2m.edit --help``).

Examples::

    python -m t2m.edit --source walk.npy --text "a person sits down" --mode continue --keep-seconds 2
    python -m t2m.edit --source take.bvh --text "a person jumps" --mode inbetween --keep-start 1 --keep-end 1
    python -m t2m.edit --source walk.npy --text "a person waves both hands" --mode body --part lower
    python -m t2m.edit --text "a person walks" --mode path --path path.csv
    python -m t2m.edit --text "a person raises the left hand" --mode keys --keys targets.npy
    python -m t2m.edit --mode compose --timeline "a person walks forward#0#4" "a person waves#4#7"
    python -m t2m.edit --batch edits.json --num-samples 3

Writes what ``python -m t2m.sample`` writes (``sampleNN_repRR.npy``, ``_feats.npy``, mp4/gif
with the kept joints in green, BVH with ``--bvh``, glTF binary with ``--glb``, ``results.npy``, ``results.json``), all or
nothing. Exit status 2 with a one-line message on bad input.
"""

from __future__ import annotations

import json
import logging
import sys
from dataclasses import asdict, dataclass, field
from pathlib import Path

from dataset_tools.command import CommandParser, UsageError, command, option, parse_config
from t2m.config import check_seed
from t2m.edit.core import Method, SearchSettings
from t2m.edit.modes import Mode, Part
from t2m.options import OutputOptions
from t2m.outputs import write_motions

logger = logging.getLogger("t2m.edit")


@dataclass
class EditConfig(OutputOptions):
    """``python -m t2m.edit``: which edit, from which checkpoints, into which folder."""

    mode: Mode | None = field(default=None, metadata=option(metavar="MODE"))
    """continue | inbetween | body | path | keys | compose (or --batch)"""
    batch: Path | None = field(default=None, metadata=option(metavar="JSON"))
    """many edits: a JSON list of objects with the edit options (mode, text, source, keep_seconds,
    ..., timeline as a list; paths relative to the file); edit i writes sampleNN_repRR with NN = i"""
    text: str | None = None
    """what the generated part does, e.g. "a person waves both hands" (not for compose)"""
    source: Path | None = field(default=None, metadata=option(metavar="FILE"))
    """the motion to edit: joints .npy (T, 22, 3) (a sampleNN_repRR.npy too) or .bvh"""
    mapping: str | None = field(default=None, metadata=option(metavar="NAME|FILE"))
    """BVH joint mapping (bandai, cmu_cc, smpl or a JSON file; default: detected)"""
    source_fps: float | None = field(default=None, metadata=option(metavar="F"))
    """frame rate of a .npy source (default: the model's, 20)"""
    seconds: float | None = field(default=None, metadata=option(metavar="S"))
    """length of the result (default: the source's, or up to the last path point)"""
    keep_seconds: float = field(default=2.0, metadata=option(metavar="S"))
    """continue: seconds of the source's start that are kept"""
    keep_start: float = field(default=1.0, metadata=option(metavar="S"))
    """inbetween: seconds of the source's start kept at the result's start (0.05: one pose)"""
    keep_end: float = field(default=1.0, metadata=option(metavar="S"))
    """inbetween: seconds of the source's end kept at the result's end"""
    part: Part = "lower"
    """body: the part kept from the source (lower keeps the root path and the legs)"""
    path: Path | None = field(default=None, metadata=option(metavar="FILE"))
    """path: CSV or JSON of floor points 'seconds,x,z' (metres; start at 0,0 facing +z)"""
    keys: Path | None = field(default=None, metadata=option(metavar="NPY"))
    """keys: joint targets (T, 22, 3), NaN where free"""
    timeline: tuple[str, ...] = field(default=(), metadata=option(metavar="LINE"))
    """compose: lines 'text#start#end' (seconds) or 'text#seconds', or one file of them"""
    num_samples: int = field(default=1, metadata=option(metavar="N"))
    """different results of the edit"""
    seed: int = 0
    """random seed: same seed, same bytes"""
    method: Method = "auto"
    """auto (optimize where targets cannot be kept exactly: keys; posterior elsewhere),
    optimize (read the kept start with the posterior, optimise the noise against the
    constraints past it: slower, the model reaches them itself), posterior (no optimisation)
    or best_of_n (the baseline)"""
    candidates: int = field(default=8, metadata=option(metavar="N"))
    """noise draws per result, the closest to the constraints kept"""
    steps: int = field(default=20, metadata=option(metavar="N"))
    """optimisation steps of --method optimize (and auto)"""
    out: Path | None = field(default=None, metadata=option(metavar="DIR"))
    """output folder (default outputs/edit-<timestamp>/)"""

    def __post_init__(self) -> None:
        if self.num_samples < 1 or self.candidates < 1 or self.steps < 0:
            raise UsageError("--num-samples and --candidates must be >= 1, --steps >= 0")
        check_seed(self.seed)
        super().__post_init__()

    def requests(self) -> list:
        """The :class:`t2m.edit.EditRequest` list (checked: missing or extra inputs per mode)."""
        if (self.mode is None) == (self.batch is None):
            raise UsageError("give one of --mode and --batch")
        return [self.request()] if self.batch is None else read_batch(self.batch)

    def request(self):
        """The :class:`t2m.edit.EditRequest` of the options."""
        from t2m.edit import EditRequest

        timeline = self.timeline
        if len(timeline) == 1 and "#" not in timeline[0]:
            timeline = Path(timeline[0])
        return EditRequest(
            mode=self.mode,
            text=self.text or "",
            source=self.source,
            seconds=self.seconds,
            keep_seconds=self.keep_seconds,
            keep_start=self.keep_start,
            keep_end=self.keep_end,
            part=self.part,
            path=self.path,
            keys=self.keys,
            timeline=timeline or None,
            mapping=self.mapping,
            source_fps=self.source_fps,
        )


BATCH_KEYS = ("mode", "text", "source", "seconds", "keep_seconds", "keep_start", "keep_end",
              "part", "path", "keys", "timeline", "mapping", "source_fps")  # fmt: skip


def read_batch(path: Path) -> list:
    """Edits of a ``--batch`` JSON file (a list of objects with :data:`BATCH_KEYS`); relative
    file paths are taken from the file's folder. UsageError (one line) for anything else."""
    from t2m.edit import EditRequest

    try:
        entries = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, ValueError) as error:
        raise UsageError(f"cannot read --batch {path}: {error}") from None
    if not isinstance(entries, list) or not entries:
        raise UsageError(f"--batch {path}: give a non-empty JSON list of edits")
    requests = []
    for number, entry in enumerate(entries):
        if not isinstance(entry, dict):
            raise UsageError(f"--batch {path}: edit {number} is not an object")
        unknown = sorted(set(entry) - set(BATCH_KEYS))
        if unknown:
            raise UsageError(f"--batch {path}: edit {number} has unknown keys {unknown}")
        entry = dict(entry)
        for key in ("source", "path", "keys"):
            if isinstance(entry.get(key), str):
                entry[key] = path.parent / entry[key]
        try:
            requests.append(EditRequest(**entry))
        except UsageError as error:
            raise UsageError(f"--batch {path}: edit {number}: {error}") from None
        except TypeError:
            raise UsageError(f"--batch {path}: edit {number} needs a mode") from None
    return requests


@command(interrupted="interrupted; nothing was written")
def main(argv: list[str] | None = None) -> int:
    from t2m.edit import edit_batch

    parser = CommandParser(
        prog="python -m t2m.edit",
        description="Edit a motion or compose several prompts with trained T2M checkpoints.",
    )
    config = parse_config(parser, EditConfig, argv)
    # 1. everything the user gave, checked before any model is loaded
    requests = config.requests()
    settings = SearchSettings(
        method=config.method, candidates=config.candidates, steps=config.steps
    )
    out = config.output_folder("edit-")
    # 2. the models
    pipe = config.load_pipeline(need_length_model=False)
    try:
        from t2m.edit.modes import read_timeline

        frames = [
            read_timeline(r.timeline, pipe.spec)[-1].stop
            if r.mode == "compose"
            else r.plan(pipe.spec).num_frames
            for r in requests
        ]
    except ValueError as error:
        raise UsageError(str(error)) from None
    # 3. edit and write
    write_motions(
        lambda: edit_batch(pipe, requests, config.num_samples, config.seed, settings),
        pipe.spec,
        out,
        frames=frames,
        num_samples=config.num_samples,
        seed=config.seed,
        render=config.render,
        bvh=config.bvh,
        glb=config.glb,
        overwrite=config.overwrite,
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
