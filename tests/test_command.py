"""dataset_tools.command: options generated from config dataclasses, the one error wrapper, the
one logging setup."""

from __future__ import annotations

import importlib
import logging
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Literal

import numpy as np
import pytest

from dataset_tools.command import (
    CommandParser,
    UsageError,
    add_config_options,
    command,
    config_from_args,
    configure_logging,
    field_docs,
    option,
)


@dataclass
class ToyConfig:
    """A config with every supported kind of field."""

    name: str
    """who to greet,
    over two lines"""
    times: int = 2
    """how often"""
    scale: float | None = None
    """optional scale"""
    loud: bool = False
    """shout"""
    tidy: bool | None = field(default=None, metadata=option(negative="--messy"))
    """tidy output"""
    mode: Literal["a", "b"] = "a"
    """which mode"""
    tags: tuple[str, ...] = ()
    """zero or more tags"""
    size: tuple[int, int] = (3, 4)
    """width and height"""
    folder: Path = field(default=Path("out"), metadata=option("--dir", metavar="DIR"))
    """where to write"""

    def __post_init__(self) -> None:
        if self.times < 1:
            raise UsageError(f"--times must be at least 1, got {self.times}")


def _parse(*argv: str) -> ToyConfig:
    parser = CommandParser(prog="toy")
    add_config_options(parser, ToyConfig)
    return config_from_args(ToyConfig, parser.parse_args(list(argv)))


@command
def _toy_main(argv: list[str]) -> int:
    _parse(*argv)
    return 0


def test_defaults_types_and_values():
    config = _parse("--name", "x")
    assert config == ToyConfig(name="x")
    config = _parse(
        "--name",
        "x",
        "--times",
        "5",
        "--scale",
        "0.5",
        "--loud",
        "--messy",
        "--mode",
        "b",
        "--tags",
        "p",
        "q",
        "--size",
        "7",
        "8",
        "--dir",
        "d",
    )
    assert (config.times, config.scale, config.loud, config.tidy) == (5, 0.5, True, False)
    assert (config.mode, config.tags, config.size, config.folder) == (
        "b",
        ("p", "q"),
        (7, 8),
        Path("d"),
    )
    assert _parse("--name", "x", "--tidy").tidy is True
    assert _parse("--name", "x", "--loud", "--no-loud").loud is False


def test_help_comes_from_the_field_docstrings(capsys):
    assert field_docs(ToyConfig)["name"] == "who to greet, over two lines"
    with pytest.raises(SystemExit) as exit_info:
        _parse("--help")
    assert exit_info.value.code == 0
    text = " ".join(capsys.readouterr().out.split())
    assert "--name NAME who to greet, over two lines" in text
    assert "--times TIMES how often (default: 2)" in text
    assert "--dir DIR where to write (default: out)" in text
    assert "--mode a|b which mode" in text and "--messy" in text


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--times", "3"], "required: --name"),
        (["--name", "x", "--times", "many"], "invalid int value: 'many'"),
        (["--name", "x", "--mode", "c"], "invalid choice: 'c'"),
        (["--name", "x", "--size", "1"], "expected 2 arguments"),
        (["--name", "x", "--tidy", "--messy"], "not allowed with"),
        (["--name", "x", "--times", "0"], "--times must be at least 1"),
        (["--name", "x", "--colour", "red"], "unrecognized arguments: --colour red"),
    ],
)
def test_bad_input_is_one_line_and_exit_2(capsys, argv, message):
    assert _toy_main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and message in err and err.count("\n") == 1


def test_programming_errors_keep_their_traceback(capsys):
    @command
    def broken(argv: list[str]) -> int:
        raise ValueError("operands could not be broadcast together")

    with pytest.raises(ValueError, match="broadcast"):
        broken([])
    assert capsys.readouterr().err == ""


def test_interrupt_and_os_errors(capsys):
    @command(interrupted="interrupted; continue with --resume")
    def interrupted(argv: list[str]) -> int:
        raise KeyboardInterrupt

    @command
    def disk_full(argv: list[str]) -> None:
        raise OSError(28, "No space left on device")

    assert interrupted([]) == 130
    assert capsys.readouterr().err == "interrupted; continue with --resume\n"
    assert disk_full([]) == 1
    assert capsys.readouterr().err == "error: [Errno 28] No space left on device\n"


