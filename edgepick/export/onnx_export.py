"""ONNX export per docs/contracts.md#onnx-model: uint8 NHWC `image` in, uint8 `labels` out, metadata_props filled.

Works for the float model and for a converted pt2e (int8) graph alike: `DeployNet` puts
the uint8 -> float cast and the ArgMax around whatever maps [0, 255] NCHW to logits, and
`torch.onnx.export(dynamo=True)` turns pt2e's quantize/dequantize into QDQ nodes.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable, Iterable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import Tensor, nn

from edgepick.errors import ConfigError
from edgepick.export.checks import check_onnx_out
from edgepick.export.crop_convs import crop_padded_convs
from edgepick.export.int8_activations import integer_activations
from edgepick.files import atomic_path, sha256_of
from edgepick.geometry import Size
from edgepick.models.deeplabv3 import LogitsNet
from edgepick.onnx_graph import Graph
from edgepick.runtime.model_info import ModelInfo
from edgepick.train.checkpoint import Checkpoint, load_model
from edgepick.train.run import Run

OPSET = 21


@dataclass(frozen=True)
class ExportResult:
    """An exported fp32 model (the JSON `edgepick export` prints)."""

    out: str
    size_bytes: int
    input_size: Size
    classes: list[str]

    def to_dict(self) -> dict:
        """The JSON `edgepick export` prints: input_size as [H, W], like the model's metadata."""
        return {**asdict(self), "input_size": list(self.input_size.hw)}


class DeployNet(nn.Module):
    """uint8 [1, H, W, 3] RGB -> uint8 [1, H, W] class ids (docs/contracts.md#onnx-model)."""

    def __init__(self, net: nn.Module):
        super().__init__()
        self.net = net

    def forward(self, image: Tensor) -> Tensor:
        x = image.permute(0, 3, 1, 2).to(torch.float32)
        out = self.net(x)
        logits = out["out"] if isinstance(out, dict) else out
        return logits.argmax(1).to(torch.uint8)


def run_train_time_s(path: Path | None, train_time_s: float) -> float:
    """Training time of the run the checkpoint at PATH came from. A run's best.pt holds the time up
    to its (earlier) best epoch; the thesis counts the whole run, which its metrics hold."""
    if path is not None and Run(path.parent).best == path:
        total = Run(path.parent).total_train_time_s()
        if total is not None:
            return total
    return train_time_s


def contract_metadata(ckpt: Checkpoint, precision: str, quant: dict | None, train_time_s: float | None = None) -> dict:
    """The edgepick.* metadata_props of docs/contracts.md#onnx-model, from a checkpoint's own description."""
    seconds = train_time_s if train_time_s is not None else run_train_time_s(ckpt.path, ckpt.train_time_s)
    return ModelInfo(list(ckpt.classes), ckpt.input_size, ckpt.colorspace, precision, quant=quant or {"mode": "none"},
                     source_sha256=sha256_of(ckpt.path) if ckpt.path else "", arch=ckpt.model_config.arch,
                     train_time_s=seconds).to_metadata()


def strip_debug_info(model) -> None:
    """Drop the exporter's per-node stack traces and value_info (~0.6 MB on MobileNetV3): not needed to run."""
    for node in model.graph.node:
        del node.metadata_props[:]
        node.doc_string = ""
    del model.graph.value_info[:]


# ONNX graph passes run after the export, by name; both change only int8 graphs and keep the labels.
EXPORT_PASSES: dict[str, Callable[[Any], object]] = {
    "crop_convs": crop_padded_convs,  # int8 convs split into regions that skip padding-only taps (ASPP)
    "integer_activations": integer_activations,  # integer kernels for hardsigmoid (gated hardswish), pooling
}


def export_onnx(net: nn.Module, path: str | Path, metadata: dict, input_size: Size,
                passes: tuple[str, ...] = tuple(EXPORT_PASSES)) -> Path:
    """Export NET ([0, 255] NCHW float -> logits, float or pt2e-converted) as an ONNX model
    (docs/contracts.md#onnx-model), then run the named graph PASSES (EXPORT_PASSES; all by
    default, none with passes=() to measure what they bring).

    Written to a temporary file first and checked with onnx.checker; PATH appears only
    when the whole file is good.
    """
    _check_out_and_passes(path, passes)
    example = (torch.zeros(1, *input_size.hw, 3, dtype=torch.uint8),)
    return _write(DeployNet(_in_eval(net)), example, path, metadata, passes, ["image"], ["labels"])


