"""Static PTQ methods (weight bits, bias correction, CLE, AdaRound) on a float ONNX model edgepick did
not make, over several calibration seeds: how closely each int8 file decides as fp32 does, per
output (on the foreground: the pixels either model decides as non-background, the measure that
cannot be lucky; and on all pixels), calibration time, and the int8 latency on onnxruntime (and
OpenVINO with --openvino).

The last --held inputs of --calib are where agreement is measured and latency timed; each seed draws
--calib-count of the inputs before them to calibrate.

    python benchmarks/ptq_methods_onnx.py --onnx MODEL.onnx --calib DIR [preprocessing options]
        [--seeds 0,1,2] [--cases 7/none,first-7/none,7/empirical,7/none/ada,...] [--openvino]
        [--out FILE.md | --save]     # --save: benchmarks/results/ptq-methods/<date>-<machine>-<model>.md

A case is WEIGHT_BITS/BIAS_CORRECTION, optionally /METHODS (cle, ada, pPERCENTILE joined by +), as in
ptq_methods.py.
"""

from __future__ import annotations

import argparse
import os
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
from peers_onnx import OpenVino, Ort, add_input_options, input_tensors  # noqa: E402
from ptq_methods import adaround_text, case, seven_bit_convs, spread, start_case  # noqa: E402

from edgepick.quant.config import PtqMethods  # noqa: E402
from edgepick.quant.fidelity import guess_task  # noqa: E402
from edgepick.quant.onnx.static import quantize_onnx_static  # noqa: E402


def agreement(model, reference: list[list[np.ndarray]], inputs: list[np.ndarray], nhwc: bool,
              probability: list[bool]) -> tuple[list[float], list[float]]:
    """Per output, (foreground agreement, all-pixel agreement) of MODEL with the fp32 outputs
    REFERENCE: the foreground is where either decides something other than class 0 (or False);
    NaN for an output where neither ever does."""
    outputs = len(probability)
    fg_same, fg_total, same, total = (np.zeros(outputs) for _ in range(4))
    for x, ref in zip(inputs, reference):
        for k, (a, b) in enumerate(zip(model(x), ref)):
            task = guess_task(a.shape, probability[k], nhwc)
            da, db = task.decide(a, nhwc), task.decide(b, nhwc)
            if da is None or db is None:  # a raw output decides nothing
                continue
            equal, foreground = da == db, (da != 0) | (db != 0)
            fg_same[k] += (equal & foreground).sum()
            fg_total[k] += foreground.sum()
            same[k] += equal.sum()
            total[k] += equal.size
    return list(np.where(fg_total > 0, fg_same / np.maximum(fg_total, 1), np.nan)), list(same / np.maximum(total, 1))


