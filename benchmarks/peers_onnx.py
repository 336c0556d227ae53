"""A float ONNX model edgepick did not make, quantized by the tools people use and by edgepick, side
by side in one run: onnxruntime's `quantize_static` with its defaults and with its best CPU
settings (QDQ, U8S8, per-channel, reduce-range), NNCF on OpenVINO, and edgepick's
`quantize static MODEL.onnx` (run by onnxruntime and by OpenVINO). Per output, how often each
int8 model decides a pixel as fp32 does (ArgMax over channels, or a one-channel map thresholded);
p50/p95 latency on the same threads and inputs, timed in alternating blocks; size.

The first --calib-count inputs of --calib calibrate every tool; the rest (all, if there are no
more) are where agreement is measured and latency timed.

    pip install '.[peers]'      # nncf, openvino
    python benchmarks/peers_onnx.py --onnx MODEL.onnx --calib DIR [preprocessing options] [--save]
    # --save: benchmarks/results/peers-onnx/<date>-<machine>-<model>.md
    python benchmarks/peers.py --onnx ...   # the same
    # --edgepick-methods first-7/empirical,7/empirical/convs: two more edgepick rows each
    # (onnxruntime, OpenVINO), with static PTQ's methods that work on an ONNX graph (weight bits, bias
    # correction, /cle), the placement (/convs) and the GELU form (/gelu-sigmoid)
"""

from __future__ import annotations

import argparse
import re
import shlex
import shutil
import statistics
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from _common import add_output, emit, interleaved_times, machine_line  # noqa: E402
from _quantizers import OpenVino, Ort, nncf_quantize, ort_quantize, ort_ready  # noqa: E402

from edgepick.errors import ParameterError  # noqa: E402
from edgepick.geometry import Size  # noqa: E402
from edgepick.quant.config import (  # noqa: E402
    BiasCorrection,
    GeluForm,
    OnnxOptions,
    Placement,
    PtqMethods,
    QuantConfig,
    WeightBits,
)  # noqa: E402
from edgepick.quant.fidelity import guess_task  # noqa: E402
from edgepick.quant.onnx.inputs import folder_tensors  # noqa: E402
from edgepick.quant.onnx.static import quantize_onnx_static  # noqa: E402
from edgepick.runtime.preprocessing import Preprocessing  # noqa: E402
from edgepick.runtime.session import openvino_config  # noqa: E402


def onnxruntime_by_op(path: Path, threads: int, x: np.ndarray, runs: int = 10) -> dict[str, float]:
    """onnxruntime's own profiler: ms per run by op type (the kernels it runs after its fusions)."""
    import json
    import os

    import onnxruntime as ort

    opts = ort.SessionOptions()
    opts.intra_op_num_threads, opts.inter_op_num_threads, opts.log_severity_level = threads, 1, 3
    opts.enable_profiling = True
    opts.profile_file_prefix = str(Path(tempfile.gettempdir()) / "peers-onnx-profile")
    session = ort.InferenceSession(str(path), opts, providers=["CPUExecutionProvider"])
    name = session.get_inputs()[0].name
    for _ in range(runs):
        session.run(None, {name: x})
    trace = session.end_profiling()
    totals: dict[str, float] = {}
    for event in json.loads(Path(trace).read_text()):
        if event.get("cat") == "Node" and event["name"].endswith("_kernel_time"):
            op = event["args"]["op_name"]
            totals[op] = totals.get(op, 0.0) + event["dur"] / 1000 / runs
    os.remove(trace)
    return totals


def openvino_by_layer(model, threads: int, x: np.ndarray, runs: int = 10) -> dict[str, float]:
    """OpenVINO's own per-layer counters: median ms per run by layer type and the kernel's precision."""
    import openvino as ov

    compiled = ov.Core().compile_model(model, "CPU", {**openvino_config(threads), "PERF_COUNT": True})
    request = compiled.create_infer_request()
    per_run: dict[str, list[float]] = {}
    for _ in range(runs):
        request.infer({0: x})
        totals: dict[str, float] = {}
        for info in request.profiling_info:
            if info.status != info.Status.EXECUTED:
                continue
            precision = info.exec_type.rsplit("_", 1)[-1]
            key = f"{info.node_type} ({precision})"
            totals[key] = totals.get(key, 0.0) + info.real_time.total_seconds() * 1000
        for key, ms in totals.items():
            per_run.setdefault(key, []).append(ms)
    return {key: statistics.median(ms) for key, ms in per_run.items()}


