"""Hostile and careless inputs to ``python -m dataset_tools ...``: every one ends in one line and
exit status 2 (or, for a dead worker, 1), leaves the user's files intact and a resumable folder.

Covered: malformed arrays (empty, a header claiming 24 TiB, strings, complex, objects, an .npz
renamed .npy, truncated, text) for features / recover / contact-sheet / a build's sources;
output paths (under a file, a folder where a file goes, the input itself, an unwritable folder);
every numeric option out of range (inf, nan, zero, negative, huge); clip names that collide
(``walk``/``Mwalk``, case, hidden names); a rebuild with other options; a non-empty foreign
output folder; temporaries of a killed run; a SIGKILLed worker; damaged dataset files; a second
build into a locked folder; malformed index, source.json and mapping files; synth ``--force``
over files it did not write.
"""

from __future__ import annotations

import fcntl
import io
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from test_build import synth_source

from dataset_tools.__main__ import main as dataset_main

ROOT = Path(__file__).resolve().parents[2]


def run_in_process(capsys, *argv: str) -> tuple[int, str]:
    """(exit status, stderr) of ``python -m dataset_tools argv`` run in this process."""
    code = dataset_main(list(argv))
    return code, capsys.readouterr().err


def assert_one_line_error(code: int, err: str, *needles: str, status: int = 2) -> None:
    assert code == status, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), err
    assert "Traceback" not in err
    for needle in needles:
        assert needle in lines[0], (needle, lines[0])


def run_subprocess(*argv: str, timeout: float = 120) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    return subprocess.run(
        [sys.executable, *argv], capture_output=True, text=True, timeout=timeout, env=env, cwd=ROOT
    )


# ----------------------------------------------------------------------------- malformed arrays


def _header(shape: tuple[int, ...], descr: str = "<f8") -> bytes:
    buffer = io.BytesIO()
    np.lib.format.write_array_header_1_0(
        buffer, {"descr": descr, "fortran_order": False, "shape": shape}
    )
    return buffer.getvalue()


def write_malformed(folder: Path) -> dict[str, tuple[Path, str]]:
    """name -> (a malformed .npy, words its error must contain)."""
    folder.mkdir(parents=True, exist_ok=True)
    good = np.random.default_rng(0).normal(size=(8, 22, 3))
    files = {
        "empty": (b"", "empty"),
        "huge_header": (_header((1 << 40, 3)) + bytes(64), "24.0 TiB"),
        "truncated": (_header((8, 22, 3)) + bytes(100), "header promises"),
        "text": (b"0 1 2\n3 4 5\n", "no numpy header"),
    }
    cases = {}
    for name, (content, words) in files.items():
        (folder / f"{name}.npy").write_bytes(content)
        cases[name] = (folder / f"{name}.npy", words)
    np.save(folder / "strings.npy", np.array([["a"] * 3] * 22))
    cases["strings"] = (folder / "strings.npy", "not real numbers")
    np.save(folder / "complex.npy", good.astype(complex))
    cases["complex"] = (folder / "complex.npy", "complex128")
    np.save(folder / "objects.npy", np.array([{"x": 1}], dtype=object), allow_pickle=True)
    cases["objects"] = (folder / "objects.npy", "Python objects")
    np.savez(folder / "archive.npz", joints=good)
    (folder / "archive.npz").rename(folder / "archive.npy")
    cases["archive"] = (folder / "archive.npy", ".npz archive")
    return cases


MALFORMED = (
    "empty",
    "huge_header",
    "truncated",
    "text",
    "strings",
    "complex",
    "objects",
    "archive",
)


@pytest.mark.parametrize("command", ["features", "recover"])
@pytest.mark.parametrize("case", MALFORMED)
def test_malformed_arrays_are_one_line_naming_the_file(tmp_path, capsys, command, case):
    path, words = write_malformed(tmp_path / "in")[case]
    before = path.read_bytes()
    code, err = run_in_process(capsys, command, str(path), str(tmp_path / "out.npy"))
    assert_one_line_error(code, err, str(path), words)
    assert path.read_bytes() == before and not (tmp_path / "out.npy").exists()


@pytest.mark.parametrize("case", ["huge_header", "objects"])
def test_malformed_arrays_through_a_real_process(tmp_path, case):
    path, words = write_malformed(tmp_path / "in")[case]
    done = run_subprocess("-m", "dataset_tools", "features", str(path), str(tmp_path / "o.npy"))
    assert_one_line_error(done.returncode, done.stderr, str(path), words)


