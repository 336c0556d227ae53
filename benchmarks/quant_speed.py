"""fp32 vs int8 (static PTQ) latency of the default model in onnxruntime, with the per-op breakdown.

    python benchmarks/quant_speed.py [--checkpoint RUN] [--threads 2] [--runs 30] [--out FILE.md | --save]

Without --checkpoint a seeded, untrained DeepLabV3-MobileNetV3 at 640x480 is used (latency
does not depend on the weights; accuracy does, so mIoU needs a trained RUN). Both files run
in this one process, same thread count, same input, after warm-up; medians and the ratio
are what to quote. Per-op times come from onnxruntime's profiler.
"""

from __future__ import annotations

import argparse
import json
import shutil
import statistics
import sys
import tempfile
from collections import defaultdict
from pathlib import Path

import numpy as np
import onnxruntime as ort

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from _common import add_output, emit, interleaved_times, machine_line, untrained_checkpoint  # noqa: E402

WHOLE = "int8, convs whole"
FLOAT_ACT = "int8, float activations"
DW_FLOAT = "int8, depthwise convs in float"
FIRST_FLOAT = "int8, first conv in float"


def session(path: str, threads: int, profile: str | None = None) -> ort.InferenceSession:
    opts = ort.SessionOptions()
    opts.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
    opts.intra_op_num_threads, opts.inter_op_num_threads = threads, 1
    opts.log_severity_level = 3
    if profile:
        opts.enable_profiling, opts.profile_file_prefix = True, profile
        opts.optimized_model_filepath = profile + ".optimized.onnx"  # the graph the profiler's node names refer to
    return ort.InferenceSession(path, opts, providers=["CPUExecutionProvider"])


def latency(paths: list[str], image: np.ndarray, threads: int, runs: int) -> list[list[float]]:
    """RUNS timed inferences of each model after 5 warm-up, interleaved in blocks (_common.interleaved_times)."""
    sessions = [session(p, threads) for p in paths]
    for sess in sessions:
        for _ in range(5):
            sess.run(None, {"image": image})
    return interleaved_times([lambda i, s=s: s.run(None, {"image": image}) for s in sessions], runs)


def conv_kinds(optimized: str) -> dict[str, str]:
    """Node name -> kind of convolution (first, depthwise, 1x1, dense) in onnxruntime's optimized graph."""
    import onnx

    graph = onnx.load(optimized, load_external_data=False).graph
    weights = {t.name: list(t.dims) for t in graph.initializer if len(t.dims) == 4}
    kinds = {}
    for node in graph.node:
        if "Conv" not in node.op_type:
            continue
        group = next((a.i for a in node.attribute if a.name == "group"), 1)
        w = next((weights[x] for x in node.input if x in weights), None)
        if group > 1:
            kinds[node.name] = "depthwise"
        elif w and w[1] == 3:
            kinds[node.name] = "first (3 input channels)"
        elif w and w[2:] == [1, 1]:
            kinds[node.name] = "1x1"
        else:
            kinds[node.name] = "dense kxk (ASPP, head; cropped taps included)"
    return kinds


