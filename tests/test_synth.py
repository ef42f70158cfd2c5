"""The procedural demo corpus: bodies, clips, captions, the written folder and its command line."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from dataset_tools.rotations import y_up_to_z_up, z_up_to_y_up
from dataset_tools.synth import captions as caption_module
from dataset_tools.synth.body import DOF, NUM_DOFS, make_body, mirror_dofs, sample_body
from dataset_tools.synth.captions import captions_for
from dataset_tools.synth.cli import contact_sheet_main, main
from dataset_tools.synth.clip import MAX_SECONDS, MIN_SECONDS, synthesize_action, synthesize_clip
from dataset_tools.synth.corpus import load_clip, make_clip, write_corpus
from dataset_tools.synth.motions import ACTIONS


def _files(folder: Path) -> dict[str, bytes]:
    return {
        str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()
    }


def test_there_are_fourteen_actions_with_parameters():
    assert len(ACTIONS) >= 14
    rng = np.random.default_rng(0)
    for name, spec in ACTIONS.items():
        params, seconds = spec.sample(rng)
        assert 0.5 < seconds <= MAX_SECONDS, name
        json.dumps(params)  # labels must be JSON-ready


def test_subject_proportions_vary_within_ten_percent_and_are_symmetric():
    mean = make_body().bone_lengths
    rng = np.random.default_rng(1)
    ratios = []
    for _ in range(50):
        lengths = sample_body(rng).bone_lengths
        ratios.append(lengths[1:] / mean[1:])
        for left, right in (
            (1, 2),
            (4, 5),
            (7, 8),
            (10, 11),
            (13, 14),
            (16, 17),
            (18, 19),
            (20, 21),
        ):
            assert lengths[left] == pytest.approx(lengths[right])
    ratios = np.array(ratios)
    assert ratios.min() > 0.85 and ratios.max() < 1.15
    assert ratios.std() > 0.03  # the subjects do differ


def test_bone_lengths_constant_and_feet_on_the_ground_in_every_clip():
    for index in range(12):
        clip = synthesize_clip(3, index)
        joints = clip.joints.astype(np.float64)
        assert MIN_SECONDS * clip.fps <= len(joints) <= MAX_SECONDS * clip.fps + 1
        parents = np.array(
            [-1, 0, 0, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 9, 9, 12, 13, 14, 16, 17, 18, 19]
        )
        lengths = np.linalg.norm(joints[:, 1:] - joints[:, parents[1:]], axis=-1)
        np.testing.assert_allclose(lengths, lengths[:1].repeat(len(lengths), 0), atol=2e-5)
        np.testing.assert_allclose(lengths[0], clip.body.bone_lengths[1:], atol=2e-5)
        lowest = joints[:, :, 1].min(axis=1)
        assert lowest.min() > -1e-4  # no penetration
        airborne = sum(s.end - s.start for s in clip.segments if s.action in ("jump", "hop", "run"))
        if airborne == 0:
            # Some foot touches the ground: a toe joint, or the heel under an ankle (about 6 cm).
            assert lowest.max() < 0.08


def test_mirroring_poses_is_an_involution_that_swaps_sides():
    rng = np.random.default_rng(2)
    pose = rng.normal(size=(5, NUM_DOFS))
    np.testing.assert_array_equal(mirror_dofs(mirror_dofs(pose)), pose)
    mirrored = mirror_dofs(pose)
    np.testing.assert_array_equal(mirrored[:, DOF["r_knee"]], pose[:, DOF["l_knee"]])
    np.testing.assert_array_equal(mirrored[:, DOF["spine_twist"]], -pose[:, DOF["spine_twist"]])


def test_gait_speed_follows_the_requested_speed_and_planted_feet_do_not_slide():
    for gait, speed in (("walk", 0.7), ("walk", 1.2), ("walk", 1.7), ("run", 2.4), ("run", 3.6)):
        params = {"gait": gait, "direction": "forward", "speed": "normal", "speed_mps": speed}
        joints = synthesize_action(gait, params, 4.0).joints.astype(np.float64)
        measured = (joints[-60, 0, 2] - joints[60, 0, 2]) / ((len(joints) - 120) / 60)
        assert measured == pytest.approx(speed, rel=0.05), gait
        # The planted foot: the lowest toe barely moves while it is down.
        for toe in (10, 11):
            down = joints[1:, toe, 1] < 0.004
            step = np.linalg.norm(np.diff(joints[:, toe, [0, 2]], axis=0), axis=1)[down[:]]
            assert np.median(step) * 60 < 0.06


def test_arms_swing_against_the_legs_in_gait():
    params = {"gait": "walk", "direction": "forward", "speed": "normal", "speed_mps": 1.2}
    joints = synthesize_action("walk", params, 4.0).joints.astype(np.float64)
    left_foot_ahead = joints[:, 7, 2] - joints[:, 8, 2]
    left_hand_ahead = joints[:, 20, 2] - joints[:, 21, 2]
    assert np.corrcoef(left_foot_ahead, left_hand_ahead)[0, 1] < -0.7


def test_same_seed_same_bytes_and_worker_count_does_not_matter(tmp_path):
    write_corpus(tmp_path / "a", 6, seed=7, progress=False)
    write_corpus(tmp_path / "b", 6, seed=7, progress=False, workers=2)
    write_corpus(tmp_path / "c", 6, seed=8, progress=False)
    a, b, c = (_files(tmp_path / x) for x in "abc")
    assert a == b
    assert a["joints/synth_000000.npy"] != c["joints/synth_000000.npy"]


def test_corpus_layout_and_labels(tmp_path):
    out = tmp_path / "corpus"
    write_corpus(out, 5, seed=3, progress=False)
    source = json.loads((out / "source.json").read_text())
    assert source["fps"] == 60 and source["up"] == "z" and source["skeleton"] == "smpl"
    assert (
        source["generator"] == "dataset_tools.synth"
        and source["seed"] == 3
        and source["clips"] == 5
    )
    labels = json.loads((out / "labels.json").read_text())
    assert sorted(labels["clips"]) == [f"synth_{i:06d}" for i in range(5)]
    assert source["paraphrase_clips"] == 0  # a tenth of 5 clips
    for name, label in labels["clips"].items():
        joints = np.load(out / "joints" / f"{name}.npy")
        assert joints.dtype == np.float32 and joints.shape == (label["frames"], 22, 3)
        # z-up: the head is above the pelvis above the ankles along z.
        assert joints[0, 15, 2] > joints[0, 0, 2] > joints[0, 7, 2]
        lines = (out / "texts" / f"{name}.txt").read_text().splitlines()
        assert len(lines) == 3 and len(set(lines)) == 3
        segments = label["segments"]
        assert segments[0]["start"] == 0 and segments[-1]["end"] == label["frames"]
        assert all(a["end"] == b["start"] for a, b in zip(segments[:-1], segments[1:]))
        assert 1 <= len(segments) <= 3
        assert 0.85 < label["subject"]["overall_scale"] < 1.15
        back, texts, again = load_clip(out, name)
        np.testing.assert_allclose(back, z_up_to_y_up(joints))
        assert again == label and texts == lines


def test_z_up_conversion_is_a_proper_rotation():
    points = np.random.default_rng(0).normal(size=(10, 3))
    zup = y_up_to_z_up(points)
    np.testing.assert_allclose(z_up_to_y_up(zup), points)
    np.testing.assert_allclose(
        np.cross(zup[0], zup[1]), y_up_to_z_up(np.cross(points[0], points[1]))
    )


def _captions(pool: str, clips: int = 60) -> list[str]:
    rng = np.random.default_rng(4)
    out = []
    for index in range(clips):
        _, _, label = make_clip(11, index)
        plan = [(s["action"], s["params"]) for s in label["segments"]]
        out += [t.lower() for t in captions_for(plan, rng, pool=pool)]
    return out


# Phrasings of the held-out families (:mod:`dataset_tools.synth.captions`) no training caption
# may contain; each occurs in the held-out captions of 60 clips.
HELD_OUT_MARKERS = [" two times", " 2 times", " 2x", "couple of times", "stroll", "paces forward",
                    "dash", "bounc", "duck", "applaud", "subsequently", "an individual",
                    "the subject", "followed by", "tward"]  # fmt: skip


def test_captions_name_the_side_and_heldout_wording_is_disjoint():
    for index in range(60):
        _, texts, label = make_clip(11, index)
        for segment in label["segments"]:
            side = segment["params"].get("side") or segment["params"].get("direction")
            if side in ("left", "right"):
                assert all(side in t.lower() for t in texts), (texts, segment)
    train, heldout = _captions("train"), _captions("heldout")
    for subject in caption_module.SUBJECTS["heldout"]:
        assert not any(t.startswith(subject) for t in train)
    for subject in caption_module.SUBJECTS["train"]:
        assert not any(t.startswith(subject + " ") for t in heldout)
    # Held-out verb templates never occur in training captions.
    for templates in caption_module._TEMPLATES.values():
        for present, _ in templates["heldout"]:
            head = present.split("{")[0].strip()
            assert not any(head in t for t in train), head
    for marker in HELD_OUT_MARKERS:
        assert not any(marker in t for t in train), marker
        assert any(marker in t for t in heldout), marker


def test_training_captions_vary_as_people_write():
    train = _captions("train", clips=120)
    for form in [" twice", " once", " times", " 3 times", " is ", "he ", "then", " before ",
                 "after "]:  # fmt: skip
        assert any(form in t for t in train), form
    assert any(not t.endswith(".") for t in train)  # a few lose their full stop
    # every imperative (held out) starts with a verb in its base form
    assert (
        caption_module.base_form("raises the left hand and waves") == "raise the left hand and wave"
    )
    assert caption_module.base_form("does two squats") == "do two squats"
    assert caption_module.base_form("dashes ahead") == "dash ahead"
    assert caption_module.base_form("lowers to the ground, sits, then stands up") == (
        "lower to the ground, sit, then stand up"
    )
    assert caption_module.base_form("sits a moment and stands up") == "sit a moment and stand up"


def test_paraphrase_captions_mix_training_and_held_out_families():
    paraphrase = _captions("paraphrase")
    train = set(_captions("train", clips=300))
    assert not set(paraphrase) & train
    assert any(
        t.split(" ")[0] in ("walk", "jump", "run", "hop", "clap", "squat") for t in paraphrase
    )
    with pytest.raises(ValueError, match="unknown caption pool"):
        caption_module.caption([("bow", {})], np.random.default_rng(0), "nope")


def test_cli_writes_a_corpus_and_rejects_bad_input(tmp_path, capsys):
    out = tmp_path / "cli"
    assert main(["--out", str(out), "--clips", "3", "--seed", "1", "--quiet"]) == 0
    assert len(list((out / "joints").glob("*.npy"))) == 3
    assert main(["--out", str(out), "--clips", "3", "--quiet"]) == 2  # exists, no --force
    assert main(["--out", str(out), "--clips", "2", "--quiet", "--force"]) == 0
    assert len(list((out / "joints").glob("*.npy"))) == 2
    assert main(["--out", str(tmp_path / "x"), "--clips", "0", "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "error:" in err and "\n" not in err.strip().splitlines()[-1]


def test_contact_sheet_renders_a_png(tmp_path):
    out = tmp_path / "cli"
    assert main(["--out", str(out), "--clips", "3", "--seed", "2", "--quiet"]) == 0
    png = tmp_path / "sheet.png"
    assert (
        contact_sheet_main(
            ["--input", str(out), "--out", str(png), "--clips", "2", "--frames", "3"]
        )
        == 0
    )
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert contact_sheet_main(["--input", str(tmp_path / "missing"), "--out", str(png)]) == 2


def test_paraphrase_clips_follow_the_corpus_and_keep_to_their_split(tmp_path):
    from dataset_tools.build import pinned_splits
    from dataset_tools.command import UsageError

    out = tmp_path / "corpus"
    source = write_corpus(out, 20, seed=5, progress=False)
    labels = json.loads((out / "labels.json").read_text())["clips"]
    assert source["paraphrase_clips"] == 2 and len(labels) == 22
    pinned = [name for name, label in labels.items() if label.get("split")]
    assert pinned == ["synth_000020", "synth_000021"]
    assert {labels[n]["caption_pool"] for n in pinned} == {"paraphrase"}
    assert pinned_splits(out, sorted(labels)) == dict.fromkeys(pinned, "test_paraphrase")
    # the first clips are those of a corpus without paraphrase clips
    plain = tmp_path / "plain"
    write_corpus(plain, 20, seed=5, progress=False, paraphrase_clips=0)
    assert _files(plain)["joints/synth_000019.npy"] == _files(out)["joints/synth_000019.npy"]
    assert not (plain / "joints" / "synth_000020.npy").exists()
    # a label may not pin a clip to a split the builder writes itself
    labels["synth_000020"]["split"] = "train"
    (out / "labels.json").write_text(json.dumps({"clips": labels}))
    with pytest.raises(UsageError, match="names split 'train'"):
        pinned_splits(out, sorted(labels))


def test_paraphrase_clips_change_nothing_the_stages_train_on(tmp_path):
    from dataset_tools import humanml3d
    from dataset_tools.build import BuildConfig, build_dataset

    built = {}
    for name, extra in (("with", 3), ("without", 0)):
        write_corpus(tmp_path / name / "src", 10, seed=2, progress=False, paraphrase_clips=extra)
        config = BuildConfig("joints", tmp_path / name / "src", tmp_path / name / "ds", seed=2)
        report = build_dataset(config)
        built[name] = (tmp_path / name / "ds", report)
    (with_dir, report), (without_dir, _) = built["with"], built["without"]
    assert report["splits"]["test_paraphrase"] == 6  # 3 clips and their mirrors
    assert humanml3d.read_split(with_dir, "test_paraphrase") == [
        "Msynth_000010", "Msynth_000011", "Msynth_000012",
        "synth_000010", "synth_000011", "synth_000012",
    ]  # fmt: skip
    for split in ("train", "val", "test"):
        assert humanml3d.read_split(with_dir, split) == humanml3d.read_split(without_dir, split)
    for a, b in zip(humanml3d.read_mean_std(with_dir), humanml3d.read_mean_std(without_dir)):
        np.testing.assert_array_equal(a, b)


COUNTED = ("jump", "hop", "punch", "squat", "clap")


@pytest.mark.parametrize("pool", ["train", "paraphrase"])
def test_the_clause_parser_reads_the_counts_and_clauses_of_every_pool(pool):
    """Tagged as the builder tags them, captions give their clip's labelled clauses and counts
    (a count of one may go unsaid)."""
    pytest.importorskip("spacy")
    from dataset_tools.texts import tag_captions
    from t2m.clauses import clause_captions, repetition_count

    rng = np.random.default_rng(9)
    texts, wanted = [], []
    for index in range(80):
        _, _, label = make_clip(13, index)
        segments = label["segments"]
        plan = [(s["action"], s["params"]) for s in segments]
        counts = [  # the actions whose captions say a count
            s["params"].get("count", 1) if s["action"] in COUNTED else 0 for s in segments
        ]
        for text in captions_for(plan, rng, pool=pool):
            texts.append(text)
            wanted.append(counts)
    wrong = []
    for text, counts, pairs in zip(texts, wanted, tag_captions(texts), strict=True):
        clauses = clause_captions([f"{word}/{pos}" for word, pos in pairs])
        got = [repetition_count(clause) for clause in clauses]
        if len(got) != len(counts) or any(g != c and (g, c) != (0, 1) for g, c in zip(got, counts)):
            wrong.append((text, got, counts))
    assert len(texts) > 150 and not wrong, wrong[:5]
