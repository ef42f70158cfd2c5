"""``python -m t2m.release.export``: a run is written in the original release's layout only when
the original code would run it as we do; every setting in the way is refused in one line that
names the override to retrain with (each refusal tested, and each named override tested to
remove it); a release-compatible run round-trips to identical outputs; the ``paper`` preset is
release-compatible and stops at once when its GloVe file is missing."""

from __future__ import annotations

import logging
import shutil
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import torch

from dataset_tools.command import UsageError
from dataset_tools.spec import HUMANML3D
from t2m.accel import accelerate
from t2m.config import apply_overrides
from t2m.data.words import WordVectors, load_vectorizer, vectorizer_from_info
from t2m.lexicon import MOTION_WORDS, RELEASE_MOTION_WORDS
from t2m.presets import PAPER_WORD_VECTORS, paper, preset
from t2m.release import is_release_folder, load_release, load_release_evaluator
from t2m.release.export import PAPER_WORDS, _check_exportable, release_incompatibilities
from t2m.release.layout import read_opt

REFERENCE = Path(__file__).resolve().parents[2] / "shared" / "reference" / "t2m-original"

RELEASE_COMPATIBLE = {
    "device": "cpu",
    "data.motion_words": "release",
    "generator.model.count_clock": "false",
    "generator.model.text.flip_backward_words": "true",
    "length.model.plan_inputs": "false",
    "length.model.text.hidden_size": "512",
    "length.model.mlp_sizes": "512,256,128",
    "evaluator.model.text.hidden_size": "512",
    "evaluator.model.motion_hidden_size": "1024",
    "evaluator.model.embedding_size": "512",
}
"""The ``tiny`` preset made release-compatible (with 300-d word vectors)."""


def _vectors(dim: int = 300, lists=RELEASE_MOTION_WORDS, trainable: bool = False) -> WordVectors:
    words = ["sos", "eos", "unk", "a", "person", "walks", "head"]
    if trainable:
        return WordVectors(words, None, "trainable", dim=dim)
    table = np.random.default_rng(0).normal(size=(len(words), dim)).astype(np.float32)
    return WordVectors(words, table, "glove.txt", motion_words=lists)


def _stages(config, vectors=None, names=("generator", "length", "evaluator")) -> dict:
    """Stand-ins for loaded stages: what the export's checks read (config, vocabulary, spec)."""
    vectors = vectors or _vectors()
    return {
        name: SimpleNamespace(config=config, vectorizer=vectors, spec=HUMANML3D) for name in names
    }


def _compatible_config():
    return apply_overrides(preset("tiny"), RELEASE_COMPATIBLE)


def test_a_release_compatible_config_has_nothing_in_the_way():
    assert release_incompatibilities(_stages(_compatible_config())) == []


@pytest.mark.parametrize(
    ("override", "fix"),
    [
        ({"generator.model.text.flip_backward_words": "false"}, "flip_backward_words=true"),
        ({"generator.model.count_clock": "true"}, "count_clock=false"),
        ({"generator.model.progress_frequencies": "2"}, "progress_frequencies=0"),
        ({"length.model.plan_inputs": "true"}, "plan_inputs=false"),
        ({"length.model.text.hidden_size": "64"}, "length.model.text.hidden_size=512"),
        ({"length.model.mlp_sizes": "128,64"}, "length.model.mlp_sizes=512,256,128"),
        ({"length.model.num_classes": "60"}, "length.model.num_classes=50"),
        ({"evaluator.model.text.hidden_size": "64"}, "evaluator.model.text.hidden_size=512"),
        ({"evaluator.model.motion_hidden_size": "128"}, "motion_hidden_size=1024"),
        ({"evaluator.model.embedding_size": "128"}, "evaluator.model.embedding_size=512"),
    ],
)
def test_each_setting_the_original_cannot_reproduce_is_named_with_its_override(override, fix):
    config = apply_overrides(_compatible_config(), override)
    found = release_incompatibilities(_stages(config))
    assert len(found) == 1 and found[0].fix.endswith(fix), found
    # the override it names is a real option, and retraining with it clears the refusal
    key, _, value = found[0].fix.removeprefix("--").partition("=")
    assert release_incompatibilities(_stages(apply_overrides(config, {key: value}))) == []


