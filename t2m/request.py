"""One generation request, declared once: :class:`GenerationRequest`.

Its typed fields are the whole schema. ``python -m t2m.sample`` makes its options from them (its
:class:`t2m.sample.SampleConfig` is this request plus :class:`t2m.options.OutputOptions`), and
the web app's ``POST /api/generate`` reads the same fields with the schema's JSON reader
(:func:`dataset_tools.command.fields_from_dict`, file names refused), adding only its limits
(:func:`t2m.serve.api.parse_generate`). A field's JSON key is its name but for
``num_samples``, ``"samples"`` in JSON (``--num-samples`` on the command line).

The prompts are one of ``text`` (one prompt, taken as typed) and ``prompts``: lines ``text`` or
``text#FRAMES``, from a file (``--text-file``; Python: a path) or given as a list (JSON, Python).
Python callers build the request directly and hand its parts to the pipeline::

    request = GenerationRequest(prompts=("a person jumps#60", "someone waves"), num_samples=3)
    prompts = request.prompts_for(pipe.spec)
    sample_to_folder(pipe, prompts, "out", **request.generate_options())
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

from dataset_tools.command import UsageError, option
from dataset_tools.spec import HUMANML3D, DatasetSpec
from t2m.config import check_seed
from t2m.prompts import Prompt, parse_prompt_line, read_prompt_file, with_lengths


@dataclass
class GenerationRequest:
    """What to generate: the prompts, how many motions of each, how long, from which seed, how.

    Not frozen: :class:`t2m.sample.SampleConfig` is this request plus the (mutable) output
    options."""

    text: str | None = None
    """one prompt, taken as typed (a '#FRAMES' suffix is read in --text-file lines only), e.g.
    "a person walks forward and waves" (or --text-file)"""
    prompts: Path | tuple[str, ...] | None = field(
        default=None, metadata=option("--text-file", metavar="FILE")
    )
    """prompts one a line; 'prompt#FRAMES' fixes that prompt's length"""
    num_samples: int = field(default=1, metadata=option(metavar="N", key="samples"))
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
    (--no-clean: the model's output, only made rigid)"""
    plan: Literal["clauses", "whole"] = "clauses"
    """clauses: a prompt of several clauses ("jumps twice, then waves") is generated clause by
    clause, each with its share of the length; whole: the whole prompt in one pass (the paper)"""
    settle: bool = True
    """at a length you fix, a clause that names a count ("jumps twice") gets the time its count
    needs and stands still for the rest (--no-settle: the count is spread over the whole length,
    and the model repeats the action at its own pace)"""

    def __post_init__(self) -> None:
        if isinstance(self.prompts, str):  # a file name, as for every other file field
            self.prompts = Path(self.prompts)
        elif isinstance(self.prompts, list):
            self.prompts = tuple(self.prompts)
        if (self.text is None) == (self.prompts is None):
            raise UsageError("give one of --text and --text-file")
        if self.text is not None and not self.text.strip():
            raise UsageError("empty --text: give a sentence describing the motion")
        if isinstance(self.prompts, tuple) and not any(line.strip() for line in self.prompts):
            raise UsageError("empty prompts: give a sentence describing the motion")
        if self.length is not None and self.seconds is not None:
            raise UsageError("give one of --length and --seconds")
        if self.num_samples < 1 or self.batch_size < 1:
            raise UsageError("--num-samples and --batch-size must be at least 1")
        if isinstance(self.prompts, Path) and not self.prompts.is_file():
            raise UsageError(f"--text-file {self.prompts} is not a file")
        check_seed(self.seed)

    def read_prompts(self) -> list[Prompt]:
        """The prompts as given, each with its own '#FRAMES' length or None (``text``: none).
        Blank lines are skipped; a bad suffix is a one-line UsageError naming its line (``prompt
        N``, or the file's ``name:line``)."""
        if self.text is not None:
            return [Prompt(self.text.strip())]
        if isinstance(self.prompts, Path):
            return read_prompt_file(self.prompts)
        lines = [line for line in self.prompts if line.strip()]
        return [parse_prompt_line(line, f"prompt {n}") for n, line in enumerate(lines, start=1)]

    def prompts_for(self, spec: DatasetSpec = HUMANML3D) -> list[Prompt]:
        """The prompts with their lengths in frames of ``spec`` (the models' dataset): a prompt's
        '#FRAMES', else ``length``, else ``seconds``, each rounded and clamped; None: drawn by
        the text2length model."""
        return with_lengths(self.read_prompts(), spec, self.length, self.seconds)

    def generate_options(self) -> dict:
        """The keywords :meth:`t2m.pipeline.TextToMotion.generate` and
        :func:`t2m.outputs.sample_to_folder` take from this request (with the prompts' texts
        and lengths from :meth:`prompts_for`)."""
        return {
            "num_samples": self.num_samples,
            "seed": self.seed,
            "batch_size": self.batch_size,
            "clean": self.clean,
            "plan": self.plan,
            "settle": self.settle,
        }
