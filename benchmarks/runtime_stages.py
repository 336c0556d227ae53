"""Per-stage and per-sub-step time of the runtime on the synthetic cell's 640x480 frames, on a fixed
thread count (target: the grasp step's p95 <= 5 ms).

    python benchmarks/runtime_stages.py [--model m.onnx ...] [--engine onnxruntime|openvino] [--threads 2]
                                        [--frames 200] [--out FILE.md | --save]

Frames: the synthetic cell's (camera 0.7 m over the table, seeds 0, 1, ... 50 frames each), the
ones `bench --cell` and `pick --camera synth-cell` see. Without --model, the shipped reference
model (edgepick/reference). Stages as Table 5.6 counts them (pre, inference, post, grasp) and the
grasp step's sub-steps (runtime/grasp.py Laps), p50 and p95 over the frames; the grasp step also
on the scenes' true labels. One process, the same frames for every model, after warm-up.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
import onnxruntime as ort

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from _common import add_output, emit, machine_line  # noqa: E402

from edgepick.data.render import CLASSES  # noqa: E402
from edgepick.reference import reference_model  # noqa: E402
from edgepick.runtime.engine import Engine  # noqa: E402
from edgepick.runtime.grasp import Laps  # noqa: E402
from edgepick.runtime.pipeline import STAGES, Perception, Pipeline  # noqa: E402
from edgepick.runtime.session import Segmenter  # noqa: E402
from edgepick.sim.camera import SynthCamera  # noqa: E402
from edgepick.sim.oracle import TruthPipeline  # noqa: E402

PER_SEED = 50
MOUNT_M = 0.7


def cell_frames(count: int) -> list:
    """COUNT frames of the synthetic cell: seeds 0, 1, ..., PER_SEED frames each."""
    frames = []
    for seed in range((count + PER_SEED - 1) // PER_SEED):
        camera = SynthCamera(640, 480, seed=seed, mount_height_m=MOUNT_M)
        frames += [camera.read() for _ in range(min(PER_SEED, count - len(frames)))]
    return frames


def percentiles(runs: list[Perception]) -> dict[str, tuple[float, float]]:
    """(p50, p95) ms of each stage, of 'outside inference' and the total, and of each grasp sub-step."""
    series = {s: [r.ms[s] for r in runs] for s in STAGES}
    series["outside inference"] = [sum(v for k, v in r.ms.items() if k != "inference") for r in runs]
    series["total"] = [sum(r.ms.values()) for r in runs]
    series.update({f"grasp: {s}": [r.grasp_ms[s] for r in runs] for s in Laps.STEPS})
    return {k: (float(np.percentile(v, 50)), float(np.percentile(v, 95))) for k, v in series.items()}


def by_objects(runs: list[Perception]) -> dict[int, tuple[int, float, float, float]]:
    """Per count of records in a frame: (frames, median object pixels, grasp p50, grasp p95 ms)."""
    table = {}
    for n in sorted({len(r.records) for r in runs}):
        some = [r for r in runs if len(r.records) == n]
        ms = [r.ms["grasp"] for r in some]
        pixels = float(np.median([sum(rec.area_px for rec in r.records) for r in some]))
        table[n] = (len(some), pixels, float(np.percentile(ms, 50)), float(np.percentile(ms, 95)))
    return table


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", action="append", default=None, help="ONNX model(s) to time (repeatable) "
                    "[default: the shipped reference model]")
    ap.add_argument("--engine", default=Engine.ONNXRUNTIME.value, choices=[Engine.ONNXRUNTIME.value, Engine.OPENVINO.value])
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--frames", type=int, default=200)
    add_output(ap)
    args = ap.parse_args()

    models = args.model or [str(reference_model())]
    frames = cell_frames(args.frames)
    calibration = SynthCamera(640, 480, seed=0, mount_height_m=MOUNT_M).calibration()
    pipelines = {"true labels": TruthPipeline(list(CLASSES), calibration, profile=True)}
    pipelines.update({Path(m).name: Pipeline(Segmenter(m, threads=args.threads, engine=args.engine), calibration,
                                             profile=True) for m in models})
    rows, objects, by_count = {}, {}, {}
    for name, pipeline in pipelines.items():
        for f in frames[:3]:
            pipeline(f)  # warm-up
        runs = [pipeline(f) for f in frames]
        rows[name] = percentiles(runs)
        objects[name] = float(np.median([len(r.records) for r in runs]))
        by_count[name] = by_objects(runs)

    columns = list(next(iter(rows.values())))
    lines = [f"# Runtime per-stage time in the synthetic cell, 640x480, {args.threads} threads", "",
             f"Command: `python benchmarks/runtime_stages.py {' '.join(sys.argv[1:])}`  ",
             f"{machine_line()}; engine {args.engine}, onnxruntime {ort.__version__}; {len(frames)} frames of the synthetic "
             f"cell (seeds 0-{(len(frames) - 1) // PER_SEED}, camera {MOUNT_M} m over the table), one process, "
             "after 3 warm-up frames. ms, p50 / p95 over the frames; a sub-step's time is its sum over the frame's "
             "objects.", "",
             "| Stage | " + " | ".join(f"{n} (median {objects[n]:.0f} objects)" for n in rows) + " |",
             "|---" * (len(rows) + 1) + "|"]
    for col in columns:
        lines.append(f"| {col} | " + " | ".join(f"{r[col][0]:.2f} / {r[col][1]:.2f}" for r in rows.values()) + " |")
    counts = sorted({n for table in by_count.values() for n in table})
    lines += ["", "The grasp step by the objects it finds in the frame (frames; their median object pixels; grasp p50 / p95 "
              "ms): its cost follows the pixels of the objects it works on.", "",
              "| Objects | " + " | ".join(rows) + " |", "|---" * (len(rows) + 1) + "|"]
    for n in counts:
        cells = [f"{t[n][0]}; {t[n][1]:.0f} px; {t[n][2]:.2f} / {t[n][3]:.2f}" if n in t else "-" for t in by_count.values()]
        lines.append(f"| {n} | " + " | ".join(cells) + " |")
    worst = max(r["grasp"][1] for r in rows.values())
    lines += ["", f"Grasp step p95, slowest labels: **{worst:.2f} ms** (target <= 5 ms). The true-label column has no "
              "model: its pre, inference and post are 0."]
    emit("\n".join(lines) + "\n", args)
    print(json.dumps(rows), file=sys.stderr)


if __name__ == "__main__":
    main()
