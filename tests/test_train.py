"""Training: the tiny run of all four stages, the stage registry, checkpoints, resume, refusals,
runs of the first releases (old names), the CLI and DDP."""

from __future__ import annotations

import json
import os
import re
import shutil
import socket
from pathlib import Path

import pytest
import torch
import torch.multiprocessing as mp

from dataset_tools.command import UsageError
from t2m.config import apply_overrides, from_dict
from t2m.data.dataset import load_split
from t2m.data.words import TRAINABLE
from t2m.models.autoencoder import MovementAutoencoder
from t2m.presets import tiny
from t2m.train import STAGE_NAMES, ModelSizes, find_stage, load_stage, train_stage
from t2m.train.__main__ import main
from t2m.train.checkpoint import atomic_save, read_checkpoint
from t2m.train.generator import Curriculum

ROOT = Path(__file__).resolve().parents[1]


def test_tiny_run_writes_every_stage_and_loads_back(tiny_run: Path):
    assert STAGE_NAMES == ("autoencoder", "length", "generator", "evaluator")
    for stage in STAGE_NAMES:
        folder = tiny_run / stage
        for name in ("latest.pt", "best.pt", "config.json", "metrics.jsonl", "curves.png"):
            assert (folder / name).is_file(), f"{stage}/{name}"
        records = [json.loads(line) for line in (folder / "metrics.jsonl").read_text().splitlines()]
        assert {r["split"] for r in records} == {"train", "val"}
        assert all(r["loss"] is not None and r["loss"] == r["loss"] for r in records)
        assert json.loads((folder / "config.json").read_text())["preset"] == "tiny"
        trained = load_stage(tiny_run, stage)
        assert trained.stage == stage and tuple(trained.models) == find_stage(stage).models
        assert all(not module.training for module in trained.models.values())
        assert trained.normalizer.dim == 263 and trained.dims.feature_dim == 263
        assert read_checkpoint(folder / "best.pt")["stage"] == stage
    t2m = load_stage(tiny_run, "generator")
    assert t2m.dims == ModelSizes(263, 50, 0, t2m.config.autoencoder.model.code_size)
    assert t2m.initial_code.shape == (t2m.config.autoencoder.model.code_size,)
    assert t2m.progress["snippets"] == t2m.config.generator.end_snippets and t2m.progress["done"]
    # end to end: free text -> codes -> features, through the stored vocabulary
    encoded = t2m.vectorizer.encode_tokens("a/DET person/NOUN walk/VERB forward/ADV".split())
    words = torch.from_numpy(encoded.words)[None]
    pos = torch.from_numpy(encoded.pos_onehot)[None]
    vae, decoder = t2m.models["vae"], t2m.models["decoder"]
    features, sentence, mask = vae.encode_text(words, pos, torch.tensor([encoded.length]))
    codes = vae.generate(
        features,
        sentence,
        mask,
        torch.tensor([12]),
        t2m.initial_code,
        torch.Generator().manual_seed(0),
    )
    motion = decoder(codes)
    assert motion.shape == (1, 48, 263) and torch.isfinite(motion).all()
    # the autoencoder and the evaluator share statistics and the frozen encoder
    ae, evaluator = load_stage(tiny_run, "autoencoder"), load_stage(tiny_run, "evaluator")
    assert (ae.normalizer.std == evaluator.normalizer.std).all()
    ae_best = read_checkpoint(tiny_run / "autoencoder" / "best.pt")["models"]["autoencoder"]
    stored = evaluator.models["evaluator"].movement_encoder.state_dict()
    assert all(torch.equal(stored[k], ae_best[f"encoder.{k}"]) for k in stored)


def weights(path: Path) -> dict[str, torch.Tensor]:
    return {
        f"{m}.{k}": v for m, sd in read_checkpoint(path)["models"].items() for k, v in sd.items()
    }


