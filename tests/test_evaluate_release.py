"""Evaluation with the original T2M release's evaluator (``--evaluator``): the release's own
generator and a run of ours, evaluated end to end on the reference release
(``../shared/reference/t2m-original``: the original code's files, random weights at small
sizes); the motions and captions reach the evaluator as the release feeds them; the table names
the evaluator's file and hash; bad folders are one line."""

from __future__ import annotations

import hashlib
import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch

from t2m.data.dataset import load_split
from t2m.evaluate import ROWS, CheckpointBackend
from t2m.evaluate.__main__ import main
from t2m.release import load_release_evaluator
from tests.tolerances import as_float64, assert_same_rounding

REFERENCE = Path(__file__).resolve().parents[2] / "shared" / "reference" / "t2m-original"
DATASET = REFERENCE / "checkpoints" / "t2m"
TEXT_MOT_MATCH = DATASET / "text_mot_match"
META = DATASET / "Comp_v6_KLD01" / "meta"
# One replication of one pool on the tiny corpus' 46 items ("all": the test split has 6).
QUICK = ["--split", "all", "--replications", "1", "--mm-texts", "2", "--mm-samples", "2"]
QUICK += ["--device", "cpu", "--threads", "1"]

pytestmark = pytest.mark.skipif(not REFERENCE.is_dir(), reason="reference release not present")


def _evaluate(dataset: Path, checkpoints: Path, out: Path, *extra: str) -> dict:
    args = ["--dataset", str(dataset), "--checkpoints", str(checkpoints), "--out", str(out)]
    assert main([*args, *QUICK, *extra]) == 0
    return json.loads((out / "results.json").read_text())


def _check_names_the_release_evaluator(summary: dict, out: Path) -> None:
    digest = hashlib.sha256((TEXT_MOT_MATCH / "model" / "finest.tar").read_bytes()).hexdigest()
    evaluator = summary["evaluator"]
    assert evaluator["sha256"] == digest
    assert evaluator["path"] == str(TEXT_MOT_MATCH / "model" / "finest.tar")
    assert str(META) in evaluator["normalization"]
    table = (out / "results.md").read_text()
    assert digest in table and str(META / "mean.npy") in table and "Split `all`" in table
    for row in ROWS:
        values = [entry["values"][0] for entry in summary["rows"][row].values()]
        assert len(values) >= 9 and np.isfinite(values).all(), row


def test_the_release_evaluated_with_its_own_evaluator(tiny_dataset, tmp_path):
    """A release given to --checkpoints: its generator, and by default its evaluator."""
    summary = _evaluate(tiny_dataset, REFERENCE, tmp_path / "out")
    _check_names_the_release_evaluator(summary, tmp_path / "out")
    assert summary["checkpoints"] == str(REFERENCE)


def test_our_run_evaluated_with_the_release_evaluator(tiny_run, tiny_dataset, tmp_path):
    out = tmp_path / "out"
    glove = ["--glove", str(REFERENCE / "glove")]
    summary = _evaluate(tiny_dataset, tiny_run, out, "--evaluator", str(TEXT_MOT_MATCH), *glove)
    _check_names_the_release_evaluator(summary, out)
    # Without --evaluator: the run's own evaluator stage, named as such.
    own = _evaluate(tiny_dataset, tiny_run, tmp_path / "own")
    assert own["evaluator"]["source"] == "the run's own evaluator stage"
    assert own["evaluator"]["path"].startswith(str(tiny_run))
    assert own["evaluator"]["sha256"] != summary["evaluator"]["sha256"]