def per_op(path: str, image: np.ndarray, threads: int, runs: int, prefix: str,
           by: str = "op") -> dict[str, float]:
    """Mean ms per run for each op type, node, or kind of conv (`by` = op | node | conv),
    from onnxruntime's profiler after warm-up."""
    sess = session(path, threads, profile=prefix)
    for _ in range(3 + runs):
        sess.run(None, {"image": image})
    trace = json.loads(Path(sess.end_profiling()).read_text())
    kinds = conv_kinds(prefix + ".optimized.onnx") if by == "conv" else {}
    per_run = defaultdict(float)
    for ev in trace:
        if ev.get("cat") == "Node" and ev["name"].endswith("_kernel_time"):
            key, node = ev["args"]["op_name"], ev["name"].removesuffix("_kernel_time")
            if by == "node":
                shape = next(iter(ev["args"].get("output_type_shape", [{}])[0].values()), [])
                key = f"{key} {node} -> {shape}"
            elif by == "conv":
                key = kinds.get(node, "other ops")
            per_run[key] += ev["dur"] / 1000
    total_runs = 3 + runs
    return {op: ms / total_runs for op, ms in sorted(per_run.items(), key=lambda kv: -kv[1])}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--checkpoint", default=None, help="RUN or checkpoint (default: untrained model at 640x480)")
    ap.add_argument("--data", default=None, help="data set for calibration and mIoU (default: 24 synthetic scenes)")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--runs", type=int, default=30)
    ap.add_argument("--calib-images", type=int, default=16)
    ap.add_argument("--variant", default="standard", choices=["standard", "edge"], help="model variant (untrained)")
    ap.add_argument("--nodes", type=int, default=8, help="also list the N slowest nodes of each model")
    add_output(ap)
    args = ap.parse_args()

    import torch

    from edgepick.data.synth import SynthConfig, synthesize
    from edgepick.evaluation import evaluate
    from edgepick.export.onnx_export import export_checkpoint
    from edgepick.geometry import Size
    from edgepick.quant.config import Pt2eOptions, QuantConfig
    from edgepick.quant.pt2e.images import folder_images
    from edgepick.quant.pt2e.passes import quantize_static
    from edgepick.train.checkpoint import load_model

    work = Path(tempfile.mkdtemp(prefix="quant-speed-"))
    data = Path(args.data) if args.data else work / "data"
    if not args.data:
        synthesize(data, SynthConfig(scenes=24, seed=3, splits=(16, 4, 4)), progress=False)
    classes = json.loads((data / "meta.json").read_text())["classes"]
    ckpt = args.checkpoint or str(untrained_checkpoint(work / "untrained.pt", Size(640, 480), classes, args.variant))
    fp32 = export_checkpoint(ckpt, work / "fp32.onnx")
    calib = folder_images(data, "train", args.calib_images)
    int8 = quantize_static(ckpt, calib, work / "int8.onnx", progress=False)
    whole = quantize_static(ckpt, calib, work / "int8_whole.onnx", progress=False,
                            export_passes=("integer_activations",))  # the same int8 model, convs whole
    float_act = quantize_static(ckpt, calib, work / "int8_float_act.onnx", pt2e=Pt2eOptions(hardswish_gate=False),
                                progress=False, export_passes=("crop_convs",))  # hardswish, SE, pooling in float
    model, _ = load_model(ckpt)
    depthwise = [n for n, m in model.named_modules() if isinstance(m, torch.nn.Conv2d) and m.groups > 1]
    dw_float = quantize_static(ckpt, calib, work / "int8_dw_float.onnx", QuantConfig(keep_float=depthwise),
                               progress=False)
    first = [next(n for n, m in model.named_modules() if isinstance(m, torch.nn.Conv2d) and m.in_channels == 3)]
    first_float = quantize_static(ckpt, calib, work / "int8_first_float.onnx", QuantConfig(keep_float=first),
                                  progress=False)
    size = fp32.input_size
    image = (np.random.default_rng(0).random((1, *size.hw, 3)) * 255).astype(np.uint8)

    rows, ops, nodes, convs = {}, {}, {}, {}
    models = (("fp32", fp32), ("int8", int8), (WHOLE, whole), (FLOAT_ACT, float_act), (DW_FLOAT, dw_float),
              (FIRST_FLOAT, first_float))
    timed = latency([f.out for _, f in models], image, args.threads, args.runs)
    for (name, f), t in zip(models, timed):
        rows[name] = {"p50": statistics.median(t), "p95": float(np.percentile(t, 95)), "mb": f.size_bytes / 1e6}
        if name in (WHOLE, FLOAT_ACT, DW_FLOAT, FIRST_FLOAT):  # timed only
            continue
        ops[name] = per_op(f.out, image, args.threads, 10, str(work / f"prof_{name}"))
        nodes[name] = per_op(f.out, image, args.threads, 10, str(work / f"nodes_{name}"), by="node")
        convs[name] = per_op(f.out, image, args.threads, 10, str(work / f"convs_{name}"), by="conv")
        if args.checkpoint:
            rows[name]["miou"] = evaluate(f.out, data, "test", progress=False)["miou"]
    ratio = rows["fp32"]["p50"] / rows["int8"]["p50"]
    conv_fp32 = ops["fp32"].get("Conv", 0.0) + ops["fp32"].get("FusedConv", 0.0)
    conv_int8 = ops["int8"].get("QLinearConv", 0.0) + ops["int8"].get("Conv", 0.0)  # kept-float convs count too

    lines = [f"# fp32 vs int8 (static PTQ) in onnxruntime {ort.__version__}, {args.threads} threads, "
             f"input {size}",
             "", f"Command: `python benchmarks/quant_speed.py {' '.join(sys.argv[1:])}`  ",
             f"{machine_line()}; "
             f"model: {'checkpoint ' + args.checkpoint if args.checkpoint else f'untrained DeepLabV3-MobileNetV3 ({args.variant})'}; "
             f"{args.runs} runs each after 5 warm-up, one process, the models timed in alternating blocks of 5.", "",
             "| Model | p50 (ms) | p95 (ms) | Size (MB) |" + (" mIoU |" if args.checkpoint else ""),
             "|---|---|---|---|" + ("---|" if args.checkpoint else "")]
    for name, r in rows.items():
        lines.append(f"| {name} | {r['p50']:.1f} | {r['p95']:.1f} | {r['mb']:.2f} |"
                     + (f" {r['miou']:.4f} |" if 'miou' in r else " |" if args.checkpoint else ""))
    lines += ["", f"**int8 / fp32 speed-up (p50): {ratio:.2f}x**; onnxruntime-vs-torch label agreement of the "
              f"int8 file: {int8['agreement_vs_torch']}", "",
              f"`{WHOLE}` is the same int8 model without the export's crop of padding-only taps "
              f"(`edgepick/export/crop_convs.py`): {rows['fp32']['p50'] / rows[WHOLE]['p50']:.2f}x fp32; "
              f"the crop makes int8 {rows[WHOLE]['p50'] / rows['int8']['p50']:.2f}x faster. `{FLOAT_ACT}` is the int8 "
              f"model as exported before hardswish was quantized as x * hardsigmoid(x) and before "
              f"`edgepick/export/int8_activations.py` (HardSigmoid, HardSwish, ReduceMean run in float): "
              f"{rows['fp32']['p50'] / rows[FLOAT_ACT]['p50']:.2f}x fp32; the integer activations make int8 "
              f"{rows[FLOAT_ACT]['p50'] / rows['int8']['p50']:.2f}x faster. `{DW_FLOAT}` keeps the "
              f"{len(depthwise)} depthwise convs float (`--keep-float`), where onnxruntime's int8 kernels gain least: "
              f"{rows['fp32']['p50'] / rows[DW_FLOAT]['p50']:.2f}x fp32. `{FIRST_FLOAT}` keeps `{first[0]}`, the "
              f"conv on the 3-channel image, float (its int8 kernel is slower than fp32's): "
              f"{rows['fp32']['p50'] / rows[FIRST_FLOAT]['p50']:.2f}x fp32.", "",
              f"Convolutions alone (profiler): fp32 {conv_fp32:.1f} ms, int8 {conv_int8:.1f} ms, {conv_fp32 / conv_int8:.2f}x. "
              f"Had every other int8 op cost nothing, int8 would run at most {rows['fp32']['p50'] / conv_int8:.2f}x "
              f"faster than fp32 on this CPU.", "", "Per-op time (ms per run, onnxruntime profiler):", "",
              "| Op | fp32 | | Op | int8 |", "|---|---|---|---|---|"]
    f_ops, i_ops = list(ops["fp32"].items()), list(ops["int8"].items())
    for k in range(max(len(f_ops), len(i_ops))):
        a = f_ops[k] if k < len(f_ops) else ("", None)
        b = i_ops[k] if k < len(i_ops) else ("", None)
        lines.append(f"| {a[0]} | {'' if a[1] is None else f'{a[1]:.2f}'} | | {b[0]} | "
                     f"{'' if b[1] is None else f'{b[1]:.2f}'} |")
    lines += ["", "Time by kind of convolution (ms per run, onnxruntime profiler; int8 kept-float convs count "
              "with their kind):", "", "| Kind | fp32 | int8 | fp32 / int8 |", "|---|---|---|---|"]
    for kind in sorted(set(convs["fp32"]) | set(convs["int8"]), key=lambda k: (k == "other ops", -convs["fp32"].get(k, 0))):
        a, b = convs["fp32"].get(kind, 0.0), convs["int8"].get(kind, 0.0)
        lines.append(f"| {kind} | {a:.2f} | {b:.2f} | {a / b if b else float('nan'):.2f}x |")
    for name in nodes:
        lines += ["", f"Slowest {args.nodes} nodes, {name} (ms per run):", ""]
        lines += [f"- {ms:.2f} `{node}`" for node, ms in list(nodes[name].items())[:args.nodes]]
    report = "\n".join(lines) + "\n"
    emit(report, args)
    shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
