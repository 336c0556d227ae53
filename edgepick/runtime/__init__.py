"""Torch-free CPU runtime: onnxruntime session, mask filters, moments grasps, geometry, calibration, cameras.

Nothing under this package may import torch (tests/runtime/test_no_torch.py enforces it).
"""

import importlib
from typing import TYPE_CHECKING

_WHERE = {
    "Calibration": "calibration", "draw_overlay": "grasp", "Engine": "engine", "FolderCamera": "camera",
    "grasp_records": "grasp", "kabsch": "calibration", "ModelError": "session", "Pipeline": "pipeline",
    "RealSenseCamera": "camera", "Segmenter": "session"
}
__all__ = ["Calibration", "Engine", "FolderCamera", "ModelError", "Pipeline", "RealSenseCamera", "Segmenter",
           "draw_overlay", "grasp_records", "kabsch"]

if TYPE_CHECKING:
    from edgepick.runtime.calibration import Calibration, kabsch
    from edgepick.runtime.camera import FolderCamera, RealSenseCamera
    from edgepick.runtime.engine import Engine
    from edgepick.runtime.grasp import draw_overlay, grasp_records
    from edgepick.runtime.pipeline import Pipeline
    from edgepick.runtime.session import ModelError, Segmenter


def __getattr__(name: str) -> object:
    """The public objects are imported when first asked for, so that importing one light module of
    the package (a config, an enum) does not import onnxruntime and OpenCV."""
    if name in _WHERE:
        return getattr(importlib.import_module(f"{__name__}.{_WHERE[name]}"), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
