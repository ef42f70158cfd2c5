"""The dataset spec: its values, round trip and lookups, old config files, and a KIT-ML-shaped
dataset (21 joints, 251-d features, 12.5 fps) read, trained on, stored and sampled at its own
frame rate."""

from __future__ import annotations

import json
import logging
from pathlib import Path

import numpy as np
import pytest
from conftest import CAPTIONS, KINDS
from PIL import Image

from dataset_tools.skeleton import KIT, SMPL
from dataset_tools.spec import HUMANML3D, KIT_ML, DatasetSpec, spec_for_dim, spec_for_folder
from t2m.config import apply_overrides, from_dict
from t2m.data.dataset import MotionTextData, load_split
from t2m.data.normalization import Normalizer
from t2m.data.words import BUILTIN_GLOVE, load_vectorizer
from t2m.models.autoencoder import check_snippet_length
from t2m.pipeline import frames_for, frames_for_seconds
from t2m.presets import tiny


def test_known_specs_round_trip_and_are_found_by_dimension(tmp_path):
    assert (HUMANML3D.skeleton, HUMANML3D.num_joints, HUMANML3D.feature_dim) == (SMPL, 22, 263)
    assert (HUMANML3D.fps, HUMANML3D.snippet_length) == (20.0, 4)
    assert (HUMANML3D.min_frames, HUMANML3D.max_frames, HUMANML3D.length_limit) == (40, 196, 200)
    assert (KIT_ML.skeleton, KIT_ML.num_joints, KIT_ML.feature_dim) == (KIT, 21, 251)
    assert (KIT_ML.fps, KIT_ML.min_frames, KIT_ML.max_snippets) == (12.5, 24, 49)
    assert KIT_ML.layout.dim == 251 and KIT_ML.layout.foot_contact == slice(247, 251)
    for spec in (HUMANML3D, KIT_ML):
        stored = json.loads(json.dumps(spec.to_dict()))  # plain values, as in a checkpoint
        assert DatasetSpec.from_dict(stored) == spec
        assert spec_for_dim(spec.feature_dim) is spec
    with pytest.raises(ValueError, match="no known dataset has 100-d features"):
        spec_for_dim(100)
    bad = [
        ({**KIT_ML.to_dict(), "skeleton": "horse"}, "unknown skeleton 'horse'"),
        ({**KIT_ML.to_dict(), "snippet_length": 3}, "multiple of snippet_length"),
        ({**KIT_ML.to_dict(), "min_frames": 2.5}, "min_frames must be a whole number"),
        ({**KIT_ML.to_dict(), "fps": 0}, "fps must be positive"),
        ({**KIT_ML.to_dict(), "length_limit": 196}, "max_frames < length_limit"),
        ({"name": "x"}, "missing"),
    ]
    for values, message in bad:
        with pytest.raises(ValueError, match=message):
            DatasetSpec.from_dict(values)
    # a folder is known by the size of its Mean.npy
    np.save(tmp_path / "Mean.npy", np.zeros(251, np.float32))
    assert spec_for_folder(tmp_path) is KIT_ML
    np.save(tmp_path / "Mean.npy", np.zeros(100, np.float32))
    with pytest.raises(ValueError, match="Mean.npy: no known dataset has 100-d"):
        spec_for_folder(tmp_path)
    with pytest.raises(ValueError, match="no Mean.npy"):
        spec_for_folder(tmp_path / "missing")


def test_snippet_length_is_the_autoencoders_and_old_config_files_still_load():
    check_snippet_length(4)
    with pytest.raises(ValueError, match="codes snippets of 4 frames"):
        check_snippet_length(8)
    # config.json of earlier releases: the frame settings they fixed are read and dropped ...
    old = tiny().to_dict()
    old["data"].update(unit_length=4, min_frames=40, max_frames=196, length_limit=200)
    assert from_dict(old) == tiny()
    # ... and one the models would no longer follow is refused
    old["data"]["max_frames"] = 100
    with pytest.raises(ValueError, match="data.max_frames=100.*dataset"):
        from_dict(old)


def test_frame_rounding_follows_the_spec():
    assert frames_for(10, KIT_ML) == 24 and frames_for(10) == 40  # the shortest motion
    assert frames_for(1000, KIT_ML) == 196
    assert frames_for_seconds(4.0, KIT_ML) == 52  # 50 frames at 12.5 fps, rounded up to 4
    assert frames_for_seconds(4.0) == 80


