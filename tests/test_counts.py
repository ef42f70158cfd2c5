"""Counts follow the text at any length: a counted clause given more time than it needs does
its count in the time it needs and stands still for the rest (t2m.clauses.settle_counted,
TextToMotion.clause_plan), on the session's tiny models."""

from __future__ import annotations

import logging

import numpy as np
import pytest
import torch

from t2m.clauses import (
    MIN_SETTLE_SNIPPETS,
    SETTLE_TEXT,
    SETTLE_TOKENS,
    needed_snippets,
    settle_counted,
    settled_captions,
)
from t2m.pipeline import SHORT_COUNT_SHARE

COUNTED = "a person jumps up and down twice"
PLAIN = "a person walks forward"
TWO_PARTS = "a person jumps up and down three times, then walks forward"


def test_settle_counted_splits_only_counted_clauses_with_time_to_spare():
    # one counted clause of 30 snippets that needs 12: 12, then 18 of settling
    assert settle_counted([2], [30], [12]) == [(0, 12), (-1, 18)]
    # no count: kept whole, however long
    assert settle_counted([0], [30], [12]) == [(0, 30)]
    # spare time below the minimum: kept whole
    spare = MIN_SETTLE_SNIPPETS - 1
    assert settle_counted([3], [12 + spare], [12]) == [(0, 12 + spare)]
    assert settle_counted([3], [12 + MIN_SETTLE_SNIPPETS], [12])[1] == (-1, MIN_SETTLE_SNIPPETS)
    # shorter than it needs: kept as given
    assert settle_counted([3], [8], [12]) == [(0, 8)]
    # the settling part follows its clause; the others keep their place and length
    plan = settle_counted([0, 4, 0], [10, 25, 9], [0, 15, 0])
    assert plan == [(0, 10), (1, 15), (-1, 10), (2, 9)]
    assert sum(n for _, n in plan) == 44
    # a small surplus goes to a neighbour without a count (the next, else the one before)
    assert settle_counted([3, 0], [14, 10], [12, 0]) == [(0, 12), (1, 12)]
    assert settle_counted([0, 3], [10, 14], [0, 12]) == [(0, 12), (1, 12)]
    assert settle_counted([2, 3], [10, 14], [10, 12]) == [(0, 10), (1, 14)]  # none free: stays
    with pytest.raises(ValueError, match="2 counts"):
        settle_counted([1, 2], [10], [5])


def test_needed_snippets_round_the_expected_length():
    np.testing.assert_array_equal(needed_snippets([10.4, 10.5, 13.6, 0.2]), [10, 11, 14, 1])


def test_settled_captions_read_the_counts_from_the_tokens():
    jumps = "a/DET person/NOUN jump/VERB twice/ADV".split()
    walks = "a/DET person/NOUN walk/VERB forward/ADV".split()
    plan = settled_captions([walks, jumps], [20, 30], [0, 12], SETTLE_TOKENS)
    assert plan == [(walks, 20), (jumps, 12), (list(SETTLE_TOKENS), 18)]


def test_settle_tokens_are_the_settle_text_as_prompts_are_tagged():
    from dataset_tools.texts import tag_prompts

    for spacy_pos in (False, True):
        (pairs,) = tag_prompts([SETTLE_TEXT], spacy_pos=spacy_pos)
        assert tuple(f"{w}/{p}" for w, p in pairs) == SETTLE_TOKENS


@pytest.fixture
def settling(pipe, monkeypatch):
    """The tiny pipeline as if its captions had said "a person stands still" (they never do:
    without those words trained nothing settles)."""
    words = {t.rpartition("/")[0] for t in SETTLE_TOKENS}
    monkeypatch.setattr(pipe, "training_words", pipe.training_words | words)
    pipe.__dict__.pop("_settle_encoded", None)  # the pipeline caches the settling caption
    yield pipe
    pipe.__dict__.pop("_settle_encoded", None)


def _own_snippets(pipe, prepared) -> int:
    means, _ = pipe.length_moments([prepared.encoded])
    return int(needed_snippets(means)[0])


