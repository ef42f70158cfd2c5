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
metadata renames the option, makes it positional, adds a metavar or gives the field another
JSON key (``option(key="samples")``: ``--num-samples`` on the command line, ``"samples"`` in
JSON). A union such as
``Path | np.ndarray`` (a file, or an array from Python or JSON) is the option of its first member
the command line can spell.

The same type table reads a JSON object into the dataclass (:func:`config_from_dict`,
:func:`fields_from_dict`), so a request declared once is also its ``--batch`` file's and its web
API's schema; a bad value is one line naming the field: ``edit.mode must be one of continue,
inbetween, ...; got 'x'``. ``add_config_options(..., unset=True)`` with :func:`given_fields` gives
the fields the user typed, for a command that takes a request either from options or from a file.

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
import math
import os
import sys
import textwrap
import types
import typing
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, Literal, TypeVar

import numpy as np

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
    key: str | None = None


def option(
    *flags: str,
    negative: str | None = None,
    positional: bool = False,
    metavar: str | None = None,
    choices: Sequence | None = None,
    key: str | None = None,
) -> dict:
    """Field metadata for an option that is not plain ``--field-name``.

    Args:
        flags: the option's names instead of ``--field-name`` (e.g. ``"--input"``, or
            ``"--input", "-i"``); the field name stays the attribute.
        negative: for a bool field, the name of the "false" flag instead of ``--no-<name>``.
        positional: a positional argument instead of an option.
        metavar: the placeholder shown in ``--help`` (e.g. ``"DIR"``).
        choices: the allowed values, when they live in a constant rather than a ``Literal``.
        key: the field's key in a JSON object (:func:`fields_from_dict`) instead of its name.

    Use as ``input_dir: Path = field(metadata=option("--input", metavar="DIR"))``.
    """
    return {
        _METADATA_KEY: _Option(
            flags, negative, positional, metavar, choices and tuple(choices), key
        )
    }


def json_key(field: dataclasses.Field) -> str:
    """A field's key in a JSON object: its :func:`option` ``key``, else its name."""
    spec: _Option = field.metadata.get(_METADATA_KEY, _Option())
    return spec.key or field.name


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


def _members(hint: Any) -> list[Any]:
    """The types of a union without None (``[hint]`` for a plain type)."""
    if typing.get_origin(hint) in (typing.Union, types.UnionType):
        return [arg for arg in typing.get_args(hint) if arg is not type(None)]
    return [hint]


def _spellable(hint: Any) -> bool:
    """Whether a command-line value can spell ``hint`` (an array, say, cannot)."""
    origin = typing.get_origin(hint)
    return hint in (bool, int, float, str, Path) or origin in (Literal, tuple)