def test_usage_error_is_a_value_error_and_defaults_can_be_overridden():
    assert issubclass(UsageError, ValueError)
    parser = CommandParser(prog="toy")
    add_config_options(parser, ToyConfig, defaults={"times": 9})
    assert config_from_args(ToyConfig, parser.parse_args(["--name", "x"])).times == 9


def test_unsupported_field_types_are_refused():
    @dataclass
    class Bad:
        pair: tuple[int, str] = (1, "a")

    with pytest.raises(TypeError, match="one type"):
        add_config_options(CommandParser(prog="bad"), Bad)


def test_only_rank_zero_talks(monkeypatch):
    root = logging.getLogger()
    monkeypatch.setattr(root, "handlers", [])
    monkeypatch.setattr(root, "level", logging.WARNING)
    monkeypatch.setenv("RANK", "1")
    configure_logging(verbose=True)
    assert root.level == logging.WARNING
    root.handlers = []
    monkeypatch.setenv("RANK", "0")
    configure_logging(verbose=True)
    assert root.level == logging.DEBUG
    root.handlers = []
    monkeypatch.delenv("RANK")
    configure_logging()
    assert root.level == logging.INFO and len(root.handlers) == 1


@pytest.mark.parametrize(
    ("module", "options"),
    [
        (
            "dataset_tools.build",
            "--source --input --out --texts --index --body-model --mapping "
            "--fps --up --bvh-scale --drop-first-frame --keep-first-frame --target-skeleton --splits "
            "--max-seconds --workers --force --seed",
        ),
        (
            "t2m.sample",
            "--text --text-file --num-samples --length --seconds --seed --checkpoints "
            "--out --overwrite --render --bvh --device --batch-size --threads --precision",
        ),
        ("dataset_tools.synth.cli", "--out --clips --seed --heldout-phrasings --workers --force"),
        ("t2m.bench", "--only --quick --out --compare"),
    ],
)
def test_documented_options_are_generated(capsys, module, options):
    main = importlib.import_module(module).main
    with pytest.raises(SystemExit):
        main(["--help"])
    text = capsys.readouterr().out
    for name in options.split():
        assert f"{name} " in text or f"{name}," in text or f"{name}\n" in text, name
    if module == "t2m.sample":
        assert "auto, cpu, cuda or cuda:N (auto: CUDA when present) (default: auto)" in " ".join(
            text.split()
        )


def test_parse_config_is_options_parsing_and_checks_in_one_call():
    from dataclasses import dataclass

    from dataset_tools.command import CommandParser, UsageError, parse_config

    @dataclass
    class Greet:
        times: int = 1
        """how often"""

        def __post_init__(self):
            if self.times < 1:
                raise UsageError("--times must be at least 1")

    assert parse_config(CommandParser(prog="greet"), Greet, ["--times", "3"]) == Greet(3)
    with pytest.raises(UsageError, match="--times must be at least 1"):
        parse_config(CommandParser(prog="greet"), Greet, ["--times", "0"])
    with pytest.raises(UsageError, match="invalid int value"):
        parse_config(CommandParser(prog="greet"), Greet, ["--times", "x"])


@dataclass
class ToyRequest:
    """A request read from JSON: the same type table as the options."""

    mode: Literal["a", "b"]
    """which mode"""
    times: int = 1
    """how often"""
    scale: float | None = None
    """optional scale"""
    tags: tuple[str, ...] = ()
    """zero or more tags"""
    source: Path | np.ndarray | None = None
    """a file, or an array"""


