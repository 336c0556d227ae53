"""`edgepick bench`: every model on the same images, in one process, then the reports."""

from __future__ import annotations

import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import onnxruntime as ort

from edgepick.bench.measure import BenchConfig, Row, bench_model, order_key
from edgepick.bench.report import write_reports
from edgepick.data.native import NativeDataset
from edgepick.errors import CheckpointError, ConfigError, ParameterError
from edgepick.machine import machine_line
from edgepick.runtime.session import check_model


def gpu_row(checkpoint: str | Path, data: str | Path, images: list[np.ndarray], cfg: BenchConfig) -> Row | None:
    """The thesis's fp32 GPU row: the float checkpoint in torch on CUDA (None without a GPU)."""
    try:
        import torch
    except ImportError:
        return None
    if not torch.cuda.is_available():
        return None
    import cv2

    from edgepick.evaluation import evaluate
    from edgepick.export.onnx_export import run_train_time_s
    from edgepick.train.checkpoint import load_model

    model, ckpt = load_model(checkpoint)
    model = model.cuda().eval()
    h, w = ckpt.input_size.hw
    batch = [torch.from_numpy(cv2.resize(im, (w, h), interpolation=cv2.INTER_AREA)).permute(2, 0, 1)[None].float().cuda()
             for im in images]
    times = []
    with torch.inference_mode():
        for i in range(cfg.warmup + cfg.runs):
            torch.cuda.synchronize()
            t0 = time.perf_counter()
            model(batch[i % len(batch)])["out"].argmax(1)
            torch.cuda.synchronize()
            if i >= cfg.warmup:
                times.append(1000 * (time.perf_counter() - t0))
    acc = evaluate(checkpoint, data, cfg.split, progress=False)
    assert ckpt.path is not None, "a checkpoint load_model read has its file"
    size = ckpt.path.stat().st_size
    return Row("fp32 GPU", str(checkpoint), "fp32", acc["pixel_acc"], acc["miou"], round(float(np.median(times)), 3),
               round(float(np.percentile(times, 95)), 3), run_train_time_s(ckpt.path, ckpt.train_time_s),
               round(size / 1e6, 3),
               device=torch.cuda.get_device_name())


def check_gpu_checkpoint(checkpoint: str | Path, classes: list[str]) -> None:
    """The float checkpoint of the fp32 GPU row, checked before anything is measured: there, and (where
    torch is installed) an edgepick checkpoint of the data's classes. A machine without a GPU still
    checks it: the same command line then fails alike on the machine that has one."""
    from edgepick.train.run import checkpoint_path

    path = checkpoint_path(checkpoint)
    if not path.is_file():
        raise ParameterError("{gpu_checkpoint}: no checkpoint there (a float RUN folder or its .pt file)",
                             gpu_checkpoint=checkpoint)
    try:
        from edgepick.train.checkpoint import Checkpoint
    except ImportError:  # the base install: no GPU row without torch, and nothing to read the file with
        return
    ckpt = Checkpoint.load(path)
    ckpt.build_model()  # a QaT checkpoint, or weights that do not fit, are refused here
    if list(ckpt.classes) != classes:
        raise CheckpointError(f"{path}: the checkpoint's classes {list(ckpt.classes)} differ from the data set's "
                              f"{classes}")


def run_bench(models: Sequence[str | Path], data: str | Path, out_dir: str | Path, cfg: BenchConfig | None = None,
              gpu_checkpoint: str | Path | None = None, with_pipeline: bool = True, title: str = "edgepick bench",
              progress=print) -> dict:
    """Bench each ONNX model (and the GPU row when asked and possible); write the reports."""
    cfg = cfg or BenchConfig()
    if not models:
        raise ConfigError("give at least one ONNX model to bench")
    for m in models:
        if Path(m).suffix != ".onnx":
            raise ConfigError(f"{m} is not an .onnx file (bench runs ONNX models through the runtime)")
    ds = NativeDataset.open(data, cfg.split)
    for m in models:  # every model's contract, and its classes, before the first is measured
        classes = check_model(m).classes
        if classes != ds.classes:
            raise CheckpointError(f"{m}: the model's classes {classes} differ from the data set's {ds.classes}")
    if gpu_checkpoint:
        check_gpu_checkpoint(gpu_checkpoint, ds.classes)
    ds.check_files()
    images = [ds.rgb(sid) for sid in ds.ids[:cfg.latency_images]]
    rows = []
    notes = []
    if gpu_checkpoint:
        row = gpu_row(gpu_checkpoint, data, images, cfg)
        if row is None:
            notes.append("no CUDA GPU here: the fp32 GPU row is left out")
            progress(f"edgepick: warning: {notes[-1]}")
        else:
            rows.append(row)
    for m in models:
        progress(f"bench {Path(m).name} ...")
        rows.append(bench_model(m, data, images, cfg, with_pipeline))
    rows.sort(key=order_key)
    gpu = next((r.device for r in rows if r.device != "cpu"), None)  # the fp32 GPU row's card, when there is one
    context = {"title": title, "machine": machine_line(gpu).removeprefix("Machine: "),  # as in `bench --cell`
               "engine": cfg.engine, "onnxruntime": ort.__version__, "threads": cfg.threads,
               "runs": f"{cfg.runs} timed inferences after {cfg.warmup} warm-up, cycling {len(images)} {cfg.split} images",
               "accuracy": f"{len(ds)} {cfg.split} images of {data}", **({"note": "; ".join(notes)} if notes else {})}
    paths = write_reports(rows, out_dir, context)
    return {"rows": [r.to_dict() for r in rows], "reports": paths, "notes": notes}
