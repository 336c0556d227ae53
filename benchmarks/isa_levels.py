"""edgepick int8 files on one CPU at several instruction-set levels: how closely each decides as a
reference does (object pixels and all pixels) and its p50, on onnxruntime (at the CPU's own level:
it offers no cap) and on OpenVINO capped by ONEDNN_MAX_CPU_ISA (AVX2, the laptops without VNNI;
AVX512_CORE_VNNI; the CPU's own). What it shows: whether 8-bit weights, exact where the CPU adds
int8 products in int32 (VNNI, AMX), are worth more than the 7-bit weights that AVX2's int16 pairs
need (docs/quantization.md, "Weight bits").

    python benchmarks/isa_levels.py --models w7.onnx w8.onnx --reference fp32.onnx --data DATA \\
        [--split test --count 16] [--isa default,AVX512_CORE_VNNI,AVX2] [--threads 2 --runs 40] [--save]

The reference is an edgepick model run by onnxruntime here (typically the fp32 export), or labels
saved earlier with --write-labels (the fp32 labels of the same images, made on another machine).
Each OpenVINO level runs in a process of its own: oneDNN reads its cap once, when it loads.
"""

from __future__ import annotations

import argparse
import json
import os
import shlex
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from _common import add_output, emit, interleaved_times, machine_line, object_agreement  # noqa: E402

from edgepick.data.native import NativeDataset  # noqa: E402
from edgepick.runtime.engine import Engine  # noqa: E402
from edgepick.runtime.session import Segmenter  # noqa: E402

DEFAULT_LEVEL = "default"  # OpenVINO at the CPU's own instruction set


def images(data: str, split: str, count: int) -> list[np.ndarray]:
    """The first COUNT images of DATA/SPLIT (all if fewer), HxWx3 uint8 RGB."""
    ds = NativeDataset.open(data, split)
    return [ds.rgb(i) for i in ds.ids[:count]]


def labels_of(model: Segmenter, frames: list[np.ndarray]) -> np.ndarray:
    return np.stack([model.labels(rgb) for rgb in frames])


def agreement(labels: np.ndarray, reference: np.ndarray) -> tuple[float, float]:
    """(object-pixel, all-pixel) agreement of LABELS with REFERENCE: object pixels are those either
    labels as something other than class 0 (background)."""
    if labels.shape != reference.shape:
        raise SystemExit(f"labels of shape {labels.shape} against a reference of {reference.shape}: "
                         "not the same images")
    return object_agreement(labels, reference), float((labels == reference).mean())


def measure(models: list[str], engine: Engine, frames: list[np.ndarray], reference: np.ndarray,
            threads: int, runs: int) -> list[dict]:
    """Per model: agreement with REFERENCE and the p50 of one frame's labels, timed in alternating blocks."""
    segmenters = [Segmenter(path, threads, engine) for path in models]
    rows = []
    for seg in segmenters:
        objects, every = agreement(labels_of(seg, frames), reference)
        rows.append({"objects": objects, "pixels": every})
    images_in = [seg.prepare(frames[0]) for seg in segmenters]
    times = interleaved_times([lambda i, s=seg, x=x: s.infer(x) for seg, x in zip(segmenters, images_in)], runs)
    for row, t in zip(rows, times):
        row["p50_ms"] = statistics.median(t)
    return rows


def child(args: argparse.Namespace) -> None:
    """One engine at one level, in this process: print the rows as JSON."""
    frames = images(args.data, args.split, args.count)
    reference = np.load(args.labels)["labels"]
    print(json.dumps(measure(args.models, Engine(args.engine), frames, reference, args.threads, args.runs)))


