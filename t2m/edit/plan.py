"""The plan every edit mode becomes (:class:`EditPlan`), shared by the search
(:mod:`t2m.edit.core`) and the finishing (:mod:`t2m.edit.keep`)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class EditPlan:
    """One result to make (see the module docstring). ``num_frames`` is a whole number of
    snippets; arrays are on the result's timeline."""

    text: str
    num_frames: int
    target: np.ndarray  # (T, J, 3), NaN where free
    keep: np.ndarray  # (T, J) bool
    source_features: np.ndarray | None = None  # (T, D), used where keep
    source_half_yaw: np.ndarray | None = None  # (T,), used where keep[:, 0]
    # The text goes on with what the kept start does (compose's next window of one line, the
    # live stream's segments): its part is fed the last kept code, as the clause plan
    # starts a clause. Otherwise (a new text) it starts as plain generation starts a caption.
    continues: bool = False

    def kept_mask(self) -> np.ndarray:
        """(T, J) bool: joints copied from the source or given a target on each frame."""
        return self.keep | np.isfinite(self.target).any(-1)
