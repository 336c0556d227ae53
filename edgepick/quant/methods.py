"""Cross-layer equalization's scale rule, shared by the pt2e pass (equalize.py) and the ONNX pass
(onnx_equalize.py). numpy only: a mistake with an .onnx model is reported before torch is imported."""

from __future__ import annotations

import numpy as np

ROUNDS = 20  # passes over the pairs: a conv between two others is pulled both ways and settles in a few
TOLERANCE = 1e-3  # stop when no scale moves by more than this share


def equalizing_scales(r1: np.ndarray, r2: np.ndarray) -> np.ndarray:
    """Per channel s = sqrt(r1 / r2), which gives both layers the range sqrt(r1 * r2); 1 where
    either range is 0 (a dead channel stays as it is)."""
    live = (r1 > 0) & (r2 > 0)
    return np.where(live, np.sqrt(r1 / np.where(live, r2, 1.0)), 1.0)
