"""Clause-by-clause generation (TextToMotion plan="clauses") on the session's tiny models."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from t2m.evaluate.protocol import EvalConfig, deviations
from t2m.inference.generation import clause_codes, text_batch
from t2m.models.temporal_vae import StepRollout
from t2m.pipeline import PLANS

TWO = "a person walks forward, then jumps up and down"
THREE = "a person turns to the left and then walks forward, after that jumps"
ONE = "a person walks forward"


def test_prepare_finds_the_clauses(pipe):
    one, two, three = pipe.prepare([ONE, TWO, THREE])
    assert one.clauses == ()
    assert len(two.clauses) == 2 and len(three.clauses) == 3
    # each clause is a caption of its own: "then jumps up and down" -> "a person jump up and down"
    expected = pipe.vectorizer.encode_tokens(
        "a/DET person/NOUN jump/VERB up/ADP and/CCONJ down/ADP".split()
    )
    np.testing.assert_array_equal(two.clauses[1].words, expected.words)
    assert two.clauses[1].length == expected.length


def test_clause_snippets_follow_the_length_model(pipe):
    two = pipe.prepare([TWO])[0]
    shares = pipe.clause_snippets([two.clauses], [160])[0]
    assert sum(shares) == 40 and min(shares) >= 5
    with torch.inference_mode():
        words, pos, lengths = text_batch(list(two.clauses), pipe.device, torch.float32)
        counts = torch.tensor([c.count for c in two.clauses])
        logits = pipe.length_model(words, pos, lengths, counts, clause=True)
        probs = torch.softmax(logits.double(), -1)
    units = torch.arange(probs.shape[-1], dtype=torch.float64)
    mean = (probs * units).sum(-1).numpy()
    variance = (probs * units**2).sum(-1).numpy() - mean**2
    ideal = mean + variance / variance.sum() * (40 - mean.sum())
    assert np.abs(np.array(shares) - ideal).max() <= 1.0 or min(shares) == 5
    # fewer snippets than clauses: one clause
    assert pipe.clause_snippets([two.clauses], [4])[0] == [1]


def test_the_length_model_reads_each_clause_count(pipe, monkeypatch):
    """The clause plan gives the length model each clause's count, marked as clauses; the
    length draws give it each caption's count, a whole caption of one clause and the clauses of
    one of several (the ``tiny`` preset's length model reads both:
    ``LengthModelConfig.plan_inputs``)."""
    assert pipe.length_model.config.plan_inputs
    seen = []
    model = pipe.length_model

    def recording(words, pos, lengths, counts=None, clause=False):
        seen.append((counts.tolist(), clause))
        return model(words, pos, lengths, counts, clause)

    recording.config = model.config
    monkeypatch.setattr(pipe, "length_model", recording)
    (two,) = pipe.prepare(["someone hops twice, then claps five times"])
    assert pipe.clause_snippets([two.clauses], [160])[0] and seen == [([2, 5], True)]
    pipe.sample_lengths(pipe.prepare(["a person claps five times", TWO]), torch.Generator())
    assert seen[1:] == [([5], False), ([0, 0], True)]  # TWO's clauses: as clauses
    pipe.sample_lengths(pipe.prepare([TWO]), torch.Generator(), by_clause=False)
    assert seen[3] == ([0], False)


def test_lengths_of_prompts_of_several_clauses_are_drawn_clause_by_clause(pipe):
    """With the clause plan a prompt of several clauses draws each clause's length as a clause
    (with its count) and sums them; prompts of one clause, and the whole plan, draw the whole
    caption's length as before. A clause (or a prompt of one clause) that names a count takes
    its expected length (the rounded mean) in every repeat instead of its draw; the draws are
    still made, so the others get the lengths they got before."""
    from t2m.models.length import sample_lengths

    texts = [ONE, "someone hops twice, then claps five times", TWO, "someone claps five times"]
    one, two, plain, single = pipe.prepare(texts)
    assert [c.count for c in two.clauses] == [2, 5] and single.encoded.count == 5
    unit, spec = pipe.spec.snippet_length, pipe.spec
    low = spec.min_frames // unit
    seed = lambda: torch.Generator().manual_seed(4)  # noqa: E731
    drawn = pipe.sample_lengths([one, two, plain, single], seed(), repeats=3)
    with torch.inference_mode():
        whole = pipe._length_logits([one.encoded, single.encoded], 8)
        parts = pipe._length_logits([*two.clauses, *plain.clauses], 8, clause=True)
    mean = lambda logits: (  # noqa: E731
        torch.softmax(logits.double(), -1) @ torch.arange(logits.shape[-1], dtype=torch.float64)
    )
    generator = seed()
    first = sample_lengths(whole.repeat_interleave(3, 0), generator, min_units=low).view(2, 3)
    units = torch.multinomial(
        torch.softmax(parts, -1).repeat_interleave(3, 0), 1, generator=generator
    ).view(4, 3)
    need = torch.floor(mean(parts) + 0.5).long()
    counted = units.clone()
    counted[:2] = need[:2, None]  # hops twice, claps five times: their means, every repeat
    sums = [counted[:2].sum(0), counted[2:].sum(0)]
    sums = [s.clamp(low, spec.max_snippets) for s in sums]
    alone = torch.floor(mean(whole[1:]) + 0.5).long().clamp(min=low).repeat(3)
    expected = first[0].tolist() + sums[0].tolist() + sums[1].tolist() + alone.tolist()
    assert drawn == [int(u) * unit for u in expected]
    assert len(set(drawn[3:6])) == 1 and len(set(drawn[9:])) == 1  # counted: no spread
    # the whole plan (the paper's) draws every length, a counted prompt's too
    assert pipe.sample_lengths([one, single], seed(), repeats=3, by_clause=False) == [
        int(u) * unit
        for u in sample_lengths(whole.repeat_interleave(3, 0), seed(), spec.min_frames // unit)
        .clamp(max=spec.max_snippets)
        .tolist()
    ]
    # generate draws through it: the clause plan's lengths, the whole plan's
    for plan, by_clause in (("clauses", True), ("whole", False)):
        made = pipe.generate([TWO], num_samples=2, seed=5, plan=plan)[0]
        expected = pipe.sample_lengths(
            pipe.prepare([TWO]), torch.Generator().manual_seed(5), 2, by_clause=by_clause
        )
        assert [m.num_frames for m in made] == expected


def test_one_clause_prompts_are_what_the_whole_plan_gives(pipe):
    texts = [ONE, TWO, "someone jumps up and down"]
    kwargs = dict(num_samples=2, lengths=[48, 96, 60], seed=3, batch_size=8)
    whole = pipe.generate(texts, plan="whole", **kwargs)
    clauses = pipe.generate(texts, plan="clauses", **kwargs)
    for p in (0, 2):  # the same draws and weights; the batch's other captions differ
        for a, b in zip(whole[p], clauses[p]):
            np.testing.assert_allclose(a.features, b.features, rtol=1e-3, atol=1e-4)
    alone = [pipe.generate([ONE], plan=plan, num_samples=2, lengths=48, seed=3) for plan in PLANS]
    for a, b in zip(alone[0][0], alone[1][0]):
        np.testing.assert_array_equal(a.features, b.features)
    assert all(m.num_frames == 96 for m in clauses[1])
    assert not np.array_equal(whole[1][0].features, clauses[1][0].features)
    with pytest.raises(ValueError, match="plan"):
        pipe.generate(texts, plan="sentences")


def test_clause_codes_chain_the_clauses(pipe):
    """The batched plan equals each item generated clause by clause with the step-by-step
    rollout: clause k reads its own caption, starts its GRU states from that caption's
    sentence, is fed the code clause k-1 ended on, counts down to its own end, and reads its
    stretch of the item's latent draws."""
    prepared = pipe.prepare([THREE, ONE, TWO])
    frames = [120, 64, 96]
    clauses = [p.clauses for p in prepared]
    unit = pipe.spec.snippet_length
    steps = max(frames) // unit
    noise = torch.randn(
        3, steps, pipe.vae.config.latent_size, generator=torch.Generator().manual_seed(0)
    )
    with torch.inference_mode():
        planned, planned_shares = pipe.clause_plan(
            [p.encoded for p in prepared], clauses, frames, settle=False
        )
        codes = clause_codes(
            pipe.vae,
            planned,
            planned_shares,
            pipe.initial_code,
            None,
            noise,
            pipe.device,
            pipe.dtype,
        )
    lists = [list(c) if c else [p.encoded] for c, p in zip(clauses, prepared)]
    shares = pipe.clause_snippets(lists, frames)
    assert planned_shares == shares
    vae = pipe.vae
    for b, (items, counts) in enumerate(zip(lists, shares)):
        previous, start, made = pipe.initial_code, 0, []
        for caption, count in zip(items, counts):
            words, pos, lengths = text_batch([caption], pipe.device, pipe.dtype)
            with torch.inference_mode():
                features, sentence, mask = vae.encode_text(words, pos, lengths)
                out = vae.generate(
                    features,
                    sentence,
                    mask,
                    torch.tensor([count]),
                    noise=noise[b : b + 1, start : start + count],
                    state=vae.initial_state(sentence, previous),
                    rollout=StepRollout(vae),
                )
            made.append(out[0])
            previous, start = out[0, -1], start + count
        expected = torch.cat(made)
        assert len(expected) == frames[b] // unit
        torch.testing.assert_close(codes[b, : len(expected)], expected, rtol=1e-4, atol=1e-5)
        assert torch.all(codes[b, len(expected) :] == 0)


