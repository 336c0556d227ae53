"""The same float model quantized by the tools people use instead, side by side in one run:
onnxruntime's `quantize_static` with its defaults and with its best CPU settings (QDQ, U8S8,
per-channel, reduce-range), NNCF on OpenVINO (with OpenVINO's fp32, run in f32, as that engine's
baseline, and a bf16 row on CPUs where OpenVINO runs bf16: AMX or avx512_bf16), and edgepick's
static pass (run by onnxruntime, and by OpenVINO). mIoU, agreement with fp32,
latency on the same threads and images, size. The model's input size is its run's (train it at
640x480 for the thesis's size).

    pip install '.[peers]'      # nncf, openvino
    python benchmarks/peers.py --run demo-out/run --data demo-out/data [--threads 2] [--out FILE.md | --save]
    python benchmarks/peers.py --onnx MODEL.onnx --calib DIR ...   # a model from elsewhere: peers_onnx.py
"""

from __future__ import annotations

import argparse
import shlex
import shutil
import statistics
import sys
import tempfile
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from _common import add_output, emit, interleaved_times, machine_line  # noqa: E402

from edgepick.data.native import NativeDataset  # noqa: E402
from edgepick.geometry import Size  # noqa: E402
from edgepick.metrics import confusion_matrix, segmentation_metrics  # noqa: E402
from edgepick.runtime.session import Segmenter, openvino_config  # noqa: E402


class OrtModel:
    def __init__(self, path: Path, threads: int):
        self.seg = Segmenter(path, threads=threads)
        self.size = self.seg.info.input_size

    def infer(self, image: np.ndarray) -> np.ndarray:
        return self.seg.infer(image)


class OpenVinoModel:
    """A model compiled by OpenVINO for the CPU, float parts in PRECISION (f32, as the runtime's
    `--engine openvino`, unless asked)."""

    def __init__(self, model, threads: int, size: Size, precision: str = "f32"):
        import openvino as ov

        self.compiled = ov.Core().compile_model(model, "CPU", openvino_config(threads, precision))
        self.request = self.compiled.create_infer_request()
        self.size = size

    def runs_in_bf16(self) -> bool:
        """Whether OpenVINO really runs the float parts in bf16 (it falls back to f32 on CPUs without it)."""
        import openvino as ov

        return self.compiled.get_property("INFERENCE_PRECISION_HINT") == ov.Type.bf16

    def infer(self, image: np.ndarray) -> np.ndarray:
        return self.request.infer({0: image})[self.compiled.output(0)][0].astype(np.uint8)


def prepare(rgb: np.ndarray, size: Size) -> np.ndarray:
    return np.ascontiguousarray(cv2.resize(rgb, (size.width, size.height), interpolation=cv2.INTER_AREA))[None]


def evaluate(model, ds: NativeDataset, reference: dict[str, np.ndarray] | None) -> tuple[dict, float | None]:
    """mIoU on the split and the share of pixels equal to the fp32 model's labels."""
    n = len(ds.classes)
    cm = np.zeros((n, n), np.int64)
    same = total = 0
    labels_out = {}
    for sid in ds.ids:
        rgb = ds.rgb(sid)
        labels = cv2.resize(model.infer(prepare(rgb, model.size)), (rgb.shape[1], rgb.shape[0]),
                            interpolation=cv2.INTER_NEAREST)
        labels_out[sid] = labels
        cm += confusion_matrix(ds.mask(sid), labels, n)
        if reference is not None:
            same += int((labels == reference[sid]).sum())
            total += labels.size
    return {"metrics": segmentation_metrics(cm, ds.classes), "labels": labels_out}, (same / total if total else None)


def latency(models: list, images: list[np.ndarray], runs: int) -> list[tuple[float, float]]:
    """p50/p95 ms per model, RUNS timed inferences each, in alternating blocks (_common.interleaved_times),
    so a shared machine's load drifts over all of them alike."""
    inputs = [[prepare(im, m.size) for im in images] for m in models]
    for m, xs in zip(models, inputs):
        for i in range(5):
            m.infer(xs[i % len(xs)])
    calls = [lambda i, m=m, xs=xs: m.infer(xs[i % len(xs)]) for m, xs in zip(models, inputs)]
    return [(statistics.median(t), float(np.percentile(t, 95))) for t in interleaved_times(calls, runs)]


