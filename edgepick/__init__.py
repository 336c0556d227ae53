"""edgepick: train, quantize and deploy DeepLabV3 segmentation for robot picking on CPUs.

The Python API: `edgepick.train`, `edgepick.quant`, `edgepick.export` and `edgepick.runtime`
(each names its public objects in `__all__`), and here the error type and `Size`, the
(width, height) of an image or a model input.
"""

from edgepick.errors import EdgepickError
from edgepick.geometry import Size

__version__ = "0.1.0"
__all__ = ["EdgepickError", "Size", "__version__"]
