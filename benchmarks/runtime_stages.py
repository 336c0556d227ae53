"""Per-stage time of the runtime at 640x480 on a fixed thread count (target: everything
outside inference <= 5 ms median).

    python benchmarks/runtime_stages.py [--model m.onnx ...] [--threads 2] [--frames 20] [--out FILE.md | --save]

Frames are synthetic 640x480 scenes. Without --model, an untrained DeepLabV3-MobileNetV3 at
640x480 is exported as fp32 and static int8 (needs the [train] extra); an untrained model's
labels are noise, so the grasp stage is also timed on each scene's true label image, which has
the real number of objects. One process, same frames for every model, after warm-up.
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import onnxruntime as ort

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from _common import add_output, emit, machine_line, untrained_checkpoint  # noqa: E402

from edgepick.data.render import CLASSES, SceneRenderer  # noqa: E402
from edgepick.frames import Frame  # noqa: E402
from edgepick.geometry import Intrinsics, Size  # noqa: E402
from edgepick.runtime.grasp import grasp_records  # noqa: E402
from edgepick.runtime.pipeline import STAGES, Pipeline, median_ms  # noqa: E402
from edgepick.runtime.session import Segmenter  # noqa: E402


def default_models(work: Path) -> list[str]:
    from edgepick.data.synth import SynthConfig, synthesize
    from edgepick.export.onnx_export import export_checkpoint
    from edgepick.quant.passes import folder_images, quantize_static

    data = work / "data"
    synthesize(data, SynthConfig(scenes=20, seed=3, splits=(16, 2, 2)), progress=False)
    ckpt = untrained_checkpoint(work / "untrained.pt", Size(640, 480), list(CLASSES))
    fp32 = export_checkpoint(ckpt, work / "fp32.onnx").out
    int8 = quantize_static(ckpt, folder_images(data, "train", 16), work / "int8.onnx", progress=False).out
    return [fp32, int8]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", action="append", default=None, help="ONNX model(s) to time (repeatable)")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--frames", type=int, default=20)
    ap.add_argument("--repeats", type=int, default=3, help="timed passes over the frames")
    add_output(ap)
    args = ap.parse_args()

    work = Path(tempfile.mkdtemp(prefix="runtime-stages-"))
    try:
        models = args.model or default_models(work)
        intr = Intrinsics.d415(640, 480)
        renderer = SceneRenderer(intr)
        scenes = [renderer.render(np.random.default_rng([11, i])) for i in range(args.frames)]
        frames = [Frame(s.rgb, s.depth, intr, str(i)) for i, s in enumerate(scenes)]

        true_grasp = []
        for _ in range(args.repeats):
            for s in scenes:
                t0 = time.perf_counter()
                grasp_records(s.mask, s.depth, intr, CLASSES)
                true_grasp.append(1000 * (time.perf_counter() - t0))
        objects = np.median([len(grasp_records(s.mask, s.depth, intr, CLASSES)) for s in scenes])

        rows = {}
        for path in models:
            pipe = Pipeline(Segmenter(path, threads=args.threads))
            for f in frames[:3]:
                pipe(f)  # warm-up
            runs = [pipe(f).ms for _ in range(args.repeats) for f in frames]
            rows[Path(path).name] = (median_ms(runs), float(np.percentile([sum(r.values()) for r in runs], 95)),
                                     pipe.segmenter.info.input_size)
    finally:
        shutil.rmtree(work, ignore_errors=True)

    true_med = float(np.median(true_grasp))
    lines = [f"# Runtime per-stage time, 640x480 frames, {args.threads} onnxruntime threads",
             "", f"Command: `python benchmarks/runtime_stages.py {' '.join(sys.argv[1:])}`  ",
             f"{machine_line()}; onnxruntime "
             f"{ort.__version__}; {args.frames} synthetic frames x {args.repeats} passes after warm-up, one process. "
             f"Medians in ms.", "",
             "| Model (input) | " + " | ".join(STAGES) + " | outside inference | total p50 | total p95 |",
             "|---" * (len(STAGES) + 4) + "|"]
    for name, (med, p95, size) in rows.items():
        lines.append(f"| {name} ({size}) | " + " | ".join(f"{med[s]:.2f}" for s in STAGES)
                     + f" | {med['outside_inference']:.2f} | {med['total']:.1f} | {p95:.1f} |")
    lines += ["", f"Grasp stage on the scenes' true label images (median {objects:.0f} objects per frame): "
              f"**{true_med:.2f} ms** median.", ""]
    worst = max(med["pre"] + med["post"] for med, _, _ in rows.values())
    lines.append(f"Outside inference with true labels (pre + post of the slowest model + grasp): "
                 f"**{worst + true_med:.2f} ms** (target <= 5 ms).")
    report = "\n".join(lines) + "\n"
    emit(report, args)
    print(json.dumps({n: m for n, (m, _, _) in rows.items()}), file=sys.stderr)


if __name__ == "__main__":
    main()
