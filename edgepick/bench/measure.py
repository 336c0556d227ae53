"""Measure one ONNX model: accuracy on a split, inference latency at a fixed thread count on
the same images as every other row, and the whole pipeline (folder frame -> labels -> grasp
records) per frame."""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from edgepick.data.config import Split
from edgepick.errors import ParameterError
from edgepick.evaluation import evaluate
from edgepick.runtime.camera import FolderCamera
from edgepick.runtime.engine import Engine
from edgepick.runtime.model_info import ModelInfo
from edgepick.runtime.pipeline import Pipeline
from edgepick.runtime.session import Segmenter
from edgepick.schema import member


@dataclass(frozen=True)
class BenchConfig:
    """How every model of a bench is measured, checked on creation."""

    threads: int = 2
    runs: int = 50  # timed inferences per model
    warmup: int = 5
    split: Split = Split.TEST
    latency_images: int = 10  # distinct test images cycled through the timed runs
    engine: Engine = Engine.ONNXRUNTIME

    def __post_init__(self) -> None:
        object.__setattr__(self, "split", member(Split, "split", self.split))
        object.__setattr__(self, "engine", member(Engine, "engine", self.engine))
        for name in ("threads", "runs", "latency_images"):
            if getattr(self, name) < 1:
                raise ParameterError(f"{{{name}}}: must be at least 1", **{name: getattr(self, name)})
        if self.warmup < 0:
            raise ParameterError("{warmup}: must be 0 or more", warmup=self.warmup)


@dataclass
class Row:
    mode: str  # fp32 CPU | static | QaT | hybrid-QaT 5% | ...
    file: str
    precision: str
    pixel_acc: float | None
    miou: float | None
    p50_ms: float
    p95_ms: float
    train_time_s: float | None
    size_mb: float
    pipeline_p50_ms: float | None = None
    pipeline_p95_ms: float | None = None
    device: str = "cpu"

    def to_dict(self) -> dict:
        return asdict(self)


def mode_label(info: ModelInfo) -> str:
    """The row name the thesis uses, from the model's metadata (docs/contracts.md#onnx-model)."""
    if info.precision != "int8":
        return "fp32 CPU"
    mode = info.mode
    if mode == "hybrid":
        return f"hybrid-QaT {100 * float(info.quant.get('qat_fraction', 0)):.3g}%"
    return {"qat": "QaT", "static": "static"}.get(mode, mode)


def order_key(row: Row) -> tuple:
    """Thesis order: fp32 GPU, fp32 CPU, static, QaT, hybrid by fraction."""
    if row.mode.startswith("fp32"):
        return (0 if row.device != "cpu" else 1, 0.0, row.file)
    if row.mode.startswith("hybrid"):
        return (4, float(row.mode.split()[-1].rstrip("%")), row.file)
    return ({"static": 2, "QaT": 3}.get(row.mode, 5), 0.0, row.file)


def _percentiles(times: list[float]) -> tuple[float, float]:
    return round(float(np.median(times)), 3), round(float(np.percentile(times, 95)), 3)


def inference_times(seg: Segmenter, images: list[np.ndarray], cfg: BenchConfig) -> list[float]:
    prepared = [seg.prepare(img) for img in images]
    for i in range(cfg.warmup):
        seg.infer(prepared[i % len(prepared)])
    times = []
    for i in range(cfg.runs):
        t0 = time.perf_counter()
        seg.infer(prepared[i % len(prepared)])
        times.append(1000 * (time.perf_counter() - t0))
    return times


def pipeline_times(seg: Segmenter, data: str | Path, cfg: BenchConfig, frames: int) -> list[float]:
    """Per frame: read the PNGs from the split's folder (the capture), labels, grasp records."""
    camera = FolderCamera(Path(data) / cfg.split, loop=True)
    pipe = Pipeline(seg)
    for _ in range(min(cfg.warmup, 2)):
        pipe(camera.read())
    times = []
    for _ in range(frames):
        t0 = time.perf_counter()
        pipe(camera.read())
        times.append(1000 * (time.perf_counter() - t0))
    return times


def bench_model(path: str | Path, data: str | Path, images: list[np.ndarray], cfg: BenchConfig,
                with_pipeline: bool = True) -> Row:
    """One row of the table for an edgepick ONNX file."""
    path = Path(path)
    seg = Segmenter(path, threads=cfg.threads, engine=cfg.engine)
    acc = evaluate(path, data, cfg.split, progress=False, engine=cfg.engine)
    p50, p95 = _percentiles(inference_times(seg, images, cfg))
    row = Row(mode_label(seg.info), str(path), seg.info.precision, acc["pixel_acc"], acc["miou"], p50, p95,
              seg.info.train_time_s,
              round(path.stat().st_size / 1e6, 3))
    depth_there = (Path(data) / cfg.split / "depth").is_dir()
    if with_pipeline and depth_there:
        row.pipeline_p50_ms, row.pipeline_p95_ms = _percentiles(pipeline_times(seg, data, cfg, max(10, cfg.runs // 2)))
    return row
