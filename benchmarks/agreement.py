"""onnxruntime-vs-torch label agreement of a static int8 model, with and without the conv biases
snapped to onnxruntime's int32 grid, at each onnxruntime graph-optimisation level (DISABLE runs
DQ -> float Conv -> Q, BASIC and up fuse convs into QLinearConv with an int32 bias).

    python benchmarks/agreement.py --run demo-out/run --data demo-out/data [--out FILE.md | --save]
"""

from __future__ import annotations

import argparse
import copy
import shutil
import sys
import tempfile
from pathlib import Path

import numpy as np
import onnxruntime as ort
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from _common import add_output, emit, machine_line  # noqa: E402

from edgepick.export.onnx_export import contract_metadata, export_onnx  # noqa: E402
from edgepick.quant.config import QuantConfig  # noqa: E402
from edgepick.quant.pt2e.graph import as_input, convert, prepare  # noqa: E402
from edgepick.quant.pt2e.images import model_images  # noqa: E402
from edgepick.train.checkpoint import load_model  # noqa: E402

LEVELS = {"DISABLE_ALL": ort.GraphOptimizationLevel.ORT_DISABLE_ALL,
          "BASIC": ort.GraphOptimizationLevel.ORT_ENABLE_BASIC,
          "ALL": ort.GraphOptimizationLevel.ORT_ENABLE_ALL}


def onnx_labels(path: Path, level, images: list[np.ndarray], threads: int = 2) -> list[np.ndarray]:
    opts = ort.SessionOptions()
    opts.graph_optimization_level, opts.intra_op_num_threads, opts.log_severity_level = level, threads, 3
    session = ort.InferenceSession(str(path), opts, providers=["CPUExecutionProvider"])
    return [session.run(["labels"], {"image": rgb[None]})[0][0] for rgb in images]


@torch.no_grad()
def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--run", default="demo-out/run", help="float RUN or checkpoint (default: make demo's)")
    ap.add_argument("--data", default="demo-out/data")
    ap.add_argument("--calib-images", type=int, default=64)
    ap.add_argument("--images", type=int, default=12, help="val images compared")
    add_output(ap)
    args = ap.parse_args()

    model, ckpt = load_model(args.run)
    size = ckpt.input_size
    config = QuantConfig()
    calib = model_images(args.data, "train", args.calib_images, size)
    images = model_images(args.data, "val", args.images, size)
    prepared = prepare(model, config, size, qat=False)
    for rgb in calib:
        prepared(as_input(rgb))
    work = Path(tempfile.mkdtemp(prefix="agreement-"))
    rows, labels = [], {}
    try:
        for snap in (False, True):
            converted = convert(copy.deepcopy(prepared), snap_biases=snap)
            path = export_onnx(converted, work / f"snap{snap}.onnx", contract_metadata(ckpt, "int8", {"mode": "static"}), size)
            ref = [converted(as_input(rgb)).argmax(1)[0].numpy() for rgb in images]
            for name, level in LEVELS.items():
                ours = onnx_labels(path, level, images)
                labels[snap, name] = ours
                rows.append((snap, name, float(np.mean([np.mean(a == b) for a, b in zip(ours, ref)]))))
    finally:
        shutil.rmtree(work, ignore_errors=True)
    same_model = float(np.mean([np.mean(a == b) for a, b in zip(labels[False, "ALL"], labels[True, "ALL"])]))

    lines = ["# onnxruntime-vs-torch label agreement: conv biases on the int32 grid", "",
             f"Command: `python benchmarks/agreement.py {' '.join(sys.argv[1:])}`  ",
             f"{machine_line()}; onnxruntime "
             f"{ort.__version__}, torch {torch.__version__}; model {args.run} (input {size}); static PTQ "
             f"({config.calib_method}, {'7' if config.reduce_range else '8'}-bit weights, {args.calib_images} calibration "
             f"images); agreement over {args.images} val images (share of pixels with the same label).", "",
             "| conv biases | onnxruntime optimisation | agreement with torch's simulation (%) |", "|---|---|---|"]
    for snap, name, agree in rows:
        lines.append(f"| {'snapped to the int32 grid' if snap else 'float (as trained)'} | {name} | {100 * agree:.3f} |")
    lines += ["", f"onnxruntime's labels (ALL) from the two files agree on {100 * same_model:.4f}% of pixels: the snap "
              "changes torch's simulation, not the int8 model onnxruntime runs."]
    emit("\n".join(lines) + "\n", args)


if __name__ == "__main__":
    main()