def test_json_objects_are_read_by_the_same_type_table(tmp_path):
    from dataset_tools.command import config_from_dict

    request = config_from_dict(
        ToyRequest,
        {"mode": "b", "times": 3, "scale": 2, "tags": ["x", "y"], "source": "walk.npy"},
        "toy",
        files=tmp_path,
    )
    assert request.times == 3 and request.scale == 2.0 and isinstance(request.scale, float)
    assert request.tags == ("x", "y") and request.source == tmp_path / "walk.npy"
    inline = config_from_dict(ToyRequest, {"mode": "a", "source": [[1, 2, 3]]}, "toy")
    np.testing.assert_array_equal(inline.source, [[1.0, 2.0, 3.0]])
    assert config_from_dict(ToyRequest, {"mode": "a", "scale": None}, "toy").scale is None


@pytest.mark.parametrize(
    ("data", "message"),
    [
        ({"mode": "x"}, "toy.mode must be one of a, b; got 'x'"),
        ({}, "toy.mode is required"),
        ({"mode": "a", "times": True}, "toy.times must be a whole number; got True"),
        ({"mode": "a", "scale": "2"}, "toy.scale must be a number; got '2'"),
        ({"mode": "a", "scale": float("nan")}, "toy.scale must be a number; got nan"),
        ({"mode": "a", "tags": "x"}, "toy.tags must be a list of texts; got 'x'"),
        (
            {"mode": "a", "loud": 1},
            "toy: unknown field 'loud'; use mode, times, scale, tags, source",
        ),
        ({"mode": "a", "source": "/etc/passwd"}, "toy.source must be an array of numbers"),
        ([1], "toy must be a JSON object, got list"),
    ],
)
def test_json_errors_name_the_field_in_one_line(data, message):
    from dataset_tools.command import config_from_dict

    with pytest.raises(UsageError) as error:
        config_from_dict(ToyRequest, data, "toy")  # files=None: file names are refused
    assert str(error.value).startswith(message) and "\n" not in str(error.value)


def test_union_fields_become_the_option_of_their_first_spellable_type():
    parser = CommandParser(prog="toy")
    add_config_options(parser, ToyRequest, unset=True)
    from dataset_tools.command import given_fields

    given = given_fields(ToyRequest, parser.parse_args(["--mode", "a", "--source", "w.npy"]))
    assert given == {"mode": "a", "source": Path("w.npy")}
    assert given_fields(ToyRequest, parser.parse_args([])) == {}


@dataclass
class ToyCount:
    """A field whose JSON key differs from its option's name."""

    num_samples: int = field(default=1, metadata=option(metavar="N", key="samples"))
    """how many"""
    seed: int = 0
    """random seed"""
    batch_size: int = 4
    """the command line's only"""


def test_a_json_key_renames_a_field_in_json_only():
    from dataset_tools.command import fields_from_dict, json_key

    parser = CommandParser(prog="toy")
    add_config_options(parser, ToyCount)
    assert parser.parse_args(["--num-samples", "3"]).num_samples == 3
    assert [json_key(f) for f in fields(ToyCount)] == ["samples", "seed", "batch_size"]
    assert fields_from_dict(ToyCount, {"samples": 3}, "toy") == {"num_samples": 3}
    with pytest.raises(UsageError, match=r"^toy.samples must be a whole number; got '3'$"):
        fields_from_dict(ToyCount, {"samples": "3"}, "toy")
    with pytest.raises(UsageError, match="unknown field 'num_samples'; use samples, seed"):
        fields_from_dict(ToyCount, {"num_samples": 3}, "toy")


def test_a_reader_of_some_fields_names_the_keys_other_readers_take():
    from dataset_tools.command import fields_from_dict

    # the whole request, no prefix: the key alone names the field
    with pytest.raises(UsageError, match=r"^seed must be a whole number; got 1.5$"):
        fields_from_dict(ToyCount, {"seed": 1.5}, "")
    read = fields_from_dict(
        ToyCount, {"seed": 2, "mode": "x"}, "", only=("seed",), others=("mode",)
    )
    assert read == {"seed": 2}
    with pytest.raises(UsageError) as error:
        fields_from_dict(ToyCount, {"batch_size": 2}, "", only=("seed",), others=("mode",))
    assert str(error.value) == "unknown field 'batch_size'; use seed, mode"
    with pytest.raises(UsageError, match="^the object must be a JSON object, got list$"):
        fields_from_dict(ToyCount, [1], "")