def build_kit_dataset(out: Path, num_clips: int = 30, seed: int = 0) -> Path:
    """A KIT-ML-shaped HumanML3D-layout folder: smooth random 251-d features (the spec, the
    normalisation and the frame limits are what is tested, not the motions) with captions."""
    rng = np.random.default_rng(seed)
    for sub in ("new_joint_vecs", "texts"):
        (out / sub).mkdir(parents=True, exist_ok=True)
    names, features = [], []
    for index in range(num_clips):
        kind = KINDS[index % len(KINDS)]
        frames = 30 if index == 0 else int(rng.integers(50, 110))  # 30: under HumanML3D's 40
        motion = np.cumsum(rng.normal(scale=0.1, size=(frames, 251)), axis=0)
        motion += np.sin(np.arange(frames) / 5.0)[:, None] * (1 + index % len(KINDS))
        name = f"{index:06d}"
        np.save(out / "new_joint_vecs" / f"{name}.npy", motion.astype(np.float32))
        lines = [f"{text}#{tokens}#0.0#0.0" for text, tokens in CAPTIONS[kind]]
        if index == 1:  # a timed caption: 2.0 s is 25 frames at 12.5 fps
            lines.append(f"{CAPTIONS[kind][0][0]}#{CAPTIONS[kind][0][1]}#0.0#2.0")
        (out / "texts" / f"{name}.txt").write_text("\n".join(lines) + "\n")
        names.append(name)
        features.append(motion)
    stacked = np.concatenate(features)
    np.save(out / "Mean.npy", stacked.mean(0).astype(np.float32))
    np.save(out / "Std.npy", np.maximum(stacked.std(0), 1e-3).astype(np.float32))
    splits = {"train": names[:20], "val": names[20:25], "test": names[25:]}
    for split, members in splits.items():
        (out / f"{split}.txt").write_text("\n".join(members) + "\n")
    return out


@pytest.fixture(scope="module")
def kit_dataset(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return build_kit_dataset(tmp_path_factory.mktemp("kit_dataset"))


def test_a_kit_dataset_is_read_at_its_rate(kit_dataset):
    assert spec_for_folder(kit_dataset) is KIT_ML
    clips = load_split(kit_dataset, "train")
    names = {clip.name: clip for clip in clips}
    assert len(names["000000"].motion) == 30  # kept: KIT-ML's clips start at 24 frames
    assert len(names["000001#0.0#2.0"].motion) == 25  # 2 s at 12.5 fps
    with pytest.raises(ValueError, match="251-d features, HumanML3D has 263"):
        load_split(kit_dataset, "train", spec=HUMANML3D)
    normalizer = Normalizer.from_dataset(kit_dataset)
    assert normalizer.dim == 251
    data = MotionTextData(clips, normalizer, load_vectorizer(BUILTIN_GLOVE))
    assert data.spec is KIT_ML
    batch = data.length_batch(np.arange(len(data)), np.random.default_rng(0))
    expected = np.minimum(data.lengths, 196) // 4
    assert np.array_equal(batch["length_class"].numpy(), expected)


def test_a_kit_run_stores_its_spec_and_samples_at_its_frame_rate(kit_dataset, tmp_path):
    from t2m.outputs import sample_to_folder
    from t2m.pipeline import TextToMotion
    from t2m.prompts import Prompt
    from t2m.train import STAGE_NAMES, load_stage, train_stage
    from t2m.train.checkpoint import atomic_save, checkpoint_spec, read_checkpoint

    logging.getLogger("t2m").setLevel(logging.WARNING)
    config = apply_overrides(
        tiny(),
        {
            "device": "cpu",
            "ae.epochs": "1",
            "length.epochs": "1",
            "eval.epochs": "1",
            "t2m.end_snippets": "10",
        },
    )
    run_dir = tmp_path / "run"
    for stage in STAGE_NAMES:
        if stage != "evaluator":
            train_stage(stage, config, kit_dataset, run_dir)
    generator = load_stage(run_dir, "generator")
    assert generator.spec == KIT_ML and generator.dims.feature_dim == 251
    # a checkpoint written before specs were stored loads as the spec of its feature dimension
    path = run_dir / "length" / "best.pt"
    checkpoint = read_checkpoint(path)
    assert DatasetSpec.from_dict(checkpoint["spec"]) == KIT_ML
    del checkpoint["spec"]
    atomic_save(checkpoint, path)
    assert checkpoint_spec(checkpoint) == KIT_ML and load_stage(run_dir, "length").spec == KIT_ML

    pipe = TextToMotion.from_checkpoints(run_dir)
    assert pipe.spec == KIT_ML
    motion = pipe.generate("a person walks forward", lengths=10, seed=0)[0][0]
    assert motion.joints.shape == (24, 21, 3) and motion.features.shape == (24, 251)
    out = sample_to_folder(pipe, [Prompt("a person jumps", 30)], tmp_path / "out", render="gif")
    summary = json.loads((out / "results.json").read_text())
    assert summary["fps"] == 12.5 and summary["lengths"] == [[32]]
    with Image.open(out / "sample00_rep00.gif") as gif:
        assert gif.info["duration"] == 80  # ms per frame at 12.5 fps
