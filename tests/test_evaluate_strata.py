"""Numbers to trust: subsets with enough segments of every action, both generation plans tabled
and named, the headline as mean and spread, the demo's evaluation on pinned threads."""

from collections import Counter

import numpy as np
import pytest
from test_evaluate import FakeBackend, _clips

from t2m import evaluate
from t2m.evaluate.protocol import plan_row, stratified_subset
from t2m.evaluate.report import headline

ACTIONS = ("walk", "walk", "walk", "walk", "wave", "jump", "sit")
"""Labels by frequency: walks common, sits rare (one item in seven)."""


def _labels(count: int) -> list[list[str]]:
    rng = np.random.default_rng(3)
    return [list(rng.choice(ACTIONS, size=int(rng.integers(1, 3)))) for _ in range(count)]


def test_stratified_subset_holds_every_label_enough_times():
    labels = _labels(600)
    totals = Counter(label for item in labels for label in item)
    subset = stratified_subset(labels, 64, 30, np.random.default_rng(0), multiple=32)
    assert len(subset) % 32 == 0 and len(subset) >= 64 and len(set(subset.tolist())) == len(subset)
    counts = Counter(label for index in subset for label in labels[index])
    assert all(counts[label] >= min(30, totals[label]) for label in totals), counts
    # a uniform draw of as many items falls short of the rare label now and then
    assert totals["sit"] * len(subset) / len(labels) < 30 * 1.5
    # filled up to the size asked for; deterministic for a generator; random order
    large = stratified_subset(labels, 320, 30, np.random.default_rng(0), multiple=32)
    assert len(large) == 320
    again = stratified_subset(labels, 320, 30, np.random.default_rng(0), multiple=32)
    assert np.array_equal(large, again) and not np.all(np.diff(large) > 0)
    # a label rarer than asked: all of its items
    scarce = [["sit"]] * 5 + [["walk"]] * 100
    subset = stratified_subset(scarce, 32, 30, np.random.default_rng(1), multiple=32)
    assert sum(scarce[i] == ["sit"] for i in subset) == 5


class LabelScorer:
    """Scores every segment right; knows each item's segments (``segments_for``)."""

    def __init__(self, clips, labels):
        self.segments = {
            clip.name: [{"action": a} for a in item] for clip, item in zip(clips, labels)
        }

    def segments_for(self, name):
        return self.segments.get(name)

    def __call__(self, names, motions):
        counts = Counter(a["action"] for name in names for a in self.segments[name])
        scores = {"all": 1.0}
        for action, count in counts.items():
            scores[f"action_{action}"] = 1.0
            scores[f"scored_action_{action}"] = float(count)
        return scores


def test_every_replication_scores_enough_segments_of_every_action():
    clips, labels = _clips(600), _labels(600)
    scorer = LabelScorer(clips, labels)
    config = evaluate.EvalConfig(
        replications=3, max_items=64, mm_texts=4, mm_samples=3, plan="whole"
    )
    result = evaluate.run_protocol(clips, FakeBackend(), config, semantic=scorer)
    assert result.stratified and result.num_items % 32 == 0 and result.num_items > 64
    summary = evaluate.summarize(result)
    for row in evaluate.ROWS:
        for action in set(ACTIONS):
            counts = summary["rows"][row][f"semantic_accuracy_scored_action_{action}"]["values"]
            assert min(counts) >= 30, (row, action, counts)
    assert any("at least 30 segments" in note for note in summary["deviations"])
    # min_segments 0: a uniform draw of max_items
    uniform = evaluate.run_protocol(
        clips,
        FakeBackend(),
        evaluate.EvalConfig(**{**vars(config), "min_segments": 0}),
        semantic=scorer,
    )
    assert not uniform.stratified and uniform.num_items == 64


