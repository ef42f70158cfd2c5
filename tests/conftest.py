"""Shared fixtures: a tiny HumanML3D-layout dataset and a run of all four stages at ``tiny``.

``tiny_dataset`` builds a few dozen procedural clips (walking forward or backward, turning,
raising an arm, jumping) with numpy forward kinematics, runs them through
``dataset_tools.representation.process_motion`` and writes captions as tagged HumanML3D lines
(``caption#word/POS ...#from#to``), so it needs neither spaCy nor the demo corpus.
``tiny_run`` trains the four stages at the ``tiny`` preset into a temporary run folder;
sampling and evaluation tests reuse it.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import pytest

SHARED = Path(__file__).resolve().parents[1].parent / "shared"


def pytest_report_header(config) -> str:
    """The CPU and the kernels it runs (the suite's tolerances hold on every x86-64 CPU; a
    failure report says which one it came from)."""
    from t2m.hardware import cpu_description

    return f"cpu: {cpu_description()}"


# kind -> captions as (text, tagged tokens); the tags are what spaCy + HumanML3D rules produce.
CAPTIONS: dict[str, list[tuple[str, str]]] = {
    "walk_forward": [
        ("a person walks forward", "a/DET person/NOUN walk/VERB forward/ADV"),
        ("someone walks straight ahead", "someone/PRON walk/VERB straight/ADV ahead/ADV"),
    ],
    "walk_backward": [
        ("a person walks backward", "a/DET person/NOUN walk/VERB backward/ADV"),
        ("someone steps back slowly", "someone/PRON step/VERB back/ADV slowly/ADV"),
    ],
    "turn_left": [
        ("a person turns to the left", "a/DET person/NOUN turn/VERB to/ADP the/DET left/NOUN"),
        ("someone spins around", "someone/PRON spin/VERB around/ADV"),
    ],
    "raise_left_arm": [
        ("a person raises the left arm", "a/DET person/NOUN raise/VERB the/DET left/ADJ arm/NOUN"),
        ("someone lifts a hand up", "someone/PRON lift/VERB a/DET hand/NOUN up/ADV"),
    ],
    "jump": [
        ("a person jumps up and down", "a/DET person/NOUN jump/VERB up/ADV and/CCONJ down/ADV"),
        ("someone hops in place", "someone/PRON hop/VERB in/ADP place/NOUN"),
    ],
}
KINDS = tuple(CAPTIONS)
FPS = 20.0


def synth_joints(kind: str, frames: int, rng: np.random.Generator) -> np.ndarray:
    """Joint positions (frames, 22, 3), y-up metres at 20 fps, of one procedural motion."""
    from dataset_tools.kinematics import forward_kinematics
    from dataset_tools.rotations import axis_angle_to_quat, qmul, yaw_quat
    from dataset_tools.skeleton import SMPL

    t = np.arange(frames) / FPS
    rate = rng.uniform(0.8, 1.4)  # steps per second
    phase = np.sin(2 * np.pi * rate * t + rng.uniform(0, 2 * np.pi))
    axis_angles = np.zeros((frames, 22, 3))
    heading = np.full(frames, rng.uniform(-np.pi, np.pi))
    root = np.zeros((frames, 3))
    speed = rng.uniform(0.8, 1.3)
    if kind in ("walk_forward", "walk_backward"):
        direction = 1.0 if kind == "walk_forward" else -0.6
        axis_angles[:, 1, 0] = 0.5 * phase  # hips swing about x, in opposition
        axis_angles[:, 2, 0] = -0.5 * phase
        axis_angles[:, 4, 0] = 0.4 * (1 + phase)  # knees bend
        axis_angles[:, 5, 0] = 0.4 * (1 - phase)
        axis_angles[:, 16, 0] = -0.3 * phase  # arms swing
        axis_angles[:, 17, 0] = 0.3 * phase
        distance = np.cumsum(np.full(frames, direction * speed / FPS))
        root[:, 0] = distance * np.sin(heading)
        root[:, 2] = distance * np.cos(heading)
    elif kind == "turn_left":
        heading = heading + np.linspace(0, rng.uniform(1.5, 3.0), frames)
        axis_angles[:, 1, 0] = 0.2 * phase
        axis_angles[:, 2, 0] = -0.2 * phase
    elif kind == "raise_left_arm":
        lift = np.clip(np.sin(np.pi * t / t[-1]) * 1.5, 0, None)
        axis_angles[:, 16, 2] = -lift  # left shoulder about z raises the arm sideways
        axis_angles[:, 18, 2] = -0.3 * lift
    elif kind == "jump":
        hop = np.maximum(0.0, np.sin(2 * np.pi * rate * t)) * 0.25
        root[:, 1] = hop
        axis_angles[:, 4, 0] = 0.6 * (0.25 - hop)
        axis_angles[:, 5, 0] = 0.6 * (0.25 - hop)
    local = axis_angle_to_quat(axis_angles)
    local[:, 0] = qmul(yaw_quat(heading), local[:, 0])
    offsets = SMPL.offsets
    joints = forward_kinematics(local, root, offsets, SMPL)
    joints[..., 1] += 0.95 - joints[:, :, 1].min()  # stand on the floor
    return joints.astype(np.float32)


def build_tiny_dataset(out: Path, num_clips: int = 40, seed: int = 0) -> Path:
    """Write a HumanML3D-layout folder of ``num_clips`` procedural clips (plus mirrors)."""
    from dataset_tools.representation import FeatureLayout, process_motion

    rng = np.random.default_rng(seed)
    for sub in ("new_joint_vecs", "new_joints", "texts"):
        (out / sub).mkdir(parents=True, exist_ok=True)
    names, all_features = [], []
    for index in range(num_clips):
        kind = KINDS[index % len(KINDS)]
        frames = int(rng.integers(50, 130))
        features, joints = process_motion(synth_joints(kind, frames, rng))
        name = f"{index:06d}"
        np.save(out / "new_joint_vecs" / f"{name}.npy", features.astype(np.float32))
        np.save(out / "new_joints" / f"{name}.npy", joints.astype(np.float32))
        lines = [f"{text}#{tokens}#0.0#0.0" for text, tokens in CAPTIONS[kind]]
        if index % 7 == 3:  # a timed caption: its own sub-clip
            lines.append(f"{CAPTIONS[kind][0][0]}#{CAPTIONS[kind][0][1]}#0.0#2.2")
        (out / "texts" / f"{name}.txt").write_text("\n".join(lines) + "\n")
        names.append(name)
        all_features.append(features)
    stacked = np.concatenate(all_features)
    layout = FeatureLayout(22)
    std = stacked.std(0)
    for _, group in layout.groups():  # pooled per group, as HumanML3D's Std.npy
        std[group] = max(std[group].mean(), 1e-3)
    np.save(out / "Mean.npy", stacked.mean(0).astype(np.float32))
    np.save(out / "Std.npy", std.astype(np.float32))
    order = list(names)
    splits = {
        "train": order[: int(0.7 * num_clips)],
        "val": order[int(0.7 * num_clips) : int(0.85 * num_clips)],
        "test": order[int(0.85 * num_clips) :],
    }
    splits["train_val"] = splits["train"] + splits["val"]
    splits["all"] = order
    for split, members in splits.items():
        (out / f"{split}.txt").write_text("\n".join(members) + "\n")
    return out


@pytest.fixture(scope="session")
def tiny_dataset(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A HumanML3D-layout folder of 40 procedural clips (28 train, 6 val, 6 test)."""
    return build_tiny_dataset(tmp_path_factory.mktemp("tiny_dataset"))


