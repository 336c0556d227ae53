"""Torch-free CPU runtime: onnxruntime session, mask filters, moments grasps, geometry, calibration, cameras.

Nothing under this package may import torch (tests/runtime/test_no_torch.py enforces it).
"""

from typing import TYPE_CHECKING

from edgepick.lazy import lazy_attributes

_WHERE = {
    "Calibration": "calibration", "draw_overlay": "grasp", "Engine": "engine", "FolderCamera": "camera",
    "grasp_records": "grasp", "GraspConfig": "grasp_config", "Grasp": "grasp_record", "kabsch": "calibration", "ModelError": "model_info",
    "ModelInfo": "model_info",
    "Pipeline": "pipeline", "Preprocessing": "preprocessing", "RealSenseCamera": "camera", "Segmenter": "session"
}
__all__ = sorted(_WHERE)

if TYPE_CHECKING:
    from edgepick.runtime.calibration import Calibration, kabsch
    from edgepick.runtime.camera import FolderCamera, RealSenseCamera
    from edgepick.runtime.engine import Engine
    from edgepick.runtime.grasp import draw_overlay, grasp_records
    from edgepick.runtime.grasp_config import GraspConfig
    from edgepick.runtime.grasp_record import Grasp
    from edgepick.runtime.model_info import ModelError, ModelInfo
    from edgepick.runtime.pipeline import Pipeline
    from edgepick.runtime.preprocessing import Preprocessing
    from edgepick.runtime.session import Segmenter


__getattr__ = lazy_attributes(__name__, _WHERE)
