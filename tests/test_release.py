"""The original T2M release as input: every array the original code computed on the reference
release (``../shared/reference/t2m-original``: random weights at small sizes, written by the
original implementation) is reproduced by our models loaded through :mod:`t2m.release` up to float32 rounding: each side's
distance to the float64 evaluation of the same weights within 16x the other's
(:func:`tests.tolerances.assert_same_rounding`); sampling runs from the command line (export:
``tests/test_release_export.py``)."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
import torch

from t2m.accel import accelerate
from t2m.accel.recurrence import fast_forward
from t2m.release import find_release, is_release_folder, load_release, load_release_evaluator
from t2m.release.layout import read_opt
from tests.tolerances import as_float64, assert_same_rounding, propagated_bound

REFERENCE = Path(__file__).resolve().parents[2] / "shared" / "reference" / "t2m-original"

pytestmark = pytest.mark.skipif(not REFERENCE.is_dir(), reason="reference release not present")


@pytest.fixture(scope="module")
def expected():
    return dict(np.load(REFERENCE / "expected.npz"))


def accelerated(release):
    """The release's models accelerated (:func:`t2m.accel.accelerate`), as the pipeline runs
    them and as ``load_stage`` gives a run's."""
    for name in ("vae", "encoder", "decoder", "length_model"):
        accelerate(getattr(release, name))
    return release


@pytest.fixture(scope="module")
def release():
    return accelerated(load_release(REFERENCE))


@pytest.fixture(scope="module")
def release64(release):
    """The release's models in float64: the exact values both float32 evaluations round."""
    return {
        name: as_float64(getattr(release, name))
        for name in ("vae", "encoder", "decoder", "length_model")
    }


@pytest.fixture(scope="module")
def text_inputs(expected):
    return (
        torch.from_numpy(expected["word_emb"]),
        torch.from_numpy(expected["pos_ohot"]),
        torch.from_numpy(expected["cap_lens"]),
    )


def as64(inputs: tuple[torch.Tensor, ...]) -> tuple[torch.Tensor, ...]:
    return tuple(x.double() if x.is_floating_point() else x for x in inputs)


def close(ours: torch.Tensor, ours64: torch.Tensor, recorded: np.ndarray, msg: str = "") -> None:
    """Ours and the release's recorded array are float32 roundings of the same values: each
    one's distance to our float64 evaluation (the same weights, the same inputs) within 16x the
    other's (``tests/tolerances.py``, ``ORDER_FACTOR``: observed at most 3.9 here, under 2.9 but
    for the movement encoder). The recorded side is what checks our model: a wrong weight, gate
    or option moves it 1e-3 or more from ours in float64, against rounding of 1e-7 to 1e-5."""
    assert ours.shape == recorded.shape, msg
    assert_same_rounding(ours, torch.from_numpy(recorded), ours64, msg=msg)


def test_every_folder_of_the_release_names_it():
    dataset = REFERENCE / "checkpoints" / "t2m"
    for path in (REFERENCE, REFERENCE / "checkpoints", dataset, dataset / "Comp_v6_KLD01"):
        assert is_release_folder(path)
        layout = find_release(path)
        assert layout.generator_dir == dataset / "Comp_v6_KLD01"
        assert layout.default_glove_dir == REFERENCE / "glove"
    assert find_release(dataset / "text_mot_match").generator_dir == dataset / "Comp_v6_KLD01"
    assert not is_release_folder(REFERENCE / "glove")
    assert read_opt(dataset / "Comp_v6_KLD01" / "opt.txt")["dim_movement_latent"] == "40"


def test_sizes_and_options_come_from_the_files(release):
    config = release.vae.config
    assert (config.hidden_size, config.latent_size, config.attention_size) == (64, 16, 32)
    assert config.text.hidden_size == 32 and config.text.flip_backward_words
    assert release.spec.feature_dim == 263 and release.vectorizer.size == 4199
    assert release.length_model.config.mlp_sizes == (512, 256, 128)


def test_the_release_vocabulary_encodes_the_tokens_as_the_release(release, expected):
    for i, tokens in enumerate(expected["tokens"]):
        encoded = release.vectorizer.encode_tokens(str(tokens).split(" "))
        assert encoded.length == expected["cap_lens"][i]
        np.testing.assert_array_equal(encoded.words, expected["word_emb"][i])
        np.testing.assert_array_equal(encoded.pos_onehot, expected["pos_ohot"][i])


def test_normalisation_is_meta_as_stored_the_dataset_std_over_25(release):
    std = np.load(REFERENCE.parent / "humanml3d" / "Std.npy")
    ratio = std / release.normalizer.std
    root_and_contacts = np.r_[0:4, 259:263]
    np.testing.assert_allclose(ratio[root_and_contacts], 25.0, rtol=0.02)
    np.testing.assert_allclose(np.delete(ratio, root_and_contacts), 1.0, rtol=0.01)