def test_a_setting_of_a_stage_the_run_lacks_is_not_in_the_way():
    config = apply_overrides(_compatible_config(), {"length.model.plan_inputs": "true"})
    assert release_incompatibilities(_stages(config, names=("generator", "evaluator"))) == []


@pytest.mark.parametrize(
    ("vectors", "fix"),
    [
        (_vectors(dim=50), PAPER_WORDS),
        (_vectors(dim=301), PAPER_WORDS),  # "+counts": one more column
        (_vectors(trainable=True), PAPER_WORDS),
        (_vectors(lists=MOTION_WORDS), "--data.motion_words=release"),
    ],
    ids=["50-d", "counts", "trainable", "our-motion-words"],
)
def test_word_vectors_the_original_cannot_read_as_we_do(vectors, fix):
    found = release_incompatibilities(_stages(_compatible_config(), vectors))
    assert [item.fix for item in found] == [fix]


def test_stages_on_different_vocabularies_are_refused():
    stages = _stages(_compatible_config())
    stages["evaluator"] = SimpleNamespace(**{**vars(stages["evaluator"])})
    stages["evaluator"].vectorizer = _vectors(lists=MOTION_WORDS)
    assert any("different word vectors" in item.what for item in release_incompatibilities(stages))


def test_the_demo_preset_is_refused_in_one_line_naming_every_override():
    with pytest.raises(UsageError) as error:
        _check_exportable(_stages(preset("demo"), _vectors(dim=50, lists=MOTION_WORDS)), None)
    message = str(error.value)
    assert "\n" not in message
    for fix in (
        PAPER_WORDS,
        "--data.motion_words=release",
        "--generator.model.text.flip_backward_words=true",
        "--generator.model.count_clock=false",
        "--length.model.plan_inputs=false",
        "--length.model.text.hidden_size=512",
        "--evaluator.model.motion_hidden_size=1024",
        "--preset paper",
    ):
        assert fix in message, fix


def test_the_paper_preset_is_release_compatible():
    config = paper()
    assert config.data.word_vectors == PAPER_WORD_VECTORS
    assert config.data.motion_words == "release"
    assert config.generator.model.text.flip_backward_words
    assert release_incompatibilities(_stages(config)) == []


