"""Presets sized in optimiser steps: the same steps on any dataset size, the demo corpus' own
schedule unchanged, and the log that says how many steps a stage takes."""

from __future__ import annotations

import json
import logging

import numpy as np
import pytest

from t2m.config import apply_overrides
from t2m.data.dataset import epoch_batches
from t2m.presets import PRESETS, preset
from t2m.train import train_stage
from t2m.train.generator import curriculum_lengths
from t2m.train.stage import step_sized_batches

DEMO_TRAIN_CLIPS = 3200
"""The demo corpus' training split: 2,000 clips and their mirrors, 80% of them."""


def _stage_steps(config, name: str, train_clips: int) -> int:
    """Optimiser steps a stage of ``config`` takes on ``train_clips`` (the generator at most)."""
    section = getattr(config, name)
    if name == "generator":
        epochs = len(curriculum_lengths(section)) * section.max_stage_epochs
        epochs += section.final_epochs
    else:
        epochs = section.epochs
    batches = step_sized_batches(train_clips, section.batch_size, 0, 0, section.epoch_steps)
    return epochs * len(batches)


@pytest.mark.parametrize("name", ["autoencoder", "length", "generator", "evaluator"])
def test_demo_preset_trains_as_many_steps_on_400_or_20000_clips(name):
    config = preset("demo")
    steps = {clips: _stage_steps(config, name, clips) for clips in (320, 3200, 16000)}
    assert len(set(steps.values())) == 1, steps
    expected = {"autoencoder": 2000, "length": 1250, "generator": 2500, "evaluator": 800}
    assert steps[3200] == expected[name]


@pytest.mark.parametrize("name", ["autoencoder", "length", "generator", "evaluator"])
def test_demo_corpus_keeps_its_schedule_batch_for_batch(name):
    """On the demo corpus' 3,200 training clips an epoch is still one pass, the same batches as
    before the preset was sized in steps (so make demo trains exactly what it trained)."""
    section = getattr(preset("demo"), name)
    assert section.epoch_steps * section.batch_size == DEMO_TRAIN_CLIPS
    for epoch in (0, 1, 7):
        sized = step_sized_batches(
            DEMO_TRAIN_CLIPS, section.batch_size, 0, epoch, section.epoch_steps
        )
        passes = epoch_batches(DEMO_TRAIN_CLIPS, section.batch_size, 0, epoch)
        assert len(sized) == len(passes)
        assert all(np.array_equal(a, b) for a, b in zip(sized, passes, strict=True))


def test_step_sized_epochs_walk_through_consecutive_passes():
    # 10 items, batches of 3: 3 batches a pass (one item left out of each)
    first = step_sized_batches(10, 3, seed=4, epoch=0, epoch_steps=5)
    second = step_sized_batches(10, 3, seed=4, epoch=1, epoch_steps=5)
    passes = [epoch_batches(10, 3, 4, number) for number in range(4)]
    flat = [batch for one in passes for batch in one]
    assert [b.tolist() for b in first + second] == [b.tolist() for b in flat[:10]]
    for batch in first:  # each batch within one pass: no item twice
        assert len(set(batch.tolist())) == 3
    # a large split is passed over in part: every batch distinct
    part = step_sized_batches(1000, 10, seed=0, epoch=0, epoch_steps=4)
    assert len(part) == 4 and len(np.unique(np.concatenate(part))) == 40
    assert step_sized_batches(2, 3, seed=0, epoch=0, epoch_steps=5) == []


def test_every_preset_states_how_its_epochs_are_sized():
    for name in PRESETS:
        config = preset(name)
        for section in config.stage_sections().values():
            assert section.epoch_steps >= 0
    assert preset("demo").sized_for_clips == DEMO_TRAIN_CLIPS
    with pytest.raises(ValueError, match="epoch_steps"):
        apply_overrides(preset("tiny"), {"autoencoder.epoch_steps": "-1"})


def test_training_log_gives_the_steps_and_warns_on_a_small_split(
    tiny_dataset, tiny_config, tmp_path, caplog
):
    """A stage sized in steps takes epochs x epoch_steps steps on the tiny dataset's 32 training
    items (28 clips, 4 timed sub-clips), says so first, and warns that they are under a quarter
    of the split the config was sized on."""
    config = apply_overrides(
        tiny_config,
        {"autoencoder.epoch_steps": "3", "autoencoder.epochs": "2", "sized_for_clips": "200"},
    )
    with caplog.at_level(logging.INFO, logger="t2m.train"):
        folder = train_stage("autoencoder", config, tiny_dataset, tmp_path / "run")
    finished = json.loads((folder / "finished.json").read_text())
    assert finished["step"] == 6 and finished["epoch"] == 2
    messages = [record.getMessage() for record in caplog.records]
    assert any("autoencoder will take 6 optimiser steps: 2 epochs" in m for m in messages)
    assert any("32 training items" in m and "3 steps an epoch" in m for m in messages)
    warnings = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    assert any("under a quarter of the 200" in m for m in warnings), warnings
