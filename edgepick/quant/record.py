"""The `edgepick.quant` metadata entry of an int8 file (docs/contracts.md#onnx-model), written in one
place for every pass: `QuantRecord` takes the configs the pass was given and what it measured, and
`to_dict()` lays them out as the pass's kind of file records them (`LAYOUTS`)."""

from __future__ import annotations

import enum
import json
from dataclasses import dataclass, field
from typing import Any

from edgepick.quant.config import OnnxOptions, Pt2eOptions, PtqMethods, QatOptions, QuantConfig


class RecordKind(enum.StrEnum):
    """Which pass wrote a file, and so which settings its record holds."""

    STATIC = "static"  # static PTQ of a checkpoint (the torch pass)
    QAT = "qat"  # QaT from scratch
    HYBRID = "hybrid"  # hybrid-QaT
    ONNX = "onnx"  # static PTQ of a float .onnx model
    MODULE = "module"  # static PTQ of an nn.Module


_QAT = ("mode", "qat_fraction", "calib_method", "calib_images", "weight_bits", "weight_averaging", "hardswish_gate",
        "keep_float", "skip")
# the settings each kind of file records, in order; what the pass measured follows them
LAYOUTS: dict[RecordKind, tuple[str, ...]] = {
    RecordKind.STATIC: ("mode", "qat_fraction", "calib_method", "calib_images", "percentile", "weight_bits",
                        "hardswish_gate", "bias_correction", "equalize", "adaround", "adaround_budget_s", "placement",
                        "target", "gelu", "keep_float", "skip", "ranges"),
    RecordKind.QAT: _QAT,
    RecordKind.HYBRID: (*_QAT, "freeze_at", "carry_optimizer", "hold_ranges"),
    RecordKind.ONNX: ("mode", "source", "calib_method", "calib_images", "percentile", "weight_bits", "placement", "gelu",
                      "equalize", "bias_correction", "adaround", "adaround_budget_s", "adaround_if_far", "keep_float",
                      "ranges"),
    RecordKind.MODULE: ("mode", "source", "calib_method", "calib_images", "percentile", "weight_bits",
                        "bias_correction", "equalize", "adaround", "keep_float", "ranges"),
}
# a torch model's int8 graph quantizes every activation and runs its GELU as exported: what a checkpoint's
# static file records for the ONNX pass's choices
TORCH_GRAPH = OnnxOptions()


@dataclass(frozen=True)
class QuantRecord:
    """What a pass writes into its file's `edgepick.quant`: its KIND, the configs it was given, how
    many calibration images it saw, its range rule (RANGES), and what it MEASURED (appended as given)."""

    kind: RecordKind
    config: QuantConfig
    calib_images: int | None = None
    methods: PtqMethods | None = None
    options: OnnxOptions | None = None
    qat: QatOptions | None = None
    pt2e: Pt2eOptions | None = None
    ranges: dict | None = None
    qat_fraction: float | None = None
    calib_method: str | None = None  # the QaT passes: how the ranges started (default: config.calib_method)
    hybrid: dict = field(default_factory=dict)  # hybrid-QaT's carry_optimizer and hold_ranges
    measured: dict = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        """The record as the file holds it (docs/contracts.md#onnx-model)."""
        options = self.options or (TORCH_GRAPH if self.kind == RecordKind.STATIC else None)
        settings: dict[str, Any] = {}
        for config in (self.config, self.methods, options, self.qat, self.pt2e):
            settings.update(config.to_dict() if config is not None else {})
        settings.update({  # the pass's own facts, after the configs' fields: calib_method is the pass's to say
            "mode": self.kind.value if self.kind in (RecordKind.QAT, RecordKind.HYBRID) else "static",
            "source": self.kind.value, "qat_fraction": self.qat_fraction,
            "calib_method": self.calib_method or self.config.calib_method.value, "calib_images": self.calib_images,
            "ranges": self.ranges, **self.hybrid})
        keys = LAYOUTS[self.kind]
        if self.kind == RecordKind.ONNX and not settings["adaround"] and "adaround_first" not in self.measured:
            keys = tuple(k for k in keys if k != "adaround_budget_s")  # recorded where AdaRound ran
        return {**{k: settings[k] for k in keys}, **self.measured}

    def to_json(self) -> str:
        return json.dumps(self.to_dict())