def test_paper_training_without_its_glove_file_stops_at_once(
    tiny_dataset, tmp_path, monkeypatch, capsys
):
    from t2m.train.__main__ import main

    monkeypatch.chdir(tmp_path)  # no glove/ here
    run = tmp_path / "run"
    argv = ["generator", "--preset", "paper", "--dataset", str(tiny_dataset)]
    assert main([*argv, "--checkpoints", str(run)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1, err
    assert f"--data.word_vectors={PAPER_WORD_VECTORS}: no such file" in err
    assert "nlp.stanford.edu/projects/glove" in err
    assert not run.exists()  # refused before any work


def test_a_missing_glove_file_is_one_line_naming_the_download(tmp_path):
    with pytest.raises(UsageError, match="no such file.*nlp.stanford.edu") as error:
        load_vectorizer(str(tmp_path / "glove.6B.300d.txt"))
    assert "\n" not in str(error.value)


def test_the_release_motion_word_lists_on_a_glove_file(tmp_path, monkeypatch):
    from t2m.data import words as words_module

    monkeypatch.setenv(words_module.CACHE_ENV, str(tmp_path / "cache"))
    glove = tmp_path / "g.txt"
    glove.write_text(
        "".join(f"{w} {i}.0 1.0 2.0\n" for i, w in enumerate("sos eos unk a head".split()))
    )
    ours = load_vectorizer(str(glove))
    release = load_vectorizer(str(glove), motion_words="release")
    noun, body_part = 1, 10
    assert ours.encode_tokens(["head/NOUN"]).pos_onehot[1].argmax() == body_part
    assert release.encode_tokens(["head/NOUN"]).pos_onehot[1].argmax() == noun
    assert not ours.compatible(release)  # one encoding must not serve both
    for vocabulary in (release, release.subset(["head"], margin=0)):  # whole and as a table
        again = vectorizer_from_info(vocabulary.info())
        assert again.motion_words is RELEASE_MOTION_WORDS
        assert again.encode_tokens(["head/NOUN"]).pos_onehot[1].argmax() == noun
    with pytest.raises(UsageError, match="data.motion_words"):
        apply_overrides(preset("tiny"), {"data.motion_words": "theirs"})


# ---------------------------------------------------------------- a release-compatible tiny run


def _glove_300(dataset: Path, path: Path) -> Path:
    """A GloVe text file of random 300-d vectors for the dataset's words (and a few more)."""
    words = {"sos", "eos", "unk", "a", "person", "walk", "forward", "head"}
    for text in (dataset / "texts").glob("*.txt"):
        for line in text.read_text().splitlines():
            words.update(token.rpartition("/")[0] for token in line.split("#")[1].split())
    rng = np.random.default_rng(0)
    lines = [
        f"{word} " + " ".join(f"{x:.5f}" for x in rng.normal(0, 0.4, 300)) for word in sorted(words)
    ]
    path.write_text("\n".join(lines) + "\n")
    return path


@pytest.fixture(scope="module")
def release_run(tiny_run, tiny_dataset, tmp_path_factory):
    """``tiny_run``'s autoencoder with a generator, length model and evaluator trained
    release-compatibly: 300-d word vectors, the release's motion-word lists, the flip, and the
    original's length and evaluator sizes (a few steps: the weights only need to be distinct)."""
    from t2m.data import words as words_module
    from t2m.train import train_stage

    logging.getLogger("t2m").setLevel(logging.WARNING)
    folder = tmp_path_factory.mktemp("release_run")
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv(words_module.CACHE_ENV, str(folder / "cache"))
        glove = _glove_300(tiny_dataset, folder / "glove.300d.txt")
        config = apply_overrides(
            _compatible_config(),
            {
                "data.word_vectors": str(glove),
                "length.max_steps": "3",
                "evaluator.max_steps": "3",
            },
        )
        run = folder / "run"
        shutil.copytree(tiny_run / "autoencoder", run / "autoencoder")
        for stage in ("generator", "length", "evaluator"):
            train_stage(stage, config, tiny_dataset, run)
        yield run


@pytest.fixture(scope="module")
def exported(release_run, tmp_path_factory):
    from t2m.release.export import main

    out = tmp_path_factory.mktemp("exported")
    assert main(["--checkpoints", str(release_run), "--out", str(out)]) == 0
    return out


def test_export_refuses_the_tiny_run_in_one_line(tiny_run, tmp_path, capsys):
    from t2m.release.export import main

    assert main(["--checkpoints", str(tiny_run), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1, err
    assert "count clock" in err and "--length.model.plan_inputs=false" in err
    assert not (tmp_path / "out").exists()


def test_export_writes_the_release_layout(exported):
    dataset = exported / "checkpoints" / "t2m"
    generator = torch.load(
        dataset / "Comp_v6_KLD01" / "model" / "latest.tar", map_location="cpu", weights_only=True
    )
    assert generator["text_enc"]["pos_emb.weight"].shape == (300, 15)
    assert np.load(dataset / "Comp_v6_KLD01" / "meta" / "std.npy").shape == (263,)
    assert read_opt(dataset / "text_mot_match" / "opt.txt")["dataset_name"] == "t2m"
    assert read_opt(dataset / "Comp_v6_KLD01" / "opt.txt")["flip_backward_words"] == "True"
    assert is_release_folder(exported)


@pytest.mark.skipif(not REFERENCE.is_dir(), reason="reference release not present")
def test_export_has_the_release_keys_and_shapes_where_the_original_fixes_them(exported):
    dataset = exported / "checkpoints" / "t2m"
    for path in (
        "Comp_v6_KLD01/model/latest.tar",
        "length_est_bigru/model/latest.tar",
        "text_mot_match/model/finest.tar",
    ):
        mine = torch.load(dataset / path, map_location="cpu", weights_only=True)
        reference = torch.load(
            REFERENCE / "checkpoints" / "t2m" / path, map_location="cpu", weights_only=True
        )
        assert set(mine) == set(reference)
        for entry, state in reference.items():
            if isinstance(state, dict) and "param_groups" not in state:
                assert set(mine[entry]) == set(state), entry
    # the sizes the original's code fixes (its MotionLenEstimatorBiGRU(300, 15, 512, 50) and
    # evaluator wrapper), which the small reference files do not have
    length = torch.load(dataset / "length_est_bigru/model/latest.tar", weights_only=True)
    shapes = {key: tuple(value.shape) for key, value in length["estimator"].items()}
    assert shapes["input_emb.weight"] == (512, 300) and shapes["hidden"] == (2, 1, 512)
    assert [shapes[f"output.{i}.weight"] for i in (0, 3, 6, 9)] == [
        (512, 1024),
        (256, 512),
        (128, 256),
        (50, 128),
    ]
    evaluator = torch.load(dataset / "text_mot_match/model/finest.tar", weights_only=True)
    assert evaluator["text_encoder"]["hidden"].shape == (2, 1, 512)
    assert evaluator["motion_encoder"]["hidden"].shape == (2, 1, 1024)
    assert evaluator["text_encoder"]["output_net.3.weight"].shape == (512, 512)


def test_the_exported_vocabulary_encodes_captions_as_the_run(release_run, exported):
    from t2m.data.words import read_glove_folder
    from t2m.train.stages import load_stage

    ours = load_stage(release_run, "generator").vectorizer
    back = read_glove_folder(exported / "glove")
    tokens = "a/DET person/NOUN walk/VERB forward/ADV head/NOUN".split()
    mine, theirs = ours.encode_tokens(tokens), back.encode_tokens(tokens)
    np.testing.assert_array_equal(mine.words, theirs.words)
    np.testing.assert_array_equal(mine.pos_onehot, theirs.pos_onehot)


@torch.no_grad()
def test_export_round_trip_gives_identical_outputs(release_run, exported):
    from t2m.train.stages import load_stage

    run = release_run
    generator, length = load_stage(run, "generator"), load_stage(run, "length")
    evaluator = load_stage(run, "evaluator").models["evaluator"]
    back = load_release(exported)
    for name in ("vae", "encoder", "decoder", "length_model"):
        accelerate(getattr(back, name))
    back_evaluator = accelerate(load_release_evaluator(exported).evaluator)
    assert torch.equal(back.initial_code, generator.initial_code)
    np.testing.assert_array_equal(back.normalizer.std, generator.normalizer.std)
    assert back.vectorizer.words == generator.vectorizer.words
    assert back.vae.config.text.flip_backward_words
    encoded = generator.vectorizer.encode_tokens("a/DET person/NOUN walk/VERB forward/ADV".split())
    words = torch.from_numpy(np.stack([encoded.words] * 2))
    pos = torch.from_numpy(np.stack([encoded.pos_onehot] * 2))
    lengths = torch.tensor([encoded.length, encoded.length - 1])
    vae = generator.models["vae"]
    noise = torch.randn(2, 12, vae.config.latent_size, generator=torch.Generator().manual_seed(0))
    codes = []
    for model in (vae, back.vae):
        features, sentence, mask = model.encode_text(words, pos, lengths)
        steps = torch.tensor([12, 10])
        codes.append(
            model.generate(features, sentence, mask, steps, back.initial_code, noise=noise)
        )
    assert torch.equal(codes[0], codes[1])
    assert torch.equal(generator.models["decoder"](codes[0]), back.decoder(codes[1]))
    assert torch.equal(
        length.models["length"](words, pos, lengths), back.length_model(words, pos, lengths)
    )
    motion = torch.randn(2, 40, 263, generator=torch.Generator().manual_seed(1))
    frames = torch.tensor([40, 32])
    assert torch.equal(
        evaluator.embed_motion(motion, frames), back_evaluator.embed_motion(motion, frames)
    )
    assert torch.equal(
        evaluator.embed_text(words, pos, lengths), back_evaluator.embed_text(words, pos, lengths)
    )


def test_export_refuses_to_overwrite(release_run, exported):
    from t2m.release.export import main

    assert main(["--checkpoints", str(release_run), "--out", str(exported)]) == 2
