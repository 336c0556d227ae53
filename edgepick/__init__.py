"""edgepick: train, quantize and deploy DeepLabV3 segmentation for robot picking on CPUs.

The Python API: `edgepick.train`, `edgepick.quant`, `edgepick.export` and `edgepick.runtime`
(each names its public objects in `__all__`), and here the error type and `Size`, the
(width, height) of an image or a model input.
"""

from typing import TYPE_CHECKING

from edgepick.errors import EdgepickError

__version__ = "0.1.0"
__all__ = ["EdgepickError", "Size", "__version__"]

if TYPE_CHECKING:
    from edgepick.geometry import Size


def __getattr__(name: str) -> object:
    """Size is imported when first asked for: `edgepick --help` does not need numpy."""
    if name == "Size":
        from edgepick.geometry import Size

        return Size
    raise AttributeError(f"module 'edgepick' has no attribute {name!r}")