@pytest.mark.parametrize("stage,kill_at", [("autoencoder", 3), ("generator", 5)])
def test_resume_after_kill_equals_uninterrupted(
    stage, kill_at, tiny_dataset, tiny_config, tiny_run, tmp_path
):
    config = apply_overrides(
        tiny_config, {f"{stage}.checkpoint_every": "1000", "autoencoder.epochs": "2"}
    )
    whole, killed = tmp_path / "whole", tmp_path / "killed"
    for run_dir in (whole, killed):
        if stage == "generator":  # the same trained autoencoder under both
            shutil.copytree(tiny_run / "autoencoder", run_dir / "autoencoder")
    train_stage(stage, config, tiny_dataset, whole)
    # "kill" after kill_at steps (mid-epoch, a checkpoint is written on stopping) and resume
    train_stage(
        stage, apply_overrides(config, {f"{stage}.max_steps": str(kill_at)}), tiny_dataset, killed
    )
    assert read_checkpoint(killed / stage / "latest.pt")["progress"]["step"] == kill_at
    train_stage(stage, config, tiny_dataset, killed, resume=True)
    a, b = (
        read_checkpoint(whole / stage / "latest.pt"),
        read_checkpoint(killed / stage / "latest.pt"),
    )
    assert a["progress"] == b["progress"]
    wa, wb = weights(whole / stage / "latest.pt"), weights(killed / stage / "latest.pt")
    assert wa.keys() == wb.keys() and all(torch.equal(wa[k], wb[k]) for k in wa)
    steps_a = [
        (r["split"], r["step"])
        for r in map(json.loads, (whole / stage / "metrics.jsonl").read_text().splitlines())
    ]
    steps_b = [
        (r["split"], r["step"])
        for r in map(json.loads, (killed / stage / "metrics.jsonl").read_text().splitlines())
    ]
    assert steps_a == steps_b


def test_mismatched_checkpoints_are_refused(tiny_dataset, tiny_config, tiny_run, tmp_path):
    run_dir = tmp_path / "run"
    for stage in ("autoencoder", "length"):
        (run_dir / stage).mkdir(parents=True)
        (run_dir / stage / "latest.pt").write_bytes((tiny_run / stage / "latest.pt").read_bytes())
    bigger = apply_overrides(tiny_config, {"autoencoder.model.hidden_size": "48"})
    with pytest.raises(UsageError, match="model size differs"):
        train_stage("autoencoder", bigger, tiny_dataset, run_dir, resume=True)
    latest = run_dir / "autoencoder" / "latest.pt"
    latest.write_bytes((tiny_run / "length" / "latest.pt").read_bytes())
    with pytest.raises(UsageError, match="'length' checkpoint, not 'autoencoder'"):
        train_stage("autoencoder", tiny_config, tiny_dataset, run_dir, resume=True)
    other_words = apply_overrides(
        tiny_config, {"data.word_vectors": TRAINABLE, "data.trainable_word_dim": "50"}
    )
    with pytest.raises(UsageError, match="vocabulary differs"):
        train_stage("length", other_words, tiny_dataset, run_dir, resume=True)
    with pytest.raises(UsageError, match="make train-ae"):
        train_stage("generator", tiny_config, tiny_dataset, tmp_path / "empty")
    with pytest.raises(UsageError, match="make train-len"):
        load_stage(tmp_path / "empty", "length")
    with pytest.raises(UsageError, match="unknown stage 'vae'; choose one of autoencoder, length"):
        load_stage(tiny_run, "vae")


def test_trainable_vocabulary_stage(tiny_dataset, tiny_config, tmp_path):
    config = apply_overrides(
        tiny_config, {"data.word_vectors": TRAINABLE, "data.trainable_word_dim": "8"}
    )
    train_stage("length", config, tiny_dataset, tmp_path)
    trained = load_stage(tmp_path, "length")
    assert trained.vectorizer.trainable and "walk" in trained.vectorizer.index
    encoded = trained.vectorizer.encode_tokens(["walk/VERB", "zzzz/NOUN"])
    assert encoded.words.dtype.kind == "i" and encoded.words[2] == trained.vectorizer.index["unk"]
    logits = trained.models["length"](
        torch.from_numpy(encoded.words)[None],
        torch.from_numpy(encoded.pos_onehot)[None],
        torch.tensor([encoded.length]),
    )
    assert logits.shape == (1, 50)


