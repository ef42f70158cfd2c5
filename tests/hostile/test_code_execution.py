"""Nothing runs code from data: checkpoints, dataset arrays and Makefile variables.

The attack: a file of a working run or dataset rewritten to carry a pickle payload, an object
whose unpickling creates a marker file (:class:`Payload`; :func:`test_the_payloads_are_live`
shows that they do run under plain unpickling). Every command and API that loads such a file
must refuse it with one line naming the file, and the marker must never appear. The Makefile
must pass prompts, paths and options to the commands as text, whatever quotes, backticks,
``$(...)`` or make functions they hold.
"""

from __future__ import annotations

import json
import os
import shutil
import stat
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from dataset_tools.command import UsageError
from t2m.train.checkpoint import FORMAT_VERSION, read_checkpoint

REPO = Path(__file__).resolve().parents[2]
STAGES = ("autoencoder", "length", "generator", "evaluator")


class Payload:
    """Unpickling this creates ``marker`` (through ``builtins.exec``, as a real attack would run
    any code)."""

    def __init__(self, marker: Path):
        self.marker = str(marker)

    def __reduce__(self):
        return (exec, (f"open({self.marker!r}, 'w').close()",))


def _one_line_error(err: str, *needles: str) -> None:
    """``err`` (progress bars aside) is one ``error: ...`` line containing every needle."""
    lines = [line.rsplit("\r", 1)[-1] for line in err.split("\n")]
    lines = [line for line in lines if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: "), err
    for needle in needles:
        assert needle in lines[0], (needle, err)


def _poison(path: Path, marker: Path, where: str = "extra") -> None:
    """Rewrite the checkpoint at ``path`` with a payload hidden at ``where``."""
    checkpoint = read_checkpoint(path)
    payload = Payload(marker)
    if where == "models":  # one more entry of a state dict
        next(iter(checkpoint["models"].values()))["note"] = payload
    elif where == "optimizer":
        checkpoint["optimizer"]["param_groups"][0]["note"] = payload
    elif where == "vocabulary":
        checkpoint["vocabulary"]["words"] = [payload]
    elif where == "format-1 array":  # a numpy object array, where format 1 kept numpy arrays
        checkpoint["format_version"] = 1
        checkpoint["normalizer"]["mean"] = np.array([payload], dtype=object)
    else:
        checkpoint[where]["note"] = payload
    torch.save(checkpoint, path)


@pytest.fixture
def run(tiny_run: Path, tmp_path: Path) -> Path:
    """A copy of the session's tiny run, free to be poisoned."""
    return Path(shutil.copytree(tiny_run, tmp_path / "run"))


@pytest.fixture
def marker(tmp_path: Path) -> Path:
    return tmp_path / "marker"


# ----------------------------------------------------------------------------- the format


def test_our_checkpoints_hold_only_tensors_and_plain_types(tiny_run):
    for stage in STAGES:
        for name in ("best.pt", "latest.pt"):
            # no allow-list at all: torch's own weights-only unpickler
            checkpoint = torch.load(tiny_run / stage / name, weights_only=True)
            assert checkpoint["format_version"] == FORMAT_VERSION
            assert all(isinstance(v, torch.Tensor) for v in checkpoint["normalizer"].values())


def test_checkpoints_of_format_1_still_load(tiny_run, run):
    """The first releases stored the statistics as numpy arrays: read with numpy's float32
    array reconstruction allowed by name, and nothing else."""
    from t2m.pipeline import TextToMotion
    from t2m.train import load_stage

    for path in run.glob("*/*.pt"):
        checkpoint = read_checkpoint(path)
        checkpoint["format_version"] = 1
        checkpoint["normalizer"] = {k: v.numpy() for k, v in checkpoint["normalizer"].items()}
        torch.save(checkpoint, path)
        with pytest.raises(Exception, match="numpy"):  # torch alone refuses the arrays
            torch.load(path, weights_only=True)
    for stage in STAGES:
        old, new = load_stage(run, stage).normalizer, load_stage(tiny_run, stage).normalizer
        np.testing.assert_array_equal(old.std, new.std)
    assert TextToMotion.from_checkpoints(run, device="cpu").spec.name == "HumanML3D"


def test_the_payloads_are_live(tmp_path, marker):
    """The attack of this file works where code is unpickled: the tests below mean something."""
    torch.save({"note": Payload(marker)}, tmp_path / "evil.pt")
    torch.load(tmp_path / "evil.pt", weights_only=False)
    assert marker.is_file()
    marker.unlink()
    np.save(tmp_path / "evil.npy", np.array([Payload(marker)], dtype=object), allow_pickle=True)
    np.load(tmp_path / "evil.npy", allow_pickle=True)
    assert marker.is_file()


# ----------------------------------------------------------------------------- checkpoints


@pytest.mark.parametrize(
    "where", ["extra", "progress", "models", "optimizer", "vocabulary", "format-1 array"]
)
def test_a_payload_anywhere_in_a_checkpoint_is_refused(run, marker, where):
    path = run / "generator" / "best.pt"
    _poison(path, marker, where)
    with pytest.raises(UsageError) as refused:
        read_checkpoint(path)
    message = str(refused.value)
    assert message.startswith(f"{path}: refused without running it") and "\n" not in message
    assert not marker.exists()


@pytest.mark.parametrize("stage", ["length", "generator"])
def test_sample_refuses_a_poisoned_checkpoint(run, marker, tmp_path, capsys, stage):
    from t2m import sample

    path = run / stage / "best.pt"
    _poison(path, marker)
    argv = ["--text", "a person walks forward", "--checkpoints", str(run)]
    assert sample.main([*argv, "--out", str(tmp_path / "out"), "--render", "none"]) == 2
    _one_line_error(capsys.readouterr().err, str(path), "refused without running it")
    assert not marker.exists() and not (tmp_path / "out").exists()


def test_sample_command_line_refuses_a_poisoned_checkpoint(run, marker, tmp_path):
    path = run / "generator" / "best.pt"
    _poison(path, marker)
    argv = ["--text", "a person walks forward", "--checkpoints", str(run), "--render", "none"]
    done = subprocess.run(
        [sys.executable, "-m", "t2m.sample", *argv, "--out", str(tmp_path / "out")],
        capture_output=True,
        text=True,
        cwd=REPO,
        env={**os.environ, "PYTHONPATH": str(REPO)},
    )
    assert done.returncode == 2
    _one_line_error(done.stderr, str(path), "refused without running it")
    assert not marker.exists()


def test_the_api_refuses_a_poisoned_checkpoint(run, marker):
    from t2m.pipeline import TextToMotion

    path = run / "generator" / "best.pt"
    _poison(path, marker, "models")
    with pytest.raises(ValueError, match="refused without running it") as refused:
        TextToMotion.from_checkpoints(run, device="cpu")
    assert str(path) in str(refused.value)
    assert not marker.exists()


def test_evaluate_refuses_a_poisoned_evaluator(run, marker, tiny_dataset, tmp_path, capsys):
    from t2m.evaluate.__main__ import main

    path = run / "evaluator" / "best.pt"
    _poison(path, marker, "optimizer")
    folders = ["--dataset", str(tiny_dataset), "--checkpoints", str(run)]
    assert main([*folders, "--quick", "--out", str(tmp_path / "eval")]) == 2
    _one_line_error(capsys.readouterr().err, str(path), "refused without running it")
    assert not marker.exists()


def test_resume_refuses_a_poisoned_latest(run, marker, tiny_dataset, capsys):
    from t2m.train.__main__ import main

    path = run / "autoencoder" / "latest.pt"
    _poison(path, marker, "progress")
    poisoned = path.read_bytes()
    argv = ["autoencoder", "--preset", "tiny", "--device", "cpu", "--resume"]
    assert main([*argv, "--dataset", str(tiny_dataset), "--checkpoints", str(run)]) == 2
    _one_line_error(capsys.readouterr().err, str(path), "refused without running it")
    assert not marker.exists() and path.read_bytes() == poisoned


def test_resume_from_weights_that_do_not_fit_is_one_line(run, tiny_dataset, capsys):
    from t2m.train.__main__ import main

    path = run / "autoencoder" / "latest.pt"
    checkpoint = read_checkpoint(path)
    weights = checkpoint["models"]["autoencoder"]
    weights[next(iter(weights))] = torch.zeros(3)
    torch.save(checkpoint, path)
    argv = ["autoencoder", "--preset", "tiny", "--device", "cpu", "--resume"]
    assert main([*argv, "--dataset", str(tiny_dataset), "--checkpoints", str(run)]) == 2
    _one_line_error(capsys.readouterr().err, str(path), "cannot resume from it", "size mismatch")


def test_a_poisoned_prerequisite_is_refused(run, marker, tiny_dataset, capsys):
    from t2m.train.__main__ import main

    shutil.rmtree(run / "generator")  # a generator not trained yet: it loads the autoencoder
    path = run / "autoencoder" / "best.pt"
    _poison(path, marker)
    argv = ["generator", "--preset", "tiny", "--device", "cpu"]
    assert main([*argv, "--dataset", str(tiny_dataset), "--checkpoints", str(run)]) == 2
    _one_line_error(capsys.readouterr().err, str(path), "refused without running it")
    assert not marker.exists() and not (run / "generator").exists()


def _rewrite(path: Path, change: str) -> None:
    """Make the checkpoint at ``path`` malformed in one way (no payload)."""
    if change in ("garbage", "empty", "torn"):
        data = {"garbage": bytes(range(256)), "empty": b"", "torn": path.read_bytes()[:1000]}
        path.write_bytes(data[change])
        return
    checkpoint = read_checkpoint(path)
    if change == "not ours":
        checkpoint = {"state_dict": checkpoint["models"]}
    elif change == "future format":
        checkpoint["format_version"] = FORMAT_VERSION + 1
    elif change == "models not state dicts":
        checkpoint["models"] = {"vae": [1, 2, 3]}
    elif change == "wrong weights":
        weights = checkpoint["models"]["vae"]
        name = next(iter(weights))
        weights[name] = torch.zeros(3)
    elif change == "vocabulary info":
        del checkpoint["vocabulary"]["fingerprint"]
    elif change == "statistics":
        checkpoint["normalizer"]["mean"] = "abc"
    elif change == "initial code":
        checkpoint["extra"]["initial_code"] = "abc"
    torch.save(checkpoint, path)


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ("garbage", "unreadable checkpoint"),
        ("empty", "unreadable checkpoint"),
        ("torn", "unreadable checkpoint"),
        ("not ours", "not a t2m checkpoint"),
        ("future format", f"checkpoint format {FORMAT_VERSION + 1}"),
        ("models not state dicts", "malformed t2m checkpoint"),
        ("wrong weights", "unusable generator checkpoint"),
        ("vocabulary info", "'fingerprint' is missing"),
        ("statistics", "unusable generator checkpoint"),
        ("initial code", "initial_code is a str"),
    ],
)
def test_a_malformed_checkpoint_is_one_line(run, capsys, tmp_path, change, message):
    from t2m import sample

    path = run / "generator" / "best.pt"
    _rewrite(path, change)
    argv = ["--text", "a person walks forward", "--checkpoints", str(run), "--render", "none"]
    assert sample.main([*argv, "--out", str(tmp_path / "out")]) == 2
    _one_line_error(capsys.readouterr().err, str(path), message)


