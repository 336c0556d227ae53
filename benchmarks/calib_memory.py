"""How much memory `edgepick quantize static MODEL.onnx` takes: peak resident memory (and wall time)
per calibration method and number of calibration tensors, against the float model's own inference
peak and onnxruntime's own `quantize_static` on the same model.

The model is edgepick's DeepLabV3-MobileNetV3 exported as a float ONNX at a large input (1024x2048
by default; the weights are seeded, not trained: memory does not depend on them), calibrated on
blurred noise images of that size. Each measurement is its own process, started by this script;
its peak is the kernel's maximum resident set size of that process (`ru_maxrss`).

    python benchmarks/calib_memory.py --save
    python benchmarks/calib_memory.py --size 2048x1024 --counts 8,64 --methods auto,percentile,minmax --peer-counts 2
    python benchmarks/calib_memory.py --counts 64 --methods auto --peer-counts '' --adaround-counts 64
"""

from __future__ import annotations

import argparse
import json
import shlex
import subprocess
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from _common import add_output, emit, machine_line  # noqa: E402

# run in a child: the peak of the command it starts, and its wall time
MEASURE = ("import resource, subprocess, sys, time; t0 = time.perf_counter(); "
           "r = subprocess.run(sys.argv[1:], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True); "
           "print(resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss, time.perf_counter() - t0, r.returncode); "
           "print(r.stderr.strip().splitlines()[-1] if r.returncode else '', file=sys.stderr)")
INFER = ("import sys, numpy as np, onnxruntime as ort; o = ort.SessionOptions(); o.intra_op_num_threads = 2; "
         "s = ort.InferenceSession(sys.argv[1], o, providers=['CPUExecutionProvider']); "
         "x = np.random.rand(*[int(v) for v in sys.argv[2].split(',')]).astype(np.float32); "
         "s.run(None, {s.get_inputs()[0].name: x})")
ORT_PEER = ("import sys, glob, cv2, numpy as np; from onnxruntime.quantization import CalibrationMethod, QuantFormat, "
            "QuantType, quantize_static\n"
            "files = sorted(glob.glob(sys.argv[2] + '/*.png'))[:int(sys.argv[4])]\n"
            "class R:\n"
            "    def __init__(self): self.it = iter(files)\n"
            "    def get_next(self):\n"
            "        f = next(self.it, None)\n"
            "        return None if f is None else {'input': (cv2.imread(f)[..., ::-1].transpose(2, 0, 1)[None] / 255)"
            ".astype(np.float32)}\n"
            "quantize_static(sys.argv[1], sys.argv[3], R(), quant_format=QuantFormat.QDQ, per_channel=True, "
            "reduce_range=True, activation_type=QuantType.QUInt8, weight_type=QuantType.QInt8, "
            "calibrate_method=CalibrationMethod[sys.argv[5]])")


def make_model(path: Path, height: int, width: int) -> None:
    """edgepick's default model, seeded, exported as a float ONNX taking [1, 3, HEIGHT, WIDTH]."""
    import warnings

    import torch

    from edgepick.models import ModelConfig, build_model
    from edgepick.models.blocks import LogitsNet

    torch.manual_seed(0)
    net = LogitsNet(build_model(ModelConfig(num_classes=5))).eval()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        torch.onnx.export(net, torch.rand(1, 3, height, width), str(path), opset_version=13, dynamo=False,
                          input_names=["input"], output_names=["logits"])


def make_images(folder: Path, count: int, height: int, width: int) -> None:
    import cv2
    import numpy as np

    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(0)
    for k in range(count):
        noise = (rng.random((height, width, 3)) * 255).astype(np.uint8)
        cv2.imwrite(str(folder / f"{k:03d}.png"), cv2.GaussianBlur(noise, (0, 0), 8))


