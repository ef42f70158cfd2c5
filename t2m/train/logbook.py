"""Training records: metrics as JSON lines in the stage folder, and a PNG of the curves.

Each record is appended with one ``write`` call of the whole line, so a process killed while
writing leaves at most one torn last line; readers (:func:`read_records`, a resume) skip it.
"""

from __future__ import annotations

import io
import json
import logging
import math
import os
import time
from pathlib import Path
from typing import Any

from dataset_tools.io import write_bytes_atomic

logger = logging.getLogger(__name__)


def read_records(path: Path) -> list[dict[str, Any]]:
    """The records of a ``metrics.jsonl`` (empty when it does not exist); a line that is not a
    JSON object (the torn last line of a killed run) is skipped with a warning."""
    if not path.is_file():
        return []
    records = []
    for number, line in enumerate(path.read_text(encoding="utf-8", errors="replace").splitlines()):
        if not line.strip():
            continue
        try:
            record = json.loads(line)
        except ValueError:
            record = None
        if isinstance(record, dict):
            records.append(record)
        else:
            logger.warning("%s:%d: skipping a torn or malformed record", path, number + 1)
    return records


def _position(record: dict[str, Any]) -> tuple[int, int]:
    """(step, epoch) of a record, 0 for a value that is not an integer."""
    step, epoch = record.get("step"), record.get("epoch")
    return (step if isinstance(step, int) else 0, epoch if isinstance(epoch, int) else 0)


class Logbook:
    """Appends one JSON object per record to ``metrics.jsonl`` and redraws ``curves.png``.

    Only the main process writes; on resume, the records the checkpoint does not cover are
    dropped so the file reads as one run: those past its step, and those of its step from a later
    epoch (a validation record written just before a kill, which the resumed run writes again).
    """

    def __init__(
        self,
        stage_dir: Path,
        stage: str,
        enabled: bool = True,
        resume_step: int | None = None,
        resume_epoch: int = 0,
    ):
        self.path = stage_dir / "metrics.jsonl"
        self.curves_path = stage_dir / "curves.png"
        self.stage = stage
        self.enabled = enabled
        self.start = time.time()
        self._drawn_at = time.time()
        if not enabled:
            return
        stage_dir.mkdir(parents=True, exist_ok=True)
        if resume_step is None:
            self.path.unlink(missing_ok=True)
        elif self.path.is_file():
            kept = [
                record
                for record in read_records(self.path)
                if _position(record) <= (resume_step, resume_epoch)
            ]
            text = "".join(json.dumps(record) + "\n" for record in kept)
            write_bytes_atomic(self.path, text.encode())

    def write(self, split: str, step: int, epoch: int, values: dict[str, Any]) -> None:
        if not self.enabled:
            return
        record = {
            "stage": self.stage,
            "split": split,
            "step": step,
            "epoch": epoch,
            "elapsed_s": round(time.time() - self.start, 2),
        }
        for key, value in values.items():
            value = float(value) if not isinstance(value, (str, int)) else value
            record[key] = None if isinstance(value, float) and not math.isfinite(value) else value
        line = (json.dumps(record) + "\n").encode()
        descriptor = os.open(self.path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o666)
        try:
            written = 0
            while written < len(line):  # one call for any line of a record's size
                written += os.write(descriptor, line[written:])
        finally:
            os.close(descriptor)

    def records(self) -> list[dict[str, Any]]:
        return read_records(self.path)

    def draw(self, force: bool = True, min_interval_s: float = 60.0) -> None:
        """Plot every numeric metric against the step, train and val, one panel per metric.

        With ``force`` False, skip when the last drawing is younger than ``min_interval_s`` (the
        loops redraw after each validation; plotting costs a fraction of a second).
        """
        if not self.enabled:
            return
        if not force and time.time() - self._drawn_at < min_interval_s:
            return
        self._drawn_at = time.time()
        records = self.records()
        if not records:
            return
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        skip = {"stage", "split", "step", "epoch", "elapsed_s", "lr"}
        names = sorted(
            {
                k
                for r in records
                for k, v in r.items()
                if k not in skip and isinstance(v, (int, float))
            }
        )
        if not names:
            return
        columns = min(3, len(names))
        rows = math.ceil(len(names) / columns)
        figure, axes = plt.subplots(rows, columns, figsize=(4.5 * columns, 3 * rows), squeeze=False)
        for axis, name in zip(axes.flat, names):
            for split, style in (("train", "-"), ("val", "o-")):
                points = [
                    (r["step"], r[name])
                    for r in records
                    if r["split"] == split and isinstance(r.get(name), (int, float))
                ]
                if points:
                    xs, ys = zip(*points)
                    axis.plot(xs, ys, style, label=split, markersize=3)
            axis.set_title(name)
            axis.set_xlabel("step")
            axis.legend(fontsize=7)
        for axis in list(axes.flat)[len(names) :]:
            axis.axis("off")
        figure.suptitle(f"{self.stage} training")
        figure.tight_layout()
        buffer = io.BytesIO()
        figure.savefig(buffer, format="png", dpi=80)
        plt.close(figure)
        write_bytes_atomic(self.curves_path, buffer.getvalue())
