"""Command line: ``python -m dataset_tools <command> ...``; ``--help`` on each command.

Each command lives in the module that owns its work; this file only dispatches, so that a
command's imports (spaCy, scipy, ...) are paid only when it runs.
"""

from __future__ import annotations

import importlib
import sys

from dataset_tools.command import UsageError, command

# command -> ("module", "function", one-line help). The function takes argv and returns an exit
# code; it is a `dataset_tools.command.command`, so it reports bad input itself.
COMMANDS: dict[str, tuple[str, str, str]] = {
    "features": ("dataset_tools.cli", "features_main", "joints (T, J, 3) -> features (T-1, D)"),
    "recover": ("dataset_tools.cli", "recover_main", "features (T, D) -> joints (T, J, 3)"),
    "build": ("dataset_tools.build", "main", "build a HumanML3D-layout dataset from a source"),
    "synth": ("dataset_tools.synth.cli", "main", "write the procedural demo corpus"),
    "contact-sheet": (
        "dataset_tools.synth.cli",
        "contact_sheet_main",
        "render a grid of key frames of N clips to PNG",
    ),
}


def _usage() -> str:
    lines = ["usage: python -m dataset_tools <command> [options]", "", "commands:"]
    lines += [f"  {name:<14} {help_}" for name, (_, _, help_) in COMMANDS.items()]
    return "\n".join(lines)


@command
def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if not argv or argv[0] in ("-h", "--help"):
        print(_usage())
        return 0 if argv else 2
    name, rest = argv[0], argv[1:]
    if name not in COMMANDS:
        raise UsageError(f"unknown command {name!r} (choose from {', '.join(COMMANDS)})")
    module_name, function_name, _ = COMMANDS[name]
    function = getattr(importlib.import_module(module_name), function_name)
    return int(function(rest) or 0)


if __name__ == "__main__":
    sys.exit(main())
