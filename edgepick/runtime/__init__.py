"""Torch-free CPU runtime: onnxruntime session, mask filters, moments grasps, geometry, calibration, cameras.

Nothing under this package may import torch (tests/runtime/test_no_torch.py enforces it).

    from edgepick.runtime import Calibration, FolderCamera, Pipeline, Segmenter
"""

from edgepick.runtime.calibration import Calibration, kabsch
from edgepick.runtime.camera import FolderCamera, RealSenseCamera
from edgepick.runtime.grasp import draw_overlay, grasp_records
from edgepick.runtime.pipeline import Pipeline
from edgepick.runtime.session import ModelError, Segmenter

__all__ = ["Calibration", "FolderCamera", "ModelError", "Pipeline", "RealSenseCamera", "Segmenter", "draw_overlay",
           "grasp_records", "kabsch"]
