"""An inbetween draws ``SearchSettings.end_draws`` times the candidates: the draw whose decoded
end lies nearest the kept end needs the least bending of its path."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from t2m.edit.core import SearchSettings, has_kept_end
from t2m.edit.plan import EditPlan

FRAMES = 64


def _plan(kept_rows: slice | list[int], joints: slice | list[int] = slice(None)) -> EditPlan:
    keep = np.zeros((FRAMES, 22), bool)
    keep[kept_rows, joints] = True
    target = np.full((FRAMES, 22, 3), np.nan)
    source = np.zeros((FRAMES, 263))
    return EditPlan("a person walks", FRAMES, target, keep, source_features=source)


def test_only_a_kept_end_without_optimisation_draws_more():
    ends = _plan([*range(8), *range(FRAMES - 8, FRAMES)])  # inbetween
    start = _plan(slice(0, 8))  # continue
    body = _plan(slice(None), [0, 1, 2])  # a kept body part on every frame
    assert has_kept_end(ends) and not has_kept_end(start) and not has_kept_end(body)
    settings = SearchSettings(candidates=8)
    assert settings.draws([ends], steps=0) == 24 and settings.draws([start, ends], 0) == 24
    assert settings.draws([start], 0) == 8 and settings.draws([body], 0) == 8
    assert settings.draws([ends], steps=20) == 8  # optimised: the search meets the end itself
    assert SearchSettings(method="best_of_n", candidates=8).draws([ends], 0) == 8  # baseline
    assert SearchSettings(candidates=8, end_draws=1).draws([ends], 0) == 8
    with pytest.raises(ValueError, match="end_draws"):
        SearchSettings(end_draws=0)


def test_an_inbetween_search_draws_and_chooses_among_the_extra_draws(pipe, monkeypatch):
    """The search's noise batch holds candidates x end_draws rollouts per inbetween, and the one
    it keeps is the nearest the kept end among all of them."""
    from conftest import synth_joints

    import t2m.edit.core as core
    from t2m.edit import edit

    seen = []
    randn = torch.randn

    def recording(*size, **options):
        seen.append(size[0] if len(size) > 1 else size[0][0])
        return randn(*size, **options)

    monkeypatch.setattr(core.torch, "randn", recording)
    errors = []
    search = core._search

    def keeping(*args, **options):
        found = search(*args, **options)
        errors.extend(error for _, error in found)
        return found

    monkeypatch.setattr(core, "_search", keeping)
    source = synth_joints("walk_forward", 97, np.random.default_rng(3))
    request = {"source": source, "keep_start": 1.0, "keep_end": 1.0, "seconds": 4.8}
    for end_draws in (1, 3):
        settings = SearchSettings(method="posterior", candidates=4, end_draws=end_draws)
        edit(pipe, "a person walks forward", "inbetween", seed=2, settings=settings, **request)
    assert seen == [4, 12]
    # the first 4 of the 12 draws are the 4 of the first search (the same generator seed), so
    # the nearest of 12 is at least as near the kept end
    assert errors[1] <= errors[0]