@torch.no_grad()
def test_text_encoder_and_length_estimator(release, release64, expected, text_inputs):
    words, sentence = release.vae.text_encoder(*text_inputs)
    words64, sentence64 = release64["vae"].text_encoder(*as64(text_inputs))
    longest = int(text_inputs[2].max())
    close(words[:, :longest], words64[:, :longest], expected["text_word_hids"], "words")
    close(sentence, sentence64, expected["text_sentence"], "sentence")
    logits64 = release64["length_model"](*as64(text_inputs))
    close(release.length_model(*text_inputs), logits64, expected["length_logits"], "length")


@torch.no_grad()
def test_movement_encoder_and_decoder(release, release64, expected):
    motions = torch.from_numpy(expected["motions"])[..., :-4]
    codes, recorded = release.encoder(motions), torch.from_numpy(expected["mov_enc_codes"])
    # Rigorous: each output of the first convolution sums 259 channels x 4 taps + bias = 1,037
    # terms, the second 48 x 4 + 1, the Linear 40 + 1; every float32 evaluation, whatever its
    # order, is within gamma_n (|W| |x| + |b|) per layer, carried through |W| and the 1-Lipschitz
    # LeakyReLU (tests.tolerances.propagated_bound). The motions reach |x| = 470, so that worst
    # case is up to 0.45 where both sides are 1e-5 from float64 (4.1e-5 ours on AVX2, 1.8e-5 on
    # AVX-512, 1.1e-5 the recorded codes): it fails only for gross errors (without the Linear's
    # bias: 1,400x over it).
    exact, bound = propagated_bound([*release.encoder.net, release.encoder.out], motions)
    for side in (codes, recorded):
        assert ((side.double() - exact).abs() <= bound).all()
    # Tight: the two roundings against each other (observed ratio 3.9 of 16).
    close(codes, release64["encoder"](motions.double()), expected["mov_enc_codes"], "codes")
    # The decoder from the recorded codes, the input the release's features came from (ours
    # differ by float32 rounding, 3e-5, which its sums carry on).
    features64 = release64["decoder"](recorded.double())
    close(release.decoder(recorded), features64, expected["mov_dec_features"], "features")


@torch.no_grad()
def test_evaluator_embeddings_as_the_release_feeds_it(expected, text_inputs):
    loaded = load_release_evaluator(REFERENCE / "checkpoints" / "t2m" / "text_mot_match")
    evaluator, evaluator64 = loaded.evaluator, as_float64(loaded.evaluator)
    m_lens = torch.from_numpy(expected["m_lens"])
    assert (m_lens.diff() <= 0).all()  # the release returns length-sorted order; here it is one
    close(
        evaluator.embed_text(*text_inputs),
        evaluator64.embed_text(*as64(text_inputs)),
        expected["eval_text_embedding"],
        "text embedding",
    )
    motions = torch.from_numpy(expected["motions"])
    close(
        evaluator.embed_motion(motions, m_lens),
        evaluator64.embed_motion(motions.double(), m_lens),
        expected["eval_motion_embedding"],
        "motion embedding",
    )
    assert len(loaded.sha256) == 64


