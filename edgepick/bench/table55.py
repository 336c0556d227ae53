"""Thesis Tables 5.5 and 5.6, regenerated in one go: synthetic data, one float run, static PTQ,
QaT from scratch, hybrid-QaT 1/5/10% from the float run's kept epochs, then the bench.

`benchmarks/table55.py` writes the result under benchmarks/results/; `make demo` ends with the
quick setting.
"""

from __future__ import annotations

import json
import os
import platform
import re
import time
from dataclasses import dataclass, replace
from pathlib import Path

from edgepick.bench.measure import BenchConfig
from edgepick.bench.run import run_bench


@dataclass(frozen=True)
class Setting:
    """The scale of one table run."""

    name: str
    splits: tuple[int, int, int]  # synthetic train/val/test scenes (640x480)
    size: tuple[int, int]  # training input H, W
    epochs: int  # the epoch budget E; hybrid-QaT switches at (1 - p)E, so E = 100 gives 1/5/10% exactly
    batch_size: int
    lr: float
    runs: int  # timed inferences per model


# Scaled down until the whole table takes minutes on 2 CPU cores: 3 steps per epoch at 64x96.
QUICK = Setting("quick", splits=(24, 12, 12), size=(64, 96), epochs=100, batch_size=8, lr=2e-3, runs=30)
FULL = Setting("full", splits=(4000, 1000, 100), size=(480, 640), epochs=100, batch_size=16, lr=1e-3, runs=100)
FRACTIONS = (0.01, 0.05, 0.10)


def machine_name() -> str:
    """gpu-<device name> or cpu-<N>core: the results file's name."""
    import torch

    if torch.cuda.is_available():
        return "gpu-" + re.sub(r"[^a-z0-9]+", "-", torch.cuda.get_device_name().lower()).strip("-")
    return f"cpu-{os.cpu_count()}core"


def make_table55(work: str | Path, setting: Setting, device: str = "auto", command: str = "",
                 echo=print) -> dict:
    """Run every phase in WORK (an empty or missing folder) and return the Markdown report,
    the PNG's path, the phase wall times and the bench rows."""
    import onnxruntime
    import torch
    import torchao

    from edgepick.data.synth import SynthConfig, synthesize
    from edgepick.export.onnx_export import export_checkpoint
    from edgepick.quant.passes import quantize_hybrid, quantize_qat, quantize_static
    from edgepick.train.loop import TrainConfig, train

    s = setting
    work = Path(work)
    keep = sorted({round((1 - p) * s.epochs) for p in FRACTIONS})
    phases: dict[str, float] = {}

    def timed(name: str, fn, *a, **k):
        echo(f"-- {name}")
        t0 = time.perf_counter()
        out = fn(*a, **k)
        phases[name] = round(time.perf_counter() - t0, 1)
        return out

    data, models = work / "data", work / "models"
    timed("synth", synthesize, data, SynthConfig(scenes=sum(s.splits), splits=s.splits, seed=0), progress=False)
    tc = TrainConfig(data=str(data), out=str(work / "float"), epochs=s.epochs, batch_size=s.batch_size, size=s.size,
                     lr=s.lr, device=device, keep_epochs=keep)
    timed("float training", train, tc, progress=False)
    files = [timed("fp32 export", export_checkpoint, work / "float", models / "fp32.onnx")["out"],
             timed("static PTQ", quantize_static, work / "float", data, models / "static.onnx",
                   calib_images=min(64, s.splits[0]), progress=False)["out"]]
    qat_tc = replace(tc, out=str(work / "qat"), keep_epochs=[])
    files.append(timed("QaT from scratch", quantize_qat, qat_tc, models / "qat.onnx", progress=False)["out"])
    for p in FRACTIONS:
        files.append(timed(f"hybrid-QaT {p:.0%}", quantize_hybrid, work / "float", data, models / f"hybrid{p:.2f}.onnx",
                           p, qat_run=work / f"hybrid{p:.2f}.run", progress=False)["out"])
    bench = timed("bench", run_bench, files, data, work / "bench", BenchConfig(threads=2, runs=s.runs),
                  gpu_checkpoint=work / "float", title="Table 5.5 / 5.6", progress=lambda line: None)

    gpu = torch.cuda.is_available() and device != "cpu"
    name = machine_name() + ("-quick" if s is QUICK else "")
    table = Path(bench["reports"]["md"]).read_text().split("## Table 5.5", 1)[1]
    lines = [f"# Thesis Table 5.5 / 5.6 on {name}", "",
             f"Command: `{command}` (every figure below comes from this one run)", "",
             f"- machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores, "
             f"{'GPU ' + torch.cuda.get_device_name() if torch.cuda.is_available() else 'no GPU'}",
             f"- versions: python {platform.python_version()}, torch {torch.__version__}, torchao {torchao.__version__}, "
             f"onnxruntime {onnxruntime.__version__}",
             f"- setting: {'QUICK (scaled down for a 2-core CPU: not the thesis scale)' if s is QUICK else s.name}; "
             f"synthetic splits {s.splits} at 640x480, training input {s.size[0]}x{s.size[1]}, {s.epochs} epochs, "
             f"batch {s.batch_size}, device {'cuda' if gpu else 'cpu'}; hybrid-QaT from the float run's "
             f"epochs {keep} (p = 10/5/1%); inference on 2 onnxruntime threads, {s.runs} timed runs per model",
             f"- phase wall times (s): {json.dumps(phases)}",
             *([f"- {n}" for n in bench["notes"]]), "", "## Table 5.5" + table]
    return {"name": name, "markdown": "\n".join(lines), "png": bench["reports"]["png"], "phases": phases,
            "rows": bench["rows"]}