def why_slower(table: list[tuple]) -> str:
    """Where edgepick's int8 on onnxruntime is slower than a peer in this run, and the known causes."""
    ours = next(r for r in table if r[0].startswith("edgepick static (onnxruntime"))
    faster = [r for r in table if r[4] < ours[4] and not r[0].startswith("edgepick static (onnxruntime")]
    if not faster:
        return "edgepick static on onnxruntime had the lowest p50 in this run."
    names = ", ".join(f"{r[0]} ({r[4]:.1f} ms)" for r in faster)
    return (f"Slower in this run: edgepick static on onnxruntime ({ours[4]:.1f} ms p50) against {names}. Where "
            "its time goes, op by op, is benchmarks/quant_speed.py's report (onnxruntime's int8 depthwise convs and "
            "the first conv on the 3-channel image run slower than their fp32 kernels; OpenVINO fuses more of the "
            "graph into its int8 kernels). The runtime can run the same file on OpenVINO (`--engine openvino`, the "
            "`[peers]` extra).")


def main() -> None:
    if "--onnx" in sys.argv[1:]:  # a float ONNX model edgepick did not make: benchmarks/peers_onnx.py
        import peers_onnx

        sys.argv[0] = peers_onnx.__file__
        peers_onnx.main()
        return
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--run", default="demo-out/run", help="float RUN or checkpoint (default: make demo's)")
    ap.add_argument("--data", default="demo-out/data")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--runs", type=int, default=30)
    ap.add_argument("--calib-images", type=int, default=32)
    ap.add_argument("--split", default="val", help="split for accuracy (the demo's test split has only 4 images)")
    ap.add_argument("--model-note", default="", help="how the --run model was made, for the report's header")
    add_output(ap)
    args = ap.parse_args()

    import nncf
    import onnx
    import onnxruntime as ort
    import openvino as ov
    from onnxruntime.quantization import CalibrationDataReader, QuantFormat, QuantType, quantize_static

    from edgepick.export.onnx_export import export_checkpoint
    from edgepick.quant.pt2e.images import agreement_images, folder_images, model_images
    from edgepick.quant.pt2e.passes import quantize_static as edgepick_static

    work = Path(tempfile.mkdtemp(prefix="peers-"))
    try:
        fp32 = Path(export_checkpoint(args.run, work / "fp32.onnx").out)
        size = Segmenter(fp32).info.input_size
        calib = [prepare(im, size) for im in model_images(args.data, "train", args.calib_images, size)]

        class Reader(CalibrationDataReader):
            def __init__(self):
                self.it = iter(calib)

            def get_next(self):
                x = next(self.it, None)
                return None if x is None else {"image": x}

        def with_contract(path: Path) -> Path:
            m = onnx.load(path)  # keep the contract metadata so the runtime session accepts it
            del m.metadata_props[:]
            m.metadata_props.extend(onnx.load(fp32).metadata_props)
            onnx.save(m, path)
            return path

        ort_int8 = work / "ort_default.onnx"
        quantize_static(str(fp32), str(ort_int8), Reader())  # onnxruntime's defaults
        with_contract(ort_int8)
        ort_best = work / "ort_best.onnx"  # its documented CPU choice: QDQ, U8S8, per-channel, reduce-range
        quantize_static(str(fp32), str(ort_best), Reader(), quant_format=QuantFormat.QDQ, per_channel=True,
                        reduce_range=True, activation_type=QuantType.QUInt8, weight_type=QuantType.QInt8)
        with_contract(ort_best)

        ov_fp32 = ov.Core().read_model(str(fp32))
        ov_int8 = nncf.quantize(ov_fp32, nncf.Dataset(calib), subset_size=len(calib))
        ov.save_model(ov_int8, work / "nncf.xml")
        ours = Path(edgepick_static(args.run, folder_images(args.data, "train", args.calib_images),
                                    work / "edgepick.onnx", check_images=agreement_images(args.data),
                                    progress=False).out)

        # OpenVINO's own default for a float model on CPUs with AMX or avx512_bf16: a row only where it is bf16
        bf16 = OpenVinoModel(ov.Core().read_model(str(fp32)), args.threads, size, precision="bf16")

        def mb(*paths: Path) -> float:
            return round(sum(p.stat().st_size for p in paths) / 1e6, 2)

        rows = [("fp32 (onnxruntime)", OrtModel(fp32, args.threads), mb(fp32)),
                ("onnxruntime quantize_static, defaults", OrtModel(ort_int8, args.threads), mb(ort_int8)),
                ("onnxruntime quantize_static, QDQ U8S8 per-channel reduce-range", OrtModel(ort_best, args.threads),
                 mb(ort_best)),
                ("fp32 (OpenVINO)", OpenVinoModel(ov.Core().read_model(str(fp32)), args.threads, size), mb(fp32)),
                *([("bf16 (OpenVINO)", bf16, mb(fp32))] if bf16.runs_in_bf16() else []),
                ("NNCF + OpenVINO", OpenVinoModel(ov_int8, args.threads, size), mb(work / "nncf.xml", work / "nncf.bin")),
                ("edgepick static (onnxruntime)", OrtModel(ours, args.threads), mb(ours)),
                ("edgepick static (OpenVINO)", OpenVinoModel(ov.Core().read_model(str(ours)), args.threads, size),
                 mb(ours))]
        ds = NativeDataset.open(args.data, args.split)
        images = [ds.rgb(sid) for sid in ds.ids[:10]]
        reference = None
        accuracy = []
        for _name, model, _mbytes in rows:
            result, agree = evaluate(model, ds, reference)
            if reference is None:
                reference = result["labels"]
            accuracy.append((result["metrics"]["miou"], result["metrics"]["pixel_acc"], agree))
        times = latency([model for _, model, _ in rows], images, args.runs)
        table = [(name, *acc, *t, mbytes) for (name, _, mbytes), acc, t in zip(rows, accuracy, times)]
    finally:
        shutil.rmtree(work, ignore_errors=True)

    fp32_p50 = table[0][4]
    ov_fp32_p50 = next(r[4] for r in table if r[0] == "fp32 (OpenVINO)")
    lines = [f"# Peers: the same float model quantized by other tools, {args.threads} threads",
             "", f"Command: `python benchmarks/peers.py {shlex.join(sys.argv[1:])}`  ",
             f"{machine_line()}; onnxruntime "
             f"{ort.__version__}, openvino {ov.__version__.split('-')[0]}, nncf {nncf.__version__}; model: {args.run} "
             f"(input {size}); accuracy on {len(ds)} {args.split} images of {args.data}; latency over "
             f"{args.runs} runs per model after warm-up, the models timed in alternating blocks of 5 (one process, same "
             f"images).", *([f"Model: {args.model_note}"] if args.model_note else []), "",
             "| Quantized by (engine) | mIoU (%) | Pixel acc (%) | agreement with fp32 (%) | p50 (ms) | p95 (ms) "
             "| vs fp32 (onnxruntime) | vs its engine's fp32 | Size (MB) |", "|---|---|---|---|---|---|---|---|---|"]
    for name, miou, acc, agree, p50, p95, mbytes in table:
        own = ov_fp32_p50 if "OpenVINO" in name else fp32_p50
        lines.append(f"| {name} | {100 * miou:.2f} | {100 * acc:.2f} | {'-' if agree is None else f'{100 * agree:.2f}'} "
                     f"| {p50:.1f} | {p95:.1f} | {fp32_p50 / p50:.2f}x | {own / p50:.2f}x | {mbytes:.2f} |")
    labels = np.concatenate([v.ravel() for v in reference.values()])
    top_share = np.bincount(labels).max() / labels.size
    if top_share > 0.97:
        lines += ["", f"The fp32 model gives one class to {100 * top_share:.1f}% of the pixels: a latency-only model; "
                      "its accuracy and agreement columns say nothing about the passes."]
    lines += ["", why_slower(table)]
    report = "\n".join(lines) + "\n"
    emit(report, args)


if __name__ == "__main__":
    main()