def test_a_sparse_file_as_large_as_its_header_is_not_loaded(tmp_path, capsys):
    """A header and a file size that agree, beyond the machine's memory: refused unread."""
    from dataset_tools.io import memory_bytes

    path = tmp_path / "sparse.npy"
    count = 2 * memory_bytes() // 8  # float64 values filling twice the memory
    header = _header((count,))
    with open(path, "wb") as file:
        file.write(header)
        file.truncate(len(header) + 8 * count)  # all holes: nothing on disk
    code, err = run_in_process(capsys, "recover", str(path), str(tmp_path / "o.npy"))
    assert_one_line_error(code, err, "larger than this machine's memory")


def test_degenerate_and_overflowing_motions_write_nothing(tmp_path, capsys):
    np.save(tmp_path / "zeros.npy", np.zeros((10, 22, 3)))
    np.save(tmp_path / "huge.npy", np.full((10, 263), 1e38))
    code, err = run_in_process(capsys, "features", str(tmp_path / "zeros.npy"), str(tmp_path / "a"))
    assert_one_line_error(code, err, "zeros.npy", "zero leg length")
    code, err = run_in_process(capsys, "recover", str(tmp_path / "huge.npy"), str(tmp_path / "b"))
    assert_one_line_error(code, err, "not finite")
    assert not (tmp_path / "a").exists() and not (tmp_path / "b").exists()


# ----------------------------------------------------------------------------- output paths


def test_output_paths_are_checked_before_work(tmp_path, capsys):
    joints = tmp_path / "joints.npy"
    np.save(joints, np.random.default_rng(0).normal(size=(8, 22, 3)))
    before = joints.read_bytes()
    cases = [
        (("features", str(joints), str(joints / "out.npy")), "is a file, not a folder"),
        (("features", str(joints), str(tmp_path)), "is a folder"),
        (("features", str(joints), str(joints)), "is the input"),
        (
            (
                "features",
                str(joints),
                str(tmp_path / "f.npy"),
                "--joints-out",
                str(tmp_path / "f.npy"),
            ),
            "is the output",
        ),
        (("synth", "--out", str(joints), "--clips", "1"), "exists and is not a folder"),
        (("contact-sheet", "--input", str(tmp_path), "--out", str(tmp_path)), "is a folder"),
    ]
    for argv, words in cases:
        assert_one_line_error(*run_in_process(capsys, *argv), words)
    assert joints.read_bytes() == before and sorted(p.name for p in tmp_path.iterdir()) == [
        "joints.npy"
    ]


@pytest.mark.skipif(os.geteuid() == 0, reason="root may write into any folder")
def test_an_unwritable_output_folder_is_one_line(tmp_path, capsys):
    locked = tmp_path / "locked"
    locked.mkdir()
    locked.chmod(0o500)
    try:
        np.save(tmp_path / "j.npy", np.random.default_rng(0).normal(size=(8, 22, 3)))
        code, err = run_in_process(
            capsys, "features", str(tmp_path / "j.npy"), str(locked / "sub" / "o.npy")
        )
        assert_one_line_error(code, err, "no permission to write")
    finally:
        locked.chmod(0o700)


# ----------------------------------------------------------------------------- numeric options


BAD_BUILD_OPTIONS = [
    (("--max-seconds", "inf"), "--max-seconds"),
    (("--max-seconds", "nan"), "--max-seconds"),
    (("--max-seconds", "0"), "--max-seconds"),
    (("--max-seconds", "-3"), "--max-seconds"),
    (("--fps", "inf"), "--fps"),
    (("--fps", "0"), "--fps"),
    (("--fps", "1e-9"), "--fps"),
    (("--bvh-scale", "nan"), "--bvh-scale"),
    (("--workers", "0"), "--workers"),
    (("--workers", "100000"), "--workers"),
    (("--seed", "-1"), "--seed"),
    (("--max-seconds", "ten"), "invalid float"),
]


@pytest.mark.parametrize("option, words", BAD_BUILD_OPTIONS)
def test_bad_numeric_build_options(tmp_path, capsys, option, words):
    source = synth_source(tmp_path / "src", num_clips=1, num_frames=30)
    out = tmp_path / "out"
    argv = ("build", "--source", "joints", "--input", str(source), "--out", str(out), *option)
    assert_one_line_error(*run_in_process(capsys, *argv), words)
    assert not out.exists()


