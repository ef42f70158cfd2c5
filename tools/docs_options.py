"""The option tables of docs/*.md, made from the commands' own option definitions.

A table sits between two marker comments in a page::

    <!-- options t2m.sample:SampleConfig -->

    | option | meaning |
    | --- | --- |
    | `--num-samples N` | different motions per prompt (default: 1) |

    <!-- /options -->

The opening marker names what the command builds its options from, in the command's order: one
or more config dataclasses (``module:Class``, each added by
``dataset_tools.command.add_config_options`` as the command adds it), or a function that
returns the command's parser (``module:function``). A dataclass may carry flags after a comma:
``,unset`` as the command's ``add_config_options(..., unset=True)``; ``,nodefault=FIELD`` (one
per field) shows that field without a default, for a command that sets its own (its docstring
says which).
Each row is what ``--help`` prints for one option: its flags and placeholder, its help text
with the default.

    python tools/docs_options.py            # names the stale pages, exit status 1 if any
    python tools/docs_options.py --write    # rewrites the tables in place

``tests/test_docs.py`` fails when a page is stale.
"""

from __future__ import annotations

import argparse
import dataclasses
import importlib
import re
import sys
from pathlib import Path

from dataset_tools.command import CommandParser, add_config_options

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"

BLOCK = re.compile(
    r"(?P<open><!-- options (?P<spec>[^>]*?) -->\n)(?P<body>.*?)(?P<close><!-- /options -->)",
    re.DOTALL,
)


def _resolve(name: str, spec: str):
    module_name, _, attribute = name.partition(":")
    try:
        return getattr(importlib.import_module(module_name), attribute)
    except (ImportError, AttributeError, ValueError) as error:
        raise LookupError(f"marker '{spec}' names nothing importable: {error}") from None


def _target(spec: str) -> argparse.ArgumentParser:
    """The parser a marker's ``module:name[,flags] ...`` describes."""
    parser = CommandParser(prog="docs")
    for item in spec.split():
        name, *flags = item.split(",")
        target = _resolve(name, spec)
        if not dataclasses.is_dataclass(target):
            if len(spec.split()) > 1 or flags:
                raise LookupError(f"marker '{spec}': a parser function stands alone")
            parser = target()
            if not isinstance(parser, argparse.ArgumentParser):
                raise LookupError(f"marker '{spec}': {name}() returned no ArgumentParser")
            return parser
        nodefault = [flag.partition("=")[2] for flag in flags if flag.startswith("nodefault=")]
        add_config_options(parser, target, dict.fromkeys(nodefault), unset="unset" in flags)
    return parser


def _cell(text: str) -> str:
    return " ".join(text.split()).replace("|", "\\|")


def options_table(spec: str) -> str:
    """The Markdown table of the options ``spec`` names, one row per option, as ``--help``."""
    parser = _target(spec)
    formatter = argparse.HelpFormatter(parser.prog)
    rows = ["| option | meaning |", "| --- | --- |"]
    for action in parser._actions:
        if isinstance(action, argparse._HelpAction) or action.help == argparse.SUPPRESS:
            continue
        invocation = formatter._format_action_invocation(action)
        meaning = formatter._expand_help(action) if action.help else ""
        rows.append(f"| `{_cell(invocation)}` | {_cell(meaning)} |")
    return "\n".join(rows) + "\n"


def render(text: str) -> str:
    """``text`` with every options block regenerated (LookupError: a marker names nothing)."""
    return BLOCK.sub(
        lambda match: match["open"] + "\n" + options_table(match["spec"]) + "\n" + match["close"],
        text,
    )


def pages() -> list[Path]:
    """The pages that hold options blocks."""
    return sorted(path for path in DOCS.glob("*.md") if BLOCK.search(path.read_text()))


def stale_pages() -> list[Path]:
    """The pages whose tables differ from what the commands define now."""
    return [path for path in pages() if render(path.read_text()) != path.read_text()]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python tools/docs_options.py",
        description="Check (or with --write, regenerate) the option tables of docs/*.md.",
    )
    parser.add_argument("--write", action="store_true", help="rewrite stale pages in place")
    arguments = parser.parse_args(argv)
    try:
        stale = stale_pages()
    except LookupError as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    for path in stale:
        if arguments.write:
            path.write_text(render(path.read_text()))
            print(f"wrote {path.relative_to(ROOT)}")
        else:
            print(f"stale: {path.relative_to(ROOT)}")
    if stale and not arguments.write:
        print("regenerate with: python tools/docs_options.py --write", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
