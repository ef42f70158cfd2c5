"""Commands built from config dataclasses: their options, one error type, one wrapper, one log setup.

A command is a config dataclass plus a ``main(argv) -> int``::

    @dataclass
    class GreetConfig:
        name: str
        \"\"\"who to greet\"\"\"
        times: int = 1
        \"\"\"how often\"\"\"

    @command
    def main(argv: list[str] | None = None) -> int:
        parser = CommandParser(prog="python -m greet", description="Say hello.")
        config = parse_config(parser, GreetConfig, argv)  # options, parsing, checks, logging
        ...

Each field becomes ``--field-name`` (required when the field has no default); its help is the
string literal written under the field (its attribute docstring). Field types: ``int``,
``float``, ``str``, ``Path``, ``bool`` (``--x`` / ``--no-x``), ``Literal[...]`` (choices),
``tuple[X, ...]`` (zero or more values), each optionally ``| None``. :func:`option` in a field's
metadata renames the option, makes it positional or adds a metavar.

What the user got wrong is a :class:`UsageError` (raised by the parser too): the :func:`command`
wrapper prints it as one line ``error: ...`` and exits with status 2. Everything else keeps its
traceback: a ``ValueError`` from deep inside numpy is a bug to report, not a message for the user.
"""

from __future__ import annotations

import argparse
import ast
import dataclasses
import functools
import inspect
import logging
import os
import sys
import textwrap
import types
import typing
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, Literal, TypeVar

Config = TypeVar("Config")

_METADATA_KEY = "command_option"


class UsageError(ValueError):
    """What the user got wrong (an option, an input file, a folder): one line, exit status 2.

    A ``ValueError``, so library functions can raise it for bad arguments and Python callers who
    catch ``ValueError`` keep working.
    """


# ----------------------------------------------------------------------------- the wrapper


def command(
    function: Callable[..., int | None] | None = None, *, interrupted: str = "interrupted"
) -> Callable:
    """Wrap a command's ``main(argv) -> int``: user errors become one line and exit status 2.

    ``UsageError`` -> ``error: <message>`` on stderr, returns 2; ``OSError`` (a full disk, a
    permission) -> ``error: <message>``, returns 1; ``KeyboardInterrupt`` -> the ``interrupted``
    line, returns 130. Any other exception propagates with its traceback. Use as ``@command`` or
    ``@command(interrupted="interrupted; continue with --resume")``.
    """

    def wrap(main: Callable[..., int | None]) -> Callable[..., int]:
        @functools.wraps(main)
        def wrapped(*args: Any, **kwargs: Any) -> int:
            try:
                return int(main(*args, **kwargs) or 0)
            except UsageError as error:
                print(f"error: {error}", file=sys.stderr)
                return 2
            except OSError as error:
                print(f"error: {error}", file=sys.stderr)
                return 1
            except KeyboardInterrupt:
                print(interrupted, file=sys.stderr)
                return 130

        return wrapped

    return wrap if function is None else wrap(function)


class CommandParser(argparse.ArgumentParser):
    """An ``ArgumentParser`` whose errors are :class:`UsageError` (one line, via :func:`command`)."""

    def error(self, message: str) -> typing.NoReturn:
        raise UsageError(f"{message} (see {self.prog} --help)")


def configure_logging(verbose: bool = False) -> None:
    """The one logging setup of every command: INFO (DEBUG with ``verbose``) with time and logger
    name; under ``torchrun`` only rank 0 talks (other ranks log warnings and errors only)."""
    level = logging.DEBUG if verbose else logging.INFO
    if os.environ.get("RANK", "0") != "0":
        level = logging.WARNING
    logging.basicConfig(
        level=level, format="%(asctime)s %(levelname)s %(name)s: %(message)s", datefmt="%H:%M:%S"
    )


# ----------------------------------------------------------------------------- options


@dataclasses.dataclass(frozen=True)
class _Option:
    flags: tuple[str, ...] = ()
    negative: str | None = None
    positional: bool = False
    metavar: str | None = None
    choices: tuple | None = None


def option(
    *flags: str,
    negative: str | None = None,
    positional: bool = False,
    metavar: str | None = None,
    choices: Sequence | None = None,
) -> dict:
    """Field metadata for an option that is not plain ``--field-name``.

    Args:
        flags: the option's names instead of ``--field-name`` (e.g. ``"--input"``, or
            ``"--input", "-i"``); the field name stays the attribute.
        negative: for a bool field, the name of the "false" flag instead of ``--no-<name>``.
        positional: a positional argument instead of an option.
        metavar: the placeholder shown in ``--help`` (e.g. ``"DIR"``).
        choices: the allowed values, when they live in a constant rather than a ``Literal``.

    Use as ``input_dir: Path = field(metadata=option("--input", metavar="DIR"))``.
    """
    return {
        _METADATA_KEY: _Option(flags, negative, positional, metavar, choices and tuple(choices))
    }


def field_docs(cls: type) -> dict[str, str]:
    """``{field: docstring}`` from the string literals written under a dataclass's fields
    (base classes first, so a subclass may redocument a field)."""
    docs: dict[str, str] = {}
    for klass in reversed(cls.__mro__):
        if klass is object or not dataclasses.is_dataclass(klass):
            continue
        tree = ast.parse(textwrap.dedent(inspect.getsource(klass)))
        body = tree.body[0].body  # type: ignore[attr-defined]
        for statement, following in zip(body, body[1:]):
            if (
                isinstance(statement, ast.AnnAssign)
                and isinstance(statement.target, ast.Name)
                and isinstance(following, ast.Expr)
                and isinstance(following.value, ast.Constant)
                and isinstance(following.value.value, str)
            ):
                docs[statement.target.id] = " ".join(following.value.value.split())
    return docs


