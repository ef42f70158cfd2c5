"""Hostile inputs to ``python -m t2m.edit`` (and the prompt file of ``t2m.sample``): a bad one must
end in exit status 2 with one ``error:`` line and no traceback, before any generation, and write
nothing; a good one that runs long must say how far it is. Built on the tiny run of
``tests/conftest.py``.

Cases per area (issue 31, second round):

* tracebacks (overflowing times, JSON nested too deep or with 400-digit numbers, batch values
  out of range, coordinates whose distances overflow, a 400-digit time from Python): 14 cases;
* memory exhaustion (a source resampled without bound, a million candidates, a search larger
  than memory, a path of too many rows, a batch of too many edits): 5 cases;
* silent fixes and needless refusals (``--source-fps 0`` taken as 20 fps, a byte-order mark kept
  as a prompt's first character, a ``--batch`` file with one refused): 3 cases;
* long runs (a compose timeline of too many lines or seconds, no progress while composing or
  searching): 4 cases;
* messages naming the input (refusals of a --path, --keys, --source or --timeline file name
  it; a --batch refusal names the edit and its JSON key, not the command's option): 9 cases.
"""

from __future__ import annotations

import json
import logging
import warnings
from pathlib import Path

import numpy as np
import pytest
from conftest import synth_joints

from dataset_tools.command import UsageError
from dataset_tools.spec import HUMANML3D
from t2m.edit.__main__ import main
from t2m.edit.modes import read_path

DEEP = "[" * 100_000 + "]" * 100_000
HUGE = "9" * 400


@pytest.fixture(scope="module")
def walk_file(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("edit_inputs") / "walk.npy"
    np.save(path, synth_joints("walk_forward", 101, np.random.default_rng(3)))
    return path


def refused(capsys, argv: list[str], out: Path, *needles: str) -> str:
    """``main(argv)`` exits 2 with one ``error:`` line holding every needle and writes nothing."""
    assert main([*argv, "--out", str(out), "--render", "none"]) == 2
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), err
    assert all(needle in lines[0] for needle in needles), lines[0]
    assert not out.exists()
    return lines[0]


# ------------------------------------------------------------------------- tracebacks


@pytest.mark.parametrize(
    ("options", "needle"),
    [
        (["--mode", "continue", "--keep-seconds", "1e308"], "--keep-seconds must be from 0"),
        (["--mode", "continue", "--seconds", "1e308"], "--seconds must be from 0"),
        (["--mode", "inbetween", "--keep-end", "1e308"], "--keep-end must be from 0"),
    ],
)
def test_huge_seconds_options_are_refused(tiny_run, tmp_path, walk_file, capsys, options, needle):
    argv = [*options, "--text", "a person walks", "--source", str(walk_file)]
    refused(capsys, [*argv, "--checkpoints", str(tiny_run)], tmp_path / "out", needle)


@pytest.mark.parametrize(
    ("lines", "needle"),
    [(["a person walks#0#1e308"], "ends at 1e+308 s"), (["a person walks#1e308"], "ends at")],
)
def test_huge_timeline_times_are_refused(tiny_run, tmp_path, capsys, lines, needle):
    argv = ["--mode", "compose", "--timeline", *lines, "--checkpoints", str(tiny_run)]
    refused(capsys, argv, tmp_path / "out", needle)


@pytest.mark.parametrize(
    ("name", "content", "needle"),
    [
        ("late.csv", "0,0,0\n1e308,0.5,0.5\n", "at most 3600 s"),
        ("deep.json", DEEP, "nested too deep"),
        ("huge.json", f"[[{HUGE}, 0, 0]]", "has 400 digits; at most 30"),
    ],
)
def test_hostile_path_files_are_refused(tiny_run, tmp_path, capsys, name, content, needle):
    (tmp_path / name).write_text(content)
    argv = ["--mode", "path", "--text", "a person walks", "--path", str(tmp_path / name),
            "--checkpoints", str(tiny_run)]  # fmt: skip
    refused(capsys, argv, tmp_path / "out", "--path" if name != "late.csv" else "path", needle)