@pytest.mark.parametrize(
    "argv, words",
    [
        (("synth", "--clips", "0"), "--clips"),
        (("synth", "--clips", "1000000000"), "--clips"),
        (("synth", "--clips", "2", "--seed", "-5"), "--seed"),
        (("synth", "--clips", "2", "--workers", "0"), "--workers"),
        (("contact-sheet", "--input", ".", "--azimuth", "nan"), "--azimuth"),
        (("contact-sheet", "--input", ".", "--frames", "1000000"), "--frames"),
        (("contact-sheet", "--input", ".", "--clips", "-1"), "--clips"),
    ],
)
def test_bad_numeric_options_of_other_commands(tmp_path, capsys, argv, words):
    out = tmp_path / ("sheet.png" if argv[0] == "contact-sheet" else "corpus")
    assert_one_line_error(*run_in_process(capsys, *argv, "--out", str(out)), words)
    assert not out.exists()


# ----------------------------------------------------------------------------- builds


def build(capsys, source: Path, out: Path, *extra: str) -> tuple[int, str]:
    return run_in_process(
        capsys, "build", "--source", "joints", "--input", str(source), "--out", str(out), *extra
    )


def test_colliding_clip_names_are_refused_reported_and_never_overwrite(tmp_path, capsys):
    source = synth_source(tmp_path / "src", num_clips=4, num_frames=60)
    joints, texts = source / "joints", source / "texts"
    renames = {"clip00": "walk", "clip01": "Mwalk", "clip02": "Run", "clip03": "run"}
    for old, new in renames.items():
        (joints / f"{old}.npy").rename(joints / f"{new}.npy")
        (texts / f"{old}.txt").rename(texts / f"{new}.txt")
    np.save(joints / ".hidden.npy", np.load(joints / "walk.npy"))
    (texts / ".hidden.txt").write_text("a person walks\n")
    out = tmp_path / "out"
    code, err = build(capsys, source, out)
    assert code == 0, err
    report = json.loads((out / "build_report.json").read_text())
    reasons = {entry["name"]: entry["reason"] for entry in report["skipped"]}
    assert set(reasons) == {"Mwalk", "Run", "run", ".hidden"}
    assert "mirror name of clip 'walk'" in reasons["Mwalk"]
    assert "collides" in reasons["Run"] and "collides" in reasons["run"]
    assert "hidden" in reasons[".hidden"]
    # Mwalk is walk's mirror, not the file named Mwalk.npy; every name is in one split once.
    built = sorted(path.stem for path in (out / "new_joint_vecs").glob("*.npy"))
    assert built == ["Mwalk", "walk"]
    lines = [
        line
        for split in ("train", "val", "test")
        for line in (out / f"{split}.txt").read_text().split()
    ]
    assert sorted(lines) == ["Mwalk", "walk"]
    mirror_caption = (out / "texts" / "Mwalk.txt").read_text()
    assert "turns right" in mirror_caption  # walk's caption, mirrored


def test_rebuild_with_other_options_refuses_unless_forced(tmp_path, capsys):
    source = synth_source(tmp_path / "src", num_clips=2, num_frames=240)  # 4 s at 60 fps
    out = tmp_path / "out"
    assert build(capsys, source, out)[0] == 0
    assert len(np.load(out / "new_joint_vecs" / "clip00.npy")) == 79
    recorded = json.loads((out / "build_options.json").read_text())["options"]
    assert recorded["max_seconds"] == 10.0 and recorded["source"] == "joints"
    stamps = {path: path.stat().st_mtime_ns for path in out.rglob("*") if path.is_file()}
    code, err = build(capsys, source, out, "--max-seconds", "2")
    assert_one_line_error(code, err, "other options (max_seconds)", "--force")
    assert {path: path.stat().st_mtime_ns for path in out.rglob("*") if path.is_file()} == stamps
    code, err = build(capsys, source, out, "--max-seconds", "2", "--force")
    assert code == 0, err
    assert len(np.load(out / "new_joint_vecs" / "clip00.npy")) == 39  # 2 s at 20 fps, minus 1
    assert json.loads((out / "build_options.json").read_text())["options"]["max_seconds"] == 2.0
    assert build(capsys, source, out, "--max-seconds", "2")[0] == 0  # same options: resumes


