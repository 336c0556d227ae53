"""Standard vs quantization-friendly ('edge') DeepLabV3-MobileNetV3, measured in one run:
mIoU in fp32 and after static int8 (same data, same training budget), onnxruntime-vs-torch
agreement, and fp32/int8 latency at 640x480 on 2 threads.

    python benchmarks/variant_study.py [--epochs 30] [--size 128x96] [--out FILE.md | --save]

The edge variant drops MobileNetV3's squeeze-excitation blocks and hardswish (ReLU instead)
and slims the ASPP head to 128 channels: the ops that stay float or drift in int8 graphs.
"""

from __future__ import annotations

import argparse
import shutil
import statistics
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from _common import add_output, emit, machine_line, untrained_checkpoint  # noqa: E402
from quant_speed import latency  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--epochs", type=int, default=30)
    ap.add_argument("--size", default="128x96", help="model input WIDTHxHEIGHT")
    ap.add_argument("--splits", default="80,20,20")
    ap.add_argument("--runs", type=int, default=20)
    add_output(ap)
    args = ap.parse_args()
    from edgepick.cli.options import model_size

    size = model_size(args.size)
    splits = tuple(int(v) for v in args.splits.split(","))

    import torch

    from edgepick.data.render import CLASSES
    from edgepick.data.synth import SynthConfig, synthesize
    from edgepick.evaluation import evaluate
    from edgepick.export.onnx_export import export_checkpoint
    from edgepick.geometry import Size
    from edgepick.quant.config import QuantConfig
    from edgepick.quant.pt2e.images import agreement_images, folder_images
    from edgepick.quant.pt2e.passes import quantize_static
    from edgepick.train.checkpoint import load_model
    from edgepick.train.loop import TrainConfig, train

    work = Path(tempfile.mkdtemp(prefix="variant-study-"))
    rows = {}
    try:
        data = work / "data"
        synthesize(data, SynthConfig(scenes=sum(splits), splits=splits, seed=5), progress=False)
        image = (np.random.default_rng(0).random((1, 480, 640, 3)) * 255).astype(np.uint8)
        for variant in ("standard", "edge"):
            run = work / f"run-{variant}"
            res = train(TrainConfig(data=str(data), out=str(run), variant=variant, epochs=args.epochs, batch_size=8,
                                    size=size, lr=2e-3, device="cpu"), progress=False)
            fp32 = export_checkpoint(run, work / f"{variant}-fp32.onnx").out
            int8 = quantize_static(run, folder_images(data, "train", 32), work / f"{variant}-int8.onnx",
                                   check_images=agreement_images(data), progress=False)
            m_fp32 = evaluate(fp32, data, "test", progress=False)["miou"]
            m_int8 = evaluate(int8.out, data, "test", progress=False)["miou"]
            params = sum(p.numel() for p in load_model(run)[0].parameters())
            # latency does not depend on the weights: untrained models at the deployment size
            ckpt = untrained_checkpoint(work / f"{variant}-480.pt", Size(640, 480), list(CLASSES), variant)
            f480 = export_checkpoint(ckpt, work / f"{variant}-480-fp32.onnx").out
            i480 = quantize_static(ckpt, folder_images(data, "train", 16), work / f"{variant}-480-int8.onnx",
                                   progress=False).out
            t_f, t_i = (statistics.median(t) for t in latency([f480, i480], image, 2, args.runs))
            rows[variant] = {"params_m": params / 1e6, "train_s": res.train_time_s, "fp32": m_fp32, "int8": m_int8,
                             "agree": int8.agreement_vs_torch, "fp32_ms": t_f, "int8_ms": t_i,
                             "int8_mb": int8.size_bytes / 1e6}
    finally:
        shutil.rmtree(work, ignore_errors=True)

    lines = ["# Standard vs edge DeepLabV3-MobileNetV3: accuracy and int8 speed", "",
             f"Command: `python benchmarks/variant_study.py {' '.join(sys.argv[1:])}`  ",
             f"{machine_line()}; torch {torch.__version__}. "
             f"Accuracy: synthetic splits {splits}, {args.epochs} CPU epochs at {size}, static int8 ({QuantConfig().calib_method}, 32 "
             f"images), test-split mIoU through onnxruntime. Latency: the same architectures at 640x480, 2 threads, "
             f"median of {args.runs} runs, one process, fp32 and int8 timed in alternating blocks of 5.", "",
             "| Variant | Params (M) | train (s) | fp32 mIoU (%) | int8 mIoU (%) | drop (pp) | ORT vs torch agreement "
             "| fp32 p50 (ms) | int8 p50 (ms) | int8 speed-up | int8 size (MB) |", "|---" * 11 + "|"]
    for v, r in rows.items():
        lines.append(f"| {v} | {r['params_m']:.2f} | {r['train_s']:.0f} | {100 * r['fp32']:.2f} | {100 * r['int8']:.2f} "
                     f"| {100 * (r['fp32'] - r['int8']):.2f} | {r['agree']:.4f} | {r['fp32_ms']:.1f} | "
                     f"{r['int8_ms']:.1f} | {r['fp32_ms'] / r['int8_ms']:.2f}x | {r['int8_mb']:.2f} |")
    s, e = rows["standard"], rows["edge"]
    lines += ["", f"Edge int8 vs standard fp32 latency: {s['fp32_ms'] / e['int8_ms']:.2f}x faster; "
              f"edge int8 vs standard int8: {s['int8_ms'] / e['int8_ms']:.2f}x."]
    report = "\n".join(lines) + "\n"
    emit(report, args)


if __name__ == "__main__":
    main()
