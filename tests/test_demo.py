from t2m.demo import PROMPTS, run_demo


def test_demo_runs_end_to_end_then_reuses_everything(tmp_path):
    paths = {
        "dataset": tmp_path / "data",
        "source": tmp_path / "src",
        "run_dir": tmp_path / "run",
        "out": tmp_path / "out",
    }
    summary = run_demo(**paths, clips=120, num_samples=2, render="none", preset_name="tiny")
    assert "make demo finished" in summary and "Real motions" in summary
    for stage in ("autoencoder", "length", "generator", "evaluator"):
        assert (paths["run_dir"] / stage / "finished.json").is_file()
        assert f"{stage} trained in" in summary
    motions = sorted(p.name for p in paths["out"].glob("sample*_rep*.npy") if "feats" not in p.name)
    assert len(motions) == len(PROMPTS) * 2
    assert len(list(paths["out"].glob("*.bvh"))) == len(PROMPTS) * 2
    assert (tmp_path / "out_eval" / "results.md").is_file()
    # A second run trains nothing and rebuilds nothing.
    again = run_demo(**paths, clips=120, num_samples=2, render="none", preset_name="tiny")
    assert "autoencoder reused, length reused, generator reused, evaluator reused" in again
