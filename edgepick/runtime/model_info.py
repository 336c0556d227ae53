"""The edgepick.* metadata of an ONNX model (docs/contracts.md#onnx-model) in one place: the export
writers fill a `ModelInfo` and write its `to_metadata()`, the runtime reads one back, checked, with
`ModelInfo.from_metadata`. No onnxruntime and no torch: both sides import it."""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass, field

from edgepick.errors import EdgepickError
from edgepick.geometry import Size
from edgepick.schema import Where, as_names, as_numbers


class ModelError(EdgepickError):
    """An ONNX file that is not an edgepick model (docs/contracts.md#onnx-model)."""


REQUIRED_KEYS = ("edgepick.classes", "edgepick.input_size", "edgepick.colorspace", "edgepick.precision")


@dataclass(frozen=True)
class ModelInfo:
    """What an edgepick model says of itself: its classes, input size, colour space and precision (what
    the runtime needs), and how it was made (the pass, the source, the training time)."""

    classes: list[str]
    input_size: Size  # the image input's; the file keeps [H, W]
    colorspace: str  # rgb | hsv | gray
    precision: str  # fp32 | int8
    quant: dict = field(default_factory=lambda: {"mode": "none"})  # edgepick.quant: the pass and its settings
    source_sha256: str = ""  # of the checkpoint (or the wrapped file) it came from
    arch: str | None = None
    train_time_s: float | None = None  # the whole run's training time; none for a wrapped model
    preprocessing: dict | None = None  # a wrapped model's Preprocessing (edgepick.preprocessing)
    metadata: dict[str, str] = field(default_factory=dict)  # every entry of the file as read, its own keys too

    def to_metadata(self) -> dict[str, str]:
        """The edgepick.* metadata_props to write into the file, in the contract's order."""
        meta = {"edgepick.classes": json.dumps(list(self.classes)),
                "edgepick.input_size": json.dumps(list(self.input_size.hw)),
                "edgepick.colorspace": self.colorspace, "edgepick.precision": self.precision,
                "edgepick.quant": json.dumps(self.quant), "edgepick.source_sha256": self.source_sha256}
        if self.train_time_s is not None:
            meta["edgepick.train_time_s"] = f"{self.train_time_s:.1f}"
        if self.arch is not None:
            meta["edgepick.arch"] = self.arch
        if self.preprocessing is not None:
            meta["edgepick.preprocessing"] = json.dumps(self.preprocessing)
        return meta

    @property
    def mode(self) -> str:
        """The pass that made the file: none (fp32), static, qat, hybrid or foreign."""
        return str(self.quant.get("mode", "static" if self.precision == "int8" else "none"))

    @classmethod
    def from_metadata(cls, meta: Mapping[str, str], path: object) -> ModelInfo:
        """The metadata of the file at PATH, checked (ModelError in one line naming the file); the
        entries only some files have (how it was made) are read as far as they are readable."""
        missing = [k for k in REQUIRED_KEYS if k not in meta]
        if missing:
            raise ModelError(f"{path} is not an edgepick model: metadata {', '.join(missing)} missing")
        where = Where(str(path))
        try:
            classes, size = json.loads(meta["edgepick.classes"]), json.loads(meta["edgepick.input_size"])
        except ValueError:
            raise ModelError(f"{path} has unreadable edgepick metadata (edgepick.classes and edgepick.input_size "
                             "are JSON)") from None
        classes = as_names(classes, where.at("edgepick.classes"), min_length=2)
        h, w = as_numbers(size, where.at("edgepick.input_size"), 2, integer=True, minimum=1, maximum=8192)
        return cls(list(classes), Size(w, h), meta["edgepick.colorspace"], meta["edgepick.precision"],
                   quant=_json_object(meta.get("edgepick.quant")) or {},
                   source_sha256=meta.get("edgepick.source_sha256", ""), arch=meta.get("edgepick.arch"),
                   train_time_s=_number(meta.get("edgepick.train_time_s")),
                   preprocessing=_json_object(meta.get("edgepick.preprocessing")), metadata=dict(meta))


def _json_object(text: str | None) -> dict | None:
    """TEXT as a JSON object, or None when it is missing or not one."""
    try:
        value = json.loads(text) if text else None
    except ValueError:
        return None
    return value if isinstance(value, dict) else None


def _number(text: str | None) -> float | None:
    """TEXT as a number, or None when it is missing or not one."""
    try:
        return float(text) if text else None
    except ValueError:
        return None
