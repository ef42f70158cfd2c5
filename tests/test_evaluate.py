"""The evaluation protocol on a synthetic backend, and a tiny end-to-end evaluation."""

import json
import math
import re
import subprocess
import sys
import zlib
from pathlib import Path

import numpy as np
import pytest
import torch

from dataset_tools.command import field_docs
from dataset_tools.spec import HUMANML3D
from dataset_tools.synth.scoring import SemanticScorer, find_corpus_labels
from t2m import evaluate
from t2m.data.dataset import Caption, Clip
from t2m.evaluate.__main__ import EvalFolders, eval_config, main, parser

EMBED = 16
NOISE = 0.5


def _chi_mean(dof: int) -> float:
    """E||x|| for x ~ N(0, I_dof)."""
    return math.sqrt(2) * math.exp(math.lgamma((dof + 1) / 2) - math.lgamma(dof / 2))


def _caption_vector(text: str) -> np.ndarray:
    return np.random.default_rng(zlib.crc32(text.encode())).normal(size=EMBED) * 3.0


class FakeBackend:
    """Motions carry their caption's vector in every frame; the text embedding is that vector,
    the motion embedding the mean over frames. Generation adds one Gaussian offset per motion, so
    every metric has a value known in advance."""

    def __init__(self):
        self.calls: list[tuple[int, np.ndarray | None]] = []

    def embed_texts(self, captions):
        return np.stack([_caption_vector(c.text) for c in captions])

    def embed_motions(self, motions):
        for motion in motions:
            assert len(motion) % 4 == 0 and 4 <= len(motion) <= 196
        return np.stack([m[:, :EMBED].mean(axis=0) for m in motions])

    def generate(self, captions, lengths, seed):
        self.calls.append((len(captions), None if lengths is None else np.array(lengths)))
        rng = np.random.default_rng(seed)
        if lengths is None:
            lengths = rng.integers(10, 50, size=len(captions)) * 4
        out = []
        for caption, length in zip(captions, lengths, strict=True):
            vector = _caption_vector(caption.text) + NOISE * rng.normal(size=EMBED)
            out.append(np.tile(vector, (int(length), 1)))
        return out


def _clips(count: int = 70) -> list[Clip]:
    rng = np.random.default_rng(0)
    clips = []
    for k in range(count):
        text = f"a person does thing {k}"
        frames = int(rng.integers(40, 200))
        motion = np.tile(_caption_vector(text), (frames, 1)).astype(np.float32)
        clips.append(Clip(f"clip{k:03d}", motion, [Caption(text, ["a/DET", "person/NOUN"])]))
    return clips