def export_module_onnx(net: nn.Module, path: str | Path, input_shape: tuple[int, ...], metadata: dict,
                       passes: tuple[str, ...] = tuple(EXPORT_PASSES)) -> Path:
    """Export a model edgepick did not build (float or pt2e-converted) with its own float `input`
    of INPUT_SHAPE and its own outputs (`output`, or `output_0`, `output_1`, ... for several);
    `model wrap` makes it an edgepick model. The graph PASSES, the checks and the atomic write
    are export_onnx's."""
    _check_out_and_passes(path, passes)
    example = (torch.zeros(*input_shape),)
    net = _in_eval(net)
    with torch.no_grad():
        out = net(*example)
    count = len(out) if isinstance(out, (tuple, list)) else 1
    names = ["output"] if count == 1 else [f"output_{k}" for k in range(count)]
    return _write(net, example, path, metadata, passes, ["input"], names)


def _in_eval(net: nn.Module) -> nn.Module:
    if not isinstance(net, torch.fx.GraphModule):  # exported graphs are already in eval form
        net.eval()
    return net


def _check_out_and_passes(path: str | Path, passes: tuple[str, ...]) -> None:
    """Refuse a bad output name or an unknown pass before any work."""
    check_onnx_out(path)
    unknown = [p for p in passes if p not in EXPORT_PASSES]
    if unknown:
        raise ConfigError(f"unknown export pass {unknown[0]!r}; the passes are {', '.join(EXPORT_PASSES)}")


def _write(net: nn.Module, example: tuple, path: str | Path, metadata: dict, passes: tuple[str, ...],
           input_names: list[str], output_names: list[str]) -> Path:
    import onnx

    path = Path(path)
    with atomic_path(path) as tmp:
        with warnings.catch_warnings(), torch.no_grad():
            warnings.simplefilter("ignore")
            program = torch.onnx.export(net, example, dynamo=True, opset_version=OPSET, input_names=input_names,
                                        output_names=output_names, verbose=False, optimize=True)
        model = program.model_proto
        strip_debug_info(model)
        for name in passes:
            EXPORT_PASSES[name](model)
        Graph(model).drop_unused_initializers()  # left by the passes; onnxruntime warns about each
        for key, value in metadata.items():
            entry = model.metadata_props.add()
            entry.key, entry.value = key, str(value)
        model.producer_name = "edgepick"
        onnx.save(model, tmp)
        onnx.checker.check_model(tmp, full_check=True)
    return path


def export_checkpoint(checkpoint: str | Path, out: str | Path) -> ExportResult:
    """`edgepick export`: the float model of a checkpoint (or RUN) as an fp32 ONNX model
    (docs/contracts.md#onnx-model)."""
    from edgepick.models.deeplabv3 import trim_dilated_convs

    model, ckpt = load_model(checkpoint)
    size = ckpt.input_size
    trim_dilated_convs(model, size)
    path = export_onnx(LogitsNet(model), out, contract_metadata(ckpt, "fp32", None), size)
    return ExportResult(out=str(path), size_bytes=path.stat().st_size, input_size=size, classes=list(ckpt.classes))


def label_agreement(onnx_path: str | Path, net: nn.Module, images: Iterable[np.ndarray]) -> float:
    """Share of pixels where onnxruntime's labels equal NET's argmax, NET fed [0, 255] NCHW float.

    For an int8 file NET is the converted pt2e graph (torch's simulation of the same
    quantized model); for fp32 it is the float model. Images are already at the model size.
    """
    from edgepick.runtime.session import Segmenter

    seg = Segmenter(onnx_path, threads=2)
    same = total = 0
    with torch.no_grad():
        for rgb in images:
            ours = seg.infer(seg.prepare(rgb))
            out = net(torch.from_numpy(rgb).permute(2, 0, 1)[None].float())
            ref = (out["out"] if isinstance(out, dict) else out).argmax(1)[0].numpy().astype(np.uint8)
            same += int((ours == ref).sum())
            total += ref.size
    return same / max(total, 1)