@torch.no_grad()
def test_the_backend_feeds_the_release_evaluator_as_the_release_does(tiny_run, tiny_dataset):
    """Real and generated motions (raw features) normalised with the release's meta/ as stored,
    zero-padded to 196 frames, contacts dropped and m_len // 4 steps (inside embed_motion);
    captions in the release's vocabulary with their true token count."""
    backend = CheckpointBackend.from_run_dir(tiny_run, evaluator_dir=TEXT_MOT_MATCH)
    release = load_release_evaluator(TEXT_MOT_MATCH)
    mean, std = np.load(META / "mean.npy"), np.load(META / "std.npy")
    # The run's own statistics differ from the release's: the check below can fail.
    assert np.abs(backend.pipeline.normalizer.std / std - 1).max() > 0.1

    clip = load_split(tiny_dataset, "test")[0]
    caption = clip.captions[0]
    real = clip.motion[: len(clip.motion) // 4 * 4]
    generated = backend.generate([caption], np.array([48]), seed=0)[0]
    motions = [real, generated]
    padded = np.zeros((2, 196, 263), np.float32)
    for row, motion in enumerate(motions):
        padded[row, : len(motion)] = (motion - mean) / std
    frames = torch.tensor([len(real), len(generated)])
    by_hand = release.evaluator.embed_motion(torch.from_numpy(padded), frames)
    # The backend's embeddings and the hand-made ones are two float32 evaluations of the same
    # network on the same normalised input (batch sizes and kernels may differ): each within
    # ORDER_FACTOR of the other's distance to a float64 evaluation of the release's weights
    # (tests/tolerances.py). A wrong statistic, padding or step count moves them by 1e-2 or
    # more against distances of about 1e-6.
    exact_evaluator = as_float64(release.evaluator)
    padded64 = np.zeros((2, 196, 263))
    for row, motion in enumerate(motions):
        padded64[row, : len(motion)] = (motion.astype(np.float64) - mean) / std
    exact = exact_evaluator.embed_motion(torch.from_numpy(padded64), frames)
    ours = torch.from_numpy(backend.embed_motions(motions))
    assert_same_rounding(ours, by_hand, exact, msg="motion embeddings")
    alone = torch.from_numpy(backend.embed_motions([real]))  # padding not read: batch of one
    assert_same_rounding(alone[0], by_hand[0], exact[0], msg="a motion alone")

    encoded = release.vectorizer.encode_tokens(caption.tokens)
    assert encoded.length == len(caption.tokens) + 2  # sos, the tokens, eos
    words = torch.from_numpy(encoded.words[None])
    pos = torch.from_numpy(encoded.pos_onehot[None])
    length = torch.tensor([encoded.length])
    text = release.evaluator.embed_text(words, pos, length)
    exact_text = exact_evaluator.embed_text(words.double(), pos.double(), length)
    ours_text = torch.from_numpy(backend.embed_texts([caption]))
    assert_same_rounding(ours_text, text, exact_text, msg="text embeddings")


@pytest.fixture(autouse=True)
def _keep_torch_threads():
    """--threads 1 sets torch's process-wide count; later tests get theirs back."""
    threads = torch.get_num_threads()
    yield
    torch.set_num_threads(threads)


@pytest.fixture
def folders(tmp_path):
    """An empty run folder and a dataset folder whose test split lists one clip."""
    (tmp_path / "data").mkdir()
    (tmp_path / "data" / "test.txt").write_text("000000\n")
    (tmp_path / "run").mkdir()
    return ["--dataset", str(tmp_path / "data"), "--checkpoints", str(tmp_path / "run")]


def test_bad_evaluator_or_glove_folders_are_one_line(folders, tmp_path, capsys):
    def refused(extra: list[str], message: str) -> None:
        assert main([*folders, *extra]) == 2, extra
        err = capsys.readouterr().err
        assert err.startswith("error: ") and err.count("\n") == 1, err
        assert message in err, (extra, err)

    refused(["--evaluator", "/no/such/release"], "--evaluator /no/such/release: no such folder")
    refused(["--evaluator", str(tmp_path / "data")], "not a T2M release folder")
    refused(["--evaluator", str(REFERENCE / "glove")], "not a T2M release folder")
    refused(["--evaluator", str(TEXT_MOT_MATCH), "--glove", "/no/glove"], "--glove /no/glove: no")
    copy = tmp_path / "release"
    shutil.copytree(REFERENCE / "checkpoints", copy / "checkpoints")
    refused(["--evaluator", str(copy)], "pass --glove DIR")  # no glove/ beside the copy
    model = copy / "checkpoints" / "t2m" / "text_mot_match" / "model"
    (model / "finest.tar").rename(model / "latest.tar")
    refused(["--evaluator", str(copy), "--glove", str(REFERENCE / "glove")], "finest.tar")