# ----------------------------------------------------------------------------- dataset arrays


@pytest.fixture
def dataset(tiny_dataset: Path, tmp_path: Path) -> Path:
    """A copy of the session's tiny dataset, free to be poisoned."""
    return Path(shutil.copytree(tiny_dataset, tmp_path / "data"))


@pytest.mark.parametrize("file", ["new_joint_vecs/000000.npy", "Mean.npy", "Std.npy"])
def test_an_object_array_in_a_dataset_is_refused(dataset, marker, tmp_path, capsys, file):
    from t2m.train.__main__ import main

    path = dataset / file
    np.save(path, np.array([Payload(marker)], dtype=object), allow_pickle=True)
    argv = ["autoencoder", "--preset", "tiny", "--device", "cpu", "--dataset", str(dataset)]
    assert main([*argv, "--checkpoints", str(tmp_path / "run")]) == 2
    _one_line_error(capsys.readouterr().err, str(path))
    assert not marker.exists()


# ----------------------------------------------------------------------------- the Makefile

HOSTILE_TEXT = (
    'a person walks "forward" `touch {m}1` $(touch {m}2) it\'s $(shell touch {m}3) '
    "${{HOME}} \\ # * ; | && touch {m}4\nand waves"
)


def _make(*arguments: str, env: dict[str, str]) -> subprocess.CompletedProcess:
    """``make -s -C REPO *arguments`` with ``env`` added (and no variables of an outer make)."""
    outer = ("MAKEFLAGS", "MFLAGS", "MAKELEVEL", "MAKEOVERRIDES")
    base = {key: value for key, value in os.environ.items() if key not in outer}
    return subprocess.run(
        ["make", "-s", "-C", str(REPO), *arguments],
        capture_output=True,
        text=True,
        env={**base, **env},
        timeout=600,
    )


