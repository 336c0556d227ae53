"""Thesis Tables 5.5 and 5.6, regenerated: synthetic data, one float run, static PTQ, QaT from
scratch, hybrid-QaT 1/5/10% from the float run's kept epochs, then `edgepick bench`.

    python benchmarks/table55.py --quick        # minutes on 2 CPU cores (scaled down, stated in the output)
    python benchmarks/table55.py                # the full setting: 4000/1000/100 at 480x640, 100 epochs (GPU)

Writes benchmarks/results/table55-<machine>[-quick].md (+ .png) with the machine, the
versions, the settings, the wall time of every phase and the tables.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import re
import shutil
import sys
import time
from dataclasses import dataclass, replace
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from edgepick.bench.measure import BenchConfig  # noqa: E402
from edgepick.bench.run import run_bench  # noqa: E402


@dataclass
class Setting:
    splits: tuple[int, int, int]
    size: tuple[int, int]  # training input H, W
    epochs: int
    batch_size: int
    lr: float
    runs: int


QUICK = Setting(splits=(48, 12, 12), size=(64, 96), epochs=100, batch_size=8, lr=2e-3, runs=30)
FULL = Setting(splits=(4000, 1000, 100), size=(480, 640), epochs=100, batch_size=16, lr=1e-3, runs=100)
FRACTIONS = (0.01, 0.05, 0.10)


def machine_name() -> str:
    import torch

    if torch.cuda.is_available():
        return "gpu-" + re.sub(r"[^a-z0-9]+", "-", torch.cuda.get_device_name().lower()).strip("-")
    return f"cpu-{os.cpu_count()}core"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="the scaled-down CPU setting")
    ap.add_argument("--work", default=None, help="work folder (default: a fresh one under /tmp, removed at the end)")
    ap.add_argument("--results", default=str(Path(__file__).parent / "results"))
    ap.add_argument("--device", default="auto", choices=["auto", "cpu", "cuda"])
    args = ap.parse_args()

    import onnxruntime
    import torch
    import torchao

    from edgepick.data.synth import SynthConfig, synthesize
    from edgepick.export.onnx_export import export_checkpoint
    from edgepick.quant.passes import quantize_hybrid, quantize_qat, quantize_static
    from edgepick.train.loop import TrainConfig, train

    s = QUICK if args.quick else FULL
    keep = sorted({round((1 - p) * s.epochs) for p in FRACTIONS})
    work = Path(args.work) if args.work else Path(f"/tmp/table55-{os.getpid()}")
    if work.exists():
        shutil.rmtree(work)
    work.mkdir(parents=True)
    phases: dict[str, float] = {}

    def timed(name: str, fn, *a, **k):
        print(f"== {name}", file=sys.stderr, flush=True)
        t0 = time.perf_counter()
        out = fn(*a, **k)
        phases[name] = round(time.perf_counter() - t0, 1)
        return out

    data, models = work / "data", work / "models"
    timed("synth", synthesize, data, SynthConfig(scenes=sum(s.splits), splits=s.splits, seed=0))
    tc = TrainConfig(data=str(data), out=str(work / "float"), epochs=s.epochs, batch_size=s.batch_size, size=s.size,
                     lr=s.lr, device=args.device, keep_epochs=keep)
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

    device = "cuda" if args.device != "cpu" and torch.cuda.is_available() else "cpu"
    name = machine_name() + ("-quick" if args.quick else "")
    results = Path(args.results)
    results.mkdir(parents=True, exist_ok=True)
    table = Path(bench["reports"]["md"]).read_text().split("## Table 5.5", 1)[1]
    cmd = "python benchmarks/table55.py" + (" --quick" if args.quick else "")
    lines = [f"# Thesis Table 5.5 / 5.6 on {name}", "",
             f"Command: `{cmd}` (2026 edgepick; every figure below comes from this one run)", "",
             f"- machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores, "
             f"{'GPU ' + torch.cuda.get_device_name() if torch.cuda.is_available() else 'no GPU'}",
             f"- versions: python {platform.python_version()}, torch {torch.__version__}, torchao {torchao.__version__}, "
             f"onnxruntime {onnxruntime.__version__}",
             f"- setting: {'QUICK (scaled down for a 2-core CPU: not the thesis scale)' if args.quick else 'full'}; "
             f"synthetic splits {s.splits} at 640x480, training input {s.size[0]}x{s.size[1]}, {s.epochs} epochs, "
             f"batch {s.batch_size}, device {device}; hybrid-QaT from the float run's "
             f"epochs {keep} (p = 10/5/1%); inference on 2 onnxruntime threads, {s.runs} timed runs per model",
             f"- phase wall times (s): {json.dumps(phases)}",
             *([f"- {n}" for n in bench["notes"]]), "", "## Table 5.5" + table]
    (results / f"table55-{name}.md").write_text("\n".join(lines))
    shutil.copy(bench["reports"]["png"], results / f"table55-{name}.png")
    print("\n".join(lines))
    if not args.work:
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
