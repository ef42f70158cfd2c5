"""The real-mocap benchmark (t2m.evaluate.mocap_bench): captions, split, classifier, bad input,
two Bandai-Namco folders (a small Bandai-Namco-1-layout folder made from Bandai-Namco-2 clips, since
CI has no Bandai-Namco-1), and a tiny end to end on a few Bandai-Namco-2 clips."""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import numpy as np
import pytest

from dataset_tools.command import UsageError
from dataset_tools.mirror import mirror_caption
from t2m.evaluate import mocap, mocap_bench
from t2m.evaluate.mocap_bench import Capture

MOCAP = Path(__file__).resolve().parents[1].parent / "shared" / "mocap" / "bandai-namco-2"
# Bandai-Namco-1 is not in ../shared: its folder (data/ and cfg/) given by this variable
BN1 = Path(os.environ.get("BANDAI_NAMCO_1", "/nonexistent"))
BN2_CONTENTS = (
    "walk", "walk-turn-left", "walk-turn-right", "run", "wave-both-hands", "wave-left-hand",
    "wave-right-hand", "raise-up-both-hands", "raise-up-left-hand", "raise-up-right-hand",
)  # fmt: skip
STYLES = ("active", "elderly", "exhausted", "feminine", "masculine", "normal", "youthful")
BN1_CONTENTS = (
    "walk", "run", "dash", "walk-back", "walk-right", "walk-left", "bow", "bye", "guide",
    "byebye", "respond", "call", "punch", "kick", "slash", "dance-long", "dance-short",
)  # fmt: skip
BN1_STYLES = (
    "normal", "happy", "sad", "angry", "proud", "not-confident", "masculinity", "feminine",
    "childish", "old", "tired", "active", "musical", "giant", "chimpira",
)  # fmt: skip
"""Bandai-Namco-1's labels, in the order of its cfg/*_label.txt."""
HELD_OUT = ("run", "dash", "walk-back", "walk-left", "walk-right", "bow", "bye", "byebye", "guide")
"""Bandai-Namco-1's contents with one take of every style."""


def captures(takes: int = 6) -> list[Capture]:
    """Every content and style of Bandai-Namco-2 with ``takes`` takes, no files."""
    return [
        Capture(f"dataset-2_{content}_{style}_{take:03d}", Path("x.bvh"), content, style,
                f"{take:03d}", "dataset-2", 5.0)
        for content in BN2_CONTENTS
        for style in STYLES
        for take in range(1, takes + 1)
    ]  # fmt: skip


def bn1_captures() -> list[Capture]:
    """Bandai-Namco-1's clips as its copy here holds them, no files: walk in two takes of every
    style, call, punch and slash in two normal takes, kick and dance-short in one, the other
    contents one take of every style (dance-long: none); its dash in the normal style is too
    short to use."""
    every = []
    for content in BN1_CONTENTS:
        if content == "dance-long":
            continue
        if content in ("call", "punch", "slash", "kick", "dance-short"):
            styles, takes = ("normal",), 1 if content in ("kick", "dance-short") else 2
        else:
            styles, takes = BN1_STYLES, 2 if content == "walk" else 1
        for style in styles:
            for take in range(1, takes + 1):
                seconds = 0.7 if (content, style) == ("dash", "normal") else 4.0
                every.append(
                    Capture(f"dataset-1_{content}_{style}_{take:03d}", Path("x.bvh"), content,
                            mocap_bench.STYLE_ALIASES.get(style, style), f"{take:03d}",
                            "dataset-1", seconds)
                )  # fmt: skip
    return every