def agreement(model, reference: list[list[np.ndarray]], inputs: list[np.ndarray], nhwc: bool,
              probability: list[bool]) -> list[float]:
    """Per output, the share of pixels where MODEL decides as the fp32 outputs REFERENCE do."""
    same, total = np.zeros(len(probability)), np.zeros(len(probability))
    for x, ref in zip(inputs, reference):
        for k, (a, b) in enumerate(zip(model(x), ref)):
            task = guess_task(a.shape, probability[k], nhwc)
            da, db = task.decide(a, nhwc), task.decide(b, nhwc)
            if da is None or db is None:  # a raw output decides nothing
                continue
            same[k] += (da == db).sum()
            total[k] += da.size
    return list(same / np.maximum(total, 1))


GELU_SIGMOID = f"gelu-{GeluForm.SIGMOID.value}"


def method_config(text: str) -> dict:
    """An --edgepick-methods entry WEIGHT_BITS/BIAS_CORRECTION[/cle][/convs][/gelu-sigmoid] as the configs of a pass
    (by the keyword quantize_onnx_static takes each as)."""
    bits, method, *extra = text.split("/")
    if (not set(extra) <= {"cle", Placement.CONVS.value, GELU_SIGMOID} or len(set(extra)) < len(extra)
            or bits not in set(WeightBits) or method not in set(BiasCorrection)):
        raise SystemExit(f"--edgepick-methods {text}: expected WEIGHT_BITS/BIAS_CORRECTION[/cle][/convs][/{GELU_SIGMOID}]")
    placement = Placement.CONVS if Placement.CONVS.value in extra else Placement.ALL
    gelu = GeluForm.SIGMOID if GELU_SIGMOID in extra else GeluForm.FLOAT
    try:
        return {"config": QuantConfig(weight_bits=bits),
                "methods": PtqMethods(bias_correction=method, equalize="cle" in extra),
                "options": OnnxOptions(placement=placement, gelu=gelu)}
    except ParameterError as e:
        raise SystemExit(f"--edgepick-methods {text}: {e}") from None


def add_input_options(ap: argparse.ArgumentParser) -> None:
    """The options that make --calib's images into the model's input tensors, and fix its shape."""
    ap.add_argument("--input-shape", default=None, help="N,C,H,W for a model with dynamic dims")
    ap.add_argument("--size", default=None, help="WIDTHxHEIGHT the images are resized to")
    ap.add_argument("--channels", default="rgb")
    ap.add_argument("--scale", type=float, default=1 / 255)
    ap.add_argument("--mean", default="0,0,0")
    ap.add_argument("--std", default="1,1,1")
    ap.add_argument("--layout", default="nchw")