@pytest.mark.parametrize("mode", ["path", "keys"])
def test_huge_coordinates_are_one_line_without_warnings(tiny_run, tmp_path, capsys, mode):
    if mode == "path":
        np.savetxt(tmp_path / "far.csv", [[1.0, 1e308, 0.0], [2.0, -1e308, 0.0]], delimiter=",")
        given = ["--path", str(tmp_path / "far.csv")]
    else:
        keys = np.full((20, 22, 3), np.nan)
        keys[5, 0] = [1e308, 0.0, 1e308]
        np.save(tmp_path / "far.npy", keys)
        given = ["--keys", str(tmp_path / "far.npy")]
    argv = ["--mode", mode, "--text", "a person walks", *given, "--checkpoints", str(tiny_run)]
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # an overflow warning would be a second stderr line
        refused(capsys, argv, tmp_path / "out", "inf m/s", "cannot get there in time")


@pytest.mark.parametrize(
    ("content", "needle"),
    [
        (DEEP, "nested too deep"),
        (
            f'[{{"mode": "path", "text": "x", "path": [[1, 0, 0]], "seconds": {HUGE}}}]',
            "a number in --batch",
        ),  # fmt: skip
        (
            '[{"mode": "path", "text": "x", "path": [[1, 0, 0]], "seconds": 1e308}]',
            "edits[0]: seconds must be from 0",
        ),  # fmt: skip
    ],
)
def test_hostile_batch_files_are_refused(tmp_path, capsys, content, needle):
    (tmp_path / "edits.json").write_text(content)
    refused(capsys, ["--batch", str(tmp_path / "edits.json")], tmp_path / "out", needle)


def test_a_huge_integer_time_from_python_is_refused():
    from t2m.edit import EditRequest

    with pytest.raises(UsageError, match="--seconds must be from 0 to 3600 seconds, got a huge"):
        EditRequest(mode="path", text="a person walks", path=[[1.0, 0.0, 0.0]], seconds=10**400)


# ------------------------------------------------------------------------- memory


def test_a_source_resampled_without_bound_is_refused(tiny_run, tmp_path, walk_file, capsys):
    argv = ["--mode", "body", "--text", "a person waves", "--source", str(walk_file),
            "--source-fps", "1e-4", "--checkpoints", str(tiny_run)]  # fmt: skip
    # 101 frames at 1e-4 fps would be 20 million frames at 20 fps
    refused(capsys, argv, tmp_path / "out", "lasts 1010000 s", "at most 3600 s: trim it")
    argv[-3] = "5000"
    refused(capsys, argv, tmp_path / "out", "--source-fps must be above 0 and at most 1000")


def test_a_million_candidates_are_refused(tmp_path, capsys):
    argv = ["--mode", "path", "--text", "a person walks", "--path", str(tmp_path / "p.csv"),
            "--candidates", "1000000"]  # fmt: skip
    refused(capsys, argv, tmp_path / "out", "--candidates 1000000: at most 4096")


def test_a_search_larger_than_memory_is_refused(tiny_run, tmp_path, walk_file, capsys):
    argv = ["--mode", "continue", "--text", "a person walks", "--source", str(walk_file),
            "--candidates", "4096", "--num-samples", "100000",
            "--checkpoints", str(tiny_run)]  # fmt: skip
    refused(capsys, argv, tmp_path / "out", "GiB of memory", "lower --candidates or --num-samples")


def test_a_path_of_too_many_rows_is_refused(tmp_path):
    rows = np.stack([np.arange(1, 10_002) * 0.01, np.zeros(10_001), np.zeros(10_001)], axis=1)
    with pytest.raises(UsageError, match="at most 10000"):
        read_path(rows)
    np.savetxt(tmp_path / "long.csv", rows, delimiter=",")
    with pytest.raises(UsageError, match="at most 10000"):
        read_path(tmp_path / "long.csv")


