"""End-to-end dataset builds from each source, in temporary folders."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from test_sources import make_amass_npz, make_body_model, smplh_rest_joints_y_up

from dataset_tools.build import BuildConfig, build_dataset, main
from dataset_tools.mirror import mirror_joints
from dataset_tools.representation import process_motion
from dataset_tools.skeleton import SMPL
from dataset_tools.sources.amass import smplh_joints

SHARED = Path(__file__).resolve().parents[1].parent / "shared"
MOCAP = SHARED / "mocap"
needs_mocap = pytest.mark.skipif(not MOCAP.is_dir(), reason=f"real mocap files absent ({MOCAP})")

CAPTIONS = "a person walks forward and turns left.\nSomeone waves the Right hand clockwise#0.5#2\n"


def walk(num_frames: int, fps: float, seed: int = 0) -> np.ndarray:
    """(T, 22, 3) y-up walking-like motion: swinging legs, moving along +z."""
    rng = np.random.default_rng(seed)
    time = np.arange(num_frames) / fps
    poses = np.zeros((num_frames, 22, 3))
    phase = rng.uniform(0, 2 * np.pi)
    poses[:, 1, 0] = 0.5 * np.sin(2 * np.pi * time + phase)
    poses[:, 2, 0] = -0.5 * np.sin(2 * np.pi * time + phase)
    poses[:, 4, 0] = 0.3 + 0.3 * np.sin(2 * np.pi * time + phase + 1)
    poses[:, 5, 0] = 0.3 + 0.3 * np.sin(2 * np.pi * time + phase + 4)
    poses[:, 0, 1] = 0.3 * np.sin(0.5 * time)  # slow turn
    trans = np.stack([0.1 * time, 0.02 * np.sin(4 * np.pi * time), 1.0 * time], axis=-1)
    rest = smplh_rest_joints_y_up()[:22]
    return smplh_joints(poses.reshape(num_frames, -1), trans, rest, np.asarray(SMPL.parents))


def synth_source(folder: Path, num_clips: int = 3, num_frames: int = 150) -> Path:
    """The demo-corpus layout: joints/<clip>.npy z-up 60 fps, texts/<clip>.txt, source.json."""
    (folder / "joints").mkdir(parents=True)
    (folder / "texts").mkdir()
    for index in range(num_clips):
        joints = walk(num_frames, 60.0, seed=index)
        z_up = np.stack([joints[..., 0], -joints[..., 2], joints[..., 1]], axis=-1)
        np.save(folder / "joints" / f"clip{index:02d}.npy", z_up.astype(np.float32))
        (folder / "texts" / f"clip{index:02d}.txt").write_text(CAPTIONS)
    (folder / "source.json").write_text(json.dumps({"fps": 60, "up": "z", "generator": "test"}))
    return folder


def read_split(out: Path, split: str) -> list[str]:
    return (out / f"{split}.txt").read_text().split()


def check_layout(out: Path, names: list[str]) -> None:
    """Every clip and its mirror have features, joints and texts of matching lengths."""
    for name in names:
        for clip in (name, "M" + name):
            features = np.load(out / "new_joint_vecs" / f"{clip}.npy")
            joints = np.load(out / "new_joints" / f"{clip}.npy")
            assert features.dtype == np.float32 and features.shape[1] == 263
            assert joints.shape == (features.shape[0], 22, 3) and np.isfinite(features).all()
            lines = (out / "texts" / f"{clip}.txt").read_text().splitlines()
            assert lines and all(len(line.split("#")) == 4 for line in lines)
    for split in ("train", "val", "test", "train_val", "all"):
        assert (out / f"{split}.txt").is_file()
    assert np.load(out / "Mean.npy").shape == (263,) and (np.load(out / "Std.npy") > 0).all()


# ----------------------------------------------------------------------------- joints


def test_joints_build_layout_mirrors_captions_splits_and_resume(tmp_path):
    source = synth_source(tmp_path / "src", num_clips=4)
    out = tmp_path / "out"
    assert main(["--source", "joints", "--input", str(source), "--out", str(out)]) == 0
    names = [f"clip{i:02d}" for i in range(4)]
    check_layout(out, names)

    # Mirrored clip = the pipeline applied to the mirrored 20-fps input.
    z_up = np.load(source / "joints" / "clip01.npy").astype(np.float64)
    joints = np.stack([z_up[..., 0], z_up[..., 2], -z_up[..., 1]], axis=-1)[::3]
    features, recovered = process_motion(mirror_joints(joints))
    np.testing.assert_allclose(np.load(out / "new_joint_vecs" / "Mclip01.npy"), features, atol=1e-5)
    np.testing.assert_allclose(np.load(out / "new_joints" / "Mclip01.npy"), recovered, atol=1e-5)
    assert len(features) == 49  # 150 frames at 60 fps -> 50 at 20 fps -> 49 feature frames

    # Captions: tagged, mirrored, timed.
    plain = (out / "texts" / "clip01.txt").read_text().splitlines()
    mirrored = (out / "texts" / "Mclip01.txt").read_text().splitlines()
    assert plain[0].startswith("a person walks forward and turns left.#a/DET person/NOUN walk/VERB")
    assert plain[0].endswith("#0.0#0.0") and plain[1].endswith("#0.5#2.0")
    assert mirrored[0].startswith("a person walks forward and turns right.#")
    assert mirrored[1].startswith("Someone waves the Left hand counterclockwise#")
    assert "Left/" in mirrored[1] and "counterclockwise/" in mirrored[1]

    # Splits: every clip once, mirror with its source, train_val = train + val.
    train, val, test = (read_split(out, s) for s in ("train", "val", "test"))
    assert sorted(train + val + test) == read_split(out, "all")
    assert len(read_split(out, "all")) == 8 and sorted(train + val) == read_split(out, "train_val")
    for split in (train, val, test):
        assert all(("M" + n in split) for n in split if not n.startswith("M"))

    report = json.loads((out / "build_report.json").read_text())
    assert report["clips_in"] == 4 and report["clips_out"] == 8 and report["skipped"] == []
    assert report["frames_out"] == 8 * 49
    assert report["hours_out"] == pytest.approx(8 * 49 / 20 / 3600)
    assert {"clips_s", "captions_s", "stats_s", "total_s"} <= set(report["timings"])
    assert report["versions"]["spacy_model"].startswith("en_core_web_sm")

    # Resume: nothing rebuilt, files untouched; --force rebuilds the same bytes.
    stamp = (out / "new_joint_vecs" / "clip00.npy").stat().st_mtime_ns
    before = (out / "new_joint_vecs" / "clip00.npy").read_bytes()
    (out / "texts" / "clip02.txt").unlink()  # an unfinished clip is rebuilt
    again = build_dataset(BuildConfig("joints", source, out))
    assert again["clips_built_this_run"] == 1 and again["clips_resumed"] == 3
    assert (out / "new_joint_vecs" / "clip00.npy").stat().st_mtime_ns == stamp
    forced = build_dataset(BuildConfig("joints", source, out, force=True))
    assert forced["clips_built_this_run"] == 4
    assert (out / "new_joint_vecs" / "clip00.npy").read_bytes() == before


def test_workers_give_the_same_dataset(tmp_path):
    source = synth_source(tmp_path / "src", num_clips=4, num_frames=90)
    one = build_dataset(BuildConfig("joints", source, tmp_path / "one", seed=3))
    two = build_dataset(BuildConfig("joints", source, tmp_path / "two", seed=3, workers=2))
    assert one["clips_out"] == two["clips_out"] == 8
    for relative in (
        "Mean.npy",
        "Std.npy",
        "train.txt",
        "test.txt",
        "new_joint_vecs/Mclip03.npy",
        "texts/Mclip03.txt",
    ):
        assert (tmp_path / "one" / relative).read_bytes() == (
            tmp_path / "two" / relative
        ).read_bytes()


def test_long_clips_are_cropped_with_shifted_captions(tmp_path):
    source = synth_source(tmp_path / "src", num_clips=1, num_frames=60 * 25)  # 25 s
    (source / "texts" / "clip00.txt").write_text("all of it\nlate part#20#24\n")
    build_dataset(BuildConfig("joints", source, tmp_path / "out", seed=1, max_seconds=10.0))
    assert np.load(tmp_path / "out" / "new_joints" / "clip00.npy").shape[0] == 199
    lines = (tmp_path / "out" / "texts" / "clip00.txt").read_text().splitlines()
    assert lines[0].endswith("#0.0#0.0")
    for line in lines[1:]:  # a timed caption survives only shifted inside the 10 s crop
        start, end = map(float, line.split("#")[-2:])
        assert 0.0 <= start < end <= 10.0


def test_reference_layout_with_index(tmp_path):
    pose_data = tmp_path / "pose_data"
    (pose_data / "MPI_HDM05" / "bk").mkdir(parents=True)
    (pose_data / "humanact12" / "humanact12").mkdir(parents=True)
    (pose_data / "CMU" / "01").mkdir(parents=True)
    long = walk(200, 20.0, seed=1)
    np.save(pose_data / "MPI_HDM05" / "bk" / "a_poses.npy", long)
    np.save(pose_data / "humanact12" / "humanact12" / "P1.npy", walk(40, 20.0, seed=2))
    np.save(pose_data / "CMU" / "01" / "b_poses.npy", walk(80, 20.0, seed=3))
    texts_dir = tmp_path / "texts"
    texts_dir.mkdir()
    for name in ("000000", "000001", "000002", "000003", "000004"):
        (texts_dir / f"{name}.txt").write_text(
            "a person walks.#a/DET person/NOUN walk/VERB#0.0#0.0\n"
        )
    (texts_dir / "000000.txt").write_text("a person walks.\nthen stops#1.0#2.0\n")
    index = tmp_path / "index.csv"
    index.write_text(
        "source_path,start_frame,end_frame,new_name\n"
        "./pose_data/MPI_HDM05/bk/a_poses.npy,10,60,000000.npy\n"
        "./pose_data/humanact12/humanact12/P1.npy,0,-1,000001.npy\n"
        "./pose_data/CMU/01/b_poses.npy,0,50,000002.npy\n"
        "./pose_data/CMU/01/b_poses.npy,40,80,000003.npy\n"
        "./pose_data/CMU/01/missing_poses.npy,0,50,000004.npy\n"
    )
    out = tmp_path / "out"
    code = main(
        [
            "--source",
            "joints",
            "--input",
            str(tmp_path),
            "--index",
            str(index),
            "--texts",
            str(texts_dir),
            "--out",
            str(out),
        ]
    )
    assert code == 0
    report = json.loads((out / "build_report.json").read_text())
    assert [(s["name"], s["reason"]) for s in report["skipped"]] == [
        ("000004", "source file not found")
    ]
    # Caption times are within the segment already: not shifted by the trim or the start.
    assert (out / "texts" / "000000.txt").read_text().splitlines()[1].endswith("#1.0#2.0")
    # HDM05: 3 s (60 frames) trimmed, then [10:60] -> 50 frames -> 49 feature frames.
    assert np.load(out / "new_joint_vecs" / "000000.npy").shape[0] == 49
    assert np.load(out / "new_joint_vecs" / "000001.npy").shape[0] == 39  # HumanAct12 taken whole
    assert np.load(out / "new_joint_vecs" / "000003.npy").shape[0] == 39
    # x is negated for AMASS rows: the clip equals the pipeline on the negated segment.
    segment_joints = long[60:][10:60].copy()
    segment_joints[..., 0] *= -1
    expected, _ = process_motion(segment_joints)
    np.testing.assert_allclose(np.load(out / "new_joint_vecs" / "000000.npy"), expected, atol=1e-5)
    expected_act, _ = process_motion(np.load(pose_data / "humanact12" / "humanact12" / "P1.npy"))
    np.testing.assert_allclose(
        np.load(out / "new_joint_vecs" / "000001.npy"), expected_act, atol=1e-5
    )
    # Segments of one capture share a split.
    splits = {s: set(read_split(out, s)) for s in ("train", "val", "test")}
    assert any({"000002", "000003"} <= names for names in splits.values())


def test_given_split_files(tmp_path):
    source = synth_source(tmp_path / "src", num_clips=3, num_frames=90)
    splits = tmp_path / "splits"
    splits.mkdir()
    (splits / "train.txt").write_text("clip00\nMclip00\n")
    (splits / "val.txt").write_text("clip01\n")
    (splits / "test.txt").write_text("")
    report = build_dataset(BuildConfig("joints", source, tmp_path / "out", splits_dir=splits))
    out = tmp_path / "out"
    assert read_split(out, "train") == ["Mclip00", "clip00"]
    assert read_split(out, "val") == ["Mclip01", "clip01"]
    assert report["stats"]["unassigned_to_splits"] == ["clip02"]


# ----------------------------------------------------------------------------- AMASS


def test_amass_build(tmp_path):
    models = make_body_model(tmp_path / "body_models", genders=("male", "female", "neutral"))
    amass = tmp_path / "amass" / "KIT" / "3"
    amass.mkdir(parents=True)
    make_amass_npz(amass / "walk_poses.npz", num_frames=240, fps=120.0)
    make_amass_npz(
        amass / "odd_poses.npz", num_frames=120, fps=59.94, seed=1, gender=np.array(b"female")
    )
    make_amass_npz(amass / "shape.npz", mocap_framerate=None)  # like AMASS's shape.npz files
    texts_dir = tmp_path / "texts"
    texts_dir.mkdir()
    for name in ("KIT_3_walk_poses", "KIT_3_odd_poses", "KIT_3_shape"):
        (texts_dir / f"{name}.txt").write_text("a person walks forward\n")
    out = tmp_path / "out"
    code = main(
        [
            "--source",
            "amass",
            "--input",
            str(tmp_path / "amass"),
            "--body-model",
            str(models),
            "--texts",
            str(texts_dir),
            "--out",
            str(out),
        ]
    )
    assert code == 0
    check_layout(out, ["KIT_3_walk_poses", "KIT_3_odd_poses"])
    report = json.loads((out / "build_report.json").read_text())
    assert report["skipped"] == [
        {
            "name": "KIT_3_shape",
            "path": str(amass / "shape.npz"),
            "reason": "no mocap_framerate (not a motion file)",
        }
    ]
    # 240 frames at 120 fps -> 40 at 20 fps; 120 at 59.94 fps -> 40 -> 39 feature frames each.
    assert np.load(out / "new_joint_vecs" / "KIT_3_walk_poses.npy").shape[0] == 39
    assert np.load(out / "new_joint_vecs" / "KIT_3_odd_poses.npy").shape[0] == 39
    # The built clip walks forward (+z after canonicalisation) at about 1.1 m/s.
    joints = np.load(out / "new_joints" / "KIT_3_walk_poses.npy")
    assert 0.8 < (joints[-1, 0, 2] - joints[0, 0, 2]) / (len(joints) - 1) * 20 < 1.4
    assert main(["--source", "amass", "--input", str(tmp_path / "amass"), "--out", str(out)]) == 2


# ----------------------------------------------------------------------------- BVH


@needs_mocap
def test_bvh_build_from_real_files(tmp_path):
    source = tmp_path / "bvh"
    source.mkdir()
    shutil.copy(
        MOCAP / "bandai-namco-2/data/dataset-2_walk_normal_001.bvh", source / "bandai_walk.bvh"
    )
    shutil.copy(MOCAP / "cmu/002_01.bvh", source / "cmu_walk.bvh")
    (source / "texts").mkdir()
    for name in ("bandai_walk", "cmu_walk"):
        (source / "texts" / f"{name}.txt").write_text("a person walks forward.\n")
    out = tmp_path / "out"
    assert main(["--source", "bvh", "--input", str(source), "--out", str(out)]) == 0
    check_layout(out, ["bandai_walk", "cmu_walk"])
    # 273 frames at 30 fps -> 182 at 20 fps -> 181; CMU: 170 at 60 fps (T-pose dropped) -> 57 -> 56.
    assert np.load(out / "new_joint_vecs" / "bandai_walk.npy").shape[0] == 181
    assert np.load(out / "new_joint_vecs" / "cmu_walk.npy").shape[0] == 56
    for name in ("bandai_walk", "cmu_walk", "Mcmu_walk"):
        joints = np.load(out / "new_joints" / f"{name}.npy")
        assert joints[-1, 0, 2] - joints[0, 0, 2] > 1.0  # walks forward along +z
        assert joints[..., 1].min() == pytest.approx(0.0, abs=0.03)  # on the floor


# ----------------------------------------------------------------------------- bad inputs


def test_bad_clips_are_reported_and_skipped(tmp_path):
    source = synth_source(tmp_path / "src", num_clips=1, num_frames=90)
    joints_dir, texts_dir = source / "joints", source / "texts"
    good = np.load(joints_dir / "clip00.npy")
    (joints_dir / "truncated.npy").write_bytes((joints_dir / "clip00.npy").read_bytes()[:300])
    nan = good.copy()
    nan[5:7, 3] = np.nan
    np.save(joints_dir / "nan.npy", nan)
    np.save(joints_dir / "oneframe.npy", good[:1])
    np.save(joints_dir / "nocaption.npy", good)
    np.save(joints_dir / "latin1.npy", good)
    np.save(joints_dir / "empty.npy", good)
    for name in ("truncated", "nan", "oneframe"):
        (texts_dir / f"{name}.txt").write_text("a person walks\n")
    (texts_dir / "latin1.txt").write_bytes("un caf\xe9\n".encode("latin-1"))
    (texts_dir / "empty.txt").write_text("\n")
    report = build_dataset(BuildConfig("joints", source, tmp_path / "out"))
    reasons = {entry["name"]: entry["reason"] for entry in report["skipped"]}
    assert set(reasons) == {"truncated", "nan", "oneframe", "nocaption", "latin1", "empty"}
    assert "cannot read" in reasons["truncated"]
    assert "NaN" in reasons["nan"]
    assert "1 frame" in reasons["oneframe"]
    assert reasons["nocaption"] == "no caption file"
    assert "not UTF-8" in reasons["latin1"] and "empty" in reasons["empty"]
    assert report["clips_out"] == 2 and read_split(tmp_path / "out", "all") == ["Mclip00", "clip00"]
    assert not (tmp_path / "out" / "new_joint_vecs" / "nan.npy").exists()


def test_bad_bvh_files_are_reported(tmp_path):
    from test_sources import TINY_BVH

    source = tmp_path / "bvh"
    (source / "texts").mkdir(parents=True)
    (source / "zero_time.bvh").write_text(TINY_BVH.replace("Frame Time: 0.05", "Frame Time: 0"))
    (source / "unknown.bvh").write_text(TINY_BVH)
    for name in ("zero_time", "unknown"):
        (source / "texts" / f"{name}.txt").write_text("a person walks\n")
    report = build_dataset(BuildConfig("bvh", source, tmp_path / "out"))
    reasons = {entry["name"]: entry["reason"] for entry in report["skipped"]}
    assert "frame time" in reasons["zero_time"]
    assert "no built-in mapping" in reasons["unknown"]
    assert report["clips_out"] == 0
    assert json.loads((tmp_path / "out" / "build_report.json").read_text())["clips_out"] == 0
    mapping = {name: "Hips" for name in SMPL.joint_names} | {"head": "Skull"}
    (tmp_path / "map.json").write_text(json.dumps(mapping))
    config = BuildConfig("bvh", source, tmp_path / "out2", mapping=str(tmp_path / "map.json"))
    reasons = {entry["name"]: entry["reason"] for entry in build_dataset(config)["skipped"]}
    assert "['Skull']" in reasons["unknown"] and "not in the file" in reasons["unknown"]


def test_a_bug_stops_the_build_instead_of_skipping_the_clip(tmp_path, monkeypatch):
    """Only clip data errors are skipped; anything else keeps its traceback."""
    import dataset_tools.build_clips as build_clips

    source = synth_source(tmp_path / "src", num_clips=1, num_frames=60)

    def broken(clip, skeleton, target_offsets):
        raise TypeError("a bug in the feature code")

    monkeypatch.setattr(build_clips, "process_motion", broken)
    with pytest.raises(TypeError, match="a bug in the feature code"):
        build_dataset(BuildConfig("joints", source, tmp_path / "out"))


def test_command_line_errors(tmp_path, capsys):
    def run(input_dir: Path, *extra: str) -> int:
        return main(
            ["--source", "joints", "--input", str(input_dir), "--out", str(tmp_path / "o"), *extra]
        )

    assert run(tmp_path / "nope") == 2
    assert "does not exist" in capsys.readouterr().err
    (tmp_path / "plain").mkdir()
    assert run(tmp_path / "plain") == 2
    assert "--fps is required" in capsys.readouterr().err
    assert run(tmp_path, "--workers", "0") == 2
    capsys.readouterr()
    assert main(["--source", "fbx", "--input", "x", "--out", "y"]) == 2
    err = capsys.readouterr().err
    assert "invalid choice: 'fbx'" in err and len(err.strip().splitlines()) == 1


@needs_mocap
def test_bandai_labels_give_captions(tmp_path):
    bandai = MOCAP / "bandai-namco-2"
    data = tmp_path / "bandai" / "data"
    data.mkdir(parents=True)
    shutil.copytree(bandai / "cfg", tmp_path / "bandai" / "cfg")
    stem = "dataset-2_raise-up-left-hand_elderly_001"
    for suffix in (".bvh", ".json"):
        shutil.copy(bandai / "data" / f"{stem}{suffix}", data / f"{stem}{suffix}")
    out = tmp_path / "out"
    report = build_dataset(BuildConfig("bvh", data, out))
    assert report["clips_out"] == 2
    lines = (out / "texts" / f"{stem}.txt").read_text().splitlines()
    assert [line.split("#")[0] for line in lines] == [
        "a person raises the left hand.",
        "a person raises the left hand in an elderly way.",
    ]
    mirrored = (out / "texts" / f"M{stem}.txt").read_text()
    assert mirrored.startswith("a person raises the right hand.#")


def test_amass_with_index_and_humanact12_rows(tmp_path):
    models = make_body_model(tmp_path / "models")
    amass = tmp_path / "amass"
    (amass / "TotalCapture" / "s1").mkdir(parents=True)
    (amass / "humanact12" / "humanact12").mkdir(parents=True)
    make_amass_npz(amass / "TotalCapture" / "s1" / "walk_poses.npz", num_frames=300, fps=60.0)
    np.save(amass / "humanact12" / "humanact12" / "P2.npy", walk(30, 20.0, seed=5))
    (amass / "texts").mkdir()
    for name in ("000007", "000008"):
        (amass / "texts" / f"{name}.txt").write_text("a person walks\n")
    index = tmp_path / "index.csv"
    index.write_text(
        "source_path,start_frame,end_frame,new_name\n"
        "./pose_data/TotalCapture/s1/walk_poses.npy,5,65,000007.npy\n"
        "./pose_data/humanact12/humanact12/P2.npy,0,-1,000008.npy\n"
    )
    report = build_dataset(
        BuildConfig("amass", amass, tmp_path / "out", index=index, body_model_dir=models)
    )
    assert report["skipped"] == [] and report["clips_out"] == 4
    # 300 frames at 60 fps -> 100 at 20; 1 s (20 frames) trimmed; [5:65] -> 60 -> 59 features.
    assert np.load(tmp_path / "out" / "new_joint_vecs" / "000007.npy").shape[0] == 59
    assert np.load(tmp_path / "out" / "new_joint_vecs" / "000008.npy").shape[0] == 29


REFERENCE = SHARED / "reference" / "humanml3d"


@pytest.mark.skipif(not REFERENCE.is_dir(), reason=f"reference files absent ({REFERENCE})")
def test_parity_with_reference_clip(tmp_path):
    # Rebuilding HumanML3D's own processed joints (20 fps, y-up) reproduces its features to the
    # tolerance the retargeting round trip allows (see shared/README.md), contacts exactly.
    source = tmp_path / "src"
    (source / "texts").mkdir(parents=True)
    shutil.copy(REFERENCE / "new_joints" / "012314.npy", source / "012314.npy")
    (source / "texts" / "012314.txt").write_text("a person walks\n")
    out = tmp_path / "out"
    assert (
        main(["--source", "joints", "--fps", "20", "--input", str(source), "--out", str(out)]) == 0
    )
    built = np.load(out / "new_joint_vecs" / "012314.npy")
    reference = np.load(REFERENCE / "new_joint_vecs" / "012314.npy")[: len(built)]
    assert built.shape == (169, 263)
    assert np.abs(built - reference).max() < 0.02
    np.testing.assert_array_equal(built[:, -4:], reference[:, -4:])


def test_target_skeleton_sets_bone_lengths(tmp_path):
    source = synth_source(tmp_path / "src", num_clips=1, num_frames=90)
    rest = smplh_rest_joints_y_up()[:22] * 1.25
    np.save(tmp_path / "big.npy", rest)
    build_dataset(
        BuildConfig("joints", source, tmp_path / "out", target_skeleton=tmp_path / "big.npy")
    )
    joints = np.load(tmp_path / "out" / "new_joints" / "clip00.npy")
    # new_joints come from ric features, whose bone lengths follow the target skeleton.
    expected = SMPL.bone_lengths_of(rest)[1:]
    np.testing.assert_allclose(SMPL.bone_lengths_of(joints[0])[1:], expected, rtol=0.02, atol=0.005)