def _generation(vae, initial_code, expected, text_inputs):
    """Codes of ``generate`` and the outputs of the same ``rollout``, batched, from the
    recorded noise, in ``vae``'s dtype."""
    dtype = initial_code.dtype
    words, sentence, mask = vae.encode_text(*text_inputs)
    steps = [int(expected[f"gen{b}_length"]) // 4 for b in range(4)]
    noise = torch.zeros(4, max(steps), vae.config.latent_size, dtype=dtype)
    for b, count in enumerate(steps):
        noise[b, :count] = torch.from_numpy(expected[f"gen{b}_eps"])
    steps = torch.tensor(steps)
    codes = vae.generate(words, sentence, mask, steps, initial_code, noise=noise)
    _, outputs = vae.rollout(
        vae.initial_state(sentence, initial_code),
        vae.word_context(words, mask),
        vae.time_codes(steps, int(steps.max())),
        noise,
    )
    return steps, codes, outputs


@torch.no_grad()
def test_generation_given_the_recorded_noise_batched_as_at_batch_one(
    release, release64, expected, text_inputs
):
    """The release generated each caption alone; one batch of all four gives the same."""
    steps, codes, outputs = _generation(release.vae, release.initial_code, expected, text_inputs)
    _, codes64, outputs64 = _generation(
        release64["vae"], release.initial_code.double(), expected, as64(text_inputs)
    )
    for b in range(4):
        count, words_b = int(steps[b]), int(text_inputs[2][b])
        close(codes[b, :count], codes64[b, :count], expected[f"gen{b}_codes"], f"codes {b}")
        for name, key in (("prior_mean", "prior_mu"), ("prior_logvar", "prior_logvar")):
            ours, ours64 = getattr(outputs, name)[b, :count], getattr(outputs64, name)[b, :count]
            close(ours, ours64, expected[f"gen{b}_{key}"], f"{name} {b}")
        close(
            outputs.attention_weights[b, :count, :words_b],
            outputs64.attention_weights[b, :count, :words_b],
            expected[f"gen{b}_attention"],
            f"attention {b}",
        )
        assert not outputs.attention_weights[b, :, words_b:].any()  # padding masked
        close(
            release.decoder(codes[b : b + 1, :count])[0],
            release64["decoder"](codes64[b : b + 1, :count])[0],
            expected[f"gen{b}_features"],
            f"features {b}",
        )


@torch.no_grad()
def test_teacher_forced_training_pass(release, release64, expected, text_inputs):
    frames = int(expected["m_lens"][0])
    motion = torch.from_numpy(expected["motions"][:1, :frames, :-4])
    noise = torch.from_numpy(expected["tf_eps_post"])[None]
    runs = {}
    for dtype, vae, encoder in (
        (torch.float32, release.vae, release.encoder),
        (torch.float64, release64["vae"], release64["encoder"]),
    ):
        inputs = tuple(
            x[:1] for x in (text_inputs if dtype == torch.float32 else as64(text_inputs))
        )
        words, sentence, mask = vae.encode_text(*inputs)
        targets = encoder(motion.to(dtype))
        initial = release.initial_code.to(dtype)
        runs[dtype] = []
        for fast in (True, False):
            vae.set_training_pass(fast_forward if fast else None)
            runs[dtype].append(vae(words, sentence, mask, targets, initial, True, noise.to(dtype)))
        vae.set_training_pass(fast_forward)
    for fast, out, out64 in zip((True, False), *runs.values(), strict=True):
        for name, key in (
            ("posterior_mean", "tf_post_mu"),
            ("posterior_logvar", "tf_post_logvar"),
            ("prior_mean", "tf_prior_mu"),
            ("prior_logvar", "tf_prior_logvar"),
            ("codes", "tf_codes"),
        ):
            close(out[name][0], out64[name][0], expected[key], f"{name} fast={fast}")


def test_without_the_flip_the_word_features_differ(release, expected, text_inputs):
    """The flip option is what makes the release's word features: off, they differ."""
    encoder = release.vae.text_encoder
    encoder.flip_backward_words = False
    try:
        with torch.no_grad():
            words, _ = encoder(*text_inputs)
    finally:
        encoder.flip_backward_words = True
    longest = int(text_inputs[2].max())
    assert np.abs(words[:, :longest].numpy() - expected["text_word_hids"]).max() > 1e-3


def test_refusals_are_one_line(tmp_path):
    from dataset_tools.command import UsageError

    copy = tmp_path / "release"
    shutil.copytree(REFERENCE / "checkpoints", copy / "checkpoints")
    with pytest.raises(UsageError, match="--glove"):
        load_release(copy)
    with pytest.raises(UsageError, match="not a T2M release"):
        load_release(tmp_path)
    shutil.copytree(REFERENCE / "glove", copy / "glove")
    tar = copy / "checkpoints" / "t2m" / "Comp_v6_KLD01" / "model" / "latest.tar"
    torch.save({"text_enc": Path("payload")}, tar)  # a pickled object, not plain weights
    with pytest.raises(UsageError, match="refused") as error:
        load_release(copy)
    assert "\n" not in str(error.value)


def test_sample_command_from_the_release_folder(tmp_path):
    from t2m.sample import main

    out = tmp_path / "out"
    args = ["--checkpoints", str(REFERENCE), "--text", "a person kicks", "--num-samples", "2"]
    assert main([*args, "--render", "none", "--bvh", "--out", str(out)]) == 0
    joints = np.load(out / "sample00_rep01.npy")
    assert joints.ndim == 3 and joints.shape[1:] == (22, 3) and 40 <= len(joints) <= 196
    assert (out / "sample00_rep00.bvh").is_file()
    info = np.load(out / "results.npy", allow_pickle=True).item()
    assert info["num_repetitions"] == 2 and info["motion"].shape[:3] == (2, 22, 3)


def test_the_release_glove_folder_as_word_vectors_for_our_training():
    from t2m.data.words import load_vectorizer, vectorizer_from_info
    from t2m.lexicon import MOTION_WORDS

    vectors = load_vectorizer(str(REFERENCE / "glove"))
    assert (vectors.size, vectors.dim) == (4199, 300) and vectors.words[:3] == ["sos", "eos", "unk"]
    again = vectorizer_from_info(vectors.info())  # what a checkpoint stores rebuilds it
    assert again.fingerprint() == vectors.fingerprint()
    # the release's motion-word lists, not ours: "head" keeps its tag there
    head = vectors.encode_tokens(["head/NOUN"]).pos_onehot[1].argmax()
    assert "head" in MOTION_WORDS["BODY_PART"] and head == 1  # NOUN
