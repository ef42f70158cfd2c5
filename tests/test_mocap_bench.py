"""The real-mocap benchmark (t2m.evaluate.mocap_bench): captions, split, classifier, bad input,
and a tiny end to end on a few Bandai-Namco-2 clips."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from dataset_tools.command import UsageError
from dataset_tools.mirror import mirror_caption
from t2m.evaluate import mocap, mocap_bench
from t2m.evaluate.mocap_bench import Capture

MOCAP = Path(__file__).resolve().parents[1].parent / "shared" / "mocap" / "bandai-namco-2"
STYLES = tuple(mocap_bench.STYLE_WORDS)


def captures(takes: int = 6) -> list[Capture]:
    """Every content and style of Bandai-Namco-2 with ``takes`` takes, no files."""
    return [
        Capture(f"dataset-2_{content}_{style}_{take:03d}", Path("x.bvh"), content, style, f"{take:03d}")
        for content in mocap.CONTENT_LABELS
        for style in STYLES
        for take in range(1, takes + 1)
    ]  # fmt: skip


def test_content_labels_name_the_checks_and_mirror_onto_each_other():
    assert set(mocap.CONTENT_LABELS.values()) == set(mocap.CONTENT_CHECKS)
    for content, caption in mocap.CONTENT_LABELS.items():
        other = mocap_bench.MIRRORED_CONTENT.get(content, content)
        assert mirror_caption(caption) == mocap.CONTENT_LABELS[other]
        assert set(mocap_bench.CONTENT_PHRASES) == set(mocap.CONTENT_LABELS)


def test_captions_name_content_and_style_in_varied_words():
    every = captures()
    texts = {capture.name: mocap_bench.clip_captions(capture) for capture in every}
    assert texts == {c.name: mocap_bench.clip_captions(c) for c in every}  # deterministic
    for capture in every:
        words = mocap_bench.STYLE_WORDS[capture.style]
        shapes = (words.subjects, words.manners, words.adverbs)
        for caption, options in zip(texts[capture.name], shapes, strict=True):
            assert any(phrase in caption for phrase in mocap_bench.CONTENT_PHRASES[capture.content])
            assert any(option in caption for option in options), (caption, capture.style)
        # the side of a one-handed content is named, and it is the content's own
        for caption in texts[capture.name]:
            sides = {side for side in ("left", "right") if side in caption}
            assert sides == {side for side in ("left", "right") if side in capture.content}
    distinct = {caption for captions in texts.values() for caption in captions}
    assert len(distinct) > 0.7 * 3 * len(every)  # varied: most captions are unique
    walks = {t for c in every if c.content == "walk" for t in texts[c.name]}
    assert {"walks forward", "walks straight ahead"} <= {
        phrase for phrase in mocap_bench.CONTENT_PHRASES["walk"] if any(phrase in t for t in walks)
    }


def test_caption_words_are_known_to_the_word_vectors():
    from t2m.data.words import BUILTIN_GLOVE, load_vectorizer

    vectors = load_vectorizer(BUILTIN_GLOVE)
    unknown = [word for word in mocap_bench.caption_words() if word.lower() not in vectors.index]
    assert not unknown


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
    status = mocap_bench.main(["--mocap", str(tmp_path / "absent"), "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err
    assert status == 2 and err.count("\n") == 1 and "no such folder" in err


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
    assert again["timings"]["build"] == "reused" and again["timings"]["evaluation"] == "reused"
    assert set(again["timings"]["stages"].values()) == {"reused"}
    assert again["protocol"] == written["protocol"]