@pytest.fixture(scope="session")
def tiny_config():
    """The ``tiny`` preset with the built-in 50-d GloVe vectors, single-threaded, on CPU."""
    from t2m.config import apply_overrides
    from t2m.presets import tiny

    return apply_overrides(tiny(), {"device": "cpu"})


@pytest.fixture(scope="session")
def tiny_run(tiny_dataset: Path, tiny_config, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A run folder with all four stages trained at ``tiny`` (autoencoder, length, generator,
    evaluator)."""
    from t2m.train import STAGE_NAMES, train_stage

    logging.getLogger("t2m").setLevel(logging.WARNING)
    run_dir = tmp_path_factory.mktemp("tiny_run")
    for stage in STAGE_NAMES:
        train_stage(stage, tiny_config, tiny_dataset, run_dir)
    return run_dir


@pytest.fixture(scope="module")
def pipe(tiny_run: Path):
    """The tiny run's pipeline on the CPU (one per test module: a test may patch it)."""
    from t2m.pipeline import TextToMotion

    return TextToMotion.from_checkpoints(tiny_run, device="cpu")


@pytest.fixture(scope="module")
def server(pipe, tiny_run: Path, tmp_path_factory: pytest.TempPathFactory):
    """The web app's server for :func:`pipe` on a free port of 127.0.0.1, in a thread."""
    from t2m.serve.server import make_server

    server = make_server(pipe, str(tiny_run), port=0, work_dir=tmp_path_factory.mktemp("work"))
    server.start_in_thread()
    yield server
    server.shutdown_app()