def bn1_folder(root: Path, clips: dict[str, str]) -> Path:
    """A Bandai-Namco-1-layout folder (``data/dataset-1_<content>_<style>_<take>.bvh`` with its
    ``.json``, ``cfg/*_label.txt`` as Bandai-Namco-1's) whose motions are Bandai-Namco-2 clips:
    ``clips`` maps a Bandai-Namco-1 clip name to the Bandai-Namco-2 clip copied under it. Also
    a ``.json`` without its ``.bvh`` (dance-long), as in the copy of Bandai-Namco-1 here."""
    (root / "data").mkdir(parents=True)
    (root / "cfg").mkdir()
    for kind, labels in (("content", BN1_CONTENTS), ("style", BN1_STYLES)):
        lines = "".join(f"dataset-1_{label}\n" for label in labels)
        (root / "cfg" / f"{kind}_label.txt").write_text(lines)
    for name, source in clips.items():
        _, content, style, _ = name.split("_")
        shutil.copy(MOCAP / "data" / f"{source}.bvh", root / "data" / f"{name}.bvh")
        labels = {"content": BN1_CONTENTS.index(content), "style": BN1_STYLES.index(style)}
        (root / "data" / f"{name}.json").write_text(json.dumps(labels))
    dance = {"content": BN1_CONTENTS.index("dance-long"), "style": 0}
    (root / "data" / "dataset-1_dance-long_normal_001.json").write_text(json.dumps(dance))
    return root


def bn2_folder(root: Path, names: list[str]) -> Path:
    """A Bandai-Namco-2 folder with the named clips only."""
    (root / "data").mkdir(parents=True)
    shutil.copytree(MOCAP / "cfg", root / "cfg")
    for name in names:
        for suffix in (".bvh", ".json"):
            shutil.copy(MOCAP / "data" / f"{name}{suffix}", root / "data" / f"{name}{suffix}")
    return root


def test_content_labels_name_the_checks_and_mirror_onto_each_other():
    assert set(mocap.CONTENT_LABELS.values()) == set(mocap.CONTENT_CHECKS)
    for content, caption in mocap.CONTENT_LABELS.items():
        other = mocap_bench.MIRRORED_CONTENT.get(content, content)
        assert mirror_caption(caption) == mocap.CONTENT_LABELS[other]
    # every content of both datasets has phrases, and is either judged or named as not judged
    assert set(mocap_bench.CONTENT_PHRASES) == set(BN2_CONTENTS) | set(BN1_CONTENTS)
    assert set(mocap.CONTENT_LABELS) | set(mocap.NOT_JUDGED) == set(mocap_bench.CONTENT_PHRASES)
    assert not set(mocap.CONTENT_LABELS) & set(mocap.NOT_JUDGED)
    assert {"walk-back", "walk-left", "walk-right", "dash", "bow"} <= set(mocap.CONTENT_LABELS)
    # one label per style meaning: Bandai-Namco-1's names of Bandai-Namco-2's styles are aliases
    merged = {mocap_bench.STYLE_ALIASES.get(style, style) for style in BN1_STYLES}
    assert merged | set(STYLES) == set(mocap_bench.STYLE_WORDS)
    assert len(set(mocap_bench.STYLE_WORDS)) == 15 and set(STYLES) <= merged
    assert mocap_bench.STYLE_ALIASES == {
        "old": "elderly", "tired": "exhausted", "masculinity": "masculine", "childish": "youthful"
    }  # fmt: skip


