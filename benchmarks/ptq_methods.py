"""Static PTQ methods (weight bits, bias correction, CLE, AdaRound) compared on one float run, over several
calibration seeds: how closely the int8 file follows fp32 on onnxruntime (labels equal on object
pixels, the pixels either model calls an object; and the test mIoU against fp32's), how closely
onnxruntime follows torch's simulation of the same int8 model (where 8-bit weights saturate an
AVX2 CPU's int16 pairs, it does not), calibration time, and the int8 latency.

Object-pixel agreement is the measure that cannot be lucky: on a weak model, quantization noise
can raise mIoU by chance, while agreeing with fp32 can only be earned.

    python benchmarks/ptq_methods.py --run RUN --data DATA [--seeds 0,1,2]
        [--cases 7/none,7/empirical,7/none/cle,7/none/ada,...] [--adaround-budget S] [--openvino]
        [--out FILE.md | --save]

A case is WEIGHT_BITS/BIAS_CORRECTION, optionally /METHODS: cle (cross-layer equalization), ada
(AdaRound) and pPERCENTILE (the activation ranges at that fixed percentile, instead of quantize
static's default, auto) joined by +, e.g. /cle+ada or /p99.999.
"""

from __future__ import annotations

import argparse
import os
import re
import shutil
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from _common import add_output, emit, interleaved_times, machine_line, object_agreement  # noqa: E402

from edgepick.data.native import NativeDataset  # noqa: E402
from edgepick.export.onnx_export import export_checkpoint  # noqa: E402
from edgepick.metrics import confusion_matrix, segmentation_metrics  # noqa: E402
from edgepick.quant.config import BiasCorrection, CalibMethod, PtqMethods, QuantConfig, WeightBits  # noqa: E402
from edgepick.quant.pt2e.images import agreement_images, folder_images  # noqa: E402
from edgepick.quant.pt2e.passes import quantize_static  # noqa: E402
from edgepick.runtime.engine import Engine  # noqa: E402
from edgepick.runtime.session import Segmenter  # noqa: E402


def labels(model: Path, frames: list[np.ndarray], engine: Engine = Engine.ONNXRUNTIME) -> list[np.ndarray]:
    seg = Segmenter(model, threads=2, engine=engine)
    return [seg.labels(rgb) for rgb in frames]


def scores(ours: list[np.ndarray], fp32: list[np.ndarray], truth: list[np.ndarray], classes: int) -> tuple[float, float]:
    """(share of object pixels where OURS equals FP32, test mIoU of OURS against TRUTH)."""
    return object_agreement(ours, fp32), miou(ours, truth, classes)


def miou(pred: list[np.ndarray], truth: list[np.ndarray], classes: int) -> float:
    cm = sum(confusion_matrix(t, p, classes) for p, t in zip(pred, truth))
    return float(segmentation_metrics(cm)["miou"])


def openvino_version() -> str:
    import openvino

    return openvino.__version__.split("-")[0]


def versions() -> str:
    import onnxruntime
    import torch
    import torchao

    return f"torch {torch.__version__}, torchao {torchao.__version__}, onnxruntime {onnxruntime.__version__}"


def spread(values: list[float]) -> str:
    """Mean and (min-max) of percentages."""
    pct = [100 * v for v in values]
    return f"{statistics.mean(pct):.2f} ({min(pct):.2f}-{max(pct):.2f})"


def case(text: str) -> tuple[WeightBits, BiasCorrection, str]:
    """A --cases entry: (weight bits, bias correction, methods): methods "" or "+"-joined tokens of
    cle, ada and pPERCENTILE (the activation ranges' percentile instead of the default)."""
    bits, method, *extra = text.split("/")
    methods = extra[0] if extra else ""
    tokens = methods.split("+") if methods else []
    if (len(extra) > 1 or len(set(tokens)) != len(tokens)
            or not all(t in ("cle", "ada") or re.fullmatch(r"p\d+(\.\d+)?", t) for t in tokens)):
        raise SystemExit(f"--cases {text}: expected WEIGHT_BITS/BIAS_CORRECTION[/METHODS], METHODS cle, ada "
                         f"or pPERCENTILE joined by +, e.g. 7/none/cle+ada or 7/empirical/p99.999")
    return WeightBits(bits), BiasCorrection(method), methods


def adaround_text(seconds: float | None) -> str:
    """How AdaRound's steps were set, for a results file."""
    return (f"AdaRound's budget: {seconds:g} s per pass." if seconds is not None else
            "AdaRound: its steps per conv planned from the model's size (no time budget; edgepick/quant/methods.py).")