def test_a_batch_of_too_many_edits_is_refused(tiny_run, tmp_path, capsys):
    edit = {"mode": "path", "text": "a person walks", "path": [[1.0, 0.2, 0.8]]}
    (tmp_path / "edits.json").write_text(json.dumps([edit] * 10_001))
    argv = ["--batch", str(tmp_path / "edits.json"), "--checkpoints", str(tiny_run)]
    refused(capsys, argv, tmp_path / "out", "10001 edits; at most 10000", "split the file")


# ------------------------------------------------------------------------- silent fixes


def test_source_fps_zero_is_refused(tmp_path, walk_file, capsys):
    argv = ["--mode", "continue", "--text", "a person walks", "--source", str(walk_file),
            "--source-fps", "0"]  # fmt: skip
    refused(capsys, argv, tmp_path / "out", "--source-fps must be above 0")
    from t2m.edit.source import load_source

    with pytest.raises(UsageError, match="--source-fps must be above 0"):
        load_source(walk_file, HUMANML3D, fps=0)


def test_prompt_file_byte_order_mark_is_dropped(tmp_path):
    from t2m.prompts import read_prompt_file

    (tmp_path / "prompts.txt").write_bytes("\ufeffa person walks#40\na person jumps\n".encode())
    prompts = read_prompt_file(tmp_path / "prompts.txt")
    assert [p.text for p in prompts] == ["a person walks", "a person jumps"]
    assert prompts[0].frames == 40


# ------------------------------------------------------------------------- long runs


def test_a_timeline_of_too_many_lines_is_refused(tiny_run, tmp_path, capsys):
    lines = "".join(f"a person walks#{0.2 * i:.1f}#{0.2 * (i + 1):.1f}\n" for i in range(1000))
    (tmp_path / "timeline.txt").write_text(lines)
    argv = ["--mode", "compose", "--timeline", str(tmp_path / "timeline.txt"),
            "--checkpoints", str(tiny_run)]  # fmt: skip
    refused(capsys, argv, tmp_path / "out", "1000 lines", "--max-timeline-lines")


def test_a_timeline_of_too_many_seconds_is_refused(tiny_run, tmp_path, capsys):
    argv = ["--mode", "compose", "--timeline", "a person walks#0#300", "a person runs#300#900",
            "--checkpoints", str(tiny_run)]  # fmt: skip
    refused(capsys, argv, tmp_path / "out", "line 2", "600 s", "--max-timeline-seconds")
    lower = [*argv, "--max-timeline-seconds", "100"]  # the limit is the user's to set
    refused(capsys, lower, tmp_path / "out", "line 1", "100 s")


def test_compose_logs_its_progress(tiny_run, caplog):
    from t2m.edit import SearchSettings, edit
    from t2m.pipeline import TextToMotion

    pipe = TextToMotion.from_checkpoints(tiny_run, need_length_model=False)
    with caplog.at_level(logging.INFO, logger="t2m.edit"):
        edit(pipe, "", "compose", timeline=["a person walks#0#12"],
             settings=SearchSettings(candidates=1, steps=0))  # fmt: skip
    windows = [r.getMessage() for r in caplog.records if "compose: window" in r.getMessage()]
    assert len(windows) == 2 and windows[0].startswith("compose: window 1/2"), windows


def test_edits_log_their_search(tiny_run, caplog):
    from t2m.edit import SearchSettings, edit
    from t2m.pipeline import TextToMotion

    pipe = TextToMotion.from_checkpoints(tiny_run, need_length_model=False)
    with caplog.at_level(logging.INFO, logger="t2m.edit"):
        edit(pipe, "a person walks", "path", path=[[1.0, 0.2, 0.8]],
             settings=SearchSettings(method="optimize", candidates=2, steps=2))  # fmt: skip
    searches = [r.getMessage() for r in caplog.records if r.getMessage().startswith("search ")]
    assert searches == ["search 1/1: 1 results of 1.2 s, 2 candidates each, 2 optimisation steps"]


