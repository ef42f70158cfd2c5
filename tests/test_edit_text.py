"""Edits follow the text (issue 32 item 2), on the tiny trained run: a new text's part starts
as plain generation starts a caption (its own sentence state, the mean-pose code fed, the
clocks of its own stretch); a text that goes on with the kept motion (``EditPlan.continues``:
compose's next window of one line) as the clause plan starts a clause (the last kept code fed);
neither from the kept start read under the new text."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch
from conftest import synth_joints

from t2m.edit import EditRequest, SearchSettings
from t2m.edit import core as search
from t2m.edit.core import free_snippets, known_prefix_snippets
from t2m.inference.generation import text_batch

TEXT = "a person waves both hands"
COUNTED = "a person jumps three times"  # a count: the count clock runs


@pytest.fixture(scope="module")
def walk() -> np.ndarray:
    return synth_joints("walk_forward", 121, np.random.default_rng(5))


def _continue_plan(pipe, joints: np.ndarray, text: str = TEXT):
    request = EditRequest("continue", text, joints, keep_seconds=2.0, seconds=5.0)
    return request.plan(pipe.spec)


def _parts(pipe, plan, known: int):
    (prepared,) = pipe.prepare([plan.text])
    return [search.text_parts(pipe, plan, prepared, known, pipe.spec.snippet_length)]


@pytest.mark.parametrize("continues", [False, True], ids=["new text", "text goes on"])
def test_the_texts_part_starts_as_a_caption_or_as_a_clause(pipe, walk, continues):
    """The search's candidate is exactly what the model makes for the text after the kept
    start: GRU states from the text's sentence, the mean-pose code fed first (a new text, as
    plain generation starts a caption; feeding the last kept code made the part spend its
    first half second leaving the kept pose) or the last kept code (a text that goes on, as
    the clause plan starts a clause), time to arrival and count clock over the text's own
    snippets. Reading the kept start with the posterior under the new text, clocks that count
    the kept start as the text's motion, or the other first code give other codes and fail."""
    plan = dataclasses.replace(_continue_plan(pipe, walk, COUNTED), continues=continues)
    assert _continue_plan(pipe, walk).continues is False  # continue's text is a new one
    unit = pipe.spec.snippet_length
    known = known_prefix_snippets(plan, unit)
    total = plan.num_frames // unit
    assert known == 10 and free_snippets(plan, unit, known) == total - known
    settings = SearchSettings(method="posterior", candidates=1)
    parts = _parts(pipe, plan, known)
    assert len(parts[0]) == 1  # the tiny models never trained "stands still": no settling
    (found,) = search._search(
        pipe, [plan], parts, plan.num_frames, known, torch.Generator().manual_seed(4), settings, 0
    )
    vae = pipe.vae
    with torch.no_grad():
        source = torch.from_numpy(plan.source_features[: known * unit]).float()[None]
        normalised = pipe.normalizer.normalize(source)[..., : pipe.encoder_input_size]
        known_codes = pipe.encoder(normalised)  # (1, K, C)
        assert not torch.allclose(known_codes[:, -1], pipe.initial_code)  # the starts differ
        (encoded,) = [item.encoded for item in pipe.prepare([COUNTED])]
        assert encoded.count == 3
        words, pos, lengths = text_batch([encoded], pipe.device, pipe.dtype)
        word_features, sentence, mask = vae.encode_text(words, pos, lengths)
        noise = torch.randn(
            1, total - known, vae.config.latent_size, generator=torch.Generator().manual_seed(4)
        )
        made = vae.generate(
            word_features,
            sentence,
            mask,
            torch.tensor([total - known]),
            noise=noise,
            state=vae.initial_state(
                sentence, known_codes[:, -1] if continues else pipe.initial_code
            ),
            counts=torch.tensor([encoded.count]),
        )
        decoded = pipe.decoder(torch.cat([known_codes, made], dim=1)).float()
        expected = pipe.normalizer.denormalize(decoded)[0].numpy()
    np.testing.assert_allclose(found[0], expected, rtol=1e-4, atol=1e-4)


def test_only_the_last_kept_snippets_shape_what_follows(pipe, walk):
    """Two sources that differ only in their first second give the same regenerated part past
    the convolutions' reach: the kept start's earlier motion does not steer the text's part
    (it did when the posterior read the whole kept start)."""
    other = walk.copy()
    rng = np.random.default_rng(0)
    other[:20] += rng.normal(0.0, 0.05, size=other[:20].shape)  # the first second only
    settings = SearchSettings(method="posterior", candidates=1)
    parts = []
    for joints in (walk, other):
        plan = _continue_plan(pipe, joints)
        known = known_prefix_snippets(plan, pipe.spec.snippet_length)
        (found,) = search._search(
            pipe,
            [plan],
            _parts(pipe, plan, known),
            plan.num_frames,
            known,
            torch.Generator().manual_seed(2),
            settings,
            0,
        )
        parts.append(found[0])
    kept = 40
    assert not np.allclose(parts[0][:20], parts[1][:20])  # the sources do differ
    np.testing.assert_allclose(parts[0][kept + 8 :], parts[1][kept + 8 :], atol=1e-5)


def test_the_texts_stretch_ends_at_a_kept_end(pipe, walk):
    unit = pipe.spec.snippet_length
    inbetween = EditRequest(
        "inbetween", TEXT, walk, keep_start=1.0, keep_end=1.0, seconds=5.0
    ).plan(pipe.spec)
    known = known_prefix_snippets(inbetween, unit)
    assert known == 5
    assert free_snippets(inbetween, unit, known) == 25 - 5 - 5  # up to the kept last second
    body = EditRequest("body", TEXT, walk, part="lower").plan(pipe.spec)
    assert free_snippets(body, unit, 0) == body.num_frames // unit


def test_compose_goes_on_with_a_line_and_starts_a_new_line_afresh(pipe, monkeypatch):
    """compose's windows: the next window of one line goes on with it (fed the last code), a
    new line's first window starts as its caption does."""
    import t2m.edit
    from t2m.edit.modes import Segment

    seen = []
    original = t2m.edit.generate_plans

    def recording(pipe, plans, generator, settings):
        seen.append([(plan.text, plan.continues) for plan in plans])
        return original(pipe, plans, generator, settings)

    monkeypatch.setattr(t2m.edit, "generate_plans", recording)
    timeline = [Segment("a person walks forward", 0, 60), Segment("a person jumps", 60, 300)]
    settings = SearchSettings(candidates=1)
    t2m.edit.compose(pipe, timeline, 1, torch.Generator().manual_seed(0), settings)
    # windows: 60 from rest, then the jump's 156 after 2 s of the walk, then its last 84
    assert seen == [
        [("a person walks forward", False)],
        [("a person jumps", False)],
        [("a person jumps", True)],
    ]
