"""Motion sources: each turns files into joints (T, 22 or 52, 3), y-up, metres, plus fps.

A source module exposes a loader returning a :class:`Motion`. ``build`` enumerates
:class:`ClipTask` items (one per output clip) so that the work can be split across processes; a
task names a file and, optionally, the slice of it that makes the clip.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

# Frame rates a source may have: below 1 fps resampling to 20 fps would multiply the frames
# without bound; above 10 kHz no capture system records.
MIN_FPS, MAX_FPS = 1.0, 10_000.0


def fps_problem(fps: float) -> str | None:
    """Why ``fps`` is not a usable frame rate (not a number in [MIN_FPS, MAX_FPS]), or None."""
    if isinstance(fps, bool) or not isinstance(fps, (int, float)):
        return f"frame rate must be a number, got {fps!r}"
    if not (MIN_FPS <= fps <= MAX_FPS):  # also refuses NaN
        return f"frame rate must be between {MIN_FPS:g} and {MAX_FPS:g}, got {fps:g}"
    return None


class ClipError(ValueError):
    """A problem with one clip's data (unreadable or corrupt file, NaN frames, too few frames,
    a skeleton no mapping fits, unusable captions): the build reports the clip and skips it.

    Anything else raised while building a clip is a bug and stops the build with its traceback.
    """


@dataclass
class Motion:
    """Joint positions read from one source file.

    Attributes:
        joints: (T, J, 3) float array, J = 22 (SMPL body) or 52 (SMPL-H), y-up, metres.
        fps: frame rate of ``joints``.
        metadata: free-form facts about the file (gender, skeleton name, dropped frames, ...).
    """

    joints: np.ndarray
    fps: float
    metadata: dict = field(default_factory=dict)


@dataclass(frozen=True)
class ClipTask:
    """One output clip: which file, which part of it, and the per-clip rules.

    Attributes:
        name: output clip name (no extension); its mirror is ``humanml3d.mirror_name(name)``.
        path: source file.
        segmented: the clip is cut by an index (``start_frame``/``end_frame`` at 20 fps after
            ``trim_seconds``, end exclusive, ``None`` = to the end); otherwise it is the whole
            motion, cropped when too long.
        trim_seconds: seconds dropped from the start before segmenting (reference-pipeline rule).
        negate_x: negate x before mirroring (reference-pipeline rule for its intermediate layout).
        caption_path: the clip's caption file, or ``None`` when it has none.
    """

    name: str
    path: str
    segmented: bool = False
    start_frame: int = 0
    end_frame: int | None = None
    trim_seconds: float = 0.0
    negate_x: bool = False
    caption_path: str | None = None
