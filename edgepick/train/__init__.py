"""Float training of a segmentation model (CPU, one GPU, or DDP under torchrun) and the run folder it writes.

    from edgepick import Size
    from edgepick.train import TrainConfig, train
    train(TrainConfig(data="data", out="run", epochs=30, size=Size(320, 240)))
"""

from typing import TYPE_CHECKING

from edgepick.lazy import lazy_attributes

_WHERE = {
    "Checkpoint": "checkpoint", "Device": "config", "EpochRecord": "run", "fit": "loop", "Hooks": "loop",
    "load_model": "checkpoint", "new_model": "loop", "resume_run": "loop", "Run": "run", "train": "loop",
    "TrainConfig": "config", "TrainResult": "run"
}
__all__ = sorted(_WHERE)

if TYPE_CHECKING:
    from edgepick.train.checkpoint import Checkpoint, load_model
    from edgepick.train.config import Device, TrainConfig
    from edgepick.train.loop import Hooks, fit, new_model, resume_run, train
    from edgepick.train.run import EpochRecord, Run, TrainResult


__getattr__ = lazy_attributes(__name__, _WHERE)