class PlanBackend(FakeBackend):
    """A fake backend whose one-pass plan misses (a larger offset) on captions of several
    clauses: those whose text holds "then"."""

    def __init__(self, plan="clauses"):
        super().__init__()
        self.plan = plan

    def with_plan(self, plan):
        return PlanBackend(plan)

    def plans_differ(self, captions):
        return any("then" in caption.text for caption in captions)

    def generate(self, captions, lengths, seed):
        out = super().generate(captions, lengths, seed)
        if self.plan == "whole":
            out = [m + 3.0 if "then" in c.text else m for m, c in zip(out, captions)]
        return out


def _clause_clips():
    clips = _clips(64)
    for clip in clips[::2]:
        clip.captions[0] = evaluate.protocol.Caption(clip.captions[0].text + " then waves", [])
    return clips


def test_both_plans_are_tabled_named_on_the_same_items():
    clips = _clause_clips()
    config = evaluate.EvalConfig(replications=2, mm_texts=4, mm_samples=3)
    result = evaluate.run_protocol(clips, PlanBackend(), config)
    one_pass = plan_row(evaluate.GT_LENGTH, "whole")
    assert one_pass == "Ours (ground-truth length, one pass)"
    assert result.rows == (*evaluate.ROWS, one_pass)
    assert plan_row(evaluate.SAMPLED_LENGTH, "clauses") == "Ours (sampled length, clause by clause)"
    values = result.values
    assert "multimodality" not in values[one_pass]
    # the one-pass rows miss on the captions of two clauses: further from their captions
    assert np.mean(values[one_pass]["mm_dist"]) > np.mean(values[evaluate.GT_LENGTH]["mm_dist"])
    # the plan's rows are what they are without the other plan's
    alone = evaluate.run_protocol(
        clips, PlanBackend(), evaluate.EvalConfig(**{**vars(config), "both_plans": False})
    )
    assert alone.rows == evaluate.ROWS
    for row in evaluate.ROWS:
        assert alone.values[row] == values[row]
    summary = evaluate.summarize(result)
    text = evaluate.format_markdown(summary)
    assert f"| {one_pass} |" in text and "row named 'one pass'" in text
    assert any("plan = clauses" in note for note in summary["deviations"])
    # captions of one clause each: the plans agree, one set of rows, no deviation
    plain = evaluate.run_protocol(_clips(64), PlanBackend(), config)
    assert plain.rows == evaluate.ROWS
    assert not any("plan" in note for note in evaluate.summarize(plain)["deviations"])


def test_headline_gives_mean_and_spread_of_each_plan():
    clips = _clause_clips()
    scorer = LabelScorer(clips, _labels(64))
    config = evaluate.EvalConfig(replications=3, mm_texts=4, mm_samples=3)
    summary = evaluate.summarize(
        evaluate.run_protocol(clips, PlanBackend(), config, semantic=scorer)
    )
    lines = headline(summary)
    assert lines[0].startswith("mean (lowest-highest) over 3 replications")
    fid = summary["rows"][evaluate.GT_LENGTH]["fid"]["values"]
    shown = f"FID {np.mean(fid):.3f} ({min(fid):.3f}-{max(fid):.3f})"
    assert any("clause by clause)" in line and shown in line for line in lines), lines
    assert any("one pass)" in line for line in lines)
    assert any(line.strip().startswith("per action") for line in lines)


def test_demo_evaluation_runs_on_pinned_threads(monkeypatch):
    import t2m.evaluate as package
    from t2m import demo

    seen = {}
    monkeypatch.setattr(package, "evaluate", lambda *args: seen.setdefault("config", args[3]))
    demo.quick_evaluation("data", "run", "out")
    config = seen["config"]
    assert config.quick and config.num_threads == demo.EVALUATION_THREADS == 1
    assert config.plan == "clauses" and config.both_plans and config.min_segments == 30


@pytest.mark.parametrize("bad", [{"min_segments": -1}])
def test_bad_settings_are_refused(bad):
    with pytest.raises(ValueError, match="min-segments"):
        evaluate.EvalConfig(**bad)