def start_case(seed: int, key: tuple[WeightBits, BiasCorrection, str], work: Path,
               adaround_budget_s: float | None) -> tuple[Path, dict]:
    """Announce case KEY for SEED on stderr; its int8 file's path in WORK and its configs (by keyword)."""
    bits, method, extra = key
    print(f"-- seed {seed}, weight bits {bits}, bias correction {method} {extra}", file=sys.stderr, flush=True)
    tokens = extra.split("+")
    percentile = next((float(t[1:]) for t in tokens if t.startswith("p")), None)
    config = QuantConfig(weight_bits=bits,
                         **({"calib_method": CalibMethod.PERCENTILE, "percentile": percentile} if percentile else {}))
    methods = PtqMethods(bias_correction=method, equalize="cle" in tokens, adaround="ada" in tokens,
                         adaround_budget_s=adaround_budget_s)
    return work / f"{bits}-{method}-{extra}-{seed}.onnx", {"config": config, "methods": methods}


def seven_bit_convs(bits: WeightBits, quant: dict, int8_convs: int) -> int:
    """How many convs a pass gave 7-bit weights."""
    if bits == WeightBits.FIRST_SEVEN:
        return len(quant.get("seven_bit_convs", []))
    return int8_convs if bits == WeightBits.SEVEN else 0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--run", required=True, help="float RUN or checkpoint")
    ap.add_argument("--data", required=True)
    ap.add_argument("--split", default="test")
    ap.add_argument("--seeds", default="0,1,2", help="calibration seeds (which train images are drawn)")
    ap.add_argument("--cases", default="7/none,8/none,first-7/none,7/fast,7/empirical,first-7/empirical,7/none/cle,"
                    "7/none/ada,7/empirical/cle,7/empirical/ada,7/empirical/cle+ada",
                    help="WEIGHT_BITS/BIAS_CORRECTION[/METHODS] cases to compare (METHODS: cle, ada, pPERCENTILE joined by +)")
    ap.add_argument("--adaround-budget", type=float, default=PtqMethods.adaround_budget_s,
                    help="AdaRound's time budget per pass, seconds [default: none, its steps planned from the model]")
    ap.add_argument("--runs", type=int, default=20, help="timed int8 calls per case (seed 0's file)")
    ap.add_argument("--openvino", action="store_true",
                    help="also time each file on OpenVINO (the peers extra), in the same alternating blocks; "
                         "ONEDNN_MAX_CPU_ISA in the environment caps its instruction set (e.g. AVX2)")
    ap.add_argument("--calib-images", type=int, default=None, help="[default: quantize static's]")
    add_output(ap)
    args = ap.parse_args()
    seeds = [int(s) for s in args.seeds.split(",")]
    cases = [case(c) for c in args.cases.split(",")]

    ds = NativeDataset.open(args.data, args.split)
    frames, truth = [ds.rgb(i) for i in ds.ids], [ds.mask(i) for i in ds.ids]
    classes = len(ds.classes)
    work = Path(tempfile.mkdtemp(prefix="ptq-methods-"))
    results: dict[tuple[WeightBits, BiasCorrection, str], list[tuple[float, float, float, float, int]]] = {
        c: [] for c in cases}
    timed: dict[tuple[WeightBits, BiasCorrection, str], Path] = {}
    ov_agree: dict[tuple[WeightBits, BiasCorrection, str], list[float]] = {c: [] for c in cases}
    rules: dict[tuple[WeightBits, BiasCorrection, str], list[str]] = {c: [] for c in cases}  # per seed
    try:
        fp32_path = Path(export_checkpoint(args.run, work / "fp32.onnx").out)
        fp32 = labels(fp32_path, frames)
        fp32_miou = miou(fp32, truth, classes)
        fp32_ov = labels(fp32_path, frames, Engine.OPENVINO) if args.openvino else []
        check = agreement_images(args.data)
        for seed in seeds:
            calib = folder_images(args.data, "train", args.calib_images, seed)
            for bits, method, extra in cases:
                out, configs = start_case(seed, (bits, method, extra), work, args.adaround_budget)
                t0 = time.perf_counter()
                r = quantize_static(args.run, calib, out, **configs, check_images=check, progress=False)
                pass_s = time.perf_counter() - t0
                agree, int8_miou = scores(labels(out, frames), fp32, truth, classes)
                if args.openvino:  # the same file on OpenVINO, against fp32 on OpenVINO
                    ov_agree[(bits, method, extra)].append(object_agreement(labels(out, frames, Engine.OPENVINO), fp32_ov))
                sevens = seven_bit_convs(bits, r.quant, r.int8_convs)
                results[(bits, method, extra)].append(
                    (agree, int8_miou - fp32_miou, r.agreement_vs_torch, r.calib_s, sevens))
                timed.setdefault((bits, method, extra), out)
                rules[(bits, method, extra)].append(r.quant.get("ranges", {}).get("rule", "-"))
                print(f"   object agreement {100 * agree:.2f}%, mIoU {100 * (int8_miou - fp32_miou):+.2f} pp, "
                      f"onnxruntime-vs-torch {100 * r.agreement_vs_torch:.2f}%, "
                      f"{sevens} 7-bit convs, range rule {rules[(bits, method, extra)][-1]}, calibration {r.calib_s:.1f} s, "
                      f"pass {pass_s:.1f} s", file=sys.stderr, flush=True)
        print(f"-- timing seed {seeds[0]}'s files", file=sys.stderr, flush=True)
        engines = [Engine.ONNXRUNTIME, Engine.OPENVINO] if args.openvino else [Engine.ONNXRUNTIME]
        sessions = [Segmenter(path, threads=2, engine=engine) for engine in engines for path in timed.values()]
        frame = frames[0]
        times = interleaved_times([lambda i, s=seg: s.labels(frame) for seg in sessions], args.runs)
        medians = [statistics.median(t) for t in times]
        p50 = {case: medians[k::len(timed)] for k, case in enumerate(timed)}  # per engine
    finally:
        shutil.rmtree(work, ignore_errors=True)

    lines = ["# Static PTQ methods on one float run", "",
             f"Command: `python benchmarks/ptq_methods.py {' '.join(sys.argv[1:])}`  ",
             f"{machine_line()}; model {args.run}; fp32 mIoU {100 * fp32_miou:.2f}% on the {args.split} split "
             f"({len(frames)} images) of {args.data}; calibration seeds {args.seeds}; onnxruntime, 2 threads.  ",
             f"Libraries: {versions()}.", "",
             "Mean over the seeds, (min-max) in brackets. Object-pixel agreement: the share of pixels that either "
             f"model labels as an object on which the int8 labels equal fp32's (onnxruntime, {args.split} split). "
             "onnxruntime-vs-torch: labels equal to torch's simulation of the same int8 model on 8 val images. "
             "Calibration time: prepare, calibration, conversion and what the method measures, without the "
             f"export. p50: int8 labels for one {args.split} frame, the first seed's files timed in alternating blocks "
             f"of 5 ({args.runs} calls each, one process)"
             + (f"; OpenVINO {openvino_version()}, ONEDNN_MAX_CPU_ISA={os.environ.get('ONEDNN_MAX_CPU_ISA', 'unset')}"
                if args.openvino else "") + ".", "",
             adaround_text(args.adaround_budget), "",
             "Range rule: the one each seed's pass used (calib_method auto chooses it per pass).", "",
             "| Weight bits | 7-bit convs | Bias correction | CLE / AdaRound / percentile | Range rule (per seed) | "
             "Object-pixel agreement with fp32 (%) | "
             "mIoU - fp32's (pp) | onnxruntime-vs-torch (%) | Calibration (s) | p50 (ms) |"
             + (" OpenVINO: object-pixel agreement with its fp32 (%) | OpenVINO p50 (ms) |" if args.openvino else ""),
             "|---|---|---|---|---|---|---|---|---|---|" + ("---|---|" if args.openvino else "")]
    for (bits, method, extra), rows in results.items():
        agree, drop, vs_torch, calib_s, sevens = zip(*rows)
        drops = [100 * d for d in drop]
        lines.append(f"| {bits} | {min(sevens)}-{max(sevens)} | {method} | {extra.replace('+', ' + ') or '-'} | "
                     f"{', '.join(rules[(bits, method, extra)])} | "
                     f"{spread(list(agree))} | {statistics.mean(drops):+.2f} "
                     f"({min(drops):+.2f} to {max(drops):+.2f}) | {spread(list(vs_torch))} | "
                     f"{statistics.median(calib_s):.1f} | {p50[(bits, method, extra)][0]:.1f} |"
                     + (f" {spread(ov_agree[(bits, method, extra)])} | {p50[(bits, method, extra)][1]:.1f} |"
                        if args.openvino else ""))
    emit("\n".join(lines) + "\n", args)


if __name__ == "__main__":
    main()
