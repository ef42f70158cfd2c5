"""Hostile and careless inputs to ``python -m t2m.export`` and to the original release's loader
(:mod:`t2m.release`). Each bad input ends in exit status 2 (or a UsageError) with one line naming
the option or file, before anything is written; nothing the user made is lost.

Export (issue 31, cases 7 and 8): 8 tests, 21 cases: an existing output file (refused without
``--overwrite``), frame rates outside 1..1000 fps (10) and the range in ``--help``, joints beyond
1e4 m (4), bones of no length (2), features whose joints overflow, no traceback in a real
process, a write that fails naming the output rather than its temporary file.

Release loading (issue 31, case 6): 10 tests, 36 cases, each a crafted copy of the reference
release (``../shared/reference/t2m-original``; skipped without it): a vocabulary index of other
than whole numbers (3, and once read alone by ``t2m.data.words``) or without ``unk`` (1); generator weights of 0-d, wrong shape, missing,
non-float or non-finite, claiming more values than stored, or not tensors at all (16); the length
estimator's (3) and the evaluator's (3); ``opt.txt``'s unit_length (3), ``opt.txt`` not UTF-8 or
a folder (1); ``meta/`` statistics of wrong shape or zero std, naming ``mean.npy`` or ``std.npy``
(4); one line from ``t2m.sample``
in a real process (1).
"""

from __future__ import annotations

import os
import pickle
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from dataset_tools.bvh import read_bvh, write_bvh
from dataset_tools.command import UsageError
from dataset_tools.gltf import write_glb
from dataset_tools.skeleton import SMPL
from t2m import export
from t2m.release import load_release, load_release_evaluator

ROOT = Path(__file__).resolve().parents[2]


def one_line(err: str, *needles: str) -> None:
    """``err`` is exactly one ``error: ...`` line holding every needle (after any progress bar
    that cleared itself with a carriage return)."""
    assert err.count("\n") == 1 and err.endswith("\n"), err
    err = err.rsplit("\r", 1)[-1]
    assert err.startswith("error: ") and "Traceback" not in err, err
    assert all(needle in err for needle in needles), err


def walk(frames: int = 12) -> np.ndarray:
    """Joints (T, 22, 3): the template rest pose moving forward at 1 m/s (20 fps)."""
    pose = np.zeros((SMPL.num_joints, 3))
    pose[0] = (0.0, 0.95, 0.0)
    for joint, parent in enumerate(SMPL.parents):
        if parent >= 0:
            pose[joint] = pose[parent] + SMPL.offsets[joint]
    steps = np.arange(frames)[:, None, None] * np.array([0.0, 0.0, 0.05])
    return pose[None] + steps


def saved(folder: Path, joints: np.ndarray, name: str = "in.npy") -> Path:
    path = folder / name
    np.save(path, joints)
    return path


# ------------------------------------------------------------------------------------- export


def test_export_refuses_an_existing_output_file_without_overwrite(tmp_path, capsys):
    source = saved(tmp_path, walk())
    for name in ("mine.bvh", "mine.glb"):
        out = tmp_path / name
        out.write_text("the user's own file")
        assert export.main([str(source), str(out)]) == 2
        one_line(capsys.readouterr().err, str(out), "--overwrite")
        assert out.read_text() == "the user's own file"
        assert export.main([str(source), str(out), "--overwrite"]) == 0
        assert out.read_bytes() != b"the user's own file"
    assert read_bvh(tmp_path / "mine.bvh")[3].shape == (12, 22, 3)
    # the write stays atomic: nothing but the two files (no temporary left beside them)
    assert sorted(os.listdir(tmp_path)) == ["in.npy", "mine.bvh", "mine.glb"]


def test_export_names_a_folder_given_as_output(tmp_path, capsys):
    source = saved(tmp_path, walk())
    folder = tmp_path / "takes.bvh"
    folder.mkdir()
    for output in (tmp_path, folder):
        assert export.main([str(source), str(output)]) == 2
        one_line(capsys.readouterr().err, f"output {output} is a folder")
    assert sorted(os.listdir(tmp_path)) == ["in.npy", "takes.bvh"]
    assert not list(folder.iterdir())


@pytest.mark.parametrize("fps", ["1e9", "1e300", "0.5", "1001", "inf"])
@pytest.mark.parametrize("suffix", [".bvh", ".glb"])
def test_export_refuses_a_frame_rate_outside_1_to_1000(tmp_path, capsys, fps, suffix):
    # 1e9 fps printed a BVH frame time of 0.00000000 (our reader refuses it); 1e300 fps put
    # every glTF key at time 0
    source = saved(tmp_path, walk())
    out = tmp_path / f"out{suffix}"
    assert export.main([str(source), str(out), "--fps", fps]) == 2
    one_line(capsys.readouterr().err, "--fps", "from 1 to 1000")
    assert not out.exists()
    with pytest.raises(ValueError, match="fps"):
        (write_bvh if suffix == ".bvh" else write_glb)(walk(), out, fps=float(fps))
    assert not out.exists()


