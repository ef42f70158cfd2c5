"""Checkpoints carry their own word table (the dataset's caption words plus a margin of frequent
words); they load without the vector file, encode as the whole vocabulary does, and checkpoints
that name the file (written before) still load."""

from __future__ import annotations

import numpy as np
import pytest
import torch

import t2m.data.words as words_module
from dataset_tools import humanml3d
from dataset_tools.command import UsageError
from t2m.data.words import (
    BUILTIN_GLOVE,
    load_vectorizer,
    split_token,
    vectorizer_from_info,
)
from t2m.pipeline import TextToMotion
from t2m.train.checkpoint import atomic_save, read_checkpoint
from t2m.train.stages import load_stage


def _glove_file(path, words, dim=6, seed=0):
    rng = np.random.default_rng(seed)
    lines = [f"{w} " + " ".join(f"{x:.5f}" for x in rng.normal(size=dim)) for w in words]
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


def test_a_subset_keeps_vectors_and_loads_without_the_file(tmp_path, monkeypatch):
    words = ["the", "a", "of", "sos", "eos", "unk", "walk", "jump", "zebra", "quark"]
    whole = load_vectorizer(str(_glove_file(tmp_path / "g.txt", words)))
    table = whole.subset(["jump", "absent"], margin=2)
    assert table.words == ["the", "a", "sos", "eos", "unk", "jump"]
    assert table.is_subset and not whole.is_subset and table.compatible(whole)
    assert table.fingerprint() != whole.fingerprint() and table.origin == whole.fingerprint()
    tokens = ["the/DET", "jump/VERB", "zebra/NOUN"]
    a, b = table.encode_tokens(tokens), whole.encode_tokens(tokens)
    np.testing.assert_array_equal(a.words[:3], b.words[:3])  # sos, the, jump
    np.testing.assert_array_equal(a.words[3], whole.vectors[whole.index["unk"]])  # zebra: unk
    assert whole.subset([], margin=len(words)) is whole and whole.subset([], margin=-1) is whole

    info = table.info()
    assert info["fingerprint"] == whole.fingerprint() and info["vectors"].shape == (6, 6)
    monkeypatch.setattr(words_module, "load_vectorizer", lambda *a: pytest.fail("file read"))
    again = vectorizer_from_info(info)
    assert again.words == table.words and again.fingerprint() == table.fingerprint()
    np.testing.assert_array_equal(again.vectors, table.vectors)
    tampered = {**info, "vectors": info["vectors"].clone()}
    tampered["vectors"][5, 0] += 1.0
    with pytest.raises(ValueError, match="does not match its fingerprint"):
        vectorizer_from_info(tampered)
    with pytest.raises(ValueError, match=r"not \(6, 6\) float32"):
        vectorizer_from_info({**info, "vectors": info["vectors"].double()})
    with pytest.raises(ValueError, match="not distinct"):
        vectorizer_from_info({**info, "words": "\n".join(["the"] * 6)})
    with pytest.raises(ValueError, match="'words' is missing or not a str"):
        vectorizer_from_info({**info, "words": table.words})


def test_checkpoints_store_the_dataset_words_and_the_margin(tiny_run, tiny_dataset):
    whole = load_vectorizer(BUILTIN_GLOVE)
    generator = load_stage(tiny_run, "generator")
    table = generator.vectorizer
    dataset_words = {
        split_token(token)[0]
        for path in (tiny_dataset / humanml3d.TEXTS_DIR).glob("*.txt")
        for caption in humanml3d.read_texts(tiny_dataset, path.stem)
        for token in caption.tokens
    }
    margin = generator.config.data.vocabulary_margin
    expected = (dataset_words & set(whole.index)) | set(whole.words[:margin])
    assert set(table.words) == expected | {"sos", "eos", "unk"}
    assert table.compatible(whole) and table.size < whole.size
    # every caption of the dataset (the evaluation's test split too) encodes as before
    for path in sorted((tiny_dataset / humanml3d.TEXTS_DIR).glob("*.txt"))[:20]:
        for caption in humanml3d.read_texts(tiny_dataset, path.stem):
            np.testing.assert_array_equal(
                table.encode_tokens(caption.tokens).words,
                whole.encode_tokens(caption.tokens).words,
            )


