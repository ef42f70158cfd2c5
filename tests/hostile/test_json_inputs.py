"""Hostile JSON (issue 31, second round): the project's one strict reader,
:func:`dataset_tools.io.parse_json` / :func:`dataset_tools.io.read_json`, and every reader of a
user's JSON that goes through it (the web's request bodies, ``t2m.edit --batch``, ``--path``
JSON files, BVH mapping files, a source folder's ``source.json``). A refusal is one line naming
the file or "the request body"; nothing is parsed before the nesting is checked.

Cases:

* the reader itself (16 cases): nesting 100,000 deep, a 400-digit whole number, a 40-digit
  float, 1e400, NaN, -Infinity, a key given twice, malformed JSON (with its line and column),
  a file over its size bound, a file not UTF-8, a folder or no file, a byte-order mark
  (taken); brackets inside strings do not count as nesting, the nesting check agrees with a
  character scan (3 chunk sizes) and takes linear time on 2 MB of unterminated escaped quotes;
* the same hostile text is refused alike by each reader (4 readers x 3 texts: 12 cases), and
  ``source.json`` goes through the reader too (1 case).
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import pytest

from dataset_tools.command import UsageError
from dataset_tools.io import MAX_JSON_DEPTH, json_depth, parse_json, read_json

DEEP = "[" * 100_000 + "]" * 100_000
HUGE = "9" * 400


@pytest.mark.parametrize(
    ("text", "message"),
    [
        (DEEP, "x.json is nested too deep for a JSON input: 100000 levels; at most 32"),
        (f"[{HUGE}]", "a number in x.json has 400 digits; at most 30"),
        ("[0." + "1" * 40 + "]", "a number in x.json has 41 digits; at most 30"),
        ('{"a": 1e400}', "the number 1e400 in x.json is too large for a float"),
        ("[NaN]", "NaN in x.json is not a JSON number: give a finite number"),
        ("[-Infinity]", "-Infinity in x.json is not a JSON number: give a finite number"),
        ('{"seconds": 2, "seconds": 3}', "x.json: the key 'seconds' appears twice in one object"),
        ('{"a": [1, 2}', "x.json is not valid JSON (line 1, column 12: Expecting ',' delimiter)"),
    ],
    ids=["deep", "digits", "float-digits", "1e400", "nan", "infinity", "twice", "malformed"],
)
def test_the_reader_refuses_in_one_line_naming_the_input(text, message):
    with pytest.raises(UsageError) as error:
        parse_json(text, "x.json")
    assert str(error.value) == message


def test_brackets_inside_strings_are_not_nesting():
    text = json.dumps({"text": "[" * 1000, "rows": [[1.5, -2], [0.25, 1e-300]]})
    assert json_depth(text) == 3
    assert parse_json(text, "x")["text"] == "[" * 1000
    assert parse_json("[" * MAX_JSON_DEPTH + "]" * MAX_JSON_DEPTH, "x") is not None


def _depth_by_characters(text: str) -> int:
    """The nesting of ``text`` read a character at a time (what :func:`json_depth` finds with
    arrays): a quote opens or closes a string unless an odd number of backslashes precedes it."""
    depth = deepest = run = 0
    inside = False
    for character in text:
        if character == '"' and run % 2 == 0:
            inside = not inside
        elif not inside and character in "[{":
            depth += 1
            deepest = max(deepest, depth)
        elif not inside and character in "]}":
            depth -= 1
        run = run + 1 if character == "\\" else 0
    return deepest


@pytest.mark.parametrize("chunk", [1, 7, 1 << 20])
def test_the_nesting_check_agrees_with_a_character_scan(monkeypatch, chunk):
    import random

    import dataset_tools.io

    monkeypatch.setattr(dataset_tools.io, "_DEPTH_CHUNK", chunk)  # state carried across chunks
    rng = random.Random(chunk)
    for size in (1, 5, 50, 300):
        for _ in range(100):
            text = "".join(rng.choice('[]{}"\\a') for _ in range(size))
            assert json_depth(text) == _depth_by_characters(text), text


def test_unterminated_escaped_quotes_are_checked_in_linear_time():
    # a regular expression for strings tried again from each escaped quote took 25 s for 80 KB
    text = '"' + '\\"' * 1_000_000
    started = time.perf_counter()
    assert json_depth(text) == 0
    with pytest.raises(UsageError, match="not valid JSON"):
        parse_json(text, "x")
    assert time.perf_counter() - started < 10


def test_a_file_over_its_bound_or_not_utf8_is_refused_naming_it(tmp_path):
    (tmp_path / "big.json").write_text("[" + "0," * 600 + "0]")
    with pytest.raises(UsageError, match=r"^--batch .*big\.json is 1\.2 KiB; a JSON input here is"):
        read_json(tmp_path / "big.json", "--batch", max_bytes=1024)
    (tmp_path / "latin.json").write_bytes(b'{"text": "caf\xe9"}')
    with pytest.raises(UsageError, match=r"latin\.json is not UTF-8 text$"):
        read_json(tmp_path / "latin.json")


def test_a_folder_or_a_missing_file_is_refused_naming_it(tmp_path):
    with pytest.raises(UsageError, match=r"^--batch .* is a folder, not a JSON file$"):
        read_json(tmp_path, "--batch")
    with pytest.raises(UsageError, match=r"^--batch .*gone\.json: no such file$"):
        read_json(tmp_path / "gone.json", "--batch")


def test_a_byte_order_mark_is_taken(tmp_path):
    (tmp_path / "bom.json").write_bytes("\ufeff[1, 2.5]".encode())
    assert read_json(tmp_path / "bom.json") == [1, 2.5]


# -- every reader of a user's JSON goes through it ----------------------------------------------


def _batch(path: Path):
    from t2m.edit.__main__ import read_batch

    return read_batch(path)


def _path(path: Path):
    from t2m.edit.modes import read_path

    return read_path(path)


def _mapping(path: Path):
    from dataset_tools.sources.bvh import load_mapping

    return load_mapping(str(path))


def _web(path: Path):
    from t2m.serve.api import read_json as read_body

    return read_body(path.read_text())


READERS = {"batch": _batch, "path": _path, "mapping": _mapping, "web": _web}
HOSTILE = {
    "deep": (DEEP, "nested too deep"),
    "digits": (f'{{"a": [[1, {HUGE}, 0]]}}', "has 400 digits; at most 30"),
    "twice": ('{"mode": "path", "mode": "keys"}', "appears twice"),
}


@pytest.mark.parametrize("text_name", HOSTILE)
@pytest.mark.parametrize("reader", READERS)
def test_every_reader_refuses_hostile_json_alike(tmp_path, reader, text_name):
    text, needle = HOSTILE[text_name]
    path = tmp_path / "input.json"
    path.write_text(text)
    with pytest.raises(UsageError) as error:
        READERS[reader](path)
    message = str(error.value)
    assert needle in message and "\n" not in message, message
    assert ("the request body" if reader == "web" else str(path)) in message, message


def test_source_json_goes_through_it(tmp_path):
    from dataset_tools.sources.joints import read_source_config

    (tmp_path / "source.json").write_text('{"fps": 20, "fps": 30}')
    with pytest.raises(UsageError, match="source.json: the key 'fps' appears twice"):
        read_source_config(tmp_path)