def per_output(values: list[list[float]]) -> str:
    """Mean (min-max) over seeds, per output, joined by ' / ' ('no foreground' where NaN)."""
    columns = [[v[k] for v in values] for k in range(len(values[0]))]
    return " / ".join("no foreground" if any(np.isnan(c)) else spread(c) for c in columns)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--onnx", required=True, help="float ONNX model from any exporter")
    ap.add_argument("--calib", required=True, help="folder of .npy input tensors or images")
    ap.add_argument("--held", type=int, default=16, help="the last this many inputs measure agreement and time")
    ap.add_argument("--calib-count", type=int, default=32, help="inputs each seed draws to calibrate")
    ap.add_argument("--seeds", default="0,1,2", help="calibration seeds (which inputs are drawn)")
    ap.add_argument("--cases", default="7/none,8/none,first-7/none,7/empirical,first-7/empirical,7/none/ada",
                    help="WEIGHT_BITS/BIAS_CORRECTION[/METHODS] cases to compare (METHODS: cle, ada, pPERCENTILE joined by +)")
    ap.add_argument("--adaround-budget", type=float, default=PtqMethods.adaround_budget_s,
                    help="AdaRound's time budget per pass, seconds [default: none, its steps planned from the model]")
    add_input_options(ap)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--runs", type=int, default=20, help="timed calls per file (the first seed's files)")
    ap.add_argument("--openvino", action="store_true",
                    help="also run each file on OpenVINO (the peers extra): agreement with OpenVINO's fp32 and "
                         "p50; ONEDNN_MAX_CPU_ISA in the environment caps its instruction set (e.g. AVX2)")
    ap.add_argument("--model-note", default="", help="where the model comes from, for the report's header")
    add_output(ap)
    args = ap.parse_args()
    seeds = [int(s) for s in args.seeds.split(",")]
    cases = [case(c) for c in args.cases.split(",")]

    import onnx

    tensors = input_tensors(args)
    if len(tensors) < args.held + args.calib_count:
        raise SystemExit(f"--calib: {len(tensors)} inputs, need --held {args.held} + --calib-count {args.calib_count}")
    pool, held = tensors[:-args.held], tensors[-args.held:]
    shape = tuple(int(v) for v in args.input_shape.split(",")) if args.input_shape else held[0].shape
    nhwc = args.layout == "nhwc"
    float_model = onnx.load(args.onnx)
    producer = {o: n for n in float_model.graph.node for o in n.output}
    outputs = [o.name for o in float_model.graph.output]
    probability = [getattr(producer.get(o), "op_type", "") in ("Sigmoid", "Softmax") for o in outputs]

    work = Path(tempfile.mkdtemp(prefix="ptq-methods-onnx-"))
    results: dict[tuple, list[tuple[list[float], list[float], float, int]]] = {c: [] for c in cases}
    ov_agree: dict[tuple, list[list[float]]] = {c: [] for c in cases}
    timed: dict[tuple, Path] = {}
    try:
        from edgepick.export.onnx_io import fix_input_shape, load_float_onnx

        fp32_path = work / "fp32.onnx"
        fixed = load_float_onnx(args.onnx)
        fix_input_shape(fixed, shape)
        onnx.save(fixed, fp32_path)
        fp32 = Ort(fp32_path, args.threads)
        reference = [fp32(x) for x in held]
        if args.openvino:
            import openvino as ov

            ov_reference = [OpenVino(ov.Core().read_model(str(fp32_path)), args.threads)(x) for x in held]
        for seed in seeds:
            drawn = np.random.default_rng(seed).choice(len(pool), args.calib_count, replace=False)
            calib = [pool[i] for i in sorted(drawn)]
            for bits, method, extra in cases:
                out, configs = start_case(seed, (bits, method, extra), work, args.adaround_budget)
                r = quantize_onnx_static(args.onnx, calib, out, **configs, input_shape=shape, progress=False)
                foreground, every = agreement(Ort(out, args.threads), reference, held, nhwc, probability)
                sevens = seven_bit_convs(bits, r.quant, r.int8_convs)
                results[(bits, method, extra)].append((foreground, every, r.calib_s, sevens))
                if args.openvino:
                    ov_model = OpenVino(ov.Core().read_model(str(out)), args.threads)
                    ov_agree[(bits, method, extra)].append(
                        agreement(ov_model, ov_reference, held, nhwc, probability)[0])
                timed.setdefault((bits, method, extra), out)
                print(f"   foreground agreement {' / '.join(f'{100 * v:.2f}' for v in foreground)}%, "
                      f"{sevens} 7-bit convs, calibration {r.calib_s:.1f} s", file=sys.stderr, flush=True)
        print(f"-- timing seed {seeds[0]}'s files", file=sys.stderr, flush=True)
        models = [Ort(path, args.threads) for path in timed.values()]
        if args.openvino:
            models += [OpenVino(ov.Core().read_model(str(path)), args.threads) for path in timed.values()]
        times = interleaved_times([lambda i, m=m: m(held[i % len(held)]) for m in models], args.runs)
        medians = [statistics.median(t) for t in times]
        p50 = {c: medians[k::len(timed)] for k, c in enumerate(timed)}  # per engine
    finally:
        shutil.rmtree(work, ignore_errors=True)

    import onnxruntime

    engines = f"onnxruntime {onnxruntime.__version__}"
    if args.openvino:
        engines += (f", OpenVINO {ov.__version__.split('-')[0]} "
                    f"(ONEDNN_MAX_CPU_ISA={os.environ.get('ONEDNN_MAX_CPU_ISA', 'unset')})")
    lines = [f"# Static PTQ methods on a model edgepick did not make: {Path(args.onnx).name}", "",
             f"Command: `python benchmarks/ptq_methods_onnx.py {shlex.join(sys.argv[1:])}`  ",
             f"{machine_line()}; {engines}, {args.threads} threads.  ",
             *([f"Model: {args.model_note}  "] if args.model_note else []),
             f"Input {list(shape)}; outputs {', '.join(outputs)}. Each seed draws {args.calib_count} of the first "
             f"{len(pool)} inputs to calibrate; agreement and latency on the last {len(held)}. Mean over seeds "
             f"{args.seeds}, (min-max) in brackets, per output. Foreground agreement: the share of pixels that "
             "either model decides as non-background (argmax above class 0, or a one-channel map above its "
             "threshold) on which the int8 decision equals fp32's. Calibration time: the median over seeds of "
             "calibration and what the method measures. p50: the first seed's files, timed in alternating "
             f"blocks of 5 ({args.runs} calls each, one process). " + adaround_text(args.adaround_budget), "",
             "| Weight bits | 7-bit convs | Bias correction | CLE / AdaRound / percentile | Foreground agreement with fp32 (%) | "
             "All-pixel agreement (%) | Calibration (s) | p50 (ms) |"
             + (" OpenVINO: foreground agreement with its fp32 (%) | OpenVINO p50 (ms) |" if args.openvino else ""),
             "|---|---|---|---|---|---|---|---|" + ("---|---|" if args.openvino else "")]
    for key, rows in results.items():
        bits, method, extra = key
        foreground, every, calib_s, sevens = zip(*rows)
        lines.append(f"| {bits} | {min(sevens)}-{max(sevens)} | {method} | {extra.replace('+', ' + ') or '-'} | "
                     f"{per_output(list(foreground))} | {per_output(list(every))} | "
                     f"{statistics.median(calib_s):.1f} | {p50[key][0]:.1f} |"
                     + (f" {per_output(ov_agree[key])} | {p50[key][1]:.1f} |" if args.openvino else ""))
    emit("\n".join(lines) + "\n", args, suffix=re.sub(r"[^a-z0-9]+", "-", Path(args.onnx).stem.lower()).strip("-"))


if __name__ == "__main__":
    main()