def test_older_checkpoints_naming_the_file_still_load(tiny_run, tmp_path):
    """A run whose checkpoints hold the vocabulary as earlier versions wrote it (the file's name
    and fingerprint, no table) loads, is compatible with one that has a table, and generates
    exactly what the table gives for prompts of trained words."""
    whole = load_vectorizer(BUILTIN_GLOVE)
    old_run = tmp_path / "old"
    for stage in ("length", "generator"):
        checkpoint = read_checkpoint(tiny_run / stage / "best.pt")
        assert "vectors" in checkpoint["vocabulary"]
        checkpoint["vocabulary"] = {
            key: checkpoint["vocabulary"][key]
            for key in ("source", "dim", "size", "max_tokens", "fingerprint")
        }
        checkpoint["vocabulary"]["size"] = whole.size
        (old_run / stage).mkdir(parents=True)
        atomic_save(checkpoint, old_run / stage / "best.pt")
    old = TextToMotion.from_checkpoints(old_run)
    new = TextToMotion.from_checkpoints(tiny_run)
    assert old.vectorizer.size == whole.size and new.vectorizer.size < whole.size
    prompt = ["a person walks forward"]
    motions = [
        pipe.generate_features(
            [p.encoded for p in pipe.prepare(prompt)], [40], torch.Generator().manual_seed(3)
        )[0]
        for pipe in (old, new)
    ]
    np.testing.assert_array_equal(motions[0], motions[1])
    # a new length stage beside an old generator: one origin, accepted
    TextToMotion(
        old.vae, old.decoder, old.normalizer, old.vectorizer, old.initial_code,
        length_model=new.length_model, length_vectorizer=new.vectorizer,
    )  # fmt: skip
    for pipe in (old, new):
        with pytest.raises(UsageError, match="no known word in prompt 'qwxzv plughzz'"):
            pipe.prepare(["qwxzv plughzz"])


def test_a_table_keeps_the_release_motion_word_lists():
    from t2m.data.words import WordVectors
    from t2m.lexicon import RELEASE_MOTION_WORDS

    words = ["sos", "eos", "unk", "head", "walk", "quark"]
    vectors = np.arange(len(words) * 4, dtype=np.float32).reshape(-1, 4)
    release = WordVectors(words, vectors, "/release/glove", motion_words=RELEASE_MOTION_WORDS)
    again = vectorizer_from_info(release.subset(["head"], margin=3).info())
    assert again.motion_words is RELEASE_MOTION_WORDS and again.words == words[:4]
    # "head" is no body part in the release's lists: spaCy's tag stays
    np.testing.assert_array_equal(
        again.encode_tokens(["head/NOUN"]).pos_onehot,
        release.encode_tokens(["head/NOUN"]).pos_onehot,
    )


def test_counts_column_names_the_number_a_word_names(tmp_path):
    words = ["sos", "eos", "unk", "walk", "twice", "five", "seven", "clap"]
    path = _glove_file(tmp_path / "glove.6d.txt", words)
    plain = load_vectorizer(str(path))
    counted = load_vectorizer(str(path) + words_module.COUNTS_SUFFIX)
    assert counted.dim == plain.dim + 1 and counted.words == plain.words
    np.testing.assert_array_equal(counted.vectors[:, :-1], plain.vectors)
    column = dict(zip(counted.words, counted.vectors[:, -1]))
    scale = words_module.COUNT_SCALE
    assert column["twice"] == 2 / scale and column["five"] == 5 / scale
    assert column["seven"] == 7 / scale and column["walk"] == column["clap"] == 0
    encoded = counted.encode_tokens("a/DET person/NOUN clap/VERB five/NUM time/NOUN".split())
    assert encoded.words.shape == (22, 7) and encoded.words[4, -1] == 5 / scale
    # a checkpoint's table keeps the column, and a table naming the source rebuilds it
    table = counted.subset(["clap", "five"], margin=0)
    assert vectorizer_from_info(table.info()).vectors[:, -1].tolist() == [
        column[w] for w in table.words
    ]
    whole = vectorizer_from_info(counted.info())
    assert whole.fingerprint() == counted.fingerprint() != plain.fingerprint()
    with pytest.raises(ValueError, match="trainable"):  # built from captions, not loaded
        load_vectorizer("trainable" + words_module.COUNTS_SUFFIX)
