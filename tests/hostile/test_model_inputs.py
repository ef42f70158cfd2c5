"""Hostile and careless inputs to the model commands: sample, train, evaluate, render, export,
demo. Each bad input must end in exit status 2 with one line on stderr and no traceback, before
any long work; nothing the user made may be lost; a killed run must leave a state the next run
resumes or cleans up. Built on the tiny fixtures of ``tests/conftest.py``.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import torch

from dataset_tools.command import UsageError
from t2m import export, outputs, render, sample
from t2m.demo import DemoConfig, run_demo
from t2m.evaluate.__main__ import main as evaluate_main
from t2m.prompts import Prompt
from t2m.train.__main__ import main as train_main
from t2m.train.checkpoint import read_checkpoint

ROOT = Path(__file__).resolve().parents[2]


def one_line(err: str, *needles: str) -> None:
    """``err`` is exactly one ``error: ...`` line holding every needle (after any progress bar
    that cleared itself with a carriage return, as a terminal shows it)."""
    assert err.count("\n") == 1 and err.endswith("\n"), err
    err = err.rsplit("\r", 1)[-1]
    assert err.startswith("error: "), err
    assert "Traceback" not in err and all(needle in err for needle in needles), err


def run_command(*argv: str, timeout: float = 120) -> subprocess.CompletedProcess:
    """``python -m ...`` in a real subprocess from the repository root."""
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    return subprocess.run(
        [sys.executable, *argv], capture_output=True, text=True, cwd=ROOT, env=env, timeout=timeout
    )


def dead_pid() -> int:
    """The id of a process that has just ended (not reused this soon)."""
    child = subprocess.Popen([sys.executable, "-c", "pass"])
    child.wait()
    return child.pid


def snapshot(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in folder.rglob("*") if p.is_file()}


# ------------------------------------------------------------------------------------- sample


def _sample(capsys, run_dir: Path, out: Path, *argv: str) -> tuple[int, str]:
    base = ["--checkpoints", str(run_dir), "--out", str(out), "--render", "none"]
    code = sample.main(["--text", "a person walks forward", *base, *argv])
    return code, capsys.readouterr().err


def test_overwrite_never_replaces_a_folder_we_did_not_write(tiny_run, tmp_path, capsys):
    # A folder that merely holds a results.json (the old test of "ours") is the user's.
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "results.json").write_text("{}")
    (mine / "thesis.tex").write_text("years of work")
    before = snapshot(mine)
    code, err = _sample(capsys, tiny_run, mine, "--length", "40", "--overwrite")
    assert code == 2
    one_line(err, "--overwrite refuses", outputs.MARKER)
    assert snapshot(mine) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["mine"]  # no temp folder either


def test_overwrite_replaces_our_folder_only_while_it_holds_nothing_else(tiny_run, tmp_path, capsys):
    out = tmp_path / "out"
    assert _sample(capsys, tiny_run, out, "--length", "40")[0] == 0
    (out / "notes.txt").write_text("my notes")
    before = snapshot(out)
    code, err = _sample(capsys, tiny_run, out, "--length", "44", "--overwrite")
    assert code == 2
    one_line(err, "notes.txt", "not written by t2m.sample")
    assert snapshot(out) == before
    # a file of ours replaced by a folder of the user's is not ours either
    (out / "notes.txt").unlink()
    (out / "sample00_rep00.bvh").mkdir()
    (out / "sample00_rep00.bvh" / "keep").write_text("x")
    assert _sample(capsys, tiny_run, out, "--length", "44", "--overwrite")[0] == 2
    shutil.rmtree(out / "sample00_rep00.bvh")
    code, err = _sample(capsys, tiny_run, out, "--length", "44", "--overwrite")
    assert code == 0, err
    assert np.load(out / "sample00_rep00.npy").shape == (44, 22, 3)


def test_stale_temp_folders_of_killed_runs_are_cleaned_and_only_ours(tiny_run, tmp_path, capsys):
    out = tmp_path / "out"
    marker = json.dumps({"written_by": "t2m.sample", "files": []})
    ours = tmp_path / f".out.{dead_pid()}.abc_1.tmp"
    alive = tmp_path / f".out.{os.getpid()}.def_2.tmp"  # a run still going: left alone
    stranger = tmp_path / f".out.{dead_pid()}.ghi_3.tmp"  # our pattern, not our marker
    for folder in (ours, alive):
        folder.mkdir()
        (folder / outputs.MARKER).write_text(marker)
        (folder / "sample00_rep00.npy").write_bytes(b"half")
    stranger.mkdir()
    (stranger / "data").write_text("someone's")
    code, err = _sample(capsys, tiny_run, out, "--length", "40")
    assert code == 0, err
    assert not ours.exists() and alive.is_dir()
    assert (stranger / "data").read_text() == "someone's"
    # a run killed between its two final renames: the replaced output is put back
    shutil.rmtree(alive)
    swapped = tmp_path / f".out.old-{dead_pid()}"
    os.replace(out, swapped)
    code, err = _sample(capsys, tiny_run, out, "--length", "40", "--overwrite")
    assert code == 0, err
    assert not swapped.exists() and (out / "results.npy").is_file()


def test_sigkill_while_sampling_leaves_nothing_the_next_run_trips_on(tiny_run, tmp_path):
    out = tmp_path / "out"
    argv = ["-m", "t2m.sample", "--text", "a person walks forward", "--checkpoints"]
    argv += [str(tiny_run), "--out", str(out), "--length", "196", "--render", "gif"]
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    child = subprocess.Popen(
        [sys.executable, *argv, "--num-samples", "30"],
        cwd=ROOT,
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    deadline = time.time() + 60
    while time.time() < deadline and not list(tmp_path.glob(".out.*.tmp/*.gif")):
        time.sleep(0.05)
    child.send_signal(signal.SIGKILL)
    child.wait()
    assert list(tmp_path.glob(".out.*.tmp")), "the run was not killed while writing"
    assert not out.exists()
    again = run_command(*argv, "--num-samples", "1", "--render", "none")
    assert again.returncode == 0, again.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]


def test_a_model_producing_nan_writes_nothing(tiny_run, tmp_path):
    from t2m.pipeline import TextToMotion

    pipe = TextToMotion.from_checkpoints(tiny_run, device="cpu")
    with torch.no_grad():
        for parameter in pipe.decoder.parameters():
            parameter.fill_(float("nan"))
    prompts = [Prompt("a person walks forward", 40)]
    with pytest.raises(UsageError, match="NaN or infinite"):
        outputs.sample_to_folder(pipe, prompts, tmp_path / "out", render="none")
    assert not list(tmp_path.iterdir())


def test_a_request_that_cannot_fit_in_memory_is_refused_up_front(tiny_run, tmp_path, capsys):
    code, err = _sample(capsys, tiny_run, tmp_path / "out", "--num-samples", str(10**9))
    assert code == 2
    one_line(err, "1000000000 motions need about", "GiB of memory", "--num-samples")
    assert not list(tmp_path.iterdir())


@pytest.mark.parametrize(
    ("argv", "needle"),
    [
        (["--seed", "-1"], "--seed must be from 0"),
        (["--seed", str(2**64)], "--seed must be from 0"),
        (["--threads", str(10**6)], "--threads must be from 0"),
        (["--seconds", "inf"], "positive number of seconds"),
        (["--seconds", "nan"], "positive number of seconds"),
        (["--length", "-4"], "positive number of frames"),
        (["--num-samples", "-3"], "at least 1"),
        (["--batch-size", "0"], "at least 1"),
        (["--render", "avi"], "invalid choice"),
    ],
)
def test_bad_sample_options(tiny_run, tmp_path, capsys, argv, needle):
    code, err = _sample(capsys, tiny_run, tmp_path / "out", *argv)
    assert code == 2
    one_line(err, needle)
    assert not list(tmp_path.iterdir())


def test_bad_prompt_files_and_output_paths(tiny_run, tmp_path, capsys):
    prompts = tmp_path / "prompts.txt"
    prompts.write_text("a person walks#-3\n")
    file = tmp_path / "file.txt"
    file.write_text("mine")
    cases = [
        (["--text-file", str(prompts)], tmp_path / "out", "positive number of frames"),
        (["--text-file", "/dev/zero"], tmp_path / "out", "is not a file"),  # would never end
        (["--text-file", str(tmp_path)], tmp_path / "out", "is not a file"),
        (["--text", "a person walks"], file, "exists and is not a folder"),
        (["--text", "a person walks"], file / "sub", "is a file, not a folder"),
    ]
    for argv, out, needle in cases:
        code = sample.main([*argv, "--checkpoints", str(tiny_run), "--out", str(out)])
        assert code == 2
        one_line(capsys.readouterr().err, needle)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["file.txt", "prompts.txt"]
    assert file.read_text() == "mine"


def test_sample_subprocess_out_is_a_file(tiny_run, tmp_path):
    file = tmp_path / "results"
    file.write_text("mine")
    argv = ["--text", "a person walks", "--checkpoints", str(tiny_run), "--out", str(file)]
    done = run_command("-m", "t2m.sample", *argv)
    assert done.returncode == 2
    one_line(done.stderr, "exists and is not a folder")
    assert file.read_text() == "mine"


# -------------------------------------------------------------------------------------- train


def _train_argv(dataset: Path, run_dir: Path, stage: str = "autoencoder") -> list[str]:
    argv = [stage, "--preset", "tiny", "--dataset", str(dataset), "--checkpoints", str(run_dir)]
    return [*argv, "--device", "cpu"]


@pytest.mark.parametrize(
    ("override", "needle"),
    [
        ("--autoencoder.epochs=-1", "autoencoder.epochs must be at least 1, got -1"),
        ("--ae.epochs=0", "autoencoder.epochs must be at least 1, got 0"),
        ("--autoencoder.batch_size=0", "autoencoder.batch_size must be at least 1"),
        ("--autoencoder.lr=nan", "autoencoder.lr must be a finite number"),
        ("--autoencoder.lr=-1", "autoencoder.lr must be positive"),
        ("--autoencoder.log_every=0", "log_every must be at least 1"),
        ("--autoencoder.max_steps=-5", "must not be negative"),
        ("--autoencoder.model.hidden_size=0", "hidden_size must be at least 1"),
        ("--length.model.mlp_sizes=8,0", "sizes of at least 1"),
        ("--generator.patience=0", "generator.patience"),
        ("--generator.kl_weight=inf", "finite number"),
        ("--seed=-1", "seed must be from 0"),
        ("--num_threads=100000", "num_threads must be from 0"),  # torch would crash
        ("--autoencoder.batch_size=1000", "fewer than one batch of autoencoder.batch_size=1000"),
    ],
)
def test_training_that_trains_nothing_is_refused_before_any_work(
    tiny_dataset, tmp_path, capsys, override, needle
):
    assert train_main([*_train_argv(tiny_dataset, tmp_path / "run"), override]) == 2
    one_line(capsys.readouterr().err, needle)
    assert not (tmp_path / "run" / "autoencoder").exists()


def test_checkpoints_under_a_file_is_refused_before_any_work(tiny_dataset, tmp_path, capsys):
    file = tmp_path / "file"
    file.write_text("mine")
    for run_dir, needle in ((file, "exists and is not a folder"), (file / "run", "is a file")):
        assert train_main(_train_argv(tiny_dataset, run_dir)) == 2
        one_line(capsys.readouterr().err, "--checkpoints", needle)
    assert file.read_text() == "mine"


def test_generator_without_a_clip_long_enough_is_refused(tiny_dataset, tiny_run, tmp_path, capsys):
    run_dir = tmp_path / "run"
    shutil.copytree(tiny_run / "autoencoder", run_dir / "autoencoder")
    # 40 snippets are 160 frames; the tiny clips are 50 to 130 frames long
    argv = [*_train_argv(tiny_dataset, run_dir, "generator"), "--generator.start_snippets=40"]
    assert train_main([*argv, "--generator.end_snippets=40"]) == 2
    one_line(capsys.readouterr().err, "0 usable clips of at least 160 frames")
    assert not (run_dir / "generator").exists()


def test_a_finished_stage_is_not_retrained_without_force(tiny_dataset, tiny_run, tmp_path, capsys):
    run_dir = tmp_path / "run"
    shutil.copytree(tiny_run / "length", run_dir / "length")
    before = snapshot(run_dir)
    argv = _train_argv(tiny_dataset, run_dir, "length")
    assert train_main(argv) == 2
    one_line(capsys.readouterr().err, "finished length run", "--resume", "--force")
    assert train_main([*argv, "--resume", "--force"]) == 2
    one_line(capsys.readouterr().err, "give one of --resume")
    assert snapshot(run_dir) == before
    # an interrupted one neither
    (run_dir / "length" / "finished.json").unlink()
    assert train_main(argv) == 2
    one_line(capsys.readouterr().err, "unfinished length run")
    assert train_main([*argv, "--force", "--length.epochs=1"]) == 0
    assert (run_dir / "length" / "best.pt").read_bytes() != before["length/best.pt"]


def test_a_forced_retrain_stopped_early_leaves_no_old_best(
    tiny_dataset, tiny_run, tmp_path, capsys, monkeypatch
):
    """--force sets the earlier run aside before it trains: a retrain stopped before its first
    validation must not leave the old best.pt for sampling (--which best) to take."""
    import t2m.train.stages as stages

    run_dir = tmp_path / "run"
    for stage in ("autoencoder", "length"):
        shutil.copytree(tiny_run / stage, run_dir / stage)
    old = snapshot(run_dir / "length")

    def killed(*args, **kwargs):
        raise KeyboardInterrupt  # the retrain stops before it validates once

    monkeypatch.setattr(stages, "StageJob", killed)
    assert train_main([*_train_argv(tiny_dataset, run_dir, "length"), "--force"]) != 0
    assert "interrupted" in capsys.readouterr().err
    assert not (run_dir / "length" / "best.pt").exists()
    assert snapshot(run_dir / "length" / "previous") == old  # recoverable, byte for byte
    monkeypatch.undo()
    # loading (what sampling and export do) no longer finds a length model there
    with pytest.raises(UsageError, match="make train-len"):
        stages.load_stage(run_dir, "length", which="best")
    # a forced retrain that finishes trains afresh; the run set aside stays as it was
    argv = [*_train_argv(tiny_dataset, run_dir, "length"), "--force", "--length.epochs=1"]
    assert train_main(argv) == 0
    assert stages.load_stage(run_dir, "length").models
    assert snapshot(run_dir / "length" / "previous") == old


def test_finished_json_is_standard_json(tiny_run):
    def refuse(constant: str) -> None:
        raise AssertionError(f"non-standard JSON constant {constant}")

    for stage in ("autoencoder", "length", "generator", "evaluator"):
        text = (tiny_run / stage / "finished.json").read_text()
        assert isinstance(json.loads(text, parse_constant=refuse), dict)


def test_sigkill_during_training_and_a_torn_metrics_line_resume(tiny_dataset, tmp_path):
    run_dir = tmp_path / "run"
    argv = ["-m", "t2m.train", *_train_argv(tiny_dataset, run_dir)]
    argv += ["--autoencoder.checkpoint_every=1", "--autoencoder.log_every=1"]
    argv += ["--autoencoder.epochs=100000"]
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    child = subprocess.Popen(
        [sys.executable, *argv],
        cwd=ROOT,
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    latest, metrics = (
        run_dir / "autoencoder" / "latest.pt",
        run_dir / "autoencoder" / "metrics.jsonl",
    )
    deadline = time.time() + 60
    while time.time() < deadline and not (latest.is_file() and metrics.is_file()):
        time.sleep(0.05)
    time.sleep(0.5)
    child.send_signal(signal.SIGKILL)
    child.wait()
    assert latest.is_file(), "training was not killed after its first checkpoint"
    with open(metrics, "a") as handle:  # what a kill in the middle of a write would leave
        handle.write('{"stage": "autoencoder", "split": "tr')
    step = read_checkpoint(latest)["progress"]["step"]
    done = run_command(*argv, "--resume", f"--autoencoder.max_steps={step + 2}")
    assert done.returncode == 0, done.stderr
    records = [json.loads(line) for line in metrics.read_text().splitlines()]
    assert records[-1]["step"] == step + 2
    assert [r["step"] for r in records if r["split"] == "train"] == sorted(
        r["step"] for r in records if r["split"] == "train"
    )


@pytest.mark.parametrize(("resume_epoch", "kept"), [(0, [(2, 0)]), (1, [(2, 0), (2, 1)])])
def test_resume_drops_torn_and_uncovered_records(tmp_path, resume_epoch, kept):
    from t2m.train.logbook import Logbook, read_records

    metrics = tmp_path / "metrics.jsonl"
    lines = [
        {"split": "train", "step": 2, "epoch": 0},
        {"split": "val", "step": 2, "epoch": 1},  # written just before a kill, not checkpointed
        {"split": "train", "step": 3, "epoch": 1},
    ]
    metrics.write_text("".join(json.dumps(line) + "\n" for line in lines) + '{"split": "tr')
    assert len(read_records(metrics)) == 3  # the torn line is skipped, not an error
    Logbook(tmp_path, "autoencoder", resume_step=2, resume_epoch=resume_epoch)
    assert [(r["step"], r["epoch"]) for r in read_records(metrics)] == kept
    assert metrics.read_text().endswith("}\n")


# ----------------------------------------------------------------------------------- evaluate


def _evaluate(capsys, dataset: Path, run_dir: Path, out: Path, *argv: str) -> tuple[int, str]:
    base = ["--dataset", str(dataset), "--checkpoints", str(run_dir), "--out", str(out)]
    code = evaluate_main([*base, "--device", "cpu", *argv])
    return code, capsys.readouterr().err


def test_one_replication_reports_no_interval(tiny_dataset, tiny_run, tmp_path, capsys):
    out = tmp_path / "out"
    small = ["--split", "all", "--replications", "1", "--mm-texts", "2", "--mm-samples", "2"]
    code, err = _evaluate(capsys, tiny_dataset, tiny_run, out, *small)
    assert code == 0, err
    table = (out / "results.md").read_text()
    assert "±n/a" in table and "±0.000" not in table
    summary = json.loads((out / "results.json").read_text())
    entries = [entry for row in summary["rows"].values() for entry in row.values()]
    assert entries and all(entry["interval"] is None for entry in entries)


def test_sigkill_during_evaluation_leaves_nothing_half_written(tiny_dataset, tiny_run, tmp_path):
    out = tmp_path / "eval"
    base = ["-m", "t2m.evaluate", "--dataset", str(tiny_dataset), "--checkpoints", str(tiny_run)]
    base += ["--out", str(out), "--split", "all", "--device", "cpu", "--mm-texts", "2"]
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    child = subprocess.Popen(
        [sys.executable, *base, "--replications", "200", "--mm-samples", "20"],
        cwd=ROOT,
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )
    # Kill it once the protocol is under way (its progress bar has started), long before the end.
    deadline, seen = time.time() + 90, ""
    while time.time() < deadline and "replication" not in seen:
        seen += child.stderr.read(1) or ""
        if child.poll() is not None:
            break
    assert child.poll() is None, f"the evaluation ended before it could be killed: {seen[-300:]}"
    child.send_signal(signal.SIGKILL)
    child.wait()
    left = sorted(p.name for p in out.rglob("*")) if out.exists() else []
    assert not [name for name in left if name.startswith("results")], left
    assert not [name for name in left if name.startswith(".")], left  # no temporary files
    again = run_command(*base, "--replications", "1", "--mm-samples", "2")
    assert again.returncode == 0, again.stderr
    assert (out / "results.md").is_file() and (out / "results.json").is_file()


@pytest.mark.parametrize(
    ("argv", "needle"),
    [
        (["--split", "all", "--max-items", "10"], "--max-items 10 is fewer than one"),
        ([], "the test split has 7 usable items"),
        (["--split", "all", "--mm-samples", str(10**9)], "GiB of memory"),
        (["--seed", "-1"], "--seed must be from 0"),
        (["--replications", "0"], "--replications must be >= 1"),
        (["--threads", "100000"], "--threads must be from 0"),
    ],
)
def test_bad_evaluation_settings_say_what_is_wrong(
    tiny_dataset, tiny_run, tmp_path, capsys, argv, needle
):
    code, err = _evaluate(capsys, tiny_dataset, tiny_run, tmp_path / "out", *argv)
    assert code == 2
    one_line(err, needle)
    assert not (tmp_path / "out").exists()


def test_evaluation_out_and_garbage_checkpoints_fail_before_the_work(
    tiny_dataset, tiny_run, tmp_path, capsys
):
    file = tmp_path / "file"
    file.write_text("mine")
    code, err = _evaluate(capsys, tiny_dataset, tiny_run, file / "results")
    assert code == 2
    one_line(err, "is a file, not a folder")
    code, err = _evaluate(capsys, tiny_dataset, tiny_run, file)
    assert code == 2
    one_line(err, "exists and is not a folder")
    assert file.read_text() == "mine"
    notes = tmp_path / "notes"
    notes.mkdir()
    (notes / "results.md").write_text("my own results")
    code, err = _evaluate(capsys, tiny_dataset, tiny_run, notes)
    assert code == 2
    one_line(err, "that no evaluation wrote")
    assert (notes / "results.md").read_text() == "my own results"
    for name, content in (("empty", b""), ("truncated", None)):
        broken = tmp_path / name
        shutil.copytree(tiny_run, broken)
        best = broken / "evaluator" / "best.pt"
        best.write_bytes(best.read_bytes()[:2000] if content is None else content)
        code, err = _evaluate(capsys, tiny_dataset, broken, tmp_path / f"out_{name}")
        assert code == 2
        one_line(err, str(best))
        assert not (tmp_path / f"out_{name}").exists()


# ------------------------------------------------------------------------ render, export, demo


def test_render_and_export_check_their_output_first(tiny_dataset, tmp_path, capsys):
    joints = tiny_dataset / "new_joints" / "000001.npy"
    before = joints.read_bytes()
    file = tmp_path / "file"
    file.write_text("mine")
    (tmp_path / "folder.gif").mkdir()
    (tmp_path / "folder.bvh").mkdir()
    cases = [
        (render.main, [str(file / "x.gif")], "is a file, not a folder"),
        (render.main, [str(tmp_path / "folder.gif")], "is a folder"),
        (render.main, [str(tmp_path / "x.gif"), "--fps", "inf"], "--fps must be positive"),
        (export.main, [str(file / "x.bvh")], "is a file, not a folder"),
        (export.main, [str(tmp_path / "folder.bvh")], "is a folder"),
        (export.main, [str(tmp_path / "x.bvh"), "--fps", "nan"], "--fps must be positive"),
    ]
    for main, argv, needle in cases:
        assert main([str(joints), *argv]) == 2
        one_line(capsys.readouterr().err, needle)
    assert joints.read_bytes() == before and file.read_text() == "mine"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["file", "folder.bvh", "folder.gif"]
    done = run_command("-m", "t2m.render", str(joints), str(file / "x.mp4"))
    assert done.returncode == 2
    one_line(done.stderr, "is a file, not a folder")


def test_demo_refuses_an_output_folder_of_the_users_before_building(tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    (out / "holiday.mp4").write_text("mine")
    config = DemoConfig(dataset=tmp_path / "data", source=tmp_path / "src", out=out)
    with pytest.raises(UsageError, match="--overwrite refuses"):
        run_demo(config)
    assert not (tmp_path / "data").exists() and not (tmp_path / "src").exists()
    assert (out / "holiday.mp4").read_text() == "mine"