def test_evaluation_plan_is_a_marked_deviation():
    assert EvalConfig().plan == "clauses"  # as t2m.sample; the paper's is whole
    notes = deviations(EvalConfig(), 10)
    assert any("plan = clauses" in note for note in notes)
    assert not any("plan" in note for note in deviations(EvalConfig(plan="whole"), 10))
    # captions of one clause each: the clause plan is the paper's one pass
    assert not any("plan" in note for note in deviations(EvalConfig(), 10, plans_differ=False))


def test_sample_cli_plan_option(tiny_run, tmp_path):
    from t2m import sample

    joints = {}
    for plan in ("clauses", "whole"):
        out = tmp_path / plan
        argv = ["--text", TWO, "--length", "96", "--checkpoints", str(tiny_run)]
        argv += ["--out", str(out), "--render", "none", "--plan", plan, "--seed", "1"]
        assert sample.main(argv) == 0
        summary = json.loads((out / "results.json").read_text())
        assert summary["plan"] == plan
        joints[plan] = np.load(out / "sample00_rep00.npy")
    assert joints["clauses"].shape == joints["whole"].shape == (96, 22, 3)
    assert not np.array_equal(joints["clauses"], joints["whole"])
    assert sample.main(["--text", TWO, "--checkpoints", str(tiny_run), "--plan", "words"]) == 2