def measure(command: list[str]) -> tuple[float, float, str]:
    """Peak resident GB and wall seconds of COMMAND in a process of its own, and its one-line error if it failed."""
    proc = subprocess.run([sys.executable, "-c", MEASURE, *command], capture_output=True, text=True)
    kb, seconds, code = proc.stdout.split()
    return int(kb) / 2**20, float(seconds), proc.stderr.strip() if int(code) else ""


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", default="2048x1024", help="WIDTHxHEIGHT of the model's input")
    ap.add_argument("--counts", default="8,64", help="numbers of calibration tensors")
    ap.add_argument("--methods", default="auto,percentile,minmax,entropy,mse")
    ap.add_argument("--peer-counts", default="2", help="onnxruntime's quantize_static (MinMax and Percentile) on this "
                    "many tensors ('' for none): it keeps every intermediate output of every tensor")
    ap.add_argument("--adaround-counts", default="", help="also with --adaround on this many tensors (as the default "
                    "makes a file again where its outputs are far from fp32's; '' for none)")
    add_output(ap)
    args = ap.parse_args()
    width, height = (int(v) for v in args.size.split("x"))
    counts = [int(v) for v in args.counts.split(",")]
    adaround_counts = [int(v) for v in args.adaround_counts.split(",") if v]
    work = Path(tempfile.mkdtemp(prefix="calib-memory-"))
    model, images = work / "float.onnx", work / "images"
    make_model(model, height, width)
    make_images(images, max([*counts, *adaround_counts]), height, width)
    edgepick = [sys.executable, "-m", "edgepick", "quantize", "static", str(model), "--calib", str(images)]
    infer_gb, infer_s, _ = measure([sys.executable, "-c", INFER, str(model), f"1,3,{height},{width}"])
    rows = [("the float model's own inference (onnxruntime, 1 input)", "-", "-", infer_gb, infer_s, "")]
    for method in args.methods.split(","):
        for count in counts:
            gb, s, error = measure([*edgepick, "--calib-images", str(count), "--calib-method", method,
                                    "--out", str(work / "int8.onnx")])
            rows.append(("edgepick quantize static", method, count, gb, s, error))
    for count in adaround_counts:
        gb, s, error = measure([*edgepick, "--calib-images", str(count), "--adaround", "--out", str(work / "int8.onnx")])
        rows.append(("edgepick quantize static --adaround", "auto", count, gb, s, error))
    for count in filter(None, args.peer_counts.split(",")):
        for method in ("MinMax", "Percentile"):
            gb, s, error = measure([sys.executable, "-c", ORT_PEER, str(model), str(images), str(work / "ort.onnx"),
                                    count, method])
            rows.append(("onnxruntime quantize_static (QDQ, U8S8, per-channel)", method, int(count), gb, s, error))
    command = "python benchmarks/calib_memory.py " + " ".join(shlex.quote(a) for a in sys.argv[1:])
    lines = [f"# Calibration memory: quantize static MODEL.onnx at {width}x{height}", "",
             f"Command: `{command}`  ", machine_line(), "",
             f"Model: edgepick's DeepLabV3-MobileNetV3 (5 classes, seeded weights), float ONNX, input [1, 3, {height}, "
             f"{width}]; calibration images: blurred noise at that size. Each row is one process; peak = its maximum "
             "resident set size. Defaults otherwise (bias correction empirical, placement all).", "",
             "| what | method | tensors | peak RSS (GB) | wall (s) | note |", "|---|---|---|---|---|---|"]
    lines += [f"| {what} | {method} | {count} | {gb:.2f} | {s:.0f} | {error} |" for what, method, count, gb, s, error in rows]
    ours = [gb for what, _, _, gb, _, error in rows if what.startswith("edgepick") and not error]
    if ours:
        lines += ["", f"edgepick's largest peak: {max(ours):.2f} GB; the float model's own inference: {infer_gb:.2f} GB "
                  f"(target: at most 2 GB here, and 1.5x the float model's inference peak + 1 GB = "
                  f"{1.5 * infer_gb + 1:.2f} GB)."]
    lines += ["", "Raw rows (JSON):", "", "```", json.dumps([dict(zip(("what", "method", "tensors", "peak_gb",
                                                                      "wall_s", "error"), r)) for r in rows]), "```"]
    emit("\n".join(lines) + "\n", args)


if __name__ == "__main__":
    main()