def test_export_help_states_the_frame_rate_range(capsys):
    with pytest.raises(SystemExit):
        export.main(["--help"])
    assert "from 1 to 1000" in " ".join(capsys.readouterr().out.split())


@pytest.mark.parametrize("scale", [1e300, 1e5])
@pytest.mark.parametrize("suffix", [".bvh", ".glb"])
def test_export_refuses_joints_beyond_a_physical_bound(tmp_path, capsys, scale, suffix):
    # 1e300 gave a traceback (qbetween got a zero-length vector); 1e5 (millimetres read as
    # metres, 100 km away) wrote a file
    source = saved(tmp_path, walk() * scale)
    out = tmp_path / f"out{suffix}"
    assert export.main([str(source), str(out)]) == 2
    one_line(capsys.readouterr().err, str(source), "10000 m")
    assert not out.exists()
    with pytest.raises(ValueError, match="beyond"):
        write_bvh(walk() * scale, out)


@pytest.mark.parametrize("case", ["all_zero", "one_collapsed_knee"])
def test_export_refuses_bones_of_no_length(tmp_path, capsys, case):
    # all-zero joints exported a rest pose with exit 0
    joints = walk()
    if case == "all_zero":
        joints = np.zeros_like(joints)
    else:
        knee = SMPL.joint_names.index("left_knee")
        joints[5, SMPL.joint_names.index("left_ankle")] = joints[5, knee]
    source = saved(tmp_path, joints)
    for suffix in (".bvh", ".glb"):
        assert export.main([str(source), str(tmp_path / f"out{suffix}")]) == 2
        err = capsys.readouterr().err
        one_line(err, str(source), "bone", "under 1 mm")
        if case != "all_zero":
            assert "left_knee-left_ankle" in err and "frame 5" in err, err
    assert sorted(os.listdir(tmp_path)) == ["in.npy"]


def run_export(*argv: str) -> subprocess.CompletedProcess:
    """``python -m t2m.export`` in a real process (warnings print to its stderr)."""
    return subprocess.run(
        [sys.executable, "-m", "t2m.export", *argv],
        capture_output=True,
        text=True,
        cwd=ROOT,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
        timeout=120,
    )


def test_export_refuses_features_whose_joints_overflow(tmp_path):
    # features of 1e308 recover to infinite joints: numpy's overflow warnings and a ValueError
    # traceback (exit 1) before; one line now
    source = saved(tmp_path, np.full((10, 263), 1e308))
    done = run_export(str(source), str(tmp_path / "out.bvh"))
    assert done.returncode == 2
    one_line(done.stderr, str(source), "not finite")
    assert sorted(os.listdir(tmp_path)) == ["in.npy"]


def test_export_refusals_have_no_traceback_in_a_real_process(tmp_path):
    source = saved(tmp_path, walk() * 1e300)
    out = tmp_path / "out.bvh"
    done = run_export(str(source), str(out))
    assert done.returncode == 2
    one_line(done.stderr, str(source))
    assert not out.exists()


def test_a_write_that_fails_names_the_output_not_its_temporary_file(tmp_path, capsys):
    from dataset_tools.io import atomic_write

    def full_disk(file) -> None:
        raise OSError(28, "No space left on device", file.name)

    with pytest.raises(OSError) as error:
        atomic_write(tmp_path / "out.bvh", full_disk)
    assert str(error.value) == f"[Errno 28] No space left on device: '{tmp_path / 'out.bvh'}'"
    assert sorted(os.listdir(tmp_path)) == []
    if Path("/proc/self").is_dir():  # a folder no file can be made in, whoever runs the test
        assert export.main([str(saved(tmp_path, walk())), "/proc/out.bvh"]) != 0
        last = capsys.readouterr().err.strip().splitlines()[-1]  # after a gimbal-lock warning
        assert last == "error: [Errno 2] No such file or directory: '/proc/out.bvh'", last


# ------------------------------------------------------------------------------------ release

REFERENCE = ROOT.parent / "shared" / "reference" / "t2m-original"
needs_reference = pytest.mark.skipif(not REFERENCE.is_dir(), reason="reference release absent")
GENERATOR = Path("checkpoints/t2m/Comp_v6_KLD01")
LENGTH_TAR = Path("checkpoints/t2m/length_est_bigru/model/latest.tar")
EVALUATOR_TAR = Path("checkpoints/t2m/text_mot_match/model/finest.tar")


@pytest.fixture
def release_copy(tmp_path) -> Path:
    """A copy of the reference release (random weights at small sizes) to spoil."""
    copy = tmp_path / "release"
    shutil.copytree(REFERENCE, copy, ignore=shutil.ignore_patterns("expected.npz"))
    return copy