def test_draw_items_crops_to_units_inside_the_clip():
    clips = _clips()
    draw = evaluate.draw_items(clips, 64, np.random.default_rng(1))
    assert len(set(draw.items.tolist())) == 64
    full = np.array([min(len(clips[i].motion), 196) // 4 * 4 for i in draw.items])
    assert np.all(draw.lengths % 4 == 0)
    assert np.all((draw.lengths == full) | (draw.lengths == full - 4))
    assert np.all(draw.starts + draw.lengths <= [len(clips[i].motion) for i in draw.items])
    many = evaluate.draw_items(clips * 30, 2100, np.random.default_rng(2))
    full = np.array([min(len((clips * 30)[i].motion), 196) // 4 * 4 for i in many.items])
    assert np.mean(many.lengths < full) == pytest.approx(1 / 3, abs=0.04)


def test_protocol_on_a_known_backend():
    backend = FakeBackend()
    config = evaluate.EvalConfig(replications=3, mm_texts=16, mm_samples=30, seed=5)
    result = evaluate.run_protocol(_clips(64), backend, config)
    assert result.num_items == 64
    real = result.values[evaluate.REAL]
    assert "multimodality" not in real
    np.testing.assert_allclose(real["r_precision_top1"], 1.0)
    np.testing.assert_allclose(real["mm_dist"], 0.0, atol=1e-4)  # float32 motions
    np.testing.assert_allclose(real["fid"], 0.0, atol=1e-6)  # the same 64 clips, reordered
    for row in (evaluate.GT_LENGTH, evaluate.SAMPLED_LENGTH):
        values = result.values[row]
        assert all(len(series) == 3 for series in values.values())
        # Offsets of norm ~ NOISE * sqrt(16) = 2: small against caption vectors ~ 3 * sqrt(32) apart.
        assert min(values["r_precision_top3"]) > 0.9
        assert np.mean(values["mm_dist"]) == pytest.approx(NOISE * _chi_mean(EMBED), rel=0.1)
        # Two independent offsets are NOISE * sqrt(2) * chi_16 apart, except for the ~1/30 of
        # pairs that draw the same generation twice (as the original's index draws allow).
        expected = NOISE * math.sqrt(2) * _chi_mean(EMBED) * (29 / 30)
        assert np.mean(values["multimodality"]) == pytest.approx(expected, rel=0.12)
        assert len(set(values["fid"])) == 3  # each replication generates anew
        assert np.all(np.array(values["fid"]) > 0)
    # Per replication: the GT-length row, its MM extras, the sampled row, its MM extras.
    sizes = [size for size, _ in backend.calls]
    assert sizes == [64, 16 * 29, 64, 16 * 29] * 3
    gt_lengths = backend.calls[0][1]
    assert gt_lengths is not None and np.all(gt_lengths % 4 == 0)
    assert backend.calls[2][1] is None  # sampled length: the model draws it
    mm_lengths = backend.calls[1][1]
    np.testing.assert_array_equal(mm_lengths, np.repeat(gt_lengths[:16], 29))


def test_protocol_is_deterministic_per_seed():
    config = evaluate.EvalConfig(replications=2, mm_texts=4, mm_samples=10, seed=1)
    first = evaluate.run_protocol(_clips(), FakeBackend(), config).values
    second = evaluate.run_protocol(_clips(), FakeBackend(), config).values
    assert first == second
    other = evaluate.EvalConfig(replications=2, mm_texts=4, mm_samples=10, seed=2)
    third = evaluate.run_protocol(_clips(), FakeBackend(), other).values
    assert third[evaluate.GT_LENGTH]["fid"] != first[evaluate.GT_LENGTH]["fid"]


def test_generation_seeds_come_from_the_named_streams():
    from t2m.streams import GenerationStream, stream_seed

    class Recording(FakeBackend):
        def generate(self, captions, lengths, seed):
            seeds.append(seed)
            return super().generate(captions, lengths, seed)

    seeds = []
    config = evaluate.EvalConfig(replications=2, mm_texts=4, mm_samples=3, seed=5)
    evaluate.run_protocol(_clips(), Recording(), config)
    # per replication and generated row: its motions, then its MultiModality extras
    assert seeds == [
        stream_seed(stream, 5, rep, row)
        for rep in range(2)
        for row in range(2)
        for stream in (GenerationStream.MOTIONS, GenerationStream.MULTIMODALITY)
    ]
    assert [int(stream) for stream in GenerationStream] == [0, 1]  # part of what a seed reproduces


def test_too_few_items_is_a_clear_error():
    with pytest.raises(ValueError, match="pool of 32"):
        evaluate.run_protocol(_clips(20), FakeBackend(), evaluate.EvalConfig(replications=1))


def test_summary_and_markdown_mark_quick_runs(tmp_path):
    config = evaluate.quick_config(evaluate.EvalConfig())
    assert config.replications == 3 and config.quick
    result = evaluate.run_protocol(_clips(70), FakeBackend(), config)
    assert result.num_items == 64  # two full pools of 32; 6 items left out
    summary = evaluate.summarize(result)
    assert summary["quick"] and not summary["standard_protocol"]
    assert any("QUICK MODE" in note for note in summary["deviations"])
    assert any("diversity over 64 pairs" in note for note in summary["deviations"])
    entry = summary["rows"][evaluate.GT_LENGTH]["fid"]
    mean, interval = entry["mean"], entry["interval"]
    assert mean == pytest.approx(np.mean(entry["values"]))
    assert interval == pytest.approx(1.96 * np.std(entry["values"]) / math.sqrt(3))
    json_path, md_path = evaluate.write_results(summary, tmp_path / "out")
    assert json.loads(json_path.read_text())["rows"][evaluate.REAL]["fid"]["values"]
    text = md_path.read_text()
    assert "QUICK MODE" in text
    for row in evaluate.ROWS:
        assert f"| {row} |" in text
    assert f"{mean:.3f} ±{interval:.3f}" in text
    real_line = next(line for line in text.splitlines() if line.startswith(f"| {evaluate.REAL} |"))
    assert real_line.rstrip(" |").endswith("-")  # no MultiModality for real motions


def test_standard_settings_have_no_deviation():
    paper = evaluate.EvalConfig(plan="whole")
    assert evaluate.deviations(paper, num_items=4384) == []
    notes = evaluate.deviations(evaluate.EvalConfig(plan="whole", replications=5), num_items=4384)
    assert notes == ["replications = 5 (standard: 20)"]


USAGE_PAGE = Path(__file__).resolve().parents[1] / "docs" / "evaluation.md"


def test_help_lists_the_documented_options_with_their_docstrings(capsys, monkeypatch):
    monkeypatch.setenv("COLUMNS", "1000")  # one line per option: no word broken at a hyphen
    with pytest.raises(SystemExit) as exit_info:
        main(["--help"])
    assert exit_info.value.code == 0
    text = " ".join(capsys.readouterr().out.split())
    usage = next(
        line
        for line in USAGE_PAGE.read_text().splitlines()
        if line.startswith("`python -m t2m.evaluate --dataset")
    )
    documented = set(re.findall(r"--[a-z][a-z-]+", usage))
    assert {"--dataset", "--checkpoints", "--replications", "--quick", "--precision"} <= documented
    for name in documented | {"--threads", "--max-items", "--seed", "--device", "--batch-size"}:
        assert re.search(rf" {name}[ ,]", text), name
    for cls in (evaluate.EvalConfig, EvalFolders):
        for name, doc in field_docs(cls).items():
            assert doc and doc in text, name
    assert "(default: auto)" in text and "[--which best|latest]" in text


def test_quick_lowers_only_the_values_not_given():
    base = ["--dataset", "d", "--checkpoints", "c"]
    standard = eval_config(parser().parse_args(base))
    assert standard == evaluate.STANDARD and standard.device == "auto"
    quick = eval_config(parser().parse_args([*base, "--quick", "--replications", "5"]))
    assert quick.quick and quick.replications == 5
    assert (quick.mm_texts, quick.mm_samples, quick.max_items) == (16, 10, 224)
    assert eval_config(parser().parse_args([*base, "--threads", "2"])).num_threads == 2


@pytest.fixture
def folders(tmp_path):
    """An empty run folder and a dataset folder whose test split lists one clip."""
    (tmp_path / "data").mkdir()
    (tmp_path / "data" / "test.txt").write_text("000000\n")
    (tmp_path / "run").mkdir()
    return ["--dataset", str(tmp_path / "data"), "--checkpoints", str(tmp_path / "run")]


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--replications", "0"], "--replications must be >= 1, got 0"),
        (["--mm-texts", "0"], "--mm-texts must be >= 1"),
        (["--mm-samples", "1"], "--mm-samples must be >= 2"),
        (["--max-items", "0"], "--max-items must be >= 1"),
        (["--batch-size", "0"], "--batch-size must be >= 1"),
        (["--threads", "-1"], "--threads must be >= 0"),
        (["--replications", "two"], "invalid int value"),
        (["--precision", "fp16"], "invalid choice"),
        (["--split", "val"], "no split file val.txt"),
        (["--device", "tpu"], "unknown device 'tpu'"),
        (["--dataset", "/no/such/dataset"], "--dataset /no/such/dataset: no such folder"),
        (["--checkpoints", "/no/such/run"], "--checkpoints /no/such/run: no such folder"),
    ],
)
def test_bad_input_is_one_line_and_exit_2(folders, capsys, extra, message):
    assert main([*folders, *extra]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and err.count("\n") == 1 and "Traceback" not in err
    assert message in err


def test_inputs_are_checked_before_anything_is_loaded(tmp_path, folders, capsys):
    (tmp_path / "data" / "empty.txt").write_text("\n")
    assert main([*folders, "--split", "empty"]) == 2
    assert "lists no clip" in capsys.readouterr().err
    (tmp_path / "file").write_text("")
    assert main([*folders, "--out", str(tmp_path / "file")]) == 2
    assert "not a folder" in capsys.readouterr().err
    # A run folder without its stages: the one line names the make target that trains them.
    assert main(folders) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "make " in err


def test_cli_is_offered_by_the_package():
    assert evaluate.main is main


def test_checkpoint_backend_generates_requested_lengths_deterministically(tiny_run):
    backend = evaluate.CheckpointBackend.from_run_dir(tiny_run, batch_size=3)
    captions = [
        Caption("a person walks forward", ["a/DET", "person/NOUN", "walk/VERB", "forward/ADV"]),
        Caption("someone hops in place", ["someone/PRON", "hop/VERB", "in/ADP", "place/NOUN"]),
    ] * 3
    lengths = np.array([40, 48, 196, 60, 44, 100])
    first = backend.generate(captions, lengths, seed=3)
    assert [len(m) for m in first] == lengths.tolist()
    assert all(m.shape[1] == 263 and np.isfinite(m).all() for m in first)
    again = backend.generate(captions, lengths, seed=3)
    assert all(np.array_equal(a, b) for a, b in zip(first, again, strict=True))
    other = backend.generate(captions, lengths, seed=4)
    assert not np.array_equal(first[0], other[0])
    sampled = [len(m) for m in backend.generate(captions, None, seed=3)]
    assert all(length % 4 == 0 and 40 <= length <= 196 for length in sampled)
    embeddings = backend.embed_motions(first)
    assert embeddings.shape == (6, backend.evaluator.config.embedding_size)
    # An embedding must not depend on the batch it is computed in.
    alone = np.concatenate([backend.embed_motions([m]) for m in first])
    np.testing.assert_allclose(embeddings, alone, atol=1e-4)
    assert backend.embed_texts(captions).shape == embeddings.shape


def test_tiny_end_to_end_evaluation(tiny_run, tiny_dataset, tmp_path, capsys):
    out = tmp_path / "results"
    # The tiny test split has 6 clips; "all" holds one full pool of 32 items.
    args = ["--dataset", str(tiny_dataset), "--checkpoints", str(tiny_run), "--split", "all"]
    args += ["--replications", "2", "--mm-texts", "4", "--mm-samples", "10", "--out", str(out)]
    assert main(args) == 0
    summary = json.loads((out / "results.json").read_text())
    assert summary["num_items"] == 32 and not summary["standard_protocol"]
    # --device auto: the evaluator and the generator ran on the resolved device.
    assert summary["settings"]["device"] == "auto"
    assert summary["device"] == ("cuda:0" if torch.cuda.is_available() else "cpu")
    assert "split = all (standard: test)" in summary["deviations"]
    for row in evaluate.ROWS:
        for name, entry in summary["rows"][row].items():
            assert len(entry["values"]) == 2 and all(math.isfinite(v) for v in entry["values"]), (
                name
            )
            assert entry["interval"] >= 0
    real = summary["rows"][evaluate.REAL]
    assert 0 <= real["r_precision_top1"]["mean"] <= real["r_precision_top3"]["mean"] <= 1
    # Reals against reals (other captions and crops of the same clips) sit closer than
    # an untrained generator's motions do.
    assert real["fid"]["mean"] < summary["rows"][evaluate.GT_LENGTH]["fid"]["mean"]
    text = (out / "results.md").read_text()
    assert "| Ours (sampled length) |" in text and "Deviations from the standard protocol" in text
    # Physical quality is measured for every row (the dataset's motions are 263-d features).
    for row in evaluate.ROWS:
        assert {"physical_skating_ratio", "physical_jerk_area"} <= summary["rows"][row].keys()
    assert "Physical quality" in text and "Foot skating ratio" in text
    assert "results.md" in capsys.readouterr().out


def _corpus_items(count: int):
    """Demo-corpus clips as the builder makes them: y-up, 20 fps, canonical features."""
    from dataset_tools.mirror import mirror_joints
    from dataset_tools.representation import process_motion
    from dataset_tools.segment import resample
    from dataset_tools.synth.corpus import clip_name, make_clip, z_up_to_y_up

    labels, names, features, mirrored = {"fps": 60, "clips": {}}, [], [], []
    for index in range(count):
        joints, _, label = make_clip(3, index)
        labels["clips"][clip_name(index)] = label
        y_up = resample(z_up_to_y_up(joints), 60, 20)
        names.append(clip_name(index))
        features.append(process_motion(y_up)[0])
        mirrored.append(process_motion(mirror_joints(y_up))[0])
    return labels, names, features, mirrored


def test_semantic_scorer_recovers_corpus_labels_and_rejects_wrong_ones():
    labels, names, features, mirrored = _corpus_items(8)
    scorer = SemanticScorer(labels, fps=HUMANML3D.fps)
    right = scorer(names, features)
    assert right["all"] >= 0.75 and right["segments"] >= 0.8
    assert set(right) >= {"all", "segments"} and any(k.startswith("action_") for k in right)
    # Each motion scored against another clip's labels.
    wrong = scorer(names, features[1:] + features[:1])
    assert wrong["all"] <= 0.25
    # Mirrored clips are held to the mirrored labels (left and right swap).
    assert scorer(["M" + n for n in names], mirrored)["all"] >= 0.75
    assert scorer(["M" + n for n in names], features)["all"] < right["all"]
    # Sub-clips and unknown clips are not scored.
    assert scorer([names[0] + "#0.0#2.0", "elsewhere"], features[:2]) == {}


def test_corpus_labels_are_found_through_the_build_report(tmp_path):
    source, dataset = tmp_path / "source", tmp_path / "dataset"
    source.mkdir()
    dataset.mkdir()
    assert find_corpus_labels(dataset) is None
    assert evaluate.find_scorer(dataset) is None
    labels = {"fps": 60, "clips": {"clip": {"frames": 60, "segments": []}}}
    (source / "labels.json").write_text(json.dumps(labels))
    (source / "source.json").write_text(json.dumps({"generator": "dataset_tools.synth"}))
    report = {"config": {"input_dir": str(source)}}
    (dataset / "build_report.json").write_text(json.dumps(report))
    assert find_corpus_labels(dataset) == source / "labels.json"
    # The evaluation finds the corpus' scorer through the plug-in, loaded with those labels.
    scorer = evaluate.find_scorer(dataset)
    assert isinstance(scorer, SemanticScorer) and scorer.clips == labels["clips"]
    (source / "source.json").write_text(json.dumps({"generator": "someone else"}))
    assert find_corpus_labels(dataset) is None
    assert evaluate.find_scorer(dataset) is None


def test_corpus_scoring_needs_neither_torch_nor_t2m():
    code = (
        "import sys, dataset_tools.synth.scoring; "
        "assert not {'torch', 't2m'} & set(sys.modules), sorted(sys.modules)"
    )
    subprocess.run([sys.executable, "-c", code], check=True, cwd=Path(__file__).parents[1])


def test_semantic_accuracy_reaches_the_table():
    def semantic(names, motions):
        return {"all": 0.5, "segments": 0.75, "action_walk": 0.25, "scored_action_walk": 12.0}

    config = evaluate.EvalConfig(replications=2, mm_texts=4, mm_samples=10)
    result = evaluate.run_protocol(_clips(64), FakeBackend(), config, semantic=semantic)
    summary = evaluate.summarize(result)
    for row in evaluate.ROWS:
        assert summary["rows"][row]["semantic_accuracy"]["values"] == [0.5, 0.5]
        assert summary["rows"][row]["semantic_accuracy_segments"]["mean"] == 0.75
    text = evaluate.format_markdown(summary)
    assert "Semantic accuracy" in text
    assert "| walk | 12 | 0.250 ±0.000 | 0.250 ±0.000 | 0.250 ±0.000 |" in text
    # a scorer without segment counts: the column reads "-"
    bare = lambda names, motions: {"all": 0.5, "action_walk": 0.25}  # noqa: E731
    result = evaluate.run_protocol(_clips(64), FakeBackend(), config, semantic=bare)
    assert "| walk | - | 0.250 ±0.000 |" in evaluate.format_markdown(evaluate.summarize(result))


def test_a_subset_is_shared_by_all_draws_of_a_replication():
    # 64 of 70 clips: the reference and the real row must describe the same clips, so real
    # motions (whose embedding ignores the crop here) are at FID 0 from the reference.
    config = evaluate.EvalConfig(replications=2, max_items=64, mm_texts=4, mm_samples=10)
    result = evaluate.run_protocol(_clips(70), FakeBackend(), config)
    np.testing.assert_allclose(result.values[evaluate.REAL]["fid"], 0.0, atol=1e-6)


def test_checkpoint_backend_settles_counts_at_given_lengths_as_sampling_does(tiny_run, monkeypatch):
    """With the clause plan, ground-truth (given) lengths are fixed lengths: a counted clause
    keeps the time its count needs, as t2m.sample does; drawn lengths and the paper's one-pass
    plan never settle."""
    backend = evaluate.CheckpointBackend.from_run_dir(tiny_run, batch_size=3)
    seen = []
    original = backend.pipeline.generate_features

    def recording(*args, **kwargs):
        seen.append(kwargs.get("settle"))
        return original(*args, **kwargs)

    monkeypatch.setattr(backend.pipeline, "generate_features", recording)
    captions = [Caption("a person walks forward", ["a/DET", "person/NOUN", "walk/VERB"])] * 2
    backend.generate(captions, np.array([40, 48]), seed=0)
    assert seen == [[True, True]]
    seen.clear()
    backend.generate(captions, None, seed=0)
    assert seen == [[False, False]]
    seen.clear()
    backend.with_plan("whole").generate(captions, np.array([40, 48]), seed=0)
    assert seen == [False]


def test_checkpoint_backend_reads_untrained_caption_words_as_prompts_are(tiny_run):
    """The generator reads a caption's untrained words as sampling reads a typed prompt's
    (t2m.lexicon): "leaps" as "jumps"; the evaluator reads the caption as stored."""
    backend = evaluate.CheckpointBackend.from_run_dir(tiny_run, batch_size=3)
    assert "leap" not in backend.pipeline.training_words
    leaps = Caption("a person leaps", ["a/DET", "person/NOUN", "leap/VERB"])
    jumps = Caption("a person jumps", ["a/DET", "person/NOUN", "jump/VERB"])
    lengths = np.array([40])
    (read,) = backend.generate([leaps], lengths, seed=1)
    (trained,) = backend.generate([jumps], lengths, seed=1)
    assert np.array_equal(read, trained)
    assert backend.readings == {"leap": "jump"}
    assert not np.allclose(backend.embed_texts([leaps]), backend.embed_texts([jumps]))