def input_tensors(args: argparse.Namespace) -> list[np.ndarray]:
    """--calib's inputs as NCHW (or NHWC) float tensors with the batch axis."""
    prep = Preprocessing(size=Size.parse(args.size) if args.size else None, channels=args.channels,
                         scale=args.scale, mean=tuple(float(v) for v in args.mean.split(",")),
                         std=tuple(float(v) for v in args.std.split(",")), layout=args.layout)
    return [t if t.ndim == 4 else t[None] for t in folder_tensors(args.calib, prep)]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--onnx", required=True, help="float ONNX model from any exporter")
    ap.add_argument("--calib", required=True, help="folder of .npy input tensors or images")
    ap.add_argument("--calib-count", type=int, default=32, help="the first this many inputs calibrate")
    add_input_options(ap)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--runs", type=int, default=30)
    ap.add_argument("--model-note", default="", help="where the model comes from, for the report's header")
    ap.add_argument("--edgepick-methods", default="", help="comma-separated WEIGHT_BITS/BIAS_CORRECTION[/cle]"
                    f"[/convs][/{GELU_SIGMOID}] cases, two more edgepick rows each (onnxruntime, OpenVINO), e.g. "
                    f"first-7/empirical,7/empirical/convs,7/empirical/{GELU_SIGMOID}")
    add_output(ap)
    args = ap.parse_args()
    methods = {text: method_config(text) for text in filter(None, args.edgepick_methods.split(","))}

    import nncf
    import onnx
    import onnxruntime as ort
    import openvino as ov

    from edgepick.export.onnx_io import fix_input_shape, load_float_onnx, opset

    tensors = input_tensors(args)
    calib, held = tensors[:args.calib_count], tensors[args.calib_count:] or tensors
    shape = tuple(int(v) for v in args.input_shape.split(",")) if args.input_shape else calib[0].shape
    nhwc = args.layout == "nhwc"

    work = Path(tempfile.mkdtemp(prefix="peers-onnx-"))
    try:
        model = load_float_onnx(args.onnx)
        opset_in = opset(model)
        fix_input_shape(model, shape)
        fp32 = work / "fp32.onnx"
        onnx.save(model, fp32)
        lifted = ort_ready(fp32, work / "pre.onnx")  # onnxruntime's per-channel QDQ needs opset 13
        ort_default, ort_best = work / "ort_default.onnx", work / "ort_best.onnx"
        ort_quantize(work / "pre.onnx", ort_default, calib, best=False)
        ort_quantize(work / "pre.onnx", ort_best, calib, best=True)
        nncf_model = nncf_quantize(fp32, calib)
        ov.save_model(nncf_model, work / "nncf.xml")
        ours = quantize_onnx_static(args.onnx, calib, work / "edgepick.onnx", input_shape=shape, progress=False)

        def mb(*paths: Path) -> float:
            return round(sum(p.stat().st_size for p in paths) / 1e6, 2)

        t = args.threads
        rows = [("fp32 (onnxruntime)", Ort(fp32, t), mb(fp32)),
                ("onnxruntime quantize_static, defaults", Ort(ort_default, t), mb(ort_default)),
                ("onnxruntime quantize_static, QDQ U8S8 per-channel reduce-range", Ort(ort_best, t), mb(ort_best)),
                ("fp32 (OpenVINO)", OpenVino(ov.Core().read_model(str(fp32)), t), mb(fp32)),
                ("NNCF + OpenVINO", OpenVino(nncf_model, t), mb(work / "nncf.xml", work / "nncf.bin")),
                ("edgepick static (onnxruntime)", Ort(Path(ours.out), t), mb(Path(ours.out))),
                ("edgepick static (OpenVINO)", OpenVino(ov.Core().read_model(ours.out), t), mb(Path(ours.out)))]
        ort_files = {"edgepick static (onnxruntime)": Path(ours.out)}
        for k, (text, configs) in enumerate(methods.items()):
            path = work / f"edgepick-{k}.onnx"
            quantize_onnx_static(args.onnx, calib, path, **configs, input_shape=shape, progress=False)
            ort_files[f"edgepick static, {text} (onnxruntime)"] = path
            rows.append((f"edgepick static, {text} (onnxruntime)", Ort(path, t), mb(path)))
            rows.append((f"edgepick static, {text} (OpenVINO)", OpenVino(ov.Core().read_model(str(path)), t), mb(path)))
        producer = {o: n for n in model.graph.node for o in n.output}
        outputs = [o.name for o in model.graph.output]
        probability = [getattr(producer.get(o), "op_type", "") in ("Sigmoid", "Softmax") for o in outputs]
        reference = [rows[0][1](x) for x in held]
        agree = [agreement(m, reference, held, nhwc, probability) for _, m, _ in rows]
        times = interleaved_times([lambda i, m=m: m(held[i % len(held)]) for _, m, _ in rows], args.runs)
        # profiled: onnxruntime's best file, edgepick's default one and, with methods, edgepick's fastest
        fastest_ort = min((statistics.median(ms), label) for (label, _, _), ms in zip(rows, times) if label in ort_files)
        profiled = {"onnxruntime quantize_static, best": ort_best, "edgepick": Path(ours.out)}
        if fastest_ort[1] != "edgepick static (onnxruntime)":
            profiled[fastest_ort[1]] = ort_files[fastest_ort[1]]
        ops = {label: onnxruntime_by_op(path, args.threads, held[0]) for label, path in profiled.items()}
        layers = {label: openvino_by_layer(model_ir, args.threads, held[0]) for label, model_ir in
                  (("NNCF", nncf_model), ("edgepick", ov.Core().read_model(ours.out)))}
    finally:
        shutil.rmtree(work, ignore_errors=True)

    p50 = [statistics.median(ms) for ms in times]
    p95 = [float(np.percentile(ms, 95)) for ms in times]
    best = p50[2]
    nncf_p50 = p50[4]
    fastest = min((m50, label) for (label, _, _), m50 in zip(rows, p50) if label.startswith("edgepick") and "OpenVINO" in label)
    lines = [f"# Peers on a model edgepick did not make: {Path(args.onnx).name}, {args.threads} threads", "",
             f"Command: `python benchmarks/peers_onnx.py {shlex.join(sys.argv[1:])}`  ",
             f"{machine_line()}; onnxruntime {ort.__version__}, openvino {ov.__version__.split('-')[0]}, nncf "
             f"{nncf.__version__}, onnx {onnx.__version__}. Model: opset {opset_in}, input {list(shape)}, outputs "
             f"{', '.join(outputs)}. {len(calib)} inputs calibrate every tool; agreement with fp32 and latency on "
             f"{len(held)} {'other ' if held is not tensors else ''}inputs, {args.runs} timed runs per model after "
             "warm-up, the models in alternating blocks of 5 (one process).",
             *([f"Model: {args.model_note}"] if args.model_note else []),
             *(["onnxruntime's `quantize_static` writes an invalid file from this opset-"
                f"{opset_in} model with per-channel weights (DequantizeLinear's axis needs opset 13); its rows are "
                "for the model lifted to opset 13 by onnx's version converter first, as a user would."]
               if lifted else []), "",
             "| Quantized by (engine) | agreement with fp32 (%), per output | p50 (ms) | p95 (ms) | vs fp32 "
             "(onnxruntime) | Size (MB) |", "|---|---|---|---|---|---|"]
    for (label, _, size_mb), a, m50, m95 in zip(rows, agree, p50, p95):
        lines.append(f"| {label} | {' / '.join(f'{100 * v:.2f}' for v in a)} | {m50:.1f} | {m95:.1f} "
                     f"| {p50[0] / m50:.2f}x | {size_mb:.2f} |")
    lines += ["", f"edgepick on onnxruntime against onnxruntime's own best settings: {best / p50[5]:.2f}x (p50; "
                  f"target 1.25x). edgepick on OpenVINO against NNCF + OpenVINO: {nncf_p50 / p50[6]:.2f}x (target: "
                  "1.00x or more).",
              *([f"edgepick's fastest file on onnxruntime against onnxruntime's own best settings: "
                 f"{best / fastest_ort[0]:.2f}x ({fastest_ort[1]}).",
                 f"edgepick's fastest file on OpenVINO against NNCF + OpenVINO: {nncf_p50 / fastest[0]:.2f}x "
                 f"({fastest[1]})."] if methods else []), "",
              f"edgepick's pass: {ours.int8_convs} of {ours.convs} convs int8"
              f"{' (float: ' + ', '.join(ours.float_convs) + ')' if ours.float_convs else ''}; rewrites "
              f"{', '.join(f'{k} {v}' for k, v in ours.rewrites.items() if v)}."]
    kinds = sorted(set().union(*ops.values()), key=lambda k: -max(by_op.get(k, 0.0) for by_op in ops.values()))
    lines += ["", "onnxruntime's profiler, ms per run by op type (after its QDQ fusions), its best-settings file "
                  "against edgepick's (and edgepick's fastest file, if another; one run of 10 calls after the "
                  "timing; totals differ from p50 by the profiler's own cost):", "",
              "| op | " + " | ".join(f"{label} (ms)" for label in ops) + " |", "|---|" + "---|" * len(ops),
              *(f"| {k} | " + " | ".join(f"{by_op.get(k, 0.0):.2f}" for by_op in ops.values()) + " |"
                for k in kinds[:14]),
              "| total | " + " | ".join(f"{sum(by_op.values()):.2f}" for by_op in ops.values()) + " |"]
    kinds = sorted(set(layers["NNCF"]) | set(layers["edgepick"]),
                   key=lambda k: -max(layers["NNCF"].get(k, 0.0), layers["edgepick"].get(k, 0.0)))
    lines += ["", "OpenVINO's per-layer counters (`PERF_COUNT`), median ms per run by layer type and kernel "
                  "precision, NNCF's IR against edgepick's file:", "",
              "| layer type (precision) | NNCF + OpenVINO (ms) | edgepick (OpenVINO) (ms) |", "|---|---|---|",
              *(f"| {k} | {layers['NNCF'].get(k, 0.0):.2f} | {layers['edgepick'].get(k, 0.0):.2f} |"
                for k in kinds[:14])]
    emit("\n".join(lines) + "\n", args, suffix=re.sub(r"[^a-z0-9]+", "-", Path(args.onnx).stem.lower()).strip("-"))


if __name__ == "__main__":
    main()
