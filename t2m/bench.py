"""``python -m t2m.bench``: run every part's benchmark and write ``bench/results.json`` and
``bench/results.md`` with the hardware and versions they were measured on.

Each module in ``t2m/benchmarks/`` exposes ``run(quick: bool = False) -> dict`` returning flat
``name -> number or string`` measurements; a benchmark that fails is recorded as such and the
others still run.
"""

from __future__ import annotations

import importlib
import logging
import os
import pkgutil
import platform
import sys
import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from dataset_tools.command import (
    CommandParser,
    UsageError,
    command,
    option,
    parse_config,
)
from dataset_tools.io import write_json_atomic, write_text_atomic

logger = logging.getLogger(__name__)

# The order in which the parts run (cheap first); modules not listed run after these.
ORDER = ("representation", "synth", "build", "train", "sample", "memory", "evaluate")
# Benchmarks with their own command line, not parts of ``make bench`` (the side-by-side run
# against the original needs its checkout; the GPU check needs CUDA).
STANDALONE = ("versus_original", "gpu")


def _cpu_name() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def environment() -> dict:
    """Hardware and versions the numbers were measured with."""
    info = {
        "cpu": _cpu_name(),
        "cpu_count": os.cpu_count(),
        "torch_threads": torch.get_num_threads(),
        "python": platform.python_version(),
        "numpy": np.__version__,
        "torch": torch.__version__,
        "platform": platform.platform(),
        "cuda": torch.cuda.get_device_name(0) if torch.cuda.is_available() else None,
        "date": time.strftime("%Y-%m-%d %H:%M:%S %Z"),
    }
    return info


def available() -> list[str]:
    import t2m.benchmarks as package

    names = [
        m.name
        for m in pkgutil.iter_modules(package.__path__)
        if not m.name.startswith("_") and m.name not in STANDALONE
    ]
    return sorted(names, key=lambda n: (ORDER.index(n) if n in ORDER else len(ORDER), n))


def run_all(names: list[str], quick: bool) -> dict:
    results: dict = {"environment": environment(), "quick": quick, "parts": {}}
    for name in names:
        logger.info("benchmark %s ...", name)
        start = time.perf_counter()
        try:
            measured = importlib.import_module(f"t2m.benchmarks.{name}").run(quick=quick)
            status = "ok"
        except Exception as error:  # one part failing must not hide the others' numbers
            logger.error("benchmark %s failed: %s", name, error)
            measured = {
                "error": f"{type(error).__name__}: {error}",
                "trace": traceback.format_exc(),
            }
            status = "failed"
        results["parts"][name] = {
            "status": status,
            "seconds": round(time.perf_counter() - start, 2),
            "results": measured,
        }
    return results


def to_markdown(results: dict) -> str:
    env = results["environment"]
    lines = [
        "# Benchmarks" + (" (quick mode)" if results["quick"] else ""),
        "",
        f"Measured {env['date']} on {env['cpu']} ({env['cpu_count']} cores, "
        f"{env['torch_threads']} torch threads), CUDA: {env['cuda'] or 'none'}; Python "
        f"{env['python']}, numpy {env['numpy']}, torch {env['torch']}.",
        "",
        "| part | measurement | value |",
        "| --- | --- | --- |",
    ]
    for part, entry in results["parts"].items():
        if entry["status"] != "ok":
            lines.append(f"| {part} | FAILED | {entry['results']['error']} |")
            continue
        for key, value in entry["results"].items():
            lines.append(f"| {part} | {key} | {value} |")
    return "\n".join(lines) + "\n"


def compare(results: dict, earlier: dict) -> str:
    """A Markdown table of the numbers both results hold: earlier, now and now / earlier.

    Only a ratio of two runs on the same machine means anything; a different CPU or thread
    count is said in the table's heading.
    """
    now_env, then_env = results["environment"], earlier.get("environment", {})
    heading = f"Ratios now / earlier ({then_env.get('date', '?')})"
    changed = [
        f"{key} {then_env.get(key)!r} -> {now_env.get(key)!r}"
        for key in ("cpu", "cpu_count", "torch_threads", "torch")
        if then_env.get(key) != now_env.get(key)
    ]
    if changed:
        heading += "; NOT the same setting: " + ", ".join(changed)
    lines = [heading, "", "| part | measurement | earlier | now | now / earlier |"]
    lines.append("| --- | --- | --- | --- | --- |")
    for part, entry in results["parts"].items():
        before = earlier.get("parts", {}).get(part, {}).get("results", {})
        for key, value in entry["results"].items():
            old = before.get(key)
            numbers = all(
                isinstance(v, (int, float)) and not isinstance(v, bool) for v in (value, old)
            )
            if numbers and old:
                lines.append(f"| {part} | {key} | {old} | {value} | {value / old:.3f} |")
    return "\n".join(lines) + "\n"


def read_results(path: Path) -> dict:
    """An earlier ``results.json``; UsageError (one line) when it is not one."""
    import json

    try:
        results = json.loads(Path(path).read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as error:
        raise UsageError(f"cannot read benchmark results {path}: {error}") from None
    if not isinstance(results, dict) or not isinstance(results.get("parts"), dict):
        raise UsageError(f"{path} is not a results.json written by python -m t2m.bench")
    return results


@dataclass
class BenchConfig:
    """``python -m t2m.bench``."""

    only: tuple[str, ...] = field(default=(), metadata=option(metavar="PART"))
    """parts to run (default: all of them, see t2m/benchmarks/)"""
    quick: bool = False
    """fewer repetitions (a smoke run)"""
    out: Path = field(default=Path("bench"), metadata=option(metavar="DIR"))
    """output folder"""
    compare: Path | None = field(default=None, metadata=option(metavar="FILE"))
    """an earlier results.json of this machine: also print (and write to compare.md) every
    measurement's ratio now / earlier"""


@command
def main(argv: list[str] | None = None) -> int:
    parser = CommandParser(prog="python -m t2m.bench", description=__doc__.split("\n\n")[0])
    config = parse_config(parser, BenchConfig, argv)
    names = available()
    unknown = sorted(set(config.only) - set(names))
    if unknown:
        raise UsageError(f"unknown benchmark(s) {', '.join(unknown)}; known: {', '.join(names)}")
    if config.only:
        names = [n for n in names if n in config.only]
    earlier = read_results(config.compare) if config.compare is not None else None
    results = run_all(names, config.quick)
    write_json_atomic(config.out / "results.json", results)
    markdown = to_markdown(results)
    write_text_atomic(config.out / "results.md", markdown)
    print(markdown)
    if earlier is not None:
        table = compare(results, earlier)
        write_text_atomic(config.out / "compare.md", table)
        print(table)
    return 0 if all(p["status"] == "ok" for p in results["parts"].values()) else 1


if __name__ == "__main__":
    sys.exit(main())