def test_captions_name_content_and_style_in_varied_words():
    every = captures() + bn1_captures()
    texts = {capture.name: mocap_bench.clip_captions(capture) for capture in every}
    assert texts == {c.name: mocap_bench.clip_captions(c) for c in every}  # deterministic
    for capture in every:
        words = mocap_bench.STYLE_WORDS[capture.style]
        shapes = (words.subjects, words.manners, words.adverbs)
        for caption, options in zip(texts[capture.name], shapes, strict=True):
            assert any(phrase in caption for phrase in mocap_bench.CONTENT_PHRASES[capture.content])
            assert any(option in caption for option in options), (caption, capture.style)
        # the side of a one-sided content is named, and it is the content's own
        for caption in texts[capture.name]:
            sides = {side for side in ("left", "right") if side in caption}
            assert sides == {side for side in ("left", "right") if side in capture.content}
    assert {c.content for c in every} == set(BN1_CONTENTS + BN2_CONTENTS) - {"dance-long"}
    assert len({c.style for c in every}) == 15
    distinct = {caption for captions in texts.values() for caption in captions}
    assert len(distinct) > 0.7 * 3 * len(every)  # varied: most captions are unique
    walks = {t for c in every if c.content == "walk" for t in texts[c.name]}
    assert {"walks forward", "walks straight ahead"} <= {
        phrase for phrase in mocap_bench.CONTENT_PHRASES["walk"] if any(phrase in t for t in walks)
    }
    # no wording of one style is another's (the normal style's subjects are the plain ones)
    wordings = {
        style: {*words.subjects, *words.manners, *words.adverbs}
        for style, words in mocap_bench.STYLE_WORDS.items()
        if style != "normal"
    }
    for style, own in wordings.items():
        assert not any(own & other for s, other in wordings.items() if s != style), style
    # a walk to the left, mirrored, walks to the right, and its captions say so
    left = next(c for c in every if c.content == "walk-left")
    mirror = mocap_bench.mirrored(left)
    assert mirror.content == "walk-right" and mirror.name == "M" + left.name
    for caption in mocap_bench.clip_captions(left):
        assert "left" in caption and "right" in mirror_caption(caption)


def test_caption_words_are_known_to_the_word_vectors():
    from t2m.data.words import BUILTIN_GLOVE, load_vectorizer

    vectors = load_vectorizer(BUILTIN_GLOVE)
    unknown = [word for word in mocap_bench.caption_words() if word.lower() not in vectors.index]
    assert not unknown
    assert {"thug", "menacingly", "bows", "backward", "dashes"} <= mocap_bench.caption_words()


def test_split_is_by_take_with_every_content_and_style_in_test():
    every = captures()
    splits = mocap_bench.split_takes(every, seed=3)
    names = [name for split in splits.values() for name in split]
    assert sorted(names) == sorted(c.name for c in every)  # each take in exactly one split
    by_name = {c.name: c for c in every}
    test_groups = [(by_name[n].content, by_name[n].style) for n in splits["test"]]
    assert sorted(test_groups) == sorted({(c.content, c.style) for c in every})
    assert len(splits["val"]) == len(test_groups) // 2
    assert splits != mocap_bench.split_takes(every, seed=4)  # the seed draws the takes
    assert mocap_bench.split_takes(captures(takes=1))["test"] == []  # one take: training only
    mirror = mocap_bench.mirrored(by_name[splits["test"][0]])
    assert mirror.name == "M" + splits["test"][0]
    assert mocap_bench.mirrored(every[0]).content == mocap_bench.MIRRORED_CONTENT.get(
        every[0].content, every[0].content
    )
    assert mocap_bench.split_clips(every, seed=3) == splits  # Bandai-Namco-2 alone: by take