def _without_none(hint: Any) -> Any:
    """X for ``X | None`` / ``Optional[X]``, ``hint`` otherwise (None is every option's "unset").
    Of a union such as ``Path | np.ndarray`` (a file, or an array from Python or JSON), the
    command line takes the first member it can spell."""
    members = _members(hint)
    if len(members) == 1:
        return members[0]
    for member in members:
        if _spellable(member):
            return member
    raise TypeError(f"unsupported option type {hint!r} (one type, optionally | None)")


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
    parser: argparse.ArgumentParser,
    cls: type,
    defaults: dict[str, Any] | None = None,
    unset: bool = False,
) -> None:
    """Add one option per field of the dataclass ``cls`` to ``parser`` (see the module docstring).

    ``defaults`` overrides the dataclass default of some fields for this command only (say so in
    the field's docstring). The option's ``dest`` is the field name, for :func:`config_from_args`.
    ``unset``: every option is optional and None when not given (``--help`` still shows the
    dataclass default), for a config made later from the options given (:func:`given_fields`).
    Raises TypeError for a field type it cannot turn into an option (a programming error).
    """
    defaults = defaults or {}
    hints = typing.get_type_hints(cls)
    docs = field_docs(cls)
    for field in dataclasses.fields(cls):
        spec: _Option = field.metadata.get(_METADATA_KEY, _Option())
        default = defaults.get(field.name, _default_of(field))
        required = default is dataclasses.MISSING
        value = None if required or unset else default  # what argparse gives when not given
        hint = _without_none(hints[field.name])
        help_text = docs.get(field.name, "")
        if hint is bool:
            _bool_option(parser, field.name, spec, help_text, value)
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
            parser.add_argument(field.name, help=help_text, default=value, **keywords)
            continue
        flags = spec.flags or ("--" + field.name.replace("_", "-"),)
        parser.add_argument(
            *flags,
            dest=field.name,
            required=required and not unset,
            help=help_text,
            default=value,
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


def given_fields(cls: type, namespace: argparse.Namespace) -> dict[str, Any]:
    """The fields of ``cls`` the user gave, from options added with ``unset=True`` (lists become
    tuples)."""
    values = {}
    for field in dataclasses.fields(cls):
        value = getattr(namespace, field.name, None)
        if value is not None:
            values[field.name] = tuple(value) if isinstance(value, list) else value
    return values


# ----------------------------------------------------------------------------- JSON objects


def _describe(hint: Any) -> str:
    """How a JSON value of type ``hint`` is described in a message."""
    if typing.get_origin(hint) is Literal:
        return "one of " + ", ".join(map(str, typing.get_args(hint)))
    if typing.get_origin(hint) is tuple:
        return f"a list of {_describe(typing.get_args(hint)[0]).removeprefix('a ')}s"
    names = {bool: "true or false", int: "a whole number", float: "a number", str: "a text",
             Path: "a file name", np.ndarray: "an array of numbers"}  # fmt: skip
    return names.get(hint, getattr(hint, "__name__", str(hint)))


def _json_scalar(hint: Any, value: Any, files: Path | None) -> Any:
    """``value`` as a ``hint`` (one member of a field's type); ValueError when it is not one."""
    if typing.get_origin(hint) is Literal:
        if isinstance(value, bool) or value not in typing.get_args(hint):
            raise ValueError
        return value
    if hint is bool or hint is str:
        if not isinstance(value, hint):
            raise ValueError
        return value
    if isinstance(value, bool):  # a JSON true is no number
        raise ValueError
    if hint is int and isinstance(value, int):
        return value
    if hint is float and isinstance(value, (int, float)) and math.isfinite(value):
        return float(value)
    if hint is Path and isinstance(value, str) and files is not None:
        return files / value
    if hint is np.ndarray and isinstance(value, (list, np.ndarray)):
        array = np.asarray(value, dtype=np.float64)  # ragged rows or text: ValueError
        return array
    raise ValueError


def _json_value(hint: Any, value: Any, files: Path | None) -> Any:
    """``value`` as the first member of ``hint`` it fits; ValueError when it fits none."""
    for member in _members(hint):
        try:
            if typing.get_origin(member) is not tuple:
                return _json_scalar(member, value, files)
            if isinstance(value, list):
                item = typing.get_args(member)[0]
                return tuple(_json_scalar(item, one, files) for one in value)
        except (ValueError, TypeError, OverflowError):  # OverflowError: a 400-digit number
            continue
    raise ValueError


def fields_from_dict(
    cls: type,
    data: object,
    where: str,
    files: Path | None = None,
    exclude: Sequence[str] = (),
    only: Sequence[str] | None = None,
    others: Sequence[str] = (),
) -> dict[str, Any]:
    """The fields of the dataclass ``cls`` from a JSON object ``data``, each checked against its
    type (the same table the options come from; an array type takes nested lists of numbers).

    A field is read from its JSON key (:func:`json_key`: its name, or its :func:`option`
    ``key``). ``where`` names the object in messages: ``edit.mode must be one of ...; got 'x'``
    (empty: the key alone, ``samples must be ...``, for a request that is the whole object).
    ``files``: the folder a relative file name is read from; None refuses file names (a web
    request never names a file of the server). ``exclude``: fields this reader does not take;
    ``only``: the fields it takes (None: all but ``exclude``). ``others``: keys of ``data`` that
    another reader takes, skipped here but named among the known keys of the unknown-key
    message. A missing field keeps its default; a missing required one, an unknown key or a
    value of the wrong type is a one-line :class:`UsageError`. Returns ``{field: value}`` (field
    names) of the keys given, for ``cls(**values)`` (whose ``__post_init__`` checks the rest).
    """
    if not isinstance(data, dict):
        raise UsageError(
            f"{where or 'the object'} must be a JSON object, got {type(data).__name__}"
        )
    hints = typing.get_type_hints(cls)
    fields = {
        json_key(f): f
        for f in dataclasses.fields(cls)
        if f.name not in exclude and (only is None or f.name in only)
    }
    unknown = sorted(set(data) - set(fields) - set(others), key=str)
    if unknown:
        known = ", ".join([*fields, *others])
        raise UsageError(
            f"{where + ': ' if where else ''}unknown field {unknown[0]!r}; use {known}"
        )
    values = {}
    for key, field in fields.items():
        shown_key = f"{where}.{key}" if where else key
        if key not in data:
            if _default_of(field) is dataclasses.MISSING:
                raise UsageError(f"{shown_key} is required")
            continue
        hint, value = hints[field.name], data[key]
        if value is None and type(None) in typing.get_args(hint):
            values[field.name] = None
            continue
        try:
            values[field.name] = _json_value(hint, value, files)
        except ValueError:
            kinds = " or ".join(
                _describe(m) for m in _members(hint) if files is not None or m is not Path
            )
            shown = repr(value) if len(repr(value)) <= 40 else repr(value)[:37] + "..."
            raise UsageError(f"{shown_key} must be {kinds}; got {shown}") from None
    return values


def config_from_dict(
    cls: type[Config],
    data: object,
    where: str,
    files: Path | None = None,
    exclude: Sequence[str] = (),
) -> Config:
    """The dataclass ``cls`` from a JSON object (see :func:`fields_from_dict`); its own checks
    (``__post_init__``) raise :class:`UsageError`, prefixed with ``where``."""
    values = fields_from_dict(cls, data, where, files, exclude)
    try:
        return cls(**values)
    except UsageError as error:
        raise UsageError(f"{where}: {error}") from None


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
