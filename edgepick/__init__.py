"""edgepick: train, quantize and deploy DeepLabV3 segmentation for robot picking on CPUs."""

from edgepick.errors import EdgepickError

__version__ = "0.1.0"
__all__ = ["EdgepickError", "__version__"]