def test_split_holds_out_content_and_style_combinations_of_single_takes():
    bn2, bn1 = captures(), bn1_captures()
    splits = mocap_bench.split_clips(bn2 + bn1, seed=0)
    assert splits == mocap_bench.split_clips(list(reversed(bn1 + bn2)), seed=0)  # deterministic
    assert splits != mocap_bench.split_clips(bn2 + bn1, seed=1)  # the seed draws the styles
    names = [name for split in splits.values() for name in split]
    assert sorted(names) == sorted(c.name for c in bn2 + bn1)  # each clip in exactly one split
    where = {name: split for split, names in splits.items() for name in names}
    # Bandai-Namco-2 keeps its take split, whatever is read beside it
    alone = mocap_bench.split_takes(bn2, seed=0)
    assert all(where[name] == split for split, names in alone.items() for name in names)
    # several takes (walk: two of every style; call, punch, slash: two normal ones): by take,
    # every combination in test and in training
    for content in ("walk", "call", "punch", "slash"):
        clips = [c for c in bn1 if c.content == content]
        for style in {c.style for c in clips}:
            split_of = sorted(where[c.name] for c in clips if c.style == style)
            assert split_of == ["test", "train"], (content, style)
    # one take of every style: whole combinations held out, 3 test and 2 validation of 15
    for content in HELD_OUT:
        clips = [c for c in bn1 if c.content == content]
        counts = {s: sum(where[c.name] == s for c in clips) for s in ("train", "val", "test")}
        usable = sum(c.seconds >= mocap_bench.MIN_SECONDS for c in clips)
        assert counts["test"] == 3 and counts["val"] == round(0.1 * usable), (content, counts)
    assert where["dataset-1_dash_normal_001"] == "train"  # too short to use
    # every content with three clips or more has test clips; kick and dance-short (one clip)
    # train only
    for content in {c.content for c in bn1}:
        clips = [c for c in bn1 if c.content == content]
        if len(clips) >= 3:
            assert any(where[c.name] == "test" for c in clips), content
    assert where["dataset-1_kick_normal_001"] == where["dataset-1_dance-short_normal_001"]
    assert where["dataset-1_kick_normal_001"] == "train"
    # the held-out styles rotate from content to content: every style is held out somewhere
    held_out = {c.style for c in bn1 if c.content in HELD_OUT and where[c.name] == "test"}
    assert held_out == set(mocap_bench.STYLE_WORDS)
    # three single takes suffice to hold one out
    three = [c for c in bn1 if c.content == "bow"][:3]
    assert sum(n in {c.name for c in three} for n in mocap_bench.split_clips(three)["test"]) == 1


def test_style_classifier_learns_separable_styles_and_not_noise():
    rng = np.random.default_rng(0)
    centres = rng.normal(size=(3, 20)) * 2.0

    def draw(n: int, labels=None):
        labels = rng.integers(3, size=n) if labels is None else labels
        x = centres[labels] + rng.normal(size=(n, 20))
        return x, [f"style{k}" for k in labels]

    classifier, info = mocap_bench.StyleClassifier.fit(draw(150), draw(60))
    assert classifier.accuracy(*draw(200)) > 0.9 and info["val_accuracy"] > 0.9

    def noise(n: int):  # features that say nothing of the labels
        return rng.normal(size=(n, 20)), [f"style{k}" for k in rng.integers(3, size=n)]

    guess, _ = mocap_bench.StyleClassifier.fit(noise(150), noise(60))
    assert guess.accuracy(*noise(600)) < 0.45  # chance is 1/3


