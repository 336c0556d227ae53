"""Static PTQ calibration methods compared on one float run: val mIoU of the int8 file on
onnxruntime and on OpenVINO, and onnxruntime-vs-torch label agreement, for each activation-range
method with 7-bit (the default), 8-bit and first-7 weights (--weight-bits).

    python benchmarks/calib_methods.py --run demo-out/run --data demo-out/data [--out FILE.md | --save]
"""

from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from _common import add_output, emit, machine_line  # noqa: E402

from edgepick.evaluation import evaluate  # noqa: E402
from edgepick.export.onnx_export import export_checkpoint  # noqa: E402
from edgepick.quant.config import QuantConfig  # noqa: E402
from edgepick.quant.pt2e.images import agreement_images, folder_images  # noqa: E402
from edgepick.quant.pt2e.passes import quantize_static  # noqa: E402

CASES = [("minmax", "7"), ("minmax", "8"), ("percentile", "7"), ("percentile", "8"), ("percentile", "first-7"),
         ("mse", "7"), ("entropy", "7")]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--run", default="demo-out/run", help="float RUN or checkpoint (default: make demo's)")
    ap.add_argument("--data", default="demo-out/data")
    ap.add_argument("--calib-images", type=int, default=64)
    ap.add_argument("--split", default="val")
    add_output(ap)
    args = ap.parse_args()

    try:
        import openvino  # noqa: F401
        engines = ["onnxruntime", "openvino"]
    except ImportError:
        engines = ["onnxruntime"]
    work = Path(tempfile.mkdtemp(prefix="calib-"))
    rows = []
    try:
        fp32 = export_checkpoint(args.run, work / "fp32.onnx").out
        calib, check = folder_images(args.data, "train", args.calib_images), agreement_images(args.data)
        base = {e: evaluate(fp32, args.data, args.split, progress=False, engine=e)["miou"] for e in engines}
        rows.append(("fp32", "-", base, None))
        for method, bits in CASES:
            out = work / f"{method}-{bits}.onnx"
            print(f"-- {method} weight bits {bits}", file=sys.stderr, flush=True)
            r = quantize_static(args.run, calib, out, QuantConfig(calib_method=method, weight_bits=bits),
                                check_images=check, progress=False)
            miou = {e: evaluate(out, args.data, args.split, progress=False, engine=e)["miou"] for e in engines}
            rows.append((method, bits, miou, r.agreement_vs_torch))
    finally:
        shutil.rmtree(work, ignore_errors=True)

    lines = ["# Static PTQ: calibration methods on one float run", "",
             f"Command: `python benchmarks/calib_methods.py {' '.join(sys.argv[1:])}`  ",
             f"{machine_line()}; model {args.run}; "
             f"{args.calib_images} calibration images of the train split; mIoU on the {args.split} split of "
             f"{args.data}.", "",
             "| Method | Weights | " + " | ".join(f"mIoU {e} (%)" for e in engines) + " | onnxruntime-vs-torch agreement (%) |",
             "|---|---|" + "---|" * len(engines) + "---|"]
    for method, bits, miou, agree in rows:
        lines.append(f"| {method} | {bits} | " + " | ".join(f"{100 * miou[e]:.2f}" for e in engines)
                     + f" | {'-' if agree is None else f'{100 * agree:.2f}'} |")
    emit("\n".join(lines) + "\n", args)


if __name__ == "__main__":
    main()
