"""A training run's folder (docs/contracts.md#run-folder): the one place that knows its file names.

    RUN/last.pt        the latest epoch: weights, AdamW and schedule (what a resumed run continues)
    RUN/best.pt        the epoch with the best validation mIoU, without the optimizer state
    RUN/epoch_NNN.pt   copies of last.pt at the kept epochs (hybrid-QaT's switch points)
    RUN/metrics.json   the run's summary and per-epoch history
    RUN/.edgepick      the marker that says `edgepick train` made the folder (edgepick/files.py)

No torch here: the command line asks a Run about its files before importing the trainer.
"""

from __future__ import annotations

import json
import re
from dataclasses import asdict, dataclass
from pathlib import Path

from edgepick.errors import ParameterError
from edgepick.files import atomic_write

_EPOCH = re.compile(r"epoch_(\d{3,})\.pt")



@dataclass(frozen=True)
class EpochRecord:
    """One epoch of a run: metrics.json's and the checkpoint's history entry."""

    epoch: int
    loss: float
    pixel_acc: float
    miou: float | None  # None: no class of the val split was present or predicted
    per_class_iou: dict[str, float | None]
    epoch_s: float
    train_s: float
    images: int
    val_images: int
    images_per_s: float

    def to_dict(self) -> dict:
        return asdict(self)


@dataclass(frozen=True)
class TrainResult:
    """What a training run ended with (the JSON `edgepick train` prints)."""

    out: str
    epochs: int
    best_miou: float
    train_time_s: float
    last: EpochRecord | None  # the last epoch's record; None when the run has none

    def to_dict(self) -> dict:
        return {**asdict(self), "last": self.last.to_dict() if self.last else None}


class Run:
    """The folder of one training run (float, QaT or the QaT phase of hybrid-QaT)."""

    def __init__(self, path: str | Path):
        self.path = Path(path)

    def __repr__(self) -> str:
        return f"Run({str(self.path)!r})"

    @property
    def last(self) -> Path:
        return self.path / "last.pt"

    @property
    def best(self) -> Path:
        return self.path / "best.pt"

    @property
    def metrics(self) -> Path:
        return self.path / "metrics.json"

    def epoch(self, n: int) -> Path:
        """The kept checkpoint of epoch N."""
        return self.path / f"epoch_{n:03d}.pt"

    def kept_epochs(self) -> list[int]:
        """The epochs whose checkpoints the run kept, in order."""
        if not self.path.is_dir():
            return []
        return sorted(int(m.group(1)) for p in self.path.iterdir() if (m := _EPOCH.fullmatch(p.name)))

    def holds_run(self) -> bool:
        """Whether the folder holds a run that has finished at least one epoch."""
        return self.last.is_file()

    def check_new(self) -> None:
        """Refuse to start a run here when the folder holds one already (continuing it is resuming)."""
        if self.holds_run():
            raise ParameterError("{out} already holds a training run; pass {resume} or choose another {out:name}",
                                 out=self.path, resume=True)

    def write_metrics(self, summary: dict) -> None:
        self.path.mkdir(parents=True, exist_ok=True)
        atomic_write(self.metrics, json.dumps(summary, indent=1))

    def total_train_time_s(self) -> float | None:
        """The whole run's training time from metrics.json, or None when it cannot be read."""
        try:
            return float(json.loads(self.metrics.read_text())["train_time_s"])
        except (OSError, ValueError, KeyError, TypeError):
            return None


def checkpoint_path(path: str | Path) -> Path:
    """A checkpoint file as given, or a RUN folder's best.pt."""
    path = Path(path)
    return Run(path).best if path.is_dir() else path
