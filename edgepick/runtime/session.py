"""The runtime's segmentation session: one onnxruntime CPU session per model (docs/contracts.md#onnx-model).

Reads the model's metadata (classes, input size, colour space, precision), checks the
graph's input/output against the contract, resizes a camera frame to the model's input
and the labels back to the frame.
"""

from __future__ import annotations

import hashlib
import importlib.util
import json
import os
import statistics
import time
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np
import onnxruntime as ort

from edgepick.files import atomic_write
from edgepick.geometry import Size
from edgepick.machine import cpu_model
from edgepick.runtime.engine import Engine
from edgepick.runtime.model_info import ModelError, ModelInfo
from edgepick.schema import member


def _session(path: Path, threads: int, optimize: bool = True) -> ort.InferenceSession:
    opts = ort.SessionOptions()
    opts.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL if optimize else \
        ort.GraphOptimizationLevel.ORT_DISABLE_ALL
    opts.intra_op_num_threads = threads
    opts.inter_op_num_threads = 1
    opts.log_severity_level = 3
    try:
        return ort.InferenceSession(str(path), opts, providers=["CPUExecutionProvider"])
    except Exception as exc:  # noqa: BLE001 - onnxruntime raises several types for a bad file
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise ModelError(f"onnxruntime cannot load {path}: {first}") from None


def plain_session(path: str | Path, threads: int = 2) -> ort.InferenceSession:
    """An onnxruntime CPU session for any ONNX file, without the contract's checks (a model
    edgepick did not make)."""
    return _session(Path(path), threads)


def check_model(path: str | Path) -> ModelInfo:
    """A model's contract checked without preparing it to run (no graph optimisation): what a
    command that takes several models checks for each before working on the first."""
    path = Path(path)
    if not path.is_file():
        raise ModelError(f"no model file at {path}")
    return read_info(_session(path, 1, optimize=False), path)


def read_info(session: ort.InferenceSession, path: Path) -> ModelInfo:
    """The checks of docs/contracts.md#onnx-model: edgepick metadata (ModelInfo), uint8 [1,H,W,3] `image`
    in, uint8 [1,H,W] `labels` out."""
    info = ModelInfo.from_metadata(session.get_modelmeta().custom_metadata_map, path)
    h, w = info.input_size.hw
    inputs, outputs = session.get_inputs(), {o.name: o for o in session.get_outputs()}
    if len(inputs) != 1 or inputs[0].name != "image" or inputs[0].type != "tensor(uint8)" \
            or list(inputs[0].shape) != [1, h, w, 3]:
        got = [(i.name, i.type, i.shape) for i in inputs]
        raise ModelError(f"{path} must take one uint8 input 'image' of shape [1, {h}, {w}, 3], has {got}")
    out = outputs.get("labels")
    if out is None or out.type != "tensor(uint8)" or list(out.shape) != [1, h, w]:
        raise ModelError(f"{path} must give a uint8 output 'labels' of shape [1, {h}, {w}]")
    return info


def openvino_config(threads: int, precision: str = "f32") -> dict[str, object]:
    """OpenVINO CPU compile settings: THREADS threads, latency first, the model's float parts run in
    PRECISION ("f32" unless asked; "bf16" is only for benchmarks that name it)."""
    # Without INFERENCE_PRECISION_HINT, OpenVINO runs float models in bf16 on CPUs with AMX or
    # avx512_bf16: an fp32 model would give other labels than its precision says. f32 holds for
    # int8 models too: their int8 ops run in int8 either way, and their float parts (the logits the
    # labels are taken from, and the layers `quantize static --max-miou-drop` kept float because
    # int8 drifted there) then match the onnxruntime run the model's mIoU was measured with.
    return {"INFERENCE_NUM_THREADS": threads, "PERFORMANCE_HINT": "LATENCY", "INFERENCE_PRECISION_HINT": precision}


def _openvino_runner(path: Path, threads: int):
    """OpenVINO's CPU plugin on the same ONNX file (the optional `[peers]` extra), float parts in f32;
    the two engines are compared by benchmarks/peers.py (benchmarks/results/peers/)."""
    try:
        import openvino as ov
    except ImportError:
        raise ModelError("the openvino engine needs the peers extra: pip install 'edgepick[peers]'") from None
    try:
        compiled = ov.Core().compile_model(str(path), "CPU", openvino_config(threads))
    except Exception as exc:  # noqa: BLE001 - OpenVINO raises RuntimeError subclasses
        raise ModelError(f"OpenVINO cannot compile {path}: {str(exc).strip().splitlines()[0]}") from None
    request, output = compiled.create_infer_request(), compiled.output("labels")
    return lambda image: request.infer({"image": image})[output]


def _cache_file() -> Path:
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "edgepick" / "engines.json"


# between blocks of different models: onnxruntime's worker threads keep spinning after a run, and on 2 cores a
# session timed while another's still spin runs at a fraction of its speed (benchmarks/results/session-switch/)
SWITCH_PAUSE_S = 0.1


def interleaved_times(calls: list[Callable[[int], object]], runs: int, block: int = 5) -> list[list[float]]:
    """Milliseconds per call of each CALLS[k](i), RUNS timed calls each, in alternating blocks of BLOCK,
    each block after SWITCH_PAUSE_S (where there are several calls) and one untimed call: a shared
    machine's load drifts over all models alike, and no timed call runs beside the previous model's
    spinning thread pool."""
    times: list[list[float]] = [[] for _ in calls]
    i = 0
    while any(len(t) < runs for t in times):
        for call, t in zip(calls, times):
            if len(calls) > 1:
                time.sleep(SWITCH_PAUSE_S)
            call(i)
            for _ in range(min(block, runs - len(t))):
                i += 1
                t0 = time.perf_counter()
                call(i)
                t.append(1000 * (time.perf_counter() - t0))
    return times


