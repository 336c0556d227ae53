"""Static PTQ methods compared on one float run, over several calibration seeds: how closely the
int8 file follows fp32 on onnxruntime (labels equal on object pixels, the pixels either model
calls an object; and the test mIoU against fp32's), and what each method costs in calibration time.

Object-pixel agreement is the measure that cannot be lucky: on a weak model, quantization noise
can raise mIoU by chance, while agreeing with fp32 can only be earned.

    python benchmarks/ptq_methods.py --run RUN --data DATA [--seeds 0,1,2] [--methods none,fast,empirical]
        [--out FILE.md | --save]
"""

from __future__ import annotations

import argparse
import shutil
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from _common import add_output, emit, machine_line  # noqa: E402

from edgepick.data.native import NativeDataset  # noqa: E402
from edgepick.export.onnx_export import export_checkpoint  # noqa: E402
from edgepick.metrics import confusion_matrix, segmentation_metrics  # noqa: E402
from edgepick.quant.config import BiasCorrection, QuantConfig  # noqa: E402
from edgepick.quant.passes import agreement_images, folder_images, quantize_static  # noqa: E402
from edgepick.runtime.session import Segmenter  # noqa: E402


def labels(model: Path, frames: list[np.ndarray]) -> list[np.ndarray]:
    seg = Segmenter(model, threads=2)
    return [seg.labels(rgb) for rgb in frames]


def scores(ours: list[np.ndarray], fp32: list[np.ndarray], truth: list[np.ndarray], classes: int) -> tuple[float, float]:
    """(share of object pixels where OURS equals FP32, test mIoU of OURS against TRUTH)."""
    return agreement(ours, fp32), miou(ours, truth, classes)


def miou(pred: list[np.ndarray], truth: list[np.ndarray], classes: int) -> float:
    cm = sum(confusion_matrix(t, p, classes) for p, t in zip(pred, truth))
    return float(segmentation_metrics(cm)["miou"])


def agreement(ours: list[np.ndarray], fp32: list[np.ndarray]) -> float:
    same = total = 0
    for a, b in zip(ours, fp32):
        objects = (a > 0) | (b > 0)
        same += int(((a == b) & objects).sum())
        total += int(objects.sum())
    return same / max(total, 1)


def spread(values: list[float]) -> str:
    """Mean and (min-max) of percentages."""
    pct = [100 * v for v in values]
    return f"{statistics.mean(pct):.2f} ({min(pct):.2f}-{max(pct):.2f})"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--run", required=True, help="float RUN or checkpoint")
    ap.add_argument("--data", required=True)
    ap.add_argument("--split", default="test")
    ap.add_argument("--seeds", default="0,1,2", help="calibration seeds (which train images are drawn)")
    ap.add_argument("--methods", default=",".join(m.value for m in BiasCorrection),
                    help="bias-correction forms to compare")
    ap.add_argument("--calib-images", type=int, default=None, help="[default: quantize static's]")
    add_output(ap)
    args = ap.parse_args()
    seeds = [int(s) for s in args.seeds.split(",")]
    methods = [BiasCorrection(m) for m in args.methods.split(",")]

    ds = NativeDataset.open(args.data, args.split)
    frames, truth = [ds.rgb(i) for i in ds.ids], [ds.mask(i) for i in ds.ids]
    classes = len(ds.classes)
    work = Path(tempfile.mkdtemp(prefix="ptq-methods-"))
    results: dict[BiasCorrection, list[tuple[float, float, float]]] = {m: [] for m in methods}
    try:
        fp32_path = Path(export_checkpoint(args.run, work / "fp32.onnx").out)
        fp32 = labels(fp32_path, frames)
        fp32_miou = miou(fp32, truth, classes)
        check = agreement_images(args.data)
        for seed in seeds:
            calib = folder_images(args.data, "train", args.calib_images, seed)
            for method in methods:
                print(f"-- seed {seed}, bias correction {method}", file=sys.stderr, flush=True)
                out = work / f"{method}-{seed}.onnx"
                t0 = time.perf_counter()
                r = quantize_static(args.run, calib, out, QuantConfig(bias_correction=method), check_images=check,
                                    progress=False)
                pass_s = time.perf_counter() - t0
                agree, int8_miou = scores(labels(out, frames), fp32, truth, classes)
                results[method].append((agree, int8_miou - fp32_miou, r.calib_s))
                print(f"   object agreement {100 * agree:.2f}%, mIoU {100 * (int8_miou - fp32_miou):+.2f} pp, "
                      f"calibration {r.calib_s:.1f} s, pass {pass_s:.1f} s", file=sys.stderr, flush=True)
    finally:
        shutil.rmtree(work, ignore_errors=True)

    lines = ["# Static PTQ methods on one float run", "",
             f"Command: `python benchmarks/ptq_methods.py {' '.join(sys.argv[1:])}`  ",
             f"{machine_line()}; model {args.run}; fp32 test mIoU {100 * fp32_miou:.2f}% on the {args.split} split "
             f"({len(frames)} images) of {args.data}; calibration seeds {args.seeds}; onnxruntime, 2 threads.", "",
             "Mean over the seeds, (min-max) in brackets. Object-pixel agreement: the share of pixels that either "
             "model labels as an object on which the int8 labels equal fp32's. Calibration time: prepare, "
             "calibration, conversion and bias correction, without the export.", "",
             "| Bias correction | Object-pixel agreement with fp32 (%) | mIoU - fp32's (pp) | Calibration (s) |",
             "|---|---|---|---|"]
    for method, rows in results.items():
        agree, drop, calib_s = zip(*rows)
        drops = [100 * d for d in drop]
        lines.append(f"| {method} | {spread(list(agree))} | {statistics.mean(drops):+.2f} "
                     f"({min(drops):+.2f} to {max(drops):+.2f}) | {statistics.median(calib_s):.1f} |")
    emit("\n".join(lines) + "\n", args)


if __name__ == "__main__":
    main()