def test_a_foreign_output_folder_is_refused_and_left_alone(tmp_path, capsys):
    source = synth_source(tmp_path / "src", num_clips=1, num_frames=30)
    out = tmp_path / "mine"
    out.mkdir()
    (out / "train.txt").write_text("my own split\n")
    for extra in ((), ("--force",)):
        code, err = build(capsys, source, out, *extra)
        assert_one_line_error(code, err, "holds no dataset built by this tool")
    assert sorted(p.name for p in out.iterdir()) == ["train.txt"]
    assert (out / "train.txt").read_text() == "my own split\n"


def test_folders_the_build_reads_are_never_its_output(tmp_path, capsys):
    source = synth_source(tmp_path / "src", num_clips=1, num_frames=30)
    out = tmp_path / "out"
    (tmp_path / "splits").mkdir()
    cases = [
        (("--out", str(source)), "must not be the --input"),
        (("--out", str(out), "--texts", str(out / "texts")), "texts/ folder the build writes"),
        (("--out", str(tmp_path / "splits"), "--splits", str(tmp_path / "splits")), "has no train"),
    ]
    (out / "texts").mkdir(parents=True)
    for extra, words in cases:
        argv = ("build", "--source", "joints", "--input", str(source), *extra)
        assert_one_line_error(*run_in_process(capsys, *argv), words)
    for split in ("train", "val", "test"):
        (out / f"{split}.txt").write_text("clip00\n")
    argv = ("build", "--source", "joints", "--input", str(source), "--out", str(out))
    code, err = run_in_process(capsys, *argv, "--splits", str(out))
    assert_one_line_error(code, err, "split files the build writes")
    assert (out / "train.txt").read_text() == "clip00\n"


def test_temporaries_of_a_killed_run_are_removed_and_user_files_kept(tmp_path, capsys):
    source = synth_source(tmp_path / "src", num_clips=2, num_frames=60)
    out = tmp_path / "out"
    assert build(capsys, source, out)[0] == 0
    leftovers = [
        out / "new_joints" / ".clip00.k3j_9x0a.partial.npy",
        out / "texts" / ".Mclip01.abcdefgh.partial.txt",
        out / ".Mean.zzzzzzzz.partial.npy",
    ]
    keep = [out / "new_joints" / "notes.partial.npy", out / "texts" / ".clip00.txt.swp"]
    for path in leftovers + keep:
        path.write_bytes(b"half")
    code, err = build(capsys, source, out)
    assert code == 0, err
    assert not any(path.exists() for path in leftovers)
    assert all(path.read_bytes() == b"half" for path in keep)
    assert json.loads((out / "build_report.json").read_text())["partial_files_removed"] == 3


def test_bad_source_arrays_are_skipped_clips_with_their_reason(tmp_path, capsys):
    source = synth_source(tmp_path / "src", num_clips=1, num_frames=60)
    for name, (path, _) in write_malformed(tmp_path / "bad").items():
        path.rename(source / "joints" / f"bad_{name}.npy")
        (source / "texts" / f"bad_{name}.txt").write_text("a person walks\n")
    out = tmp_path / "out"
    code, err = build(capsys, source, out)
    assert code == 0, err
    report = json.loads((out / "build_report.json").read_text())
    reasons = {entry["name"]: entry["reason"] for entry in report["skipped"]}
    assert set(reasons) == {f"bad_{name}" for name in MALFORMED}
    for name, reason in reasons.items():
        assert reason.startswith("cannot read") and f"{name}.npy" in reason, reason
    assert "24.0 TiB" in reasons["bad_huge_header"] and report["clips_out"] == 2


def test_a_damaged_dataset_file_is_named(tmp_path, capsys):
    source = synth_source(tmp_path / "src", num_clips=2, num_frames=60)
    out = tmp_path / "out"
    assert build(capsys, source, out)[0] == 0
    damaged = out / "new_joint_vecs" / "Mclip01.npy"
    damaged.write_bytes(damaged.read_bytes()[:90])
    code, err = build(capsys, source, out)
    assert_one_line_error(code, err, str(damaged), "delete it")


