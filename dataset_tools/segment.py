"""Time handling of motions: resampling to the dataset rate, cropping, and index segmentation.

The reference pipeline (HumanML3D) cuts its AMASS joint arrays with an ``index.csv`` of rows
``source_path,start_frame,end_frame,new_name`` (frames at 20 fps, end exclusive, -1 = to the end),
after dropping a dataset-specific lead-in, and negates x for every row except HumanAct12 ones.
"""

from __future__ import annotations

import csv
import zlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from dataset_tools.command import UsageError

# Seconds of lead-in the reference pipeline drops before applying index frames (T-poses and
# calibration moves at the start of these captures).
LEADING_TRIM_SECONDS: dict[str, float] = {
    "Eyes_Japan_Dataset": 3.0,
    "MPI_HDM05": 3.0,
    "TotalCapture": 1.0,
    "MPI_Limits": 1.0,
    "Transitions_mocap": 0.5,
}


def resample(joints: np.ndarray, src_fps: float, dst_fps: float = 20.0) -> np.ndarray:
    """Resample (T, ...) frames from ``src_fps`` to ``dst_fps`` by linear interpolation in time.

    Output frame k is the source at time k / dst_fps, for every such time inside the source's span
    [0, (T - 1) / src_fps]; with an integer rate ratio this picks exactly every n-th frame.
    Returns (T', ...) with T' = floor((T - 1) * dst_fps / src_fps) + 1.
    """
    joints = np.asarray(joints)
    if not (np.isfinite(src_fps) and src_fps > 0 and np.isfinite(dst_fps) and dst_fps > 0):
        raise ValueError(f"frame rates must be positive, got src={src_fps} dst={dst_fps}")
    num_frames = joints.shape[0]
    if num_frames == 0:
        raise ValueError("cannot resample an empty motion")
    ratio = src_fps / dst_fps
    # The epsilon keeps a last frame that floating point would put a hair past the end.
    num_out = int(np.floor((num_frames - 1) / ratio + 1e-6)) + 1
    positions = np.arange(num_out) * ratio  # fractional source frame of each output frame
    if np.allclose(positions, np.round(positions), atol=1e-6):
        return joints[np.minimum(np.round(positions).astype(np.int64), num_frames - 1)].copy()
    lower = np.minimum(np.floor(positions).astype(np.int64), num_frames - 1)
    upper = np.minimum(lower + 1, num_frames - 1)
    weight = (positions - lower).reshape((-1,) + (1,) * (joints.ndim - 1))
    return (1.0 - weight) * joints[lower] + weight * joints[upper]


def clip_rng(name: str, seed: int) -> np.random.Generator:
    """A generator that depends only on the clip name and the build seed (not on worker order)."""
    return np.random.default_rng([seed, zlib.crc32(name.encode("utf-8"))])


def random_crop(
    joints: np.ndarray, max_frames: int, rng: np.random.Generator
) -> tuple[np.ndarray, int]:
    """Crop (T, ...) to at most ``max_frames`` at a random start; returns (crop, start frame)."""
    if joints.shape[0] <= max_frames:
        return joints, 0
    start = int(rng.integers(0, joints.shape[0] - max_frames + 1))
    return joints[start : start + max_frames], start


def trim_seconds_for(source_path: str) -> float:
    """Lead-in seconds the reference pipeline drops for this AMASS sub-dataset path (0 if none)."""
    # A substring test, as the reference pipeline does.
    for dataset, seconds in LEADING_TRIM_SECONDS.items():
        if dataset in source_path:
            return seconds
    return 0.0


@dataclass(frozen=True)
class IndexRow:
    """One row of a segmentation index (frames at 20 fps, end exclusive; None = to the end)."""

    source_path: str
    start_frame: int
    end_frame: int | None
    new_name: str

    @property
    def is_humanact12(self) -> bool:
        return "humanact12" in self.source_path.lower()


def read_index(path: str | Path) -> list[IndexRow]:
    """Read an ``index.csv`` (``source_path,start_frame,end_frame,new_name``).

    Raises UsageError (a ValueError) naming the file, and the line where there is one, for a
    file that is not UTF-8 CSV, a missing column, a non-integer or negative start frame, or an
    end frame (other than -1) before its start.
    """
    path = Path(path)
    rows: list[IndexRow] = []
    try:
        with path.open(newline="", encoding="utf-8") as handle:
            reader = csv.DictReader(handle)
            missing = {"source_path", "start_frame", "end_frame", "new_name"} - set(
                reader.fieldnames or []
            )
            if missing:
                raise UsageError(f"{path}: index is missing column(s) {sorted(missing)}")
            for line_number, row in enumerate(reader, start=2):
                try:
                    start, end = int(row["start_frame"]), int(row["end_frame"])
                except (TypeError, ValueError):
                    raise UsageError(f"{path}:{line_number}: frames must be integers") from None
                if start < 0 or (end >= 0 and end <= start):
                    raise UsageError(
                        f"{path}:{line_number}: frames {start}..{end} are not a segment "
                        "(start >= 0, end > start or -1)"
                    )
                name = Path(row["new_name"] or "").stem
                rows.append(
                    IndexRow(row["source_path"] or "", start, None if end < 0 else end, name)
                )
    except (UnicodeDecodeError, csv.Error) as error:
        raise UsageError(f"{path}: not a UTF-8 CSV index ({error})") from None
    return rows


def cut_segment(
    joints: np.ndarray,
    start_frame: int,
    end_frame: int | None,
    trim_seconds: float = 0.0,
    negate_x: bool = False,
    fps: float = 20.0,
) -> np.ndarray:
    """Cut an index segment out of (T, J, 3) frames at ``fps`` the way the reference pipeline does.

    First ``trim_seconds`` are dropped, then ``[start_frame:end_frame]`` is taken (end exclusive,
    ``None`` = to the end), then x is negated when asked. Returns a new (T', J, 3) array.
    """
    trim = int(round(trim_seconds * fps))
    cut = np.array(np.asarray(joints)[trim:][start_frame:end_frame], copy=True)
    if negate_x:
        cut[..., 0] *= -1
    return cut