def _fake_venv(folder: Path, python: str) -> Path:
    """A folder that ``make VENV=folder`` takes for an installed venv whose python is
    ``python`` (a script body)."""
    (folder / "bin").mkdir(parents=True)
    script = folder / "bin" / "python"
    script.write_text(python)
    script.chmod(script.stat().st_mode | stat.S_IXUSR)
    (folder / ".installed").touch()  # newer than setup.cfg: make installs nothing
    return folder


def test_makefile_variables_reach_the_commands_as_text(tmp_path):
    """Every target, every variable given something a shell or make would run: the commands
    get it verbatim (ARGS split into words at blanks), and nothing runs."""
    marker = tmp_path / "marker"
    log = tmp_path / "argv.jsonl"
    recorder = f"#!{sys.executable}\nimport json, sys\n"
    recorder += f"open({str(log)!r}, 'a').write(json.dumps(sys.argv[1:]) + '\\n')\n"
    venv = _fake_venv(tmp_path / "venv", recorder)
    text = HOSTILE_TEXT.format(m=marker)
    hostile = {
        "TEXT": text,
        "PRESET": f"p$(shell touch {marker}5)`touch {marker}6`",
        "DATASET": f"d'; touch {marker}7; '",
        "OUT": f"$(shell touch {marker}8) x",
        "SEED": f"1;touch {marker}9",
        "DEMO_SOURCE": f"a b$(shell touch {marker}10)",
    }
    args = f"--length 40 * $(shell touch {marker}11) `touch {marker}12` $(touch {marker}13)"
    given = [f"{name}={value}" for name, value in hostile.items()]
    for target in ("sample", "eval", "train-ae", "dataset", "contact-sheet", "demo"):
        done = _make(target, f"VENV={venv}", *given, f"ARGS={args}", env={})
        assert done.returncode == 0, done.stderr
    calls = [json.loads(line) for line in log.read_text().splitlines()]
    assert not list(tmp_path.glob("marker*"))
    split_args = args.split()
    sample = calls[0]
    assert sample[:2] == ["-m", "t2m.sample"] and sample[-len(split_args) :] == split_args
    assert sample[sample.index("--text") + 1] == text
    assert sample[sample.index("--checkpoints") + 1] == f"checkpoints/{hostile['PRESET']}"
    train = calls[2]
    assert train[train.index("--dataset") + 1] == hostile["DATASET"]
    assert train[train.index("--preset") + 1] == hostile["PRESET"]
    synth, build = calls[3], calls[4]
    assert synth[synth.index("--out") + 1] == hostile["DEMO_SOURCE"]
    assert synth[synth.index("--seed") + 1] == hostile["SEED"]
    assert build[build.index("--out") + 1] == hostile["OUT"]
    # a value given in the environment is taken as written too
    done = _make("sample", f"VENV={venv}", env={"TEXT": text})
    sample = json.loads(log.read_text().splitlines()[-1])
    assert done.returncode == 0 and sample[sample.index("--text") + 1] == text
    assert not list(tmp_path.glob("marker*"))


def test_make_sample_gives_a_hostile_prompt_to_the_model_as_text(tiny_run, tmp_path):
    marker = tmp_path / "marker"
    python = f'#!/bin/sh\nexec {sys.executable} "$@"\n'
    venv = _fake_venv(tmp_path / "venv", python)
    text = HOSTILE_TEXT.format(m=marker).replace("\n", " ")
    out = tmp_path / "out"
    done = _make(
        "sample",
        f"VENV={venv}",
        f"CHECKPOINTS={tiny_run}",
        f"TEXT={text}",
        f"ARGS=--out {out} --render none --length 40",
        env={"PYTHONPATH": str(REPO)},
    )
    assert done.returncode == 0, done.stderr
    assert json.loads((out / "results.json").read_text())["texts"] == [text]
    assert not list(tmp_path.glob("marker*"))