def _without_none(hint: Any) -> Any:
    """X for ``X | None`` / ``Optional[X]``, ``hint`` otherwise (None is every option's "unset")."""
    if typing.get_origin(hint) in (typing.Union, types.UnionType):
        members = [arg for arg in typing.get_args(hint) if arg is not type(None)]
        if len(members) != 1:
            raise TypeError(f"unsupported option type {hint!r} (one type, optionally | None)")
        return members[0]
    return hint


def _default_of(field: dataclasses.Field) -> Any:
    if field.default is not dataclasses.MISSING:
        return field.default
    if field.default_factory is not dataclasses.MISSING:
        return field.default_factory()
    return dataclasses.MISSING


def _scalar(hint: Any) -> dict:
    """argparse keywords (type, choices) for one value of type ``hint``."""
    if typing.get_origin(hint) is Literal:
        choices = typing.get_args(hint)
        return {"type": type(choices[0]), "choices": choices}
    if hint in (int, float, str, Path):
        return {"type": hint}
    raise TypeError(f"unsupported option type {hint!r}")


def _bool_option(
    parser: argparse.ArgumentParser, field: str, spec: _Option, help_text: str, default: bool | None
) -> None:
    """``--x`` / ``--no-x`` (or ``--x`` / ``spec.negative``) setting ``field`` to True / False."""
    flags = spec.flags or ("--" + field.replace("_", "-"),)
    if spec.negative is None:
        parser.add_argument(
            *flags,
            dest=field,
            action=argparse.BooleanOptionalAction,
            default=default,
            help=help_text,
        )
        return
    group = parser.add_mutually_exclusive_group()
    group.add_argument(*flags, dest=field, action="store_const", const=True, help=help_text)
    group.add_argument(
        spec.negative,
        dest=field,
        action="store_const",
        const=False,
        help=f"the opposite of {flags[0]}",
    )
    parser.set_defaults(**{field: default})


def _value_keywords(hint: Any, required: bool) -> dict:
    """argparse keywords (type, choices, nargs) for a field of type ``hint`` (``| None`` removed)."""
    if typing.get_origin(hint) is not tuple:
        return _scalar(hint)
    items = typing.get_args(hint)
    if len(items) == 2 and items[1] is Ellipsis:
        return {**_scalar(items[0]), "nargs": "+" if required else "*"}
    if len(set(items)) != 1:
        raise TypeError(f"unsupported option type {hint!r} (tuples hold one type)")
    return {**_scalar(items[0]), "nargs": len(items)}


def add_config_options(
    parser: argparse.ArgumentParser, cls: type, defaults: dict[str, Any] | None = None
) -> None:
    """Add one option per field of the dataclass ``cls`` to ``parser`` (see the module docstring).

    ``defaults`` overrides the dataclass default of some fields for this command only (say so in
    the field's docstring). The option's ``dest`` is the field name, for :func:`config_from_args`.
    Raises TypeError for a field type it cannot turn into an option (a programming error).
    """
    defaults = defaults or {}
    hints = typing.get_type_hints(cls)
    docs = field_docs(cls)
    for field in dataclasses.fields(cls):
        spec: _Option = field.metadata.get(_METADATA_KEY, _Option())
        default = defaults.get(field.name, _default_of(field))
        required = default is dataclasses.MISSING
        hint = _without_none(hints[field.name])
        help_text = docs.get(field.name, "")
        if hint is bool:
            _bool_option(parser, field.name, spec, help_text, None if required else default)
            continue
        keywords = _value_keywords(hint, required)
        if spec.choices is not None:
            keywords["choices"] = spec.choices
        if "choices" in keywords:  # shown as a|b|c rather than {a,b,c}
            keywords["metavar"] = "|".join(map(str, keywords["choices"]))
        if spec.metavar is not None:
            keywords["metavar"] = spec.metavar
        if not required and default not in (None, (), ""):
            help_text = f"{help_text} (default: {default})".lstrip()
        if spec.positional:
            if not required:
                keywords.setdefault("nargs", "?")
            parser.add_argument(
                field.name, help=help_text, default=None if required else default, **keywords
            )
            continue
        flags = spec.flags or ("--" + field.name.replace("_", "-"),)
        parser.add_argument(
            *flags,
            dest=field.name,
            required=required,
            help=help_text,
            default=None if required else default,
            **keywords,
        )


def config_from_args(cls: type[Config], namespace: argparse.Namespace) -> Config:
    """The dataclass ``cls`` from options added by :func:`add_config_options` (lists become
    tuples). The config's own checks (its ``__post_init__``) raise :class:`UsageError`."""
    values = {}
    for field in dataclasses.fields(cls):
        value = getattr(namespace, field.name)
        values[field.name] = tuple(value) if isinstance(value, list) else value
    return cls(**values)


# ----------------------------------------------------------------------------- output paths


def parse_config(
    parser: CommandParser,
    cls: type[Config],
    argv: Sequence[str] | None = None,
    defaults: dict[str, Any] | None = None,
) -> Config:
    """The usual start of a command: ``cls``'s options on ``parser``, ``argv`` (default: the
    process's arguments) parsed into a validated ``cls``, and logging configured."""
    add_config_options(parser, cls, defaults)
    config = config_from_args(cls, parser.parse_args(sys.argv[1:] if argv is None else argv))
    configure_logging()
    return config
