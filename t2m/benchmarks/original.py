"""The original T2M code (github.com/EricGuo5513/text-to-motion), imported from a checkout for
the side-by-side benchmark (:mod:`t2m.benchmarks.versus_original`): its modules, the options
its trainers read, and its generation networks at the paper's sizes. Nothing of it is copied
here.
"""

from __future__ import annotations

import importlib
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import torch

FEATURES, WORD_DIM = 263, 300
"""The paper's feature size (HumanML3D) and word-vector size (GloVe 300-d)."""


def import_original(path: Path) -> SimpleNamespace:
    """The original's modules, imported from its checkout (put first on ``sys.path``)."""
    if not (path / "networks" / "modules.py").is_file():
        raise SystemExit(f"{path}: not a checkout of EricGuo5513/text-to-motion")
    sys.path.insert(0, str(path))
    # its common/quaternion.py reads np.float, removed in numpy 1.24 (it was the builtin float)
    if "float" not in np.__dict__:
        setattr(np, "float", float)  # noqa: B010 (ruff would rewrite np.float itself)
    return SimpleNamespace(
        modules=importlib.import_module("networks.modules"),
        trainers=importlib.import_module("networks.trainers"),
        motion_process=importlib.import_module("scripts.motion_process"),
        param=importlib.import_module("utils.paramUtil"),
        skeleton=importlib.import_module("common.skeleton"),
    )


def original_options(**values) -> SimpleNamespace:
    """The option namespace the original's trainers read (CPU, training, 4-frame snippets),
    with ``values`` set."""
    base = dict(device=torch.device("cpu"), is_train=True, log_dir="", unit_length=4)
    base.update(values)
    return SimpleNamespace(**base)


def original_generation_models(orig: SimpleNamespace) -> dict:
    """The original's generation networks at the paper's sizes (``train_comp_v6.build_models``)."""
    m = orig.modules
    text_size = 1024
    return dict(
        text_enc=m.TextEncoderBiGRU(WORD_DIM, 15, 512, "cpu"),
        seq_pri=m.TextDecoder(text_size, 512 + 512, 128, 1024, 1),
        seq_post=m.TextDecoder(text_size, 512 + 1024, 128, 1024, 1),
        seq_dec=m.TextVAEDecoder(text_size, 512 + 128 + 512, 512, 1024, 1),
        att_layer=m.AttLayer(1024, text_size, 512),
        mov_enc=m.MovementConvEncoder(FEATURES - 4, 512, 512),
        mov_dec=m.MovementConvDecoder(512, 512, FEATURES),
    )