def refused(load, folder: Path, spoiled: Path, *needles: str) -> None:
    """``load(folder)`` raises a UsageError of one line naming ``spoiled`` and every needle;
    the spoiled file is left as it was."""
    before = spoiled.read_bytes() if spoiled.is_file() else None
    with pytest.raises(UsageError) as error:
        load(folder)
    message = str(error.value)
    assert "\n" not in message and str(spoiled) in message, message
    assert all(needle in message for needle in needles), message
    assert (spoiled.read_bytes() if spoiled.is_file() else None) == before


def spoil_checkpoint(path: Path, change) -> None:
    checkpoint = torch.load(path, map_location="cpu", weights_only=True)
    change(checkpoint)
    torch.save(checkpoint, path)


def spoil_pickle(path: Path, change) -> None:
    path.write_bytes(pickle.dumps(change(pickle.loads(path.read_bytes()))))


def _mixed_rows(rows: dict) -> dict:
    return {word: str(row) if row % 2 else row for word, row in rows.items()}


def _without_unk(words: list) -> list:
    return ["zzz-not-unk" if word == "unk" else word for word in words]


@needs_reference
@pytest.mark.parametrize(
    ("name", "change", "needle"),
    [
        ("our_vab_idx.pkl", _mixed_rows, "not a whole number"),  # was TypeError
        ("our_vab_idx.pkl", lambda rows: {w: float(r) for w, r in rows.items()}, "whole number"),
        ("our_vab_idx.pkl", lambda rows: {w: r == 1 for w, r in rows.items()}, "whole number"),
    ],
)
def test_release_vocabulary_index_of_other_than_whole_numbers(release_copy, name, change, needle):
    spoiled = release_copy / "glove" / name
    spoil_pickle(spoiled, change)
    refused(load_release, release_copy, spoiled, needle)


@needs_reference
def test_release_vocabulary_without_unk(release_copy):
    # a ValueError traceback from WordVectors
    spoiled = release_copy / "glove" / "our_vab_words.pkl"
    index = release_copy / "glove" / "our_vab_idx.pkl"
    spoil_pickle(spoiled, _without_unk)
    spoil_pickle(
        index, lambda rows: {("zzz-not-unk" if w == "unk" else w): r for w, r in rows.items()}
    )
    refused(load_release, release_copy, spoiled, "'unk'")


@needs_reference
def test_a_glove_folder_read_alone_refuses_a_mixed_index(release_copy):
    # the same folder read by t2m.data.words (training on the release's vocabulary), not
    # through the release loader: a TypeError from sorting int beside str before
    from t2m.data.words import read_glove_folder

    folder = release_copy / "glove"
    spoil_pickle(folder / "our_vab_idx.pkl", _mixed_rows)
    with pytest.raises(UsageError, match="not a whole number"):
        read_glove_folder(folder)


def _set(entry: str, key: str, value):
    return lambda checkpoint: checkpoint[entry].__setitem__(key, value)


def _as(entry: str, key: str, convert):
    return lambda checkpoint: checkpoint[entry].__setitem__(key, convert(checkpoint[entry][key]))


@needs_reference
@pytest.mark.parametrize(
    ("change", "needles"),
    [
        # 0-d tensors where a size is read (IndexError before)
        (_set("text_enc", "pos_emb.weight", torch.tensor(1.0)), ("shape ()",)),
        (_set("seq_pri", "emb.0.weight", torch.tensor(1.0)), ("prior.input.weight",)),
        (_set("mov_dec", "main.0.weight", torch.tensor(1.0)), ("expected 3",)),
        (_set("mov_enc", "out_net.weight", torch.tensor(1.0)), ("expected 2",)),
        (_set("seq_pri", "positional_encoder.pe", torch.tensor(1.0)), ("time encoding",)),
        # wrong shapes (IndexError, or a table of 0 steps loaded)
        (_as("mov_dec", "main.0.weight", torch.flatten), ("shape (",)),
        (_as("seq_dec", "positional_encoder.pe", lambda t: t[:0]), ("(0, ",)),
        # a weight missing where a size is read (KeyError before)
        (lambda c: c["text_enc"].pop("input_emb.weight"), ("no weight",)),
        (lambda c: c["mov_dec"].pop("main.0.weight"), ("no weight 'net.0.weight'",)),
        # wrong dtypes, silently converted before
        (_as("text_enc", "pos_emb.weight", lambda t: t.long()), ("int64",)),
        (_as("text_enc", "pos_emb.weight", lambda t: t > 0), ("bool",)),
        (_as("text_enc", "pos_emb.weight", lambda t: t.to(torch.complex64)), ("complex64",)),
        (_as("text_enc", "pos_emb.weight", lambda t: t * float("nan")), ("NaN",)),
        # a zero-stride view claiming 3e8 values over one stored number (a model sized by it)
        (_set("text_enc", "input_emb.weight", torch.zeros(1).expand(10**6, 300)), ("stores 1",)),
        # not weights at all (AttributeError before)
        (_set("text_enc", "pos_emb.weight", 3), ("not a weight tensor",)),
        (lambda c: c.__setitem__("text_enc", [1, 2]), ("not a dict of weights",)),
    ],
)
def test_release_generator_weights_of_wrong_shape_or_dtype(release_copy, change, needles):
    spoiled = release_copy / GENERATOR / "model" / "latest.tar"
    spoil_checkpoint(spoiled, change)
    refused(load_release, release_copy, spoiled, *needles)


