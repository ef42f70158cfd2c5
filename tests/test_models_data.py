"""Model inputs: config overrides, word vectors + POS one-hots, normalisation, dataset reading."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
import torch

from dataset_tools.humanml3d import Caption
from dataset_tools.spec import HUMANML3D, KIT_ML
from t2m.config import apply_overrides, from_dict, validate_for_spec
from t2m.data.dataset import MotionTextData, epoch_batches, load_split
from t2m.data.normalization import Normalizer
from t2m.data.words import (
    BUILTIN_GLOVE,
    NUM_POS,
    POS_INDEX,
    WordVectors,
    build_trainable_vocabulary,
    load_vectorizer,
    vectorizer_from_info,
)
from t2m.presets import demo, paper, preset, tiny
from tests.tolerances import gamma

SHARED = Path(__file__).resolve().parents[1].parent / "shared"


def test_presets_round_trip_and_paper_sizes():
    for name in ("paper", "demo", "tiny"):
        config = preset(name)
        assert from_dict(config.to_dict()) == config
    config = paper()
    assert (
        config.autoencoder.model.hidden_size,
        config.autoencoder.model.code_size,
        config.autoencoder.batch_size,
        config.autoencoder.window_frames,
    ) == (512, 512, 128, 24)
    assert (
        config.generator.model.hidden_size,
        config.generator.model.latent_size,
        config.generator.model.attention_size,
    ) == (1024, 128, 512)
    assert (
        config.generator.batch_size,
        config.generator.lr,
        config.generator.decoder_lr,
        config.generator.grad_clip,
    ) == (
        32,
        2e-4,
        2e-5,
        0.5,
    )
    assert (
        config.generator.start_snippets,
        config.generator.end_snippets,
        config.generator.teacher_forcing,
    ) == (
        10,
        49,
        0.4,
    )
    assert config.length.model.num_classes == 50 and config.length.model.mlp_sizes == (
        512,
        256,
        128,
    )
    assert config.evaluator.margin == 10.0 and config.generator.kl_weight == 0.01
    # the original's L1 autoencoder loss at the paper preset, smooth L1 for the small demo models
    assert (
        config.autoencoder.reconstruction_loss == "l1"
        and demo().autoencoder.reconstruction_loss == "smooth_l1"
    )
    assert (
        demo().generator.model.hidden_size < 1024
        and tiny().generator.model.hidden_size < demo().generator.model.hidden_size
    )


def test_overrides_are_validated():
    config = apply_overrides(
        tiny(),
        {
            "t2m.model.hidden_size": "64",
            "bf16": "true",
            "length.model.mlp_sizes": "8,4",
            "t2m.lr": "3e-4",
        },
    )
    assert config.generator.model.hidden_size == 64 and config.bf16 is True
    assert config.length.model.mlp_sizes == (8, 4) and config.generator.lr == 3e-4
    assert tiny().generator.model.hidden_size != 64  # presets are not mutated
    for key, value, message in [
        ("t2m.model.hiden_size", "3", "unknown config key"),
        ("nothing", "1", "unknown config key"),
        ("t2m.batch_size", "3.5", "expected an integer"),
        ("bf16", "maybe", "true/false"),
        ("t2m.model", "1", "is a section"),
        ("t2m.start_snippets", "60", "start_snippets <= generator.end_snippets"),
        ("ae.reconstruction_loss", "l2", "reconstruction_loss must be one of l1, smooth_l1"),
        ("t2m.model.progress_frequencies", "-1", "progress_frequencies must be at least 0"),
        ("t2m.model.progress_frequencies", "100", "less than half of generator.model.hidden"),
        ("data.max_frames", "100", "unknown config key"),  # the dataset's spec decides
    ]:
        with pytest.raises(ValueError, match=message):
            apply_overrides(tiny(), {key: value})
    # Settings that depend on the dataset are checked against its spec when a stage starts.
    validate_for_spec(tiny(), HUMANML3D)
    validate_for_spec(tiny(), KIT_ML)
    for key, value, message in [
        ("t2m.end_snippets", "60", "end_snippets must not exceed 49"),
        ("t2m.start_snippets", "9", "start_snippets must be at least 10"),
        ("ae.window_frames", "44", "window_frames must be a multiple of 4 frames .* to 40"),
        ("length.model.num_classes", "49", "num_classes must be at least 50"),
        ("t2m.model.max_snippets", "49", "max_snippets must exceed 49"),
    ]:
        with pytest.raises(ValueError, match=message):
            validate_for_spec(apply_overrides(tiny(), {key: value}), HUMANML3D)
    with pytest.raises(ValueError, match="window_frames .* to 24 .*KIT-ML"):
        validate_for_spec(apply_overrides(tiny(), {"ae.window_frames": "28"}), KIT_ML)
    with pytest.raises(ValueError, match="unknown preset"):
        preset("huge")


def test_builtin_glove_pos_overrides_and_padding():
    vectors = load_vectorizer(BUILTIN_GLOVE)
    assert vectors.dim == 50 and vectors.size == 400000
    encoded = vectors.encode_tokens(
        "a/DET person/NOUN walk/VERB left/VERB slowly/ADV qwzxv/NOUN".split()
    )
    assert encoded.words.shape == (22, 50) and encoded.pos_onehot.shape == (22, NUM_POS)
    assert encoded.length == 8  # sos + 6 words + eos
    categories = encoded.pos_onehot.argmax(-1)
    assert categories[1] == POS_INDEX["DET"] and categories[2] == POS_INDEX["NOUN"]
    assert categories[3] == POS_INDEX["ACTION"]  # walk: a motion word overrides VERB
    assert categories[4] == POS_INDEX["LOCATION"]  # left, whatever the tagger said
    assert categories[5] == POS_INDEX["DESCRIPTOR"]
    assert categories[6] == POS_INDEX["OTHER"]  # unknown word -> unk with OTHER
    unk = vectors.vectors[vectors.index["unk"]]
    np.testing.assert_array_equal(encoded.words[6], unk)
    np.testing.assert_array_equal(encoded.words[8:], np.broadcast_to(unk, (14, 50)))  # padding
    np.testing.assert_array_equal(encoded.words[0], vectors.vectors[vectors.index["sos"]])
    assert (encoded.pos_onehot.sum(-1) == 1).all()
    long = vectors.encode_tokens(["walk/VERB"] * 30)
    assert long.length == 22 and long.words.shape == (22, 50)


def test_glove_text_file_of_any_dimension_and_fingerprint(tmp_path):
    rows = {"sos": [1, 0, 0], "eos": [0, 1, 0], "unk": [0, 0, 1], "walk": [0.5, 0.5, 0.5]}
    path = tmp_path / "glove.3d.txt"
    path.write_text("".join(f"{w} {' '.join(map(str, v))}\n" for w, v in rows.items()))
    vectors = load_vectorizer(str(path))
    assert vectors.dim == 3
    # copied from the file: 0.5 is exact in float32
    np.testing.assert_array_equal(vectors.encode_tokens(["walk/VERB"]).words[1], [0.5, 0.5, 0.5])
    info = vectors.info()
    assert vectorizer_from_info(info).fingerprint() == info["fingerprint"]
    with pytest.raises(ValueError, match="differ"):
        vectorizer_from_info({**info, "fingerprint": "0" * 16})
    bad = tmp_path / "bad.txt"
    bad.write_text("sos 1 2\nwalk 1 2 3\n")
    with pytest.raises(ValueError, match="expected 2"):
        load_vectorizer(str(bad))
    with pytest.raises(ValueError, match=r"missing\.txt: no such file; give a GloVe text file"):
        load_vectorizer(str(tmp_path / "missing.txt"))
    with pytest.raises(ValueError, match="no 'unk'"):
        WordVectors(["sos", "eos"], np.zeros((2, 3), np.float32), "x")


def test_trainable_vocabulary_round_trip():
    vocab = build_trainable_vocabulary(
        [["walk/VERB", "left/ADV"], ["run/VERB", "walk/VERB"]], dim=8
    )
    assert vocab.words[:3] == ["sos", "eos", "unk"] and vocab.trainable
    encoded = vocab.encode_tokens(["walk/VERB", "fly/VERB"])
    assert encoded.words.tolist()[:4] == [
        vocab.index["sos"],
        vocab.index["walk"],
        vocab.index["unk"],
        vocab.index["eos"],
    ]
    again = vectorizer_from_info(vocab.info())
    assert again.words == vocab.words and again.dim == 8


def test_normalizer_weights_root_and_contacts():
    mean = np.linspace(-1, 1, 263).astype(np.float32)
    std = np.full(263, 2.0, np.float32)
    normalizer = Normalizer.weighted(mean, std, 5.0)
    # 2 / 5 is one float32 rounding (relative 2^-24); the other entries are copied exactly
    weighted = np.r_[normalizer.std[:4], normalizer.std[-4:]]
    np.testing.assert_allclose(weighted, 0.4, rtol=2.0**-23, atol=0)
    np.testing.assert_array_equal(normalizer.std[4:-4], 2.0)
    features = np.random.default_rng(0).normal(size=(5, 263)).astype(np.float32)
    # float32 round trip (x - m) / s * s + m: 4 roundings, within gamma_4 (|x - m| + |x|) of x
    # elementwise (about 2e-6 at |x| = 4; observed 2.4e-7); a wrong std slice or weight on
    # one side moves a feature by 0.6 |x - m| or more
    round_trip = normalizer.denormalize(normalizer.normalize(features)).astype(np.float64)
    x, m = features.astype(np.float64), mean.astype(np.float64)
    assert (np.abs(round_trip - x) <= gamma(4) * (np.abs(x - m) + np.abs(x))).all()
    with pytest.raises(ValueError, match="std is zero"):
        Normalizer(mean, np.zeros(263))
    with pytest.raises(ValueError, match="no feature layout"):
        Normalizer.weighted(mean[:100], std[:100], 5.0)


def test_real_humanml3d_statistics_load():
    reference = SHARED / "reference" / "humanml3d"
    if not reference.is_dir():
        pytest.skip(f"{reference} not available")
    normalizer = Normalizer.from_dataset(reference)
    raw_std = np.load(reference / "Std.npy")
    np.testing.assert_array_equal(normalizer.std[4:259], raw_std[4:259])  # copied
    # std / 5 and then x 5: two float32 roundings, relative 2 x 2^-24 = 1.2e-7; 1e-6 leaves 8x
    # (a feature_bias of 4 or 6 would be off by 20%)
    np.testing.assert_allclose(normalizer.std[:4] * 5, raw_std[:4], rtol=1e-6)
    clip = np.load(reference / "new_joint_vecs" / "012314.npy")
    normalised = normalizer.normalize(clip)
    assert np.isfinite(normalised).all() and abs(float(normalised[:, 4:259].mean())) < 1.0


def test_text_lines_and_subclips(tiny_dataset, tmp_path):
    broken = shutil.copytree(tiny_dataset, tmp_path / "broken")
    with open(broken / "texts" / "000003.txt", "a", encoding="utf-8") as file:
        file.write("just a caption\n")  # no tokens, no times: not a texts/ line
    with pytest.raises(ValueError, match="000003.txt:.*caption#tokens#from#to"):
        load_split(broken, "train")
    clips = load_split(tiny_dataset, "train")
    names = [clip.name for clip in clips]
    assert "000003#0.0#2.2" in names and "000003" in names  # a timed caption makes a sub-clip
    sub = next(clip for clip in clips if clip.name == "000003#0.0#2.2")
    assert len(sub.motion) == 44 and len(sub.captions) == 1
    assert all(40 <= len(clip.motion) < 200 for clip in clips)
    with pytest.raises(ValueError, match="no split file"):
        load_split(tiny_dataset, "nosuch")


def test_batches_are_deterministic_and_disjoint_across_processes(tiny_dataset):
    clips = load_split(tiny_dataset, "train")
    vectors = load_vectorizer(BUILTIN_GLOVE)
    data = MotionTextData(clips, Normalizer.from_dataset(tiny_dataset), vectors)
    first = epoch_batches(len(data), 4, seed=0, epoch=0, rank=0, world_size=2)
    second = epoch_batches(len(data), 4, seed=0, epoch=0, rank=1, world_size=2)
    assert not set(np.concatenate(first)) & set(np.concatenate(second))
    assert [b.tolist() for b in first] == [
        b.tolist() for b in epoch_batches(len(data), 4, 0, 0, 0, 2)
    ]
    rng = lambda: np.random.default_rng(3)  # noqa: E731
    batch = data.unit_crop_batch(first[0], rng())
    assert batch["motion"].shape == (4, 196, 263) and batch["words"].shape == (4, 22, 50)
    assert (batch["motion_lengths"] % 4 == 0).all() and (batch["motion_lengths"] >= 36).all()
    for row, length in enumerate(batch["motion_lengths"].tolist()):
        assert (batch["motion"][row, length:] == 0).all()
    again = data.unit_crop_batch(first[0], rng())
    assert all((batch[k] == again[k]).all() for k in batch)
    lengths = data.length_batch(first[0], rng())["length_class"]
    assert lengths.tolist() == (np.minimum(data.lengths[first[0]], 196) // 4).tolist()
    items = data.indices_at_least(48)[:3]
    crop = data.fixed_crop_batch(items, rng(), 48)
    assert crop["motion"].shape == (3, 48, 263)
    # a window: where each of its snippets starts, as a share of its clip
    window = data.window_batch(items, rng(), 48)
    assert window["done"].shape == (3, 12) and crop["counts"].shape == crop["done"].shape
    for row, index in enumerate(items):
        start = round(float(window["done"][row, 0]) * data.lengths[index])
        motion = window["motion"][row].numpy()
        np.testing.assert_array_equal(motion, data.motions[index][start : start + 48])
        expected = (start + 4 * np.arange(12)) / data.lengths[index]
        # a quotient rounded to float32 (relative 2^-24 = 6e-8; 1e-6 leaves 16x): a window off
        # by one frame moves it by 1 / length >= 0.5%
        np.testing.assert_allclose(window["done"][row].numpy(), expected, rtol=1e-6)


def test_free_text_is_tagged_like_the_dataset():
    pytest.importorskip("spacy")
    vectors = load_vectorizer(BUILTIN_GLOVE)
    (encoded,) = vectors.encode_text("A person walks forward and waves the left hand.")
    categories = encoded.pos_onehot.argmax(-1)
    hand = vectors.index["hand"]
    direct = vectors.encode_tokens("a/DET person/NOUN walk/VERB forward/ADV".split())
    np.testing.assert_array_equal(encoded.words[:5], direct.words[:5])  # "walks" -> lemma "walk"
    assert categories[3] == POS_INDEX["ACTION"] and categories[4] == POS_INDEX["LOCATION"]
    assert any((row == vectors.vectors[hand]).all() for row in encoded.words)
    with pytest.raises(ValueError, match="empty"):
        vectors.encode_text("   ")


def test_count_clocks_follow_the_clauses_and_the_labelled_segments():
    from t2m.data.dataset import count_clocks

    one = "a/DET person/NOUN clap/VERB five/NUM time/NOUN".split()
    starts, ends, counts = count_clocks(one, [(0.0, 0.4), (0.4, 1.0)])
    assert starts.tolist() == [0.0] and ends.tolist() == [1.0] and counts.tolist() == [5]
    two = "someone/PRON hop/VERB twice/ADV then/ADV wave/VERB".split()
    starts, ends, counts = count_clocks(two, [(0.02, 0.4), (0.4, 0.97)])
    assert starts.tolist() == [0.0, 0.4] and ends.tolist() == [0.4, 1.0]
    assert counts.tolist() == [2, 0]
    # clauses and segments that do not pair up, or no labels: no clock
    for segments in (None, [(0.0, 1.0)], [(0.0, 0.3), (0.3, 0.6), (0.6, 1.0)]):
        assert count_clocks(two, segments)[2].tolist() == [0]


def test_crops_read_their_clause_clock(tmp_path):
    from t2m.data.dataset import Clip

    vectors = load_vectorizer(BUILTIN_GLOVE)
    tokens = "someone/PRON hop/VERB twice/ADV then/ADV clap/VERB four/NUM time/NOUN".split()
    caption = Caption("someone hops twice, then claps four times.", tokens)
    motion = np.random.default_rng(0).standard_normal((100, 263)).astype(np.float32)
    clip = Clip("synth_000001", motion, [caption], [(0.0, 0.4), (0.4, 1.0)])
    normalizer = Normalizer(np.zeros(263, np.float32), np.ones(263, np.float32))
    data = MotionTextData([clip], normalizer, vectors)
    crop = data.fixed_crop_batch(np.array([0]), np.random.default_rng(1), 100)
    # snippets 0-9 are the hops' (40 of 100 frames), 10-24 the claps'
    assert crop["counts"][0].tolist() == [2] * 10 + [4] * 15
    # shares below 1 rounded to float32 (at most 6e-8; 1e-6 leaves 16x); a wrong clause
    # boundary moves them by 1 / 15 or more
    np.testing.assert_allclose(crop["done"][0, :10].numpy(), np.arange(10) / 10, atol=1e-6)
    np.testing.assert_allclose(crop["done"][0, 10:].numpy(), np.arange(15) / 15, atol=1e-6)
    np.testing.assert_array_equal(crop["clause_snippets"][0].numpy(), [10] * 10 + [15] * 15)


def test_length_examples_read_counts_and_labelled_clauses():
    """The length stage's batches carry each caption's count, and with ``clause_examples`` a
    caption whose clauses pair with labelled segments is replaced by one of its clauses as a
    caption of its own, with its segment's length; at 0 the batches draw what they drew before."""
    from t2m.clauses import clause_captions
    from t2m.data.dataset import Clip

    vectors = load_vectorizer(BUILTIN_GLOVE)
    two = "someone/PRON hop/VERB twice/ADV then/ADV clap/VERB four/NUM time/NOUN".split()
    one = "a/DET person/NOUN clap/VERB five/NUM time/NOUN".split()
    motion = np.zeros((100, 263), np.float32)
    clips = [
        Clip("synth_000001", motion, [Caption("two", two)], [(0.0, 0.4), (0.4, 1.0)]),
        Clip("synth_000002", motion[:60], [Caption("one", one)], [(0.0, 1.0)]),
    ]
    normalizer = Normalizer(np.zeros(263, np.float32), np.ones(263, np.float32))
    data = MotionTextData(clips, normalizer, vectors)
    items = np.array([0, 1])
    whole = data.length_batch(items, np.random.default_rng(3))
    assert whole["counts"].tolist() == [0, 5]  # several clauses: their counts are the clauses'
    assert whole["length_class"].tolist() == [25, 15]
    assert whole["clause"].tolist() == [False, False]
    # at 0 no extra draws: the same batch as the plain call, from the same generator state
    again = data.length_batch(items, np.random.default_rng(3), 0.0)
    assert all(torch.equal(whole[k], again[k]) for k in whole)
    # always replaced: the first clip reads one of its clauses, the second stays whole
    hops, claps = (vectors.encode_tokens(c) for c in clause_captions(two))
    seen = set()
    for seed in range(8):
        batch = data.length_batch(items, np.random.default_rng(seed), 1.0)
        length = int(batch["text_lengths"][0])
        clause, count, snippets = (
            (hops, 2, 10) if length == hops.length and batch["counts"][0] == 2 else (claps, 4, 15)
        )
        assert (int(batch["counts"][0]), int(batch["length_class"][0])) == (count, snippets)
        np.testing.assert_array_equal(batch["words"][0].numpy(), clause.words)
        assert length == clause.length
        assert (int(batch["counts"][1]), int(batch["length_class"][1])) == (5, 15)
        assert batch["clause"].tolist() == [True, False]
        seen.add(count)
    assert seen == {2, 4}
