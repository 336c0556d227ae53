"""Float training of DeepLabV3 (CPU, one GPU, or DDP under torchrun) and the run folder it writes.

    from edgepick import Size
    from edgepick.train import TrainConfig, train
    train(TrainConfig(data="data", out="run", epochs=30, size=Size(320, 240)))
"""

from edgepick.train.checkpoint import Checkpoint, load_model
from edgepick.train.config import TrainConfig
from edgepick.train.loop import Hooks, fit, new_model, train
from edgepick.train.run import Run

__all__ = ["Checkpoint", "Hooks", "Run", "TrainConfig", "fit", "load_model", "new_model", "train"]
