import pytest

from dataset_tools.command import UsageError
from t2m.demo import PROMPTS, DemoConfig, main, run_demo


def test_demo_runs_end_to_end_then_reuses_everything(tmp_path):
    config = DemoConfig(
        clips=120,
        samples=2,
        render="none",
        preset="tiny",
        dataset=tmp_path / "data",
        source=tmp_path / "src",
        checkpoints=tmp_path / "run",
        out=tmp_path / "out",
    )
    summary = run_demo(config)
    assert "make demo finished" in summary and "Real motions" in summary
    for stage in ("autoencoder", "length", "generator", "evaluator"):
        assert (config.checkpoints / stage / "finished.json").is_file()
        assert f"{stage} trained in" in summary
    motions = sorted(p.name for p in config.out.glob("sample*_rep*.npy") if "feats" not in p.name)
    assert len(motions) == len(PROMPTS) * 2
    assert len(list(config.out.glob("*.bvh"))) == len(PROMPTS) * 2
    assert (tmp_path / "out_eval" / "results.md").is_file()
    # the paraphrase split (captions in held-out wording): 12 clips here, too few for the
    # protocol's R-precision pool, so it is named as not evaluated (make demo's 200 are)
    assert "paraphrases  the test_paraphrase split is not evaluated: the test_paraphrase split" in (
        summary
    )
    # the second process's logs: training length and evaluator, sampling beside the evaluation
    assert "length trained in" in (config.checkpoints / "side_stages.log").read_text()
    assert "generating" in (tmp_path / "out.log").read_text()
    # A second run trains nothing and rebuilds nothing.
    again = run_demo(config)
    assert "autoencoder reused, length reused, generator reused, evaluator reused" in again


def test_demo_options_come_from_the_config_docstrings(capsys):
    with pytest.raises(SystemExit) as exit_info:
        main(["--help"])
    assert exit_info.value.code == 0
    shown = " ".join(capsys.readouterr().out.split())
    for option in ("--clips", "--samples", "--render mp4|gif|none", "--preset paper|demo|tiny"):
        assert option in shown
    for option in ("--seed", "--workers", "--dataset DIR", "--source DIR", "--checkpoints DIR"):
        assert option in shown
    assert "motions per example prompt (default: 3)" in shown


def test_demo_bad_options_are_one_line_and_exit_2(tmp_path, capsys):
    assert main(["--clips", "0", "--dataset", str(tmp_path / "never")]) == 2
    assert capsys.readouterr().err == "error: --clips must be at least 1, got 0\n"
    assert main(["--render", "avi"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: argument --render: invalid choice") and err.count("\n") == 1
    assert not (tmp_path / "never").exists()


def test_parallel_stages_train_the_same_models_and_report_a_side_failure(
    tiny_dataset, tiny_run, tmp_path
):
    import torch

    from t2m.demo import SIDE_LOG, train_stages
    from t2m.train.checkpoint import read_checkpoint

    # The second process trains length and evaluator exactly as one process does (tiny_run).
    status = train_stages(tiny_dataset, tmp_path / "run", "tiny", parallel=True)
    assert status["length"].endswith("(2nd process)") and "(2nd" not in status["generator"]
    assert "evaluator trained in" in (tmp_path / "run" / SIDE_LOG).read_text()
    for stage in ("length", "evaluator"):
        ours = read_checkpoint(tmp_path / "run" / stage / "best.pt")["models"][stage]
        alone = read_checkpoint(tiny_run / stage / "best.pt")["models"][stage]
        assert all(torch.equal(ours[key], alone[key]) for key in alone)
    # A refused checkpoint in the second process's stage: one line, after the main lane.
    broken = tmp_path / "broken"
    (broken / "length").mkdir(parents=True)
    (broken / "length" / "latest.pt").write_bytes(b"not a checkpoint")
    with pytest.raises(UsageError, match="latest.pt") as error:
        train_stages(tiny_dataset, broken, "tiny", parallel=True)
    assert "\n" not in str(error.value)
    assert (broken / "generator" / "finished.json").is_file()
