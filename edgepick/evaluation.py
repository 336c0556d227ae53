"""`edgepick eval`: segmentation metrics of a checkpoint on a split, at the data's own resolution."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from edgepick.data.config import Split
from edgepick.data.native import NativeDataset
from edgepick.errors import CheckpointError
from edgepick.metrics import confusion_matrix, segmentation_metrics
from edgepick.progress import progress as progress_bar
from edgepick.runtime.engine import Engine


def evaluate(model_path: str | Path, data: str | Path, split: Split | str = Split.TEST, progress: bool = True,
             engine: Engine = Engine.ONNXRUNTIME) -> dict:
    """Pixel accuracy, per-class IoU, mIoU and confusion matrix of MODEL on DATA/<split>.

    Frames are resized to the model's input size and the labels back to the frame
    (nearest), as the runtime does (docs/contracts.md#onnx-model).
    """
    model_path = Path(model_path)
    ds = NativeDataset.open(data, split)
    if model_path.suffix == ".onnx":
        from edgepick.runtime.session import Segmenter

        seg = Segmenter(model_path, engine=engine)
        classes, predict = seg.info.classes, seg.labels
    else:
        classes, predict = _torch_predictor(model_path)
    if classes != ds.classes:
        raise CheckpointError(f"the model's classes {classes} differ from the data set's {ds.classes}")
    cm = np.zeros((len(classes), len(classes)), np.int64)
    for sid in progress_bar(ds.ids, desc=f"eval {split}", unit="img", enabled=progress):
        mask, pred = ds.mask(sid), predict(ds.rgb(sid))
        if pred.size and int(pred.max()) >= len(classes):
            raise CheckpointError(f"{model_path} predicted class id {int(pred.max())}, outside its {len(classes)} classes")
        cm += confusion_matrix(mask, pred, len(classes))
    result = segmentation_metrics(cm, classes)
    return {"model": str(model_path), "data": str(data), "split": split, "images": len(ds), **result}


def _torch_predictor(model_path: Path):
    """(classes, rgb -> labels at the frame's size) for a checkpoint, resizing like the runtime."""
    import torch

    from edgepick.train.checkpoint import load_model

    model, ckpt = load_model(model_path)
    h, w = ckpt.input_size.hw

    @torch.inference_mode()
    def predict(rgb: np.ndarray) -> np.ndarray:
        x = torch.from_numpy(cv2.resize(rgb, (w, h), interpolation=cv2.INTER_AREA)).permute(2, 0, 1)[None].float()
        labels = model(x)["out"].argmax(1)[0].numpy().astype(np.uint8)
        return cv2.resize(labels, (rgb.shape[1], rgb.shape[0]), interpolation=cv2.INTER_NEAREST)

    return list(ckpt.classes), predict