def test_cli_exit_codes(tiny_dataset, tmp_path, capsys):
    base = [
        "autoencoder",
        "--preset",
        "tiny",
        "--dataset",
        str(tiny_dataset),
        "--checkpoints",
        str(tmp_path),
        "--device",
        "cpu",
    ]

    def one_line_error(*needles: str) -> None:
        err = capsys.readouterr().err
        assert err.startswith("error: ") and err.count("\n") == 1, err
        assert "Traceback" not in err and all(needle in err for needle in needles), err

    assert main(base + ["--autoencoder.nonexistent=1"]) == 2
    one_line_error("unknown config key 'autoencoder.nonexistent'")
    assert main(base + ["--ae.batch_size=abc"]) == 2
    one_line_error("expected an integer")
    assert main(base + ["--autoencoder.batch_size", "0"]) == 2
    one_line_error("autoencoder.batch_size must be at least 1, got 0")
    assert main(base + ["stray"]) == 2
    one_line_error("unexpected argument 'stray'")
    assert main(base + ["--device", "tpu"]) == 2
    one_line_error("unknown device 'tpu'")
    assert main(["ae", "--preset", "huge"]) == 2
    one_line_error("--preset: invalid choice: 'huge'")
    assert main(["vae", "--preset", "tiny"]) == 2
    one_line_error("invalid choice: 'vae'")
    missing_dataset = ["--dataset", str(tmp_path / "nope"), "--checkpoints", str(tmp_path)]
    assert main(["ae", "--preset", "tiny", *missing_dataset]) == 2
    one_line_error("does not exist (run `make dataset` first)")
    (tmp_path / "empty").mkdir()
    assert main([*base, "--dataset", str(tmp_path / "empty")]) == 2
    one_line_error("empty")  # not a dataset folder: no Mean/Std or split
    assert main(["generator", *base[1:]]) == 2
    one_line_error("run `make train-ae` first")
    assert main(base + ["--autoencoder.max_steps=2", "--autoencoder.epochs=1"]) == 0
    assert (tmp_path / "autoencoder" / "best.pt").is_file()
    # the old stage name trains the same stage, into the same folder
    assert main(["ae", *base[1:], "--ae.max_steps=2", "--ae.epochs=1", "--resume"]) == 0
    assert not (tmp_path / "ae").exists()
    assert main(base + ["--print-config", "--t2m.batch_size=5", "--seed", "7", "--bf16"]) == 0
    printed = capsys.readouterr()
    resolved = json.loads(printed.out)
    assert resolved["generator"]["batch_size"] == 5
    assert (resolved["seed"], resolved["bf16"], resolved["device"]) == (7, True, "cpu")
    assert "preset tiny:" in printed.err


def test_cli_help_comes_from_the_options_docstrings(capsys):
    with pytest.raises(SystemExit) as exit_info:
        main(["--help"])
    assert exit_info.value.code == 0
    shown = " ".join(capsys.readouterr().out.split())
    assert "--preset paper|demo|tiny the config to start from" in shown
    assert "generator (needs autoencoder)" in shown and "text2length, t2m, eval" in shown
    assert "--checkpoints DIR run folder (default: checkpoints/<preset>)" in shown
    assert "--device DEVICE auto, cpu, cuda, cuda:N (default: the config's, auto)" in shown
    for flag in ("--resume", "--bf16, --no-bf16", "--seed", "--print-config", "-v, --verbose"):
        assert flag in shown


def _free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def _ddp_worker(
    rank: int, world_size: int, port: int, dataset: str, run_dir: str, config_dict: dict
) -> None:
    from t2m.config import from_dict
    from t2m.train import stage as stage_module

    os.environ.update(
        MASTER_ADDR="127.0.0.1",
        MASTER_PORT=str(port),
        RANK=str(rank),
        WORLD_SIZE=str(world_size),
        LOCAL_RANK=str(rank),
    )
    finish = stage_module.StageRun.finish

    def finish_and_dump(self):  # each process's own weights, to compare across processes
        torch.save(self.models["autoencoder"].state_dict(), Path(run_dir) / f"rank{rank}.pt")
        finish(self)

    stage_module.StageRun.finish = finish_and_dump
    train_stage("autoencoder", from_dict(config_dict), dataset, run_dir)


