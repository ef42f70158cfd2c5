"""What generation gives: :class:`GeneratedMotion`, one motion with its prompt.

Its own module so that the pipeline (:mod:`t2m.pipeline`), the editor (:mod:`t2m.edit`) and the
writers (:mod:`t2m.outputs`) share it without importing each other.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class GeneratedMotion:
    """One generated motion.

    Attributes:
        text: the prompt.
        prompt_index: which prompt (0-based, in the order given).
        repetition: which sample of that prompt (0-based).
        joints: (T, J, 3) float32 positions in metres, y-up, at the dataset's fps (20 for
            HumanML3D, 12.5 for KIT-ML; ``TextToMotion.spec.fps``).
        features: (T, D) float32 de-normalised features (263-d for HumanML3D).
    """

    text: str
    prompt_index: int
    repetition: int
    joints: np.ndarray
    features: np.ndarray

    @property
    def num_frames(self) -> int:
        return int(self.joints.shape[0])
