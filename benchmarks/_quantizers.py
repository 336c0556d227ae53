"""The other tools' int8 for a float ONNX model, and the two runtimes, as benchmarks/peers_onnx.py and
benchmarks/conformance/ use them: onnxruntime's `quantize_static` with its defaults and with its best
CPU settings (QDQ, U8S8, per-channel, reduce-range), NNCF on OpenVINO; an onnxruntime and an OpenVINO
runner that return the outputs in the order asked."""

from __future__ import annotations

import sys
from collections.abc import Sequence
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from edgepick.runtime.session import openvino_config, plain_session  # noqa: E402


class Ort:
    """An onnxruntime CPU session on THREADS threads; OUTPUTS: the output names, in the order wanted."""

    def __init__(self, path: Path, threads: int, outputs: Sequence[str] | None = None):
        self.session = plain_session(path, threads)
        self.input = self.session.get_inputs()[0].name
        self.outputs = list(outputs) if outputs else None

    def __call__(self, x: np.ndarray) -> list[np.ndarray]:
        return self.session.run(self.outputs, {self.input: x})


class OpenVino:
    """OpenVINO's CPU plugin (float parts in f32) on MODEL (an ov.Model or a file); OUTPUTS as for Ort."""

    def __init__(self, model, threads: int, outputs: Sequence[str] | None = None):
        import openvino as ov

        self.compiled = ov.Core().compile_model(model if not isinstance(model, Path) else str(model), "CPU",
                                                openvino_config(threads))
        self.request = self.compiled.create_infer_request()
        by_name = {name: port for port in self.compiled.outputs for name in port.get_names()}
        self.ports = [by_name.get(name, port) for name, port in zip(outputs, self.compiled.outputs)] if outputs \
            else list(self.compiled.outputs)

    def __call__(self, x: np.ndarray) -> list[np.ndarray]:
        result = self.request.infer({0: x})
        return [result[p] for p in self.ports]


def ort_ready(fp32: Path, out: Path, preprocess: bool = True) -> bool:
    """FP32 as onnxruntime's quantizer is given it, written to OUT: its own pre-processing (shape
    inference, graph optimisation) unless not PREPROCESS, and lifted to opset 13 when older, as a user
    does: its per-channel QDQ needs DequantizeLinear's axis. Returns whether the opset was lifted."""
    import shutil

    import onnx
    from onnx import version_converter
    from onnxruntime.quantization import quant_pre_process

    if preprocess:
        quant_pre_process(str(fp32), str(out))
    else:
        shutil.copyfile(fp32, out)
    pre = onnx.load(str(out))
    lifted = max((o.version for o in pre.opset_import if o.domain in ("", "ai.onnx")), default=13) < 13
    if lifted:
        pre = version_converter.convert_version(pre, 13)
    onnx.save(pre, str(out))
    return lifted


def ort_quantize(pre: Path, out: Path, calib: Sequence[np.ndarray], best: bool) -> Path:
    """onnxruntime's quantize_static of PRE (see ort_ready) on CALIB: its defaults, or with BEST its
    best CPU settings (QDQ, uint8 activations, int8 weights per channel, reduce-range)."""
    import onnx
    from onnxruntime.quantization import CalibrationDataReader, QuantFormat, QuantType, quantize_static

    graph = onnx.load(str(pre), load_external_data=False).graph
    initializers = {i.name for i in graph.initializer}
    name = next(i.name for i in graph.input if i.name not in initializers)

    class Reader(CalibrationDataReader):
        def __init__(self):
            self.it = iter(calib)

        def get_next(self):
            x = next(self.it, None)
            return None if x is None else {name: x}

    if best:
        quantize_static(str(pre), str(out), Reader(), quant_format=QuantFormat.QDQ, per_channel=True,
                        reduce_range=True, activation_type=QuantType.QUInt8, weight_type=QuantType.QInt8)
    else:
        quantize_static(str(pre), str(out), Reader())
    return out


def nncf_quantize(fp32: Path, calib: Sequence[np.ndarray]):
    """NNCF's post-training quantization of FP32 for OpenVINO on CALIB (its defaults): an ov.Model."""
    import nncf
    import openvino as ov

    return nncf.quantize(ov.Core().read_model(str(fp32)), nncf.Dataset(list(calib)), subset_size=len(calib))
