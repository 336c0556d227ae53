"""The inference engines a Segmenter runs a model on (edgepick.runtime.session picks and builds
them). Alone in a module of its own, without onnxruntime or OpenCV, so the command line builds
its --engine options from it at no import cost."""

from __future__ import annotations

import enum


class Engine(enum.StrEnum):
    """onnxruntime; OpenVINO's CPU plugin (the [peers] extra); or auto: the faster of the two on this
    machine, measured once per model, thread count and CPU and cached."""

    ONNXRUNTIME = "onnxruntime"
    OPENVINO = "openvino"
    AUTO = "auto"