def median_ms(runs: dict[str, Callable[[np.ndarray], object]], image: np.ndarray, timed: int = 10, block: int = 5) -> dict[str, float]:
    """Median milliseconds of each runner on IMAGE, timed in alternating blocks (`interleaved_times`)
    after 3 warm-up calls each."""
    for run in runs.values():
        for _ in range(3):
            run(image)
    def on_image(run: Callable[[np.ndarray], object]) -> Callable[[int], object]:
        return lambda i: run(image)

    times = interleaved_times([on_image(run) for run in runs.values()], timed, block)
    return {name: round(statistics.median(t), 3) for name, t in zip(runs, times)}


def choose_engine(path: Path, threads: int, ort_run: Callable[[np.ndarray], object],
                  size: Size) -> tuple[Engine, Callable[[np.ndarray], object] | None, dict]:
    """The faster engine for this model, thread count and CPU: read from the cache, or measured on a
    blank frame and written there. Returns (engine, its OpenVINO runner or None, the record)."""
    if importlib.util.find_spec("openvino") is None:
        return Engine.ONNXRUNTIME, None, {"engine": Engine.ONNXRUNTIME.value, "why": "OpenVINO is not installed"}
    key = f"{hashlib.sha256(path.read_bytes()).hexdigest()}:{threads}:{cpu_model()}"
    cache = _cache_file()
    try:
        known = json.loads(cache.read_text())
    except (OSError, ValueError):
        known = {}
    record = known.get(key)
    ov_run = None
    if record is None or record.get("engine") not in (Engine.ONNXRUNTIME, Engine.OPENVINO):
        ov_run = _openvino_runner(path, threads)
        ms = median_ms({Engine.ONNXRUNTIME.value: ort_run, Engine.OPENVINO.value: ov_run},
                        np.zeros((1, *size.hw, 3), np.uint8))
        record = {"engine": min(ms, key=ms.__getitem__), "p50_ms": ms, "model": str(path)}
        try:
            atomic_write(cache, json.dumps({**known, key: record}, indent=1))
        except OSError:
            pass  # a read-only home: measured again next time
    if record["engine"] == Engine.OPENVINO and ov_run is None:
        ov_run = _openvino_runner(path, threads)
    return Engine(record["engine"]), ov_run, record


class Segmenter:
    """Created once per model; `labels(rgb)` gives class ids at the frame's own resolution.
    ENGINE: onnxruntime, openvino (the `[peers]` extra) or auto (the faster of the two here, measured
    once per model, thread count and CPU, cached in ~/.cache/edgepick/engines.json; onnxruntime
    when OpenVINO is not installed)."""

    def __init__(self, path: str | Path, threads: int = 2, engine: Engine = Engine.ONNXRUNTIME):
        path = Path(path)
        engine = member(Engine, "engine", engine)
        if not path.is_file():
            raise ModelError(f"no model file at {path}")
        self.session = _session(path, threads)  # onnxruntime also checks the contract for the other engine
        self.info = read_info(self.session, path)
        self._run = lambda image: self.session.run(["labels"], {"image": image})[0]
        self.engine_choice = None
        ov_run = None
        if engine == Engine.AUTO:
            engine, ov_run, self.engine_choice = choose_engine(path, threads, self._run, self.info.input_size)
        self.path, self.engine = path, engine
        if engine == Engine.OPENVINO:
            self._run = ov_run or _openvino_runner(path, threads)
            self.session = None

    def prepare(self, rgb: np.ndarray) -> np.ndarray:
        """HxWx3 uint8 RGB -> the model's [1, h, w, 3] input (area resize when the size differs)."""
        if rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.dtype != np.uint8:
            raise ModelError(f"expected an HxWx3 uint8 RGB frame, got {rgb.dtype} {rgb.shape}")
        size = self.info.input_size
        if rgb.shape[:2] != size.hw:
            rgb = cv2.resize(rgb, (size.width, size.height), interpolation=cv2.INTER_AREA)
        return np.ascontiguousarray(rgb)[None]

    def infer(self, image: np.ndarray) -> np.ndarray:
        """The model's own [h, w] labels for a prepared input."""
        return self._run(image)[0]

    def restore(self, labels: np.ndarray, frame_hw: tuple[int, int]) -> np.ndarray:
        """The model's labels at the frame's size; a class id beyond the model's classes is refused (its
        regions would have no name, and the grasp step would drop them without a word): the model's
        edgepick.classes do not fit its output."""
        top = int(labels.max()) if labels.size else 0
        if top >= len(self.info.classes):
            n = len(self.info.classes)
            raise ModelError(f"{self.path} gave class id {top}, but its edgepick.classes names {n} classes (ids 0 to "
                             f"{n - 1}): the metadata does not fit the model's output")
        if labels.shape != tuple(frame_hw):
            labels = cv2.resize(labels, (frame_hw[1], frame_hw[0]), interpolation=cv2.INTER_NEAREST)
        return labels

    def labels(self, rgb: np.ndarray) -> np.ndarray:
        return self.restore(self.infer(self.prepare(rgb)), rgb.shape[:2])