def test_ddp_two_cpu_processes(tiny_dataset, tiny_config, tmp_path):
    config = apply_overrides(
        tiny_config, {"autoencoder.batch_size": "8", "autoencoder.epochs": "1"}
    )
    mp.start_processes(
        _ddp_worker,
        args=(2, _free_port(), str(tiny_dataset), str(tmp_path), config.to_dict()),
        nprocs=2,
        join=True,
        start_method="spawn",
    )
    checkpoint = read_checkpoint(tmp_path / "autoencoder" / "latest.pt")
    clips = len(load_split(tiny_dataset, "train"))
    assert checkpoint["progress"]["step"] == (clips // 2) // 8  # each process takes half an epoch
    rank0, rank1 = (torch.load(tmp_path / f"rank{r}.pt") for r in (0, 1))
    # the processes saw different data yet hold identical weights: gradients were averaged
    assert all(torch.equal(rank0[k], rank1[k]) for k in rank0)
    assert all(torch.equal(rank0[k], v) for k, v in checkpoint["models"]["autoencoder"].items())
    torch.manual_seed(config.seed)
    initial = MovementAutoencoder(263, config.autoencoder.model).state_dict()
    assert not torch.equal(initial["encoder.out.weight"], rank0["encoder.out.weight"])


def test_diverging_loss_stops_with_a_clear_error(tiny_dataset, tiny_config, tmp_path):
    exploding = apply_overrides(
        tiny_config, {"autoencoder.lr": "1e30", "autoencoder.log_every": "1"}
    )
    with pytest.raises(UsageError, match="loss is (nan|inf)"):
        train_stage("autoencoder", exploding, tiny_dataset, tmp_path)


def test_sigkill_then_resume_equals_uninterrupted(tiny_dataset, tmp_path):
    import signal
    import subprocess
    import sys
    import time

    args = ["--preset", "tiny", "--dataset", str(tiny_dataset), "--device", "cpu"]
    args += ["--autoencoder.epochs=40", "--autoencoder.checkpoint_every=1"]
    command = [sys.executable, "-m", "t2m.train", "autoencoder", *args]
    whole, killed = tmp_path / "whole", tmp_path / "killed"
    subprocess.run([*command, "--checkpoints", str(whole)], check=True, capture_output=True)
    process = subprocess.Popen([*command, "--checkpoints", str(killed)], stderr=subprocess.DEVNULL)
    latest = killed / "autoencoder" / "latest.pt"
    deadline = time.time() + 60
    while time.time() < deadline and process.poll() is None:
        if latest.is_file() and read_checkpoint(latest)["progress"]["step"] >= 10:
            process.send_signal(signal.SIGKILL)
            break
        time.sleep(0.05)
    process.wait()
    if process.returncode != -signal.SIGKILL:
        pytest.skip("the run finished before it could be killed (machine too fast for this test)")
    stopped_at = read_checkpoint(latest)["progress"]["step"]
    assert 10 <= stopped_at < 80
    subprocess.run(
        [*command, "--checkpoints", str(killed), "--resume"], check=True, capture_output=True
    )
    a, b = read_checkpoint(whole / "autoencoder" / "latest.pt"), read_checkpoint(latest)
    assert a["progress"] == b["progress"] and a["progress"]["step"] == 80
    wa, wb = weights(whole / "autoencoder" / "latest.pt"), weights(latest)
    assert all(torch.equal(wa[k], wb[k]) for k in wa)
    lines_a = [
        json.loads(line)["step"] for line in (whole / "autoencoder" / "metrics.jsonl").open()
    ]
    lines_b = [
        json.loads(line)["step"] for line in (killed / "autoencoder" / "metrics.jsonl").open()
    ]
    assert lines_a == lines_b


def test_autoencoder_stage_uses_the_configured_loss(
    tiny_dataset, tiny_config, tmp_path, monkeypatch
):
    import t2m.train.autoencoder as ae_stage

    seen = []
    original = ae_stage.autoencoder_loss

    def recording(*args, **kwargs):
        seen.append(args[5] if len(args) > 5 else kwargs.get("reconstruction_loss", "l1"))
        return original(*args, **kwargs)

    monkeypatch.setattr(ae_stage, "autoencoder_loss", recording)
    config = apply_overrides(
        tiny_config, {"autoencoder.reconstruction_loss": "smooth_l1", "autoencoder.epochs": "1"}
    )
    train_stage("autoencoder", config, tiny_dataset, tmp_path)
    assert seen and set(seen) == {"smooth_l1"}
    trained = load_stage(tmp_path, "autoencoder")
    assert trained.config.autoencoder.reconstruction_loss == "smooth_l1"


def test_registry_names_sections_make_targets_and_old_names():
    makefile = (ROOT / "Makefile").read_text()
    for stage in STAGE_NAMES:
        record = find_stage(stage)
        assert stage in tiny().stage_sections()  # the stage's config section
        target = re.search(rf"^{record.make_target}:.*\n\t.*-m t2m.train (\w+) ", makefile, re.M)
        assert target and target.group(1) == stage
        assert all(find_stage(old) is record for old in record.old_names)
        assert set(record.needs) <= set(STAGE_NAMES[: STAGE_NAMES.index(stage)])
    assert [find_stage(n).name for n in ("ae", "len", "text2length", "t2m", "eval")] == [
        "autoencoder",
        "length",
        "length",
        "generator",
        "evaluator",
    ]


def test_old_section_names_in_overrides_and_files(tiny_config):
    config = apply_overrides(tiny_config, {"t2m.batch_size": "16", "ae.epochs": "3"})
    assert (config.generator.batch_size, config.autoencoder.epochs) == (16, 3)
    with pytest.raises(ValueError, match="expected an integer"):
        apply_overrides(tiny_config, {"eval.batch_size": "x"})
    with pytest.raises(ValueError, match="unknown config key 't2m.nope'"):
        apply_overrides(tiny_config, {"t2m.nope": "1"})
    stored = config.to_dict()
    stored["ae"], stored["t2m"] = stored.pop("autoencoder"), stored.pop("generator")
    assert from_dict(stored) == config
    with pytest.raises(ValueError, match="old and its new name"):
        from_dict({**stored, "autoencoder": stored["ae"]})


def _as_first_release(checkpoint_path: Path, old_stage: str, target: Path) -> None:
    """Write ``checkpoint_path`` as the first releases did: old stage and section names, and
    only the sizes the stage used."""
    checkpoint = read_checkpoint(checkpoint_path)
    checkpoint["stage"] = old_stage
    config = checkpoint["config"]
    for old, new in (("ae", "autoencoder"), ("t2m", "generator"), ("eval", "evaluator")):
        config[old] = config.pop(new)
    checkpoint["dims"] = {k: v for k, v in checkpoint["dims"].items() if v}
    atomic_save(checkpoint, target)


def test_runs_of_the_first_releases_still_load_and_resume(
    tiny_dataset, tiny_config, tiny_run, tmp_path
):
    old_run = tmp_path / "old"
    for old, new in (("ae", "autoencoder"), ("t2m", "generator")):
        (old_run / old).mkdir(parents=True)
        for name in ("best.pt", "latest.pt"):
            _as_first_release(tiny_run / new / name, old, old_run / old / name)
    for name in ("ae", "autoencoder"):
        loaded = load_stage(old_run, name)
        assert loaded.stage == "autoencoder" and loaded.path.parent.name == "ae"
        assert loaded.dims == ModelSizes(263)
    generator = load_stage(old_run, "t2m")
    assert generator.config == load_stage(tiny_run, "generator").config
    # Resuming the old autoencoder continues in its folder; a new stage gets a new folder.
    more = apply_overrides(tiny_config, {"autoencoder.epochs": "3"})
    assert train_stage("ae", more, tiny_dataset, old_run, resume=True) == old_run / "ae"
    assert read_checkpoint(old_run / "ae" / "latest.pt")["stage"] == "autoencoder"
    assert load_stage(old_run, "ae").progress["epoch"] == 3
    assert train_stage("evaluator", tiny_config, tiny_dataset, old_run) == old_run / "evaluator"


def test_epoch_order_is_the_named_stream():
    from t2m.data.dataset import epoch_batches
    from t2m.streams import Stream, stream_rng

    order = stream_rng(Stream.EPOCH_ORDER, 3, 5).permutation(40)
    assert [b.tolist() for b in epoch_batches(40, 8, seed=3, epoch=5)] == [
        order[i : i + 8].tolist() for i in range(0, 40, 8)
    ]


def test_curriculum_moves_on_after_patience_or_the_stage_limit(tiny_config):
    section = apply_overrides(
        tiny_config,
        {
            "generator.end_snippets": "16",
            "generator.curriculum_step": "3",
            "generator.patience": "2",
            "generator.max_stage_epochs": "3",
        },
    ).generator
    curriculum = Curriculum(snippets=10)
    assert curriculum.record(1.0, section) and curriculum.record(0.5, section)
    assert not curriculum.record(0.7, section) and curriculum.snippets == 13  # the stage limit
    assert curriculum.stage_best == float("inf") and curriculum.stage_epochs == 0
    assert curriculum.record(2.0, section)  # best at the new length, though worse than before
    assert not curriculum.record(2.1, section) and not curriculum.record(2.2, section)
    assert curriculum.snippets == 16 and not curriculum.done  # patience: two bad epochs
    for value in (3.0, 3.1, 3.2):
        curriculum.record(value, section)
    assert curriculum.done and curriculum.snippets == 16


def test_length_buckets_batch_clips_of_similar_length():
    import numpy as np

    from t2m.train.generator import length_buckets

    lengths = np.array([50, 10, 40, 20, 60, 30, 80, 70, 99, 5])
    batches = [np.array([9, 3, 7]), np.array([1, 8, 0]), np.array([4, 2, 6])]
    cut = length_buckets(batches, lengths, np.random.default_rng(0))
    assert sorted(np.concatenate(cut).tolist()) == sorted(np.concatenate(batches).tolist())
    assert sorted(sorted(lengths[b].tolist()) for b in cut) == [
        [5, 10, 20], [40, 50, 60], [70, 80, 99]
    ]  # fmt: skip


@pytest.mark.parametrize("whole_clips", [False, True])
def test_whole_clips_train_the_clips_shorter_than_the_curriculum_length(
    tiny_dataset, tiny_config, tiny_run, tmp_path, whole_clips
):
    # The tiny training split: 28 clips of 50..130 frames and a few 44-frame captioned sub-clips,
    # batches of 8. At 30 snippets (120 frames) fewer than 8 are that long: the original
    # curriculum ends there, while whole clips train every clip again (the shorter ones whole).
    items = load_split(tiny_dataset, "train")
    assert sum(len(clip.motion) >= 120 for clip in items) < 8
    batches = len(items) // 8
    shutil.copytree(tiny_run / "autoencoder", tmp_path / "autoencoder")
    overrides = {
        "generator.start_snippets": "10",
        "generator.end_snippets": "30",
        "generator.curriculum_step": "20",
        "generator.max_stage_epochs": "1",
        "generator.whole_clips": str(whole_clips).lower(),
    }
    train_stage("generator", apply_overrides(tiny_config, overrides), tiny_dataset, tmp_path)
    progress = load_stage(tmp_path, "generator", which="latest").progress
    assert progress["step"] == (2 * batches if whole_clips else batches)


def test_runtime_sets_the_threads_each_epoch_asks_for():
    """``Runtime.epoch_threads`` (t2m.demo: one thread while its second process trains, two
    after) is applied by ``before_epoch``; no answer leaves the threads alone."""
    from t2m.train.runtime import Runtime

    before = torch.get_num_threads()
    answers = iter([1, 2, 0])
    runtime = Runtime(torch.device("cpu"), epoch_threads=lambda: next(answers))
    try:
        runtime.before_epoch()
        assert torch.get_num_threads() == 1
        runtime.before_epoch()
        assert torch.get_num_threads() == 2
        runtime.before_epoch()  # 0: keep
        assert torch.get_num_threads() == 2
    finally:
        torch.set_num_threads(before)


def test_learning_rates_fall_over_the_last_epochs_of_the_last_length(tiny_config):
    """``anneal_epochs``: a half cosine from the full rates to ``anneal_to`` over the last
    epochs of the last curriculum length; full rates everywhere else."""
    import math

    from t2m.train.generator import anneal_scale

    section = apply_overrides(
        tiny_config,
        {
            "generator.start_snippets": "10",
            "generator.end_snippets": "16",
            "generator.curriculum_step": "6",
            "generator.max_stage_epochs": "2",
            "generator.final_epochs": "4",
            "generator.anneal_epochs": "4",
            "generator.anneal_to": "0.2",
        },
    ).generator
    assert anneal_scale(Curriculum(snippets=10, stage_epochs=1), section) == 1.0
    scales = [anneal_scale(Curriculum(16, stage_epochs=k), section) for k in range(6)]
    assert scales[:2] == [1.0, 1.0]  # 6 epochs at the last length, the last 4 annealed
    expected = [0.2 + 0.8 * (1 + math.cos(math.pi * k / 4)) / 2 for k in (1, 2, 3, 4)]
    assert scales[2:] == pytest.approx(expected) and scales[-1] == pytest.approx(0.2)
    assert all(a > b for a, b in zip(scales[1:], scales[2:], strict=False))
    longer = apply_overrides(tiny_config, {"generator.anneal_epochs": "50"}).generator
    last = longer.max_stage_epochs + longer.final_epochs - 1
    first = Curriculum(longer.end_snippets, stage_epochs=0)
    assert anneal_scale(first, longer) < 1.0  # more than the length has: all of them
    assert anneal_scale(Curriculum(longer.end_snippets, stage_epochs=last), longer) == 0.1
    off = apply_overrides(tiny_config, {"generator.anneal_epochs": "0"}).generator
    assert anneal_scale(Curriculum(off.end_snippets, stage_epochs=last), off) == 1.0
    for value in ("0", "1.5"):
        with pytest.raises(ValueError, match="anneal_to in"):
            apply_overrides(tiny_config, {"generator.anneal_to": value})


def test_generator_trains_its_last_epochs_at_the_annealed_rates(
    tiny_dataset, tiny_config, tiny_run, tmp_path
):
    """The rates of the annealed epochs, logged and in the optimiser; a run stopped inside its
    last (annealed) epoch and resumed ends with the same weights as one never stopped."""
    whole, killed = tmp_path / "whole", tmp_path / "killed"
    for run_dir in (whole, killed):
        shutil.copytree(tiny_run / "autoencoder", run_dir / "autoencoder")
    overrides = {
        "generator.start_snippets": "10",
        "generator.end_snippets": "10",
        "generator.max_stage_epochs": "1",
        "generator.final_epochs": "2",
        "generator.anneal_epochs": "2",
        "generator.anneal_to": "0.25",
        "generator.log_every": "1",
    }
    config = apply_overrides(tiny_config, overrides)
    train_stage("generator", config, tiny_dataset, whole)
    records = [
        json.loads(line)
        for line in (whole / "generator" / "metrics.jsonl").read_text().splitlines()
    ]
    scales = {r["epoch"]: r["lr_scale"] for r in records if r.get("split") == "train"}
    assert list(scales.values()) == pytest.approx([1.0, 0.625, 0.25])
    stored = read_checkpoint(whole / "generator" / "latest.pt")
    rates = [group["lr"] for group in stored["optimizer"]["param_groups"]]
    section = config.generator
    assert rates == pytest.approx([0.25 * section.lr, 0.25 * section.decoder_lr])
    steps = stored["progress"]["step"]
    assert steps % 3 == 0 and steps >= 6  # three epochs of at least two steps
    stop = apply_overrides(config, {"generator.max_steps": str(steps - 1)})
    train_stage("generator", stop, tiny_dataset, killed)
    train_stage("generator", config, tiny_dataset, killed, resume=True)
    wa, wb = weights(whole / "generator" / "latest.pt"), weights(killed / "generator" / "latest.pt")
    assert wa.keys() == wb.keys() and all(torch.equal(wa[k], wb[k]) for k in wa)