def test_bad_input_is_one_line(tmp_path, capsys):
    with pytest.raises(UsageError, match="no such folder"):
        mocap_bench.read_captures(tmp_path / "absent")
    (tmp_path / "data").mkdir()
    with pytest.raises(UsageError, match="not a Bandai-Namco folder"):
        mocap_bench.read_captures(tmp_path)
    (tmp_path / "cfg").mkdir()
    (tmp_path / "cfg" / "content_label.txt").write_text("dataset-2_walk\n")
    (tmp_path / "cfg" / "style_label.txt").write_text("dataset-2_normal\n")
    with pytest.raises(UsageError, match="no .bvh file"):
        mocap_bench.read_captures(tmp_path)
    (tmp_path / "data" / "a_001.bvh").write_text("HIERARCHY\n")
    (tmp_path / "data" / "a_001.json").write_text('{"content": 3, "style": 0}')
    with pytest.raises(UsageError, match="a_001.json does not name"):
        mocap_bench.read_captures(tmp_path)
    (tmp_path / "data" / "a_001.json").write_text('{"content": 0, "style": 0}')
    assert [c.content for c in mocap_bench.read_captures(tmp_path)] == ["walk"]
    assert mocap_bench.MocapBenchConfig().mocap == (mocap_bench.DEFAULT_MOCAP,)
    assert mocap_bench.MocapBenchConfig(mocap=tmp_path).mocap == (tmp_path,)
    (tmp_path / "cfg" / "content_label.txt").write_text("dataset-2_walk\ndataset-2_juggle\n")
    (tmp_path / "data" / "a_001.json").write_text('{"content": 1, "style": 0}')
    with pytest.raises(UsageError, match=r"contents \['juggle'\] have no caption words"):
        mocap_bench.read_captures(tmp_path)
    (tmp_path / "data" / "a_001.json").write_text('{"content": 0, "style": 0}')
    other = tmp_path / "other_dataset"  # built otherwise (no benchmark inputs beside it)
    other.mkdir()
    np.save(other / "Mean.npy", np.zeros(263, dtype=np.float32))
    config = mocap_bench.MocapBenchConfig(
        mocap=tmp_path, dataset=other, checkpoints=tmp_path / "run", out=tmp_path / "out"
    )
    with pytest.raises(UsageError, match="did not build"):
        mocap_bench.run_bench(config)
    status = mocap_bench.main(["--mocap", str(tmp_path / "absent"), "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err
    assert status == 2 and err.count("\n") == 1 and "no such folder" in err
    # a second folder that is missing, or the same folder twice: one line, before any work
    for second in (tmp_path / "absent", tmp_path / "data"):
        argv = ["--mocap", str(tmp_path), str(second), "--dataset", str(tmp_path / "d2")]
        status = mocap_bench.main([*argv, "--out", str(tmp_path / "o")])
        err = capsys.readouterr().err
        assert status == 2 and err.count("\n") == 1, err
        assert ("no such folder" if second.name == "absent" else "given twice") in err
        assert not (tmp_path / "d2").exists() and not (tmp_path / "d2_inputs").exists()


@pytest.mark.skipif(not MOCAP.is_dir(), reason="needs ../shared/mocap/bandai-namco-2")
def test_tiny_bench_end_to_end(tmp_path):
    data = tmp_path / "bn2" / "data"
    data.mkdir(parents=True)
    shutil.copytree(MOCAP / "cfg", tmp_path / "bn2" / "cfg")
    contents = ("walk", "run", "wave-left-hand", "raise-up-both-hands")
    for bvh in sorted((MOCAP / "data").glob("*.bvh")):
        _, content, style, take = bvh.stem.split("_")
        if content in contents and style in ("normal", "elderly") and take <= "003":
            for suffix in (".bvh", ".json"):
                shutil.copy(bvh.with_suffix(suffix), data / bvh.with_suffix(suffix).name)
    config = mocap_bench.MocapBenchConfig(
        mocap=tmp_path / "bn2",
        dataset=tmp_path / "dataset",
        checkpoints=tmp_path / "run",
        out=tmp_path / "out",
        preset="tiny",
        replications=2,
        mm_texts=2,
        mm_samples=2,
        pool_size=4,
        parallel=False,
        workers=1,
    )
    results = mocap_bench.run_bench(config)
    splits = {s: (tmp_path / "dataset" / f"{s}.txt").read_text().split() for s in ("train", "test")}
    assert len(splits["test"]) == 2 * 4 * 2  # one take of each content and style, and its mirror
    assert not {name.removeprefix("M") for name in splits["test"]} & set(splits["train"])
    texts = tmp_path / "dataset" / "texts" / f"M{splits['test'][0].removeprefix('M')}.txt"
    assert len(texts.read_text().splitlines()) == 3
    rows = results["protocol"]
    assert set(rows) >= {"Real motions", "Ours (ground-truth length)", "Ours (sampled length)"}
    real = rows["Real motions"]
    for key in ("r_precision_top3", "fid", "mm_dist", "diversity", "content_accuracy"):
        assert key in real
    assert "multimodality" in rows["Ours (ground-truth length)"]
    assert real["content_accuracy"]["mean"] >= 0.8  # the detectors know real clips
    assert real["style_accuracy"]["mean"] >= 0.8  # two styles: elderly and normal
    for content in contents:
        assert f"content_accuracy_{content}" in real and f"style_accuracy_in_{content}" in real
    assert {"style_accuracy_elderly", "content_accuracy_in_normal"} <= set(real)
    assert real["speed_mps_walk"]["mean"] > 0.7 > real["speed_mps_wave-left-hand"]["mean"]
    assert results["style_classifier"]["test_accuracy"] >= 0.8
    written = json.loads((tmp_path / "out" / "results.json").read_text())
    assert written["protocol"] == json.loads(json.dumps(results["protocol"]))
    table = (tmp_path / "out" / "results.md").read_text()
    assert "| *elderly* |" in table and "| wave-left-hand |" in table and "Bandai-Namco-1" in table
    assert (tmp_path / "out" / "protocol" / "results.md").is_file()
    # a second run reuses everything and gives the same results
    again = mocap_bench.run_bench(config)
    for entry in (again["timings"]["build"], again["timings"]["evaluation"]):
        assert entry["earlier_run"]  # reused: the seconds the first run measured
    assert again["timings"]["stages"]["generator"] == {
        **results["timings"]["stages"]["generator"],
        "earlier_run": True,
    }
    assert again["protocol"] == written["protocol"]


@pytest.mark.skipif(not MOCAP.is_dir(), reason="needs ../shared/mocap/bandai-namco-2")
def test_two_folders_build_with_mirrors_following_and_not_judged_contents_left_out(tmp_path):
    from dataset_tools.build import BuildConfig, build_dataset
    from dataset_tools.spec import spec_for_folder
    from t2m.data.dataset import load_split

    walks = [f"dataset-2_walk_normal_00{k}" for k in (1, 2, 3)]
    waves = [f"dataset-2_wave-left-hand_normal_00{k}" for k in (1, 2, 3)]
    bn2 = bn2_folder(tmp_path / "bn2", walks[:2])
    clips = {f"dataset-1_bye_{s}_001": w for s, w in zip(("normal", "old", "happy"), waves)}
    clips |= {f"dataset-1_walk-left_{s}_001": w for s, w in zip(("sad", "tired", "giant"), walks)}
    bn1 = bn1_folder(tmp_path / "bn1", clips)
    # reading: both folders, Bandai-Namco-1's styles under their shared labels, the .json
    # without its .bvh skipped
    every = mocap_bench.read_all([bn2, bn1])
    assert [c.name for c in every] == sorted([*walks[:2], *clips])
    assert {c.source for c in every} == {"dataset-1", "dataset-2"}
    by_name = {c.name: c for c in every}
    assert by_name["dataset-1_bye_old_001"].style == "elderly"
    assert by_name["dataset-1_walk-left_tired_001"].style == "exhausted"
    assert all(c.seconds and c.seconds > mocap_bench.MIN_SECONDS for c in every)
    with pytest.raises(UsageError, match="given twice"):
        mocap_bench.read_all([bn2, bn2 / "data"])
    shutil.copy(bn2 / "data" / f"{walks[0]}.bvh", bn1 / "data" / f"{walks[0]}.bvh")
    shutil.copy(bn2 / "data" / f"{walks[0]}.json", bn1 / "data" / f"{walks[0]}.json")
    with pytest.raises(UsageError, match=f"clip {walks[0]} is also in"):
        mocap_bench.read_all([bn2, bn1])
    for suffix in (".bvh", ".json"):
        (bn1 / "data" / f"{walks[0]}{suffix}").unlink()
    # the build reads both through one folder of links; every mirror is in its clip's split
    inputs = tmp_path / "dataset_inputs"
    texts, splits = mocap_bench.write_build_inputs(every, inputs, seed=0)
    folder = mocap_bench.build_input_folder(every, [bn2, bn1], inputs)
    assert sorted(p.stem for p in folder.glob("*.bvh")) == [c.name for c in every]
    build_dataset(
        BuildConfig("bvh", folder, tmp_path / "dataset", texts_dir=texts, splits_dir=splits,
                    workers=1)
    )  # fmt: skip
    wanted = mocap_bench.split_clips(every, seed=0)
    tested = {by_name[name].content for name in wanted["test"]}
    assert tested == {"walk", "bye", "walk-left"}  # three single takes: one held out
    for split, names in wanted.items():
        built = (tmp_path / "dataset" / f"{split}.txt").read_text().split()
        assert sorted(built) == sorted([*names, *(f"M{n}" for n in names)]), split
    left = "dataset-1_walk-left_sad_001"
    mirrored_texts = (tmp_path / "dataset" / "texts" / f"M{left}.txt").read_text()
    assert "right" in mirrored_texts and "left" not in mirrored_texts
    # scoring: bye is not judged (no accuracy, left out of the overall one), walks are
    spec = spec_for_folder(tmp_path / "dataset")
    loaded = {c.name: c for c in load_split(tmp_path / "dataset", "all", spec=spec)}
    labels = {c.name: c for capture in every for c in (capture, mocap_bench.mirrored(capture))}

    class Normal:  # a style classifier that always says normal
        def predict(self, features):
            return ["normal"] * len(features)

    scorer = mocap_bench.BenchScorer(labels, Normal(), spec.fps)
    names = [walks[0], walks[1], "dataset-1_bye_normal_001", "dataset-1_bye_old_001"]
    scores = scorer(names, [loaded[n].motion for n in names])
    assert scores["all"] == 1.0 and scores["action_walk"] == 1.0  # real walks, bye left out
    assert "action_bye" not in scores and scores["speed_bye"] < 0.3
    assert scores["style"] == 0.75 and scores["style_in_bye"] == 0.5
    assert "content_in_elderly" not in scores and scores["content_in_normal"] == 1.0
    assert scorer(names[2:], [loaded[n].motion for n in names[2:]]).keys() >= {"style"}
    assert "all" not in scorer(names[2:], [loaded[n].motion for n in names[2:]])


@pytest.mark.skipif(
    not BN1.is_dir(),
    reason="needs Bandai-Namco-1: BANDAI_NAMCO_1=<its folder> (not in ../shared, so not in CI)",
)
def test_bandai_namco_1_content_checks_know_its_real_clips(tmp_path):
    from dataset_tools.build import BuildConfig, build_dataset
    from dataset_tools.representation import recover_from_ric
    from dataset_tools.spec import spec_for_folder

    data = tmp_path / "bn1" / "data"
    data.mkdir(parents=True)
    shutil.copytree(BN1 / "cfg", tmp_path / "bn1" / "cfg")
    contents = ("walk-back", "walk-left", "walk-right", "dash", "bow")
    for content in contents:
        for suffix in (".bvh", ".json"):
            name = f"dataset-1_{content}_sad_001{suffix}"
            shutil.copy(BN1 / "data" / name, data / name)
    build_dataset(BuildConfig("bvh", data, tmp_path / "dataset", workers=1))
    spec = spec_for_folder(tmp_path / "dataset")
    swap = mocap_bench.MIRRORED_CONTENT
    for path in sorted((tmp_path / "dataset" / "new_joint_vecs").glob("*.npy")):
        content = path.stem.removeprefix("M").split("_")[1]
        content = swap.get(content, content) if path.stem.startswith("M") else content
        joints = recover_from_ric(np.load(path)[: spec.max_frames], spec.num_joints)
        facts = mocap.mocap_facts(joints, spec.fps)
        assert mocap.CONTENT_CHECKS[mocap.CONTENT_LABELS[content]](facts), path.stem
        others = [c for c in contents if c != content and c in mocap.CONTENT_LABELS]
        assert not any(mocap.CONTENT_CHECKS[mocap.CONTENT_LABELS[c]](facts) for c in others)