def test_batch_file_byte_order_mark_is_dropped(tmp_path):
    (tmp_path / "edits.json").write_bytes(
        ("\ufeff" + json.dumps([{"mode": "path", "text": "x", "path": [[1, 0, 0]]}])).encode()
    )
    from t2m.edit.__main__ import read_batch

    assert read_batch(tmp_path / "edits.json")[0].mode == "path"


# ------------------------------------------------------------------------- messages naming the input


def test_path_file_refusals_name_the_file(tiny_run, tmp_path, capsys):
    (tmp_path / "back.csv").write_text("t,x,z\n1,0,0.5\n0.5,0,1\n")
    argv = ["--mode", "path", "--text", "a person walks", "--path", str(tmp_path / "back.csv"),
            "--checkpoints", str(tiny_run)]  # fmt: skip
    refused(capsys, argv, tmp_path / "out", f"--path {tmp_path / 'back.csv'}", "increasing")


def test_keys_file_refusals_name_the_file(tiny_run, tmp_path, capsys):
    np.save(tmp_path / "flat.npy", np.zeros((20, 21, 3)))
    argv = ["--mode", "keys", "--text", "a person walks", "--keys", str(tmp_path / "flat.npy"),
            "--checkpoints", str(tiny_run)]  # fmt: skip
    refused(capsys, argv, tmp_path / "out", f"--keys {tmp_path / 'flat.npy'} must be (T, 22, 3)")


def test_a_source_file_too_short_is_named(tiny_run, tmp_path, capsys):
    np.save(tmp_path / "blink.npy", synth_joints("walk_forward", 3, np.random.default_rng(3)))
    argv = ["--mode", "body", "--text", "a person waves", "--source", str(tmp_path / "blink.npy"),
            "--checkpoints", str(tiny_run)]  # fmt: skip
    refused(capsys, argv, tmp_path / "out", f"--source {tmp_path / 'blink.npy'} has 3 frames")


def test_timeline_file_refusals_name_the_file(tiny_run, tmp_path, capsys):
    (tmp_path / "story.txt").write_text("a person walks#0#2\na person waves#3#4\n")
    argv = ["--mode", "compose", "--timeline", str(tmp_path / "story.txt"),
            "--checkpoints", str(tiny_run)]  # fmt: skip
    refused(capsys, argv, tmp_path / "out", f"--timeline {tmp_path / 'story.txt'} line 2", "a gap")


@pytest.mark.parametrize(
    ("edit", "needles"),
    [
        ({"keep_seconds": 1e308}, ["edits[1]: keep_seconds must be from 0 to 3600"]),
        ({"keep_seconds": 30}, ["edits[1]: keep_seconds 30 is past the source's end"]),
        ({"source_fps": 0}, ["edits[1]: source_fps must be above 0"]),
        ({"mode": "path"}, ["edits[1]: mode path takes no source"]),
        ({"source": "missing.npy"}, ["edits[1]: ", "missing.npy"]),
    ],
    ids=["range", "past-the-end", "fps", "inputs", "file"],
)
def test_batch_refusals_name_the_edit_and_its_json_key(
    tiny_run, tmp_path, capsys, walk_file, edit, needles
):
    good = {"mode": "path", "text": "a person walks", "path": [[1.0, 0.2, 0.8]]}
    bad = {"mode": "continue", "text": "a person sits", "source": str(walk_file), **edit}
    (tmp_path / "edits.json").write_text(json.dumps([good, bad]))
    argv = ["--batch", str(tmp_path / "edits.json"), "--checkpoints", str(tiny_run)]
    line = refused(capsys, argv, tmp_path / "out", f"--batch {tmp_path / 'edits.json'}", *needles)
    assert "--keep-seconds" not in line and "--source" not in line, line