def _rename_output_layer(checkpoint) -> None:
    estimator = checkpoint["estimator"]
    estimator["output.x.weight"] = estimator.pop("output.0.weight")


def _drop_output_layers(checkpoint) -> None:
    for key in [k for k in checkpoint["estimator"] if k.startswith("output.")]:
        del checkpoint["estimator"][key]


@needs_reference
@pytest.mark.parametrize(
    ("change", "needle"),
    [
        (_rename_output_layer, "output.<number>"),  # ValueError from int('x') before
        (_drop_output_layers, "no linear output layer"),  # IndexError before
        (_set("estimator", "pos_emb.weight", torch.tensor(1.0)), "shape ()"),
    ],
)
def test_release_length_estimator_crafted(release_copy, change, needle):
    spoiled = release_copy / LENGTH_TAR
    spoil_checkpoint(spoiled, change)
    refused(load_release, release_copy, spoiled, needle)


@needs_reference
@pytest.mark.parametrize(
    ("change", "needle"),
    [
        (_set("motion_encoder", "input_emb.weight", torch.tensor(1.0)), "shape ()"),
        (lambda c: c["motion_encoder"].pop("output_net.3.weight"), "no weight"),
        (_set("movement_encoder", "main.0.weight", torch.zeros(5)), "shape (5,)"),
    ],
)
def test_release_evaluator_crafted(release_copy, change, needle):
    spoiled = release_copy / EVALUATOR_TAR
    spoil_checkpoint(spoiled, change)
    refused(load_release_evaluator, release_copy, spoiled, needle)


@needs_reference
@pytest.mark.parametrize(
    ("unit", "needle"),
    [("²", "not a number"), ("٣", "not a number"), ("3", "snippets of 4 frames")],
)
def test_release_opt_unit_length(release_copy, unit, needle):
    # int('²') raised ValueError; '3' the autoencoder's ValueError, both with a traceback
    spoiled = release_copy / GENERATOR / "opt.txt"
    text = spoiled.read_text(encoding="utf-8")
    spoiled.write_text(re.sub(r"unit_length: .*", f"unit_length: {unit}", text), encoding="utf-8")
    refused(load_release, release_copy, spoiled, needle)


@needs_reference
def test_release_opt_not_text_or_a_folder(release_copy):
    spoiled = release_copy / GENERATOR / "opt.txt"
    spoiled.write_bytes(b"\xff\xfe not UTF-8")  # UnicodeDecodeError before
    refused(load_release, release_copy, spoiled, "UTF-8")
    spoiled.unlink()
    spoiled.mkdir()  # read as no options before
    refused(load_release, release_copy, spoiled, "is a folder")


@needs_reference
@pytest.mark.parametrize(
    ("name", "array", "needle"),
    [
        ("mean.npy", np.zeros((2, 263), np.float32), "(2, 263)"),
        ("std.npy", np.array(1.0, np.float32), "shape ()"),
        ("std.npy", np.zeros(263, np.float32), "std is zero"),
        ("mean.npy", np.zeros(200, np.float32), "holds 200 values"),
    ],
)
def test_release_meta_statistics(release_copy, name, array, needle):
    # Normalizer's ValueError, with a traceback, before
    meta = release_copy / GENERATOR / "meta"
    np.save(meta / name, array)
    refused(load_release, release_copy, meta / name, needle)  # the file, not the folder


@needs_reference
def test_release_refusal_is_one_line_from_the_command(release_copy):
    spoiled = release_copy / "glove" / "our_vab_idx.pkl"
    spoil_pickle(spoiled, _mixed_rows)
    done = subprocess.run(
        [
            sys.executable,
            "-m",
            "t2m.sample",
            "--checkpoints",
            str(release_copy),
            "--text",
            "a person walks",
            "--render",
            "none",
            "--out",
            str(release_copy.parent / "out"),
        ],
        capture_output=True,
        text=True,
        cwd=ROOT,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
        timeout=300,
    )
    assert done.returncode == 2, done.stderr
    one_line(done.stderr, str(spoiled))
    assert not (release_copy.parent / "out").exists()