def test_plan_splits_a_counted_clause_at_a_long_length_not_at_its_own(settling):
    pipe = settling
    unit = pipe.spec.snippet_length
    counted, plain = pipe.prepare([COUNTED, PLAIN])
    assert counted.encoded.count == 2 and counted.clauses == ()
    own = max(_own_snippets(pipe, counted), pipe.spec.min_frames // unit)
    longest = pipe.spec.max_frames // unit
    assert longest - own >= MIN_SETTLE_SNIPPETS  # room to settle in the tiny spec
    encoded = [counted.encoded, counted.encoded, plain.encoded]
    frames = [own * unit, longest * unit, longest * unit]
    lists, snippets = pipe.clause_plan(encoded, [(), (), ()], frames)
    # at its own length: one part, as before
    assert snippets[0] == [own] and lists[0] == [counted.encoded]
    # at the longest: the count in the time it needs, then standing still
    assert snippets[1] == [_own_snippets(pipe, counted), longest - _own_snippets(pipe, counted)]
    assert lists[1][0] is counted.encoded
    settle = pipe.vectorizer.encode_tokens(SETTLE_TOKENS)
    np.testing.assert_array_equal(lists[1][1].words, settle.words)
    assert lists[1][1].count == 0
    # no count: never split
    assert snippets[2] == [longest] and lists[2] == [plain.encoded]
    # settle=False: the count spread over the whole length, as before
    _, unsettled = pipe.clause_plan(encoded, [(), (), ()], frames, settle=False)
    assert unsettled[1] == [longest]


def test_count_parts_give_the_plan_as_prompts_and_frames(settling, monkeypatch):
    pipe = settling
    unit, longest = pipe.spec.snippet_length, pipe.spec.max_frames
    (counted,) = pipe.prepare([COUNTED])
    need = _own_snippets(pipe, counted) * unit
    assert pipe.count_parts(COUNTED, longest) == [(COUNTED, need), (SETTLE_TEXT, longest - need)]
    assert pipe.count_parts(counted, need) == [(COUNTED, need)]
    assert pipe.count_parts(PLAIN, longest) == [(PLAIN, longest)]
    # several clauses: the sum of their expected lengths (faked here), then standing
    fake = lambda encoded, clause=False: (np.full(len(encoded), 5.5), np.ones(len(encoded)))  # noqa: E731
    monkeypatch.setattr(pipe, "length_moments", fake)
    assert pipe.count_parts(TWO_PARTS, longest) == [(TWO_PARTS, 48), (SETTLE_TEXT, longest - 48)]
    assert pipe.count_parts(TWO_PARTS, 60) == [(TWO_PARTS, 60)]  # 3 snippets to spare: whole
    assert pipe.count_parts("a person walks forward, then waves", longest)[0][1] == longest


def test_a_counted_clause_of_several_settles_before_the_next(settling):
    pipe = settling
    (two,) = pipe.prepare([TWO_PARTS])
    assert [c.count for c in two.clauses] == [3, 0]
    means, _ = pipe.length_moments([two.clauses[0]], clause=True)
    need = int(needed_snippets(means)[0])  # estimated as a clause of a longer motion
    given = need + MIN_SETTLE_SNIPPETS + 3
    lists, snippets = pipe.settle_plan([list(two.clauses)], [[given, 9]])
    assert snippets == [[need, given - need, 9]]
    assert lists[0][0] is two.clauses[0] and lists[0][2] is two.clauses[1]
    settle = pipe.vectorizer.encode_tokens(SETTLE_TOKENS)
    np.testing.assert_array_equal(lists[0][1].words, settle.words)
    # the clause plan of such a prompt sums to its length whatever it splits
    longest = pipe.spec.max_frames
    _, planned = pipe.clause_plan([two.encoded], [two.clauses], [longest])
    assert sum(planned[0]) == longest // pipe.spec.snippet_length


def test_sampling_at_its_own_length_is_unchanged_and_a_long_length_settles(settling):
    pipe = settling
    unit = pipe.spec.snippet_length
    (counted,) = pipe.prepare([COUNTED])
    own = max(_own_snippets(pipe, counted), pipe.spec.min_frames // unit) * unit
    longest = pipe.spec.max_frames
    texts = [COUNTED, PLAIN]
    for frames, same in ((own, True), (longest, False)):
        settled = pipe.generate(texts, 2, [frames, frames], seed=3, clean=False)
        spread = pipe.generate(texts, 2, [frames, frames], seed=3, clean=False, settle=False)
        for prompt, (a_samples, b_samples) in enumerate(zip(settled, spread)):
            for a, b in zip(a_samples, b_samples):
                assert a.features.shape == b.features.shape == (frames, a.features.shape[1])
                equal = np.array_equal(a.features, b.features)
                # the prompt without a count never changes
                assert equal if (same or prompt == 1) else not equal


def test_drawn_lengths_never_settle(settling):
    """A length drawn from the text2length model is the model's own: left as it is, even a
    long draw (settling those made the demo model's MM-Dist worse)."""
    pipe = settling
    texts = [COUNTED] * 6
    settled = pipe.generate(texts, 2, None, seed=1, clean=False)
    spread = pipe.generate(texts, 2, None, seed=1, clean=False, settle=False)
    for a_samples, b_samples in zip(settled, spread):
        for a, b in zip(a_samples, b_samples):
            np.testing.assert_array_equal(a.features, b.features)
    planned = pipe.plan([COUNTED, PLAIN], 2, [None, 120])
    assert planned.fixed == [planned.items[i][0] == 1 for i in range(4)]


def test_the_web_worker_settles_as_generate_does(settling):
    from t2m.serve.worker import GenerationJob, generate_jobs

    pipe = settling
    longest = pipe.spec.max_frames
    job = GenerationJob([COUNTED, COUNTED], [longest, None], 2, seed=4, precision="fp32")
    generate_jobs(pipe, [job])
    motions, _ = job.result
    expected = pipe.generate(job.texts, 2, job.frames, seed=4)
    unsettled = pipe.generate(job.texts, 2, job.frames, seed=4, settle=False)
    for got, want in zip(motions, expected):
        for a, b in zip(got, want):
            np.testing.assert_allclose(a.joints, b.joints, atol=1e-5)
    # the fixed length settles, the drawn one does not
    assert not np.allclose(motions[0][0].joints, unsettled[0][0].joints, atol=1e-3)
    np.testing.assert_allclose(motions[1][0].joints, unsettled[1][0].joints, atol=1e-5)


def test_a_length_too_short_for_the_count_is_named(settling, caplog):
    pipe = settling
    (counted,) = pipe.prepare([COUNTED])
    need = pipe.count_frames([counted])[0]
    shortest = pipe.spec.min_frames
    assert need == _own_snippets(pipe, counted) * pipe.spec.snippet_length
    assert shortest < SHORT_COUNT_SHARE * need  # the tiny model's count needs more than that
    with caplog.at_level(logging.WARNING, logger="t2m.pipeline"):
        pipe.generate([COUNTED, PLAIN], 1, [need, need], clean=False)
        assert "names a count" not in caplog.text
        pipe.generate([COUNTED, PLAIN], 1, [shortest, shortest], clean=False)
    assert caplog.text.count("names a count that needs about") == 1
    assert repr(COUNTED) in caplog.text
    assert pipe.count_frames(pipe.prepare([PLAIN, TWO_PARTS])) == [0, 0]


def test_nothing_settles_without_the_settle_words(pipe):
    """The tiny captions never say "stands still": the plan keeps a counted clause whole."""
    assert "still" not in pipe.training_words
    (counted,) = pipe.prepare([COUNTED])
    longest = pipe.spec.max_frames
    _, snippets = pipe.clause_plan([counted.encoded], [()], [longest])
    assert snippets == [[longest // pipe.spec.snippet_length]]


def _recorded_segments(monkeypatch) -> list[tuple[str, int]]:
    """(text, new frames) of each segment a live stream generates from here on."""
    import t2m.live

    seen: list[tuple[str, int]] = []
    original = t2m.live.generate_plans

    def recording(pipe, plans, generator, settings):
        results = original(pipe, plans, generator, settings)
        for plan in plans:
            kept = int(plan.keep.any(axis=1).sum())
            seen.append((plan.text, plan.num_frames - kept))
        return results

    monkeypatch.setattr(t2m.live, "generate_plans", recording)
    return seen


def test_live_counted_prompt_counts_once_then_settles(settling, monkeypatch):
    pipe = settling
    unit = pipe.spec.snippet_length
    seen = _recorded_segments(monkeypatch)
    (counted,) = pipe.prepare([COUNTED])
    need = _own_snippets(pipe, counted) * unit
    stream = pipe.stream(COUNTED, seed=0, seconds=6.0, finish=False)
    fixed = pipe._clamp(6.0 * pipe.spec.fps)
    assert fixed - need >= MIN_SETTLE_SNIPPETS * unit
    for _ in range((fixed + fixed + 8) // unit):
        stream.next_snippet()
    # the count in the time it needs, the rest of its 6 s standing, then standing on
    assert seen[:3] == [(COUNTED, need), (SETTLE_TEXT, fixed - need), (SETTLE_TEXT, fixed)]
    assert all(s.text == COUNTED for s in [stream.next_snippet()])  # still the user's prompt
    # a new prompt without a count goes on as before: the same prompt, segment after segment
    seen.clear()
    stream.prompt(PLAIN, seconds=2.0)
    plain = pipe._clamp(2.0 * pipe.spec.fps)
    for _ in range((2 * plain + 8) // unit):
        stream.next_snippet()
    assert seen[:2] == [(PLAIN, plain), (PLAIN, plain)]


def test_sampling_at_given_lengths_loads_the_length_model(tiny_run, tmp_path, monkeypatch):
    """t2m.sample with every length given still loads the text2length stage where it is
    trained: without it nothing could settle."""
    from t2m.pipeline import TextToMotion
    from t2m.sample import main

    loads = []
    original = TextToMotion.from_checkpoints.__func__

    def recording(cls, *args, **kwargs):
        pipe = original(cls, *args, **kwargs)
        loads.append(pipe.length_model is not None)
        return pipe

    monkeypatch.setattr(TextToMotion, "from_checkpoints", classmethod(recording))
    out = tmp_path / "out"
    code = main(
        ["--text", COUNTED, "--checkpoints", str(tiny_run), "--out", str(out), "--render", "none",
         "--length", "120"]
    )  # fmt: skip
    assert code == 0 and loads == [True]


def test_sample_no_settle_reaches_generate(tiny_run, tmp_path, monkeypatch):
    """t2m.sample settles by default; --no-settle asks generate for the count spread over the
    whole length, and the run's info records which."""
    import json

    from t2m.pipeline import TextToMotion
    from t2m.sample import main

    asked = []
    original = TextToMotion.generate

    def recording(self, *args, **kwargs):
        asked.append(kwargs.get("settle"))
        return original(self, *args, **kwargs)

    monkeypatch.setattr(TextToMotion, "generate", recording)
    for flags, expected in (([], True), (["--no-settle"], False)):
        out = tmp_path / f"out{len(asked)}"
        argv = ["--text", COUNTED, "--checkpoints", str(tiny_run), "--out", str(out)]
        assert main([*argv, "--render", "none", "--length", "120", *flags]) == 0
        assert asked[-1] is expected
        info = json.loads((out / "results.json").read_text())
        assert json.dumps(info).count('"settle": ' + json.dumps(expected)) == 1


def _recorded_edit_searches(monkeypatch) -> list[tuple[str, int]]:
    """(text, new frames) of the first plan of each search t2m.edit makes from here on."""
    import t2m.edit

    seen: list[tuple[str, int]] = []
    original = t2m.edit.generate_plans

    def recording(pipe, plans, generator, settings):
        for plan in plans[:1]:  # edit_batch may search no plain plan at all
            seen.append((plan.text, plan.num_frames - int(plan.keep.any(axis=1).sum())))
        return original(pipe, plans, generator, settings)

    monkeypatch.setattr(t2m.edit, "generate_plans", recording)
    return seen


def test_compose_makes_a_counted_segment_as_its_count_then_standing(settling, monkeypatch):
    """compose cuts a counted segment as count_parts does: the count in the time it needs, the
    rest standing still; a segment without a count is made whole."""
    import t2m.edit
    from t2m.edit import SearchSettings
    from t2m.edit.modes import Segment

    pipe = settling
    unit = pipe.spec.snippet_length
    seen = _recorded_edit_searches(monkeypatch)
    (counted,) = pipe.prepare([COUNTED])
    need = _own_snippets(pipe, counted) * unit
    longest = pipe.spec.max_frames // unit * unit
    timeline = [Segment(COUNTED, 0, longest), Segment(PLAIN, longest, longest + 2 * unit)]
    (result,) = t2m.edit.compose(
        pipe, timeline, 1, torch.Generator().manual_seed(0), SearchSettings(candidates=1)
    )
    assert seen == [(COUNTED, need), (SETTLE_TEXT, longest - need), (PLAIN, 2 * unit)]
    assert len(result.features) == longest + 2 * unit


def test_continue_makes_a_counted_text_as_its_count_then_standing(settling, monkeypatch):
    """continue with a counted text and more time than the count needs: the kept start, the
    count in the time it needs, then standing still (as compose from that start)."""
    from conftest import synth_joints

    import t2m.edit

    pipe = settling
    unit = pipe.spec.snippet_length
    seen = _recorded_edit_searches(monkeypatch)
    (counted,) = pipe.prepare([COUNTED])
    need = _own_snippets(pipe, counted) * unit
    source = synth_joints("walk_forward", 101, np.random.default_rng(3))
    seconds = pipe.spec.max_frames / pipe.spec.fps
    settings = t2m.edit.SearchSettings(candidates=1)
    (motion,) = t2m.edit.edit(
        pipe, COUNTED, "continue", source, keep_seconds=1.0, seconds=seconds, settings=settings
    )
    kept = int(round(1.0 * pipe.spec.fps))
    rest = pipe.spec.max_frames // unit * unit - kept
    assert seen == [(COUNTED, need), (SETTLE_TEXT, rest - need)]
    assert motion.text == COUNTED and motion.mode == "continue"
    assert len(motion.joints) == kept + rest and motion.kept[:kept].all()
    assert not motion.kept[kept:].any()
    # a text without a count continues as planned: one search over the whole rest
    seen.clear()
    t2m.edit.edit(pipe, PLAIN, "continue", source, keep_seconds=1.0, seconds=2.0, settings=settings)
    assert seen == [(PLAIN, 40 - kept)]


def _recorded_rollouts(pipe, monkeypatch) -> list[int]:
    """The snippets of every rollout the temporal VAE runs from here on, in order."""
    seen: list[int] = []
    original = pipe.vae.rollout

    def recording(state, context, time_codes, noise, *args, **kwargs):
        seen.append(time_codes.shape[1])
        return original(state, context, time_codes, noise, *args, **kwargs)

    monkeypatch.setattr(pipe.vae, "rollout", recording)
    return seen


def test_inbetween_runs_the_count_then_standing_along_one_rollout(settling):
    """Between kept ends, a counted text given more time than its count needs is the clause
    plan's counted clause followed by standing still, along one rollout: the text's sentence
    state fed the mean-pose code (a new text starts as a caption does), its clocks over the
    time it needs, then the settling
    caption's sentence state fed the text's last code, its clocks over the rest of the
    stretch (up to the kept end), and on to the result's end."""
    from conftest import synth_joints

    from t2m.edit import EditRequest, SearchSettings
    from t2m.edit import core as search
    from t2m.inference.generation import text_batch

    pipe, vae = settling, settling.vae
    unit, total = pipe.spec.snippet_length, pipe.spec.max_frames // pipe.spec.snippet_length
    source = synth_joints("walk_forward", total * unit, np.random.default_rng(7))
    seconds = total * unit / pipe.spec.fps
    request = EditRequest(
        "inbetween", COUNTED, source, keep_start=1.0, keep_end=1.0, seconds=seconds
    )
    plan = request.plan(pipe.spec)
    known = search.known_prefix_snippets(plan, unit)
    free = search.free_snippets(plan, unit, known)
    (counted,) = pipe.prepare([COUNTED])
    need = _own_snippets(pipe, counted)
    assert free - need >= MIN_SETTLE_SNIPPETS  # the stretch has time to spare
    parts = search.text_parts(pipe, plan, counted, known, unit)
    assert [(p.snippets, p.clock, p.encoded.count) for p in parts] == [
        (need, need, 2),
        (total - known - need, free - need, 0),
    ]
    settings = SearchSettings(method="posterior", candidates=1, end_draws=1)
    (found,) = search._search(
        pipe, [plan], [parts], plan.num_frames, known, torch.Generator().manual_seed(4), settings, 0
    )
    (settle,) = pipe.prepare([SETTLE_TEXT])
    with torch.no_grad():
        kept = torch.from_numpy(plan.source_features[: known * unit]).float()[None]
        normalised = pipe.normalizer.normalize(kept)[..., : pipe.encoder_input_size]
        codes = [pipe.encoder(normalised)]  # (1, K, C)
        noise = torch.randn(
            1, total - known, vae.config.latent_size, generator=torch.Generator().manual_seed(4)
        )
        at = 0
        for encoded, steps, clock in ((counted.encoded, need, need), (settle.encoded, None, None)):
            steps = steps or total - known - need
            clock = clock or free - need
            words, pos, lengths = text_batch([encoded], pipe.device, pipe.dtype)
            word_features, sentence, mask = vae.encode_text(words, pos, lengths)
            previous = codes[-1][:, -1] if len(codes) > 1 else pipe.initial_code
            state = vae.initial_state(sentence, previous)
            times = vae.time_codes(
                torch.tensor([clock]), steps, torch.tensor([clock]), torch.tensor([encoded.count])
            )
            _, out = vae.rollout(
                state, vae.word_context(word_features, mask), times, noise[:, at : at + steps]
            )
            codes.append(out.code)
            at += steps
        decoded = pipe.decoder(torch.cat(codes, dim=1)).float()
        expected = pipe.normalizer.denormalize(decoded)[0].numpy()
    np.testing.assert_allclose(found[0], expected, rtol=1e-4, atol=1e-4)


@pytest.mark.parametrize("mode", ["inbetween", "body", "path", "keys"])
def test_edit_modes_make_a_counted_text_as_its_count_then_standing(settling, monkeypatch, mode):
    """Every edit mode whose text spans a stretch between constraints (kept ends, a kept body
    part, a path, keys) runs a counted text for the time its count needs, then standing still,
    in its search's rollouts; a text without a count runs as one caption."""
    from conftest import synth_joints

    import t2m.edit

    pipe = settling
    unit, total = pipe.spec.snippet_length, pipe.spec.max_frames // pipe.spec.snippet_length
    seconds = total * unit / pipe.spec.fps
    source = synth_joints("walk_forward", total * unit + 1, np.random.default_rng(7))
    (counted,) = pipe.prepare([COUNTED])
    need = _own_snippets(pipe, counted)
    options = {
        "inbetween": {"source": source, "keep_start": 1.0, "keep_end": 1.0, "seconds": seconds},
        "body": {"source": source, "part": "lower"},
        "path": {"path": [[seconds / 2, 0.0, 1.0], [seconds - 1, 0.5, 2.0]], "seconds": seconds},
        "keys": {
            "keys": np.where(np.arange(len(source))[:, None, None] == 30, source, np.nan)[:-1]
        },
    }[mode]
    known = 5 if mode == "inbetween" else 0  # the kept first second
    settings = t2m.edit.SearchSettings(candidates=2, steps=2)  # keys optimise through both
    seen = _recorded_rollouts(pipe, monkeypatch)
    (motion,) = t2m.edit.edit(pipe, COUNTED, mode, settings=settings, **options)
    assert len(motion.joints) == total * unit
    assert seen and seen == [need, total - known - need] * (len(seen) // 2)
    seen.clear()
    t2m.edit.edit(pipe, PLAIN, mode, settings=settings, **options)
    assert seen and set(seen) == {total - known}


@pytest.mark.parametrize("mode", ["inbetween", "body", "path"])
def test_counts_benchmark_edit_modes(settling, mode):
    """The counts benchmark's edit rows: inbetween makes the length between a kept second at
    each end, body and path a result of the length itself; one row per action, count and
    length."""
    from t2m.benchmarks.counts import measure

    pipe, unit = settling, settling.spec.snippet_length
    rows = measure(pipe, ["jump", "clap"], [2], (1.0, 1.5), 1, 0, True, mode)
    assert [(r["action"], r["length"]) for r in rows] == [
        ("jump", 1.0), ("clap", 1.0), ("jump", 1.5), ("clap", 1.5)
    ]  # fmt: skip
    for row in rows:
        frames = pipe._clamp(round(row["expected_frames"] * row["length"] / unit) * unit)
        longest = pipe.spec.max_frames // unit * unit
        whole = min(frames + 2 * pipe.spec.fps, longest) if mode == "inbetween" else frames
        assert row["frames"] == [whole] and 0.0 <= row["right"] <= 1.0