def test_a_second_build_into_a_locked_folder_is_refused(tmp_path, capsys):
    source = synth_source(tmp_path / "src", num_clips=1, num_frames=30)
    out = tmp_path / "out"
    out.mkdir()
    descriptor = os.open(out, os.O_RDONLY)
    try:
        fcntl.flock(descriptor, fcntl.LOCK_EX | fcntl.LOCK_NB)
        assert_one_line_error(*build(capsys, source, out), "another build is writing")
    finally:
        os.close(descriptor)
    assert build(capsys, source, out)[0] == 0


KILL_A_WORKER = """
import os, signal, sys
import dataset_tools.build as build
import dataset_tools.build_clips as build_clips
original = build_clips.process_task
def process(task, context):
    if task.name == "clip02":
        os.kill(os.getpid(), signal.SIGKILL)  # what the out-of-memory killer does
    return original(task, context)
build_clips.process_task = process
sys.exit(build.main(sys.argv[1:]))
"""


def test_a_killed_worker_fails_fast_and_the_rerun_resumes(tmp_path):
    source = synth_source(tmp_path / "src", num_clips=6, num_frames=60)
    out = tmp_path / "out"
    argv = ("--source", "joints", "--input", str(source), "--out", str(out), "--workers", "2")
    done = run_subprocess("-c", KILL_A_WORKER, *argv, timeout=120)
    errors = [line for line in done.stderr.splitlines() if " INFO " not in line]
    assert done.returncode == 1 and "Traceback" not in done.stderr, done.stderr
    assert len(errors) == 1 and "a worker process died" in errors[0] and "resume" in errors[0]
    assert not (out / "texts" / "clip02.txt").exists()
    finished_before = {path.name for path in (out / "texts").glob("*.txt")}
    done = run_subprocess("-m", "dataset_tools", "build", *argv, timeout=120)
    assert done.returncode == 0, done.stderr
    # The other worker, stopped mid-write, may have left a temporary file: the re-run removed it.
    assert not [path for path in out.rglob("*") if ".partial" in path.name]
    report = json.loads((out / "build_report.json").read_text())
    assert report["clips_out"] == 12 and report["clips_resumed"] == len(finished_before) // 2
    assert report["clips_built_this_run"] == 6 - len(finished_before) // 2


# ----------------------------------------------------------------------------- shared files


def test_malformed_index_source_json_and_mapping_are_one_line(tmp_path, capsys):
    source = synth_source(tmp_path / "src", num_clips=1, num_frames=30)
    out = tmp_path / "out"
    index = tmp_path / "index.csv"
    cases = []
    index.write_bytes(b"source_path,start_frame,end_frame,new_name\nx\xff,0,10,a\n")
    cases.append((("--index", str(index)), "not a UTF-8 CSV"))
    negative = tmp_path / "negative.csv"
    negative.write_text("source_path,start_frame,end_frame,new_name\nclip00,-5,10,a\n")
    cases.append((("--index", str(negative)), "negative.csv:2"))
    for extra, words in cases:
        assert_one_line_error(*build(capsys, source, out, *extra), words)
    for content, words in (("{", "not valid JSON"), ('{"fps": 1e999}', "too large")):
        (source / "source.json").write_text(content)
        assert_one_line_error(*build(capsys, source, out), "source.json", words)
    bvh = tmp_path / "bvh"
    bvh.mkdir()
    (tmp_path / "map.json").write_text('{"joints": 5}')
    argv = ("build", "--source", "bvh", "--input", str(bvh), "--out", str(out))
    code, err = run_in_process(capsys, *argv, "--mapping", str(tmp_path / "map.json"))
    assert_one_line_error(code, err, "--mapping", "JSON object")
    assert not out.exists()


def test_synth_force_never_removes_files_it_did_not_write(tmp_path, capsys):
    out = tmp_path / "corpus"
    (out / "joints").mkdir(parents=True)
    (out / "joints" / "my_capture.npy").write_bytes(b"precious")
    code, err = run_in_process(capsys, "synth", "--out", str(out), "--clips", "2", "--force")
    assert_one_line_error(code, err, "my_capture.npy", "nothing was removed")
    assert (out / "joints" / "my_capture.npy").read_bytes() == b"precious"
    (out / "joints" / "my_capture.npy").unlink()
    (out / "joints").rmdir()
    args = ("synth", "--out", str(out), "--clips", "2", "--quiet")
    assert run_in_process(capsys, *args)[0] == 0
    assert_one_line_error(*run_in_process(capsys, *args), "--force")
    assert run_in_process(capsys, *args, "--force")[0] == 0