def run_level(args: argparse.Namespace, engine: Engine, level: str, labels: Path) -> list[dict]:
    """measure() in a fresh process, OpenVINO capped at LEVEL (oneDNN reads ONEDNN_MAX_CPU_ISA once)."""
    env = dict(os.environ)
    env.pop("ONEDNN_MAX_CPU_ISA", None)
    if level != DEFAULT_LEVEL:
        env["ONEDNN_MAX_CPU_ISA"] = level
    cmd = [sys.executable, __file__, "--child", "--engine", engine.value, "--labels", str(labels), "--models",
           *args.models, "--data", args.data, "--split", args.split, "--count", str(args.count),
           "--threads", str(args.threads), "--runs", str(args.runs)]
    done = subprocess.run(cmd, env=env, capture_output=True, text=True)
    if done.returncode:
        raise SystemExit(f"{engine} at {level} failed:\n{done.stderr[-2000:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def report(args: argparse.Namespace, results: list[tuple[str, str, list[dict]]], images_seen: int,
           reference_note: str) -> str:
    names = [Path(m).name for m in args.models]
    lines = [
        "# edgepick int8 files at several instruction-set levels of one CPU",
        "",
        f"Command: `python benchmarks/isa_levels.py {shlex.join(sys.argv[1:])}`",
        "",
        machine_line() + "  ",
        f"Libraries: onnxruntime {_version('onnxruntime')}, OpenVINO {_version('openvino')}.",
        "",
        f"{images_seen} images of the {args.split} split; reference: "
        f"{reference_note}. Object pixels: those either model labels as an object. p50: one frame's "
        f"labels on {args.threads} threads, the models of one level timed in alternating blocks of 5 "
        f"({args.runs} calls each, one process per level); compare p50s within a level.",
        "",
        "| Engine | Level | Model | Object-pixel agreement (%) | All-pixel agreement (%) | p50 (ms) | p50 / first model's |",
        "|---|---|---|---|---|---|---|",
    ]
    for engine, level, rows in results:
        for name, row in zip(names, rows):
            lines.append(f"| {engine} | {level} | {name} | {100 * row['objects']:.2f} | {100 * row['pixels']:.2f} | "
                         f"{row['p50_ms']:.1f} | {row['p50_ms'] / rows[0]['p50_ms']:.2f} |")
    return "\n".join(lines) + "\n"


def _version(module: str) -> str:
    try:
        return __import__(module).__version__
    except ImportError:
        return "not installed"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--models", nargs="+", required=True, help="edgepick ONNX files to compare")
    ap.add_argument("--reference", default=None, help="edgepick model whose onnxruntime labels are the reference")
    ap.add_argument("--reference-labels", default=None, help="labels saved by --write-labels instead")
    ap.add_argument("--write-labels", default=None, help="save the reference's labels to this .npz, and stop")
    ap.add_argument("--data", required=True, help="an edgepick data set")
    ap.add_argument("--split", default="test")
    ap.add_argument("--count", type=int, default=16, help="images, the first of the split")
    ap.add_argument("--isa", default=f"{DEFAULT_LEVEL},AVX512_CORE_VNNI,AVX2",
                    help="OpenVINO levels: ONEDNN_MAX_CPU_ISA values, or 'default' for none")
    ap.add_argument("--engines", default="onnxruntime,openvino")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--runs", type=int, default=40)
    ap.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--engine", default=None, help=argparse.SUPPRESS)
    ap.add_argument("--labels", default=None, help=argparse.SUPPRESS)
    add_output(ap)
    args = ap.parse_args()
    if args.child:
        return child(args)
    if (args.reference is None) == (args.reference_labels is None):
        raise SystemExit("give one of --reference MODEL and --reference-labels NPZ")
    frames = images(args.data, args.split, args.count)
    if args.reference:
        reference = labels_of(Segmenter(args.reference, args.threads), frames)
        note = f"{Path(args.reference).name}'s labels on onnxruntime here"
    else:
        reference = np.load(args.reference_labels)["labels"]
        note = f"the labels in {Path(args.reference_labels).name}"
    if args.write_labels:
        np.savez_compressed(args.write_labels, labels=reference)
        print(f"labels of {len(frames)} images written to {args.write_labels}", file=sys.stderr)
        return None
    with tempfile.TemporaryDirectory() as tmp:
        labels = Path(tmp) / "reference.npz"
        np.savez_compressed(labels, labels=reference)
        results = []
        for engine in [Engine(e) for e in args.engines.split(",")]:
            levels = args.isa.split(",") if engine == Engine.OPENVINO else [DEFAULT_LEVEL]
            for level in levels:
                print(f"-- {engine} at {level}", file=sys.stderr)
                results.append((engine.value, level if engine == Engine.OPENVINO else "the CPU's own",
                                run_level(args, engine, level, labels)))
    emit(report(args, results, len(frames), note), args)
    return None


if __name__ == "__main__":
    main()
